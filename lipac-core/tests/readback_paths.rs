//! One read-back semantics, whatever the backend: CPU or GPU.
//!
//! Two managers run the same scene, hits and engine calls. Manager A is a
//! CPU backend: it traces, runs Algorithm 2 ([`Manager::process_feedback`],
//! which changes its records' state bits) and takes the commands
//! ([`Manager::take_commands`]); to those words the "GPU" adds injected ones
//! (slots of removed and of reused instances, slots beyond the registry,
//! either kind, any priority) and a counter that may exceed the stored words
//! (overflow), and A reads them back through a [`ReadbackRing`]. Manager B is
//! a GPU backend: it never runs Algorithm 2 (its records' state bits are
//! never changed by feedback, as where the GPU owns them), gets the same raw
//! `(frame, counter, words)` at the same frames, as a GPU backend hands its
//! read-back buffer to [`Manager::ingest_readback`], and with them that
//! frame's hit counters ([`Manager::record_hits`]; A's own feedback hits
//! become its build priorities at the same point). Latency mitigation runs
//! in both with the same cameras. Checked every frame:
//!
//! * both ingest the same way and make the same decisions: ingest summaries,
//!   latency-mitigation requests, plans, instance views (commanded states,
//!   BLASes, pending builds);
//! * the GPU-side queue (`CommandQueue::ingest`, what lipac-vk's
//!   `Readback::ingest_into` feeds) keeps, for every live slot the words
//!   name, exactly the command the manager keeps (the newest), and the
//!   manager keeps none for dead slots;
//! * after planning, an instance whose BLAS disagrees with its commanded
//!   state (active without a BLAS or a pending build, or not active with
//!   one) has a command pending or in flight in the ring.

use std::collections::VecDeque;

use glam::{Affine3A, Vec3};
use lipac_core::command::{Command, CommandKind, CommandQueue};
use lipac_core::latency::{ActivationHeuristic, Frustum};
use lipac_core::layout::MAX_SLOTS;
use lipac_core::{
    Aabb, Ack, BuildEstimate, FrameBudgets, GridConfig, HitboxGrid, IngestSummary, InstanceDesc,
    InstanceFlags, InstanceHandle, InstanceState, Manager, ManagerConfig, MeshCatalog, MeshId,
    MeshLod, Readback, ReadbackRing,
};
use lipac_test_support::synthetic::ImmediateAcks;
use proptest::prelude::*;

const CUBE: u64 = 0xC0BE;
const LATENCY: u32 = 2;

/// A word the "GPU" adds to a frame's read-back.
#[derive(Clone, Copy, Debug)]
struct Injected {
    /// Raw slot (beyond the registry's slots it is rejected).
    slot: u32,
    remove: bool,
    priority: u8,
}

/// What happens in one frame.
#[derive(Clone, Debug, Default)]
struct FrameOps {
    /// Hot hitbox cells (bit `i` = cell `i` of the 4 x 4 grid).
    hot: u16,
    /// New instances: (cell, unique BLAS).
    register: Vec<(u8, bool)>,
    /// Live instances to remove (index into the live list, modulo its
    /// length).
    remove: Vec<usize>,
    injected: Vec<Injected>,
    /// Requests the buffer did not store (counter - words).
    overflow: u32,
    /// Commands processed this frame (`None` = no limit).
    budget: Option<usize>,
    /// Latency mitigation with camera `i` of [`cameras`] (`None` = skipped).
    camera: Option<usize>,
}

