use super::*;
use crate::build_plan::BuildEstimate;
use crate::culling::ReadbackRing;
use crate::grid::GridConfig;

const CUBE: u64 = 0xC0BE;

fn lod(triangles: u64, data_bytes: u64) -> MeshLod {
    MeshLod {
        estimate: BuildEstimate {
            primitives: triangles,
            result_bytes: triangles * 64,
            build_scratch_bytes: triangles * 16,
            update_scratch_bytes: triangles * 4,
        },
        data_bytes,
    }
}

fn catalog() -> MeshCatalog {
    let mut c = MeshCatalog::new();
    c.insert(MeshId(1), vec![lod(1000, 96), lod(250, 32), lod(60, 16)])
        .unwrap();
    c.insert(MeshId(2), vec![lod(400, 64)]).unwrap();
    c
}

fn desc(x: f32, z: f32, mesh: u32) -> InstanceDesc {
    let aabb = Aabb::new(
        Vec3::new(x - 1.0, 0.0, z - 1.0),
        Vec3::new(x + 1.0, 2.0, z + 1.0),
    );
    InstanceDesc::new(
        MeshId(mesh),
        Affine3A::from_translation(Vec3::new(x, 0.0, z)),
        aabb,
    )
}

struct Rig {
    m: Manager,
    ring: ReadbackRing,
    frame: u64,
    tlas: Vec<TlasInstance>,
    /// Rays per frame into every traced record (counting boxes and instances).
    heat: u32,
}

impl Rig {
    fn new(data: DataConfig) -> Self {
        let grid = HitboxGrid::new(GridConfig {
            min: [0.0, 0.0],
            max: [64.0, 64.0],
            cell_size: 16.0,
        })
        .unwrap();
        let mut config = ManagerConfig::new(CUBE);
        config.culling.latency_mitigation = None;
        config.culling.readback_latency = 1;
        config.scheduler.lod_hysteresis_frames = 1;
        config.data = data;
        Self {
            m: Manager::new(grid, config, catalog()).unwrap(),
            ring: ReadbackRing::new(1).unwrap(),
            frame: 0,
            tlas: Vec::new(),
            heat: 2500,
        }
    }

    /// begin, ingest, plan (with `before_plan`), assemble, trace, feedback.
    fn frame_with(&mut self, before_plan: impl FnOnce(&mut Manager)) -> ManagerPlan {
        self.frame += 1;
        self.m.begin_frame(self.frame).unwrap();
        while let Some(r) = self.ring.pop_ready(self.frame) {
            self.m.ingest_readback(r.frame, r.counter, &r.words);
        }
        before_plan(&mut self.m);
        let plan = self.m.plan(&FrameBudgets::default()).unwrap();
        self.m.assemble(&mut self.tlas).unwrap();
        for t in &self.tlas {
            let i = t.custom_index() as usize;
            if t.acceleration_structure_reference == CUBE {
                self.m.hitboxes_mut()[i].add_hits(self.heat);
            } else {
                self.m.instance_hits_mut()[i] += self.heat;
            }
        }
        self.m.process_feedback().unwrap();
        self.ring.push(self.m.take_commands().unwrap()).unwrap();
        plan
    }

    fn frame(&mut self) -> ManagerPlan {
        self.frame_with(|_| {})
    }

    fn traced(&self, slot: u32) -> Option<u64> {
        self.tlas
            .iter()
            .find(|t| t.custom_index() == slot && t.acceleration_structure_reference != CUBE)
            .map(|t| t.acceleration_structure_reference)
    }
}

