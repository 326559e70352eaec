use super::*;
use crate::grid::GridConfig;
use glam::camera::rh::{proj, view};

const CUBE: u64 = 0xC0BE;

fn grid() -> HitboxGrid {
    HitboxGrid::new(GridConfig {
        min: [0.0, 0.0],
        max: [64.0, 64.0],
        cell_size: 16.0,
    })
    .unwrap()
}

fn config() -> CullingConfig {
    let mut c = CullingConfig::new(CUBE);
    c.latency_mitigation = None;
    c.readback_latency = 1;
    c
}

fn desc(x: f32, z: f32, mesh: u32, unique: bool) -> InstanceDesc {
    let aabb = Aabb::new(
        Vec3::new(x - 1.0, 0.0, z - 1.0),
        Vec3::new(x + 1.0, 2.0, z + 1.0),
    );
    let mut d = InstanceDesc::new(
        MeshId(mesh),
        Affine3A::from_translation(Vec3::new(x, 0.0, z)),
        aabb,
    );
    if unique {
        d.flags = InstanceFlags::UNIQUE_BLAS;
    }
    d
}

/// A frustum seeing the whole 64 x 64 m world from 40 m above its centre.
fn frustum_over_world() -> (Vec3, Frustum) {
    let camera = Vec3::new(32.0, 40.0, 32.0);
    let v = view::look_to_mat4(camera, Vec3::NEG_Y, Vec3::NEG_Z);
    let p = proj::vulkan::perspective(100f32.to_radians(), 1.0, 0.1, 500.0);
    (camera, Frustum::from_view_projection(p * v).unwrap())
}

/// A frustum that sees nothing of the world (looking up).
fn frustum_away() -> (Vec3, Frustum) {
    let camera = Vec3::new(32.0, 40.0, 32.0);
    let v = view::look_to_mat4(camera, Vec3::Y, Vec3::NEG_Z);
    let p = proj::vulkan::perspective(60f32.to_radians(), 1.0, 0.1, 500.0);
    (camera, Frustum::from_view_projection(p * v).unwrap())
}

/// A backend stub: acquires answer `addr(slot)`, counts releases.
#[derive(Default)]
struct Blas {
    released: Vec<u64>,
    cancelled: Vec<u32>,
    acquired: Vec<u32>,
}

impl Blas {
    /// `c.process_commands(budget)`, carrying out its events the way a
    /// backend does: acquires get `addr(slot)` at once when `ready` (counted
    /// as acquired, as the manager does), releases and cancels are recorded.
    fn process(&mut self, c: &mut Culling, budget: usize, ready: bool) -> ProcessStats {
        let mut events = Vec::new();
        let mut st = c.process_commands(budget, &mut events);
        for e in events {
            match e.action {
                BlasAction::Acquire => {
                    self.acquired.push(e.slot);
                    if ready {
                        c.set_blas(e.handle, 0x1000 + u64::from(e.slot)).unwrap();
                        st.acquired += 1;
                        st.requested -= 1;
                    }
                }
                BlasAction::Release { blas } => self.released.push(blas),
                BlasAction::CancelBuild => self.cancelled.push(e.slot),
            }
        }
        st
    }
}

fn decode_all(r: &Readback) -> Vec<(u32, CommandKind)> {
    r.words
        .iter()
        .map(|&w| {
            let c = Command::decode(w, MAX_SLOTS).unwrap();
            (c.slot, c.kind)
        })
        .collect()
}

#[test]
fn config_validation_names_the_field() {
    let ok = config();
    assert!(ok.validate().is_ok());
    let cases: Vec<(CullingConfig, &str)> = vec![
        (
            CullingConfig {
                command_capacity: 0,
                ..ok
            },
            "command_capacity",
        ),
        (
            CullingConfig {
                readback_latency: 0,
                ..ok
            },
            "readback_latency",
        ),
        (
            CullingConfig {
                readback_latency: 4,
                ..ok
            },
            "quarantine_frames",
        ),
        (
            CullingConfig {
                assembly: AssemblyConfig::new(0),
                ..ok
            },
            "unit_cube_blas",
        ),
        (
            CullingConfig {
                assembly: AssemblyConfig {
                    min_box_extent: f32::NAN,
                    ..ok.assembly
                },
                ..ok
            },
            "min_box_extent",
        ),
        (
            CullingConfig {
                thresholds: Thresholds {
                    theta_d: 5000,
                    ..Thresholds::paper()
                },
                ..ok
            },
            "thresholds",
        ),
        (
            CullingConfig {
                latency_mitigation: Some(ActivationHeuristic {
                    max_distance: f32::NAN,
                    min_projected_size: 0.1,
                    surround_radius: 0.0,
                }),
                ..ok
            },
            "max_distance",
        ),
    ];
    for (c, field) in cases {
        let err = Culling::new(grid(), c).unwrap_err();
        assert!(
            matches!(err, CoreError::InvalidConfig { .. }) && err.to_string().contains(field),
            "{field}: {err}"
        );
    }
}

