use super::*;
use crate::camera::CameraPath;
use crate::compare::StrategyRun;
use crate::memory::blas_bytes;
use crate::metrics::{FrameMetrics, Summary};
use crate::strategy::StrategyKind;

#[test]
fn ranks_average_ties_and_correlations_have_the_right_sign() {
    assert_eq!(ranks(&[3.0, 1.0, 3.0, 2.0]), vec![3.5, 1.0, 3.5, 2.0]);
    let x = [0.1, 0.2, 0.3, 0.4, 0.5];
    let y = [0.02, 0.05, 0.04, 0.09, 0.11];
    assert!(pearson(&x, &y) > 0.9);
    assert!((spearman(&x, &y) - 0.9).abs() < 1e-12);
    let neg: Vec<f64> = y.iter().map(|v| -v).collect();
    assert!((pearson(&x, &neg) + pearson(&x, &y)).abs() < 1e-12);
    assert!(pearson(&[1.0], &[2.0]).is_nan());
}

#[test]
fn bad_budgets_are_errors() {
    for mib in [0.0, -1.0, f64::NAN, f64::INFINITY, 1e-9] {
        assert!(manager_budget(mib).is_err(), "{mib}");
    }
    let Ok(ControlTarget::MemoryBudget { bytes }) = manager_budget(8.0) else {
        panic!("8 MiB is a budget");
    };
    assert_eq!(bytes + blas_bytes(12), 8 << 20);
}

fn run_of(
    name: &str,
    bytes: &[u64],
    target: Option<f64>,
    escape: &[f64],
    err: &[f64],
) -> StrategyRun {
    let frames = bytes
        .iter()
        .enumerate()
        .map(|(i, &b)| FrameMetrics {
            frame: i as u32,
            blas_bytes: b,
            error: err[i],
            escape_fraction: Some(escape[i]),
            threshold_scale: Some(1.0 + i as f64 / 100.0),
            control_target: target,
            ..FrameMetrics::default()
        })
        .collect();
    StrategyRun {
        name: name.into(),
        summary: Summary::default(),
        frames,
        last_geometry: Vec::new(),
    }
}

fn report(strategies: Vec<StrategyRun>) -> CompareReport {
    CompareReport {
        scene: "test".into(),
        instances: 1,
        frames: strategies[0].frames.len() as u32,
        width: 1,
        height: 1,
        rays_per_frame: 1,
        thresholds: [0; 6],
        ground_truth_ms: 0.0,
        full_tlas_ms: 0.0,
        geometry_ms: 0.0,
        traced_rays_per_frame: 0.0,
        wall_s: 0.0,
        strategies,
        camera_cuts: vec![100],
        rule: String::new(),
        start: String::new(),
        blas_throughput: Default::default(),
        gpu_model: Default::default(),
        device_profile: Default::default(),
    }
}

#[test]
fn budget_figures_measure_the_settled_frames_and_the_jump() {
    let budget = 1_000_000u64;
    let n = 200;
    // Far off before settling, 2 % over until the jump, 10 % under for 20
    // frames after it, then on the budget.
    let bytes: Vec<u64> = (0..n)
        .map(|f| match f {
            f if f < SETTLE_FRAMES as usize => 100,
            f if f < 100 => budget * 102 / 100,
            f if f < 120 => budget * 90 / 100,
            _ => budget,
        })
        .collect();
    let escape: Vec<f64> = (0..n).map(|f| (f % 10) as f64 / 10.0).collect();
    // Error follows the escape fraction one frame later.
    let err: Vec<f64> = (0..n).map(|f| ((f + 1) % 10) as f64 / 50.0).collect();
    let target = (budget - blas_bytes(12)) as f64;
    let r = report(vec![
        run_of("lipac-budget", &bytes, Some(target), &escape, &err),
        run_of("lipac", &bytes, None, &escape, &err),
    ]);
    let b = budget_figures(&r, &r.camera_cuts);
    assert_eq!(b.len(), 1, "only the run with a budget");
    let b = &b[0];
    assert_eq!(b.budget_bytes, budget);
    assert_eq!(b.frames, n - SETTLE_FRAMES as usize);
    assert!((b.max_deviation.unwrap() - 0.10).abs() < 1e-9, "{b:?}");
    assert!((b.max_overrun.unwrap() - 0.02).abs() < 1e-9, "{b:?}");
    assert_eq!(b.frames_outside, 20);
    // 2 % over is held; 10 % under at a scale above 1 is spare budget.
    assert_eq!((b.frames_over, b.frames_spare), (0, 20));
    assert!((b.jump_max_deviation.unwrap() - 0.10).abs() < 1e-9);
    // Escape of frame f + 1 pairs with the error of frame f: perfectly
    // correlated here.
    let c = escape_error_correlation(&r).unwrap();
    assert_eq!(c.points, 2 * (n - SETTLE_FRAMES as usize - 1));
    assert!(c.pearson > 0.999 && c.spearman > 0.999, "{c:?}");
    let md = markdown(&r, &r.camera_cuts).unwrap();
    assert!(md.contains("## Closed-loop thresholds"));
    assert!(md.contains("| lipac-budget |"));
    assert!(md.contains("20 of 140"));
    let svgs = plots(&r).unwrap();
    assert_eq!(svgs.len(), 3);
    assert!(svgs[0].1.contains("budget of lipac-budget"));
}