/// Three cameras over the 64 m x 64 m scene, each seeing part of it.
fn cameras() -> Vec<(Vec3, Frustum)> {
    [
        (Vec3::new(-10.0, 5.0, -10.0), Vec3::new(20.0, 0.0, 20.0)),
        (Vec3::new(70.0, 5.0, 32.0), Vec3::new(40.0, 0.0, 32.0)),
        (Vec3::new(32.0, 5.0, 70.0), Vec3::new(10.0, 0.0, 40.0)),
    ]
    .into_iter()
    .map(|(eye, at)| {
        use glam::camera::rh::{proj, view};
        let v = view::look_to_mat4(eye, (at - eye).normalize(), Vec3::Y);
        let p = proj::vulkan::perspective(0.8, 1.0, 0.1, 200.0);
        (eye, Frustum::from_view_projection(p * v).unwrap())
    })
    .collect()
}

/// What a run saw, to show which cases a fixed scenario covers.
#[derive(Clone, Copy, Debug, Default)]
struct Totals {
    ingest: IngestSummary,
    reused_slots: u32,
    disagreeing_with_command: u32,
    /// Latency-mitigation activations (state overrides).
    mitigated: u32,
    /// Instances whose record state (A's, Algorithm 2's) differed from the
    /// commanded state at a check: what the CPU could have peeked at.
    record_differs: u32,
}

fn catalog() -> MeshCatalog {
    let lod = |triangles: u64| MeshLod {
        estimate: BuildEstimate {
            primitives: triangles,
            result_bytes: triangles * 64,
            build_scratch_bytes: triangles * 16,
            update_scratch_bytes: triangles * 4,
        },
        data_bytes: 64,
    };
    let mut c = MeshCatalog::new();
    c.insert(MeshId(1), vec![lod(1000)]).unwrap();
    c.insert(MeshId(2), vec![lod(300)]).unwrap();
    c
}

fn manager(capacity: u32) -> Manager {
    let grid = HitboxGrid::new(GridConfig {
        min: [0.0, 0.0],
        max: [64.0, 64.0],
        cell_size: 16.0,
    })
    .unwrap();
    let mut config = ManagerConfig::new(CUBE);
    config.culling.latency_mitigation = Some(ActivationHeuristic::default());
    config.culling.readback_latency = LATENCY;
    config.culling.registry.quarantine_frames = LATENCY + 1;
    config.culling.command_capacity = capacity;
    Manager::new(grid, config, catalog()).unwrap()
}

fn desc(cell: u8, n: u64, unique: bool) -> InstanceDesc {
    let (cx, cz) = (f32::from(cell % 4), f32::from(cell / 4));
    let off = (n % 5) as f32 * 2.0;
    let c = Vec3::new(cx * 16.0 + 3.0 + off, 0.0, cz * 16.0 + 5.0 + off);
    let aabb = Aabb::new(c - Vec3::new(1.0, 0.0, 1.0), c + Vec3::new(1.0, 3.0, 1.0));
    let mut d = InstanceDesc::new(
        MeshId(1 + (n % 2) as u32),
        Affine3A::from_translation(c),
        aabb,
    );
    if unique {
        d.flags = InstanceFlags::UNIQUE_BLAS;
    }
    d
}