#[test]
fn latency_mitigation_activates_instance_and_hitbox_and_it_survives_feedback() {
    let mut cfg = config();
    cfg.latency_mitigation = Some(ActivationHeuristic {
        max_distance: f32::INFINITY,
        min_projected_size: 0.0,
        surround_radius: 0.0,
    });
    let mut c = Culling::new(grid(), cfg).unwrap();
    let a = c.register(desc(8.0, 8.0, 1, false)).unwrap();
    let b = c.register(desc(10.0, 10.0, 2, false)).unwrap(); // same hitbox as a
    let u = c.register(desc(40.0, 40.0, 3, true)).unwrap(); // unique BLAS, other hitbox
    c.begin_frame(0).unwrap();
    let (camera, f) = frustum_over_world();
    let out = c.mitigate_latency(camera, &f).unwrap();
    let requested: Vec<InstanceHandle> = out.requests.iter().map(|r| r.handle).collect();
    assert_eq!(requested.len(), 3);
    assert!(requested.contains(&a) && requested.contains(&b) && requested.contains(&u));
    assert_eq!(out.hitboxes_activated, 2);
    for h in [a, b, u] {
        assert_eq!(c.registry().state(h).unwrap(), InstanceState::Active);
        assert!(c.awaiting_blas(h).unwrap());
        let hb = c.registry().record(h).unwrap().hitbox;
        assert!(c.hitboxes()[hb as usize].is_active());
        assert_eq!(c.hitboxes()[hb as usize].streak(), 0);
    }
    // The caller provides the BLASes the same frame.
    for (i, r) in out.requests.iter().enumerate() {
        assert_eq!(c.set_blas(r.handle, 0x100 + i as u64).unwrap(), 0);
    }
    let mut tlas = Vec::new();
    let st = c.assemble(&mut tlas).unwrap();
    assert_eq!((st.active, st.hitbox_boxes), (3, 0));
    // A few hits only (below θd): Algorithm 2 must keep them active this frame.
    for r in &tlas {
        c.instance_hits_mut()[r.custom_index() as usize] = 10;
    }
    let fs = c.process_feedback().unwrap();
    assert_eq!(fs.active_to_inactive, 0);
    assert_eq!(fs.hitboxes_deactivated, 0);
    for h in [a, b] {
        assert_eq!(c.registry().state(h).unwrap(), InstanceState::Active);
    }
    // The unique instance has its BLAS and few hits: lines 34/35 omit it
    // ("quickly made inactive again"), with a remove command.
    assert_eq!(c.registry().state(u).unwrap(), InstanceState::Omitted);
    let rb = c.take_commands().unwrap();
    let slot_u = c.registry().slot(u).unwrap();
    assert_eq!(decode_all(&rb), vec![(slot_u, CommandKind::Remove)]);
    // The uploads carry the CPU's state writes: registration, then activation.
    let up = c.take_uploads();
    assert_eq!(
        up.state_overrides,
        vec![
            (0, InstanceState::Active),
            (1, InstanceState::Active),
            (2, InstanceState::Active)
        ]
    );
    assert_eq!(up.hitbox_overrides.len(), 2);
    assert!(up.hitbox_overrides.iter().all(|&(_, active)| active));

    // The shared ones go inactive after n_d = 15 quiet frames: the hitbox's
    // streak is 1 after frame 0 and reaches 15 in frame 14.
    let mut ring = ReadbackRing::new(1).unwrap();
    ring.push(rb).unwrap();
    let mut blas = Blas::default();
    for frame in 1..=14 {
        assert_eq!(
            c.registry().state(a).unwrap(),
            InstanceState::Active,
            "frame {frame}"
        );
        c.begin_frame(frame).unwrap();
        while let Some(r) = ring.pop_ready(frame) {
            c.ingest_readback(r.frame, r.counter, &r.words);
        }
        blas.process(&mut c, usize::MAX, true);
        c.assemble(&mut tlas).unwrap();
        c.process_feedback().unwrap();
        ring.push(c.take_commands().unwrap()).unwrap();
    }
    assert_eq!(c.registry().state(a).unwrap(), InstanceState::Inactive);
    assert_eq!(c.registry().state(b).unwrap(), InstanceState::Inactive);
    // u's BLAS was released first (omitted), then a's and b's.
    assert_eq!(blas.released.len(), 1);
    c.begin_frame(15).unwrap();
    while let Some(r) = ring.pop_ready(15) {
        c.ingest_readback(r.frame, r.counter, &r.words);
    }
    blas.process(&mut c, usize::MAX, true);
    assert_eq!(blas.released.len(), 3);
    for h in [a, b, u] {
        assert_eq!(c.registry().record(h).unwrap().blas, 0);
    }
}