#[test]
fn add_plans_a_build_and_the_ack_puts_it_in_the_next_tlas() {
    let mut r = Rig::new(DataConfig::default());
    let h = r.m.register(desc(8.0, 8.0, 1)).unwrap();
    let slot = r.m.instance(h).unwrap().slot;
    let p0 = r.frame(); // feedback activates the hitbox and the instance
    assert_eq!(p0.blas.builds().count(), 0);
    // Algorithm 2 wrote the record; the commanded state follows the `add`
    // when it is read back.
    assert_eq!(r.m.registry().state(h).unwrap(), InstanceState::Active);
    assert_eq!(r.m.instance(h).unwrap().state, InstanceState::Inactive);
    let p1 = r.frame(); // the `add` is processed: a build is planned
    assert_eq!(r.m.instance(h).unwrap().state, InstanceState::Active);
    let builds: Vec<_> = p1.blas.builds().copied().collect();
    assert_eq!(builds.len(), 1);
    assert_eq!(builds[0].result_bytes, 1000 * 64);
    assert!(r.m.instance(h).unwrap().awaiting_blas);
    assert_eq!(r.traced(slot), None, "no BLAS yet: not in the TLAS");
    r.m.handle_ack(Ack::Built {
        build: builds[0].id,
        result_bytes: 60_000,
        address: 0xB000,
    })
    .unwrap();
    assert_eq!(r.m.instance(h).unwrap().blas, 0xB000);
    assert!(!r.m.instance(h).unwrap().awaiting_blas);
    r.frame();
    assert_eq!(r.traced(slot), Some(0xB000));
    let st = r.m.stats();
    assert_eq!(st.memory.blas_shared, 60_000);
    assert_eq!((st.instances.active, st.instances.with_blas), (1, 1));
    assert_eq!(st.memory.data_used, 96);
}

#[test]
fn lod_switch_keeps_the_old_blas_until_the_new_one_is_acknowledged() {
    let mut r = Rig::new(DataConfig::default());
    let h = r.m.register(desc(8.0, 8.0, 1)).unwrap();
    let slot = r.m.instance(h).unwrap().slot;
    r.frame();
    let b = r.frame().blas.builds().next().copied().unwrap();
    r.m.handle_ack(Ack::Built {
        build: b.id,
        result_bytes: b.result_bytes,
        address: 0xA000,
    })
    .unwrap();
    let data_before = r.m.instance(h).unwrap().data;

    assert_eq!(r.m.set_lod(h, 2).unwrap(), 0);
    let v = r.m.instance(h).unwrap();
    assert_eq!((v.requested_lod, v.traced_lod, v.blas), (2, 0, 0xA000));
    assert_eq!(v.data, data_before, "data follows the traced LOD");
    // Hysteresis (1 frame), then the switch's build is planned.
    let mut build = None;
    for _ in 0..3 {
        let p = r.frame();
        assert_eq!(r.traced(slot), Some(0xA000));
        let first = p.blas.builds().next().copied();
        if first.is_some() {
            build = first;
            break;
        }
    }
    let b = build.expect("the LOD 2 build is planned");
    assert_eq!(b.owner.lod(), Lod(2));
    assert_eq!(r.m.registry().records().get(slot as usize).unwrap().lod, 0);
    r.m.handle_ack(Ack::Built {
        build: b.id,
        result_bytes: b.result_bytes,
        address: 0xA100,
    })
    .unwrap();
    let v = r.m.instance(h).unwrap();
    assert_eq!((v.traced_lod, v.blas), (2, 0xA100));
    assert_eq!(v.data.end - v.data.start, 16);
    assert_eq!(r.m.registry().records().get(slot as usize).unwrap().lod, 2);
    let p = r.frame();
    assert_eq!(r.traced(slot), Some(0xA100));
    // The data change is reported (shrunk in place: same offset).
    assert_eq!(
        p.data_uploads,
        vec![DataUpload {
            slot,
            handle: h,
            mesh: MeshId(1),
            lod: 2,
            offset: data_before.start,
            bytes: 16
        }]
    );
    assert_eq!(r.m.data_allocator().used_bytes(), 16);
}

#[test]
fn remove_during_a_pending_build_cancels_it_and_leaks_nothing() {
    let mut r = Rig::new(DataConfig::default());
    let h = r.m.register(desc(8.0, 8.0, 1)).unwrap();
    r.frame();
    let b = r.frame().blas.builds().next().copied().unwrap();
    r.m.remove(h).unwrap();
    assert!(r.m.instance(h).is_err(), "stale handle");
    assert_eq!(r.m.scheduler().stats().instances, 0);
    assert_eq!(r.m.data_allocator().used_bytes(), 0);
    // The late acknowledgement is still accepted; nobody gets the address.
    r.m.handle_ack(Ack::Built {
        build: b.id,
        result_bytes: b.result_bytes,
        address: 0xD000,
    })
    .unwrap();
    assert_eq!(r.m.stats().instances.with_blas, 0);
    assert_eq!(r.m.stats().commands_pending, 0);
    // The unreferenced shared BLAS is cached; trimming frees it after the
    // frames in flight.
    assert_eq!(r.m.trim_blas_cache(), 1);
    let mut freed = Vec::new();
    for _ in 0..4 {
        freed.extend(r.frame().blas.frees.iter().map(|f| f.address));
    }
    assert_eq!(freed, vec![0xD000]);
    let st = r.m.stats();
    assert_eq!((st.blas_entries, st.memory.blas_shared), (0, 0));
}

