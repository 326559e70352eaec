//! `Manager<HashedHitboxes>` against `Manager<HitboxGrid>` on a bounded
//! world whose cells map 1:1: the same decisions every frame (instance
//! states, BLAS work, TLAS records with counting boxes matched by cell),
//! while instances are registered, moved and removed. And with eviction on,
//! emptied cells are dropped and their indices reused without the Manager
//! noticing more than fresh cells.

use glam::{Affine3A, Vec3};
use lipac_core::hashed_hitboxes::{HashedConfig, HashedHitboxes};
use lipac_core::layout::TlasInstance;
use lipac_core::sparse_grid::SparseGrid;
use lipac_core::{
    Aabb, Ack, BuildEstimate, FrameBudgets, GridConfig, HitboxGrid, HitboxIndex, InstanceDesc,
    InstanceHandle, Manager, ManagerConfig, MeshCatalog, MeshId, MeshLod, ReadbackRing,
};
use lipac_test_support::synthetic::ImmediateAcks;
use lipac_test_support::{Rng64, SplitMix64};

const CUBE: u64 = 0xC0BE;
const CELL: f64 = 16.0;
/// Instances at first, in the left half of the world (32 cells).
const INSTANCES: u32 = 40;
/// 8 x 8 cells of 16 m.
const WORLD: f32 = 128.0;

fn catalog() -> MeshCatalog {
    let lod = |t: u64| MeshLod {
        estimate: BuildEstimate {
            primitives: t,
            result_bytes: t * 64,
            build_scratch_bytes: t * 16,
            update_scratch_bytes: t * 4,
        },
        data_bytes: 32,
    };
    let mut c = MeshCatalog::new();
    for m in 0..4 {
        c.insert(MeshId(m), vec![lod(1000), lod(200)]).unwrap();
    }
    c
}

fn config() -> ManagerConfig {
    let mut config = ManagerConfig::new(CUBE);
    config.culling.latency_mitigation = None;
    config.culling.readback_latency = 1;
    config
}

fn desc(x: f32, z: f32, mesh: u32) -> InstanceDesc {
    let aabb = Aabb::new(
        Vec3::new(x - 0.5, 0.0, z - 0.5),
        Vec3::new(x + 0.5, 3.0, z + 0.5),
    );
    InstanceDesc::new(
        MeshId(mesh),
        Affine3A::from_translation(Vec3::new(x, 0.0, z)),
        aabb,
    )
}

/// Rays into a record at world x: a hot band of two cell columns that moves
/// one column every 4 frames.
fn heat(frame: u64, x: f64) -> u32 {
    let col = (x / CELL).floor() as i64;
    let hot = (frame / 4 % 8) as i64;
    if col == hot || col == hot + 1 {
        3000
    } else {
        3
    }
}

/// One TLAS record, hitbox boxes named by their cell.
#[derive(Debug, PartialEq, PartialOrd, Clone, Copy)]
enum Rec {
    Instance(u32, u64),
    Box(i32, i32, u32, [u32; 12]),
}

/// A frame's decisions: TLAS records (sorted), per slot `(slot, packed
/// state bits, BLAS)`, builds planned, and Algorithm 2's adds and removes.
type Decisions = (Vec<Rec>, Vec<(u32, u32, u64)>, usize, (u32, u32));

struct Rig<H: HitboxIndex> {
    m: Manager<H>,
    ring: ReadbackRing,
    acks: Vec<Ack>,
    immediate: ImmediateAcks,
    tlas: Vec<TlasInstance>,
    cell_of: fn(&H, u32) -> Option<(i32, i32)>,
    /// Hitboxes the index evicted so far.
    evicted: usize,
}

impl<H: HitboxIndex> Rig<H> {
    fn new(index: H, cell_of: fn(&H, u32) -> Option<(i32, i32)>) -> Self {
        Self {
            m: Manager::new(index, config(), catalog()).unwrap(),
            ring: ReadbackRing::new(1).unwrap(),
            acks: Vec::new(),
            immediate: ImmediateAcks::new(0x1000),
            tlas: Vec::new(),
            cell_of,
            evicted: 0,
        }
    }

