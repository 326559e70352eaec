use super::*;
use crate::strategy::StrategyKind;

#[test]
fn pareto_front_of_a_hand_made_set() {
    // (cost, error). By hand: (1,9) cheapest; (2,4) and (5,1) trade
    // off; (3,4) is dominated by (2,4) (same error, costlier); (6,1)
    // by (5,1); (4,6) by (2,4); (2,4) twice: equal points are both on
    // the front; NaN never.
    let pts = [
        (1.0, 9.0),
        (2.0, 4.0),
        (3.0, 4.0),
        (5.0, 1.0),
        (6.0, 1.0),
        (4.0, 6.0),
        (2.0, 4.0),
        (f64::NAN, 0.0),
        (0.5, f64::NAN),
    ];
    assert_eq!(
        pareto_front(&pts),
        [true, true, false, true, false, false, true, false, false]
    );
    assert!(pareto_front(&[]).is_empty());
    assert_eq!(pareto_front(&[(3.0, 3.0)]), [true]);
}

#[test]
fn variants_follow_the_config_and_drop_duplicates() {
    let c = SweepConfig {
        // 9216 rays: ×0.25 and ×0.5 both round to θa = 2, θd = 1, but the
        // default decayed rule's rates scale apart, so neither is dropped.
        factors: vec![0.25, 0.5, 1.0, 4.0],
        ..SweepConfig::default()
    };
    let (v, skipped) = c.variants().unwrap();
    assert!(skipped.is_empty(), "{skipped:?}");
    let t = |name: &str| {
        v.iter()
            .find(|x| x.name == name)
            .and_then(|x| x.lipac.as_ref())
            .map(|l| l.thresholds)
            .unwrap()
    };
    // 4 · 9216 / 2073600 · 1000 = 17.8 → 18; · 100 → 1.78 → 2.
    let t4 = t("lipac ×4");
    assert_eq!(
        (t4.theta_a, t4.theta_d, t4.sigma_a, t4.sigma_o),
        (18, 2, 18, 2)
    );
    let t1 = t("lipac ×1");
    assert_eq!((t1.theta_a, t1.theta_d), (4, 1));
    // The decayed rule's rates scale with the factor too.
    let rate = |t: lipac_core::thresholds::Thresholds| match t.rule {
        lipac_core::thresholds::DecisionRule::Decayed(r) => r.activate,
        lipac_core::thresholds::DecisionRule::Paper => panic!("decayed rule expected"),
    };
    assert_eq!(rate(t4), 4 * rate(t1));
    assert_eq!(
        (t("lipac n_a 1 n_d 15").n_a, t("lipac n_a 4 n_d 30").n_d),
        (1, 30)
    );
    let cells: Vec<f64> = v
        .iter()
        .filter(|x| x.family == Family::CellSize)
        .map(|x| x.lipac.as_ref().unwrap().cell_size)
        .collect();
    assert_eq!(cells, [16.0, 64.0]);
    let bad = SweepConfig {
        factors: vec![0.0],
        ..SweepConfig::default()
    };
    assert!(bad.variants().is_err());
    let bad = SweepConfig {
        baselines: vec![StrategyKind::Lipac],
        ..SweepConfig::default()
    };
    assert!(bad.variants().is_err());
}

#[test]
fn hindsight_windows_are_named_references_and_a_zero_window_is_refused() {
    let c = SweepConfig {
        baselines: vec![StrategyKind::Oracle, StrategyKind::Hindsight],
        hindsight: vec![2, 8, 2],
        factors: vec![1.0],
        latency: Vec::new(),
        cell_sizes: Vec::new(),
        streaks: Vec::new(),
        ..SweepConfig::default()
    };
    let (v, skipped) = c.variants().unwrap();
    let refs: Vec<(&str, Option<u32>)> = v
        .iter()
        .filter(|x| x.kind == StrategyKind::Hindsight)
        .map(|x| (x.name.as_str(), x.hindsight))
        .collect();
    // The baseline is the default window, 8, so "hindsight 8" repeats it.
    assert_eq!(refs, [("hindsight", Some(8)), ("hindsight 2", Some(2))]);
    assert_eq!(skipped, ["hindsight 8", "hindsight 2"]);
    let bad = SweepConfig {
        hindsight: vec![0],
        ..c
    };
    assert!(bad.variants().is_err());
}

