//! Adaptive hitboxes in the CPU tracer: a TLAS with merged counting boxes
//! counts every ray into the same hitbox, at the same distance, as the
//! leaf-only TLAS of the same frame (docs/ADAPTIVE_HITBOXES.md).

use glam::Vec3;
use lipac_core::assembly::{assemble_tlas_adaptive, AssemblyConfig};
use lipac_core::grid::{GridConfig, HitboxGrid};
use lipac_core::hitbox_index::HitboxIndex;
use lipac_core::hitbox_tree::{AdaptiveHitboxes, HitboxTree};
use lipac_core::layout::{hitbox_bits, instance_bits, HitboxRecord, InstanceRecord, InstanceState};
use lipac_core::math::Aabb;
use lipac_sim::blas::BlasStore;
use lipac_sim::rng::SplitMix64;
use lipac_sim::tlas::{masks, CountingBoxes, CpuTlas, MergedBoxes};
use lipac_sim::traversal::{trace, BoxKind, Ray};

struct Resolver<'a> {
    tree: &'a HitboxTree,
    hitboxes: &'a [HitboxRecord],
    grid: &'a HitboxGrid,
    cfg: &'a AssemblyConfig,
}

impl MergedBoxes for Resolver<'_> {
    fn leaf_boxes(&self, node: u32, out: &mut Vec<(u32, [f32; 12])>) {
        self.tree
            .leaf_boxes(node, self.hitboxes, self.grid, self.cfg, out);
    }
}

#[test]
fn merged_boxes_count_what_leaf_boxes_count() {
    let (nx, nz) = (24u32, 20u32);
    let grid = HitboxGrid::new(GridConfig {
        min: [-192.0, -160.0],
        max: [192.0, 160.0],
        cell_size: 16.0,
    })
    .unwrap();
    let store = BlasStore::new();
    let cfg = AssemblyConfig::new(store.unit_cube().reference());
    let counting = CountingBoxes::default();
    let mut rng = SplitMix64::new(0xADA9);
    // Inactive instances of random heights over most cells.
    let mut instances = Vec::new();
    for _ in 0..900 {
        let x = rng.range(-190.0, 190.0);
        let z = rng.range(-158.0, 158.0);
        let (w, h) = (rng.range(0.5, 6.0), rng.range(0.0, 35.0));
        let aabb = Aabb::new(Vec3::new(x - w, 0.0, z - w), Vec3::new(x + w, h, z + w));
        let mut m = InstanceRecord {
            aabb_min: aabb.min.to_array(),
            aabb_max: aabb.max.to_array(),
            hitbox: grid.hitbox_of(&aabb).unwrap(),
            packed: instance_bits::ALIVE,
            ..Default::default()
        };
        m.set_state(InstanceState::Inactive);
        instances.push(m);
    }
    let instances = lipac_core::layout::InstanceArrays::from_records(&instances);
    for levels in 1..=3u8 {
        let tree = HitboxTree::new(nx, nz, AdaptiveHitboxes::with_levels(levels)).unwrap();
        // A few active cells (near a "camera"), the rest cold.
        let mut hitboxes = vec![HitboxRecord::default(); (nx * nz) as usize];
        for (k, h) in hitboxes.iter_mut().enumerate() {
            let (cx, cz) = (k as u32 % nx, k as u32 / nx);
            if (cx < 6 && cz < 5) || rng.below(40) == 0 {
                h.packed |= hitbox_bits::ACTIVE;
            }
        }
        lipac_core::hitbox_extents::write_extents(&instances, &mut hitboxes);
        let mut leaf_hb = hitboxes.clone();
        let (mut leaf_records, mut merged_records) = (Vec::new(), Vec::new());
        let a = assemble_tlas_adaptive(
            &instances,
            &mut leaf_hb,
            &grid,
            &cfg,
            None,
            &mut leaf_records,
        )
        .unwrap();
        let b = assemble_tlas_adaptive(
            &instances,
            &mut hitboxes,
            &grid,
            &cfg,
            Some(&tree),
            &mut merged_records,
        )
        .unwrap();
        assert!(b.merged_boxes > 0);
        let leaf_tlas = CpuTlas::build(&store, &leaf_records, &counting).unwrap();
        let mut merged_tlas = CpuTlas::default();
        // Without a resolver a merged box is refused.
        assert!(merged_tlas
            .rebuild(&store, &merged_records, &counting)
            .is_err());
        let resolver = Resolver {
            tree: &tree,
            hitboxes: &hitboxes,
            grid: &grid,
            cfg: &cfg,
        };
        merged_tlas
            .rebuild_with(&store, &merged_records, &counting, Some(&resolver))
            .unwrap();
        assert_eq!(leaf_tlas.box_count() as u32, a.hitbox_boxes);
        assert_eq!(merged_tlas.merged_box_count() as u32, b.merged_boxes);
        assert!(
            merged_tlas.box_count() * 2 < leaf_tlas.box_count(),
            "levels {levels}: {} merged-TLAS boxes against {}",
            merged_tlas.box_count(),
            leaf_tlas.box_count()
        );

        let mut counted = 0;
        let mut differ = 0;
        for _ in 0..4000 {
            let origin = Vec3::new(
                rng.range(-250.0, 250.0),
                rng.range(1.0, 80.0),
                rng.range(-220.0, 220.0),
            );
            let target = Vec3::new(
                rng.range(-200.0, 200.0),
                rng.range(-5.0, 40.0),
                rng.range(-170.0, 170.0),
            );
            let Ok(ray) = Ray::new(origin, target - origin, 0.0, f32::INFINITY, masks::ALL) else {
                continue;
            };
            let l = trace(&leaf_tlas, &store, &ray, None);
            let m = trace(&merged_tlas, &store, &ray, None);
            let key =
                |b: Option<lipac_sim::traversal::BoxHit>| b.map(|b| (b.kind, b.custom_index, b.t));
            if key(l.counted_box) != key(m.counted_box) {
                // The one known difference: a ray starting inside a leaf box
                // within millimetres of its face (exit distance ~1e-5) can be
                // culled by the leaf-only TLAS's BVH node test, while the
                // merged box's leaf test (no BVH node in between) enters it
                // at tmin.
                assert_eq!(
                    m.counted_box.map(|b| b.t),
                    Some(0.0),
                    "levels {levels}, ray {ray:?}: {l:?} against {m:?}"
                );
                differ += 1;
            }
            if let Some(b) = l.counted_box {
                assert_eq!(b.kind, BoxKind::Hitbox);
                counted += 1;
            }
        }
        assert!(counted > 1000, "only {counted} rays met a box");
        assert!(differ * 200 < counted, "{differ} of {counted} rays differ");
    }
}