#[test]
fn unknown_mesh_and_lod_are_clear_errors_that_change_nothing() {
    let mut r = Rig::new(DataConfig::default());
    let e = r.m.register(desc(8.0, 8.0, 9)).unwrap_err();
    assert_eq!(e, ManagerError::UnknownMesh(MeshId(9)));
    assert!(e.to_string().contains("mesh 9"), "{e}");
    let mut d = desc(8.0, 8.0, 1);
    d.lod = 3;
    assert!(matches!(
        r.m.register(d),
        Err(ManagerError::UnknownLod {
            lod: 3,
            lods: 3,
            ..
        })
    ));
    assert_eq!(r.m.stats().instances.live, 0);
    assert_eq!(r.m.data_allocator().allocation_count(), 0);

    let h = r.m.register(desc(8.0, 8.0, 1)).unwrap();
    assert!(matches!(
        r.m.set_lod(h, 7),
        Err(ManagerError::UnknownLod { lod: 7, .. })
    ));
    assert_eq!(r.m.instance(h).unwrap().requested_lod, 0);
    // A mesh change is refused.
    assert!(matches!(
        r.m.update(h, desc(8.0, 8.0, 2)),
        Err(ManagerError::GeometryChange { .. })
    ));
    // NaN transform: a core error, nothing changed.
    let mut bad = desc(8.0, 8.0, 1);
    bad.transform.translation.x = f32::NAN;
    assert!(matches!(r.m.update(h, bad), Err(ManagerError::Core(_))));
    assert_eq!(r.m.data_allocator().used_bytes(), 96);
    // Registering a mesh twice is refused.
    assert!(matches!(
        r.m.register_mesh(MeshId(1), vec![lod(1, 1)]),
        Err(ManagerError::InvalidMesh { .. })
    ));
    // Call order.
    assert!(matches!(
        r.m.plan(&FrameBudgets::default()),
        Err(ManagerError::CallOrder { .. })
    ));
    r.m.begin_frame(5).unwrap();
    assert!(matches!(
        r.m.begin_frame(5),
        Err(ManagerError::CallOrder { .. })
    ));
    r.m.plan(&FrameBudgets::default()).unwrap();
    assert!(matches!(
        r.m.plan(&FrameBudgets::default()),
        Err(ManagerError::CallOrder { .. })
    ));
}

#[test]
fn data_buffer_growth_is_reported_once_and_covers_every_range() {
    let mut r = Rig::new(DataConfig {
        initial_capacity: 100,
        alignment: 16,
    });
    let hs: Vec<_> = (0..5)
        .map(|i| r.m.register(desc(4.0 + 8.0 * i as f32, 8.0, 1)).unwrap())
        .collect();
    let cap = r.m.data_allocator().capacity();
    assert!(cap >= 5 * 96, "grew to {cap}");
    let p = r.frame();
    let g = p.data_growth.expect("growth reported");
    assert_eq!((g.from, g.to), (100, cap));
    assert_eq!(p.data_uploads.len(), 5);
    let mut ranges: Vec<_> = p.data_uploads.iter().map(|u| (u.offset, u.bytes)).collect();
    ranges.sort_unstable();
    for w in ranges.windows(2) {
        assert!(w[0].0 + w[0].1 <= w[1].0, "ranges overlap: {ranges:?}");
    }
    for u in &p.data_uploads {
        assert_eq!(u.offset % 16, 0);
        assert!(u.offset + u.bytes <= g.to);
        assert_eq!(
            r.m.instance(u.handle).unwrap().data,
            u.offset..u.offset + 96
        );
    }
    assert!(hs.iter().all(|&h| r.m.instance(h).is_ok()));
    // Nothing new next frame.
    let p = r.frame();
    assert_eq!((p.data_growth, p.data_uploads.len()), (None, 0));
}