#[test]
fn latency_mitigation_in_inactive_hitbox_adds_the_other_instances() {
    let mut cfg = config();
    cfg.latency_mitigation = Some(ActivationHeuristic {
        max_distance: 0.0,
        min_projected_size: 0.0,
        surround_radius: 0.0,
    });
    let mut c = Culling::new(grid(), cfg).unwrap();
    let (camera, away) = frustum_away();
    c.begin_frame(0).unwrap();
    // Nothing registered yet is seen; register two instances in one hitbox,
    // one of them in view of a frustum over the world, the other registered
    // after the update (so not newly visible in this frame).
    let a = c.register(desc(8.0, 8.0, 1, false)).unwrap();
    let out = c.mitigate_latency(camera, &away).unwrap();
    assert!(out.requests.is_empty());
    let (camera, f) = frustum_over_world();
    let out = c.mitigate_latency(camera, &f).unwrap();
    assert_eq!(out.requests.len(), 1);
    let b = c.register(desc(12.0, 12.0, 2, false)).unwrap();
    let w = c.register(desc(13.0, 13.0, 3, true)).unwrap();
    c.set_blas(a, 0xA).unwrap();
    let mut tlas = Vec::new();
    c.assemble(&mut tlas).unwrap();
    let fs = c.process_feedback().unwrap();
    // Lines 21–26 for the other inactive instances of the hitbox.
    assert_eq!((fs.inactive_to_active, fs.inactive_to_omitted), (1, 1));
    assert_eq!(c.registry().state(b).unwrap(), InstanceState::Active);
    assert_eq!(c.registry().state(w).unwrap(), InstanceState::Omitted);
    assert_eq!(c.registry().state(a).unwrap(), InstanceState::Active);
    let rb = c.take_commands().unwrap();
    assert_eq!(
        decode_all(&rb),
        vec![(c.registry().slot(b).unwrap(), CommandKind::Add)]
    );
}

#[test]
fn warm_start_activates_the_view_without_latency_mitigation_and_feedback_culls_it() {
    // Latency mitigation off (config()): mitigate_latency does nothing, the
    // warm start takes its own heuristic.
    let mut c = Culling::new(grid(), config()).unwrap();
    let near = c.register(desc(30.0, 30.0, 1, false)).unwrap();
    let far = c.register(desc(2.0, 2.0, 2, false)).unwrap(); // ~58 m from the camera
    let u = c.register(desc(26.0, 26.0, 3, true)).unwrap(); // same hitbox as near
    c.begin_frame(0).unwrap();
    let (camera, f) = frustum_over_world();
    assert!(c.mitigate_latency(camera, &f).unwrap().requests.is_empty());
    // Nothing outside the frustum, whatever the heuristic.
    let (cam_away, away) = frustum_away();
    let all = ActivationHeuristic {
        max_distance: f32::INFINITY,
        min_projected_size: 0.0,
        surround_radius: 0.0,
    };
    assert!(c
        .warm_start(cam_away, &away, all)
        .unwrap()
        .requests
        .is_empty());
    // Bad input changes nothing.
    let nan = ActivationHeuristic {
        max_distance: f32::NAN,
        min_projected_size: 0.0,
        surround_radius: 0.0,
    };
    assert!(c.warm_start(camera, &f, nan).is_err());
    assert!(c.warm_start(Vec3::NAN, &f, all).is_err());
    assert_eq!(c.registry().state(near).unwrap(), InstanceState::Inactive);
    // Within 50 m of the camera (40 m above the world's centre): near and
    // u, not far (too far, too small to pass 0.5).
    let h = ActivationHeuristic {
        max_distance: 50.0,
        min_projected_size: 0.5,
        surround_radius: 0.0,
    };
    let out = c.warm_start(camera, &f, h).unwrap();
    let requested: Vec<InstanceHandle> = out.requests.iter().map(|r| r.handle).collect();
    assert_eq!(requested, vec![near, u]);
    assert_eq!(out.hitboxes_activated, 1);
    assert_eq!(c.registry().state(far).unwrap(), InstanceState::Inactive);
    // A second warm start finds them active: nothing more to do.
    assert!(c.warm_start(camera, &f, h).unwrap().requests.is_empty());
    for r in &out.requests {
        c.set_blas(r.handle, 0x100 + u64::from(r.slot)).unwrap();
    }
    let mut tlas = Vec::new();
    let st = c.assemble(&mut tlas).unwrap();
    assert_eq!(st.active, 2);
    // No path reaches them: Algorithm 2 omits the unique one at once and
    // the hitbox's streak starts (paper rule, n_d = 15 frames).
    let fs = c.process_feedback().unwrap();
    assert_eq!(fs.active_to_omitted, 1);
    assert_eq!(c.registry().state(u).unwrap(), InstanceState::Omitted);
    assert_eq!(c.registry().state(near).unwrap(), InstanceState::Active);
}

