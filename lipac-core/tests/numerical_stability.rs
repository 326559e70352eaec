//! Numerical stability of the geometry lipac puts into the TLAS
//! (`docs/PRECISION.md` states the guarantees these tests back).
//!
//! Core property: a counting box never misses any part of the region it
//! stands for. The boxes are checked the way a GPU evaluates them: the unit
//! cube's 8 corners and points on its faces are transformed with the f32
//! 3x4 TLAS matrix, in f32 (separate multiply and add, several summation
//! orders, and fused multiply-add), and the results are compared with the
//! target region in exact f64 arithmetic. Regimes: near the origin and
//! ±100 km (f32 step 7.8 mm) to ±10^7 m, zero-extent and huge
//! (registry-maximum) extents, unaligned grids whose borders are no f32
//! values, flat hitboxes, instances on cell borders and the far border,
//! a camera inside boxes, and instance transforms with scales 1e-6 … 1e6
//! and rotations.

use glam::camera::rh::{proj, view};
use glam::{Affine3A, Quat, Vec3};
use lipac_core::assembly::{
    assemble_tlas, AssemblyConfig, AssemblyError, AssemblyStats, COUNTING_BOX_FLAGS,
};
use lipac_core::culling::{Culling, CullingConfig};
use lipac_core::error::CoreError;
use lipac_core::grid::{GridConfig, HitboxGrid};
use lipac_core::hitbox_extents::write_extents;
use lipac_core::hitbox_index::HitboxIndex;
use lipac_core::instance::{InstanceDesc, MeshId};
use lipac_core::latency::{ActivationHeuristic, Frustum};
use lipac_core::layout::{
    hitbox_bits, instance_bits, HitboxRecord, InstanceArrays, InstanceRecord, InstanceState,
    TlasInstance, VK_INSTANCE_CULL_DISABLE,
};
use lipac_core::math::{affine_to_rows, Aabb};
use lipac_core::registry::{InstanceRegistry, RegistryConfig};
use lipac_test_support::{Rng64, SplitMix64 as Rng};

/// Algorithm 1 on hand-made arrays: the hitbox extents first (the CPU's
/// part, `write_extents`), then `assemble_tlas`.
fn assemble_with_extents(
    instances: &InstanceArrays,
    hitboxes: &mut [HitboxRecord],
    index: &impl HitboxIndex,
    cfg: &AssemblyConfig,
    out: &mut Vec<TlasInstance>,
) -> Result<AssemblyStats, AssemblyError> {
    write_extents(instances, hitboxes);
    assemble_tlas(instances, hitboxes, index, cfg, out)
}

const CUBE: u64 = 0xC0BE;

// ---- helpers ----------------------------------------------------------------

/// An extent: 0, tiny, or log-uniform in [1e-6, max].
fn extent(rng: &mut Rng, max: f64) -> f32 {
    match rng.below_u32(8) {
        0 => 0.0,
        1 => f32::from_bits(1 + rng.below_u32(1000)), // subnormal
        _ => (1e-6f64 * (max / 1e-6).powf(rng.unit_f64())) as f32,
    }
}

fn pred(x: f32) -> f32 {
    if x == 0.0 {
        -f32::from_bits(1)
    } else if x > 0.0 {
        f32::from_bits(x.to_bits() - 1)
    } else {
        f32::from_bits(x.to_bits() + 1)
    }
}

fn succ(x: f32) -> f32 {
    -pred(-x)
}

/// How the hardware might evaluate one row `m[4r..4r+4]` at `u`.
#[derive(Clone, Copy, Debug)]
enum Eval {
    /// ((m0 u0 + m1 u1) + m2 u2) + m3, separate multiply and add.
    LeftToRight,
    /// m3 + (m0 u0 + (m1 u1 + m2 u2)).
    RightToLeft,
    /// fma(m0, u0, fma(m1, u1, fma(m2, u2, m3))).
    Fma,
}

const EVALS: [Eval; 3] = [Eval::LeftToRight, Eval::RightToLeft, Eval::Fma];

/// Transforms a point of the unit cube with a row-major 3x4 matrix in f32.
fn transform(m: &[f32; 12], u: [f32; 3], eval: Eval) -> [f32; 3] {
    std::array::from_fn(|r| {
        let row = &m[4 * r..4 * r + 4];
        match eval {
            Eval::LeftToRight => ((row[0] * u[0] + row[1] * u[1]) + row[2] * u[2]) + row[3],
            Eval::RightToLeft => row[3] + (row[0] * u[0] + (row[1] * u[1] + row[2] * u[2])),
            Eval::Fma => row[0].mul_add(u[0], row[1].mul_add(u[1], row[2].mul_add(u[2], row[3]))),
        }
    })
}