/// LiPaC alone on `frames` frames at 32 x 18, LiPaC's settings the
/// comparison's defaults.
fn small_lipac(frames: u32) -> CompareConfig {
    CompareConfig {
        frames: Some(frames),
        width: 32,
        height: 18,
        strategies: vec![StrategyKind::Lipac],
        share_ground_truth: true,
        threads: 2,
        ..CompareConfig::default()
    }
}

#[test]
fn a_budget_run_on_the_small_scene_reports_the_controller() {
    let config = small_lipac(12);
    let opts = ClosedLoopOptions {
        memory_budget_mib: Some(0.5),
        escape_target: Some(0.05),
        camera: ClosedLoopPath::Jump,
    };
    let (r, _) = run(
        SceneChoice::Small,
        None,
        &config,
        &opts,
        &[],
        &mut |_, _| {},
    )
    .unwrap();
    let names: Vec<_> = r.strategies.iter().map(|s| s.name.as_str()).collect();
    assert_eq!(names, ["lipac", "lipac-budget", "lipac-escape"]);
    let budget = &r.strategies[1];
    let t = budget.frames[0].control_target.unwrap();
    assert_eq!(t as u64 + blas_bytes(12), (0.5 * MIB) as u64);
    assert!(budget.frames.iter().all(|m| m.threshold_scale.is_some()));
    assert!(r.strategies[0]
        .frames
        .iter()
        .all(|m| m.control_target.is_none()));
    assert_eq!(r.strategies[2].frames[0].control_target, Some(0.05));
    // A bad escape target is the Manager's configuration error.
    let bad = ClosedLoopOptions {
        escape_target: Some(1.5),
        ..opts
    };
    let e = run(SceneChoice::Small, None, &config, &bad, &[], &mut |_, _| {}).unwrap_err();
    assert!(e.to_string().contains("(0, 1)"), "{e}");
}

#[test]
fn closed_loop_runs_take_the_comparisons_lipac_settings() {
    // `lipac compare --camera jump --cell-size 64 --warm-start off`: LiPaC
    // and the controlled runs with 64 m cells (fewer hitboxes, less
    // overhead) and a cold start (frame 0 traces only the pinned terrain).
    let config = small_lipac(3);
    let opts = ClosedLoopOptions {
        memory_budget_mib: Some(8.0),
        escape_target: Some(0.05),
        camera: ClosedLoopPath::Jump,
    };
    let go = |c: &CompareConfig| {
        run(SceneChoice::Small, None, c, &opts, &[], &mut |_, _| {})
            .unwrap()
            .0
    };
    let default = go(&config);
    let set = go(&CompareConfig {
        lipac_cell_size: Some(64.0),
        lipac_start: crate::compare::LipacStart::Cold,
        ..config.clone()
    });
    for name in ["lipac", "lipac-budget", "lipac-escape"] {
        let (a, b) = (
            &default.strategy(name).unwrap().frames[0],
            &set.strategy(name).unwrap().frames[0],
        );
        assert!(b.overhead_bytes < a.overhead_bytes, "{name}: cells");
        assert!(b.tlas_instances < a.tlas_instances, "{name}: start");
    }
}