#[test]
fn remove_cancels_pending_command_and_returns_the_blas() {
    let mut c = Culling::new(grid(), config()).unwrap();
    let a = c.register(desc(8.0, 8.0, 1, false)).unwrap();
    let b = c.register(desc(9.0, 9.0, 1, false)).unwrap();
    c.begin_frame(0).unwrap();
    let mut tlas = Vec::new();
    c.assemble(&mut tlas).unwrap();
    c.hitboxes_mut()[0].add_hits(5000);
    c.process_feedback().unwrap();
    let rb = c.take_commands().unwrap();
    assert_eq!(rb.counter, 2);
    c.begin_frame(1).unwrap();
    let s = c.ingest_readback(rb.frame, rb.counter, &rb.words);
    assert_eq!(s.accepted, 2);
    // a got its BLAS by other means (a LOD switch, say) before the command.
    c.set_blas(a, 0xAA).unwrap();
    let removal = c.remove(a).unwrap();
    assert_eq!(removal.instance.blas, 0xAA);
    assert!(!removal.build_was_pending);
    let cancelled = removal.cancelled_command.unwrap();
    assert_eq!((cancelled.slot, cancelled.kind), (0, CommandKind::Add));
    assert_eq!(c.pending_commands(), 1);
    let mut blas = Blas::default();
    let st = blas.process(&mut c, usize::MAX, false);
    assert_eq!(blas.acquired, vec![c.registry().slot(b).unwrap()]);
    assert_eq!((st.requested, st.dead), (1, 0));
    // b waits for its build; removing it reports the pending build.
    assert!(c.awaiting_blas(b).unwrap());
    let removal = c.remove(b).unwrap();
    assert!(removal.build_was_pending && removal.cancelled_command.is_none());
    assert!(c.remove(b).is_err(), "stale handle");
}

#[test]
fn commands_for_dead_slots_are_dropped_never_applied() {
    let mut c = Culling::new(grid(), config()).unwrap();
    let a = c.register(desc(8.0, 8.0, 1, false)).unwrap();
    c.begin_frame(0).unwrap();
    let mut tlas = Vec::new();
    c.assemble(&mut tlas).unwrap();
    c.hitboxes_mut()[0].add_hits(5000);
    c.process_feedback().unwrap();
    let rb = c.take_commands().unwrap();
    // Removed while its command is in flight.
    let slot = c.remove(a).unwrap().instance.slot;
    c.begin_frame(1).unwrap();
    let s = c.ingest_readback(rb.frame, rb.counter, &rb.words);
    assert_eq!((s.accepted, s.dead), (0, 1));
    assert_eq!(c.pending_command(slot), None);
    // A corrupt word naming a slot never used is rejected.
    let bogus = Command::new(999, CommandKind::Add, 3).unwrap().encode();
    assert_eq!(c.ingest_readback(0, 5, &[bogus]).rejected, 1);
    assert_eq!(c.ingest_readback(0, 5, &[bogus]).overflowed, 4);
    // The slot is not reused before the quarantine is over, and a new
    // instance in it starts clean.
    let b = c.register(desc(8.0, 8.0, 1, false)).unwrap();
    assert_ne!(c.registry().slot(b).unwrap(), slot);
    c.begin_frame(10).unwrap();
    let d = c.register(desc(8.0, 8.0, 1, false)).unwrap();
    assert_eq!(c.registry().slot(d).unwrap(), slot);
    assert_eq!(c.registry().state(d).unwrap(), InstanceState::Inactive);
    assert!(!c.awaiting_blas(d).unwrap());
}

#[test]
fn commands_set_the_commanded_state_and_reconcile_against_it() {
    let mut c = Culling::new(grid(), config()).unwrap();
    let a = c.register(desc(8.0, 8.0, 1, false)).unwrap();
    let slot = c.registry().slot(a).unwrap();
    let add = Command::new(slot, CommandKind::Add, 9).unwrap().encode();
    let remove = Command::new(slot, CommandKind::Remove, 9).unwrap().encode();
    let mut blas = Blas::default();
    // An add makes the commanded state active; the records' state bits
    // (Algorithm 2's) are neither read nor written.
    c.ingest_readback(0, 1, &[add]);
    assert!(c.commanded_active(a).unwrap());
    assert_eq!(c.registry().state(a).unwrap(), InstanceState::Inactive);
    let st = blas.process(&mut c, usize::MAX, true);
    assert_eq!((st.stale_kind, st.acquired), (0, 1));
    assert_eq!(
        c.registry().record(a).unwrap().blas,
        0x1000 + u64::from(slot)
    );
    // Even if the records say active, a remove releases it.
    c.registry.set_state(slot, InstanceState::Active).unwrap();
    c.ingest_readback(0, 1, &[remove]);
    assert!(!c.commanded_active(a).unwrap());
    let st = blas.process(&mut c, usize::MAX, true);
    assert_eq!((st.stale_kind, st.released), (0, 1));
    assert_eq!(c.registry().record(a).unwrap().blas, 0);
    // Newest wins, in the queue and in the commanded state alike.
    let s = c.ingest_readback(1, 2, &[remove, add]);
    assert_eq!((s.accepted, s.replaced), (2, 1));
    assert_eq!(
        c.pending_command(slot).map(|c| c.kind),
        Some(CommandKind::Add)
    );
    assert!(c.commanded_active(a).unwrap());
    // A build still running when a remove comes is cancelled.
    let st = blas.process(&mut c, usize::MAX, false);
    assert_eq!(st.requested, 1);
    c.ingest_readback(1, 1, &[remove]);
    let st = blas.process(&mut c, usize::MAX, false);
    assert_eq!((st.builds_cancelled, st.released), (1, 0));
    assert_eq!(blas.cancelled, vec![slot]);
    assert!(!c.awaiting_blas(a).unwrap());
    // A build finishing after a remove is handed back (synthetic command).
    c.ingest_readback(1, 1, &[add]);
    blas.process(&mut c, usize::MAX, false);
    assert!(c.awaiting_blas(a).unwrap());
    c.ingest_readback(1, 1, &[remove]);
    c.set_blas(a, 0xCD).unwrap();
    assert_eq!(c.pending_commands(), 1);
    blas.process(&mut c, usize::MAX, true);
    assert_eq!(blas.released, vec![0x1000 + u64::from(slot), 0xCD]);
    assert_eq!(c.registry().record(a).unwrap().blas, 0);
}