/// The default sweep with the decayed-rule variants `specs`.
fn with_decayed(specs: &[&str]) -> SweepConfig {
    let base = crate::strategy::lipac::LipacConfig::DEFAULT_DECAYED;
    SweepConfig {
        decayed: specs
            .iter()
            .map(|s| parse_decayed_variant(s, &base).unwrap())
            .collect(),
        ..SweepConfig::default()
    }
}

#[test]
fn decayed_family_sets_the_rise_shift_and_rates_and_rejects_what_cannot_be_met() {
    use crate::strategy::lipac::LipacConfig;
    use lipac_core::thresholds::DecisionRule;
    let base = LipacConfig::DEFAULT_DECAYED;
    let c = with_decayed(&["1", "2:200/40", "1:150/30:50/20", "-", "1:150/30"]);
    let (v, skipped) = c.variants().unwrap();
    // `1` with the default rates is the default LiPaC (`lipac ×1`).
    assert_eq!(skipped, ["lipac rise 1 100/0.2 100/0.2"]);
    let rule = |name: &str| {
        let x = v.iter().find(|x| x.name == name).unwrap();
        assert_eq!(x.family, Family::Decayed);
        match x.lipac.as_ref().unwrap().thresholds.rule {
            DecisionRule::Decayed(r) => r,
            DecisionRule::Paper => panic!("decayed rule expected"),
        }
    };
    let one = rule("lipac rise 1 150/30 100/0.2");
    let two = rule("lipac rise 2 200/40 100/0.2");
    let inst = rule("lipac rise 1 150/30 50/20");
    let sym = rule("lipac rise - 100/0.2 100/0.2");
    assert_eq!(
        (one.shift, one.rise_shift, two.rise_shift, sym.rise_shift),
        (3, 1, 2, 3)
    );
    assert!(two.activate > one.activate && two.deactivate > one.deactivate);
    assert!(inst.instance_activate < one.instance_activate);
    assert_eq!(inst.activate, one.activate);
    // A rise slower than the decay is an error, not a silent clamp.
    let bad = SweepConfig {
        decayed: vec![parse_decayed_variant("4", &base).unwrap()],
        ..SweepConfig::default()
    };
    assert!(bad
        .variants()
        .unwrap_err()
        .to_string()
        .contains("rise shift"));
}