    /// One frame; `change` edits instances before the plan. Returns the
    /// decisions to compare.
    fn frame(&mut self, frame: u64, change: impl FnOnce(&mut Manager<H>)) -> Decisions {
        self.m.begin_frame(frame).unwrap();
        self.evicted += self.m.registry().evicted_hitboxes().len();
        for ack in self.acks.drain(..) {
            self.m.handle_ack(ack).unwrap();
        }
        while let Some(r) = self.ring.pop_ready(frame) {
            self.m.ingest_readback(r.frame, r.counter, &r.words);
        }
        change(&mut self.m);
        let plan = self.m.plan(&FrameBudgets::default()).unwrap();
        let builds = plan.blas.builds().count();
        self.acks.extend(self.immediate.acks(&plan.blas));
        self.m.assemble(&mut self.tlas).unwrap();
        let mut recs = Vec::new();
        for t in self.tlas.clone() {
            let i = t.custom_index();
            if t.acceleration_structure_reference == CUBE {
                let (cx, cz) = (self.cell_of)(self.m.registry().hitbox_index(), i).unwrap();
                let rays = heat(frame, f64::from(cx) * CELL);
                self.m.hitboxes_mut()[i as usize].add_hits(rays);
                recs.push(Rec::Box(
                    cx,
                    cz,
                    t.mask().into(),
                    t.transform.map(f32::to_bits),
                ));
            } else {
                let r = self.m.records().get(i as usize).unwrap();
                let x = f64::from(r.aabb_min[0] + r.aabb_max[0]) / 2.0;
                self.m.instance_hits_mut()[i as usize] += heat(frame, x);
                recs.push(Rec::Instance(i, t.acceleration_structure_reference));
            }
        }
        recs.sort_by(|a, b| a.partial_cmp(b).unwrap());
        let fb = self.m.process_feedback().unwrap();
        self.ring.push(self.m.take_commands().unwrap()).unwrap();
        let states = self
            .m
            .records()
            .iter()
            .enumerate()
            .map(|(s, r)| (s as u32, r.packed, r.blas))
            .collect();
        (
            recs,
            states,
            builds,
            (fb.inactive_to_active, fb.active_to_inactive),
        )
    }
}

fn hashed(evict_after_frames: u32) -> HashedHitboxes {
    HashedHitboxes::new(HashedConfig {
        origin: [0.0, 0.0],
        cell_size: CELL,
        evict_after_frames,
        initial_buckets: 2,
        ..HashedConfig::default()
    })
    .unwrap()
}

fn grid_cell(g: &HitboxGrid, i: u32) -> Option<(i32, i32)> {
    g.cell(i).map(|(x, z)| (x as i32, z as i32))
}

fn hashed_cell(h: &HashedHitboxes, i: u32) -> Option<(i32, i32)> {
    h.cell(i)
}

/// A random in-world position, not on the far border (the grid closes it,
/// the hashed grid has none).
fn pos(rng: &mut SplitMix64) -> (f32, f32) {
    let u =
        |r: &mut SplitMix64| (r.next_u64() % 1_000_000) as f32 / 1_000_000.0 * (WORLD - 2.0) + 1.0;
    (u(rng), u(rng))
}

fn world_grid() -> HitboxGrid {
    HitboxGrid::new(GridConfig {
        min: [0.0, 0.0],
        max: [f64::from(WORLD), f64::from(WORLD)],
        cell_size: CELL,
    })
    .unwrap()
}

/// Drives both managers through the same scene; returns the hashed one.
fn run_both(
    evict_after_frames: u32,
    frames: u64,
    compare: impl FnMut(u64, bool),
) -> Rig<HashedHitboxes> {
    let h = Rig::new(hashed(evict_after_frames), hashed_cell);
    run_pair(h, evict_after_frames == u32::MAX, false, frames, compare)
}