#[test]
fn commands_older_than_a_registration_do_not_move_its_state() {
    let mut c = Culling::new(grid(), config()).unwrap();
    c.begin_frame(5).unwrap();
    let a = c.register(desc(8.0, 8.0, 1, false)).unwrap();
    let slot = c.registry().slot(a).unwrap();
    let add = Command::new(slot, CommandKind::Add, 9).unwrap().encode();
    // Written before the instance existed (frame 4): the state stays, the
    // command is reconciled as stale.
    c.ingest_readback(4, 1, &[add]);
    assert!(!c.commanded_active(a).unwrap());
    let st = Blas::default().process(&mut c, usize::MAX, true);
    assert_eq!((st.stale_kind, st.no_op, st.acquired), (1, 1, 0));
    // Written in the frame of the registration: after it.
    c.ingest_readback(5, 1, &[add]);
    assert!(c.commanded_active(a).unwrap());
}

/// Overflow of the command buffer and a budget of one command per frame:
/// every shared instance of an activated hitbox still ends up with exactly
/// one BLAS.
#[test]
fn overflow_and_budget_retry_end_to_end() {
    let mut cfg = config();
    cfg.command_capacity = 2;
    cfg.readback_latency = 2;
    let mut c = Culling::new(grid(), cfg).unwrap();
    let handles: Vec<InstanceHandle> = (0..5)
        .map(|i| {
            c.register(desc(2.0 + 3.0 * i as f32, 8.0, i, false))
                .unwrap()
        })
        .collect();
    let mut ring = ReadbackRing::new(2).unwrap();
    let mut blas = Blas::default();
    let mut tlas = Vec::new();
    let mut overflowed = 0;
    let mut max_pending = 0;
    for frame in 0..12 {
        c.begin_frame(frame).unwrap();
        while let Some(r) = ring.pop_ready(frame) {
            c.ingest_readback(r.frame, r.counter, &r.words);
        }
        max_pending = max_pending.max(c.pending_commands());
        let st = blas.process(&mut c, 1, true);
        assert!(st.drained <= 1);
        c.assemble(&mut tlas).unwrap();
        // Plenty of hits everywhere.
        for r in &tlas {
            if r.sbt_offset() == c.config().assembly.hitbox_sbt_offset {
                c.hitboxes_mut()[r.custom_index() as usize].add_hits(5000);
            } else {
                c.instance_hits_mut()[r.custom_index() as usize] += 5000;
            }
        }
        overflowed += c.process_feedback().unwrap().overflowed;
        ring.push(c.take_commands().unwrap()).unwrap();
    }
    // 5 adds through a buffer of 2: frame 0 overflows 3, frame 1 one more.
    assert_eq!(overflowed, 3 + 1);
    assert!(max_pending >= 2, "the budget made commands wait");
    let mut acquired = blas.acquired.clone();
    acquired.sort_unstable();
    assert_eq!(acquired, vec![0, 1, 2, 3, 4]);
    for h in handles {
        assert_eq!(c.registry().state(h).unwrap(), InstanceState::Active);
        assert_ne!(c.registry().record(h).unwrap().blas, 0);
    }
    assert_eq!(c.pending_commands(), 0);
    assert_eq!(tlas.len(), 5);
}

#[test]
fn call_order_is_checked() {
    let mut c = Culling::new(grid(), config()).unwrap();
    c.begin_frame(3).unwrap();
    assert!(c.take_commands().is_none());
    c.process_feedback().unwrap();
    assert!(matches!(
        c.process_feedback(),
        Err(CoreError::CallOrder { .. })
    ));
    assert!(matches!(c.begin_frame(4), Err(CoreError::CallOrder { .. })));
    assert_eq!(c.take_commands().unwrap().frame, 3);
    assert!(matches!(
        c.begin_frame(2),
        Err(CoreError::FrameOrder { .. })
    ));
    c.begin_frame(4).unwrap();
    let mut ring = ReadbackRing::new(1).unwrap();
    ring.push(Readback::default()).unwrap();
    assert!(ring
        .push(Readback {
            frame: 1,
            ..Readback::default()
        })
        .is_err());
    assert!(ReadbackRing::new(0).is_err());
}