#[test]
fn decayed_variants_carry_their_own_cells_and_latency_mitigation() {
    use crate::strategy::lipac::LipacConfig;
    let base = LipacConfig::DEFAULT_DECAYED;
    let c = with_decayed(&[
        "1:5/1:5/1",
        "1:5/1:5/1@128",
        "1:5/1:5/1@128+100/0.05",
        "1:150/30+50/0.1",
        "1:5/1:5/1@128%0",
        "1:5/1:5/1%3+100/0.05!",
    ]);
    let (v, skipped) = c.variants().unwrap();
    assert!(skipped.is_empty(), "{skipped:?}");
    let find = |name: &str| {
        v.iter()
            .find(|x| x.name == name)
            .unwrap_or_else(|| panic!("no variant {name}"))
    };
    let plain = find("lipac rise 1 5/1 5/1");
    let cells = find("lipac rise 1 5/1 5/1 128 m cells");
    let both = find("lipac rise 1 5/1 5/1 128 m cells + latency 100 m / 0.05");
    let lat = find("lipac rise 1 150/30 100/0.2 + latency 50 m / 0.1");
    let leaf = find("lipac rise 1 5/1 5/1 128 m cells merged 0");
    let free = find("lipac rise 1 5/1 5/1 merged 3 unpinned + latency 100 m / 0.05");
    let cfg = |x: &Variant| x.lipac.clone().unwrap();
    // Merge levels: the default's unless a variant sets its own.
    assert_eq!(
        cfg(plain).adaptive_hitboxes.levels,
        LipacConfig::DEFAULT_ADAPTIVE_LEVELS
    );
    assert_eq!(cfg(leaf).adaptive_hitboxes.levels, 0);
    // Pins: honoured unless a variant ends in `!`.
    assert!(v
        .iter()
        .filter(|x| x.name != free.name)
        .all(|x| x.lipac.as_ref().is_none_or(|c| c.honour_pins)));
    assert!(!cfg(free).honour_pins);
    assert_eq!(cfg(free).thresholds, cfg(plain).thresholds);
    assert_eq!(free.kind, StrategyKind::LipacLatency);
    assert_eq!(cfg(leaf).cell_size, 128.0);
    assert_eq!(cfg(plain).cell_size, LipacConfig::DEFAULT_CELL_SIZE);
    assert_eq!((cfg(cells).cell_size, cfg(cells).latency), (128.0, None));
    assert_eq!(cfg(both).cell_size, 128.0);
    assert_eq!(cfg(both).latency.unwrap().max_distance, 100.0);
    assert_eq!(cfg(lat).cell_size, LipacConfig::DEFAULT_CELL_SIZE);
    // Same rule: the cell size and mitigation are the only differences.
    assert_eq!(cfg(plain).thresholds, cfg(both).thresholds);
    assert_eq!(
        (plain.kind, cells.kind),
        (StrategyKind::Lipac, StrategyKind::Lipac)
    );
    assert_eq!(
        (both.kind, lat.kind),
        (StrategyKind::LipacLatency, StrategyKind::LipacLatency)
    );
    assert!(v
        .iter()
        .all(|x| x.family != Family::Decayed || x.factor == Some(1.0)));
    for bad in [
        "1@0",
        "1@x",
        "1+100",
        "1+-1/0.1",
        "1+100/inf",
        "1@128+",
        "1%5",
        "1@32%x",
        "1!!",
        "1!@32",
    ] {
        assert!(parse_decayed_variant(bad, &base).is_err(), "{bad} accepted");
    }
    // Latency mitigation without a distance limit, as `--warm-start inf:0`.
    let h = parse_decayed_variant("1+inf/0.05", &base)
        .unwrap()
        .latency
        .unwrap();
    assert_eq!(
        (h.max_distance, h.min_projected_size),
        (f32::INFINITY, 0.05)
    );
}

/// A setting's own warm-start hold (`~N`) beats the sweep's
/// (`--warm-start-hold`), and each LiPaC name says the hold it runs with,
/// once.
#[test]
fn decayed_variants_carry_their_own_warm_start_hold() {
    let c = SweepConfig {
        warm_start_hold: Some(3),
        factors: vec![1.0],
        latency: Vec::new(),
        cell_sizes: Vec::new(),
        streaks: Vec::new(),
        baselines: Vec::new(),
        ..with_decayed(&["1@256~14", "1@128~0!", "1@64"])
    };
    let (v, skipped) = c.variants().unwrap();
    assert!(skipped.is_empty(), "{skipped:?}");
    let holds: Vec<(&str, u32)> = v
        .iter()
        .map(|x| (x.name.as_str(), x.lipac.as_ref().unwrap().warm_start_hold))
        .collect();
    assert_eq!(
        holds,
        [
            ("lipac ×1 held 3", 3),
            ("lipac rise 1 100/0.2 100/0.2 256 m cells held 14", 14),
            (
                "lipac rise 1 100/0.2 100/0.2 128 m cells unpinned held 0",
                0
            ),
            ("lipac rise 1 100/0.2 100/0.2 64 m cells held 3", 3),
        ]
    );
    // Without the sweep's hold, the settings without their own keep the
    // configured one (0) and their names say nothing.
    let c = SweepConfig {
        warm_start_hold: None,
        ..c
    };
    let (v, _) = c.variants().unwrap();
    let names: Vec<&str> = v.iter().map(|x| x.name.as_str()).collect();
    assert_eq!(names[0], "lipac ×1");
    assert_eq!(names[3], "lipac rise 1 100/0.2 100/0.2 64 m cells");
    assert_eq!(v[3].lipac.as_ref().unwrap().warm_start_hold, 0);
}

