use super::*;
use crate::assembly::{assemble_tlas, assemble_tlas_adaptive, sort_canonical};
use crate::grid::{GridConfig, HitboxGrid};
use crate::layout::{hitbox_bits, instance_bits, InstanceRecord, InstanceState};
use lipac_test_support::{Rng64, SplitMix64};

const CUBE: u64 = 0xC0BE;

fn grid(nx: u32, nz: u32) -> HitboxGrid {
    HitboxGrid::new(GridConfig {
        min: [-100.0, 37.5],
        max: [-100.0 + 16.0 * f64::from(nx), 37.5 + 16.0 * f64::from(nz)],
        cell_size: 16.0,
    })
    .unwrap()
}

/// Random hitbox records as Algorithm 1's pass 1 leaves them: some active,
/// some empty, random heights.
fn random_hitboxes(rng: &mut impl Rng64, n: u32, p_active: f64, p_empty: f64) -> Vec<HitboxRecord> {
    (0..n)
        .map(|_| {
            let mut h = HitboxRecord::default();
            if rng.chance(p_active) {
                h.packed |= hitbox_bits::ACTIVE;
            }
            if !rng.chance(p_empty) {
                let a = rng.range_f32(-5.0, 40.0);
                let b = if rng.chance(0.1) {
                    a
                } else {
                    rng.range_f32(-5.0, 40.0)
                };
                h.min_y = a.min(b);
                h.max_y = a.max(b);
            }
            h
        })
        .collect()
}

fn cfg() -> AssemblyConfig {
    AssemblyConfig::new(CUBE)
}

/// The per-leaf formulation a GPU thread runs (one thread per hitbox): the
/// highest merged ancestor by scanning its leaves; the box is emitted by the
/// first leaf with inactive instances in row-major order. An independent
/// reference for [`HitboxTree::emit_boxes`] (and the shader's spec).
fn per_leaf_reference(
    tree: &HitboxTree,
    hitboxes: &[HitboxRecord],
    index: &HitboxGrid,
) -> Vec<TlasInstance> {
    let (nx, _) = tree.leaf_dims();
    let c = cfg();
    let mut out = Vec::new();
    let mut stats = AssemblyStats::default();
    for k in 0..hitboxes.len() as u32 {
        let h = &hitboxes[k as usize];
        if h.is_active() {
            continue;
        }
        let (cx, cz) = (k % nx, k / nx);
        let mut merged = None;
        for l in (1..=tree.levels()).rev() {
            let node = TreeNode {
                level: l,
                i: cx >> l,
                j: cz >> l,
            };
            let (lo, hi) = tree.leaf_rect(node);
            let all = (lo[1]..hi[1])
                .all(|z| (lo[0]..hi[0]).all(|x| !hitboxes[(x + z * nx) as usize].is_active()));
            if all {
                merged = Some(node);
                break;
            }
        }
        let Some(node) = merged else {
            emit_leaf_box(k, h, index, &c, &mut out, &mut stats);
            continue;
        };
        let (lo, hi) = tree.leaf_rect(node);
        let mut count = 0;
        let mut first = None;
        let (mut bmin, mut bmax) = (Vec3::splat(f32::INFINITY), Vec3::splat(f32::NEG_INFINITY));
        for z in lo[1]..hi[1] {
            for x in lo[0]..hi[0] {
                let leaf = x + z * nx;
                let r = &hitboxes[leaf as usize];
                if has_inactive(r) {
                    count += 1;
                    first.get_or_insert(leaf);
                    let t = leaf_box_transform(leaf, r, index, &c).unwrap();
                    let (a, b) = box_extent(&t);
                    bmin = bmin.min(a);
                    bmax = bmax.max(b);
                }
            }
        }
        if first != Some(k) {
            continue;
        }
        if count == 1 {
            emit_leaf_box(k, h, index, &c, &mut out, &mut stats);
        } else {
            let t = unit_cube_transform(bmin, bmax, c.min_box_extent).unwrap();
            out.push(TlasInstance::new(
                t,
                tree.node_id(node).unwrap(),
                c.counting_mask,
                tree.config().merged_box_sbt_offset,
                COUNTING_BOX_FLAGS,
                c.unit_cube_blas,
            ));
        }
    }
    out
}