/// The scatter a GPU backend performs keeps GPU-owned state bits and applies
/// exactly the CPU's writes.
#[test]
fn uploads_scatter_keeps_gpu_state_bits() {
    let mut cfg = config();
    cfg.latency_mitigation = Some(ActivationHeuristic {
        max_distance: f32::INFINITY,
        min_projected_size: 0.0,
        surround_radius: 0.0,
    });
    let mut c = Culling::new(grid(), cfg).unwrap();
    let a = c.register(desc(8.0, 8.0, 1, false)).unwrap();
    let b = c.register(desc(40.0, 40.0, 1, false)).unwrap();
    let mut gpu = crate::layout::InstanceArrays::new();
    let mut gpu_rates = Vec::new();
    let mut gpu_hitboxes = c.hitboxes().to_vec();
    apply_uploads(
        &c.take_uploads(),
        c.registry().records(),
        &mut gpu,
        &mut gpu_rates,
        &mut gpu_hitboxes,
    );
    assert_eq!(&gpu, c.registry().records());
    // The GPU's Algorithm 2 turns b omitted (pretend); the CPU moves b, and
    // latency mitigation activates both (first update: all newly visible).
    gpu.set_state(1, InstanceState::Omitted);
    c.begin_frame(1).unwrap();
    let moved = |y: f32| Aabb::new(Vec3::new(y, 0.0, 39.0), Vec3::new(41.0, 2.0, 41.0));
    c.set_transform(b, Affine3A::IDENTITY, moved(39.0)).unwrap();
    let (camera, f) = frustum_over_world();
    let out = c.mitigate_latency(camera, &f).unwrap();
    assert_eq!(out.requests.len(), 2);
    let up = c.take_uploads();
    assert_eq!(up.records, vec![0..2]);
    apply_uploads(
        &up,
        c.registry().records(),
        &mut gpu,
        &mut gpu_rates,
        &mut gpu_hitboxes,
    );
    assert_eq!(&gpu, c.registry().records());
    assert_eq!(gpu.hot()[1].state(), InstanceState::Active); // override applied
    let hb_a = c.registry().record(a).unwrap().hitbox as usize;
    assert!(gpu_hitboxes[hb_a].is_active());
    // A record upload without an override keeps the GPU's state.
    gpu.set_state(1, InstanceState::Omitted);
    c.set_transform(b, Affine3A::IDENTITY, moved(38.0)).unwrap();
    let up = c.take_uploads();
    assert!(up.state_overrides.is_empty() && up.hitbox_overrides.is_empty());
    apply_uploads(
        &up,
        c.registry().records(),
        &mut gpu,
        &mut gpu_rates,
        &mut gpu_hitboxes,
    );
    assert_eq!(gpu.hot()[1].state(), InstanceState::Omitted);
    assert_eq!(gpu.bounds()[1].aabb_min, [38.0, 0.0, 39.0]);
}

/// lipac-sim's default decayed rule at its 9,216 rays per frame (a single
/// hit activates; the deactivation and omit rates at the floor `2^k`).
fn sim_default_rule() -> crate::thresholds::DecayedRule {
    crate::thresholds::DecayedSettings {
        half_life_frames: 5.0,
        activate: 100.0,
        deactivate: 0.2,
        instance_activate: 100.0,
        instance_omit: 0.2,
        per_shared: 0.0,
        per_unique: 0.0,
        rise_shift: Some(1),
    }
    .rule_for_rays_per_frame(9216.0)
    .unwrap()
}