/// Drives a grid manager and `h` through the same scene (with `border`,
/// some instances move onto the world's far border, which the grid
/// closes); with `exact`, asserts the same decisions every frame. Returns
/// `h`.
fn run_pair<H: HitboxIndex>(
    mut h: Rig<H>,
    exact: bool,
    border: bool,
    frames: u64,
    mut compare: impl FnMut(u64, bool),
) -> Rig<H> {
    let mut g = Rig::new(world_grid(), grid_cell);
    let mut rng = SplitMix64::new(15);
    // Half of the cells hold instances at first (the left half of the world).
    let mut live: Vec<(InstanceHandle, InstanceHandle)> = Vec::new();
    for i in 0..INSTANCES {
        let (x, z) = pos(&mut rng);
        let d = desc(x / 2.0, z, i % 4);
        live.push((g.m.register(d).unwrap(), h.m.register(d).unwrap()));
    }
    for frame in 0..frames {
        // Per frame: a few moves (anywhere), removals and registrations.
        let mut ops = Vec::new();
        for i in 0..3 {
            let (mut x, mut z) = pos(&mut rng);
            if border && i == 0 && frame % 3 == 0 {
                // Onto the far border (the last cell of the grid).
                (x, z) = (WORLD, if frame % 2 == 0 { WORLD } else { z });
            }
            let k = (rng.next_u64() % live.len() as u64) as usize;
            ops.push((rng.next_u64() % 3, k, x, z, (rng.next_u64() % 4) as u32));
        }
        let apply = |m: &mut dyn FnMut(u64, usize, f32, f32, u32)| {
            for &(kind, k, x, z, mesh) in &ops {
                m(kind, k, x, z, mesh);
            }
        };
        let mut new_g = Vec::new();
        let mut new_h = Vec::new();
        let mut removed = Vec::new();
        let a = g.frame(frame, |m| {
            apply(&mut |kind, k, x, z, mesh| match kind {
                0 => {
                    let d = desc(x, z, mesh);
                    m.set_transform(live[k].0, d.transform, d.aabb).unwrap();
                }
                1 if !removed.contains(&k) => {
                    m.remove(live[k].0).unwrap();
                    removed.push(k);
                }
                _ => new_g.push(m.register(desc(x, z, mesh)).unwrap()),
            })
        });
        let mut removed_h = Vec::new();
        let b = h.frame(frame, |m| {
            apply(&mut |kind, k, x, z, mesh| match kind {
                0 => {
                    let d = desc(x, z, mesh);
                    m.set_transform(live[k].1, d.transform, d.aabb).unwrap();
                }
                1 if !removed_h.contains(&k) => {
                    m.remove(live[k].1).unwrap();
                    removed_h.push(k);
                }
                _ => new_h.push(m.register(desc(x, z, mesh)).unwrap()),
            })
        });
        removed.sort_unstable();
        for &k in removed.iter().rev() {
            live.swap_remove(k);
        }
        live.extend(new_g.into_iter().zip(new_h));
        let same = a == b;
        compare(frame, same);
        if exact {
            assert_eq!(a.0, b.0, "TLAS records differ at frame {frame}");
            assert_eq!(a.1, b.1, "instance states differ at frame {frame}");
            assert_eq!(
                (a.2, a.3),
                (b.2, b.3),
                "BLAS work or feedback differs at frame {frame}"
            );
        }
    }
    h
}

#[test]
fn hashed_manager_decides_as_the_grid_manager_on_a_bounded_world() {
    let mut same_frames = 0;
    let h = run_both(u32::MAX, 40, |_, same| {
        same_frames += usize::from(same);
    });
    assert_eq!(same_frames, 40);
    assert_eq!(h.evicted, 0);
    // Cells occupied at some point got indices; never more than the grid's 64.
    let index = h.m.registry().hitbox_index();
    assert!(index.len() > 32 && index.len() <= 64, "{}", index.len());
    assert_eq!(h.m.hitboxes().len() as u32, index.len());
    assert!(
        h.m.stats().instances.active > 0,
        "the hot band activated instances"
    );
}

