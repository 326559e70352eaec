//! `lipac sweep` end to end: well-formed outputs on a tiny configuration,
//! and shared ground truth giving exactly the errors of `lipac compare`.

use lipac_core::latency::ActivationHeuristic;
use lipac_sim::compare::{run_choice, CompareConfig, LipacStart, SceneChoice};
use lipac_sim::strategy::StrategyKind;
use lipac_sim::sweep::{self, SweepConfig, SweepReport, SWEEP_CSV_HEADER, SWEEP_FILES};

fn tiny(scenes: Vec<SceneChoice>, frames: u32) -> SweepConfig {
    SweepConfig {
        scenes,
        seed: None,
        frames: Some(frames),
        width: 64,
        height: 36,
        baselines: vec![StrategyKind::Full, StrategyKind::Oracle],
        hindsight: Vec::new(),
        // 2304 rays: ×1 gives θa = 2, ×16 gives θa = 18; the default
        // decayed rule's activation rate, 0.11 hits per frame here, at ×16
        // asks for more than one hit.
        factors: vec![1.0, 16.0],
        latency: vec![ActivationHeuristic::default()],
        cell_sizes: vec![],
        streaks: vec![],
        decayed: vec![],
        threads: 2,
        trace: None,
        trace_options: Default::default(),
        warm_start_at_cuts: false,
        warm_start_hold: None,
        lipac_start: LipacStart::Default,
        device: Default::default(),
    }
}

/// [`tiny`] on the trace `file` instead of scenes (no frame count).
fn on_trace(file: &std::path::Path) -> SweepConfig {
    SweepConfig {
        frames: None,
        trace: Some(file.to_path_buf()),
        ..tiny(Vec::new(), 1)
    }
}