/// A held warm start ([`CullingConfig::warm_start_hold`]) keeps what it
/// activates through that many frames of feedback without a hit, on the CPU
/// records and, through the upload's rate floors, on a GPU's; without a
/// hold the first feedback culls it.
#[test]
fn a_held_warm_start_survives_frames_without_hits() {
    let rule = sim_default_rule();
    let (camera, f) = frustum_over_world();
    let all = ActivationHeuristic {
        max_distance: f32::INFINITY,
        min_projected_size: 0.0,
        surround_radius: 0.0,
    };
    // Frames of feedback without hits after the warm start until the
    // shared instance's hitbox is inactive and the unique instance is no
    // longer active (omitted, or inactive with its hitbox).
    let run = |hold: u32| -> (u32, u32, Uploads) {
        let mut cfg = config();
        cfg.thresholds.rule = DecisionRule::Decayed(rule);
        cfg.warm_start_hold = hold;
        let mut c = Culling::new(grid(), cfg).unwrap();
        let shared = c.register(desc(8.0, 8.0, 1, false)).unwrap();
        let unique = c.register(desc(40.0, 40.0, 2, true)).unwrap();
        c.take_uploads();
        c.begin_frame(0).unwrap();
        let out = c.warm_start(camera, &f, all).unwrap();
        for r in &out.requests {
            c.set_blas(r.handle, 0x100 + u64::from(r.slot)).unwrap();
        }
        let uploads = c.take_uploads();
        let hb = c.registry().record(shared).unwrap().hitbox as usize;
        let (mut hitbox_frames, mut unique_frames) = (None, None);
        for frame in 0..40u32 {
            if frame > 0 {
                c.begin_frame(u64::from(frame)).unwrap();
            }
            c.process_feedback().unwrap();
            c.take_commands().unwrap();
            if hitbox_frames.is_none() && !c.hitboxes()[hb].is_active() {
                hitbox_frames = Some(frame);
            }
            if unique_frames.is_none()
                && c.registry().state(unique).unwrap() != InstanceState::Active
            {
                unique_frames = Some(frame);
            }
        }
        (hitbox_frames.unwrap(), unique_frames.unwrap(), uploads)
    };
    let (h0, u0, up0) = run(0);
    assert_eq!((h0, u0), (0, 0), "no hold: the first feedback culls");
    assert!(up0.hitbox_rate_floors.is_empty() && up0.instance_rate_floors.is_empty());
    for hold in [1, 4, 8] {
        let (h, u, up) = run(hold);
        assert_eq!((h, u), (hold, hold), "hold {hold}");
        // The GPU gets the same floors: one per activated hitbox (two) and
        // one for the unique-BLAS instance (slot 1).
        let hitbox_floor = rule.hold_rate(rule.deactivate, hold);
        assert_eq!(up.hitbox_rate_floors.len(), 2);
        assert!(up
            .hitbox_rate_floors
            .iter()
            .all(|&(_, r)| r == hitbox_floor));
        assert_eq!(
            up.instance_rate_floors,
            vec![(1, rule.hold_rate(rule.instance_omit, hold))]
        );
    }
    // The paper's rule has no rates: a hold changes nothing.
    let mut cfg = config();
    cfg.warm_start_hold = 8;
    let mut c = Culling::new(grid(), cfg).unwrap();
    c.register(desc(8.0, 8.0, 1, true)).unwrap();
    c.begin_frame(0).unwrap();
    c.warm_start(camera, &f, all).unwrap();
    let up = c.take_uploads();
    assert!(up.hitbox_rate_floors.is_empty() && up.instance_rate_floors.is_empty());
}

/// Rate floors raise a GPU copy's rates, never lower them, and those of a
/// reused slot's previous occupant are dropped.
#[test]
fn rate_floors_raise_the_gpu_rates_and_skip_reused_slots() {
    let mut cfg = config();
    cfg.thresholds.rule = DecisionRule::Decayed(sim_default_rule());
    cfg.warm_start_hold = 6;
    cfg.registry.quarantine_frames = 2;
    let mut c = Culling::new(grid(), cfg).unwrap();
    let a = c.register(desc(8.0, 8.0, 1, true)).unwrap();
    let b = c.register(desc(40.0, 40.0, 2, true)).unwrap();
    let mut gpu = crate::layout::InstanceArrays::new();
    let mut gpu_rates = Vec::new();
    let mut gpu_hitboxes = c.hitboxes().to_vec();
    let records = c.registry().records().clone();
    apply_uploads(
        &c.take_uploads(),
        &records,
        &mut gpu,
        &mut gpu_rates,
        &mut gpu_hitboxes,
    );
    assert_eq!(gpu_rates, vec![0, 0]);
    c.begin_frame(0).unwrap();
    let (camera, f) = frustum_over_world();
    let all = ActivationHeuristic {
        max_distance: f32::INFINITY,
        min_projected_size: 0.0,
        surround_radius: 0.0,
    };
    c.warm_start(camera, &f, all).unwrap();
    // The GPU's rate of b is already above the floor: kept.
    let high = u32::MAX / 2;
    gpu_rates[1] = high;
    let hb_b = c.registry().record(b).unwrap().hitbox as usize;
    gpu_hitboxes[hb_b].rate = high;
    let up = c.take_uploads();
    let records = c.registry().records().clone();
    apply_uploads(&up, &records, &mut gpu, &mut gpu_rates, &mut gpu_hitboxes);
    let floor = up.instance_rate_floors[0].1;
    assert!(floor > 0 && floor < high);
    assert_eq!(gpu_rates, vec![floor, high]);
    let hb_a = c.registry().record(a).unwrap().hitbox as usize;
    assert_eq!(gpu_hitboxes[hb_a].rate, c.hitboxes()[hb_a].rate);
    assert_eq!(gpu_hitboxes[hb_b].rate, high);
    // A removed instance's floor, not yet taken, is not its slot's next
    // occupant's.
    let d = c.register(desc(24.0, 8.0, 4, true)).unwrap();
    let slot_d = c.registry().slot(d).unwrap();
    c.warm_start(camera, &f, all).unwrap();
    c.remove(d).unwrap();
    for frame in 1..=3 {
        c.begin_frame(frame).unwrap();
    }
    let fresh = c.register(desc(8.0, 8.0, 3, true)).unwrap();
    assert_eq!(c.registry().slot(fresh).unwrap(), slot_d);
    assert!(c.take_uploads().instance_rate_floors.is_empty());
}