/// Points of the unit cube's surface: the 8 corners and, on every face,
/// points with awkward coordinates.
fn cube_surface() -> Vec<[f32; 3]> {
    let inner = [
        0.0,
        1.0,
        0.5,
        1.0 / 3.0,
        pred(1.0),
        f32::from_bits(1),
        0.999_9,
    ];
    let mut points = Vec::new();
    for axis in 0..3 {
        for side in [0.0f32, 1.0] {
            for &a in &inner {
                for &b in &inner {
                    let mut p = [0.0; 3];
                    p[axis] = side;
                    p[(axis + 1) % 3] = a;
                    p[(axis + 2) % 3] = b;
                    points.push(p);
                }
            }
        }
    }
    points
}

/// Checks that the unit cube, transformed by `m` every way the hardware may
/// evaluate it, encloses the exact region `[lo, hi]` (f64): its faces at
/// `u_axis = 0` lie at or below `lo`, those at `u_axis = 1` at or above
/// `hi`, and no surface point leaves the corners' box (so the faces are
/// planar boxes, not wobbling inwards).
fn assert_box_contains(m: &[f32; 12], lo: [f64; 3], hi: [f64; 3], what: &str) {
    for eval in EVALS {
        let c0 = transform(m, [0.0; 3], eval);
        let c1 = transform(m, [1.0; 3], eval);
        for axis in 0..3 {
            assert!(
                f64::from(c0[axis]) <= lo[axis] && f64::from(c1[axis]) >= hi[axis],
                "{what} ({eval:?}) axis {axis}: box {}..{} misses {}..{}",
                c0[axis],
                c1[axis],
                lo[axis],
                hi[axis]
            );
        }
        for u in cube_surface() {
            let p = transform(m, u, eval);
            for axis in 0..3 {
                let v = f64::from(p[axis]);
                assert!(
                    v >= f64::from(c0[axis]) && v <= f64::from(c1[axis]),
                    "{what} ({eval:?}): surface point {u:?} -> {p:?} leaves the box"
                );
                if u[axis] == 0.0 {
                    assert!(v <= lo[axis], "{what} ({eval:?}): low face inside");
                }
                if u[axis] == 1.0 {
                    assert!(v >= hi[axis], "{what} ({eval:?}): high face inside");
                }
            }
        }
    }
}

fn live(state: InstanceState, hitbox: u32, min: Vec3, max: Vec3) -> InstanceRecord {
    let mut r = InstanceRecord {
        aabb_min: min.to_array(),
        aabb_max: max.to_array(),
        hitbox,
        packed: instance_bits::ALIVE,
        ..Default::default()
    };
    r.set_state(state);
    r
}

fn active_hitbox() -> HitboxRecord {
    HitboxRecord {
        packed: hitbox_bits::ACTIVE,
        ..Default::default()
    }
}

fn grid(min: [f64; 2], cells: [u32; 2], cell: f64) -> HitboxGrid {
    HitboxGrid::new(GridConfig {
        min,
        max: [
            min[0] + f64::from(cells[0]) * cell,
            min[1] + f64::from(cells[1]) * cell,
        ],
        cell_size: cell,
    })
    .unwrap()
}

/// The exact centre of `[a, b]` in f64, if the sum is exact (it is for the
/// regimes used here; checked with TwoSum).
fn exact_center(a: f32, b: f32) -> f64 {
    let (a, b) = (f64::from(a), f64::from(b));
    let s = a + b;
    let bb = s - a;
    assert_eq!((a - (s - bb)) + (b - bb), 0.0, "test needs an exact sum");
    s / 2.0
}

/// Centres used for random boxes: near the origin, ±100 km, and beyond.
const CENTRES: [f64; 9] = [
    0.0, -3.3, 1_000.5, 99_999.99, -100_000.0, 100_000.0, 65_536.0, -1.0e6, 1.0e7,
];

// ---- omitted boxes ------------------------------------------------------------

#[test]
fn omitted_boxes_contain_the_instance_aabb_in_every_regime() {
    let mut rng = Rng::new(1);
    let index = grid([-2.0e7, -2.0e7], [1, 1], 4.0e7);
    let mut cfg = AssemblyConfig::new(CUBE);
    let mut out = Vec::new();
    let mut checked = 0;
    for &centre in &CENTRES {
        for i in 0..600 {
            // The registry's maximum extent is 1e6 m.
            let max_extent = if i % 3 == 0 { 1.0e6 } else { 50.0 };
            let min = Vec3::new(
                rng.range_f64(centre - 10.0, centre + 10.0) as f32,
                rng.range_f64(centre * 0.5 - 10.0, centre * 0.5 + 10.0) as f32,
                rng.range_f64(-centre - 10.0, -centre + 10.0) as f32,
            );
            let size = Vec3::new(
                extent(&mut rng, max_extent),
                extent(&mut rng, max_extent),
                extent(&mut rng, max_extent),
            );
            let max = min + size; // rounded: still >= min
            cfg.min_box_extent = [0.0, 1e-3, 0.5][rng.below_u32(3) as usize];
            let rec = live(InstanceState::Omitted, 0, min, max);
            let mut hitboxes = [active_hitbox()];
            let stats = assemble_with_extents(
                &InstanceArrays::from_records(&[rec]),
                &mut hitboxes,
                &index,
                &cfg,
                &mut out,
            )
            .unwrap();
            assert_eq!(stats.omitted_boxes, 1);
            let m = out[0].transform;
            let what = format!("omitted {min} {max} pad {}", cfg.min_box_extent);
            assert_box_contains(
                &m,
                min.to_array().map(f64::from),
                max.to_array().map(f64::from),
                &what,
            );
            // Not degenerate, and never grossly larger than needed: at most
            // the padding plus 2 f32 steps of the far corner per axis.
            for axis in 0..3 {
                let (lo, hi) = (m[4 * axis + 3], m[5 * axis] + m[4 * axis + 3]);
                assert!(hi > lo, "{what}: zero-thickness box");
                let need = f64::from(max[axis]) - f64::from(min[axis]);
                let pad = f64::from(cfg.min_box_extent).max(need);
                let step = f64::from(succ(hi.abs().max(lo.abs())) - hi.abs().max(lo.abs()));
                assert!(
                    f64::from(hi) - f64::from(lo) <= pad + 4.0 * step + pad * 1e-6,
                    "{what}: box {lo}..{hi} too large"
                );
            }
            checked += 1;
        }
    }
    assert_eq!(checked, CENTRES.len() * 600);
}

