//! `BuildScheduler::waiting_instances` lists exactly the instances with a
//! `pending_lod` (what `Manager::plan` now iterates instead of every slot),
//! through activations, cached assignments, LOD requests, acknowledgements
//! and deactivations.

use lipac_core::blas_ids::{InstanceKey, Lod};
use lipac_core::build_plan::{BlasGeometry, BuildScheduler, InstanceBlasRequest, SchedulerConfig};
use lipac_core::{Ack, BuildBudgets, BuildEstimate, MeshId};
use lipac_test_support::synthetic::AckSink;
use lipac_test_support::{Rng64, SplitMix64};
use std::collections::BTreeSet;

fn estimate(t: u64) -> BuildEstimate {
    BuildEstimate {
        primitives: t,
        result_bytes: t * 64,
        build_scratch_bytes: t * 16,
        update_scratch_bytes: t * 4,
    }
}

fn check(s: &BuildScheduler, keys: u32) -> usize {
    let listed: Vec<InstanceKey> = s.waiting_instances().collect();
    let set: BTreeSet<InstanceKey> = listed.iter().copied().collect();
    assert_eq!(set.len(), listed.len(), "an instance listed twice");
    let pending: BTreeSet<InstanceKey> = (0..keys)
        .map(InstanceKey)
        .filter(|&k| s.pending_lod(k).is_some())
        .collect();
    assert_eq!(set, pending);
    set.len()
}

#[test]
fn waiting_instances_are_the_ones_with_a_pending_lod() {
    let mut s = BuildScheduler::new(SchedulerConfig {
        lod_hysteresis_frames: 0,
        ..SchedulerConfig::default()
    })
    .unwrap();
    let mut rng = SplitMix64::new(7);
    let keys = 64u32;
    let mut active = BTreeSet::new();
    let mut acks = Vec::new();
    let mut max_waiting = 0;
    for frame in 0..40u64 {
        s.begin_frame(frame).unwrap();
        for ack in acks.drain(..) {
            s.ack(ack).unwrap();
        }
        for _ in 0..12 {
            let k = InstanceKey((rng.next_u64() % u64::from(keys)) as u32);
            let mesh = MeshId((rng.next_u64() % 4) as u32);
            let lod = Lod((rng.next_u64() % 2) as u8);
            match rng.next_u64() % 3 {
                0 if !active.contains(&k) => {
                    let geometry = if k.0 % 5 == 0 {
                        BlasGeometry::Unique { mesh }
                    } else {
                        BlasGeometry::Shared {
                            mesh,
                            variant: 0,
                            compactable: false,
                        }
                    };
                    let request = InstanceBlasRequest {
                        geometry,
                        lod,
                        estimate: estimate(100 + u64::from(lod.0) * 50),
                        hits: 1,
                        in_frustum: false,
                    };
                    s.activate(k, request).unwrap();
                    active.insert(k);
                }
                1 if active.contains(&k) => {
                    s.request_lod(k, lod, estimate(100 + u64::from(lod.0) * 50))
                        .unwrap();
                }
                2 if active.contains(&k) => {
                    s.deactivate(k).unwrap();
                    active.remove(&k);
                }
                _ => {}
            }
            max_waiting = max_waiting.max(check(&s, keys));
        }
        let budgets = BuildBudgets {
            max_builds: 3,
            ..BuildBudgets::default()
        };
        let plan = s.plan(&budgets).unwrap();
        for (i, b) in plan.builds().enumerate() {
            acks.push(Ack::Built {
                build: b.id,
                result_bytes: b.result_bytes,
                address: 0x1000 * (frame + 1) + i as u64,
            });
        }
        check(&s, keys);
    }
    assert!(
        max_waiting >= 3,
        "too few waiting instances to test: {max_waiting}"
    );
}