/// The hitbox extents (heights and cost word, `crate::hitbox_extents`)
/// Culling keeps incrementally equal a full `write_extents` over its
/// records after any mix of registrations, moves (across cells too),
/// pin/unpin and kind changes, removals, BLAS writes and evictions of a
/// hashed index; and a GPU copy fed only by the uploads (evicted records
/// reset to the default, as lipac-vk's hitbox tables do) holds the same
/// extents. Algorithm 1's boxes on the CPU then come from those extents.
#[test]
fn kept_extents_equal_a_full_recompute_and_reach_the_gpu() {
    use crate::hashed_hitboxes::{HashedConfig, HashedHitboxes};
    use crate::hitbox_extents::{write_extents, HitboxExtent};
    use lipac_test_support::{Rng64, XorShift64};

    let extents = |h: &[HitboxRecord]| -> Vec<[u32; 3]> {
        h.iter().map(|r| HitboxExtent::of(r).to_words()).collect()
    };
    for seed in 0..6u64 {
        let mut rng = XorShift64::new(0xE47E_0000 + seed);
        let index = HashedHitboxes::new(HashedConfig {
            evict_after_frames: 2,
            ..HashedConfig::default()
        })
        .unwrap();
        let mut c = Culling::new(index, config()).unwrap();
        let mut live: Vec<InstanceHandle> = Vec::new();
        let mut gpu = crate::layout::InstanceArrays::new();
        let mut gpu_rates = Vec::new();
        let mut gpu_hitboxes: Vec<HitboxRecord> = Vec::new();
        let mut uploaded = 0usize;
        let random_desc = |rng: &mut XorShift64| {
            let (x, z) = (rng.below_u32(96) as f32, rng.below_u32(96) as f32);
            let y = rng.below_u32(40) as f32 - 10.0;
            let h = [0.0, 0.5, 3.0, 12.0][rng.below_u32(4) as usize];
            let mut d = desc(x, z, rng.below_u32(5), rng.below_u32(3) == 0);
            d.aabb = Aabb::new(
                Vec3::new(x - 1.0, y, z - 1.0),
                Vec3::new(x + 1.0, y + h, z + 1.0),
            );
            if rng.below_u32(6) == 0 {
                d.flags |= InstanceFlags::PINNED;
            }
            d
        };
        for frame in 1..40u64 {
            c.begin_frame(frame).unwrap();
            // The GPU resets the records of evicted hitboxes to the default.
            for &i in c.registry().evicted_hitboxes() {
                if let Some(h) = gpu_hitboxes.get_mut(i as usize) {
                    *h = HitboxRecord::default();
                }
            }
            for _ in 0..rng.below_u32(12) {
                match rng.below_u32(6) {
                    0 | 1 => {
                        let d = random_desc(&mut rng);
                        if let Ok(h) = c.register(d) {
                            live.push(h);
                        }
                    }
                    2 if !live.is_empty() => {
                        let h = live[rng.below_u32(live.len() as u32) as usize];
                        let d = random_desc(&mut rng);
                        let _ = c.set_transform(h, d.transform, d.aabb);
                    }
                    3 if !live.is_empty() => {
                        let h = live[rng.below_u32(live.len() as u32) as usize];
                        let _ = c.update(h, random_desc(&mut rng));
                    }
                    4 if !live.is_empty() => {
                        let k = rng.below_u32(live.len() as u32) as usize;
                        c.remove(live.swap_remove(k)).unwrap();
                    }
                    5 if !live.is_empty() => {
                        let h = live[rng.below_u32(live.len() as u32) as usize];
                        let _ = c.set_blas(h, 0xB000 + u64::from(rng.below_u32(4)));
                    }
                    _ => {}
                }
            }
            let up = c.take_uploads();
            uploaded += up.hitbox_extents.len();
            let listed: Vec<u32> = up.hitbox_extents.iter().map(|&(i, _)| i).collect();
            assert!(
                listed.windows(2).all(|w| w[0] < w[1]),
                "ascending, each once"
            );
            gpu_hitboxes.resize(c.hitboxes().len(), HitboxRecord::default());
            apply_uploads(
                &up,
                c.registry().records(),
                &mut gpu,
                &mut gpu_rates,
                &mut gpu_hitboxes,
            );
            let mut want = c.hitboxes().to_vec();
            write_extents(c.registry().records(), &mut want);
            assert_eq!(
                extents(c.hitboxes()),
                extents(&want),
                "seed {seed} frame {frame}"
            );
            assert_eq!(
                extents(&gpu_hitboxes),
                extents(&want),
                "seed {seed} frame {frame}: GPU"
            );
            let mut out = Vec::new();
            c.assemble(&mut out).unwrap();
            let _ = c.process_feedback().unwrap();
            let _ = c.take_commands();
        }
        assert!(
            uploaded > 20,
            "seed {seed}: only {uploaded} extents uploaded"
        );
    }
}