#[test]
fn a_reused_slot_starts_with_a_clean_blas_state() {
    let mut r = Rig::new(DataConfig::default());
    let a = r.m.register(desc(8.0, 8.0, 1)).unwrap();
    let slot = r.m.instance(a).unwrap().slot;
    r.frame();
    let b = r.frame().blas.builds().next().copied().unwrap();
    r.m.handle_ack(Ack::Built {
        build: b.id,
        result_bytes: b.result_bytes,
        address: 0xAA00,
    })
    .unwrap();
    assert!(r.m.scheduler().blas_address(InstanceKey(slot)).is_some());
    r.m.remove(a).unwrap();
    assert_eq!(r.m.scheduler().blas_address(InstanceKey(slot)), None);
    assert_eq!(r.m.scheduler().current_blas(InstanceKey(slot)), None);
    // Cool down (no rays), past the quarantine.
    r.heat = 0;
    for _ in 0..6 {
        r.frame();
    }
    let c = r.m.register(desc(40.0, 40.0, 2)).unwrap();
    let v = r.m.instance(c).unwrap();
    assert_eq!(v.slot, slot, "slot reused");
    assert_eq!((v.blas, v.awaiting_blas, v.scheduled), (0, false, false));
    assert_eq!(r.m.scheduler().blas_address(InstanceKey(slot)), None);
    assert_eq!(r.m.scheduler().pending_lod(InstanceKey(slot)), None);
    assert_eq!(r.m.scheduler().stats().instances, 0);
    // It gets its own BLAS (mesh 2), not the old one.
    r.heat = 2500;
    r.frame();
    let b = r.frame().blas.builds().next().copied().unwrap();
    assert_eq!(b.owner.mesh(), MeshId(2));
    r.m.handle_ack(Ack::Built {
        build: b.id,
        result_bytes: b.result_bytes,
        address: 0xCC00,
    })
    .unwrap();
    assert_eq!(r.m.instance(c).unwrap().blas, 0xCC00);
}

#[test]
fn an_instance_turning_inactive_releases_its_blas_through_the_scheduler() {
    let mut r = Rig::new(DataConfig::default());
    let h = r.m.register(desc(8.0, 8.0, 1)).unwrap();
    r.frame();
    let b = r.frame().blas.builds().next().copied().unwrap();
    r.m.handle_ack(Ack::Built {
        build: b.id,
        result_bytes: b.result_bytes,
        address: 0xB100,
    })
    .unwrap();
    assert_eq!(r.m.stats().instances.scheduled, 1);
    r.heat = 0; // the hitbox deactivates after n_d frames, a remove follows
    for _ in 0..40 {
        r.frame();
    }
    let v = r.m.instance(h).unwrap();
    assert_eq!(
        (v.state, v.blas, v.scheduled),
        (InstanceState::Inactive, 0, false)
    );
    assert_eq!(r.m.scheduler().stats().instances, 0);
    // The shared BLAS stays cached for a later activation.
    assert_eq!(r.m.stats().blas_entries, 1);
    // A LOD change of an instance without a BLAS applies at once.
    r.m.set_lod(h, 1).unwrap();
    let v = r.m.instance(h).unwrap();
    assert_eq!((v.traced_lod, v.data.end - v.data.start), (1, 32));
}

#[test]
fn reserve_covers_a_scene_of_known_size() {
    let mut rig = Rig::new(DataConfig::default());
    let m = &mut rig.m;
    m.reserve(64).unwrap();
    let loop_bytes = m.memory_usage();
    let caps = (m.culling().table().capacity(), m.data_dirty.capacity());
    assert!(caps.0 >= 64 && caps.1 >= 64);
    for i in 0..64 {
        m.register(desc(1.0 + (i % 60) as f32, 5.0, 1 + i % 2))
            .unwrap();
    }
    // Nothing the registrations fill grew.
    assert_eq!(m.memory_usage(), loop_bytes);
    assert_eq!(
        (m.culling().table().capacity(), m.data_dirty.capacity()),
        caps
    );
}