/// A setting's own start (`^off`, `^DIST/SIZE[/RADIUS]`) beats the
/// sweep's (`--warm-start`), and each LiPaC name says its start once.
#[test]
fn decayed_variants_carry_their_own_start() {
    use crate::compare::LipacStart;
    use lipac_core::latency::ActivationHeuristic;
    let frustum_only = ActivationHeuristic {
        max_distance: f32::INFINITY,
        min_projected_size: 0.0,
        surround_radius: 0.0,
    };
    let c = SweepConfig {
        lipac_start: LipacStart::Warm(frustum_only),
        factors: vec![1.0],
        latency: Vec::new(),
        cell_sizes: Vec::new(),
        streaks: Vec::new(),
        baselines: Vec::new(),
        ..with_decayed(&["1@256~14^inf/0/800", "1@64^off!", "1@128"])
    };
    let (v, skipped) = c.variants().unwrap();
    assert!(skipped.is_empty(), "{skipped:?}");
    let starts: Vec<(&str, Option<ActivationHeuristic>)> = v
        .iter()
        .map(|x| (x.name.as_str(), x.lipac.as_ref().unwrap().warm_start))
        .collect();
    let around = ActivationHeuristic {
        surround_radius: 800.0,
        ..frustum_only
    };
    assert_eq!(
        starts,
        [
            ("lipac ×1 + warm start inf:0:0", Some(frustum_only)),
            (
                "lipac rise 1 100/0.2 100/0.2 256 m cells held 14 + warm start inf:0:800",
                Some(around)
            ),
            (
                "lipac rise 1 100/0.2 100/0.2 64 m cells unpinned + cold start",
                None
            ),
            (
                "lipac rise 1 100/0.2 100/0.2 128 m cells + warm start inf:0:0",
                Some(frustum_only)
            ),
        ]
    );
}

/// Latency-mitigation heuristics that differ only in their surround
/// radius are two configurations with two names (not "two sweep variants
/// share a name").
#[test]
fn latency_names_say_the_surround_radius() {
    use crate::heuristic_arg::parse_heuristic;
    let c = SweepConfig {
        factors: vec![1.0],
        cell_sizes: Vec::new(),
        streaks: Vec::new(),
        baselines: Vec::new(),
        latency: vec![
            parse_heuristic("100:0.05", ':').unwrap(),
            parse_heuristic("100:0.05:200", ':').unwrap(),
        ],
        ..with_decayed(&["1+100/0.05/50"])
    };
    let (v, skipped) = c.variants().unwrap();
    assert!(skipped.is_empty(), "{skipped:?}");
    let names: Vec<&str> = v.iter().map(|x| x.name.as_str()).collect();
    assert_eq!(
        names,
        [
            "lipac ×1",
            "lipac-latency 100 m / 0.05",
            "lipac-latency 100 m / 0.05 / 200 m around",
            "lipac rise 1 100/0.2 100/0.2 + latency 100 m / 0.05 / 50 m around",
        ]
    );
    assert_eq!(
        v[2].lipac
            .as_ref()
            .unwrap()
            .latency
            .unwrap()
            .surround_radius,
        200.0
    );
}

fn point(
    scene: &str,
    name: &str,
    strategy: &str,
    frame_ms: f64,
    gpu_ms: f64,
    error: f64,
) -> SweepPoint {
    SweepPoint {
        scene: scene.into(),
        name: name.into(),
        family: Family::Baseline,
        strategy: strategy.into(),
        factor: None,
        cell_size: None,
        thresholds: None,
        latency: None,
        summary: crate::metrics::Summary {
            mean_frame_ms: frame_ms,
            mean_gpu_frame_ms: gpu_ms,
            mean_error: error,
            mean_mib: 1.0,
            ..Default::default()
        },
        builds_per_frame: 1.0,
        frame_errors: vec![error],
        front_time: true,
        front_gpu_time: true,
        front_memory: true,
        front_builds: true,
    }
}

