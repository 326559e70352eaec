//! Embedded shaders: SPIR-V compiled from `lipac-vk/shaders/*.comp` by
//! `lipac-vk/shaders/build.sh` (glslangValidator `--target-env vulkan1.2`),
//! and the GLSL include for engines' own shaders.

use crate::error::{Result, VkError};

/// SPIR-V of `trace_test.comp`: traces rays from a buffer against a TLAS with
/// counting-box pass-through (see [`crate::RayQueryTestPipeline`]).
pub const TRACE_TEST_SPV: &[u8] = include_bytes!("../shaders/spv/trace_test.spv");

/// SPIR-V of `trace_counting.comp`: `trace_test.comp` counting hitbox hits
/// straight into the `HitboxRecord` buffer (`LIPAC_HITBOX_RECORDS`; see
/// [`crate::HitboxCounting::Records`]).
pub const TRACE_COUNTING_SPV: &[u8] = include_bytes!("../shaders/spv/trace_counting.spv");
/// SPIR-V of `trace_merged.comp`: `trace_counting.comp` resolving adaptive
/// hitboxes' merged boxes to their leaf boxes ([`crate::MergedTraceTestPipeline`]).
pub const TRACE_MERGED_SPV: &[u8] = include_bytes!("../shaders/spv/trace_merged.spv");
/// SPIR-V of `upload_records.comp`: the record upload scatter
/// ([`crate::RecordUploader`]).
pub const UPLOAD_RECORDS_SPV: &[u8] = include_bytes!("../shaders/spv/upload_records.spv");

/// SPIR-V of `hitbox_reset.comp` (Algorithm 1 pass 0, [`crate::AssemblyPipeline`]).
pub const HITBOX_RESET_SPV: &[u8] = include_bytes!("../shaders/spv/hitbox_reset.spv");
/// SPIR-V of `assemble_instances.comp` (Algorithm 1 pass 1).
pub const ASSEMBLE_INSTANCES_SPV: &[u8] = include_bytes!("../shaders/spv/assemble_instances.spv");
/// SPIR-V of `assemble_hitboxes.comp` (Algorithm 1 pass 2).
pub const ASSEMBLE_HITBOXES_SPV: &[u8] = include_bytes!("../shaders/spv/assemble_hitboxes.spv");
/// SPIR-V of `assemble_merged.comp` (Algorithm 1 pass 2 with adaptive
/// hitboxes, `lipac_core::hitbox_tree`).
pub const ASSEMBLE_MERGED_SPV: &[u8] = include_bytes!("../shaders/spv/assemble_merged.spv");
/// SPIR-V of `feedback_accumulate.comp` (Algorithm 2 lines 1–6,
/// [`crate::FeedbackPipeline`]).
pub const FEEDBACK_ACCUMULATE_SPV: &[u8] = include_bytes!("../shaders/spv/feedback_accumulate.spv");
/// SPIR-V of `feedback_hitboxes.comp` (Algorithm 2 lines 7–13).
pub const FEEDBACK_HITBOXES_SPV: &[u8] = include_bytes!("../shaders/spv/feedback_hitboxes.spv");
/// SPIR-V of `feedback_instances.comp` (Algorithm 2 lines 14–38).
pub const FEEDBACK_INSTANCES_SPV: &[u8] = include_bytes!("../shaders/spv/feedback_instances.spv");

/// SPIR-V of `escape_sums.comp`: the escape fraction's box and traced hit
/// sums of a frame (read back with its commands, see
/// [`crate::FrameReadback::escape`]).
pub const ESCAPE_SUMS_SPV: &[u8] = include_bytes!("../shaders/spv/escape_sums.spv");

/// SPIR-V of `camera_trace.comp`: a frame's primary, shadow and bounce rays
/// generated on the GPU through the counting include, merged boxes of
/// adaptive hitboxes resolved ([`crate::CameraTracer`]).
pub const CAMERA_TRACE_SPV: &[u8] = include_bytes!("../shaders/spv/camera_trace.spv");

/// GLSL source of `camera_trace.comp`: an engine-style ray-query pass with
/// lipac's counting (GPU ray generation, shadow and bounce rays).
pub const CAMERA_TRACE_GLSL: &str = include_str!("../shaders/camera_trace.comp");