#[test]
fn plan_counts_cache_hits_as_acquired_and_builds_as_requested() {
    let mut r = Rig::new(DataConfig::default());
    let first = r.m.register(desc(8.0, 8.0, 1)).unwrap();
    r.frame(); // feedback activates the hitbox and the instance
    let p = r.frame(); // its `add`: nothing cached, a build is queued
    assert_eq!((p.commands.acquired, p.commands.requested), (0, 1));
    let b = p.blas.builds().next().copied().unwrap();
    r.m.handle_ack(Ack::Built {
        build: b.id,
        result_bytes: b.result_bytes,
        address: 0xB000,
    })
    .unwrap();
    assert_eq!(r.m.instance(first).unwrap().blas, 0xB000);

    // A second instance of the same mesh in the same (active) cell: its
    // `add` finds the built shared BLAS in the cache.
    let second = r.m.register(desc(10.0, 8.0, 1)).unwrap();
    let mut served = None;
    for _ in 0..3 {
        let p = r.frame();
        if p.commands.drained > 0 {
            served = Some(p);
            break;
        }
    }
    let p = served.expect("the second instance's command is processed");
    assert_eq!((p.commands.acquired, p.commands.requested), (1, 0));
    assert_eq!(p.blas.builds().count(), 0);
    let v = r.m.instance(second).unwrap();
    assert_eq!((v.blas, v.awaiting_blas), (0xB000, false));
}

#[test]
fn unique_static_instances_get_own_blases_that_are_never_refit() {
    let mut r = Rig::new(DataConfig::default());
    let own = InstanceFlags::UNIQUE_BLAS | InstanceFlags::STATIC;
    let mut handles = Vec::new();
    for (x, flags) in [(8.0, own), (9.0, own), (10.0, InstanceFlags::UNIQUE_BLAS)] {
        let mut d = desc(x, 8.0, 2);
        d.flags = flags;
        handles.push(r.m.register(d).unwrap());
    }
    let mut builds = Vec::new();
    let hitbox_sbt = r.m.culling().config().assembly.hitbox_sbt_offset;
    // Unique instances pass through the omitted state first (its box's hits
    // are the instance's own).
    let frame = |r: &mut Rig| {
        r.frame += 1;
        r.m.begin_frame(r.frame).unwrap();
        while let Some(rb) = r.ring.pop_ready(r.frame) {
            r.m.ingest_readback(rb.frame, rb.counter, &rb.words);
        }
        let plan = r.m.plan(&FrameBudgets::default()).unwrap();
        for b in plan.blas.builds() {
            r.m.handle_ack(Ack::Built {
                build: b.id,
                result_bytes: b.result_bytes,
                address: 0xB000 + 0x100 * b.id.0,
            })
            .unwrap();
        }
        r.m.assemble(&mut r.tlas).unwrap();
        for t in r.tlas.clone() {
            let i = t.custom_index() as usize;
            if t.sbt_offset() == hitbox_sbt {
                r.m.hitboxes_mut()[i].add_hits(r.heat);
            } else {
                r.m.instance_hits_mut()[i] += r.heat;
            }
        }
        r.m.process_feedback().unwrap();
        r.ring.push(r.m.take_commands().unwrap()).unwrap();
        plan
    };
    for _ in 0..20 {
        let p = frame(&mut r);
        builds.extend(p.blas.builds().copied());
    }
    // Three BLASes for three instances of one mesh: the two static ones do
    // not share theirs, and theirs may be compacted.
    assert_eq!(builds.len(), 3, "{builds:?}");
    let blas: Vec<u64> = handles
        .iter()
        .map(|&h| r.m.instance(h).unwrap().blas)
        .collect();
    assert!(blas.iter().all(|&b| b != 0), "{blas:?}");
    assert!(blas[0] != blas[1] && blas[1] != blas[2]);
    assert_eq!(builds.iter().filter(|b| b.allow_compaction).count(), 2);
    // Later frames refit the animated one only.
    let before = builds.len();
    for _ in 0..4 {
        let p = frame(&mut r);
        let refit: Vec<u32> = p.blas.updates().map(|u| u.instance.0).collect();
        let animated = r.m.instance(handles[2]).unwrap().slot;
        assert_eq!(refit, vec![animated]);
        assert!(p.blas.builds().next().is_none());
    }
    assert_eq!(builds.len(), before);
    // The own static BLAS is part of the instance's identity.
    let mut d = r.m.registry().desc(handles[0]).unwrap();
    d.flags = InstanceFlags::STATIC;
    assert!(matches!(
        r.m.update(handles[0], d),
        Err(ManagerError::GeometryChange { .. })
    ));
    d.flags = own;
    d.mask = 0x0F;
    r.m.update(handles[0], d).unwrap();
    assert_eq!(r.m.instance(handles[0]).unwrap().blas, blas[0]);
}

