//! The hybrid path tracer: determinism, ground-truth consistency, the
//! rasterized-shadow fallback and the counting of hit feedback.

use glam::Vec3;
use lipac_core::layout::TlasInstance;
use lipac_core::math::Aabb;
use lipac_sim::blas::{box_transform, BlasStore};
use lipac_sim::camera::CameraPath;
use lipac_sim::pathtrace::{
    primary_hits, relative_rmse, render, render_with_primary, FrameOutput, FrameScene,
    PathTraceConfig,
};
use lipac_sim::scene::{flags, LodPolicy, Scene, SceneConfig};
use lipac_sim::scene_blas::{full_scene_records, SceneBlases, UniqueUpdate};
use lipac_sim::tlas::{masks, CountingBoxes, CpuTlas};
use lipac_sim::traversal::SlotSet;

struct Setup {
    scene: Scene,
    store: BlasStore,
    records: Vec<TlasInstance>,
    full: CpuTlas,
    all: SlotSet,
    path: CameraPath,
    frame: u32,
}

fn setup(frame: u32) -> Setup {
    let mut scene = Scene::generate(&SceneConfig::small()).unwrap();
    scene.set_frame(frame);
    let path = CameraPath::flythrough(&scene, 16.0 / 9.0);
    let cam = path.camera_at(frame);
    let mut store = BlasStore::new();
    let mut blases = SceneBlases::new();
    let mut records = Vec::new();
    full_scene_records(
        &scene,
        &mut blases,
        &mut store,
        cam.position,
        &LodPolicy::default(),
        frame,
        UniqueUpdate::Rebuild,
        &mut records,
    )
    .unwrap();
    let counting = CountingBoxes::default();
    let full = CpuTlas::build(&store, &records, &counting).unwrap();
    let all = SlotSet::from_geometry_records(&records, &counting);
    Setup {
        scene,
        store,
        records,
        full,
        all,
        path,
        frame,
    }
}

fn config(threads: usize) -> PathTraceConfig {
    PathTraceConfig {
        width: 48,
        height: 27,
        threads,
        ..Default::default()
    }
}

fn draw(
    s: &Setup,
    traced: &CpuTlas,
    slots: &SlotSet,
    threads: usize,
    hitboxes: usize,
) -> FrameOutput {
    let fs = FrameScene {
        store: &s.store,
        full: &s.full,
        traced,
        traced_slots: slots,
    };
    render(
        &fs,
        &s.path.camera_at(s.frame),
        s.frame,
        &config(threads),
        s.scene.instances().len(),
        hitboxes,
    )
    .unwrap()
}

#[test]
fn renders_are_deterministic_across_runs_and_thread_counts() {
    let a = setup(200);
    let b = setup(200);
    assert_eq!(a.scene.instances(), b.scene.instances());
    assert_eq!(a.records, b.records);
    let ra = draw(&a, &a.full, &a.all, 1, 0);
    let rb = draw(&b, &b.full, &b.all, 2, 0);
    assert_eq!(
        ra.without_timings(),
        rb.without_timings(),
        "same seed, same image and counters, bitwise"
    );
    assert!(ra.counters.instance_total() > 0);
    assert!(ra.indirect.iter().any(|p| p.max_element() > 0.0));
    // Another frame moves the units: the image changes.
    let c = setup(230);
    let rc = draw(&c, &c.full, &c.all, 2, 0);
    assert_ne!(ra.direct, rc.direct);
}

#[test]
fn unculled_tlas_with_extra_counting_boxes_equals_ground_truth() {
    let s = setup(200);
    let gt = draw(&s, &s.full, &s.all, 2, 0);
    // Add a grid of inactive-hitbox boxes over the whole city: they count
    // rays but never change light transport.
    let counting = CountingBoxes::default();
    let mut recs = s.records.clone();
    let ext = s.scene.config().extent;
    let cells = 8u32;
    let cell = ext / cells as f32;
    for j in 0..cells {
        for i in 0..cells {
            let min = Vec3::new(i as f32 * cell, -20.0, j as f32 * cell);
            let aabb = Aabb::new(min, min + Vec3::new(cell, 60.0, cell));
            recs.push(TlasInstance::new(
                box_transform(&aabb),
                j * cells + i,
                masks::COUNTING,
                counting.hitbox_box_sbt,
                0,
                s.store.unit_cube().reference(),
            ));
        }
    }
    let traced = CpuTlas::build(&s.store, &recs, &counting).unwrap();
    let out = draw(&s, &traced, &s.all, 2, (cells * cells) as usize);
    assert_eq!(relative_rmse(&out.indirect, &gt.indirect).unwrap(), 0.0);
    assert_eq!(out.direct, gt.direct);
    assert!(
        out.counters.hitbox_total() > 0,
        "boxes were passed and counted"
    );
    // Geometry hits are the same; a ray counting a box still counts its hit.
    assert_eq!(out.counters.instances, gt.counters.instances);
    assert_eq!(out.rays, gt.rays);
}