fn pass2(
    tree: &HitboxTree,
    hitboxes: &[HitboxRecord],
    index: &HitboxGrid,
) -> (Vec<TlasInstance>, AssemblyStats) {
    let mut out = Vec::new();
    let mut stats = AssemblyStats::default();
    tree.emit_boxes(hitboxes, index, &cfg(), &mut out, &mut stats);
    (out, stats)
}

#[test]
fn node_ids_round_trip_and_cover_the_grid() {
    let mut rng = SplitMix64::new(3);
    for _ in 0..40 {
        let (nx, nz) = (1 + rng.below_u32(40), 1 + rng.below_u32(40));
        let levels = 1 + rng.below_u32(u32::from(MAX_MERGE_LEVELS)) as u8;
        let tree = HitboxTree::new(nx, nz, AdaptiveHitboxes::with_levels(levels)).unwrap();
        let mut seen = 0;
        for id in 0..tree.node_count() {
            let n = tree.node(id).unwrap();
            assert_eq!(tree.node_id(n), Some(id));
            seen += 1;
        }
        assert_eq!(tree.node(tree.node_count()), None);
        // Every level's nodes tile the grid exactly once.
        for l in 1..=levels {
            let (w, h) = tree.dims_at(l);
            let mut cover = vec![0u8; (nx * nz) as usize];
            for j in 0..h {
                for i in 0..w {
                    let (lo, hi) = tree.leaf_rect(TreeNode { level: l, i, j });
                    assert!(lo[0] < hi[0] && lo[1] < hi[1], "empty node {l} {i} {j}");
                    for z in lo[1]..hi[1] {
                        for x in lo[0]..hi[0] {
                            cover[(x + z * nx) as usize] += 1;
                        }
                    }
                }
            }
            assert!(cover.iter().all(|&c| c == 1));
        }
        assert_eq!(seen, tree.node_count());
    }
}

#[test]
fn bad_configs_are_refused() {
    assert!(HitboxTree::new(4, 4, AdaptiveHitboxes::with_levels(0)).is_err());
    assert!(HitboxTree::new(4, 4, AdaptiveHitboxes::with_levels(MAX_MERGE_LEVELS + 1)).is_err());
    assert!(HitboxTree::new(0, 4, AdaptiveHitboxes::with_levels(1)).is_err());
    let sbt = AdaptiveHitboxes {
        levels: 1,
        merged_box_sbt_offset: 1 << 24,
    };
    assert!(HitboxTree::new(4, 4, sbt).is_err());
    // 4096 x 4096 leaves: level 1 alone has 2^22 nodes, all levels fit.
    assert!(HitboxTree::new(4096, 4096, AdaptiveHitboxes::with_levels(4)).is_ok());
    // 8192 x 8192: level 1 has 2^24 nodes, level 2 2^22 more.
    let e = HitboxTree::new(8192, 8192, AdaptiveHitboxes::with_levels(2)).unwrap_err();
    assert!(e.to_string().contains("24-bit"), "{e}");
}

#[test]
fn hashed_index_is_refused_clearly() {
    use crate::hashed_hitboxes::HashedHitboxes;
    let hashed = HashedHitboxes::new(crate::hashed_hitboxes::HashedConfig::default()).unwrap();
    let e = HitboxTree::for_index(&hashed, AdaptiveHitboxes::with_levels(2)).unwrap_err();
    assert!(e.to_string().contains("HashedHitboxes"), "{e}");
    assert_eq!(
        HitboxTree::for_index(&hashed, AdaptiveHitboxes::OFF).unwrap(),
        None
    );
}