/// The sparse grid (a bounded world's occupied cells only) decides as the
/// dense grid, far border included: the structure a replay holds for a
/// large declared world (`WorldHitboxes::for_world`).
#[test]
fn sparse_grid_manager_decides_as_the_grid_manager() {
    fn sparse_cell(s: &SparseGrid, i: u32) -> Option<(i32, i32)> {
        s.cell(i).map(|(x, z)| (x as i32, z as i32))
    }
    let mut same_frames = 0;
    let s = run_pair(
        Rig::new(SparseGrid::new(world_grid()).unwrap(), sparse_cell),
        true,
        true,
        40,
        |_, same| same_frames += usize::from(same),
    );
    assert_eq!(same_frames, 40);
    let index = s.m.registry().hitbox_index();
    assert!(index.len() > 32 && index.len() <= 64, "{}", index.len());
    // The far border's cell was used.
    assert!((0..index.len()).any(|i| index.cell(i).is_some_and(|(x, _)| x == 7)));
    assert!(s.m.stats().instances.active > 0);
}

#[test]
fn with_eviction_emptied_cells_are_dropped_and_indices_reused() {
    // Few instances per cell, so cells empty out as instances move away.
    let h = run_both(1, 60, |_, _| {});
    assert!(h.evicted > 0, "no cell was evicted");
    let m = &h.m;
    let index = m.registry().hitbox_index();
    assert_eq!(m.hitboxes().len() as u32, index.len());
    // Every live instance's hitbox is a live cell that holds its centre,
    // and the occupant counts add up to the live instances.
    let mut total = 0;
    for (handle, slot) in m.registry().iter() {
        let r = m.records().get(slot as usize).unwrap();
        let aabb = Aabb::new(Vec3::from_array(r.aabb_min), Vec3::from_array(r.aabb_max));
        assert_eq!(index.hitbox_of(&aabb), Some(r.hitbox), "{handle:?}");
        total += 1;
    }
    let occupants: u32 = (0..index.len()).map(|i| index.occupants(i)).sum();
    assert_eq!(occupants, total);
    // Indices without a cell have no bounds and carry no state.
    for i in 0..index.len() {
        if index.cell(i).is_none() {
            assert_eq!(index.xz_bounds(i), None);
            assert!(!m.hitboxes()[i as usize].is_active());
            assert_eq!(m.hitboxes()[i as usize].streak(), 0);
        }
    }
    assert!(index.len() <= 64);
}

#[test]
fn a_hashed_manager_records_an_unbounded_world() {
    use lipac_core::manager::{RecorderOptions, TraceRecorder};
    use lipac_core::trace::{InstanceEvent, TraceReader};
    let mut m = Manager::new(hashed(64), config(), catalog()).unwrap();
    m.attach_recorder(TraceRecorder::new(Vec::new(), RecorderOptions::default()))
        .unwrap();
    // 2000 km apart: no bounds needed.
    m.register(desc(-1.0e6, 3.0, 1)).unwrap();
    m.register(desc(1.0e6, -7.0, 2)).unwrap();
    m.begin_frame(0).unwrap();
    m.plan(&FrameBudgets::default()).unwrap();
    assert_eq!(m.hitboxes().len(), 2);
    let bytes: Vec<u8> = m.detach_recorder().unwrap().into_writer().unwrap();
    let mut r = TraceReader::new(bytes.as_slice()).unwrap();
    let world = r.header().world;
    assert!(!world.is_bounded());
    assert_eq!(world.cell_size, CELL);
    let f0 = r.next_frame().unwrap().unwrap();
    assert_eq!(
        f0.events
            .iter()
            .filter(|e| matches!(e, InstanceEvent::Add(_)))
            .count(),
        2
    );
    // Another origin has no unbounded world of its own: the caller names it.
    let moved = HashedHitboxes::new(HashedConfig {
        origin: [8.0, 0.0],
        ..HashedConfig::default()
    })
    .unwrap();
    let mut m = Manager::new(moved, config(), catalog()).unwrap();
    assert!(m
        .attach_recorder(TraceRecorder::new(Vec::new(), RecorderOptions::default()))
        .is_err());
}