#[test]
fn culling_changes_only_indirect_light_and_counts_only_traced_instances() {
    let s = setup(200);
    let gt = draw(&s, &s.full, &s.all, 2, 0);
    let counting = CountingBoxes::default();
    // Cull every other building and all trees from ray tracing.
    let culled: Vec<bool> = s
        .scene
        .instances()
        .iter()
        .enumerate()
        .map(|(i, inst)| {
            inst.is_vegetation()
                || (inst.flags & (flags::TERRAIN | flags::ANIMATED) == 0 && i % 2 == 0)
        })
        .collect();
    let recs: Vec<TlasInstance> = s
        .records
        .iter()
        .map(|r| {
            if culled[r.custom_index() as usize] {
                TlasInstance {
                    acceleration_structure_reference: 0,
                    ..*r
                }
            } else {
                *r
            }
        })
        .collect();
    let traced = CpuTlas::build(&s.store, &recs, &counting).unwrap();
    let slots = SlotSet::from_geometry_records(&recs, &counting);
    assert!(slots.len() < s.all.len());
    let out = draw(&s, &traced, &slots, 2, 0);
    // Hybrid guarantee: primary hits and sun shadows at them (traced rays +
    // rasterized shadows of the culled set) are those of the full scene.
    assert_eq!(out.direct, gt.direct);
    let err = relative_rmse(&out.indirect, &gt.indirect).unwrap();
    assert!(
        err > 0.0 && err.is_finite(),
        "culling must change indirect light: {err}"
    );
    for (i, &c) in out.counters.instances.iter().enumerate() {
        if culled[i] {
            assert_eq!(c, 0, "culled instance {i} was counted");
        }
    }
    assert!(out.counters.instance_total() > 0);
}

#[test]
fn bad_inputs_are_errors() {
    let s = setup(0);
    let fs = FrameScene {
        store: &s.store,
        full: &s.full,
        traced: &s.full,
        traced_slots: &s.all,
    };
    let cam = s.path.camera_at(0);
    let bad = PathTraceConfig {
        width: 0,
        ..config(1)
    };
    assert!(render(&fs, &cam, 0, &bad, 1, 1).is_err());
    let bad = PathTraceConfig {
        sun_direction: Vec3::NAN,
        ..config(1)
    };
    assert!(render(&fs, &cam, 0, &bad, 1, 1).is_err());
    assert!(relative_rmse(&[Vec3::ONE], &[]).is_err());
    assert_eq!(
        relative_rmse(&[Vec3::ONE], &[Vec3::ZERO]).unwrap(),
        f64::INFINITY
    );
}

#[test]
fn shared_primary_hits_render_as_tracing_them_and_belong_to_one_view() {
    let s = setup(120);
    // A culled TLAS: every other instance.
    let counting = CountingBoxes::default();
    let half: Vec<TlasInstance> = s.records.iter().step_by(2).copied().collect();
    let culled = CpuTlas::build(&s.store, &half, &counting).unwrap();
    let slots = SlotSet::from_geometry_records(&half, &counting);
    let cam = s.path.camera_at(s.frame);
    let primary = primary_hits(&s.full, &s.store, &cam, &config(3)).unwrap();
    assert!(primary.hit_count() > 0);
    let n = s.scene.instances().len();
    for (traced, slots) in [(&s.full, &s.all), (&culled, &slots)] {
        let fs = FrameScene {
            store: &s.store,
            full: &s.full,
            traced,
            traced_slots: slots,
        };
        let shared = render_with_primary(&fs, &cam, s.frame, &config(2), n, 0, &primary).unwrap();
        let traced_here = draw(&s, traced, slots, 1, 0);
        assert_eq!(shared.without_timings(), traced_here.without_timings());
    }
    // Primary hits of another view or size are refused.
    let fs = FrameScene {
        store: &s.store,
        full: &s.full,
        traced: &s.full,
        traced_slots: &s.all,
    };
    let other = s.path.camera_at(s.frame + 40);
    assert!(render_with_primary(&fs, &other, s.frame, &config(1), n, 0, &primary).is_err());
    let wide = PathTraceConfig {
        width: 64,
        ..config(1)
    };
    assert!(render_with_primary(&fs, &cam, s.frame, &wide, n, 0, &primary).is_err());
}