#[test]
fn all_cold_grid_collapses_to_one_box_per_top_node() {
    let index = grid(8, 8);
    let tree = HitboxTree::new(8, 8, AdaptiveHitboxes::with_levels(2)).unwrap();
    let mut hitboxes = vec![HitboxRecord::default(); 64];
    for (k, h) in hitboxes.iter_mut().enumerate() {
        h.min_y = k as f32;
        h.max_y = k as f32 + 2.0;
    }
    let (out, stats) = pass2(&tree, &hitboxes, &index);
    assert_eq!(
        (
            stats.merged_boxes,
            stats.merged_hitboxes,
            stats.hitbox_boxes
        ),
        (4, 64, 0)
    );
    assert_eq!(out.len(), 4);
    // The first level-2 node spans leaves (0..4, 0..4): x from -100 to -36,
    // heights 0 (leaf 0) .. 27 + 2 (leaf 27).
    let first = out
        .iter()
        .find(|r| {
            r.custom_index()
                == tree
                    .node_id(TreeNode {
                        level: 2,
                        i: 0,
                        j: 0,
                    })
                    .unwrap()
        })
        .unwrap();
    assert_eq!(first.sbt_offset(), 3);
    assert_eq!(first.transform[3], -100.0);
    assert!(first.transform[3] + first.transform[0] >= -36.0);
    assert_eq!(first.transform[7], 0.0);
    assert!(first.transform[7] + first.transform[5] >= 29.0);

    // One active leaf splits its ancestors: the level-2 node around it is
    // replaced by three level-1 boxes and three leaf boxes.
    hitboxes[0].packed |= hitbox_bits::ACTIVE;
    let (out, stats) = pass2(&tree, &hitboxes, &index);
    assert_eq!((stats.merged_boxes, stats.hitbox_boxes), (3 + 3, 3));
    assert_eq!(out.len(), 9);
    assert_eq!(stats.merged_hitboxes, 63 - 3);
}

#[test]
fn emission_matches_the_per_leaf_reference_and_covers_every_cold_leaf() {
    let mut rng = SplitMix64::new(0xADA);
    for round in 0..60 {
        let (nx, nz) = (1 + rng.below_u32(33), 1 + rng.below_u32(33));
        let levels = 1 + rng.below_u32(u32::from(MAX_MERGE_LEVELS)) as u8;
        let p_active = [0.0, 0.02, 0.1, 0.5][round % 4];
        let index = grid(nx, nz);
        let tree = HitboxTree::new(nx, nz, AdaptiveHitboxes::with_levels(levels)).unwrap();
        let hitboxes = random_hitboxes(&mut rng, nx * nz, p_active, 0.3);
        let (mut out, stats) = pass2(&tree, &hitboxes, &index);
        let mut reference = per_leaf_reference(&tree, &hitboxes, &index);
        sort_canonical(&mut out);
        sort_canonical(&mut reference);
        assert_eq!(
            out, reference,
            "round {round}: {nx} x {nz}, {levels} levels"
        );

        // Each inactive leaf with inactive instances is represented exactly
        // once: by its own box or as a leaf of one merged box, whose box
        // contains the leaf's; no merged node holds an active leaf.
        let mut count = vec![0u32; (nx * nz) as usize];
        let mut leaves = Vec::new();
        for r in &out {
            if r.sbt_offset() == cfg().hitbox_sbt_offset {
                count[r.custom_index() as usize] += 1;
                continue;
            }
            assert_eq!(r.sbt_offset(), 3);
            let node = tree.node(r.custom_index()).unwrap();
            let (lo, hi) = tree.leaf_rect(node);
            for z in lo[1]..hi[1] {
                for x in lo[0]..hi[0] {
                    assert!(!hitboxes[(x + z * nx) as usize].is_active());
                }
            }
            leaves.clear();
            tree.leaf_boxes(r.custom_index(), &hitboxes, &index, &cfg(), &mut leaves);
            assert!(leaves.len() >= 2);
            let m = &r.transform;
            for (leaf, t) in &leaves {
                count[*leaf as usize] += 1;
                let (a, b) = box_extent(t);
                let (ma, mb) = box_extent(m);
                assert!(a.cmpge(ma).all(), "leaf box starts inside the merged box");
                assert!(b.cmple(mb).all(), "leaf box ends inside the merged box");
            }
        }
        for (k, h) in hitboxes.iter().enumerate() {
            let want = u32::from(!h.is_active() && has_inactive(h));
            assert_eq!(count[k], want, "round {round}, leaf {k}");
        }
        assert_eq!(
            stats.hitbox_boxes + stats.merged_hitboxes,
            count.iter().sum::<u32>()
        );
    }
}