#[test]
fn zero_extent_boxes_get_a_box_at_least_one_step_thick() {
    let index = grid([-2.0e5, -2.0e5], [1, 1], 4.0e5);
    for p in [0.0f32, 1.0, -1.0e-30, 99_999.99, -100_000.0, 131_072.0] {
        let pt = Vec3::splat(p);
        for pad in [0.0, 1e-3, 1.0] {
            let mut cfg = AssemblyConfig::new(CUBE);
            cfg.min_box_extent = pad;
            let mut out = Vec::new();
            let rec = live(InstanceState::Omitted, 0, pt, pt);
            assemble_with_extents(
                &InstanceArrays::from_records(&[rec]),
                &mut [active_hitbox()],
                &index,
                &cfg,
                &mut out,
            )
            .unwrap();
            let m = out[0].transform;
            assert_box_contains(&m, [f64::from(p); 3], [f64::from(p); 3], "point");
            for eval in EVALS {
                let (c0, c1) = (transform(&m, [0.0; 3], eval), transform(&m, [1.0; 3], eval));
                for axis in 0..3 {
                    assert!(c1[axis] > c0[axis], "zero-thickness box at {p}");
                    // The padding is honoured up to f32 rounding of the corners.
                    let thick = f64::from(c1[axis]) - f64::from(c0[axis]);
                    let step = f64::from(succ(p.abs()) - p.abs());
                    assert!(thick + 2.0 * step >= f64::from(pad), "{p} {pad}: {thick}");
                }
            }
        }
    }
}

// ---- hitbox boxes ------------------------------------------------------------

/// Grids in several regimes: aligned and unaligned origins, cell sizes whose
/// borders are no f32 values, near the origin and ±100 km away.
fn test_grids() -> Vec<HitboxGrid> {
    vec![
        grid([-64.0, -64.0], [8, 8], 16.0),
        grid([-100_000.0, -100_000.0], [8, 8], 16.0),
        grid([99_872.0, -100_000.0], [8, 8], 16.0), // far border at 100 km
        grid([-100_000.3, 99_000.7], [8, 8], 16.1),
        grid([12_345.678, -0.001], [8, 8], 0.37),
        grid([-1.0e6 - 0.25, 3.3], [8, 8], 1000.01),
    ]
}

#[test]
fn hitbox_boxes_contain_cell_and_height_range_in_every_regime() {
    let mut rng = Rng::new(2);
    let cfg = AssemblyConfig::new(CUBE);
    let mut out = Vec::new();
    for g in test_grids() {
        let n = g.len();
        for _ in 0..300 {
            let hitbox = rng.below_u32(n);
            let (lo, hi) = g.bounds_f64(hitbox).unwrap();
            // 1..4 inactive instances; their x/z does not matter to the box.
            let y0 = rng.range_f64(-100_000.0, 100_000.0);
            let mut records = Vec::new();
            let (mut min_y, mut max_y) = (f32::INFINITY, f32::NEG_INFINITY);
            for _ in 0..1 + rng.below_u32(4) {
                let a = (y0 + rng.range_f64(-5.0, 5.0)) as f32;
                let b = if rng.below_u32(3) == 0 {
                    a // flat
                } else {
                    a + extent(&mut rng, 1.0e3)
                };
                min_y = min_y.min(a);
                max_y = max_y.max(b);
                let c = Vec3::new(lo[0] as f32, a, lo[1] as f32);
                records.push(live(
                    InstanceState::Inactive,
                    hitbox,
                    c,
                    c + Vec3::Y * (b - a),
                ));
            }
            let mut hitboxes = vec![HitboxRecord::default(); n as usize];
            let stats = assemble_with_extents(
                &InstanceArrays::from_records(&records),
                &mut hitboxes,
                &g,
                &cfg,
                &mut out,
            )
            .unwrap();
            assert_eq!((stats.hitbox_boxes, out.len()), (1, 1));
            assert_eq!(out[0].custom_index(), hitbox);
            assert_eq!(
                (
                    hitboxes[hitbox as usize].min_y,
                    hitboxes[hitbox as usize].max_y
                ),
                (min_y, max_y)
            );
            assert_box_contains(
                &out[0].transform,
                [lo[0], f64::from(min_y), lo[1]],
                [hi[0], f64::from(max_y), hi[1]],
                &format!("hitbox {hitbox} of {g:?}, y {min_y}..{max_y}"),
            );
        }
    }
}