/// SPIR-V of `pipeline_trace.rgen`: ray generation of
/// [`crate::PipelineTestTracer`] (rays from a buffer, `trace_merged.comp`
/// with a ray-tracing pipeline).
pub const PIPELINE_TRACE_SPV: &[u8] = include_bytes!("../shaders/spv/pipeline_trace.rgen.spv");
/// SPIR-V of `pipeline_camera.rgen`: ray generation of
/// [`crate::PipelineCameraTracer`] (`camera_trace.comp` with a ray-tracing
/// pipeline).
pub const PIPELINE_CAMERA_SPV: &[u8] = include_bytes!("../shaders/spv/pipeline_camera.rgen.spv");
/// SPIR-V of `pipeline_hit.rchit`: closest-hit of real geometry in lipac's
/// pipeline tracers.
pub const PIPELINE_HIT_SPV: &[u8] = include_bytes!("../shaders/spv/pipeline_hit.rchit.spv");
/// SPIR-V of `pipeline_hit.rahit`: any-hit of real geometry in lipac's
/// pipeline tracers (skips real instances in the boxes-alone trace).
pub const PIPELINE_HIT_AHIT_SPV: &[u8] = include_bytes!("../shaders/spv/pipeline_hit.rahit.spv");
/// SPIR-V of `pipeline_box.rahit`: any-hit of counting boxes.
pub const PIPELINE_BOX_AHIT_SPV: &[u8] = include_bytes!("../shaders/spv/pipeline_box.rahit.spv");
/// SPIR-V of `pipeline_box.rchit`: closest-hit of counting boxes.
pub const PIPELINE_BOX_CHIT_SPV: &[u8] = include_bytes!("../shaders/spv/pipeline_box.rchit.spv");
/// SPIR-V of `pipeline_miss.rmiss`: miss shader of lipac's pipeline tracers.
pub const PIPELINE_MISS_SPV: &[u8] = include_bytes!("../shaders/spv/pipeline_miss.rmiss.spv");

/// Every embedded SPIR-V module with the name of its source: a compute
/// shader's without extension (`trace_test` for `trace_test.comp`), a
/// ray-tracing stage's with it (`pipeline_hit.rchit`); the file is
/// `shaders/spv/{name}.spv`. For tooling and the freshness test.
pub const ALL_SPV: [(&str, &[u8]); 20] = [
    ("camera_trace", CAMERA_TRACE_SPV),
    ("trace_test", TRACE_TEST_SPV),
    ("trace_counting", TRACE_COUNTING_SPV),
    ("trace_merged", TRACE_MERGED_SPV),
    ("upload_records", UPLOAD_RECORDS_SPV),
    ("hitbox_reset", HITBOX_RESET_SPV),
    ("assemble_instances", ASSEMBLE_INSTANCES_SPV),
    ("assemble_hitboxes", ASSEMBLE_HITBOXES_SPV),
    ("assemble_merged", ASSEMBLE_MERGED_SPV),
    ("feedback_accumulate", FEEDBACK_ACCUMULATE_SPV),
    ("feedback_hitboxes", FEEDBACK_HITBOXES_SPV),
    ("feedback_instances", FEEDBACK_INSTANCES_SPV),
    ("escape_sums", ESCAPE_SUMS_SPV),
    ("pipeline_trace.rgen", PIPELINE_TRACE_SPV),
    ("pipeline_camera.rgen", PIPELINE_CAMERA_SPV),
    ("pipeline_hit.rchit", PIPELINE_HIT_SPV),
    ("pipeline_hit.rahit", PIPELINE_HIT_AHIT_SPV),
    ("pipeline_box.rahit", PIPELINE_BOX_AHIT_SPV),
    ("pipeline_box.rchit", PIPELINE_BOX_CHIT_SPV),
    ("pipeline_miss.rmiss", PIPELINE_MISS_SPV),
];

/// `lipac_layout.glsl`: lipac's records (`LipacInstanceRecord`,
/// `LipacHitboxRecord`, `LipacTlasInstance`) and bit constants as std430
/// GLSL, `LIPAC_HITBOX_ADD_HITS` (saturating hitbox hit count) and
/// `lipacAxisMap` (a counting box's unit-cube map). Needed next to
/// `lipac_counting.glsl` when an engine defines `LIPAC_HITBOX_RECORDS` (and
/// so for merged boxes, `LIPAC_SBT_MERGED_BOX`).
pub const LIPAC_LAYOUT_GLSL: &str = include_str!("../shaders/lipac_layout.glsl");

