use lipac_test_support::{Rng64, SplitMix64};
use proptest::prelude::*;

use super::*;

/// A delayed, lagged memory plant: the steady state is `base · s^-gain`
/// bytes (higher thresholds, less memory) plus `floor` bytes that no scale
/// removes (pinned geometry); the memory follows the scale `delay` frames
/// late with a first-order lag.
struct MemoryPlant {
    base: f64,
    floor: f64,
    gain: f64,
    delay: usize,
    lag: f64,
    history: Vec<f64>,
    memory: f64,
}

impl MemoryPlant {
    fn new(base: f64, floor: f64) -> Self {
        Self {
            base,
            floor,
            gain: 0.7,
            delay: 20,
            lag: 0.2,
            history: Vec::new(),
            memory: 0.0,
        }
    }
    fn step(&mut self, scale: f64) -> u64 {
        self.history.push(scale);
        let k = self.history.len();
        let s = if k > self.delay {
            self.history[k - 1 - self.delay]
        } else {
            1.0
        };
        let steady = self.floor + self.base * s.powf(-self.gain);
        self.memory += self.lag * (steady - self.memory);
        self.memory as u64
    }
}

fn budget(bytes: u64) -> ThresholdController {
    ThresholdController::new(
        ControlTarget::MemoryBudget { bytes },
        ControllerConfig::default(),
    )
    .unwrap()
}

/// Runs `frames` frames; returns the memory per frame.
fn run(c: &mut ThresholdController, plant: &mut MemoryPlant, frames: usize) -> Vec<u64> {
    let mut out = Vec::with_capacity(frames);
    let mut memory = 0;
    for _ in 0..frames {
        let s = c.update(memory, None);
        memory = plant.step(s);
        out.push(memory);
    }
    out
}

fn within(v: &[u64], target: u64, tol: f64) -> bool {
    v.iter()
        .all(|&m| (m as f64 - target as f64).abs() <= tol * target as f64)
}

#[test]
fn step_response_settles_within_five_percent() {
    // The scene wants 10 MB at the paper's thresholds; the budget is 6 MB.
    let mut c = budget(6_000_000);
    let mut plant = MemoryPlant::new(10_000_000.0, 0.0);
    let m = run(&mut c, &mut plant, 600);
    assert!(
        within(&m[300..], 6_000_000, 0.05),
        "not within 5 %: {:?}",
        &m[300..310]
    );
    assert!(c.scale() > 1.0, "thresholds must rise: {}", c.scale());
    assert!(!c.stats().unreachable);
    // No limit cycle: the direction of the scale reversed only a few times.
    assert!(c.stats().reversals <= 12, "{:?}", c.stats());
}

#[test]
fn spare_budget_lowers_the_thresholds() {
    let mut c = budget(15_000_000);
    let mut plant = MemoryPlant::new(10_000_000.0, 0.0);
    let m = run(&mut c, &mut plant, 600);
    assert!(within(&m[300..], 15_000_000, 0.05));
    assert!(c.scale() < 1.0);
    // A budget the scene never needs drives the scale to its floor: spare
    // budget, saturated but not "unreachable".
    let mut c = budget(500_000_000);
    run(&mut c, &mut plant, 400);
    let s = c.stats();
    assert_eq!(s.scale, ControllerConfig::default().min_scale);
    assert!(s.saturated && !s.unreachable, "{s:?}");
}

#[test]
fn an_unreachable_budget_saturates_without_oscillating() {
    // 3 MB pinned; a 2 MB budget cannot be met at any scale.
    let mut c = budget(2_000_000);
    let mut plant = MemoryPlant::new(10_000_000.0, 3_000_000.0);
    let m = run(&mut c, &mut plant, 400);
    let s = c.stats();
    assert_eq!(s.scale, ControllerConfig::default().max_scale);
    assert!(s.saturated && s.unreachable, "{s:?}");
    assert_eq!(s.reversals, 0, "one way to the bound: {s:?}");
    // It does the best it can: the pinned floor plus what the largest
    // thresholds leave.
    assert!(*m.last().unwrap() < 4_000_000, "{:?}", m.last());
    // A reachable budget again: the flag clears and the law follows.
    c.set_target(ControlTarget::MemoryBudget { bytes: 5_000_000 })
        .unwrap();
    assert!(c
        .set_target(ControlTarget::EscapeFraction { fraction: 0.1 })
        .is_err());
    let m = run(&mut c, &mut plant, 600);
    assert!(!c.stats().unreachable);
    assert!(within(&m[400..], 5_000_000, 0.05), "{:?}", &m[400..410]);
}