/// Acknowledges every build of `plan` at `0xA000 + id` and returns how many.
fn ack_builds(m: &mut Manager, plan: &ManagerPlan) -> usize {
    let builds: Vec<_> = plan.blas.builds().copied().collect();
    for b in &builds {
        m.handle_ack(Ack::Built {
            build: b.id,
            result_bytes: b.result_bytes,
            address: 0xA000 + b.id.0,
        })
        .unwrap();
    }
    builds.len()
}

fn pinned(x: f32, z: f32, mesh: u32) -> InstanceDesc {
    InstanceDesc {
        flags: InstanceFlags::PINNED,
        ..desc(x, z, mesh)
    }
}

#[test]
fn pinned_is_never_culled_through_hitbox_deactivation_or_zero_hits() {
    let mut r = Rig::new(DataConfig::default());
    let pin = r.m.register(pinned(8.0, 8.0, 1)).unwrap();
    // Active from registration, its BLAS requested at once.
    let v = r.m.instance(pin).unwrap();
    assert_eq!(v.state, InstanceState::Active);
    assert!(v.scheduled && v.awaiting_blas);
    assert_eq!(r.m.registry().state(pin).unwrap(), InstanceState::Active);
    // A normal instance in the same hitbox.
    let other = r.m.register(desc(10.0, 10.0, 2)).unwrap();
    let (ps, os) = (v.slot, r.m.instance(other).unwrap().slot);
    let p = r.frame();
    // A GPU backend writes the active state over its copy's state bits.
    assert!(p
        .uploads
        .state_overrides
        .contains(&(ps, InstanceState::Active)));
    assert!(p
        .uploads
        .state_overrides
        .contains(&(os, InstanceState::Inactive)));
    assert_eq!(ack_builds(&mut r.m, &p), 1, "only the pinned instance's");
    let address = r.m.instance(pin).unwrap().blas;
    assert_ne!(address, 0);
    // Hits activate the hitbox and the other instance ...
    for _ in 0..4 {
        let p = r.frame();
        ack_builds(&mut r.m, &p);
    }
    assert!(r.traced(os).is_some() && r.traced(ps) == Some(address));
    let hitbox = r.m.records().get(ps as usize).unwrap().hitbox as usize;
    assert!(r.m.hitboxes()[hitbox].is_active());
    // ... then the camera is far away: no hits for 1000 frames. The hitbox
    // deactivates and the other instance goes; the pinned one stays.
    r.heat = 0;
    for f in 0..1000 {
        r.frame();
        assert_eq!(r.traced(ps), Some(address), "frame {f}");
        assert_eq!(r.m.instance(pin).unwrap().state, InstanceState::Active);
    }
    assert!(!r.m.hitboxes()[hitbox].is_active());
    assert_eq!(r.traced(os), None);
    assert_eq!(r.m.instance(other).unwrap().state, InstanceState::Inactive);
    assert_eq!(r.m.registry().state(pin).unwrap(), InstanceState::Active);
    assert_eq!(r.m.stats().instances.active, 1);

    // Unpinned, it returns to its (inactive) hitbox's state by the normal
    // rule: out of the TLAS at once, its BLAS released once the `remove`
    // is read back and processed.
    r.m.update(pin, desc(8.0, 8.0, 1)).unwrap();
    r.frame();
    assert_eq!(r.traced(ps), None);
    for _ in 0..3 {
        r.frame();
    }
    let v = r.m.instance(pin).unwrap();
    assert_eq!(
        (v.state, v.blas, v.scheduled),
        (InstanceState::Inactive, 0, false)
    );
}

