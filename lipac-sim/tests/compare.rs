//! The comparison end to end: determinism, exactness of the full-scene and
//! oracle strategies, LiPaC on hand-made scenes (occlusion, mirror), and the
//! report files.

use glam::{Affine3A, Vec3};
use lipac_sim::camera::{CameraPath, FlyCamera};
use lipac_sim::compare::{
    run, run_choice, run_contenders, CompareConfig, CompareReport, Contender, SceneChoice,
};
use lipac_sim::mesh::{cuboid, material, mirror_block, MeshLibrary};
use lipac_sim::report::{write_report, CSV_HEADER, PLOTS};
use lipac_sim::scene::{flags, Scene, SceneConfig};
use lipac_sim::strategy::hindsight::Hindsight;
use lipac_sim::strategy::lipac::{Lipac, LipacConfig};
use lipac_sim::strategy::{Oracle, StrategyKind};

fn small(frames: u32, w: u32, h: u32, strategies: &[StrategyKind], share: bool) -> CompareReport {
    let config = CompareConfig {
        frames: Some(frames),
        width: w,
        height: h,
        strategies: strategies.to_vec(),
        share_ground_truth: share,
        threads: 2,
        adaptive_levels: None,
        lipac_cell_size: None,
        lipac_rise_shift: None,
        lipac_start: lipac_sim::compare::LipacStart::Default,
        lipac_warm_start_at_cuts: false,
        lipac_warm_start_hold: None,
        device: Default::default(),
    };
    run_choice(SceneChoice::Small, None, &config, &mut |_, _| {}).expect("comparison")
}

#[test]
fn same_seed_gives_identical_metrics() {
    let a = small(5, 32, 18, &StrategyKind::ALL, true);
    let b = small(5, 32, 18, &StrategyKind::ALL, true);
    assert_eq!(a.strategies.len(), StrategyKind::ALL.len());
    for (x, y) in a.strategies.iter().zip(&b.strategies) {
        assert_eq!(x.name, y.name);
        assert_eq!(x.last_geometry, y.last_geometry);
        for (m, n) in x.frames.iter().zip(&y.frames) {
            assert_eq!(
                m.error.to_bits(),
                n.error.to_bits(),
                "{} frame {}",
                x.name,
                m.frame
            );
            assert_eq!(m.without_timings(), n.without_timings());
        }
    }
    // The check can fail: LiPaC differs from the full scene.
    let (full, lipac) = (a.strategy("full").unwrap(), a.strategy("lipac").unwrap());
    assert_ne!(full.last_geometry, lipac.last_geometry);
}

#[test]
fn figures_do_not_depend_on_threads_and_twins_share_one_render() {
    let run_with = |threads: usize| {
        let mut scene = Scene::generate(&SceneChoice::Small.config(None)).unwrap();
        let path = CameraPath::flythrough(&scene, 32.0 / 18.0);
        let config = CompareConfig {
            frames: Some(6),
            width: 32,
            height: 18,
            threads,
            ..CompareConfig::default()
        };
        let lipac = LipacConfig::for_rays_per_frame(32 * 18).unwrap();
        let contenders = ["lipac", "twin"]
            .into_iter()
            .map(|name| Contender {
                name: name.into(),
                strategy: Box::new(Lipac::new(&scene, lipac.clone()).unwrap()),
            })
            .chain([Contender {
                name: "oracle".into(),
                strategy: Box::new(Oracle::new(&scene).unwrap()),
            }])
            .collect();
        run_contenders(
            "small",
            &mut scene,
            &path,
            &config,
            contenders,
            &mut |_, _| {},
        )
        .unwrap()
    };
    let (one, three) = (run_with(1), run_with(3));
    for (x, y) in one.strategies.iter().zip(&three.strategies) {
        assert_eq!(x.last_geometry, y.last_geometry);
        for (m, n) in x.frames.iter().zip(&y.frames) {
            assert_eq!(m.without_timings(), n.without_timings(), "{}", x.name);
        }
    }
    // The twin traces LiPaC's TLAS: its figures are LiPaC's, and its render
    // is LiPaC's own (the same measured times, which two renders would not
    // give to the nanosecond).
    let (lipac, twin) = (
        one.strategy("lipac").unwrap(),
        one.strategy("twin").unwrap(),
    );
    for (m, n) in lipac.frames.iter().zip(&twin.frames) {
        assert_eq!(m.without_timings(), n.without_timings());
        assert_eq!(m.trace_ms.to_bits(), n.trace_ms.to_bits());
        assert_eq!(m.tlas_build_ms.to_bits(), n.tlas_build_ms.to_bits());
    }
    // The oracle traces another TLAS: its own render.
    let oracle = one.strategy("oracle").unwrap();
    assert!(lipac
        .frames
        .iter()
        .zip(&oracle.frames)
        .any(|(m, n)| m.trace_ms != n.trace_ms));
}

