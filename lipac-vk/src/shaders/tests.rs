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