#[test]
fn a_camera_jump_is_absorbed() {
    // At frame 300 the view jumps to a part of the scene that needs twice
    // the memory; the controller returns within 5 % and stays there.
    let mut c = budget(6_000_000);
    let mut plant = MemoryPlant::new(10_000_000.0, 0.0);
    run(&mut c, &mut plant, 300);
    let before = c.scale();
    plant.base = 20_000_000.0;
    let m = run(&mut c, &mut plant, 500);
    assert!(c.scale() > before * 2.0, "{} -> {}", before, c.scale());
    assert!(within(&m[250..], 6_000_000, 0.05), "{:?}", &m[250..260]);
    assert!(c.stats().reversals <= 20, "{:?}", c.stats());
}

#[test]
fn warm_up_holds_the_scale() {
    let mut c = budget(1000);
    for _ in 0..ControllerConfig::default().warmup_frames {
        assert_eq!(c.update(1_000_000, None), 1.0);
    }
    assert!(c.update(1_000_000, None) > 1.0);
}

#[test]
fn escape_target_tracks_a_noisy_fraction() {
    // Escape share rises with the scale: 0.2 · s^0.5, plus noise of ±0.02,
    // seen 2 frames late.
    let mut c = ThresholdController::new(
        ControlTarget::EscapeFraction { fraction: 0.1 },
        ControllerConfig::default(),
    )
    .unwrap();
    let mut rng = SplitMix64::new(13);
    let mut scales = vec![1.0; 3];
    let mut tail = Vec::new();
    for f in 0..800 {
        let s = scales[scales.len() - 3];
        let fraction = (0.2 * f64::sqrt(s) + rng.range_f64(-0.02, 0.02)).clamp(0.0, 1.0);
        let total = 100_000;
        let sample = EscapeSample {
            box_hits: (fraction * total as f64) as u64,
            total_hits: total,
        };
        scales.push(c.update(0, Some(sample)));
        if f >= 400 {
            tail.push(0.2 * f64::sqrt(s));
        }
    }
    // The noise-free share the scale gives is within 10 % of the target.
    assert!(
        tail.iter().all(|&e| (e - 0.1).abs() < 0.01),
        "{:?}",
        &tail[..5]
    );
    assert!((c.scale() - 0.25).abs() < 0.06, "{}", c.scale());
}

#[test]
fn frames_without_hits_hold_an_escape_target() {
    let mut c = ThresholdController::new(
        ControlTarget::EscapeFraction { fraction: 0.5 },
        ControllerConfig {
            warmup_frames: 0,
            ..ControllerConfig::default()
        },
    )
    .unwrap();
    let s = c.update(0, Some(EscapeSample::default()));
    assert_eq!(s, 1.0);
    assert_eq!(c.update(0, None), 1.0);
    // All hits escaping: thresholds must fall.
    let all = EscapeSample {
        box_hits: 10,
        total_hits: 10,
    };
    assert!(c.update(0, Some(all)) < 1.0);
}

#[test]
fn bad_targets_and_settings_are_errors() {
    let cfg = ControllerConfig::default();
    assert_eq!(
        ThresholdController::new(ControlTarget::MemoryBudget { bytes: 0 }, cfg).unwrap_err(),
        ControllerError::ZeroBudget
    );
    for f in [f64::NAN, 0.0, 1.0, -0.5, 2.0, f64::INFINITY] {
        let e = ThresholdController::new(ControlTarget::EscapeFraction { fraction: f }, cfg)
            .unwrap_err();
        assert!(matches!(e, ControllerError::InvalidFraction(_)));
        assert!(e.to_string().contains("(0, 1)"));
    }
    let ok = ControlTarget::MemoryBudget { bytes: 1 };
    let bad = [
        ControllerConfig {
            min_scale: 0.0,
            ..cfg
        },
        ControllerConfig {
            min_scale: 2.0,
            ..cfg
        },
        ControllerConfig {
            max_scale: 0.5,
            ..cfg
        },
        ControllerConfig { ki: 0.0, ..cfg },
        ControllerConfig {
            kp: f64::NAN,
            ..cfg
        },
        ControllerConfig {
            max_step: -1.0,
            ..cfg
        },
        ControllerConfig {
            deadband: 1.0,
            ..cfg
        },
        ControllerConfig {
            smoothing: 0.0,
            ..cfg
        },
        ControllerConfig {
            over_gain: 0.5,
            ..cfg
        },
        ControllerConfig {
            unreachable_frames: 0,
            ..cfg
        },
    ];
    for b in bad {
        let e = ThresholdController::new(ok, b).unwrap_err();
        assert!(matches!(e, ControllerError::InvalidConfig { .. }), "{b:?}");
    }
}

