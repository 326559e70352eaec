//! The closed-loop thresholds in the Manager (lipac_core::controller), on a
//! synthetic backend: 256 instances on a 16 x 16 grid, one per cell, each
//! with its own 10 kB BLAS; a "tracer" gives every cell a fixed heat (hits
//! per frame, falling off with the distance to a focus), to the instance
//! when it is traced and to its cell's counting box when not. A camera jump
//! moves the focus to the far corner.

use glam::{Affine3A, Vec3};
use lipac_core::controller::{ControlTarget, ControllerConfig};
use lipac_core::{
    Aabb, Ack, BuildEstimate, FrameBudgets, GridConfig, HitboxGrid, InstanceDesc, InstanceFlags,
    Manager, ManagerConfig, ManagerError, MeshCatalog, MeshId, MeshLod, ReadbackRing, Thresholds,
};
use lipac_test_support::{Rng64, SplitMix64};

const UNIT_CUBE: u64 = 0xC0BE;
const N: u32 = 16;
const CELL: f32 = 8.0;
const BLAS_BYTES: u64 = 10000;
/// Integral gain for this rig: its memory moves in whole 10 kB BLASes and
/// one ring of cells is a factor 0.63 in heat, so the default `k_i` = 0.03
/// takes ~300 frames to cross one ring and parks 5 % under the budget; 0.1
/// holds it within one BLAS (1 %) before and after the jump.
const KI: f64 = 0.1;

fn base_thresholds() -> Thresholds {
    Thresholds {
        theta_a: 100,
        theta_d: 20,
        sigma_a: 100,
        sigma_o: 20,
        n_a: 4,
        n_d: 15,
        ..Thresholds::paper()
    }
}

fn config(target: Option<ControlTarget>) -> ManagerConfig {
    let mut c = ManagerConfig::new(UNIT_CUBE);
    c.culling.latency_mitigation = None;
    c.culling.thresholds = base_thresholds();
    c.scheduler.cache.max_unused_frames = 8;
    c.target = target;
    c.controller = ControllerConfig {
        warmup_frames: 40,
        ki: KI,
        ..ControllerConfig::default()
    };
    c
}

struct Rig {
    manager: Manager,
    ring: ReadbackRing,
    rng: SplitMix64,
    focus: (f32, f32),
    /// Metres over which a cell's heat halves.
    falloff: f32,
    handles: Vec<lipac_core::InstanceHandle>,
    tlas: Vec<lipac_core::TlasInstance>,
}

fn rig(target: Option<ControlTarget>) -> Result<Rig, ManagerError> {
    rig_with(config(target))
}

fn rig_with(config: ManagerConfig) -> Result<Rig, ManagerError> {
    rig_lods(config, &[BLAS_BYTES])
}

/// The rig with one LOD per entry of `lod_bytes` (BLAS bytes; LOD 0 the
/// finest).
fn rig_lods(config: ManagerConfig, lod_bytes: &[u64]) -> Result<Rig, ManagerError> {
    let grid = HitboxGrid::new(GridConfig {
        min: [0.0, 0.0],
        max: [N as f64 * CELL as f64, N as f64 * CELL as f64],
        cell_size: CELL as f64,
    })?;
    let mut catalog = MeshCatalog::new();
    for m in 0..N * N {
        catalog.insert(
            MeshId(m),
            lod_bytes
                .iter()
                .map(|&bytes| MeshLod {
                    estimate: BuildEstimate {
                        primitives: 100,
                        result_bytes: bytes,
                        build_scratch_bytes: 64,
                        update_scratch_bytes: 0,
                    },
                    data_bytes: 16,
                })
                .collect(),
        )?;
    }
    let mut manager = Manager::new(grid, config, catalog)?;
    let mut handles = Vec::new();
    for m in 0..N * N {
        let (x, z) = ((m % N) as f32 * CELL + 4.0, (m / N) as f32 * CELL + 4.0);
        let aabb = Aabb::new(
            Vec3::new(x - 1.0, 0.0, z - 1.0),
            Vec3::new(x + 1.0, 2.0, z + 1.0),
        );
        let desc = InstanceDesc {
            flags: InstanceFlags::STATIC,
            ..InstanceDesc::new(
                MeshId(m),
                Affine3A::from_translation(Vec3::new(x, 0.0, z)),
                aabb,
            )
        };
        handles.push(manager.register(desc)?);
    }
    Ok(Rig {
        manager,
        ring: ReadbackRing::new(2)?,
        rng: SplitMix64::new(7),
        focus: (0.0, 0.0),
        falloff: 12.0,
        handles,
        tlas: Vec::new(),
    })
}