/// Runs both managers through `frames`; fails at the first difference or
/// broken invariant.
fn run(capacity: u32, frames: &[FrameOps]) -> Result<Totals, TestCaseError> {
    let (mut a, mut b) = (manager(capacity), manager(capacity));
    let hitbox_sbt = ManagerConfig::new(CUBE).culling.assembly.hitbox_sbt_offset;
    let mut ring = ReadbackRing::new(LATENCY).unwrap();
    // B's read-backs: (frame it becomes readable, counter, words).
    let mut raw: VecDeque<(u64, u32, Vec<u32>, Vec<u32>)> = VecDeque::new();
    // (a's handle, b's handle): handles carry their manager's id.
    let mut live: Vec<(InstanceHandle, InstanceHandle)> = Vec::new();
    let mut removed_slots: Vec<u32> = Vec::new();
    let mut acks: Vec<(u64, Ack)> = Vec::new();
    let mut immediate = ImmediateAcks::after(0x10_0000, 0x1000);
    let mut registrations = 0u64;
    let mut tlas = Vec::new();
    let mut totals = Totals::default();

    for (f, ops) in frames.iter().enumerate() {
        let frame = f as u64;
        a.begin_frame(frame).unwrap();
        b.begin_frame(frame).unwrap();
        let mut i = 0;
        while i < acks.len() {
            if acks[i].0 <= frame {
                let ack = acks.swap_remove(i).1;
                a.handle_ack(ack).unwrap();
                b.handle_ack(ack).unwrap();
            } else {
                i += 1;
            }
        }

        // Read-backs: the ring (CPU path) and raw words (GPU path).
        while let Some(r) = ring.pop_ready(frame) {
            let (due, counter, words, hits) =
                raw.pop_front().expect("both paths hold the same frames");
            prop_assert_eq!(due, r.frame + u64::from(LATENCY));
            prop_assert_eq!((counter, &words), (r.counter, &r.words));
            let sa = a.ingest_readback(r.frame, r.counter, &r.words);
            let sb = b.ingest_readback(due - u64::from(LATENCY), counter, &words);
            // The GPU backend's hit counters arrive with the same read-back
            // (A holds its feedback's until now).
            b.record_hits(&hits);
            prop_assert_eq!(sa, sb);
            let stored = (counter as usize).min(words.len()) as u32;
            prop_assert_eq!(sa.accepted + sa.rejected + sa.dead, stored);
            prop_assert_eq!(sa.overflowed, counter - stored);
            let t = &mut totals.ingest;
            t.accepted += sa.accepted;
            t.rejected += sa.rejected;
            t.dead += sa.dead;
            t.replaced += sa.replaced;
            t.superseded += sa.superseded;
            t.overflowed += sa.overflowed;

            // The GPU-side queue keeps the same command per live slot.
            let mut gpu = CommandQueue::new(MAX_SLOTS);
            gpu.ingest(counter, &words);
            let slots = a.registry().slot_count();
            for &w in &words[..stored as usize] {
                let c = Command::decode(w, MAX_SLOTS).unwrap();
                let kept = a.pending_command(c.slot);
                if c.slot < slots && a.registry().handle_at(c.slot).is_some() {
                    prop_assert_eq!(kept, gpu.pending(c.slot), "slot {}", c.slot);
                } else {
                    prop_assert_eq!(kept, None, "dead slot {} kept a command", c.slot);
                }
            }
        }

        // Engine calls.
        for &k in &ops.remove {
            if live.is_empty() {
                break;
            }
            let (h, hb) = live.swap_remove(k % live.len());
            let slot = a.instance(h).unwrap().slot;
            // The same removal but for the record's state bits (A's are
            // Algorithm 2's, B's never moved).
            let (mut ra, rb) = (a.remove(h).unwrap(), b.remove(hb).unwrap());
            ra.state = rb.state;
            prop_assert_eq!(ra, rb);
            removed_slots.push(slot);
        }
        for &(cell, unique) in &ops.register {
            let d = desc(cell % 16, registrations, unique);
            registrations += 1;
            let h = a.register(d).unwrap();
            let hb = b.register(d).unwrap();
            let slot = a.instance(h).unwrap().slot;
            prop_assert_eq!(b.instance(hb).unwrap().slot, slot);
            if let Some(i) = removed_slots.iter().position(|&s| s == slot) {
                removed_slots.swap_remove(i);
                totals.reused_slots += 1;
            }
            live.push((h, hb));
        }

        // Latency mitigation: the same overrides in both.
        if let Some(i) = ops.camera {
            let (eye, frustum) = cameras()[i % 3];
            let oa = a.mitigate_latency(eye, &frustum).unwrap();
            let ob = b.mitigate_latency(eye, &frustum).unwrap();
            prop_assert_eq!(oa.summary, ob.summary);
            prop_assert_eq!(oa.already_provided, ob.already_provided);
            let slots = |o: &lipac_core::culling::LatencyOutcome| {
                o.requests.iter().map(|r| r.slot).collect::<Vec<_>>()
            };
            prop_assert_eq!(slots(&oa), slots(&ob));
            totals.mitigated += oa.summary.accepted;
        }

        // Plan; the backend "builds" at once and acknowledges next frame.
        let budgets = FrameBudgets {
            commands: ops.budget.unwrap_or(usize::MAX),
            ..FrameBudgets::default()
        };
        let plan = a.plan(&budgets).unwrap();
        let mut plan_b = b.plan(&budgets).unwrap();
        // The plans are equal but for the handles (each names its manager).
        prop_assert_eq!(plan.data_uploads.len(), plan_b.data_uploads.len());
        for (ua, ub) in plan.data_uploads.iter().zip(&mut plan_b.data_uploads) {
            prop_assert_eq!(a.instance(ua.handle).unwrap().slot, ua.slot);
            prop_assert_eq!(b.instance(ub.handle).unwrap().slot, ub.slot);
            ub.handle = ua.handle;
        }
        // Record uploads and hitbox overrides follow the records and
        // hitboxes (A's moved with Algorithm 2, B's did not); the state
        // overrides are the Manager's decisions and must agree.
        prop_assert_eq!(
            &plan.uploads.state_overrides,
            &plan_b.uploads.state_overrides
        );
        plan_b.uploads = plan.uploads.clone();
        prop_assert_eq!(&plan, &plan_b);
        for ack in immediate.acks(&plan.blas) {
            acks.push((frame + 1, ack));
        }

        // Both equal; BLAS and state agree unless a command will come.
        let in_flight: Vec<u32> = ring
            .iter()
            .flat_map(|r| r.words.iter())
            .map(|&w| Command::decode(w, MAX_SLOTS).unwrap().slot)
            .collect();
        for &(h, hb) in &live {
            let v = a.instance(h).unwrap();
            prop_assert_eq!(&v, &b.instance(hb).unwrap());
            let record_active = a.registry().state(h).unwrap() == InstanceState::Active;
            totals.record_differs += u32::from(record_active != (v.state == InstanceState::Active));
            let active = v.state == InstanceState::Active;
            let agrees = if active {
                v.blas != 0 || v.awaiting_blas
            } else {
                v.blas == 0 && !v.awaiting_blas
            };
            if !agrees {
                let commanded = a.pending_command(v.slot).is_some() || in_flight.contains(&v.slot);
                prop_assert!(
                    commanded,
                    "slot {} disagrees with no command: {:?}",
                    v.slot,
                    v
                );
                totals.disagreeing_with_command += 1;
            }
        }
        prop_assert_eq!(a.stats().instances.active, b.stats().instances.active);

        // Algorithm 1, "tracing", Algorithm 2 on A (the "GPU" for B); B only
        // gets the hit counters, as a GPU backend reads them back.
        a.assemble(&mut tlas).unwrap();
        let hot = |hitbox: u32| ops.hot & (1 << (hitbox % 16)) != 0;
        for t in &tlas {
            let i = t.custom_index();
            let hitbox_box =
                t.acceleration_structure_reference == CUBE && t.sbt_offset() == hitbox_sbt;
            if hitbox_box {
                a.hitboxes_mut()[i as usize].add_hits(if hot(i) { 2500 } else { 0 });
            } else {
                let hitbox = a.records().get(i as usize).unwrap().hitbox;
                a.instance_hits_mut()[i as usize] = if hot(hitbox) { 1500 } else { 0 };
            }
        }
        let hits = a.instance_hits_mut().to_vec();
        a.process_feedback().unwrap();
        let ra = a.take_commands().expect("feedback ran");
        prop_assert!(b.take_commands().is_none(), "B never runs Algorithm 2");

        // What the GPU left: the feedback's words, injected ones, overflow.
        let mut words = ra.words;
        for w in &ops.injected {
            let kind = if w.remove {
                CommandKind::Remove
            } else {
                CommandKind::Add
            };
            words.push(Command::new(w.slot, kind, w.priority).unwrap().encode());
        }
        let counter = ra.counter.max(words.len() as u32) + ops.overflow;
        raw.push_back((frame + u64::from(LATENCY), counter, words.clone(), hits));
        ring.push(Readback {
            frame,
            counter,
            words,
        })
        .unwrap();
    }
    Ok(totals)
}

