//! Soak test of the BLAS cache and build scheduler against a simulated
//! backend: random activation / deactivation / LOD / feedback churn with
//! acknowledgements arriving 0–3 frames late. Invariants checked every frame:
//! the memory budget holds, every address handed to the TLAS, to an update or
//! to a compaction is a live acceleration structure, and every free names a
//! live structure not used by any frame still in flight. At the end,
//! releasing everything and advancing the frames in flight leaves zero bytes
//! and no entries.

use std::collections::BTreeSet;

use lipac_core::blas_cache::CacheConfig;
use lipac_core::blas_ids::{InstanceKey, Lod};
use lipac_core::build_plan::*;
use lipac_core::MeshId;
use lipac_test_support::synthetic::LateAcks;
use lipac_test_support::{Rng64, XorShift64Star as Rng};
use proptest::prelude::*;

fn estimate(mesh: u32, lod: u8) -> BuildEstimate {
    let result = (1000 + u64::from(mesh) * 137) >> lod;
    BuildEstimate {
        primitives: result / 10,
        result_bytes: result.max(1),
        build_scratch_bytes: result / 2,
        update_scratch_bytes: result / 8,
    }
}

fn geometry(key: u32) -> (BlasGeometry, u32) {
    let mesh = key % 7;
    if key % 5 == 0 {
        (BlasGeometry::Unique { mesh: MeshId(mesh) }, mesh)
    } else {
        (
            BlasGeometry::Shared {
                mesh: MeshId(mesh),
                variant: key % 2,
                compactable: mesh % 2 == 0,
            },
            mesh,
        )
    }
}

/// Runs the soak; returns the statistics before the final release and the
/// number of compactions handed out.
fn soak(seed: u64, frames: u64, fif: u32) -> (SchedulerStats, usize) {
    let mut rng = Rng::new(seed | 1);
    let budget = 12_000;
    let mut s = BuildScheduler::new(SchedulerConfig {
        cache: CacheConfig {
            memory_budget: budget,
            frames_in_flight: fif,
            max_unused_frames: 20,
        },
        scratch_alignment: 64,
        unique_rebuild_interval: 4,
        lod_hysteresis_frames: 3,
        priority: PriorityConfig::default(),
    })
    .unwrap();
    // Acknowledgements arrive 0–3 frames late, compactions 0–2.
    let mut be = LateAcks::new(fif, 0);
    be.compaction_delay = 3;
    let mut active: BTreeSet<u32> = BTreeSet::new();
    for f in 1..=frames {
        s.begin_frame(f).unwrap();
        be.deliver(&mut s, f, &mut rng, false);
        for _ in 0..rng.below(6) {
            let k = rng.below(40) as u32;
            let inst = InstanceKey(k);
            let (g, mesh) = geometry(k);
            let lod = rng.below(3) as u8;
            if active.contains(&k) {
                match rng.below(4) {
                    0 => {
                        s.deactivate(inst).unwrap();
                        active.remove(&k);
                    }
                    1 => s
                        .set_feedback(inst, rng.below(2000) as u32, rng.below(2) == 0)
                        .unwrap(),
                    _ => s.request_lod(inst, Lod(lod), estimate(mesh, lod)).unwrap(),
                }
            } else {
                let r = InstanceBlasRequest {
                    geometry: g,
                    lod: Lod(lod),
                    estimate: estimate(mesh, lod),
                    hits: rng.below(500) as u32,
                    in_frustum: rng.below(2) == 0,
                };
                s.activate(inst, r).unwrap();
                active.insert(k);
            }
        }
        let budgets = BuildBudgets {
            max_builds: 1 + rng.below(6) as u32,
            max_primitives: 400,
            max_result_bytes: 6000,
            max_scratch_bytes: 1500,
            max_batches: 1 + rng.below(2) as u32,
            max_compactions: 2,
        };
        let plan = s.plan(&budgets).unwrap();
        be.execute_blas(&plan, &mut rng);
        be.deliver(&mut s, f, &mut rng, false);
        assert!(
            s.cache().live_bytes() <= budget,
            "budget broken at frame {f}"
        );
        // TLAS assembly for this frame.
        for &k in &active {
            if let Some(addr) = s.blas_address(InstanceKey(k)) {
                be.device.traced(addr, f);
            }
        }
        s.take_address_changes();
    }

    let churn = s.stats();
    let compactions = be.device.compactions as usize;

    // Release everything, let all acknowledgements arrive.
    let mut f = frames;
    for &k in &active {
        s.deactivate(InstanceKey(k)).unwrap();
    }
    while !be.queue.is_empty() || s.stats().in_flight > 0 {
        f += 1;
        s.begin_frame(f).unwrap();
        be.deliver(&mut s, f + 10, &mut rng, true);
        let plan = s.plan(&BuildBudgets::default()).unwrap();
        be.execute_blas(&plan, &mut rng);
        assert!(f < frames + 100, "operations never settle");
    }
    s.trim_cache();
    for _ in 0..=fif {
        f += 1;
        s.begin_frame(f).unwrap();
        let plan = s.plan(&BuildBudgets::default()).unwrap();
        assert!(plan.batches.is_empty() && plan.compactions.is_empty());
        be.execute_blas(&plan, &mut rng);
    }
    let st = s.stats();
    assert_eq!(st.cache.live_bytes(), 0);
    assert_eq!(st.cache.scratch_in_use, 0);
    assert_eq!(st.cache.entries, 0, "entries leaked");
    assert_eq!(st.cache.pending_frees, 0);
    assert_eq!(st.cache.pending_free_bytes, 0);
    assert_eq!((st.queued_builds, st.in_flight, st.instances), (0, 0, 0));
    let live = &be.device.live;
    assert!(live.is_empty(), "structures never freed: {live:?}");
    (churn, compactions)
}

#[test]
fn soak_fixed_seeds() {
    for (seed, fif) in [(1, 2), (7, 0), (42, 3), (1234, 1)] {
        let (st, compactions) = soak(seed, 400, fif);
        // The churn exercised every path.
        assert!(st.cache.hits > 0 && st.cache.misses > 0, "{st:?}");
        assert!(st.cache.evictions > 0, "{st:?}");
        assert!(st.instant_switches > 0 && st.built_switches > 0, "{st:?}");
        assert!(compactions > 0);
    }
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 24, ..ProptestConfig::default() })]
    #[test]
    fn soak_random(seed in any::<u64>(), fif in 0u32..4) {
        soak(seed, 150, fif);
    }
}