#[test]
fn full_scene_is_exact_and_the_oracle_nearly() {
    // The full strategy is rendered on its own here (no reuse of the ground
    // truth's image), so its zero error is a property of the renderer.
    let r = small(
        6,
        48,
        27,
        &[
            StrategyKind::Full,
            StrategyKind::Oracle,
            StrategyKind::Lipac,
        ],
        false,
    );
    let full = r.strategy("full").unwrap();
    assert!(full.frames.iter().all(|m| m.error == 0.0));
    // The oracle traces exactly the instances the ground truth's bounce rays
    // hit, so every bounce finds the same closest hit; only exact ties
    // between coplanar instances in a differently built TLAS could differ.
    let oracle = r.strategy("oracle").unwrap();
    assert!(
        oracle.summary.max_error <= 1e-3,
        "{}",
        oracle.summary.max_error
    );
    assert!(oracle.summary.mean_instances < full.summary.mean_instances);
    // LiPaC starts cold (everything culled), so its error is not zero.
    assert!(r.strategy("lipac").unwrap().summary.max_error > 1e-3);
}

#[test]
fn hindsight_traces_what_the_ground_truth_hit_in_its_window() {
    // Each run of f + 1 frames gives frame f's sets: the oracle's (this
    // frame's hits and the pinned terrain) and hindsight's over 2 frames.
    const FRAMES: u32 = 7;
    let (mut oracle, mut hindsight) = (Vec::new(), Vec::new());
    let mut pinned = Vec::new();
    for frames in 1..=FRAMES {
        let mut scene = Scene::generate(&SceneChoice::Small.config(None)).unwrap();
        pinned = (0u32..)
            .zip(scene.instances())
            .filter(|(_, i)| i.is_pinned())
            .map(|(s, _)| s)
            .collect();
        let path = CameraPath::flythrough(&scene, 48.0 / 27.0);
        let contenders = vec![
            Contender {
                name: "oracle".into(),
                strategy: Box::new(Oracle::new(&scene).unwrap()),
            },
            Contender {
                name: "hindsight 2".into(),
                strategy: Box::new(Hindsight::new(&scene, 2).unwrap()),
            },
        ];
        let config = CompareConfig {
            frames: Some(frames),
            width: 48,
            height: 27,
            ..CompareConfig::default()
        };
        let r = run_contenders(
            "small",
            &mut scene,
            &path,
            &config,
            contenders,
            &mut |_, _| {},
        )
        .unwrap();
        oracle.push(r.strategy("oracle").unwrap().last_geometry.clone());
        hindsight.push(r.strategy("hindsight 2").unwrap().last_geometry.clone());
    }
    let union = |sets: &[Vec<u32>]| {
        let mut u: Vec<u32> = pinned
            .iter()
            .chain(sets.iter().flatten())
            .copied()
            .collect();
        u.sort_unstable();
        u.dedup();
        u
    };
    for f in 0..FRAMES as usize {
        let window = &oracle[f.saturating_sub(2)..f];
        assert_eq!(hindsight[f], union(window), "frame {f}");
    }
    // The window matters: the last frame's set is not all the past hits.
    let last = FRAMES as usize - 1;
    assert_ne!(union(&oracle[..last]), union(&oracle[last - 2..last]));
    assert!(Hindsight::new(
        &Scene::generate(&SceneChoice::Small.config(None)).unwrap(),
        0
    )
    .is_err());
}

