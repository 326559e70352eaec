//! Run time per strategy (issue 13 item 5): the CPU times are positive where
//! there is work, zero where there is none, and sum to the frame time; the
//! modelled GPU times are the model's formula over the frame's counts.

use lipac_sim::compare::{run_choice, CompareConfig, SceneChoice};
use lipac_sim::metrics::GpuModel;
use lipac_sim::strategy::StrategyKind;

#[test]
fn timings_are_positive_sum_to_the_frame_and_follow_the_work() {
    let config = CompareConfig {
        frames: Some(4),
        width: 32,
        height: 18,
        strategies: StrategyKind::ALL.to_vec(),
        share_ground_truth: true,
        threads: 2,
        adaptive_levels: None,
        lipac_cell_size: None,
        lipac_rise_shift: None,
        lipac_start: lipac_sim::compare::LipacStart::Default,
        lipac_warm_start_at_cuts: false,
        lipac_warm_start_hold: None,
        device: Default::default(),
    };
    let r = run_choice(SceneChoice::Small, None, &config, &mut |_, _| {}).unwrap();
    let t = r.blas_throughput;
    assert!(t.build_ns_per_triangle > 0.0 && t.refit_ns_per_triangle > 0.0);
    assert!(t.triangles_built > 0 && t.triangles_refit > 0);
    assert_eq!(r.gpu_model, GpuModel::PUBLISHED);
    let (mut idle_frames, mut building_frames) = (0, 0);
    for st in &r.strategies {
        for m in &st.frames {
            let what = format!("{} frame {}", st.name, m.frame);
            assert!(m.trace_ms > 0.0 && m.traced_rays > 0, "{what}");
            assert!(m.tlas_build_ms > 0.0, "{what}");
            let sum = m.blas_build_ms + m.blas_refit_ms + m.tlas_build_ms + m.trace_ms;
            assert!((m.frame_ms - sum).abs() <= 1e-12 * sum, "{what}");
            assert!(m.frame_ms > m.trace_ms, "{what}");
            // A strategy that builds (refits) nothing spends no build (refit)
            // time; one that does, some, in proportion to its triangles.
            assert_eq!(m.primitives_built == 0, m.blas_build_ms == 0.0, "{what}");
            assert_eq!(m.primitives_refit == 0, m.blas_refit_ms == 0.0, "{what}");
            let expected = m.primitives_built as f64 * t.build_ns_per_triangle * 1e-6;
            assert!(
                (m.blas_build_ms - expected).abs() <= 1e-12 * expected,
                "{what}"
            );
            if m.primitives_built == 0 {
                idle_frames += 1;
            } else {
                building_frames += 1;
            }
            // The model: each count over its published throughput.
            let g = GpuModel::PUBLISHED.frame(
                m.primitives_built,
                m.builds,
                m.primitives_refit,
                m.tlas_instances,
                m.traced_rays,
            );
            assert_eq!(m.gpu_frame_ms, g.frame_ms, "{what}");
            assert_eq!(m.gpu_blas_build_ms, g.blas_build_ms, "{what}");
            assert!(m.gpu_frame_ms > 0.0 && m.gpu_tlas_build_ms > 0.0, "{what}");
        }
        let s = &st.summary;
        let mean = st.frames.iter().map(|m| m.frame_ms).sum::<f64>() / st.frames.len() as f64;
        assert!((s.mean_frame_ms - mean).abs() <= 1e-9 * mean, "{}", st.name);
        assert!(s.median_frame_ms > 0.0);
    }
    // Both cases occur, so both halves of the check above ran.
    assert!(idle_frames > 0 && building_frames > 0);
    // LiPaC's saving shows: it builds fewer triangles than the full scene
    // in these frames, and its modelled BLAS build time is lower with them.
    let (full, lipac) = (r.strategy("full").unwrap(), r.strategy("lipac").unwrap());
    assert!(lipac.summary.primitives_built < full.summary.primitives_built);
    assert!(lipac.summary.mean_gpu_blas_build_ms < full.summary.mean_gpu_blas_build_ms);
}
