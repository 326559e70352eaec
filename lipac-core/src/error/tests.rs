use super::*;

#[test]
fn messages_name_the_offending_value() {
    let e = CoreError::NonFiniteTransform {
        element: 7,
        value: f32::NAN,
    };
    let s = e.to_string();
    assert!(s.contains("element 7") && s.contains("row 1") && s.contains("column 3"));
    assert!(s.contains("NaN"));

    let key = (3u64 << 32) | 42;
    let s = CoreError::StaleHandle {
        kind: "instance",
        key,
    }
    .to_string();
    assert!(s.contains("index 42") && s.contains("version 3"), "{s}");

    let s = CoreError::FieldOutOfRange {
        field: "sbt_offset",
        value: 1 << 24,
        max: (1 << 24) - 1,
    }
    .to_string();
    assert!(s.contains("16777216") && s.contains("16777215"), "{s}");
}