/// GLSL source of `trace_test.comp`.
pub const TRACE_TEST_GLSL: &str = include_str!("../shaders/trace_test.comp");

/// GLSL source of `trace_counting.comp`: the reference for an engine's
/// tracer that counts into lipac's hitbox records.
pub const TRACE_COUNTING_GLSL: &str = include_str!("../shaders/trace_counting.comp");

/// `lipac_counting.glsl`: the counting-box pass-through for engines'
/// ray-query shaders (`lipacTraceCounting`, `lipacIsCountingBox`,
/// `lipacCountBox`, `lipacMaskOutCountingBoxes`). Write it next to your
/// shaders and `#include` it; its header lists the macros to define.
pub const LIPAC_COUNTING_GLSL: &str = include_str!("../shaders/lipac_counting.glsl");

/// `lipac_counting_common.glsl`: what the ray-query and the pipeline
/// includes share (macro checks, box helpers, merged-box resolution,
/// `LipacHit`); both include it.
pub const LIPAC_COUNTING_COMMON_GLSL: &str = include_str!("../shaders/lipac_counting_common.glsl");

/// `lipac_payload.glsl`: `LipacPayload`, the payload part of the pipeline
/// include (include it before declaring the payload).
pub const LIPAC_PAYLOAD_GLSL: &str = include_str!("../shaders/lipac_payload.glsl");

/// `lipac_counting_pipeline.glsl`: counting boxes for engines that trace
/// with ray-tracing pipelines (`lipacTraceCountingPipeline` in ray
/// generation; `lipacBoxAnyHit`, `lipacBoxClosestHit`, `lipacClosestHit`,
/// `lipacMiss` in the hit and miss shaders). Its header lists the macros.
pub const LIPAC_COUNTING_PIPELINE_GLSL: &str =
    include_str!("../shaders/lipac_counting_pipeline.glsl");

/// GLSL source of `pipeline_camera.rgen`: an engine-style ray generation
/// shader with lipac's pipeline counting (its hit shaders:
/// `pipeline_hit.rchit`, `pipeline_box.rahit`/`.rchit`, `pipeline_miss.rmiss`).
pub const PIPELINE_CAMERA_GLSL: &str = include_str!("../shaders/pipeline_camera.rgen");

/// The GLSL includes an engine's shaders need, by file name: the ray-query
/// include, the pipeline include and what they include.
pub const INCLUDES: [(&str, &str); 5] = [
    ("lipac_layout.glsl", LIPAC_LAYOUT_GLSL),
    ("lipac_counting_common.glsl", LIPAC_COUNTING_COMMON_GLSL),
    ("lipac_counting.glsl", LIPAC_COUNTING_GLSL),
    ("lipac_payload.glsl", LIPAC_PAYLOAD_GLSL),
    ("lipac_counting_pipeline.glsl", LIPAC_COUNTING_PIPELINE_GLSL),
];

/// Writes [`INCLUDES`] into the directory `dir` (created if missing), for
/// an engine's shader build: compile with
/// `glslangValidator --target-env vulkan1.2 -I<dir> shader.comp` (a
/// ray-tracing stage: `shader.rgen`, `.rchit`, `.rahit`, `.rmiss`; SPIR-V 1.4
/// or later, which `vulkan1.2` gives). Overwrites only these five files and
/// returns their paths.
///
/// ```no_run
/// let written = lipac_vk::shaders::write_includes(std::path::Path::new("shaders/lipac"))?;
/// assert_eq!(written.len(), 5);
/// # Ok::<(), std::io::Error>(())
/// ```
///
/// # Errors
///
/// The I/O error of creating the directory or writing a file.
pub fn write_includes(dir: &std::path::Path) -> std::io::Result<Vec<std::path::PathBuf>> {
    std::fs::create_dir_all(dir)?;
    INCLUDES
        .iter()
        .map(|(name, text)| {
            let path = dir.join(name);
            std::fs::write(&path, text)?;
            Ok(path)
        })
        .collect()
}

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
mod tests;
