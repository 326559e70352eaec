//! lipac-vk's device tests: one binary with a libtest-mimic harness.
//!
//! It probes the Vulkan device once (`HeadlessContext`, as every test
//! creates it: `LIPAC_VK_DEVICE` picks the device, `LIPAC_VK_HIDE` hides
//! tracing paths), prints the device and its tracing paths, runs every test
//! the device can run and reports the others as **ignored**, listing each
//! with the reason in a summary at the end: a test that could not run is
//! never reported as passed. `LIPAC_REQUIRE_VULKAN=1` (CI) makes a missing
//! device, validation layer or glslangValidator, and any test that could not
//! run (a missing tracing path too), a failure instead;
//! `LIPAC_REQUIRE_VULKAN=device` (a GPU machine without the layer or
//! glslang) only a missing device.
//!
//! ```text
//! cargo test -p lipac-vk --test device                       # all
//! cargo test -p lipac-vk --test device -- gpu_reference::     # one module
//! target/release/deps/device-<hash> --nocapture --test-threads 4
//! ```
//! libtest's flags work (`--nocapture`, filters, `--exact`, `--list`,
//! `--ignored`, `--include-ignored`, `--test-threads`); a test forced with
//! `--include-ignored` on a device without its feature fails with the
//! missing feature named.

mod adaptive_backend;
mod adaptive_hitboxes;
mod allocator;
mod api_errors;
mod as_pool;
mod backend;
mod blas_update;
mod common;
mod compaction;
mod counting;
mod executor;
mod gpu_reference;
mod hashed_backend;
mod lifetimes;
mod merged_counting;
mod pipeline_tracing;
mod ray_query_test_pipeline;
mod shaders;
mod trace_counting;
mod upload;
mod validation;

use libtest_mimic::{Arguments, Trial};
use lipac_vk::HeadlessContext;
use std::process::ExitCode;

/// What a test needs of the machine.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Needs {
    /// A device (acceleration structures; no tracing).
    Device,
    /// A device whose messenger records messages (`VK_EXT_debug_utils`).
    DebugUtils,
    /// A device with the validation layer enabled.
    ValidationLayer,
    /// A device with a tracing path (the test traces on the preferred one,
    /// or on each it has).
    Tracing,
    /// A device with ray queries and ray-tracing pipelines (the paths are
    /// compared).
    BothPaths,
    /// glslangValidator and the shader sources.
    Glslang,
}

struct DeviceTest {
    name: &'static str,
    needs: Needs,
    run: fn(),
}

macro_rules! tests {
    ($($needs:ident $module:ident :: $name:ident),* $(,)?) => {
        &[$(DeviceTest {
            name: concat!(stringify!($module), "::", stringify!($name)),
            needs: Needs::$needs,
            run: $module::$name,
        }),*]
    };
}

const TESTS: &[DeviceTest] = tests![
    Tracing adaptive_backend::adaptive_frame_loop_equals_the_cpu_and_the_leaf_only_trace_levels_2,
    Tracing adaptive_backend::adaptive_frame_loop_equals_the_cpu_and_the_leaf_only_trace_levels_3,
    Tracing adaptive_backend::camera_tracer_refuses_a_grid_larger_than_its_hitbox_buffers,
    Device adaptive_hitboxes::merged_assembly_matches_cpu_reference,
    Tracing allocator::custom_allocator_serves_every_buffer_and_gets_every_allocation_back,
    Device allocator::gpu_allocator_packs_buffers_into_blocks_with_exact_stats,
    Device api_errors::caller_mistakes_are_errors,
    Device api_errors::size_queries_match_builds_and_grow_with_content,
    Tracing as_pool::pooled_blases_share_blocks_trace_correctly_and_free_their_ranges,
    Device backend::tables_and_data_grow_and_assembly_matches_the_manager,
    Device backend::a_warm_start_reaches_the_gpu_records,
    Tracing blas_update::refit_and_rebuild_in_place_trace_the_deformed_mesh,
    Tracing compaction::compacted_blases_are_no_larger_and_trace_the_same,
    Tracing counting::counting_boxes_count_once_and_let_rays_through,
    Device executor::scheduler_plans_recorded_by_the_executor_stay_consistent,
    Device gpu_reference::assembly_matches_cpu_reference,
    Device gpu_reference::assembly_signed_zero_and_nan_heights_match_cpu,
    Device gpu_reference::assembly_slot_count_and_small_tlas_buffer,
    Device gpu_reference::frames_match_cpu_reference_without_overflow,
    Device gpu_reference::feedback_overflow_invariants,
    Device gpu_reference::feedback_rejects_bad_arguments,
    Device gpu_reference::readback_ring_waits_for_the_gpu_wraps_and_never_blocks,
    Device gpu_reference::hitbox_transitions_match_exhaustively,
    Device gpu_reference::decayed_hitbox_transitions_match_exhaustively,
    Device gpu_reference::command_priorities_match_at_every_boundary,
    Tracing gpu_reference::assembled_tlas_builds_and_counts_boxes,
    Tracing hashed_backend::hashed_index_on_the_gpu_equals_the_cpu_backend_paper_rule,
    Tracing hashed_backend::hashed_index_on_the_gpu_equals_the_cpu_backend_decayed_rule,
    Tracing hashed_backend::held_warm_starts_on_the_gpu_equal_the_cpu_backend,
    Tracing hashed_backend::escape_sums_equal_the_cpu_for_random_large_hit_counts,
    Tracing lifetimes::double_buffered_tlas_and_deferred_destruction,
    Tracing merged_counting::merged_boxes_count_on_the_gpu_what_leaf_boxes_count,
    Tracing pipeline_tracing::random_rays_count_alike_on_both_paths_and_the_cpu,
    BothPaths pipeline_tracing::camera_frames_are_equal_on_both_paths,
    Device pipeline_tracing::tracers_refuse_a_device_without_their_path,
    Tracing ray_query_test_pipeline::traced_rays_hit_the_right_instance_at_the_right_distance,
    Glslang shaders::committed_spirv_matches_glsl_sources,
    Tracing trace_counting::trace_counts_into_hitbox_records_saturating,
    Device upload::gpu_upload_equals_apply_uploads,
    Device upload::upload_targets_are_checked,
    DebugUtils validation::messenger_records_error_messages,
    ValidationLayer validation::validation_layer_errors_are_recorded,
];

