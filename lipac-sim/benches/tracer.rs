//! Rays per second of the two-level tracer with counting against plain
//! `obvhs` over one flattened CWBVH of the same (pre-transformed) triangles.
//!
//! Scene: the default city ([`SceneConfig::city`]) with all instances in the
//! TLAS at distance LODs from a street-level camera. Rays: primary rays of
//! three fly-through views plus one cosine bounce from each primary hit.

use std::hint::black_box;
use std::time::{Duration, Instant};

use criterion::{criterion_group, criterion_main, Criterion, Throughput};
use glam::{Vec3, Vec3A};
use lipac_core::layout::TlasInstance;
use lipac_core::math::{rows_to_affine, Aabb};
use lipac_sim::blas::{box_transform, BlasStore, BvhBlasId};
use lipac_sim::camera::CameraPath;
use lipac_sim::mesh::leaf_opaque;
use lipac_sim::pathtrace::{render, FrameScene, PathTraceConfig};
use lipac_sim::scene::{LodPolicy, Scene, SceneConfig};
use lipac_sim::scene_blas::{full_scene_records, SceneBlases, UniqueUpdate};
use lipac_sim::tlas::{masks, CountingBoxes, CpuTlas};
use lipac_sim::traversal::{trace, Counters, Ray, SlotSet};
use obvhs::cwbvh::builder::build_cwbvh_from_tris;
use obvhs::ray::{Ray as BvhRay, RayHit};
use obvhs::rt_triangle::RtTriangle;
use obvhs::triangle::Triangle;
use obvhs::BvhBuildParams;

struct Flat {
    bvh: obvhs::cwbvh::CwBvh,
    tris: Vec<RtTriangle>,
    /// World-to-object transform for alpha-tested triangles (None: opaque).
    alpha: Vec<Option<glam::Affine3A>>,
}

fn flatten(
    store: &BlasStore,
    records: &[TlasInstance],
    geoms: &[(u64, lipac_sim::mesh::LodTriangles)],
) -> Flat {
    let mut tris = Vec::new();
    let mut alpha = Vec::new();
    for r in records {
        let t = rows_to_affine(&r.transform);
        let w2o = t.inverse();
        let Some((_, g)) = geoms
            .iter()
            .find(|(rf, _)| *rf == r.acceleration_structure_reference)
        else {
            continue;
        };
        for (i, tri) in g.triangles.iter().enumerate() {
            tris.push(Triangle {
                v0: t.transform_point3a(tri.v0),
                v1: t.transform_point3a(tri.v1),
                v2: t.transform_point3a(tri.v2),
            });
            alpha.push(g.alpha_tested[i].then_some(w2o));
        }
    }
    let _ = store;
    let bvh = build_cwbvh_from_tris(
        &tris,
        BvhBuildParams::fast_build(),
        &mut Duration::default(),
    );
    let rt = bvh
        .primitive_indices
        .iter()
        .map(|&i| RtTriangle::from(&tris[i as usize]))
        .collect();
    let al = bvh
        .primitive_indices
        .iter()
        .map(|&i| alpha[i as usize])
        .collect();
    Flat {
        bvh,
        tris: rt,
        alpha: al,
    }
}

fn flat_trace(f: &Flat, ray: &BvhRay) -> f32 {
    let mut hit = RayHit::none();
    f.bvh.ray_traverse(*ray, &mut hit, |r, id| {
        let t = f.tris[id].intersect(r);
        if t < r.tmax {
            if let Some(w2o) = &f.alpha[id] {
                if !leaf_opaque(w2o.transform_point3a(r.origin + r.direction * t).into()) {
                    return f32::INFINITY;
                }
            }
        }
        t
    });
    hit.t
}