#[test]
fn neighbouring_hitbox_boxes_leave_no_gap() {
    // Every cell's box reaches at least to where its neighbour's begins, in
    // f32 as the hardware computes the corners.
    let cfg = AssemblyConfig::new(CUBE);
    for g in test_grids() {
        let (nx, nz) = g.dims();
        let n = g.len() as usize;
        // One flat inactive instance per cell.
        let records: Vec<_> = (0..g.len())
            .map(|i| {
                let (lo, _) = g.bounds_f64(i).unwrap();
                let c = Vec3::new(lo[0] as f32, 2.0, lo[1] as f32);
                live(InstanceState::Inactive, i, c, c)
            })
            .collect();
        let mut hitboxes = vec![HitboxRecord::default(); n];
        let mut out = Vec::new();
        let stats = assemble_with_extents(
            &InstanceArrays::from_records(&records),
            &mut hitboxes,
            &g,
            &cfg,
            &mut out,
        )
        .unwrap();
        assert_eq!(stats.flat_hitbox_boxes, g.len());
        let mut boxes = vec![([0.0f32; 3], [0.0f32; 3]); n];
        for r in &out {
            let m = r.transform;
            boxes[r.custom_index() as usize] = (
                transform(&m, [0.0; 3], Eval::LeftToRight),
                transform(&m, [1.0; 3], Eval::LeftToRight),
            );
        }
        for cz in 0..nz {
            for cx in 0..nx {
                let i = g.index(cx, cz).unwrap() as usize;
                if let Some(r) = g.index(cx + 1, cz) {
                    assert!(boxes[i].1[0] >= boxes[r as usize].0[0], "x gap after {i}");
                }
                if let Some(u) = g.index(cx, cz + 1) {
                    assert!(boxes[i].1[2] >= boxes[u as usize].0[2], "z gap after {i}");
                }
            }
        }
    }
}

#[test]
fn flat_hitbox_keeps_a_box_that_contains_its_height() {
    // All inactive instances of the cell at the same height (decals, a
    // ground plane), near and far from the origin: the printed algorithm's
    // `minY < maxY` would drop the box; here it exists and contains y.
    let g = grid([-100_000.0, -100_000.0], [4, 4], 16.0);
    for y in [0.0f32, 7.25, -0.001, 99_999.99, -100_000.0] {
        for pad in [0.0f32, 1e-3] {
            let mut cfg = AssemblyConfig::new(CUBE);
            cfg.min_box_extent = pad;
            let c = Vec3::new(-99_990.0, y, -99_990.0);
            let recs = [
                live(InstanceState::Inactive, 0, c, c + Vec3::new(3.0, 0.0, 1.0)),
                live(InstanceState::Inactive, 0, c, c),
            ];
            let mut hb = vec![HitboxRecord::default(); 16];
            let mut out = Vec::new();
            let stats = assemble_with_extents(
                &InstanceArrays::from_records(&recs),
                &mut hb,
                &g,
                &cfg,
                &mut out,
            )
            .unwrap();
            assert_eq!((stats.hitbox_boxes, stats.flat_hitbox_boxes), (1, 1));
            let (lo, hi) = g.bounds_f64(0).unwrap();
            let y = f64::from(y);
            assert_box_contains(
                &out[0].transform,
                [lo[0], y, lo[1]],
                [hi[0], y, hi[1]],
                "flat",
            );
            let m = out[0].transform;
            assert!(m[5] > 0.0, "flat box has zero height");
        }
    }
}

// ---- instance -> hitbox assignment --------------------------------------------