/// What the probe found.
struct Machine {
    /// The device's summary line, or why there is none.
    device: Result<HeadlessContext, String>,
    /// Why glslangValidator cannot run the shader check, if it cannot.
    glslang: Option<String>,
}

impl Machine {
    fn probe() -> Self {
        let device = HeadlessContext::new(common::validation()).map_err(|e| e.to_string());
        let dir = shaders::shader_dir();
        let glslang = if !dir.is_dir() {
            Some(format!(
                "the shader sources ({}) are not on this machine",
                dir.display()
            ))
        } else {
            match std::process::Command::new("glslangValidator")
                .arg("--version")
                .output()
            {
                Ok(o) if o.status.success() => None,
                _ => {
                    Some("glslangValidator is not installed (apt-get install glslang-tools)".into())
                }
            }
        };
        Self { device, glslang }
    }

    /// Why `needs` cannot be met here (`None`: the test runs).
    fn missing(&self, needs: Needs) -> Option<String> {
        if needs == Needs::Glslang {
            return self.glslang.clone();
        }
        let h = match &self.device {
            Ok(h) => h,
            Err(e) => return Some(format!("no Vulkan device: {e}")),
        };
        let tracing = h.context().tracing();
        match needs {
            Needs::Device | Needs::Glslang => None,
            Needs::DebugUtils => {
                (!h.records_messages()).then(|| "VK_EXT_debug_utils is not available".into())
            }
            Needs::ValidationLayer => (!h.validation_enabled())
                .then(|| "VK_LAYER_KHRONOS_validation is not installed".into()),
            Needs::Tracing => (!tracing.any()).then(|| "no tracing path".into()),
            Needs::BothPaths => (!(tracing.ray_query && tracing.ray_tracing_pipeline)).then(|| {
                format!(
                    "compares ray queries with ray-tracing pipelines; this device offers {tracing}"
                )
            }),
        }
    }
}

fn main() -> ExitCode {
    let args = Arguments::from_args();
    let required = common::vulkan_required();
    let device_required = common::device_required();
    let machine = Machine::probe();
    let device_line = match &machine.device {
        Ok(h) => h.summary(),
        Err(e) => format!("none ({e})"),
    };
    if !args.list {
        println!("lipac-vk device tests on: {device_line}");
    }
    if device_required {
        // CI: a device (with the validation layer, which the probe required)
        // and glslangValidator must be there; `=device`: a device.
        let mut fatal = Vec::new();
        if let Err(e) = &machine.device {
            fatal.push(format!("no Vulkan device: {e}"));
        }
        if let (true, Some(why)) = (required, &machine.glslang) {
            fatal.push(why.clone());
        }
        if !fatal.is_empty() {
            eprintln!(
                "LIPAC_REQUIRE_VULKAN is set but {} (install mesa-vulkan-drivers >= 23, \
                 vulkan-validationlayers, glslang-tools)",
                fatal.join("; ")
            );
            return ExitCode::FAILURE;
        }
    }
    let mut skipped = Vec::new();
    let trials: Vec<Trial> = TESTS
        .iter()
        .map(|t| {
            let run = t.run;
            let trial = Trial::test(t.name, move || {
                run();
                Ok(())
            });
            match machine.missing(t.needs) {
                Some(why) => {
                    skipped.push((t.name, why));
                    trial.with_ignored_flag(true)
                }
                None => trial,
            }
        })
        .collect();
    // CI's lavapipe offers everything the tests need (both tracing paths
    // too): there a test that could not run is a failure, not a skip.
    if required && !skipped.is_empty() {
        eprintln!("LIPAC_REQUIRE_VULKAN=1 is set but these tests cannot run here:");
        for (name, why) in &skipped {
            eprintln!("  {name}: {why}");
        }
        return ExitCode::FAILURE;
    }
    // The probe's device is not needed while the tests run.
    drop(machine);
    let conclusion = libtest_mimic::run(&args, trials);
    if !args.list {
        let ran = conclusion.num_passed + conclusion.num_failed;
        println!(
            "lipac-vk device tests: {ran} ran ({} passed, {} failed), {} filtered out, \
             {} not run, on {device_line}",
            conclusion.num_passed,
            conclusion.num_failed,
            conclusion.num_filtered_out,
            conclusion.num_ignored
        );
        if !skipped.is_empty()
            && conclusion.num_ignored > 0
            && !args.ignored
            && !args.include_ignored
        {
            println!("not run on this machine (reported as ignored, not as passed):");
            for (name, why) in &skipped {
                if args.filter.as_deref().is_none_or(|f| {
                    if args.exact {
                        name == &f
                    } else {
                        name.contains(f)
                    }
                }) {
                    println!("  {name}: {why}");
                }
            }
        }
    }
    conclusion.exit_code()
}