fn ground(lib: &mut MeshLibrary) -> u32 {
    lib.add(cuboid(
        Vec3::new(-256.0, -1.0, -256.0),
        Vec3::new(256.0, 0.0, 256.0),
        material::GROUND,
    ))
}

fn config(frames: u32) -> CompareConfig {
    CompareConfig {
        frames: Some(frames),
        width: 64,
        height: 36,
        strategies: vec![
            StrategyKind::Full,
            StrategyKind::Lipac,
            StrategyKind::Oracle,
        ],
        share_ground_truth: true,
        threads: 2,
        adaptive_levels: None,
        lipac_cell_size: None,
        lipac_rise_shift: None,
        lipac_start: lipac_sim::compare::LipacStart::Default,
        lipac_warm_start_at_cuts: false,
        lipac_warm_start_hold: None,
        device: Default::default(),
    }
}

#[test]
fn lipac_culls_instances_hidden_behind_a_wall() {
    // Camera at z = -100 looking +z at a 40 m wall (z 0..4) spanning the
    // whole ground; six 15 m buildings stand 65..105 m behind it. Every ray
    // that starts in front of the wall and passes over it is above 40 m
    // there and rising, so above the buildings behind it: no path reaches
    // them (the wall's top is not visible from 5 m).
    let mut lib = MeshLibrary::new();
    let g = ground(&mut lib);
    let wall = lib.add(cuboid(
        Vec3::new(-250.0, 0.0, 0.0),
        Vec3::new(250.0, 40.0, 4.0),
        material::WALL,
    ));
    let house = lib.add(cuboid(
        Vec3::new(-5.0, 0.0, -5.0),
        Vec3::new(5.0, 15.0, 5.0),
        material::WALL,
    ));
    let mut placed = vec![
        (g, Affine3A::IDENTITY, flags::STATIC),
        (wall, Affine3A::IDENTITY, flags::STATIC),
    ];
    for x in [-30.0, 0.0, 30.0] {
        for z in [70.0, 100.0] {
            placed.push((
                house,
                Affine3A::from_translation(Vec3::new(x, 0.0, z)),
                flags::STATIC,
            ));
        }
    }
    let mut scene = Scene::custom(SceneConfig::small(), lib, &placed).unwrap();
    let cam = FlyCamera::new(Vec3::new(0.0, 5.0, -100.0), 0.0, 0.0, 1.0, 16.0 / 9.0).unwrap();
    let path = CameraPath::fixed(cam, 24);
    let r = run("wall", &mut scene, &path, &config(24), &mut |_, _| {}).unwrap();
    let hidden: Vec<u32> = (2..8).collect();
    let (full, lipac, oracle) = (
        r.strategy("full").unwrap(),
        r.strategy("lipac").unwrap(),
        r.strategy("oracle").unwrap(),
    );
    // The scene is as designed: no ground-truth path hits the hidden houses.
    assert!(hidden.iter().all(|s| !oracle.last_geometry.contains(s)));
    assert!(hidden.iter().all(|s| full.last_geometry.contains(s)));
    // LiPaC activated the wall (hit by bounces off the ground) and left the
    // hidden houses culled.
    assert!(
        lipac.last_geometry.contains(&1),
        "{:?}",
        lipac.last_geometry
    );
    assert!(hidden.iter().all(|s| !lipac.last_geometry.contains(s)));
    assert!(lipac.last_geometry.len() < full.last_geometry.len());
}