/// The registry's rule: the cell whose exact (f64) half-open bounds hold the
/// exact centre of the f32 AABB; a centre on the far border of the world
/// belongs to the last cell.
#[test]
fn assignment_uses_the_exact_centre_in_every_regime() {
    let mut rng = Rng::new(3);
    for g in test_grids() {
        let mut reg = InstanceRegistry::new(g.clone(), RegistryConfig::default()).unwrap();
        let [x0, z0] = g.min();
        let [x1, z1] = g.max();
        let (nx, nz) = g.dims();
        let mut disagreements_with_f32_centre = 0;
        for i in 0..3000 {
            // Centres spread over the world, a third of them snapped to a
            // border or next to one.
            let mut pick = |lo: f64, hi: f64, cell: f64, n: u32| -> f64 {
                match i % 3 {
                    0 => rng.range_f64(lo, hi),
                    _ => lo + f64::from(rng.below_u32(n + 1)) * cell,
                }
            };
            let cx = pick(x0, x1, g.cell_size(), nx);
            let cz = pick(z0, z1, g.cell_size(), nz);
            let half = extent(&mut rng, g.cell_size() * 2.0) * 0.5;
            // f32 corners around the (possibly non-f32) centre, nudged by a
            // few f32 steps so the exact centre sits on all sides of a border.
            let mut corner = |c: f64, sign: f32| {
                let mut v = (c as f32) + sign * half;
                for _ in 0..rng.below_u32(3) {
                    v = if rng.below_u32(2) == 0 {
                        pred(v)
                    } else {
                        succ(v)
                    };
                }
                v
            };
            let (ax, bx) = (corner(cx, -1.0), corner(cx, 1.0));
            let (az, bz) = (corner(cz, -1.0), corner(cz, 1.0));
            let aabb = Aabb::new(
                Vec3::new(ax.min(bx), 0.0, az.min(bz)),
                Vec3::new(ax.max(bx), 1.0, az.max(bz)),
            );
            let (ex, ez) = (
                exact_center(aabb.min.x, aabb.max.x),
                exact_center(aabb.min.z, aabb.max.z),
            );
            let inside = (x0..=x1).contains(&ex) && (z0..=z1).contains(&ez);
            let desc = InstanceDesc::new(MeshId(0), Affine3A::IDENTITY, aabb);
            match reg.register(desc) {
                Ok(h) => {
                    assert!(inside, "{aabb:?} accepted with its centre outside");
                    let hitbox = reg.record(h).unwrap().hitbox;
                    let (lo, hi) = g.bounds_f64(hitbox).unwrap();
                    let (kx, kz) = g.cell(hitbox).unwrap();
                    assert!(
                        lo[0] <= ex && (ex < hi[0] || (kx + 1 == nx && ex == hi[0])),
                        "x centre {ex} not in cell {kx} [{}, {})",
                        lo[0],
                        hi[0]
                    );
                    assert!(
                        lo[1] <= ez && (ez < hi[1] || (kz + 1 == nz && ez == hi[1])),
                        "z centre {ez} not in cell {kz} [{}, {})",
                        lo[1],
                        hi[1]
                    );
                    // The f32 bounds of the cell (what the GPU box uses)
                    // contain the exact centre too.
                    let (flo, fhi) = g.xz_bounds(hitbox).unwrap();
                    assert!(f64::from(flo.x) <= ex && ex <= f64::from(fhi.x));
                    assert!(f64::from(flo.y) <= ez && ez <= f64::from(fhi.y));
                    if g.hitbox_at(aabb.center()) != Some(hitbox) {
                        disagreements_with_f32_centre += 1;
                    }
                }
                Err(CoreError::OutsideWorld { .. }) => {
                    assert!(!inside, "{aabb:?} rejected with its centre inside")
                }
                Err(e) => panic!("{aabb:?}: {e}"),
            }
        }
        // Informational: how often rounding the centre to f32 would have
        // picked another (adjacent) cell or rejected the instance.
        println!("{g:?}: the f32 centre disagrees {disagreements_with_f32_centre} times");
    }
}

#[test]
fn instances_exactly_on_borders_go_to_the_upper_cell_and_far_border_to_the_last() {
    for g in test_grids() {
        let mut reg = InstanceRegistry::new(g.clone(), RegistryConfig::default()).unwrap();
        let (nx, nz) = g.dims();
        let [x0, z0] = g.min();
        let cell = g.cell_size();
        for k in 0..=nx {
            // An f32 box whose exact x centre is the f32 value nearest to
            // border k (on it where the border is an f32 value).
            let b = x0 + f64::from(k) * cell;
            let bf = b as f32;
            let z = (z0 + 0.5 * cell) as f32;
            let aabb = Aabb::new(Vec3::new(pred(bf), 0.0, z), Vec3::new(succ(bf), 2.0, z));
            let ex = exact_center(aabb.min.x, aabb.max.x);
            let res = reg.register(InstanceDesc::new(MeshId(0), Affine3A::IDENTITY, aabb));
            let want = if ex < b {
                Some(k.checked_sub(1))
            } else if ex == b {
                Some(Some(k.min(nx - 1))) // upper cell; the far border: last
            } else if k < nx {
                Some(Some(k))
            } else {
                None // beyond the far border
            };
            match (want, res) {
                (Some(Some(cx)), Ok(h)) => {
                    let hitbox = reg.record(h).unwrap().hitbox;
                    assert_eq!(g.cell(hitbox), Some((cx, 0)), "border {k} of {g:?}");
                }
                (Some(None) | None, Err(CoreError::OutsideWorld { .. })) => {}
                (w, r) => panic!("border {k} of {g:?}: wanted {w:?}, got {r:?}"),
            }
        }
        // The far corner of the world exactly (where it is an f32 value).
        let [x1, z1] = g.max();
        if f64::from(x1 as f32) == x1 && f64::from(z1 as f32) == z1 {
            let p = Vec3::new(x1 as f32, 0.0, z1 as f32);
            let h = reg
                .register(InstanceDesc::new(
                    MeshId(0),
                    Affine3A::IDENTITY,
                    Aabb::new(p, p),
                ))
                .unwrap();
            let hitbox = reg.record(h).unwrap().hitbox;
            assert_eq!(g.cell(hitbox), Some((nx - 1, nz - 1)));
        }
    }
}

