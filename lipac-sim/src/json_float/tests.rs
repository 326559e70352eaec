use serde::{Deserialize, Serialize};

#[derive(Debug, Serialize, Deserialize)]
struct Row {
    #[serde(with = "crate::json_float")]
    x: f64,
    #[serde(with = "crate::json_float::vec")]
    v: Vec<f64>,
}

fn round_trip(x: f64, v: Vec<f64>) -> (String, Row) {
    let text = serde_json::to_string(&Row { x, v }).unwrap();
    let back = serde_json::from_str(&text).unwrap_or_else(|e| panic!("{text}: {e}"));
    (text, back)
}

#[test]
fn non_finite_values_round_trip_as_strings() {
    let (text, back) = round_trip(f64::INFINITY, vec![f64::NEG_INFINITY, f64::NAN, 0.5]);
    assert_eq!(text, r#"{"x":"inf","v":["-inf","nan",0.5]}"#);
    assert_eq!(back.x, f64::INFINITY);
    assert_eq!(back.v[0], f64::NEG_INFINITY);
    assert!(back.v[1].is_nan());
    assert_eq!(back.v[2], 0.5);
}

#[test]
fn finite_values_stay_numbers_bit_for_bit() {
    let values = [
        0.0,
        -0.0,
        0.1,
        1.0 / 3.0,
        f64::MAX,
        f64::MIN_POSITIVE,
        5e-324,
        -7.0,
    ];
    for x in values {
        let (text, back) = round_trip(x, values.to_vec());
        assert_eq!(text.matches('"').count(), 4, "numbers, not strings: {text}");
        assert_eq!(back.x.to_bits(), x.to_bits(), "{text}");
        let bits: Vec<u64> = back.v.iter().map(|v| v.to_bits()).collect();
        let want: Vec<u64> = values.iter().map(|v| v.to_bits()).collect();
        assert_eq!(bits, want);
    }
    // Integers written by other tools read as numbers.
    let r: Row = serde_json::from_str(r#"{"x":3,"v":[-2,7]}"#).unwrap();
    assert_eq!((r.x, r.v), (3.0, vec![-2.0, 7.0]));
}

#[test]
fn other_strings_and_null_are_refused() {
    for text in [
        r#"{"x":"infinity","v":[]}"#,
        r#"{"x":null,"v":[]}"#,
        r#"{"x":1,"v":["Inf"]}"#,
        r#"{"x":1,"v":[null]}"#,
        r#"{"x":1,"v":3}"#,
    ] {
        let e = serde_json::from_str::<Row>(text).unwrap_err().to_string();
        assert!(e.contains("inf"), "{text}: {e}");
    }
}
