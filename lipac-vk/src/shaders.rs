//! Embedded shaders: SPIR-V compiled from `lipac-vk/shaders/*.comp` by
//! `lipac-vk/shaders/build.sh` (glslangValidator `--target-env vulkan1.2`),
//! and the GLSL include for engines' own shaders.

use crate::error::{Result, VkError};

/// SPIR-V of `trace_test.comp`: traces rays from a buffer against a TLAS with
/// counting-box pass-through (see [`crate::TracePipeline`]).
pub const TRACE_TEST_SPV: &[u8] = include_bytes!("../shaders/spv/trace_test.spv");

/// GLSL source of `trace_test.comp`.
pub const TRACE_TEST_GLSL: &str = include_str!("../shaders/trace_test.comp");

/// `lipac_counting.glsl`: the counting-box pass-through for engines'
/// ray-query shaders (`lipacTraceCounting`, `lipacIsCountingBox`,
/// `lipacCountBox`, `lipacMaskOutCountingBoxes`). Write it next to your
/// shaders and `#include` it; its header lists the macros to define.
pub const LIPAC_COUNTING_GLSL: &str = include_str!("../shaders/lipac_counting.glsl");

/// Converts SPIR-V bytes to words (checks length and magic number).
///
/// # Errors
///
/// [`VkError::InvalidArgument`] when the bytes are not SPIR-V.
pub fn spirv_words(bytes: &[u8]) -> Result<Vec<u32>> {
    ash::util::read_spv(&mut std::io::Cursor::new(bytes))
        .map_err(|e| VkError::InvalidArgument(format!("not SPIR-V: {e}")))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn embedded_spirv_is_spirv() {
        let words = spirv_words(TRACE_TEST_SPV).unwrap();
        assert_eq!(words[0], 0x0723_0203);
        assert!(spirv_words(&[1, 2, 3]).is_err());
        assert!(spirv_words(&[0; 8]).is_err());
    }
}