#[test]
fn time_fronts_of_a_hand_made_sweep() {
    // Scene a, (frame ms, GPU ms, error). By hand, frame time: full (40,
    // error 0) and cheap (10, 0.2) trade off; mid (20, 0.1) too; worse
    // (30, 0.1) is dominated by mid; the oracle (5, 0) would dominate all
    // but is never on a front. GPU time ranks them differently: mid's 3.0
    // is dominated by worse's 1.0 at the same error.
    let mut r = SweepReport {
        frames: 1,
        width: 1,
        height: 1,
        rays_per_frame: 1,
        scenes: ["a", "b"]
            .map(|n| SweepScene {
                name: n.into(),
                instances: 1,
                ground_truth_ms: 0.0,
                traced_rays_per_frame: 0.0,
                wall_s: 0.0,
            })
            .to_vec(),
        points: vec![
            point("a", "full", "full", 40.0, 9.0, 0.0),
            point("a", "cheap", "lipac", 10.0, 0.5, 0.2),
            point("a", "mid", "lipac", 20.0, 3.0, 0.1),
            point("a", "worse", "lipac", 30.0, 1.0, 0.1),
            point("a", "oracle", "oracle", 5.0, 0.1, 0.0),
            // Hindsight reads the ground truth too: never on a front.
            point("a", "hindsight 2", "hindsight", 5.0, 0.1, 0.05),
            // Scene b is its own front: its one point is on it although
            // scene a's cheap point would dominate it.
            point("b", "mid", "lipac", 50.0, 5.0, 0.3),
        ],
        skipped: vec![],
        wall_s: 0.0,
        device_profile: Default::default(),
    };
    mark_fronts(&mut r);
    let on = |f: fn(&SweepPoint) -> bool| -> Vec<bool> { r.points.iter().map(f).collect() };
    assert_eq!(
        on(|p| p.front_time),
        [true, true, true, false, false, false, true]
    );
    assert_eq!(
        on(|p| p.front_gpu_time),
        [true, true, false, true, false, false, true]
    );
    // The fronts follow COSTS' order: 0 is frame time, 1 modelled GPU time.
    assert_eq!(r.points[2].fronts(), [true, false, false, false]);
    assert!(r.points[2].on_front(0) && !r.points[2].on_front(1) && !r.points[2].on_front(9));
}

#[test]
fn sweep_markdown_says_where_lipac_is_below_the_baselines() {
    // Scene a: frustum (frame 30 ms, error 0.02), heuristic (5 ms, 0.2),
    // LiPaC (20 ms, 0.04) and (8 ms, 0.1). Scene b has no baseline.
    let r = SweepReport {
        frames: 1,
        width: 1,
        height: 1,
        rays_per_frame: 1,
        scenes: ["a", "b"]
            .map(|n| SweepScene {
                name: n.into(),
                instances: 1,
                ground_truth_ms: 0.0,
                traced_rays_per_frame: 0.0,
                wall_s: 0.0,
            })
            .to_vec(),
        points: vec![
            point("a", "frustum", "frustum", 30.0, 3.0, 0.02),
            point("a", "heuristic", "heuristic", 5.0, 0.5, 0.2),
            point("a", "lipac ×1", "lipac", 20.0, 2.0, 0.04),
            point("a", "lipac ×4", "lipac", 8.0, 1.0, 0.1),
            point("b", "lipac ×1", "lipac", 20.0, 2.0, 0.04),
        ],
        skipped: vec![],
        wall_s: 0.0,
        device_profile: Default::default(),
    };
    let md = sweep_markdown(&r);
    assert!(md.contains("### a: LiPaC's front against the baselines'"));
    assert!(!md.contains("### b: LiPaC's front"));
    assert!(md.contains(
        "- frame time (CPU, ms) vs frustum: [0.0050, 0.0200) neither; \
         [0.0200, 0.0400) baseline only; ≥ 0.0400 LiPaC below (20.000 vs 30.000 from 0.0400)"
    ));
    assert!(md.contains(
        "- frame time (CPU, ms) vs heuristic: [0.0050, 0.0400) neither; \
         [0.0400, 0.2000) LiPaC only; ≥ 0.2000 LiPaC not below (8.000 vs 5.000 from 0.2000)"
    ));
    // Every point has 1 MiB: equal memory is not below.
    assert!(md.contains("- memory (MiB) vs frustum: [0.0050, 0.0200) neither; [0.0200, 0.0400) baseline only; ≥ 0.0400 LiPaC not below"));
}