fn frame_ops() -> impl Strategy<Value = FrameOps> {
    let injected =
        (0u32..40, any::<bool>(), 0u8..=127).prop_map(|(slot, remove, priority)| Injected {
            slot,
            remove,
            priority,
        });
    (
        (any::<u16>(), prop::option::weighted(0.4, 0usize..3)),
        prop::collection::vec((0u8..16, prop::bool::weighted(0.3)), 0..3),
        prop::collection::vec(0usize..64, 0..2),
        prop::collection::vec(injected, 0..4),
        prop::option::weighted(0.2, 1u32..6),
        prop::option::weighted(0.5, 0usize..4),
    )
        .prop_map(
            |((hot, camera), register, remove, injected, overflow, budget)| FrameOps {
                hot,
                camera,
                register,
                remove,
                injected,
                overflow: overflow.unwrap_or(0),
                budget,
            },
        )
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(128))]

    #[test]
    fn cpu_and_gpu_backends_give_the_same_states(
        capacity in 1u32..8,
        frames in prop::collection::vec(frame_ops(), 10..30),
    ) {
        run(capacity, &frames)?;
    }
}

/// A fixed scenario that reaches every case the property is about: an
/// overflowing buffer, commands for removed instances, reused slots,
/// rejected words, both replacement kinds, and instances whose BLAS waits
/// for a command.
#[test]
fn a_fixed_scenario_covers_every_case() {
    let all = u16::MAX;
    let mut frames = Vec::new();
    // Frame 0: 12 instances (3 unique) in four cells, everything hot.
    frames.push(FrameOps {
        hot: all,
        register: (0..12).map(|i| (i % 4, i % 4 == 3)).collect(),
        ..FrameOps::default()
    });
    for f in 1..24u32 {
        let mut ops = FrameOps {
            // Hot and cold in turns, so instances come and go.
            hot: if (f / 4) % 2 == 0 { all } else { 0 },
            budget: (f % 3 == 0).then_some(2),
            overflow: u32::from(f % 5 == 0) * 3,
            camera: (f % 3 == 1).then_some(f as usize / 3),
            ..FrameOps::default()
        };
        if f == 3 || f == 5 {
            ops.remove = vec![0, 1];
        }
        if f == 9 {
            ops.register = vec![(1, false), (2, true), (0, false), (3, false)];
        }
        // Commands for slots 0..4 (removed and reused ones among them), of
        // both kinds, and one beyond the registry.
        ops.injected = vec![
            Injected {
                slot: f % 4,
                remove: f % 2 == 0,
                priority: 9,
            },
            Injected {
                slot: f % 4,
                remove: f % 2 == 1,
                priority: 3,
            },
            Injected {
                slot: f % 4,
                remove: f % 2 == 1,
                priority: 5,
            },
            Injected {
                slot: 39,
                remove: false,
                priority: 0,
            },
        ];
        frames.push(ops);
    }
    let t = run(2, &frames).unwrap();
    let i = t.ingest;
    assert!(i.overflowed > 0, "{t:?}");
    assert!(i.dead > 0, "{t:?}");
    assert!(i.rejected > 0, "{t:?}");
    assert!(i.replaced > 0 && i.superseded > 0, "{t:?}");
    assert!(t.reused_slots > 0, "{t:?}");
    assert!(t.disagreeing_with_command > 0, "{t:?}");
    assert!(t.mitigated > 0, "{t:?}");
    assert!(t.record_differs > 0, "{t:?}");
}