// ---- huge and degenerate AABBs through the registry ----------------------------

#[test]
fn registry_extent_limit_and_huge_boxes() {
    let g = grid([-2.0e6, -2.0e6], [4, 4], 1.0e6);
    let cfg = RegistryConfig::default();
    let mut reg = InstanceRegistry::new(g, cfg).unwrap();
    let max = cfg.max_aabb_extent;
    // Exactly the maximum extent, ±100 km off-centre: accepted.
    let lo = Vec3::new(-100_000.0, -100_000.0, 100_000.0);
    let ok = Aabb::new(lo, lo + Vec3::splat(max));
    assert_eq!(ok.size(), Vec3::splat(max));
    reg.register(InstanceDesc::new(MeshId(0), Affine3A::IDENTITY, ok))
        .unwrap();
    // One f32 step more than the maximum along y: rejected with a clear error.
    let bad = Aabb::new(lo, Vec3::new(ok.max.x, succ(ok.max.y), ok.max.z));
    match reg.register(InstanceDesc::new(MeshId(0), Affine3A::IDENTITY, bad)) {
        Err(CoreError::InvalidAabb { reason, .. }) => assert!(reason.contains("along y")),
        other => panic!("{other:?}"),
    }
    // Zero-extent boxes anywhere inside are fine.
    for p in [
        Vec3::ZERO,
        Vec3::splat(-100_000.0),
        Vec3::new(1.0e6, 5.0, -1.0e6),
    ] {
        reg.register(InstanceDesc::new(
            MeshId(0),
            Affine3A::IDENTITY,
            Aabb::new(p, p),
        ))
        .unwrap();
    }
    // The whole pipeline on those records: every box contains its target.
    let mut records = reg.records().to_vec();
    for r in &mut records {
        r.set_state(InstanceState::Omitted);
    }
    let mut hb = vec![active_hitbox(); 16];
    let mut out = Vec::new();
    let stats = assemble_with_extents(
        &InstanceArrays::from_records(&records),
        &mut hb,
        reg.hitbox_index(),
        &AssemblyConfig::new(CUBE),
        &mut out,
    )
    .unwrap();
    assert_eq!(stats.omitted_boxes as usize, records.len());
    for (r, t) in records.iter().zip(&out) {
        assert_box_contains(
            &t.transform,
            r.aabb_min.map(f64::from),
            r.aabb_max.map(f64::from),
            "registered",
        );
    }
}

// ---- instance transforms: tiny and huge scales, rotations ----------------------

/// A conservative world AABB of `local` under `t`, computed in f64 from the
/// exact f32 matrix, widened by a bound on the GPU's f32 evaluation error
/// of each corner (at most 3 roundings of partial sums and 3 of products,
/// each half an ulp: |error| <= 6 · 2^-24 · (Σ|m_j p_j| + |t|); 8 · 2^-24
/// used) and rounded outwards (what a careful engine does).
fn conservative_aabb(t: &Affine3A, local: &Aabb) -> Aabb {
    let m = affine_to_rows(t).map(f64::from);
    let mut lo = [f64::INFINITY; 3];
    let mut hi = [f64::NEG_INFINITY; 3];
    let eps = 8.0 * f64::powi(2.0, -24);
    for i in 0..8 {
        let p = [
            if i & 1 == 0 { local.min.x } else { local.max.x },
            if i & 2 == 0 { local.min.y } else { local.max.y },
            if i & 4 == 0 { local.min.z } else { local.max.z },
        ]
        .map(f64::from);
        for r in 0..3 {
            let v = m[4 * r] * p[0] + m[4 * r + 1] * p[1] + m[4 * r + 2] * p[2] + m[4 * r + 3];
            let mag = (m[4 * r] * p[0]).abs()
                + (m[4 * r + 1] * p[1]).abs()
                + (m[4 * r + 2] * p[2]).abs()
                + m[4 * r + 3].abs();
            lo[r] = lo[r].min(v - eps * mag);
            hi[r] = hi[r].max(v + eps * mag);
        }
    }
    // f64 error is far below an f32 step; step one f32 outwards.
    Aabb::new(
        Vec3::from(lo.map(|v| pred(v as f32))),
        Vec3::from(hi.map(|v| succ(v as f32))),
    )
}