fn bench(c: &mut Criterion) {
    let t0 = Instant::now();
    let mut scene = Scene::generate(&SceneConfig::city()).expect("scene");
    let path = CameraPath::flythrough(&scene, 16.0 / 9.0);
    let frame = 150;
    scene.set_frame(frame);
    let eye = path.camera_at(frame).position;
    let t_gen = t0.elapsed();
    let mut store = BlasStore::new();
    let mut blases = SceneBlases::new();
    let mut records = Vec::new();
    let t1 = Instant::now();
    full_scene_records(
        &scene,
        &mut blases,
        &mut store,
        eye,
        &LodPolicy::default(),
        frame,
        UniqueUpdate::Rebuild,
        &mut records,
    )
    .expect("records");
    let t_blas = t1.elapsed();
    let counting = CountingBoxes::default();
    let t2 = Instant::now();
    let tlas = CpuTlas::build(&store, &records, &counting).expect("tlas");
    let t_tlas = t2.elapsed();

    // Geometry per reference, for flattening (regenerated from the scene).
    let mut geoms: Vec<(u64, lipac_sim::mesh::LodTriangles)> = Vec::new();
    {
        let mut seen = std::collections::HashMap::new();
        for (slot, r) in records.iter().enumerate() {
            let rf = r.acceleration_structure_reference;
            if seen.contains_key(&rf) {
                continue;
            }
            let inst = scene.instances()[slot];
            let lod = LodPolicy::default().lod(eye, &inst.aabb);
            let mut g = lipac_sim::mesh::LodTriangles::default();
            if inst.is_unique() {
                scene
                    .unique_geometry(slot as u32, lod, frame, &mut g)
                    .expect("geometry");
            } else {
                g = scene.library().lod(inst.mesh, lod).expect("lod").clone();
            }
            seen.insert(rf, geoms.len());
            geoms.push((rf, g));
        }
    }
    let t3 = Instant::now();
    let flat = flatten(&store, &records, &geoms);
    let t_flat = t3.elapsed();

    // Rays: primary rays of three views plus one bounce per primary hit.
    let (w, h) = (128u32, 72u32);
    let mut rays = Vec::new();
    for f in [0u32, 100, 260] {
        let cam = path.camera_at(f);
        for py in 0..h {
            for px in 0..w {
                let d = cam.ray_direction(px, py, w, h, (0.0, 0.0));
                rays.push(Ray::new(cam.position, d, 0.0, f32::INFINITY, masks::ALL).expect("ray"));
            }
        }
    }
    let primaries = rays.len();
    for i in 0..primaries {
        let r = rays[i];
        if let Some(hit) = trace(&tlas, &store, &r, None).hit {
            let p = r.origin() + r.direction() * hit.t;
            let mut n = hit.normal;
            if n.dot(r.direction()) > 0.0 {
                n = -n;
            }
            let u = lipac_sim::rng::sample(0, i as u32, 1, 0);
            let v = lipac_sim::rng::sample(0, i as u32, 1, 1);
            let a = std::f32::consts::TAU * v;
            let tangent = n.any_orthonormal_vector();
            let bit = n.cross(tangent);
            let d = (tangent * (u.sqrt() * a.cos())
                + bit * (u.sqrt() * a.sin())
                + n * (1.0 - u).sqrt())
            .normalize();
            rays.push(Ray::new(p + n * 0.01, d, 0.0, f32::INFINITY, masks::ALL).expect("ray"));
        }
    }
    let bvh_rays: Vec<BvhRay> = rays
        .iter()
        .map(|r| {
            BvhRay::new(
                Vec3A::from(r.origin()),
                Vec3A::from(r.direction()),
                r.tmin(),
                r.tmax(),
            )
        })
        .collect();

    // Sanity: both tracers agree on (almost) every ray.
    let mut agree = 0;
    for (r, b) in rays.iter().zip(&bvh_rays) {
        let a = trace(&tlas, &store, r, None)
            .hit
            .map_or(f32::INFINITY, |h| h.t);
        let f = flat_trace(&flat, b);
        if (a.is_infinite() && f.is_infinite()) || (a - f).abs() <= 1e-3 * a.max(1.0) {
            agree += 1;
        }
    }

    // A variant with counting boxes: 16 x 16 hitbox cells over the city.
    let mut boxed = records.clone();
    let ext = scene.config().extent;
    let cell = ext / 16.0;
    for j in 0..16u32 {
        for i in 0..16u32 {
            let min = Vec3::new(i as f32 * cell, -20.0, j as f32 * cell);
            boxed.push(TlasInstance::new(
                box_transform(&Aabb::new(min, min + Vec3::new(cell, 50.0, cell))),
                j * 16 + i,
                masks::COUNTING,
                counting.hitbox_box_sbt,
                0,
                store.unit_cube().reference(),
            ));
        }
    }
    let tlas_boxed = CpuTlas::build(&store, &boxed, &counting).expect("tlas");
    let flat_tris = flat.tris.len();
    eprintln!(
        "tracer bench setup: {} instances, {} BLASes, {} flattened triangles, {} rays ({} primary), agree {:.4}\n  \
         scene gen {:?}, BLAS builds {:?}, TLAS build {:?}, flat build {:?}, BLAS memory {:.1} MiB",
        records.len(),
        store.len(),
        flat_tris,
        rays.len(),
        primaries,
        agree as f64 / rays.len() as f64,
        t_gen,
        t_blas,
        t_tlas,
        t_flat,
        store.memory_bytes() as f64 / (1 << 20) as f64,
    );
    let _: BvhBlasId = store.unit_cube();

    let mut g = c.benchmark_group("tracer");
    g.sample_size(10)
        .measurement_time(Duration::from_secs(4))
        .warm_up_time(Duration::from_secs(1));
    g.throughput(Throughput::Elements(rays.len() as u64));
    g.bench_function("two_level_counting", |b| {
        let mut counters = Counters::new(records.len(), 256);
        b.iter(|| {
            for r in &rays {
                let res = trace(&tlas, &store, r, None);
                if let Some(bx) = &res.counted_box {
                    counters.count_box(bx);
                }
                if let Some(h) = &res.hit {
                    counters.count_instance(h.custom_index);
                }
            }
            black_box(&counters);
        })
    });
    g.bench_function("flat_obvhs", |b| {
        b.iter(|| {
            let mut s = 0.0f32;
            for r in &bvh_rays {
                let t = flat_trace(&flat, r);
                if t.is_finite() {
                    s += t;
                }
            }
            black_box(s)
        })
    });
    g.bench_function("two_level_counting_with_256_hitboxes", |b| {
        let mut counters = Counters::new(records.len(), 256);
        b.iter(|| {
            for r in &rays {
                let res = trace(&tlas_boxed, &store, r, None);
                if let Some(bx) = &res.counted_box {
                    counters.count_box(bx);
                }
                if let Some(h) = &res.hit {
                    counters.count_instance(h.custom_index);
                }
            }
            black_box(&counters);
        })
    });
    g.finish();

    // Per-frame costs of the path tracer and the TLAS build (one sample each
    // is enough for the report; criterion groups below keep them honest).
    let mut g = c.benchmark_group("frame");
    g.sample_size(10)
        .measurement_time(Duration::from_secs(4))
        .warm_up_time(Duration::from_secs(1));
    g.bench_function("tlas_build_city", |b| {
        b.iter(|| CpuTlas::build(&store, &records, &counting).expect("tlas"))
    });
    let slots = SlotSet::from_geometry_records(&records, &counting);
    let fs = FrameScene {
        store: &store,
        full: &tlas,
        traced: &tlas,
        traced_slots: &slots,
    };
    let cam = path.camera_at(frame);
    for (w, h) in [(128u32, 72u32), (160, 90)] {
        let cfg = PathTraceConfig {
            width: w,
            height: h,
            threads: 1,
            ..Default::default()
        };
        let out = render(&fs, &cam, frame, &cfg, records.len(), 256).expect("render");
        eprintln!("pathtrace {w}x{h}: rays {:?}", out.rays);
        g.bench_function(format!("pathtrace_{w}x{h}_1thread"), |b| {
            b.iter(|| render(&fs, &cam, frame, &cfg, records.len(), 256).expect("render"))
        });
    }
    // Animated units: deform + refit (or rebuild) every unit's BLAS for a new frame.
    let units: Vec<u32> = scene.units().iter().map(|u| u.slot).collect();
    let unit_lods: Vec<usize> = units
        .iter()
        .map(|&s| LodPolicy::default().lod(eye, &scene.instances()[s as usize].aabb))
        .collect();
    for (mode, name) in [
        (UniqueUpdate::Refit, "units_refit_all"),
        (UniqueUpdate::Rebuild, "units_rebuild_all"),
    ] {
        let mut next = frame;
        g.bench_function(format!("{name}_{}", units.len()), |b| {
            b.iter(|| {
                next += 1;
                for (&slot, &lod) in units.iter().zip(&unit_lods) {
                    blases
                        .unique(&mut store, &scene, slot, lod, next, mode)
                        .expect("unit");
                }
            })
        });
    }
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