#[test]
fn tiny_sweep_writes_well_formed_outputs() {
    let config = tiny(vec![SceneChoice::Small, SceneChoice::City], 3);
    let mut calls = 0;
    let r = sweep::run(&config, &mut |_, _, _, _| calls += 1).unwrap();
    assert_eq!(calls, 2 * 3);
    let configs = 2 + 2 + 1;
    assert!(r.skipped.is_empty(), "{:?}", r.skipped);
    assert_eq!(r.points.len(), configs * 2);
    for scene in ["small", "city"] {
        let pts: Vec<_> = r.points.iter().filter(|p| p.scene == scene).collect();
        let full = pts.iter().find(|p| p.name == "full").unwrap();
        assert_eq!(full.summary.mean_error, 0.0);
        // The oracle is exact (up to ties) and holds less than the full scene.
        let oracle = pts.iter().find(|p| p.name == "oracle").unwrap();
        assert!(oracle.summary.mean_error <= 1e-3);
        assert!(oracle.summary.mean_mib < full.summary.mean_mib);
        // The oracle is a reference, never on a front.
        assert_eq!(oracle.fronts(), [false; 4]);
        let pts: Vec<_> = pts.into_iter().filter(|p| p.name != "oracle").collect();
        // On every front: the cheapest point, and the most accurate one of
        // least cost among the most accurate.
        for (plot, (_, _, _, cost)) in sweep::COSTS.iter().enumerate() {
            let on = |p: &sweep::SweepPoint| p.on_front(plot);
            let key = |p: &&&sweep::SweepPoint| (cost(p), p.summary.mean_error);
            let cheapest = pts
                .iter()
                .min_by(|a, b| key(a).partial_cmp(&key(b)).unwrap())
                .unwrap();
            assert!(on(cheapest), "{scene} {plot} {}", cheapest.name);
            let best = pts
                .iter()
                .min_by(|a, b| {
                    (a.summary.mean_error, cost(a))
                        .partial_cmp(&(b.summary.mean_error, cost(b)))
                        .unwrap()
                })
                .unwrap();
            assert!(on(best), "{scene} {plot} {}", best.name);
            // And nothing on the front is dominated by another point.
            for p in pts.iter().filter(|p| on(p)) {
                assert!(!pts.iter().any(|q| cost(q) <= cost(p)
                    && q.summary.mean_error <= p.summary.mean_error
                    && (cost(q) < cost(p) || q.summary.mean_error < p.summary.mean_error)));
            }
        }
    }

    let dir = std::env::temp_dir().join(format!("lipac-sweep-test-{}", std::process::id()));
    let written = sweep::write_sweep(&r, &dir).unwrap();
    assert_eq!(written.len(), SWEEP_FILES.len());

    let json = std::fs::read_to_string(dir.join("sweep.json")).unwrap();
    let back: SweepReport = serde_json::from_str(&json).unwrap();
    assert_eq!(back.points.len(), r.points.len());
    assert_eq!(back.scenes.len(), 2);
    for (a, b) in back.points.iter().zip(&r.points) {
        assert_eq!((&a.scene, &a.name), (&b.scene, &b.name));
        assert_eq!(a.summary.builds, b.summary.builds);
        assert_eq!(a.frame_errors.len(), 3);
        assert_eq!(a.front_memory, b.front_memory);
    }

    let csv = std::fs::read_to_string(dir.join("sweep.csv")).unwrap();
    let mut lines = csv.lines();
    assert_eq!(lines.next(), Some(SWEEP_CSV_HEADER));
    let rows: Vec<&str> = lines.collect();
    assert_eq!(rows.len(), configs * 2);
    let columns = SWEEP_CSV_HEADER.split(',').count();
    assert!(rows.iter().all(|l| l.split(',').count() == columns));
    let lipac16 = rows
        .iter()
        .find(|l| l.starts_with("city,lipac ×16,thresholds,lipac,16,32,18,2,18,2,4,15,"))
        .copied();
    assert!(lipac16.is_some(), "{csv}");

    for (plot, file) in [
        "sweep_time.svg",
        "sweep_gpu_time.svg",
        "sweep_memory.svg",
        "sweep_builds.svg",
    ]
    .iter()
    .enumerate()
    {
        let svg = std::fs::read_to_string(dir.join(file)).unwrap();
        assert!(svg.starts_with("<svg") && svg.trim_end().ends_with("</svg>"));
        let on_front: Vec<_> = r.points.iter().filter(|p| p.on_front(plot)).collect();
        // One circle per point (the oracle's hollow), one ring per front
        // point, and the legend's markers (two scenes, their references,
        // the ring).
        assert_eq!(
            svg.matches("<circle").count(),
            configs * 2 + on_front.len() + 5,
            "{file}"
        );
        let texts: Vec<String> = svg
            .split("<text")
            .skip(1)
            .filter_map(|t| t.split_once('>'))
            .filter_map(|(_, rest)| rest.split_once("</text>"))
            .map(|(s, _)| s.trim().to_string())
            .collect();
        // Legend: each scene, its references, its front and the ring,
        // once each.
        for entry in [
            "small",
            "city",
            "small references",
            "city references",
            "small Pareto front",
            "city Pareto front",
            "on a front",
        ] {
            assert_eq!(
                texts.iter().filter(|t| *t == entry).count(),
                1,
                "{file}: {entry} in {texts:?}"
            );
        }
        // The front points carry their configuration's name, and so does
        // the oracle, once per scene; the oracle is never on a front.
        for p in &on_front {
            assert!(texts.contains(&p.name), "{file}: {}", p.name);
        }
        assert!(on_front.iter().all(|p| p.name != "oracle"), "{file}");
        assert_eq!(texts.iter().filter(|t| *t == "oracle").count(), 2, "{file}");
    }
    let md = std::fs::read_to_string(dir.join("sweep.md")).unwrap();
    for file in &SWEEP_FILES[2..] {
        assert!(md.contains(&format!("]({file})")), "{file}");
    }
    assert!(md.contains("| lipac ×16 | 18 2 18 2 4 15 | 32 |"));
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn shared_ground_truth_gives_the_errors_of_compare() {
    let frames = 8;
    let r = sweep::run(
        &tiny(vec![SceneChoice::Small], frames),
        &mut |_, _, _, _| {},
    )
    .unwrap();
    let compare = CompareConfig {
        frames: Some(frames),
        width: 64,
        height: 36,
        strategies: vec![StrategyKind::Lipac, StrategyKind::LipacLatency],
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
    let c = run_choice(SceneChoice::Small, None, &compare, &mut |_, _| {}).unwrap();
    for (swept, compared) in [("lipac ×1", "lipac"), ("lipac-latency", "lipac-latency")] {
        let s = r.point("small", swept).unwrap();
        let run = c.strategy(compared).unwrap();
        let errors: Vec<u64> = run.frames.iter().map(|m| m.error.to_bits()).collect();
        let swept_errors: Vec<u64> = s.frame_errors.iter().map(|e| e.to_bits()).collect();
        assert_eq!(swept_errors, errors, "{swept}");
        assert_eq!(s.summary.builds, run.summary.builds);
        assert_eq!(s.summary.mean_mib, run.summary.mean_mib);
    }
    // The check can fail: other thresholds give other errors.
    let x16 = r.point("small", "lipac ×16").unwrap();
    assert_ne!(
        x16.frame_errors,
        r.point("small", "lipac ×1").unwrap().frame_errors
    );
}

/// `lipac sweep --warm-start` (`SweepConfig::lipac_start`) starts every
/// LiPaC configuration as `lipac compare --warm-start` does, and says so
/// in its name: a cold sweep gives the cold comparison's errors bit for
/// bit, and they differ from the warm default's.
#[test]
fn a_sweep_starts_lipac_as_asked() {
    let frames = 6;
    let cold = SweepConfig {
        lipac_start: LipacStart::Cold,
        factors: vec![1.0],
        latency: Vec::new(),
        ..tiny(vec![SceneChoice::Small], frames)
    };
    let (variants, _) = cold.variants().unwrap();
    let lipac: Vec<&str> = variants
        .iter()
        .filter(|v| v.lipac.is_some())
        .map(|v| v.name.as_str())
        .collect();
    assert_eq!(lipac, ["lipac ×1 + cold start"]);
    assert!(variants
        .iter()
        .filter_map(|v| v.lipac.as_ref())
        .all(|c| c.warm_start.is_none()));
    let r = sweep::run(&cold, &mut |_, _, _, _| {}).unwrap();
    let compare = |start| CompareConfig {
        frames: Some(frames),
        width: 64,
        height: 36,
        strategies: vec![StrategyKind::Lipac],
        threads: 2,
        lipac_start: start,
        ..CompareConfig::default()
    };
    let errors = |c: &lipac_sim::compare::CompareReport| -> Vec<u64> {
        c.strategy("lipac")
            .unwrap()
            .frames
            .iter()
            .map(|m| m.error.to_bits())
            .collect()
    };
    let swept: Vec<u64> = r
        .point("small", "lipac ×1 + cold start")
        .unwrap()
        .frame_errors
        .iter()
        .map(|e| e.to_bits())
        .collect();
    let c = run_choice(
        SceneChoice::Small,
        None,
        &compare(LipacStart::Cold),
        &mut |_, _| {},
    )
    .unwrap();
    assert_eq!(swept, errors(&c));
    let w = run_choice(
        SceneChoice::Small,
        None,
        &compare(LipacStart::Default),
        &mut |_, _| {},
    )
    .unwrap();
    assert_ne!(swept, errors(&w), "the cold start changes the run");
}

#[test]
fn duplicate_scenes_are_rejected() {
    let c = tiny(vec![SceneChoice::Small, SceneChoice::Small], 1);
    assert!(sweep::run(&c, &mut |_, _, _, _| {}).is_err());
}

#[test]
fn a_sweep_of_a_recorded_trace_gives_the_errors_of_its_replay() {
    use lipac_core::trace::TraceFormat;
    use lipac_sim::record::{record, CameraChoice, RecordConfig};
    use lipac_sim::replay::{replay, ReplayConfig, TraceInput};
    let (w, h) = (64u32, 36u32);
    let rc = RecordConfig {
        scene: SceneChoice::Small,
        seed: None,
        camera: CameraChoice::Jump,
        frames: Some(6),
        aspect: w as f32 / h as f32,
        geometry: false,
    };
    let bytes = record(&rc, TraceFormat::Binary, Vec::new()).unwrap().0;
    let dir = std::env::temp_dir().join(format!("lipac-sweep-trace-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let file = dir.join("small-jump.bin");
    std::fs::write(&file, &bytes).unwrap();
    let config = SweepConfig {
        baselines: vec![StrategyKind::Frustum],
        ..on_trace(&file)
    };
    let r = sweep::run(&config, &mut |_, _, _, _| {}).unwrap();
    let replayed = replay(
        TraceInput::open(&file).unwrap(),
        &ReplayConfig {
            strategies: vec![
                StrategyKind::Frustum,
                StrategyKind::Lipac,
                StrategyKind::LipacLatency,
            ],
            width: w,
            height: h,
            threads: 2,
            ..ReplayConfig::default()
        },
        &mut |_| {},
    )
    .unwrap();
    assert_eq!(r.points.len(), 4);
    assert!(r.points.iter().all(|p| p.scene == "trace small-jump.bin"));
    let point = |name: &str| r.points.iter().find(|p| p.name == name).unwrap();
    for (swept, run) in [
        ("frustum", "frustum"),
        ("lipac ×1", "lipac"),
        ("lipac-latency", "lipac-latency"),
    ] {
        let want: Vec<u64> = replayed
            .strategy(run)
            .unwrap()
            .frames
            .iter()
            .map(|m| m.error.to_bits())
            .collect();
        let got: Vec<u64> = point(swept)
            .frame_errors
            .iter()
            .map(|e| e.to_bits())
            .collect();
        assert_eq!(got.len(), 6);
        assert_eq!(got, want, "{swept}");
        assert_eq!(
            point(swept).summary.mean_mib.to_bits(),
            replayed.strategy(run).unwrap().summary.mean_mib.to_bits(),
            "{swept}"
        );
    }
    // Higher thresholds are another configuration on the same frames.
    assert_ne!(
        point("lipac ×16").summary.mean_mib,
        point("lipac ×1").summary.mean_mib
    );
    // A trace is swept alone: not with scenes, a seed or a frame count.
    for bad in [
        SweepConfig {
            scenes: vec![SceneChoice::Small],
            ..config.clone()
        },
        SweepConfig {
            frames: Some(3),
            ..config.clone()
        },
    ] {
        assert!(sweep::run(&bad, &mut |_, _, _, _| {}).is_err());
    }
    let missing = SweepConfig {
        trace: Some(dir.join("missing.bin")),
        ..config.clone()
    };
    let e = sweep::run(&missing, &mut |_, _, _, _| {}).unwrap_err();
    assert!(e.to_string().contains("missing.bin"), "{e}");

    // Hindsight references on the trace: each window under its own name,
    // with the errors of a replay that runs the same window.
    let references = SweepConfig {
        baselines: vec![StrategyKind::Hindsight],
        hindsight: vec![2],
        factors: vec![],
        latency: vec![],
        ..config.clone()
    };
    let r = sweep::run(&references, &mut |_, _, _, _| {}).unwrap();
    let names: Vec<&str> = r.points.iter().map(|p| p.name.as_str()).collect();
    assert_eq!(names, ["hindsight", "hindsight 2"]);
    let with_window = |mode| ReplayConfig {
        strategies: vec![],
        hindsight_variants: vec![("window 2".into(), 2)],
        width: w,
        height: h,
        threads: 2,
        mode,
        ..ReplayConfig::default()
    };
    let replayed = replay(
        TraceInput::open(&file).unwrap(),
        &with_window(None),
        &mut |_| {},
    )
    .unwrap();
    let want: Vec<u64> = replayed
        .strategy("window 2")
        .unwrap()
        .frames
        .iter()
        .map(|m| m.error.to_bits())
        .collect();
    let got: Vec<u64> = point_of(&r, "hindsight 2")
        .frame_errors
        .iter()
        .map(|e| e.to_bits())
        .collect();
    assert_eq!(got, want);
    // The two windows differ on this trace, so the names are not mixed up.
    assert_ne!(
        point_of(&r, "hindsight").frame_errors,
        point_of(&r, "hindsight 2").frame_errors
    );
    // A hits-only replay renders no ground truth: refused.
    let e = replay(
        TraceInput::open(&file).unwrap(),
        &with_window(Some(lipac_sim::replay::ReplayMode::HitsOnly)),
        &mut |_| {},
    )
    .unwrap_err();
    assert!(e.to_string().contains("hindsight"), "{e}");
    std::fs::remove_dir_all(&dir).unwrap();
}

fn point_of<'a>(r: &'a SweepReport, name: &str) -> &'a lipac_sim::sweep::SweepPoint {
    r.points.iter().find(|p| p.name == name).unwrap()
}

/// A trace of another scene (the small scene recorded with geometry,
/// renamed) sweeps through the trace's own scene, with `lipac replay`'s
/// options: without box proxies its terrain (no geometry in the header)
/// is an error that says so; with them the LiPaC point equals the replay.
#[test]
fn a_trace_of_another_scene_sweeps_with_the_replays_options() {
    use lipac_core::trace::TraceFormat;
    use lipac_sim::record::{record, CameraChoice, RecordConfig};
    use lipac_sim::replay::ReplayConfig;
    use lipac_sim::trace_scene::{replay_path, TraceSceneOptions};
    let (w, h) = (32u32, 18u32);
    let rc = RecordConfig {
        scene: SceneChoice::Small,
        seed: None,
        camera: CameraChoice::Flythrough,
        frames: Some(3),
        aspect: w as f32 / h as f32,
        geometry: true,
    };
    let bytes = record(&rc, TraceFormat::Jsonl, Vec::new()).unwrap().0;
    let text = String::from_utf8(bytes).unwrap();
    let (first, rest) = text.split_once('\n').unwrap();
    let start = first.find("lipac-sim:small").unwrap();
    let end = start + first[start..].find('"').unwrap();
    let renamed = format!("{}my-game{}\n{rest}", &first[..start], &first[end..]);
    let dir = std::env::temp_dir().join(format!("lipac-sweep-other-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let file = dir.join("my-game.jsonl");
    std::fs::write(&file, renamed).unwrap();
    let config = SweepConfig {
        width: w,
        height: h,
        baselines: vec![StrategyKind::Frustum],
        factors: vec![1.0],
        latency: Vec::new(),
        ..on_trace(&file)
    };
    let e = sweep::run(&config, &mut |_, _, _, _| {}).unwrap_err();
    assert!(e.to_string().contains("box-proxy"), "{e}");
    let proxies = TraceSceneOptions {
        box_proxy: true,
        ..TraceSceneOptions::default()
    };
    let r = sweep::run(
        &SweepConfig {
            trace_options: proxies,
            ..config
        },
        &mut |_, _, _, _| {},
    )
    .unwrap();
    let (replayed, _) = replay_path(
        &file,
        &ReplayConfig {
            strategies: vec![StrategyKind::Lipac],
            width: w,
            height: h,
            threads: 2,
            ..ReplayConfig::default()
        },
        &proxies,
        &mut |_| {},
    )
    .unwrap();
    let point = r.points.iter().find(|p| p.name == "lipac ×1").unwrap();
    assert_eq!(point.scene, "trace my-game.jsonl");
    let want: Vec<u64> = replayed.strategies[0]
        .frames
        .iter()
        .map(|m| m.error.to_bits())
        .collect();
    let got: Vec<u64> = point.frame_errors.iter().map(|e| e.to_bits()).collect();
    assert_eq!((got.len(), &got), (3, &want));
    std::fs::remove_dir_all(&dir).unwrap();
}

/// `--warm-start-at-cuts` on a trace: every LiPaC configuration
/// warm-starts at the cut the replay finds, as `lipac replay
/// --warm-start-at-cuts` does.
#[test]
fn a_trace_sweep_warm_starts_at_the_cut_as_the_replay_does() {
    use lipac_core::trace::TraceFormat;
    use lipac_sim::record::{record, CameraChoice, RecordConfig};
    use lipac_sim::replay::{replay, ReplayConfig, TraceInput};
    use lipac_sim::scene::Scene;
    let (w, h) = (64u32, 36u32);
    let aspect = w as f32 / h as f32;
    let scene = Scene::generate(&SceneChoice::Small.config(None)).unwrap();
    let cut = CameraChoice::Jump.path(&scene, aspect).cuts()[0];
    let rc = RecordConfig {
        scene: SceneChoice::Small,
        seed: None,
        camera: CameraChoice::Jump,
        frames: Some(cut + 3),
        aspect,
        geometry: false,
    };
    let bytes = record(&rc, TraceFormat::Binary, Vec::new()).unwrap().0;
    let dir = std::env::temp_dir().join(format!("lipac-sweep-cut-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let file = dir.join("jump.bin");
    std::fs::write(&file, &bytes).unwrap();
    let sweep_with = |at_cuts: bool| {
        let config = SweepConfig {
            baselines: Vec::new(),
            factors: vec![1.0],
            latency: Vec::new(),
            warm_start_at_cuts: at_cuts,
            warm_start_hold: None,
            ..on_trace(&file)
        };
        let r = sweep::run(&config, &mut |_, _, _, _| {}).unwrap();
        assert_eq!(r.points.len(), 1);
        let named = r.points[0].name.ends_with(" + warm start at cuts");
        assert_eq!(named, at_cuts, "{}", r.points[0].name);
        r.points[0].clone()
    };
    let (plain, warm) = (sweep_with(false), sweep_with(true));
    let replayed = replay(
        TraceInput::open(&file).unwrap(),
        &ReplayConfig {
            strategies: vec![StrategyKind::Lipac],
            width: w,
            height: h,
            threads: 2,
            warm_start_at_cuts: true,
            warm_start_hold: None,
            ..ReplayConfig::default()
        },
        &mut |_| {},
    )
    .unwrap();
    let bits = |v: &[f64]| v.iter().map(|e| e.to_bits()).collect::<Vec<_>>();
    let want: Vec<f64> = replayed.strategies[0]
        .frames
        .iter()
        .map(|m| m.error)
        .collect();
    assert_eq!(bits(&warm.frame_errors), bits(&want));
    let c = cut as usize;
    assert_eq!(
        bits(&plain.frame_errors[..c]),
        bits(&warm.frame_errors[..c])
    );
    // From the cut on, more of the new view is built at once.
    assert!(
        warm.summary.builds > plain.summary.builds,
        "{} vs {}",
        warm.summary.builds,
        plain.summary.builds
    );
    std::fs::remove_dir_all(&dir).unwrap();
}