impl Rig {
    /// Hits per frame of cell (i, j): 2000 at the focus, halving every
    /// `falloff` metres (12 m).
    fn heat(&mut self, x: f32, z: f32) -> u32 {
        let d = ((x - self.focus.0).powi(2) + (z - self.focus.1).powi(2)).sqrt();
        let h = 2000.0 * 0.5f32.powf(d / self.falloff);
        (h * self.rng.range_f32(0.9, 1.1)) as u32
    }

    /// One frame; returns the controlled bytes after the plan.
    fn frame(&mut self, f: u64) -> Result<u64, ManagerError> {
        let m = &mut self.manager;
        m.begin_frame(f)?;
        while let Some(r) = self.ring.pop_ready(f) {
            m.ingest_readback(r.frame, r.counter, &r.words);
        }
        let plan = m.plan(&FrameBudgets::default())?;
        for (i, b) in plan.blas.builds().enumerate() {
            m.handle_ack(Ack::Built {
                build: b.id,
                result_bytes: b.result_bytes,
                address: 0x10_0000 + (f << 12) + i as u64 * 0x100,
            })?;
        }
        let bytes = m.controlled_bytes();
        let mut tlas = std::mem::take(&mut self.tlas);
        self.manager.assemble(&mut tlas)?;
        for t in &tlas {
            let i = t.custom_index();
            if t.acceleration_structure_reference == UNIT_CUBE {
                // A hitbox's counting box: the heat of its cell.
                let (x, z) = ((i % N) as f32 * CELL + 4.0, (i / N) as f32 * CELL + 4.0);
                let h = self.heat(x, z);
                self.manager.hitboxes_mut()[i as usize].add_hits(h);
            } else {
                let (x, z) = ((i % N) as f32 * CELL + 4.0, (i / N) as f32 * CELL + 4.0);
                let h = self.heat(x, z);
                self.manager.instance_hits_mut()[i as usize] += h;
            }
        }
        self.tlas = tlas;
        self.manager.process_feedback()?;
        let r = self.manager.take_commands().expect("feedback ran");
        self.ring.push(r).map_err(|e| ManagerError::InvalidConfig {
            what: e.to_string(),
        })?;
        Ok(bytes)
    }
}

/// Memory per frame over `frames` frames, the focus jumping at `jump`.
fn run(rig: &mut Rig, frames: u64, jump: u64) -> Result<Vec<u64>, ManagerError> {
    let mut out = Vec::new();
    for f in 0..frames {
        if f == jump {
            rig.focus = (N as f32 * CELL, N as f32 * CELL);
        }
        out.push(rig.frame(f)?);
        // The thresholds Algorithm 2 ran with (and a GPU backend uploads,
        // lipac-vk reads `culling_config().thresholds` when it records the
        // frame) are the configured ones scaled by the controller.
        let s = rig.manager.stats();
        if let Some(c) = s.controller {
            assert_eq!(
                rig.manager.thresholds(),
                base_thresholds().scaled(c.scale).unwrap()
            );
            assert_eq!(
                rig.manager.thresholds(),
                rig.manager.culling_config().thresholds
            );
        }
    }
    Ok(out)
}

#[test]
fn without_a_target_the_thresholds_stay() -> Result<(), ManagerError> {
    let mut r = rig(None)?;
    let m = run(&mut r, 80, u64::MAX)?;
    assert_eq!(r.manager.thresholds(), base_thresholds());
    assert!(r.manager.stats().controller.is_none());
    let e = r
        .manager
        .stats()
        .escape
        .expect("process_feedback samples the hits");
    assert!(e.total_hits > 0 && e.box_hits <= e.total_hits);
    assert!(m[79] > m[0], "instances activated: {} -> {}", m[0], m[79]);
    Ok(())
}

