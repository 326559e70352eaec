use super::*;

#[test]
fn embedded_spirv_is_spirv() {
    for (name, spv) in ALL_SPV {
        let words = spirv_words(spv).unwrap();
        assert_eq!(words[0], 0x0723_0203, "{name}");
    }
    assert!(spirv_words(&[1, 2, 3]).is_err());
    assert!(spirv_words(&[0; 8]).is_err());
}

#[test]
fn includes_are_written_to_a_directory_and_include_only_each_other() {
    let dir = std::env::temp_dir().join(format!("lipac-includes-{}", std::process::id()));
    let written = write_includes(&dir).unwrap();
    assert_eq!(written.len(), INCLUDES.len());
    let names: Vec<&str> = INCLUDES.iter().map(|(n, _)| *n).collect();
    for (path, (name, text)) in written.iter().zip(INCLUDES) {
        assert_eq!(std::fs::read_to_string(path).unwrap(), text, "{name}");
        for line in text.lines().filter(|l| l.starts_with("#include")) {
            let inc = line.split('"').nth(1).unwrap();
            assert!(
                names.contains(&inc),
                "{name} includes {inc}, which is not written"
            );
        }
    }
    std::fs::remove_dir_all(&dir).unwrap();
}