#[test]
fn pinning_at_run_time_activates_and_requests_the_blas() {
    let mut r = Rig::new(DataConfig::default());
    r.heat = 0;
    let h = r.m.register(desc(40.0, 40.0, 2)).unwrap();
    let slot = r.m.instance(h).unwrap().slot;
    for _ in 0..3 {
        assert_eq!(r.frame().blas.builds().count(), 0);
    }
    assert_eq!(r.m.instance(h).unwrap().state, InstanceState::Inactive);
    let p = r.frame_with(|m| {
        m.update(h, pinned(40.0, 40.0, 2)).unwrap();
        assert_eq!(m.registry().state(h).unwrap(), InstanceState::Active);
        let v = m.instance(h).unwrap();
        assert_eq!(v.state, InstanceState::Active);
        assert!(v.scheduled && v.awaiting_blas);
    });
    assert!(p
        .uploads
        .state_overrides
        .contains(&(slot, InstanceState::Active)));
    assert_eq!(ack_builds(&mut r.m, &p), 1);
    for _ in 0..20 {
        r.frame();
        assert!(r.traced(slot).is_some());
    }
    // Its flags read back, pinned; updating it again requests nothing new.
    assert_eq!(r.m.registry().flags(h).unwrap(), InstanceFlags::PINNED);
    r.m.update(h, pinned(40.0, 40.0, 2)).unwrap();
    assert_eq!(r.frame().blas.builds().count(), 0);
    assert_eq!(r.m.stats().instances.active, 1);
}

#[test]
fn engine_selected_traces_exactly_the_pinned_set() {
    let grid = || {
        HitboxGrid::new(GridConfig {
            min: [0.0, 0.0],
            max: [64.0, 64.0],
            cell_size: 16.0,
        })
        .unwrap()
    };
    let mut config = ManagerConfig::new(CUBE);
    config.culling.selection = crate::culling::Selection::EngineSelected;
    // Latency mitigation would activate what nothing deactivates.
    assert!(matches!(
        Manager::new(grid(), config, catalog()),
        Err(ManagerError::Core(_) | ManagerError::InvalidConfig { .. })
    ));
    config.culling.latency_mitigation = None;
    let mut m = Manager::new(grid(), config, catalog()).unwrap();
    let a = m.register(desc(8.0, 8.0, 1)).unwrap();
    let b = m.register(desc(40.0, 8.0, 2)).unwrap();
    let (sa, sb) = (m.instance(a).unwrap().slot, m.instance(b).unwrap().slot);
    let mut tlas = Vec::new();
    let mut frame = |m: &mut Manager, f: u64, select: &[(InstanceHandle, bool)]| {
        m.begin_frame(f).unwrap();
        for &(h, on) in select {
            m.set_pinned(h, on).unwrap();
        }
        let plan = m.plan(&FrameBudgets::default()).unwrap();
        ack_builds(m, &plan);
        m.assemble(&mut tlas).unwrap();
        // Whatever the hits, nothing moves.
        m.instance_hits_mut().fill(100_000);
        m.hitboxes_mut()[0].add_hits(100_000);
        assert_eq!(m.process_feedback().unwrap(), FeedbackStats::default());
        let r = m.take_commands().unwrap();
        assert_eq!((r.counter, r.words.len()), (0, 0));
        let mut traced: Vec<u32> = tlas.iter().map(|t| t.custom_index()).collect();
        traced.sort_unstable();
        assert!(tlas
            .iter()
            .all(|t| t.acceleration_structure_reference != CUBE));
        (plan, traced)
    };
    let (_, traced) = frame(&mut m, 1, &[]);
    assert!(traced.is_empty(), "no counting boxes, nothing selected");
    let (plan, traced) = frame(&mut m, 2, &[(a, true), (b, true)]);
    assert_eq!(plan.blas.builds().count(), 2);
    assert_eq!(traced, vec![sa, sb]);
    assert!(m.hitboxes().iter().all(HitboxRecord::is_active));
    for f in 3..10 {
        assert_eq!(frame(&mut m, f, &[]).1, vec![sa, sb]);
    }
    // Unpinned: inactive at once, out of the TLAS, its BLAS released.
    let (_, traced) = frame(&mut m, 10, &[(b, false)]);
    assert_eq!(traced, vec![sa]);
    let v = m.instance(b).unwrap();
    assert_eq!(
        (v.state, v.blas, v.scheduled),
        (InstanceState::Inactive, 0, false)
    );
    assert_eq!(m.stats().instances.active, 1);
    // Pinned again: the cached shared BLAS comes back without a build.
    let (plan, traced) = frame(&mut m, 11, &[(b, true)]);
    assert_eq!(plan.blas.builds().count(), 0);
    assert_eq!(traced, vec![sa, sb]);
    assert!(m.set_pinned(b, true).unwrap());
}