#[test]
fn tiny_and_huge_scales_and_rotations_round_trip_and_stay_enclosed() {
    let local = Aabb::new(Vec3::new(-0.5, 0.0, -0.25), Vec3::new(0.5, 0.4, 0.25));
    let g = grid([-200_000.0, -200_000.0], [20, 20], 20_000.0);
    let mut reg = InstanceRegistry::new(g, RegistryConfig::default()).unwrap();
    let mut rng = Rng::new(4);
    let mut accepted = 0;
    for &scale in &[1e-6f32, 1e-3, 1.0, 37.5, 1e4, 1e6] {
        for _ in 0..40 {
            let rot = Quat::from_euler(
                glam::EulerRot::YXZ,
                rng.range_f64(-3.2, 3.2) as f32,
                rng.range_f64(-1.6, 1.6) as f32,
                rng.range_f64(-3.2, 3.2) as f32,
            );
            let pos = Vec3::new(
                rng.range_f64(-100_000.0, 100_000.0) as f32,
                rng.range_f64(-100.0, 100.0) as f32,
                rng.range_f64(-100_000.0, 100_000.0) as f32,
            );
            let t = Affine3A::from_scale_rotation_translation(Vec3::splat(scale), rot, pos);
            let aabb = conservative_aabb(&t, &local);
            let desc = InstanceDesc::new(MeshId(1), t, aabb);
            let h = match reg.register(desc) {
                Ok(h) => h,
                Err(CoreError::InvalidAabb { .. }) => {
                    // Only a scale whose world box exceeds the 1e6 m limit.
                    assert!(aabb.size().max_element() > 1.0e6, "{scale} {aabb:?}");
                    continue;
                }
                Err(e) => panic!("{scale}: {e}"),
            };
            accepted += 1;
            let slot = reg.slot(h).unwrap();
            let rec = reg.record(h).unwrap();
            // The record carries the engine's matrix bit for bit.
            assert_eq!(
                rec.transform.map(f32::to_bits),
                affine_to_rows(&t).map(f32::to_bits)
            );
            // An active instance's TLAS record carries it unchanged.
            let mut active = rec;
            active.set_state(InstanceState::Active);
            active.blas = 0xB1A5;
            let mut omitted = rec;
            omitted.set_state(InstanceState::Omitted);
            let mut hb = vec![active_hitbox(); reg.hitbox_index().len() as usize];
            let mut out: Vec<TlasInstance> = Vec::new();
            assemble_with_extents(
                &InstanceArrays::from_records(&[active, omitted]),
                &mut hb,
                reg.hitbox_index(),
                &AssemblyConfig::new(CUBE),
                &mut out,
            )
            .unwrap();
            assert_eq!(
                out[0].transform.map(f32::to_bits),
                rec.transform.map(f32::to_bits)
            );
            // The mesh's corners, transformed by the GPU in f32, lie inside
            // the omitted counting box (both the AABB and the box are
            // conservative).
            let cube = out[1].transform;
            for eval in EVALS {
                let (c0, c1) = (
                    transform(&cube, [0.0; 3], eval),
                    transform(&cube, [1.0; 3], eval),
                );
                for i in 0..8u32 {
                    let p = Vec3::select(
                        glam::BVec3::new(i & 1 != 0, i & 2 != 0, i & 4 != 0),
                        local.max,
                        local.min,
                    );
                    let w = transform(&rec.transform, p.to_array(), eval);
                    for a in 0..3 {
                        assert!(
                            c0[a] <= w[a] && w[a] <= c1[a],
                            "scale {scale} slot {slot}: corner {w:?} outside {c0:?}..{c1:?}"
                        );
                    }
                }
            }
        }
    }
    assert!(accepted >= 5 * 40, "only {accepted} accepted");
}

// ---- camera inside a box ------------------------------------------------------

fn frustum_at(camera: Vec3, dir: Vec3, near: f32) -> Frustum {
    let view = view::look_to_mat4(camera, dir, Vec3::Y);
    let proj = proj::vulkan::perspective(60f32.to_radians(), 16.0 / 9.0, near, 5000.0);
    Frustum::from_view_projection(proj * view).unwrap()
}