#[test]
fn a_memory_budget_is_held_through_a_camera_jump() -> Result<(), ManagerError> {
    // Uncontrolled, the focus activates a few dozen instances; the budget
    // is below that.
    let mut free = rig(None)?;
    let open = run(&mut free, 150, u64::MAX)?;
    let floor = open[0];
    let uncontrolled = open[149];
    let budget = floor + (uncontrolled - floor) / 2;

    let mut r = rig(Some(ControlTarget::MemoryBudget { bytes: budget }))?;
    let m = run(&mut r, 700, 350)?;
    let stats = r.manager.stats();
    let c = stats.controller.unwrap();
    assert!(c.scale > 1.0, "over budget: the thresholds rose ({c:?})");
    assert!(!c.unreachable, "{c:?}");
    let off = |v: &[u64]| {
        v.iter()
            .map(|&b| (b as f64 / budget as f64 - 1.0).abs())
            .fold(0.0, f64::max)
    };
    // Within 5 % after warm-up, and again after the jump.
    assert!(
        off(&m[200..350]) <= 0.05,
        "before the jump: {:.3}",
        off(&m[200..350])
    );
    assert!(
        off(&m[550..]) <= 0.05,
        "after the jump: {:.3}",
        off(&m[550..])
    );
    // Nothing lost: every instance the Manager holds active has its BLAS,
    // no command waits, no build is in flight.
    assert_eq!(stats.commands_pending, 0);
    assert_eq!(stats.builds_in_flight, 0);
    assert_eq!(
        stats.instances.active, stats.instances.with_blas,
        "{stats:?}"
    );
    Ok(())
}

#[test]
fn an_unreachable_budget_is_reported_and_held() -> Result<(), ManagerError> {
    // Below the hitbox records and counters alone.
    let mut r = rig(Some(ControlTarget::MemoryBudget { bytes: 1000 }))?;
    let m = run(&mut r, 300, u64::MAX)?;
    let c = r.manager.stats().controller.unwrap();
    assert!(c.unreachable && c.saturated, "{c:?}");
    assert_eq!(c.scale, ControllerConfig::default().max_scale);
    assert_eq!(c.reversals, 0, "straight to the bound: {c:?}");
    // The best it can do: nothing but the hottest cells stays active.
    assert!(m[299] <= m[0] + 4 * BLAS_BYTES, "{} vs {}", m[299], m[0]);
    Ok(())
}

#[test]
fn an_escape_target_moves_the_thresholds() -> Result<(), ManagerError> {
    let mut r = rig(Some(ControlTarget::EscapeFraction { fraction: 0.05 }))?;
    run(&mut r, 400, u64::MAX)?;
    let s = r.manager.stats();
    let c = s.controller.unwrap();
    assert!(
        c.scale < 1.0,
        "too many escaped: the thresholds fell ({c:?})"
    );
    let e = s.escape.unwrap();
    let f = e.box_hits as f64 / e.total_hits as f64;
    assert!(f < 0.2, "escape fraction {f}");
    Ok(())
}

#[test]
fn bad_targets_are_configuration_errors() {
    for t in [
        ControlTarget::MemoryBudget { bytes: 0 },
        ControlTarget::EscapeFraction { fraction: f64::NAN },
        ControlTarget::EscapeFraction { fraction: -0.1 },
        ControlTarget::EscapeFraction { fraction: 1.0 },
    ] {
        match rig(Some(t)) {
            Err(ManagerError::InvalidConfig { what }) => assert!(what.contains("target"), "{what}"),
            other => panic!("{t:?}: {:?}", other.err()),
        }
    }
    // A scale range whose top overflows the 24-bit hit counters.
    let grid = HitboxGrid::new(GridConfig {
        min: [0.0, 0.0],
        max: [8.0, 8.0],
        cell_size: 8.0,
    })
    .unwrap();
    let mut c = config(Some(ControlTarget::MemoryBudget { bytes: 1 << 20 }));
    c.controller.max_scale = 1e6;
    match Manager::new(grid, c, MeshCatalog::new()) {
        Err(ManagerError::InvalidConfig { what }) => assert!(what.contains("scaled by"), "{what}"),
        other => panic!("{:?}", other.err()),
    }
}

/// Largest `memory / budget − 1` of `v` (an overrun; negative: under).
fn overrun(v: &[u64], budget: u64) -> f64 {
    v.iter()
        .map(|&b| b as f64 / budget as f64 - 1.0)
        .fold(f64::NEG_INFINITY, f64::max)
}