#[test]
fn a_budget_on_the_small_scene_holds_through_a_camera_jump() {
    // LiPaC and LiPaC with a budget 8 % below what LiPaC takes in the near
    // view (measured: 5.25 MiB at 32 x 18), in one comparison along a jump
    // at frame 50 of 100.
    let (at, frames) = (50usize, 100u32);
    let budget_mib = 4.83;
    let config = small_lipac(frames);
    let mut scene = Scene::generate(&SceneChoice::Small.config(None)).unwrap();
    let j = CameraPath::city_jump(&scene, 32.0 / 18.0);
    let path = CameraPath::jump(
        j.camera_at(0),
        j.camera_at(j.frames() - 1),
        at as u32,
        frames,
    );
    let opts = ClosedLoopOptions {
        memory_budget_mib: Some(budget_mib),
        ..ClosedLoopOptions::default()
    };
    let contenders = contenders(&scene, &config, &opts).unwrap();
    let (r, _) = crate::compare::run_path(
        "small",
        &mut scene,
        &path,
        &config,
        contenders,
        &[],
        &mut |_, _| {},
    )
    .unwrap();
    let over = |name: &str| -> Vec<f64> {
        r.strategy(name)
            .unwrap()
            .frames
            .iter()
            .map(|m| m.total_bytes() as f64 / (budget_mib * MIB) - 1.0)
            .collect()
    };
    let (free, held) = (over("lipac"), over("lipac-budget"));
    let max = |v: &[f64]| v.iter().copied().fold(f64::NEG_INFINITY, f64::max);
    // Uncontrolled, the near view is over the budget, and both views are
    // resident for a while after the jump.
    assert!(max(&free[30..at]) > 0.05, "{:.3}", max(&free[30..at]));
    assert!(
        max(&free[at + 5..at + 20]) > 0.10,
        "{:.3}",
        max(&free[at + 5..])
    );
    // Held: near or over the budget never above what LiPaC alone takes
    // after warm-up (well under it, the cache's retention may free a BLAS
    // a frame apart), but in the first frame after the jump, whose builds
    // bring the coarser BLASes of the old view's instances before the finer
    // ones go (measured +12.5 % against LiPaC alone's +9.1 %; with the
    // symmetric 150/30 rule of before +12.2 % against +11.8 %); then the
    // jump's transient cut (the old view's coarser LODs taken at once, its
    // BLASes evicted once over budget), and within 5 % over from the
    // second frame after the jump. In the near view the default rule,
    // which activates on a single hit, leaves the scale nothing to cut
    // before it passes ~18 (32 x 18 rays): memory there is LiPaC's own.
    for f in 30..frames as usize {
        let slack = if f == at + 1 { 0.05 } else { 0.005 };
        assert!(
            held[f] < -0.05 || held[f] <= free[f] + slack,
            "frame {f}: {:.3} vs {:.3}",
            held[f],
            free[f]
        );
    }
    assert!(
        max(&held[at + 5..]) < max(&free[at + 5..]) - 0.04,
        "{:.3} vs {:.3}",
        max(&held[at + 5..]),
        max(&free[at + 5..])
    );
    assert!(max(&held[at + 2..]) <= 0.05, "{:.3}", max(&held[at + 2..]));
    // The scale rose over the budget and came back to 1 once the far view
    // needed less than the budget (a ceiling).
    let scales: Vec<f64> = r
        .strategy("lipac-budget")
        .unwrap()
        .frames
        .iter()
        .map(|m| m.threshold_scale.unwrap())
        .collect();
    assert!(max(&scales[30..at + 10]) > 2.0, "{scales:?}");
    assert_eq!(scales[frames as usize - 1], 1.0);
}

/// With fewer frames than [`SETTLE_FRAMES`], the budget's figures say there
/// is nothing to measure: no `-inf` (the maximum of nothing) or `NaN` in
/// the line or the report.
#[test]
fn a_run_shorter_than_the_settling_prints_no_inf_or_nan() {
    let budget = 1_000_000u64;
    let bytes = vec![budget; 10];
    let target = (budget - blas_bytes(12)) as f64;
    let r = report(vec![run_of(
        "lipac-budget",
        &bytes,
        Some(target),
        &[0.1; 10],
        &[0.01; 10],
    )]);
    let b = budget_figures(&r, &r.camera_cuts);
    assert_eq!(b.len(), 1);
    assert_eq!(b[0].frames, 0);
    assert_eq!((b[0].mean_bytes, b[0].max_overrun), (None, None));
    let line = b[0].summary_line();
    assert!(line.contains("no frames to measure"), "{line}");
    let md = markdown(&r, &r.camera_cuts).unwrap_or_default();
    for text in [&line, &md] {
        let lower = text.to_lowercase();
        assert!(!lower.contains("inf") && !lower.contains("nan"), "{text}");
    }
}