#[test]
fn lipac_activates_an_instance_seen_only_in_a_mirror() {
    // Camera at the origin looking +z at a 30 m mirror block 35 m ahead; a
    // 40 m wide building stands 60 m behind the camera, outside the
    // frustum, and shows in the mirror.
    let mut lib = MeshLibrary::new();
    let g = ground(&mut lib);
    let mirror = lib.add(mirror_block(Vec3::splat(30.0)));
    let target = lib.add(cuboid(
        Vec3::new(-20.0, 0.0, -2.0),
        Vec3::new(20.0, 30.0, 2.0),
        material::WALL,
    ));
    let placed = [
        (g, Affine3A::IDENTITY, flags::STATIC),
        (
            mirror,
            Affine3A::from_translation(Vec3::new(0.0, 0.0, 50.0)),
            flags::STATIC | flags::MIRROR,
        ),
        (
            target,
            Affine3A::from_translation(Vec3::new(0.0, 0.0, -60.0)),
            flags::STATIC,
        ),
    ];
    let mut scene = Scene::custom(SceneConfig::small(), lib, &placed).unwrap();
    let cam = FlyCamera::new(Vec3::new(0.0, 5.0, 0.0), 0.0, 0.0, 1.0, 16.0 / 9.0).unwrap();
    assert!(!cam
        .frustum()
        .unwrap()
        .intersects_aabb(&scene.instances()[2].aabb));
    let path = CameraPath::fixed(cam, 16);
    let mut cfg = config(16);
    cfg.strategies.push(StrategyKind::Frustum);
    // The paper's cold start, so that only hit feedback activates the
    // building (a warm start activates the hitboxes in view, and through
    // Algorithm 2 their other instances).
    cfg.lipac_start = lipac_sim::compare::LipacStart::Cold;
    let r = run("mirror", &mut scene, &path, &cfg, &mut |_, _| {}).unwrap();
    let lipac = r.strategy("lipac").unwrap();
    assert!(
        lipac.last_geometry.contains(&2),
        "{:?}",
        lipac.last_geometry
    );
    // Its latency is that of hit feedback: some frames, not zero.
    assert!(
        lipac.summary.mean_latency >= 2.0,
        "{}",
        lipac.summary.mean_latency
    );
}

/// The text of every `<text>` element of an SVG.
fn svg_texts(svg: &str) -> Vec<String> {
    svg.split("<text")
        .skip(1)
        .filter_map(|t| t.split_once('>'))
        .filter_map(|(_, rest)| rest.split_once("</text>"))
        .map(|(s, _)| s.trim().to_string())
        .collect()
}