#[test]
fn evicting_cached_blases_over_budget_cuts_the_jump_overshoot() -> Result<(), ManagerError> {
    let mut free = rig(None)?;
    let open = run(&mut free, 150, u64::MAX)?;
    let budget = open[0] + (open[149] - open[0]) / 2;
    let target = Some(ControlTarget::MemoryBudget { bytes: budget });
    let mut with = rig(target)?;
    let a = run(&mut with, 700, 350)?;
    let mut c = config(target);
    c.controller.evict_cached_over_budget = false;
    let mut without = rig_with(c)?;
    let b = run(&mut without, 700, 350)?;
    let (ca, cb) = (
        with.manager.stats().controller.unwrap(),
        without.manager.stats().controller.unwrap(),
    );
    // The old view's BLASes leave the cache as soon as memory is over the
    // budget, not after the retention (8 frames): the overshoot after the
    // jump falls (measured 0.36 against 0.65 of the budget), and the
    // budget is held as well before and long after it.
    let (jump_with, jump_without) = (overrun(&a[350..550], budget), overrun(&b[350..550], budget));
    assert!(
        jump_with < 0.75 * jump_without,
        "with eviction {jump_with:.3}, without {jump_without:.3}"
    );
    assert!(ca.evicting_frames > 0 && ca.evicted > 0, "{ca:?}");
    assert_eq!((cb.evicting_frames, cb.evicted), (0, 0), "{cb:?}");
    assert!(overrun(&a[200..350], budget) <= 0.05 && overrun(&a[550..], budget) <= 0.05);
    // Nothing lost: evicted BLASes were unused; what is active has its BLAS.
    let stats = with.manager.stats();
    assert_eq!(
        stats.instances.active, stats.instances.with_blas,
        "{stats:?}"
    );
    assert_eq!(stats.commands_pending, 0);
    Ok(())
}

/// Memory per frame over `frames` frames of a camera that pulls back at
/// `at`: the same focus, heat spread twice as far (more instances hot), and
/// every instance asks for LOD 1 (a quarter of the bytes).
fn pull_back(rig: &mut Rig, frames: u64, at: u64) -> Result<Vec<u64>, ManagerError> {
    let mut out = Vec::new();
    for f in 0..frames {
        if f == at {
            rig.falloff = 24.0;
            for h in rig.handles.clone() {
                rig.manager.set_lod(h, 1)?;
            }
        }
        out.push(rig.frame(f)?);
    }
    Ok(out)
}

#[test]
fn coarser_lods_at_the_budget_hold_it_through_a_pull_back() -> Result<(), ManagerError> {
    const LODS: [u64; 2] = [BLAS_BYTES, BLAS_BYTES / 4];
    let lod_config = |target, coarsen| {
        let mut c = config(target);
        c.scheduler.lod_hysteresis_frames = 16;
        c.controller.coarsen_over_budget = coarsen;
        c
    };
    let mut free = rig_lods(lod_config(None, true), &LODS)?;
    let open = pull_back(&mut free, 300, u64::MAX)?;
    let budget = open[0] + (open[299] - open[0]) / 2;
    let target = Some(ControlTarget::MemoryBudget { bytes: budget });
    let mut with = rig_lods(lod_config(target, true), &LODS)?;
    let a = pull_back(&mut with, 500, 300)?;
    let mut without = rig_lods(lod_config(target, false), &LODS)?;
    let b = pull_back(&mut without, 500, 300)?;
    let (ca, cb) = (
        with.manager.stats().controller.unwrap(),
        without.manager.stats().controller.unwrap(),
    );
    // Without the lever the held instances keep LOD 0 for the hysteresis
    // while the newly hot ones arrive: over the budget by more than 5 % for
    // most of it (measured: about 10 frames at +25 %). With it they switch at
    // once; what remains is the one frame whose acknowledgements bring the
    // coarser BLASes while the finer ones wait in the cache for the next
    // frame's eviction (allocate before free). Within 5 % before and after.
    let over5 = |v: &[u64]| {
        v.iter()
            .filter(|&&m| m as f64 > 1.05 * budget as f64)
            .count()
    };
    let (n_with, n_without) = (over5(&a[300..]), over5(&b[300..]));
    assert!(n_without >= 8, "without the lever {n_without} frames over");
    assert!(n_with <= 1, "with the lever {n_with} frames over");
    assert!(overrun(&a[303..], budget) <= 0.05, "{:?}", &a[300..310]);
    assert!(overrun(&a[200..300], budget) <= 0.05);
    let (over_with, over_without) = (overrun(&a[300..], budget), overrun(&b[300..], budget));
    assert!(ca.coarsening_frames > 0 && ca.coarsened > 0, "{ca:?}");
    assert_eq!((cb.coarsening_frames, cb.coarsened), (0, 0), "{cb:?}");
    assert!(ca.reversals <= cb.reversals + 2, "{ca:?} vs {cb:?}");
    // Nothing lost: every active instance has its BLAS, no command or
    // build waits.
    let stats = with.manager.stats();
    assert_eq!(stats.commands_pending, 0);
    assert_eq!(stats.builds_in_flight, 0);
    assert_eq!(
        stats.instances.active, stats.instances.with_blas,
        "{stats:?}"
    );
    println!(
        "pull back: overrun with {over_with:.3}, without {over_without:.3}; {ca:?}; memory {} -> {}",
        a[299], a[499]
    );
    Ok(())
}