/// The slot table's columns agree with each other and with the parts that
/// do not live in it (the registry's handle map, the scheduler) through
/// registration, removal, slot reuse after the quarantine, LOD changes and
/// BLAS builds.
#[test]
fn the_slot_table_rows_agree_with_the_registry_and_the_scheduler() {
    use lipac_test_support::{Rng64, SplitMix64};
    // One row per slot stays small (occupant 24, view 16, managed 28 bytes).
    assert!(std::mem::size_of::<crate::slot_table::SlotRow>() <= 72);
    let mut r = Rig::new(DataConfig::default());
    let mut rng = SplitMix64::new(11);
    let mut live: Vec<(InstanceHandle, MeshId)> = Vec::new();
    let mut built = 0u64;
    for _ in 0..40 {
        let plan = r.frame_with(|m| {
            for _ in 0..6 {
                if live.len() > 4 && rng.below(3) == 0 {
                    let (h, _) = live.swap_remove(rng.below(live.len() as u64) as usize);
                    m.remove(h).unwrap();
                } else {
                    let mesh = 1 + rng.below(2) as u32;
                    let (x, z) = (rng.below(60) as f32 + 2.0, rng.below(60) as f32 + 2.0);
                    live.push((m.register(desc(x, z, mesh)).unwrap(), MeshId(mesh)));
                }
            }
            if let Some(&(h, MeshId(1))) = live.first() {
                m.set_lod(h, rng.below(3) as u32).unwrap();
            }
        });
        for b in plan.blas.builds() {
            built += 1;
            r.m.handle_ack(Ack::Built {
                build: b.id,
                result_bytes: b.result_bytes,
                address: 0x1_0000 * built,
            })
            .unwrap();
        }
        let m = &r.m;
        let table = m.culling().table();
        assert_eq!(table.len(), m.slot_count() as usize);
        for (slot, row) in table.iter().enumerate() {
            let slot = slot as u32;
            let handle = m.registry().handle_at(slot);
            assert_eq!(
                handle.is_some(),
                row.managed.instance.is_some(),
                "slot {slot}"
            );
            let key = InstanceKey(slot);
            let Some(h) = handle else {
                assert!(!m.scheduler().is_active(key), "dead slot {slot} scheduled");
                continue;
            };
            let &(_, mesh) = live.iter().find(|(l, _)| *l == h).expect("a live handle");
            assert_eq!(row.occupant.mesh(), mesh);
            assert_eq!(m.registry().desc(h).unwrap().mesh, mesh);
            let v = m.instance(h).unwrap();
            assert_eq!(v.slot, slot);
            assert_eq!(v.scheduled, m.scheduler().is_active(key));
            assert_eq!(v.awaiting_blas, m.culling().awaiting_blas(h).unwrap());
            let managed = row.managed.instance.unwrap();
            assert_eq!(v.traced_lod, u32::from(managed.traced_lod));
            assert_eq!(v.requested_lod, u32::from(managed.requested_lod));
            if v.scheduled {
                assert_eq!(m.scheduler().blas_address(key).unwrap_or(0), v.blas);
            } else {
                assert_eq!(v.blas, 0);
            }
        }
        assert_eq!(live.len(), m.registry().len());
    }
    assert!(built > 0, "the scene built BLASes");
    assert!(r.m.stats().instances.scheduled > 0);
}
