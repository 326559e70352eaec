//! Soak test of the `Manager`: 100 000 frames of random register / remove /
//! LOD / move churn with random hits driving Algorithm 2, latency mitigation
//! on a wandering frustum, acknowledgements arriving 0–3 frames late and
//! budgets that bind (commands, builds, scratch, BLAS memory). Invariants are
//! checked every frame (TLAS and frees against the backend's live
//! structures) and every few frames (records, scheduler, data ranges,
//! budgets). At the end, removing everything and advancing past the frames
//! in flight must leave zero bytes allocated and no handle leaked.

use lipac_core::blas_cache::CacheConfig;
use lipac_core::blas_ids::InstanceKey;
use lipac_core::build_plan::{
    BuildBudgets, BuildEstimate, PriorityConfig, SchedulerConfig, SchedulerStats,
};
use lipac_core::culling::ReadbackRing;
use lipac_core::instance::MeshId;
use lipac_core::latency::ActivationHeuristic;
use lipac_core::layout::TlasInstance;
use lipac_core::manager::{DataConfig, FrameBudgets, Manager, ManagerConfig, MeshCatalog, MeshLod};
use lipac_core::registry::InstanceHandle;
use lipac_core::thresholds::Thresholds;
use lipac_test_support::scene::{frustums, random_instance, world_grid};
use lipac_test_support::synthetic::{LateAcks, SyntheticDevice};
use lipac_test_support::{Rng64, XorShift64Star as Rng};

const CUBE: u64 = 0xC0BE;
const MESHES: u32 = 5;
const LODS: u32 = 3;
const MAX_LIVE: usize = 48;
const BLAS_BUDGET: u64 = 200_000;
const FRAMES_IN_FLIGHT: u32 = 2;

fn mesh_lod(mesh: u32, lod: u32) -> MeshLod {
    let tris = u64::from(400 + 300 * mesh) >> lod;
    MeshLod {
        estimate: BuildEstimate {
            primitives: tris,
            result_bytes: tris * 40,
            build_scratch_bytes: tris * 8,
            update_scratch_bytes: tris * 2,
        },
        data_bytes: 16 + 24 * u64::from(mesh + 1) * u64::from(LODS - lod),
    }
}

/// Everything that must hold between frames.
fn check_invariants(m: &Manager, be: &SyntheticDevice, live: &[InstanceHandle]) {
    let reg = m.registry();
    assert_eq!(reg.len(), live.len());
    let mut data_bytes = 0;
    for &h in live {
        let v = m.instance(h).unwrap();
        let record = reg.record(h).unwrap();
        let mesh = reg.mesh(h).unwrap();
        let key = InstanceKey(v.slot);
        // The scheduler knows exactly the instances holding or awaiting a BLAS.
        assert_eq!(
            v.scheduled,
            v.blas != 0 || v.awaiting_blas,
            "slot {}",
            v.slot
        );
        assert_eq!(
            m.scheduler().blas_address(key).is_some() || m.scheduler().pending_lod(key).is_some(),
            v.scheduled
        );
        if v.blas != 0 {
            assert_eq!(m.scheduler().blas_address(key), Some(v.blas));
            assert!(be.live.contains_key(&v.blas), "record holds a dead BLAS");
            assert_eq!(
                m.scheduler().current_lod(key).map(|l| u32::from(l.0)),
                Some(v.traced_lod),
                "record LOD differs from its BLAS's"
            );
        } else {
            assert_eq!(v.traced_lod, v.requested_lod);
        }
        assert_eq!(record.lod, v.traced_lod);
        let bytes = mesh_lod(mesh.0, v.traced_lod).data_bytes;
        assert_eq!(
            v.data.end - v.data.start,
            bytes,
            "data range follows the traced LOD"
        );
        assert!(v.data.end <= be.data_capacity);
        data_bytes += bytes;
    }
    let st = m.stats();
    assert_eq!(st.memory.data_used, data_bytes);
    assert_eq!(st.data_ranges, live.len());
    assert_eq!(st.instances.live, live.len());
    assert_eq!(
        m.scheduler().stats().instances,
        st.instances.scheduled,
        "scheduler knows an instance the manager does not"
    );
    let blas = st.memory.blas_shared + st.memory.blas_unique + st.memory.blas_compacted;
    assert!(blas <= BLAS_BUDGET, "BLAS budget broken: {blas}");
}