#[test]
fn report_files_are_well_formed() {
    let r = small(4, 32, 18, &StrategyKind::ALL, true);
    let dir = std::env::temp_dir().join(format!("lipac-report-test-{}", std::process::id()));
    let written = write_report(&r, &dir).unwrap();
    // report.md, report.json, frames.csv, the plots, report.html (no snapshots).
    assert_eq!(written.len(), 4 + PLOTS.len());
    assert!(dir.join("report.html").exists() && !dir.join("snapshots").exists());

    let json = std::fs::read_to_string(dir.join("report.json")).unwrap();
    let back: CompareReport = serde_json::from_str(&json).unwrap();
    assert_eq!(back.frames, r.frames);
    assert_eq!(back.strategies.len(), r.strategies.len());
    for (a, b) in back.strategies.iter().zip(&r.strategies) {
        assert_eq!(a.name, b.name);
        assert_eq!(a.frames.len(), b.frames.len());
        assert_eq!(a.summary.builds, b.summary.builds);
        assert_eq!(a.frames[3].tlas_instances, b.frames[3].tlas_instances);
    }

    let csv = std::fs::read_to_string(dir.join("frames.csv")).unwrap();
    let mut lines = csv.lines();
    assert_eq!(lines.next(), Some(CSV_HEADER));
    let rows: Vec<&str> = lines.collect();
    assert_eq!(rows.len(), 4 * StrategyKind::ALL.len());
    let columns = CSV_HEADER.split(',').count();
    assert!(rows.iter().all(|l| l.split(',').count() == columns));

    for plot in PLOTS {
        let svg = std::fs::read_to_string(dir.join(plot)).unwrap();
        assert!(svg.starts_with("<svg") && svg.trim_end().ends_with("</svg>"));
        let labels = svg_texts(&svg);
        // One legend entry per strategy, each exactly once.
        for st in &r.strategies {
            let n = labels.iter().filter(|l| **l == st.name).count();
            assert_eq!(n, 1, "{plot}: {} in {labels:?}", st.name);
        }
        // Tick labels are round numbers (no 53.8, 108, 161).
        for l in labels.iter().filter_map(|l| l.parse::<f64>().ok()) {
            let mantissa = l / 10f64.powf(l.abs().log10().floor());
            let round = l == 0.0
                || [1.0, 2.0, 2.5, 3.0, 4.0, 5.0, 6.0, 7.0, 8.0, 9.0, 1.5]
                    .iter()
                    .any(|m| (mantissa - m).abs() < 1e-9);
            assert!(round, "{plot}: tick {l}");
        }
    }
    for plot in &PLOTS[..4] {
        let svg = std::fs::read_to_string(dir.join(plot)).unwrap();
        assert!(
            svg.matches("<polyline").count() >= StrategyKind::ALL.len(),
            "{plot}"
        );
    }
    // One point per strategy plus its legend marker.
    for plot in &PLOTS[4..] {
        let scatter = std::fs::read_to_string(dir.join(plot)).unwrap();
        assert_eq!(
            scatter.matches("<circle").count(),
            2 * StrategyKind::ALL.len(),
            "{plot}"
        );
    }

    let md = std::fs::read_to_string(dir.join("report.md")).unwrap();
    assert!(md.contains("LiPaC: ") && md.contains("MiB full"));
    for plot in PLOTS {
        assert!(md.contains(&format!("]({plot})")));
    }
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn the_oracle_keeps_the_pinned_terrain_and_the_breakdowns_add_up() {
    let r = small(
        6,
        48,
        27,
        &[StrategyKind::Oracle, StrategyKind::Lipac],
        false,
    );
    let scene = Scene::generate(&SceneChoice::Small.config(None)).unwrap();
    let pinned: Vec<u32> = (0u32..)
        .zip(scene.instances())
        .filter(|(_, i)| i.is_pinned())
        .map(|(s, _)| s)
        .collect();
    assert!(!pinned.is_empty(), "the small scene pins its terrain");
    let oracle = r.strategy("oracle").unwrap();
    for s in &pinned {
        assert!(oracle.last_geometry.contains(s), "terrain slot {s} culled");
    }
    let unit_cube = lipac_sim::memory::blas_bytes(12);
    for st in &r.strategies {
        for m in &st.frames {
            // The split covers every BLAS byte (LiPaC's unit cube aside).
            let extra = if st.name == "lipac" { unit_cube } else { 0 };
            assert_eq!(m.blas_split.total() + extra, m.blas_bytes, "{}", st.name);
            assert_eq!(m.missing_by_kind.iter().sum::<u64>(), m.needed_missing);
            assert!(m.missing_hits <= m.needed_hits);
        }
        // Pinned terrain is in use every frame once built, never cached.
        let last = st.frames.last().unwrap();
        assert!(last.blas_split.terrain > 0, "{}", st.name);
        let s = &st.summary;
        let split: f64 = s.mean_split_mib.iter().sum();
        assert!(
            (split + extra_mib(st.name.as_str()) - s.mean_mib).abs() < 1e-3,
            "{}: {split} vs {}",
            st.name,
            s.mean_mib
        );
        let missing: u64 = s.missing_tail.instances.iter().sum();
        let missing_frames: u64 = st.frames.iter().map(|m| m.needed_missing).sum();
        assert!(missing <= missing_frames && (missing > 0) == (missing_frames > 0));
    }
    // LiPaC starts cold, so something was missing, and the oracle misses nothing.
    assert!(r.strategy("lipac").unwrap().summary.missing_hit_share > 0.0);
    assert_eq!(oracle.summary.missing_hit_share, 0.0);
}

fn extra_mib(name: &str) -> f64 {
    if name == "lipac" {
        lipac_sim::memory::blas_bytes(12) as f64 / (1024.0 * 1024.0)
    } else {
        0.0
    }
}

/// `lipac compare --rise-shift K` (`CompareConfig::lipac_rise_shift`):
/// LiPaC decides with the faster rise (the report names the shift, and its
/// decisions differ from the symmetric rule's: at 64x36 one hit on a cell
/// stays below the activation rate with shift 3 and crosses it with 1), and
/// a shift outside 1..=the decay shift is refused with the rule's error.
#[test]
fn a_rise_shift_reaches_lipac_and_a_bad_one_is_refused() {
    let with = |rise_shift: Option<u32>| {
        let config = CompareConfig {
            frames: Some(8),
            width: 128,
            height: 72,
            strategies: vec![StrategyKind::Lipac],
            share_ground_truth: true,
            threads: 2,
            adaptive_levels: None,
            lipac_cell_size: None,
            lipac_rise_shift: rise_shift,
            lipac_start: lipac_sim::compare::LipacStart::Default,
            lipac_warm_start_at_cuts: false,
            lipac_warm_start_hold: None,
            device: Default::default(),
        };
        run_choice(SceneChoice::City, None, &config, &mut |_, _| {})
    };
    // The default rises with shift 1; 3 is the symmetric rule. At 128 x 72
    // the default activation rate (0.44 hits per frame) is below one hit
    // at shift 1 (0.5) and above it at shift 3 (0.125); at 64 x 36 (0.11)
    // both would activate on one hit.
    let symmetric = with(Some(3)).expect("symmetric rule");
    let fast = with(None).expect("default rise shift 1");
    assert!(!symmetric.rule.contains("rising"), "{}", symmetric.rule);
    assert!(fast.rule.contains("rising with shift 1"), "{}", fast.rule);
    let decisions = |r: &CompareReport| -> Vec<(u64, u64, u64, u64)> {
        r.strategies[0]
            .frames
            .iter()
            .map(|f| {
                (
                    f.tlas_instances,
                    f.blas_bytes,
                    f.state_changes,
                    f.needed_missing,
                )
            })
            .collect()
    };
    assert_ne!(
        decisions(&symmetric),
        decisions(&fast),
        "the rise shift must change LiPaC's decisions in some frame"
    );
    assert_eq!(
        decisions(&fast),
        decisions(&with(Some(1)).expect("rise shift 1"))
    );
    for bad in [0, 4] {
        let e = with(Some(bad))
            .expect_err("rise shift outside 1..=3")
            .to_string();
        assert!(e.contains("rise shift"), "{e}");
    }
}

/// The warm start (`LipacConfig::warm_start`, `lipac compare --warm-start`):
/// on the city, where LiPaC's cold start traces nothing but the pinned
/// terrain until the first read-back (error above 0.3 in frames 0 and 1),
/// the default warm start traces the view from frame 0 (its first frame's
/// error at most half the cold start's, its second's at most two thirds:
/// Algorithm 2 of frame 0 already deactivates the warm-started cells no
/// path met, whose rates start at 0; its first frame's TLAS
/// many times larger), and hit feedback culls it down again: by frame 7 it
/// holds no more than 1.5x the records of the cold start.
#[test]
fn a_warm_start_traces_the_view_from_frame_0_and_feedback_culls_it() {
    use lipac_sim::compare::LipacStart;
    let with = |start: LipacStart| {
        let config = CompareConfig {
            frames: Some(8),
            width: 64,
            height: 36,
            strategies: vec![StrategyKind::Lipac],
            threads: 2,
            lipac_start: start,
            ..CompareConfig::default()
        };
        run_choice(SceneChoice::City, None, &config, &mut |_, _| {}).expect("comparison")
    };
    let cold = with(LipacStart::Cold);
    let warm = with(LipacStart::Default);
    let (c, w) = (&cold.strategies[0].frames, &warm.strategies[0].frames);
    for (f, bound) in [(0, 0.5), (1, 2.0 / 3.0)] {
        assert!(c[f].error > 0.3, "cold start, frame {f}: {}", c[f].error);
        assert!(
            w[f].error <= bound * c[f].error,
            "frame {f}: warm {} against cold {}",
            w[f].error,
            c[f].error
        );
    }
    assert!(
        w[0].tlas_instances > 4 * c[0].tlas_instances,
        "{} {}",
        w[0].tlas_instances,
        c[0].tlas_instances
    );
    assert!(
        (w[7].tlas_instances as f64) <= 1.5 * c[7].tlas_instances as f64,
        "not culled down: {} against {}",
        w[7].tlas_instances,
        c[7].tlas_instances
    );
    // The heuristic chooses the set: one that accepts nothing activates
    // nothing (the load frame still builds the pinned terrain unbudgeted).
    let none = with(LipacStart::Warm(lipac_core::latency::ActivationHeuristic {
        max_distance: 0.0,
        min_projected_size: f32::INFINITY,
        surround_radius: 0.0,
    }));
    let n0 = none.strategies[0].frames[0].tlas_instances;
    assert!(4 * n0 < w[0].tlas_instances, "{n0} {}", w[0].tlas_instances);
    assert!(none.strategies[0].frames[0].error > 0.3);
}

/// The default warm start takes what is within 800 m of the camera off
/// screen too (`ActivationHeuristic::surround_radius`): at frame 0 it
/// traces more than the frustum alone and its error is lower. A hold of 4
/// frames (`--warm-start-hold`, `LipacConfig::warm_start_hold`) keeps that
/// set through the feedback of frames 0–3, which culls it without one:
/// frame 0 is the same bit for bit, frames 1–4 trace more at less than
/// half the error, and at frame 5 feedback culls it down.
#[test]
fn a_warm_start_around_the_camera_and_held_keeps_the_view() {
    use lipac_core::latency::ActivationHeuristic;
    use lipac_sim::compare::LipacStart;
    let with = |start: LipacStart, hold: Option<u32>| {
        let config = CompareConfig {
            frames: Some(14),
            width: 64,
            height: 36,
            strategies: vec![StrategyKind::Lipac],
            threads: 2,
            lipac_start: start,
            lipac_warm_start_hold: hold,
            ..CompareConfig::default()
        };
        run_choice(SceneChoice::Mirror, None, &config, &mut |_, _| {}).expect("comparison")
    };
    let frustum_only = with(
        LipacStart::Warm(ActivationHeuristic {
            max_distance: f32::INFINITY,
            min_projected_size: 0.0,
            surround_radius: 0.0,
        }),
        None,
    );
    let around = with(LipacStart::Default, None);
    let held = with(LipacStart::Default, Some(4));
    let (f, a, h) = (
        &frustum_only.strategies[0].frames,
        &around.strategies[0].frames,
        &held.strategies[0].frames,
    );
    assert!(
        a[0].tlas_instances > f[0].tlas_instances && a[0].error < f[0].error,
        "frame 0: around {} records, error {}; frustum {} records, error {}",
        a[0].tlas_instances,
        a[0].error,
        f[0].tlas_instances,
        f[0].error
    );
    assert_eq!(h[0].tlas_instances, a[0].tlas_instances);
    assert_eq!(h[0].error.to_bits(), a[0].error.to_bits());
    let sum = |fr: &[lipac_sim::metrics::FrameMetrics], r: std::ops::Range<usize>| -> f64 {
        fr[r].iter().map(|x| x.error).sum()
    };
    for i in 1..=4 {
        assert!(
            h[i].tlas_instances > a[i].tlas_instances,
            "frame {i}: held {} against {}",
            h[i].tlas_instances,
            a[i].tlas_instances
        );
    }
    assert!(
        sum(h, 1..5) < 0.5 * sum(a, 1..5),
        "held {} against {}",
        sum(h, 1..5),
        sum(a, 1..5)
    );
    // The report says how LiPaC started.
    let md = lipac_sim::report::markdown(&held, false);
    assert!(
        md.contains(
            "it starts with a warm start of everything in view and of everything \
             within 800 m of the camera, held 4 frames without hits"
        ),
        "{}",
        md.lines().nth(2).unwrap_or("")
    );
    assert!(lipac_sim::report::markdown(&frustum_only, false)
        .contains("it starts with a warm start of everything in view)"));
    assert!(
        (h[5].tlas_instances as f64) < 0.8 * h[4].tlas_instances as f64,
        "not culled after the hold: {} at frame 5, {} at frame 4",
        h[5].tlas_instances,
        h[4].tlas_instances
    );
}

/// `--warm-start-at-cuts` (`LipacConfig::warm_start_at_cuts`): LiPaC makes
/// its warm start again at the camera cut. Before the cut the run is the
/// same frame for frame; at the cut frame its TLAS holds more of the new
/// view than without (its builds unbudgeted, as at the load).
#[test]
fn a_warm_start_at_the_cut_activates_the_new_view() {
    let (at, frames) = (12u32, 16u32);
    let with = |cuts: bool| {
        let config = CompareConfig {
            frames: Some(frames),
            width: 32,
            height: 18,
            strategies: vec![StrategyKind::Lipac],
            threads: 2,
            lipac_warm_start_at_cuts: cuts,
            lipac_warm_start_hold: None,
            ..CompareConfig::default()
        };
        let mut scene =
            Scene::generate(&lipac_sim::compare::SceneChoice::City.config(None)).unwrap();
        let j = CameraPath::city_jump(&scene, 32.0 / 18.0);
        let path = CameraPath::jump(j.camera_at(0), j.camera_at(j.frames() - 1), at, frames);
        assert_eq!(path.cuts(), [at]);
        run("city", &mut scene, &path, &config, &mut |_, _| {}).unwrap()
    };
    let (plain, warm) = (with(false), with(true));
    let (p, w) = (&plain.strategies[0].frames, &warm.strategies[0].frames);
    for f in 0..at as usize {
        assert_eq!(p[f].tlas_instances, w[f].tlas_instances, "frame {f}");
        assert_eq!(p[f].error.to_bits(), w[f].error.to_bits(), "frame {f}");
    }
    let c = at as usize;
    assert!(
        w[c].tlas_instances > p[c].tlas_instances,
        "{} {}",
        w[c].tlas_instances,
        p[c].tlas_instances
    );
    assert!(w[c].builds > p[c].builds, "{} {}", w[c].builds, p[c].builds);
    assert!(w[c].error < p[c].error, "{} {}", w[c].error, p[c].error);
}

/// `LipacConfig::honour_pins` false (`lipac sweep --decayed` with `!`):
/// the terrain is culled like any instance, so some tile the paths miss is
/// out of the TLAS, while the default keeps every tile every frame.
#[test]
fn lipac_without_pins_culls_terrain_the_default_keeps() {
    use lipac_sim::compare::{run_contenders, Contender};
    use lipac_sim::strategy::lipac::{Lipac, LipacConfig};
    let mut scene = Scene::generate(&SceneChoice::Small.config(None)).unwrap();
    let (w, h) = (48, 27);
    let path = CameraPath::flythrough(&scene, w as f32 / h as f32);
    let config = CompareConfig {
        strategies: Vec::new(),
        ..config(12)
    };
    let config = CompareConfig {
        width: w,
        height: h,
        ..config
    };
    let base = LipacConfig::for_rays_per_frame(u64::from(w * h)).unwrap();
    let free = LipacConfig {
        honour_pins: false,
        ..base.clone()
    };
    let contenders = vec![
        Contender {
            name: "pinned".into(),
            strategy: Box::new(Lipac::new(&scene, base).unwrap()),
        },
        Contender {
            name: "unpinned".into(),
            strategy: Box::new(Lipac::new(&scene, free).unwrap()),
        },
    ];
    let terrain: Vec<u32> = (0u32..)
        .zip(scene.instances())
        .filter(|(_, i)| i.is_pinned())
        .map(|(s, _)| s)
        .collect();
    assert!(!terrain.is_empty(), "the small scene pins its terrain");
    let r = run_contenders(
        "small",
        &mut scene,
        &path,
        &config,
        contenders,
        &mut |_, _| {},
    )
    .unwrap();
    let pinned = r.strategy("pinned").unwrap();
    let free = r.strategy("unpinned").unwrap();
    for s in &terrain {
        assert!(pinned.last_geometry.contains(s), "pinned tile {s} culled");
    }
    let kept = terrain
        .iter()
        .filter(|s| free.last_geometry.contains(s))
        .count();
    assert!(kept < terrain.len(), "every tile kept without pins");
    let terrain_bytes = |st: &lipac_sim::compare::StrategyRun| {
        st.frames.iter().map(|m| m.blas_split.terrain).sum::<u64>()
    };
    let (a, b) = (terrain_bytes(free), terrain_bytes(pinned));
    assert!(
        a < b,
        "terrain BLAS bytes over the frames: {a} without pins vs {b}"
    );
}