/// The comparison end to end on the small scene at 16 m cells: LiPaC with
/// adaptive hitboxes decides exactly as without (same state changes, BLAS
/// work, error per frame) with fewer counting boxes.
#[test]
fn compare_with_adaptive_hitboxes_decides_alike_with_fewer_boxes() {
    use lipac_sim::compare::{run_choice, CompareConfig, SceneChoice};
    use lipac_sim::strategy::StrategyKind;
    let run = |levels: u8| {
        let config = CompareConfig {
            frames: Some(6),
            width: 32,
            height: 18,
            strategies: vec![StrategyKind::Lipac],
            share_ground_truth: true,
            threads: 2,
            adaptive_levels: Some(levels),
            lipac_cell_size: Some(16.0),
            lipac_rise_shift: None,
            lipac_start: lipac_sim::compare::LipacStart::Default,
            lipac_warm_start_at_cuts: false,
            lipac_warm_start_hold: None,
            device: Default::default(),
        };
        run_choice(SceneChoice::Small, None, &config, &mut |_, _| {}).expect("comparison")
    };
    let (off, on) = (run(0), run(2));
    let (a, b) = (&off.strategies[0], &on.strategies[0]);
    let mut fewer = 0;
    for (m, n) in a.frames.iter().zip(&b.frames) {
        assert_eq!(m.state_changes, n.state_changes, "frame {}", m.frame);
        assert_eq!(m.primitives_built, n.primitives_built, "frame {}", m.frame);
        assert!(
            (m.error - n.error).abs() <= 1e-3 * m.error.max(1e-3),
            "frame {}",
            m.frame
        );
        assert!(n.counting_boxes <= m.counting_boxes, "frame {}", m.frame);
        fewer += u32::from(n.counting_boxes < m.counting_boxes);
    }
    assert!(fewer > 0, "adaptive hitboxes merged nothing");
    assert_eq!(a.last_geometry, b.last_geometry);
}