#[test]
fn camera_inside_instances_and_hitboxes_far_from_the_origin() {
    for origin in [0.0f64, -100_000.0, 99_840.0] {
        let g = grid([origin, origin], [16, 16], 16.0);
        let mut cfg = CullingConfig::new(CUBE);
        cfg.latency_mitigation = Some(ActivationHeuristic {
            max_distance: 30.0,
            min_projected_size: 0.1,
            surround_radius: 0.0,
        });
        let mut culling = Culling::new(g.clone(), cfg).unwrap();
        let o = origin as f32;
        let camera = Vec3::new(o + 40.0, 1.7, o + 40.0); // inside cell (2, 2)
        let aabb = |min: Vec3, max: Vec3| {
            InstanceDesc::new(
                MeshId(1),
                Affine3A::from_translation(min),
                Aabb::new(min, max),
            )
        };
        // A building the camera stands in (its box encloses the camera).
        let building = culling
            .register(aabb(
                camera - Vec3::new(5.0, 1.7, 5.0),
                camera + Vec3::new(5.0, 8.0, 5.0),
            ))
            .unwrap();
        // A small box around the camera that does not reach the near plane
        // (a helmet, a handheld lamp): rays from the camera start inside it.
        let helmet = culling
            .register(aabb(camera - Vec3::splat(0.05), camera + Vec3::splat(0.05)))
            .unwrap();
        // A crate right in front (1 m) and one right behind.
        let ahead = culling
            .register(aabb(
                camera + Vec3::new(-0.3, -0.3, -1.3),
                camera + Vec3::new(0.3, 0.3, -0.9),
            ))
            .unwrap();
        let behind = culling
            .register(aabb(
                camera + Vec3::new(-0.3, -0.3, 0.9),
                camera + Vec3::new(0.3, 0.3, 1.3),
            ))
            .unwrap();
        // A cell boundary box the camera is inside of: only inactive ones
        // get a box, so check that box before mitigation.
        culling.begin_frame(0).unwrap();
        let mut tlas = Vec::new();
        culling.assemble(&mut tlas).unwrap();
        let camera_hitbox = g.hitbox_at(camera).unwrap();
        let cell_box = tlas
            .iter()
            .find(|r| r.custom_index() == camera_hitbox && r.sbt_offset() == 2)
            .expect("the camera's cell has a counting box");
        // The camera is strictly inside its cell's counting box, so every
        // primary ray starts inside it and leaves through a face, which it
        // hits because counting boxes are cull-disabled (one count per ray:
        // the counting mask is then masked out).
        let (c0, c1) = (
            transform(&cell_box.transform, [0.0; 3], Eval::Fma),
            transform(&cell_box.transform, [1.0; 3], Eval::Fma),
        );
        assert!(Vec3::from(c0).cmplt(camera).all() && Vec3::from(c1).cmpgt(camera).all());
        assert_eq!(cell_box.flags(), COUNTING_BOX_FLAGS);
        assert_ne!(cell_box.flags() & VK_INSTANCE_CULL_DISABLE, 0);
        culling.process_feedback().unwrap();
        culling.take_commands().unwrap();

        // Latency mitigation with the camera looking down -z.
        culling.begin_frame(1).unwrap();
        let frustum = frustum_at(camera, Vec3::NEG_Z, 0.1);
        if origin == 0.0 {
            // Near the origin the plane test separates it (behind the near
            // plane); at 100 km its relative slack (1e-6 of the terms'
            // magnitude, ~0.1 m there) may not. Either way it must be seen.
            assert!(!frustum.intersects_aabb(&culling.registry().desc(helmet).unwrap().aabb));
        }
        let outcome = culling.mitigate_latency(camera, &frustum).unwrap();
        let requested: Vec<_> = outcome.requests.iter().map(|r| r.handle).collect();
        assert!(requested.contains(&building), "enclosing box not activated");
        assert!(requested.contains(&ahead), "box 1 m ahead not activated");
        assert!(
            requested.contains(&helmet),
            "box around the camera (inside the near plane) not activated"
        );
        assert!(
            !requested.contains(&behind),
            "box behind the camera activated"
        );
        for h in [building, helmet, ahead] {
            assert_eq!(culling.registry().state(h).unwrap(), InstanceState::Active);
            culling.set_blas(h, 0xB1A5).unwrap();
        }
        // Their hitbox was activated with them, so they are traced this frame.
        culling.assemble(&mut tlas).unwrap();
        let traced = tlas
            .iter()
            .filter(|r| r.acceleration_structure_reference == 0xB1A5)
            .count();
        assert_eq!(traced, 3);
    }
}

#[test]
fn frustum_slack_grows_with_distance_from_the_origin_but_stays_small() {
    // The plane test allows a relative slack of 1e-6 of its terms'
    // magnitude (f64 planes): sub-millimetre near the origin, about 0.1 m
    // at 100 km, never metres.
    for (origin, rejected_at, accepted_at) in [(0.0f32, 0.001f32, 0.0f32), (100_000.0, 1.0, 0.0)] {
        let camera = Vec3::new(origin, 1.7, origin);
        let f = frustum_at(camera, Vec3::NEG_Z, 0.1);
        // A thin box behind the camera, `gap` metres behind the apex plane
        // z = camera.z (the side planes meet there).
        let behind = |gap: f32| {
            let z = camera.z + gap;
            f.intersects(
                Vec3::new(camera.x - 1.0, 0.0, z),
                Vec3::new(camera.x + 1.0, 3.0, z + 1.0),
            )
        };
        assert!(!behind(rejected_at + 0.1), "origin {origin}");
        assert!(
            behind(accepted_at - 0.5),
            "origin {origin}: straddling box rejected"
        );
        // A box just before the near plane (ends 1 cm before it).
        let z_near = camera.z - 0.1;
        let before_near = f.intersects(
            Vec3::new(camera.x - 0.01, 1.69, z_near + 0.01),
            Vec3::new(camera.x + 0.01, 1.71, z_near + 0.05),
        );
        // Separated near the origin; within the slack at 100 km (conservative).
        assert_eq!(before_near, origin != 0.0, "origin {origin}");
    }
}