/// Returns the scheduler's statistics before the teardown, builds and
/// compactions handed out, and the most instances traced with a BLAS at once.
fn soak(seed: u64, frames: u64) -> (SchedulerStats, u64, u64, usize) {
    let mut rng = Rng::new(seed | 1);
    let grid = world_grid();
    let mut config = ManagerConfig::new(CUBE);
    config.culling.thresholds = Thresholds {
        theta_a: 400,
        theta_d: 60,
        sigma_a: 300,
        sigma_o: 40,
        n_a: 2,
        n_d: 4,
        ..Thresholds::paper()
    };
    config.culling.command_capacity = 12; // overflows now and then
    config.culling.readback_latency = 2;
    config.culling.latency_mitigation = Some(ActivationHeuristic {
        max_distance: 60.0,
        min_projected_size: 0.0,
        surround_radius: 0.0,
    });
    config.scheduler = SchedulerConfig {
        cache: CacheConfig {
            memory_budget: BLAS_BUDGET,
            frames_in_flight: FRAMES_IN_FLIGHT,
            max_unused_frames: 30,
        },
        scratch_alignment: 64,
        unique_rebuild_interval: 5,
        lod_hysteresis_frames: 3,
        priority: PriorityConfig::default(),
    };
    config.data = DataConfig {
        initial_capacity: 256,
        alignment: 16,
    };
    let meshes: Vec<(MeshId, u32)> = (0..MESHES).map(|m| (MeshId(m), LODS)).collect();
    let mut catalog = MeshCatalog::new();
    for mesh in 0..MESHES {
        catalog
            .insert(MeshId(mesh), (0..LODS).map(|l| mesh_lod(mesh, l)).collect())
            .unwrap();
    }
    let mut m = Manager::new(grid, config, catalog).unwrap();
    let mut ring = ReadbackRing::new(2).unwrap();
    // Acknowledgements arrive 0–3 frames late (see `LateAcks`).
    let mut be = LateAcks::new(FRAMES_IN_FLIGHT, 256);
    let frustums = frustums();
    let mut live: Vec<InstanceHandle> = Vec::with_capacity(MAX_LIVE);
    let mut tlas: Vec<TlasInstance> = Vec::new();
    let hitbox_count = m.hitboxes().len();
    // Per hitbox: how many rays its region attracts (a random walk).
    let mut heat: Vec<u32> = (0..hitbox_count).map(|_| rng.below(800) as u32).collect();
    let mut max_active = 0;

    for f in 1..=frames {
        m.begin_frame(f).unwrap();
        be.deliver(&mut m, f, &mut rng, false);
        while let Some(r) = ring.pop_ready(f) {
            m.ingest_readback(r.frame, r.counter, &r.words);
        }
        // Churn.
        for _ in 0..rng.below(3) {
            match rng.below(10) {
                0..=2 if live.len() < MAX_LIVE => {
                    live.push(m.register(random_instance(&mut rng, &meshes)).unwrap());
                }
                0..=3 if !live.is_empty() => {
                    let i = rng.below(live.len() as u64) as usize;
                    m.remove(live.swap_remove(i)).unwrap();
                }
                4..=6 if !live.is_empty() => {
                    let h = live[rng.below(live.len() as u64) as usize];
                    m.set_lod(h, rng.below(u64::from(LODS)) as u32).unwrap();
                }
                7 if !live.is_empty() => {
                    let h = live[rng.below(live.len() as u64) as usize];
                    let d = random_instance(&mut rng, &meshes);
                    m.set_transform(h, d.transform, d.aabb).unwrap();
                }
                _ => {}
            }
        }
        if f % 4 == 0 {
            let (eye, fr) = &frustums[rng.below(3) as usize];
            m.mitigate_latency(*eye, fr).unwrap();
        }
        let budgets = FrameBudgets {
            commands: 1 + rng.below(6) as usize,
            builds: BuildBudgets {
                max_builds: 1 + rng.below(3) as u32,
                max_primitives: 3000,
                max_result_bytes: 60_000,
                max_scratch_bytes: 12_000,
                max_batches: 1 + rng.below(2) as u32,
                max_compactions: 2,
            },
        };
        let plan = m.plan(&budgets).unwrap();
        be.execute(&plan, &mut rng);
        be.deliver(&mut m, f, &mut rng, false);

        // TLAS and trace.
        m.assemble(&mut tlas).unwrap();
        for h in heat.iter_mut() {
            let step = rng.below(161) as i64 - 80;
            *h = (i64::from(*h) + step).clamp(0, 1500) as u32;
        }
        let mut active = 0;
        for t in &tlas {
            let i = t.custom_index() as usize;
            let address = t.acceleration_structure_reference;
            if address == CUBE {
                if i < hitbox_count {
                    let hits = rng.below(u64::from(heat[i]) + 1) as u32;
                    m.hitboxes_mut()[i].add_hits(hits);
                } else {
                    m.instance_hits_mut()[i] += rng.below(500) as u32;
                }
            } else {
                be.device.traced(address, f);
                active += 1;
                m.instance_hits_mut()[i] += rng.below(800) as u32;
            }
        }
        max_active = max_active.max(active);
        m.process_feedback().unwrap();
        ring.push(m.take_commands().unwrap()).unwrap();
        if f % 7 == 0 {
            check_invariants(&m, &be.device, &live);
        }
    }
    check_invariants(&m, &be.device, &live);
    let churn = m.scheduler().stats();
    assert!(max_active > 0, "nothing was ever traced with its BLAS");

    // Remove everything; let every acknowledgement arrive and every frame
    // in flight pass.
    for h in live.drain(..) {
        m.remove(h).unwrap();
    }
    let mut f = frames;
    while !be.queue.is_empty() || m.stats().builds_in_flight > 0 {
        f += 1;
        m.begin_frame(f).unwrap();
        be.deliver(&mut m, f + 10, &mut rng, true);
        while let Some(r) = ring.pop_ready(f) {
            m.ingest_readback(r.frame, r.counter, &r.words);
        }
        let plan = m.plan(&FrameBudgets::default()).unwrap();
        be.execute(&plan, &mut rng);
        m.assemble(&mut tlas).unwrap();
        m.process_feedback().unwrap();
        ring.push(m.take_commands().unwrap()).unwrap();
        assert!(f < frames + 100, "operations never settle");
    }
    m.trim_blas_cache();
    for _ in 0..=FRAMES_IN_FLIGHT + 4 {
        f += 1;
        m.begin_frame(f).unwrap();
        while let Some(r) = ring.pop_ready(f) {
            m.ingest_readback(r.frame, r.counter, &r.words);
        }
        let plan = m.plan(&FrameBudgets::default()).unwrap();
        assert_eq!(plan.blas.builds().count() + plan.blas.compactions.len(), 0);
        be.execute(&plan, &mut rng);
        m.assemble(&mut tlas).unwrap();
        assert!(tlas
            .iter()
            .all(|t| t.acceleration_structure_reference == CUBE));
        m.process_feedback().unwrap();
        ring.push(m.take_commands().unwrap()).unwrap();
    }

    let st = m.stats();
    let data = m.data_allocator().stats();
    assert_eq!(data.used_bytes, 0, "geometry data leaked");
    assert_eq!(data.allocation_count, 0);
    assert_eq!(data.free_block_count, 1, "free space not merged back");
    assert_eq!(data.largest_free_block, data.capacity);
    assert_eq!(
        st.memory.blas_shared + st.memory.blas_unique + st.memory.blas_compacted,
        0
    );
    assert_eq!(st.memory.blas_scratch, 0);
    assert_eq!(st.blas_entries, 0, "BLAS cache entries leaked");
    assert_eq!((st.blas_pending_frees, st.memory.blas_pending_free), (0, 0));
    assert_eq!((st.builds_queued, st.builds_in_flight), (0, 0));
    assert!(m.registry().is_empty(), "instances leaked");
    assert_eq!(st.commands_pending, 0, "commands leaked");
    assert_eq!(
        m.scheduler().stats().instances,
        0,
        "scheduler instances leaked"
    );
    assert_eq!(st.instances.scheduled + st.instances.with_blas, 0);
    let dev = &be.device;
    assert!(
        dev.live.is_empty(),
        "structures never freed: {}",
        dev.live.len()
    );
    (churn, dev.builds, dev.compactions, max_active)
}

#[test]
fn manager_soak_100k_frames() {
    let (st, builds, compactions, max_active) = soak(0x5eed, 100_000);
    // The churn exercised the paths it is meant to.
    assert!(builds > 1000, "{builds} builds");
    assert!(compactions > 100, "{compactions} compactions");
    assert!(
        max_active > 5,
        "at most {max_active} instances traced at once"
    );
    assert!(
        st.cache.evictions > 100,
        "the BLAS memory budget never bound: {st:?}"
    );
    assert!(
        st.instant_switches > 100 && st.built_switches > 100,
        "{st:?}"
    );
    assert!(st.cache.hits > 0 && st.cache.misses > 0, "{st:?}");
}

#[test]
fn manager_soak_other_seeds() {
    for seed in [1, 42, 1234] {
        soak(seed, 3000);
    }
}