/// Instances in a grid, all inactive: the full Algorithm 1 with and without
/// the tree. Off is `assemble_tlas` exactly; on gives the same instance
/// records and heights, and fewer boxes.
#[test]
fn assemble_with_the_tree_changes_only_the_hitbox_boxes() {
    let (nx, nz) = (12, 9);
    let index = grid(nx, nz);
    let tree = HitboxTree::new(nx, nz, AdaptiveHitboxes::with_levels(2)).unwrap();
    let mut rng = SplitMix64::new(11);
    let mut instances = Vec::new();
    for _ in 0..300 {
        let x = rng.range_f32(-100.0, -100.0 + 16.0 * nx as f32);
        let z = rng.range_f32(37.5, 37.5 + 16.0 * nz as f32);
        let aabb = crate::math::Aabb::new(
            Vec3::new(x - 1.0, 0.0, z - 1.0),
            Vec3::new(x + 1.0, rng.range_f32(1.0, 30.0), z + 1.0),
        );
        let mut m = InstanceRecord {
            aabb_min: aabb.min.to_array(),
            aabb_max: aabb.max.to_array(),
            hitbox: index.hitbox_of(&aabb).unwrap(),
            packed: instance_bits::ALIVE,
            blas: 0xB0,
            ..Default::default()
        };
        m.set_state(if rng.chance(0.2) {
            InstanceState::Active
        } else {
            InstanceState::Inactive
        });
        instances.push(m);
    }
    let mut hb = vec![HitboxRecord::default(); (nx * nz) as usize];
    for h in hb.iter_mut().step_by(7) {
        h.packed |= hitbox_bits::ACTIVE;
    }
    let instances = crate::layout::InstanceArrays::from_records(&instances);
    crate::hitbox_extents::write_extents(&instances, &mut hb);
    let (mut a, mut b) = (Vec::new(), Vec::new());
    let mut ha = hb.clone();
    let mut hbb = hb.clone();
    let sa = assemble_tlas(&instances, &mut ha, &index, &cfg(), &mut a).unwrap();
    let sb =
        assemble_tlas_adaptive(&instances, &mut hbb, &index, &cfg(), Some(&tree), &mut b).unwrap();
    assert_eq!(ha, hbb, "heights and costs are the leaves' either way");
    assert_eq!((sa.active, sa.inactive), (sb.active, sb.inactive));
    let geometry = |v: &[TlasInstance]| {
        let mut g: Vec<_> = v.iter().filter(|r| r.sbt_offset() == 0).copied().collect();
        sort_canonical(&mut g);
        g
    };
    assert_eq!(geometry(&a), geometry(&b));
    assert!(sb.merged_boxes > 0);
    assert_eq!(sa.hitbox_boxes, sb.hitbox_boxes + sb.merged_hitboxes);
    assert!(b.len() < a.len(), "{} !< {}", b.len(), a.len());
    // Off is the leaf-only pass exactly.
    let mut c = Vec::new();
    let mut hc = hb.clone();
    assemble_tlas_adaptive(&instances, &mut hc, &index, &cfg(), None, &mut c).unwrap();
    assert_eq!(a, c);
    // A tree of another grid is refused.
    let other = HitboxTree::new(nx + 1, nz, AdaptiveHitboxes::with_levels(2)).unwrap();
    let e = assemble_tlas_adaptive(&instances, &mut hc, &index, &cfg(), Some(&other), &mut c)
        .unwrap_err();
    assert!(matches!(
        e,
        crate::assembly::AssemblyError::TreeMismatch { .. }
    ));
}

#[test]
fn culling_builds_the_tree_only_for_a_dense_grid() {
    use crate::culling::{Culling, CullingConfig};
    use crate::hashed_hitboxes::{HashedConfig, HashedHitboxes};
    let mut config = CullingConfig::new(CUBE);
    config.adaptive_hitboxes = AdaptiveHitboxes::with_levels(3);
    let c = Culling::new(grid(10, 6), config).unwrap();
    assert_eq!(
        c.hitbox_tree().map(|t| (t.leaf_dims(), t.levels())),
        Some(((10, 6), 3))
    );
    let hashed = HashedHitboxes::new(HashedConfig::default()).unwrap();
    let e = Culling::new(hashed, config).unwrap_err();
    assert!(e.to_string().contains("leaf-only"), "{e}");
    // The merged boxes' SBT offset must not collide with the others.
    config.adaptive_hitboxes.merged_box_sbt_offset = config.assembly.hitbox_sbt_offset;
    let e = Culling::new(grid(10, 6), config).unwrap_err();
    assert!(e.to_string().contains("merged_box_sbt_offset"), "{e}");
    let off = Culling::new(grid(10, 6), CullingConfig::new(CUBE)).unwrap();
    assert!(off.hitbox_tree().is_none());
}