proptest! {
    /// Whatever it is fed, the scale stays finite, in range, and moves at
    /// most `max_step` in log per frame.
    #[test]
    fn the_law_is_bounded_and_rate_limited(
        budget_bytes in 1u64..1 << 40,
        fraction in 0.001f64..0.999,
        memory in proptest::collection::vec(0u64..1 << 42, 1..200),
        boxes in proptest::collection::vec((0u64..1000, 0u64..1000), 1..200),
        warmup in 0u32..10,
    ) {
        let cfg = ControllerConfig { warmup_frames: warmup, ..ControllerConfig::default() };
        for target in [
            ControlTarget::MemoryBudget { bytes: budget_bytes },
            ControlTarget::EscapeFraction { fraction },
        ] {
            let mut c = ThresholdController::new(target, cfg).unwrap();
            let mut last = c.scale();
            for (i, (&m, &(b, t))) in memory.iter().zip(boxes.iter().cycle()).enumerate() {
                let s = c.update(m, Some(EscapeSample { box_hits: b, total_hits: b + t }));
                prop_assert!(s.is_finite());
                prop_assert!(s >= cfg.min_scale && s <= cfg.max_scale);
                prop_assert!((s.ln() - last.ln()).abs() <= cfg.max_step + 1e-9);
                if (i as u32) < warmup {
                    prop_assert_eq!(s, 1.0);
                }
                let st = c.stats();
                prop_assert!(st.error.abs() <= cfg.max_error);
                prop_assert!(!st.unreachable || st.saturated);
                last = s;
            }
        }
    }

    /// Monotone: a measurement above the target never lowers the
    /// thresholds, one below never raises them (integral part; P part on a
    /// constant error is zero).
    #[test]
    fn a_constant_error_moves_one_way(over in any::<bool>(), frames in 1usize..100) {
        let mut c = ThresholdController::new(
            ControlTarget::MemoryBudget { bytes: 1_000_000 },
            ControllerConfig { warmup_frames: 0, ..ControllerConfig::default() },
        ).unwrap();
        let m = if over { 2_000_000 } else { 500_000 };
        let mut last = c.scale();
        for _ in 0..frames {
            let s = c.update(m, None);
            if over { prop_assert!(s >= last) } else { prop_assert!(s <= last) }
            last = s;
        }
        prop_assert_eq!(c.stats().reversals, 0);
    }
}

#[test]
fn the_second_lever_acts_only_over_a_memory_budget() {
    let budget = ControlTarget::MemoryBudget { bytes: 1000 };
    let mut c = ThresholdController::new(budget, ControllerConfig::default()).unwrap();
    assert!(!c.wants_eviction(1000), "at the budget");
    assert!(c.wants_eviction(1001));
    c.note_eviction(3);
    c.note_eviction(0);
    assert_eq!((c.stats().evicting_frames, c.stats().evicted), (2, 3));
    let off = ControllerConfig {
        evict_cached_over_budget: false,
        ..ControllerConfig::default()
    };
    let c = ThresholdController::new(budget, off).unwrap();
    assert!(!c.wants_eviction(u64::MAX));
    let escape = ControlTarget::EscapeFraction { fraction: 0.1 };
    let c = ThresholdController::new(escape, ControllerConfig::default()).unwrap();
    assert!(
        !c.wants_eviction(u64::MAX),
        "an escape target has no budget"
    );
}

#[test]
fn the_third_lever_acts_at_a_memory_budget_and_its_dead_band() {
    // Dead band 0.01: the lever acts above 1000 · e^-0.01 ≈ 990.05 bytes.
    let budget = ControlTarget::MemoryBudget { bytes: 1000 };
    let mut c = ThresholdController::new(budget, ControllerConfig::default()).unwrap();
    assert!(!c.wants_coarsening(990), "clearly under the budget");
    assert!(c.wants_coarsening(991), "within the dead band below it");
    assert!(c.wants_coarsening(1000) && c.wants_coarsening(u64::MAX));
    c.note_coarsening(5);
    c.note_coarsening(0);
    assert_eq!((c.stats().coarsening_frames, c.stats().coarsened), (1, 5));
    let off = ControllerConfig {
        coarsen_over_budget: false,
        ..ControllerConfig::default()
    };
    let c = ThresholdController::new(budget, off).unwrap();
    assert!(!c.wants_coarsening(u64::MAX));
    let escape = ControlTarget::EscapeFraction { fraction: 0.1 };
    let c = ThresholdController::new(escape, ControllerConfig::default()).unwrap();
    assert!(
        !c.wants_coarsening(u64::MAX),
        "an escape target has no budget"
    );
}
