//! The ray-tracing-pipeline path counts what the ray-query path counts:
//! the same rays through the same TLAS give the same hits, per-slot
//! counters and hitbox records bit for bit on both paths, and those of a
//! CPU reference; a camera frame is the same image and counts on both; a
//! tracer refuses a device without its path, naming what is missing.

use crate::common::*;
use ash::vk;
use glam::{Affine3A, Quat, Vec3};
use lipac_core::layout::{
    hitbox_bits, HitboxRecord, TlasInstance, VK_INSTANCE_CULL_DISABLE, VK_INSTANCE_FORCE_OPAQUE,
};
use lipac_test_support::{Rng64, SplitMix64};
use lipac_vk::{
    counting_box_instance, Buffer, CameraTraceBuffers, CameraTracer, CameraView, CountingBoxConfig,
    CountingBoxKind, GpuHit, GpuRay, HeadlessContext, HeadlessOptions, MemoryLocation, MergedBoxes,
    OneShot, PipelineCameraTracer, PipelineTestTracer, RayQueryTestPipeline, TracingPath,
    TracingPaths, VkError,
};

const STORAGE: vk::BufferUsageFlags = vk::BufferUsageFlags::STORAGE_BUFFER;
const SLOTS: usize = 64;
const HITBOXES: usize = 64;

/// A counting box of the scene.
struct CpuBox {
    min: [f32; 3],
    max: [f32; 3],
    kind: CountingBoxKind,
    index: u32,
    opaque: bool,
}

/// Entry distance of a ray into a box (slab test, f64) and whether the
/// entry point keeps a margin from the entered face's edges (else a GPU
/// may legitimately miss or hit it).
fn slab(ray: &GpuRay, b: &CpuBox) -> Option<(f64, bool)> {
    let (mut lo, mut hi) = (f64::from(ray.t_min), f64::from(ray.t_max));
    let mut axis = usize::MAX;
    for a in 0..3 {
        let (o, d) = (f64::from(ray.origin[a]), f64::from(ray.direction[a]));
        let (bmin, bmax) = (f64::from(b.min[a]), f64::from(b.max[a]));
        if d == 0.0 {
            if o < bmin || o > bmax {
                return None;
            }
            continue;
        }
        let (t0, t1) = ((bmin - o) / d, (bmax - o) / d);
        if t0.min(t1) > lo {
            lo = t0.min(t1);
            axis = a;
        }
        hi = hi.min(t0.max(t1));
    }
    if lo > hi {
        return None;
    }
    let margin = 1e-3;
    let clear = (0..3).filter(|&a| a != axis).all(|a| {
        let p = f64::from(ray.origin[a]) + lo * f64::from(ray.direction[a]);
        p > f64::from(b.min[a]) + margin && p < f64::from(b.max[a]) - margin
    }) && hi - lo > margin;
    Some((lo, clear && axis != usize::MAX))
}

/// The scene: 12 quads (slots 0..12, mask 1) and 40 disjoint counting
/// boxes on a 8 × 5 lattice with gaps (hitbox boxes, every third an
/// omitted-instance box of slot 20 + i; every other one opaque, as
/// Algorithm 1 emits them).
fn scene(rng: &mut SplitMix64) -> (Vec<SceneInstance>, Vec<CpuBox>) {
    let mut real = Vec::new();
    for i in 0..12u32 {
        let at = Vec3::new(
            rng.range_f32(-1.0, 33.0),
            rng.range_f32(-1.0, 5.0),
            rng.range_f32(-1.0, 21.0),
        );
        let rot = Quat::from_euler(
            glam::EulerRot::XYZ,
            rng.range_f32(-1.5, 1.5),
            rng.range_f32(-1.5, 1.5),
            0.0,
        );
        real.push(SceneInstance {
            mesh: Mesh::quad(),
            transform: Affine3A::from_scale_rotation_translation(Vec3::splat(1.5), rot, at),
            custom_index: i,
            sbt_offset: 0,
            active: true,
        });
    }
    let mut boxes = Vec::new();
    for k in 0..40u32 {
        let (x, z) = ((k % 8) as f32 * 4.0, (k / 8) as f32 * 4.0);
        let h = rng.range_f32(0.5, 4.0);
        let omitted = k % 3 == 0;
        boxes.push(CpuBox {
            min: [x + 0.25, -0.5, z + 0.25],
            max: [x + 3.75, h, z + 3.75],
            kind: if omitted {
                CountingBoxKind::OmittedInstance
            } else {
                CountingBoxKind::Hitbox
            },
            index: if omitted { 20 + k } else { k },
            opaque: k % 2 == 0,
        });
    }
    (real, boxes)
}

/// The TLAS records of `scene` (quads at `quad_blas`, boxes on the cube).
fn records(
    real: &[SceneInstance],
    boxes: &[CpuBox],
    cfg: &CountingBoxConfig,
    quad_blas: &lipac_vk::GpuBlas,
    cube: u64,
) -> Vec<TlasInstance> {
    let mut out: Vec<TlasInstance> = real
        .iter()
        .map(|s| tlas_record(s, quad_blas, 0x01))
        .collect();
    for b in boxes {
        let mut r = counting_box_instance(b.min, b.max, b.kind, b.index, cfg, cube).unwrap();
        if b.opaque {
            let flags = VK_INSTANCE_CULL_DISABLE | VK_INSTANCE_FORCE_OPAQUE;
            r.sbt_offset_and_flags =
                (r.sbt_offset_and_flags & 0x00FF_FFFF) | (u32::from(flags) << 24);
        }
        out.push(r);
    }
    out
}

/// One path's trace of `rays`: hits, instance counters and hitbox records
/// (starting from `initial`).
struct Outcome {
    hits: Vec<GpuHit>,
    instances: Vec<u32>,
    hitboxes: Vec<HitboxRecord>,
}

fn trace_path(
    h: &HeadlessContext,
    tracer: &TestTracer,
    tlas: &lipac_vk::GpuTlas,
    rays: &[GpuRay],
    initial: &[HitboxRecord],
) -> Outcome {
    let ctx = h.context();
    let ray_buf = Buffer::with_data(ctx, STORAGE, MemoryLocation::CpuToGpu, rays).unwrap();
    let results = Buffer::new(
        ctx,
        (rays.len() * 16) as u64,
        STORAGE,
        MemoryLocation::GpuToCpu,
    )
    .unwrap();
    let instances =
        Buffer::with_data(ctx, STORAGE, MemoryLocation::GpuToCpu, &[0u32; SLOTS]).unwrap();
    let hitboxes = Buffer::with_data(ctx, STORAGE, MemoryLocation::GpuToCpu, initial).unwrap();
    let bounds = Buffer::with_data(
        ctx,
        STORAGE,
        MemoryLocation::CpuToGpu,
        &[[0f32; 4]; HITBOXES],
    )
    .unwrap();
    tracer.run(
        h,
        tlas,
        &ray_buf,
        rays.len() as u32,
        &results,
        &instances,
        &hitboxes,
        &bounds,
        &MergedBoxes::OFF,
        0xFF,
        0,
    );
    Outcome {
        hits: results.read(0, rays.len()).unwrap(),
        instances: instances.read(0, SLOTS).unwrap(),
        hitboxes: hitboxes.read(0, HITBOXES).unwrap(),
    }
}

/// 4000 random rays through quads and opaque and non-opaque counting boxes:
/// each tracing path the device has (both on lavapipe) and a CPU reference (nearest box
/// by slab test before the closest real hit by Möller–Trumbore, saturating
/// `HitboxRecord::add_hits`) agree on every ray's hit and on every counter
/// and hitbox record, bit for bit between the two paths.
pub fn random_rays_count_alike_on_both_paths_and_the_cpu() {
    let h = headless("random_rays_count_alike_on_both_paths_and_the_cpu");
    let ctx = h.context();
    let cfg = CountingBoxConfig::default();
    let mut rng = SplitMix64::new(0x005e_ed28);
    let (real, boxes) = scene(&mut rng);
    let mut one_shot = OneShot::new(ctx).unwrap();
    let QuadAndCube {
        quad, cube, built, ..
    } = quad_and_cube(&h, &mut one_shot);
    let recs = records(
        &real,
        &boxes,
        &cfg,
        &built.blases[0],
        built.blases[1].device_address(),
    );
    let (tlas, _instances) = build_tlas(&h, &recs);

    // Rays from above and from the sides, kept when the CPU's answer is
    // unambiguous (no edge grazing, no near-ties between box and hit).
    let mut rays = Vec::new();
    let mut want_instances = vec![0u32; SLOTS];
    let mut initial = vec![HitboxRecord::default(); HITBOXES];
    for (i, r) in initial.iter_mut().enumerate() {
        r.packed = match i % 4 {
            0 => (hitbox_bits::HITS_MAX - 2) << hitbox_bits::HITS_SHIFT,
            1 => (i as u32) << hitbox_bits::HITS_SHIFT | 0x5A,
            _ => 0,
        };
    }
    let mut want_hitboxes = initial.clone();
    let (mut counted, mut hit) = (0, 0);
    while rays.len() < 4000 {
        let origin = [
            rng.range_f32(-4.0, 36.0),
            rng.range_f32(6.0, 12.0),
            rng.range_f32(-4.0, 24.0),
        ];
        let target = Vec3::new(
            rng.range_f32(0.0, 32.0),
            rng.range_f32(-1.0, 3.0),
            rng.range_f32(0.0, 20.0),
        );
        let d = (target - Vec3::from(origin)).normalize();
        let ray = GpuRay {
            origin,
            t_min: 0.0,
            direction: d.to_array(),
            t_max: 100.0,
        };
        let real_hit = cpu_trace(&real, &ray);
        if real_hit.is_some_and(|c| c.ambiguous) {
            continue;
        }
        let entered: Vec<(f64, bool, &CpuBox)> = boxes
            .iter()
            .filter_map(|b| slab(&ray, b).map(|(t, clear)| (t, clear, b)))
            .collect();
        if entered.iter().any(|e| !e.1) {
            continue;
        }
        let nearest = entered.iter().min_by(|a, b| a.0.total_cmp(&b.0));
        if let (Some(n), Some(c)) = (nearest, real_hit) {
            if (n.0 - c.t).abs() < 1e-3 {
                continue;
            }
        }
        if let Some(&(t, _, b)) = nearest {
            if real_hit.is_none_or(|c| t <= c.t) {
                counted += 1;
                match b.kind {
                    CountingBoxKind::Hitbox => want_hitboxes[b.index as usize].add_hits(1),
                    CountingBoxKind::OmittedInstance => want_instances[b.index as usize] += 1,
                }
            }
        }
        if let Some(c) = real_hit {
            hit += 1;
            want_instances[c.custom_index as usize] += 1;
        }
        rays.push(ray);
    }
    assert!(
        counted > 1000 && hit > 300,
        "{counted} boxes counted, {hit} hits"
    );

    // Every path the device has against the CPU; the paths against each
    // other bit for bit.
    let outcomes: Vec<(TracingPath, Outcome)> = paths(&h)
        .into_iter()
        .map(|p| {
            let out = trace_path(&h, &TestTracer::new(&h, &cfg, p), &tlas, &rays, &initial);
            (p, out)
        })
        .collect();
    for (k, out) in &outcomes {
        let (compared, hits) = compare_with_cpu(&real, &rays, &out.hits);
        assert_eq!((compared, hits), (rays.len(), hit), "{k:?}");
        assert_eq!(out.instances, want_instances, "{k:?}: instance counters");
        for (i, (g, w)) in out.hitboxes.iter().zip(&want_hitboxes).enumerate() {
            assert_eq!(
                bytemuck::bytes_of(g),
                bytemuck::bytes_of(w),
                "{k:?}: hitbox {i}"
            );
        }
        let counted_gpu = out.hits.iter().filter(|x| x.counted_box()).count();
        assert_eq!(counted_gpu, counted, "{k:?}");
    }
    let (first, rq) = &outcomes[0];
    for (path, rt) in &outcomes[1..] {
        for (i, (a, b)) in rq.hits.iter().zip(&rt.hits).enumerate() {
            assert_eq!(
                bytemuck::bytes_of(a),
                bytemuck::bytes_of(b),
                "ray {i} {:?}: {first:?} {a:?}, {path:?} {b:?}",
                rays[i]
            );
        }
    }
    drop((tlas, built, cube, quad));
    assert_no_validation_errors(&h);
}

/// A camera frame (primary, shadow and bounce rays) over quads and opaque
/// counting boxes: `CameraTracer` and `PipelineCameraTracer` write the same
/// pixels, per-slot counters and hitbox records, bit for bit.
pub fn camera_frames_are_equal_on_both_paths() {
    let h = headless("camera_frames_are_equal_on_both_paths");
    let ctx = h.context();
    let cfg = CountingBoxConfig::default();
    let mut rng = SplitMix64::new(0x00ca_3e28);
    let (real, mut boxes) = scene(&mut rng);
    for b in &mut boxes {
        b.opaque = true;
    }
    let mut one_shot = OneShot::new(ctx).unwrap();
    let QuadAndCube {
        quad, cube, built, ..
    } = quad_and_cube(&h, &mut one_shot);
    let recs = records(
        &real,
        &boxes,
        &cfg,
        &built.blases[0],
        built.blases[1].device_address(),
    );
    let (tlas, _instances) = build_tlas(&h, &recs);
    let albedo: Vec<[f32; 4]> = (0..SLOTS)
        .map(|i| [0.2 + 0.01 * i as f32, 0.5, 0.9 - 0.01 * i as f32, 1.0])
        .collect();
    let data = Buffer::with_data(ctx, STORAGE, MemoryLocation::CpuToGpu, &albedo).unwrap();
    let offsets: Vec<u32> = (0..SLOTS as u32).map(|i| 16 * i).collect();
    let data_offsets = Buffer::with_data(ctx, STORAGE, MemoryLocation::CpuToGpu, &offsets).unwrap();
    let bounds = Buffer::with_data(
        ctx,
        STORAGE,
        MemoryLocation::CpuToGpu,
        &[[0f32; 4]; HITBOXES],
    )
    .unwrap();
    let (w, hgt) = (48u32, 32u32);
    let eye = Vec3::new(16.0, 14.0, -14.0);
    let fwd = (Vec3::new(16.0, 0.0, 10.0) - eye).normalize();
    let right = fwd.cross(Vec3::Y).normalize();
    let up = right.cross(fwd);
    let view = CameraView {
        origin: eye.to_array(),
        forward: fwd.to_array(),
        right: (right * 0.7 * 1.5).to_array(),
        up: (up * 0.7).to_array(),
        sun: Vec3::new(0.3, 1.0, 0.2).normalize().to_array(),
        t_max: 500.0,
        width: w,
        height: hgt,
        seed: 7,
        shadows: true,
        bounce: true,
    };
    let frame = |path: TracingPath| {
        let instance_hits =
            Buffer::with_data(ctx, STORAGE, MemoryLocation::GpuToCpu, &[0u32; SLOTS]).unwrap();
        let hitboxes = Buffer::with_data(
            ctx,
            STORAGE,
            MemoryLocation::GpuToCpu,
            &[HitboxRecord::default(); HITBOXES],
        )
        .unwrap();
        let image = Buffer::new(
            ctx,
            u64::from(w * hgt) * 4,
            STORAGE,
            MemoryLocation::GpuToCpu,
        )
        .unwrap();
        let buffers = CameraTraceBuffers {
            tlas: &tlas,
            instance_hits: &instance_hits,
            hitboxes: &hitboxes,
            data: &data,
            data_offsets: &data_offsets,
            image: &image,
            hitbox_bounds: &bounds,
        };
        let mut one_shot = OneShot::new(ctx).unwrap();
        match path {
            TracingPath::RayQuery => {
                let t = CameraTracer::new(ctx, &cfg).unwrap();
                let b = t.bind(&buffers).unwrap();
                one_shot
                    .run(|rec| t.record(rec, &b, &view, &MergedBoxes::OFF))
                    .unwrap();
            }
            TracingPath::RayTracingPipeline => {
                let t = PipelineCameraTracer::new(ctx, &cfg, 3).unwrap();
                let b = t.bind(&buffers).unwrap();
                one_shot
                    .run(|rec| t.record(rec, &b, &view, &MergedBoxes::OFF))
                    .unwrap();
            }
        }
        (
            image.read::<u32>(0, (w * hgt) as usize).unwrap(),
            instance_hits.read::<u32>(0, SLOTS).unwrap(),
            hitboxes.read::<HitboxRecord>(0, HITBOXES).unwrap(),
        )
    };
    let (img_q, inst_q, hb_q) = frame(TracingPath::RayQuery);
    let (img_p, inst_p, hb_p) = frame(TracingPath::RayTracingPipeline);
    let box_hits: u32 = hb_q.iter().map(HitboxRecord::hits).sum();
    assert!(
        box_hits > 100 && inst_q.iter().sum::<u32>() > 100,
        "the frame counts boxes and hits: {box_hits}, {inst_q:?}"
    );
    assert_eq!(inst_p, inst_q, "per-slot counters");
    for (i, (p, q)) in hb_p.iter().zip(&hb_q).enumerate() {
        assert_eq!(bytemuck::bytes_of(p), bytemuck::bytes_of(q), "hitbox {i}");
    }
    let differing = img_p.iter().zip(&img_q).filter(|(a, b)| a != b).count();
    assert_eq!(differing, 0, "pixels differ");
    drop((tlas, built, cube, quad));
    assert_no_validation_errors(&h);
}

/// On a context without ray queries (hidden) the ray-query tracers refuse
/// with an error naming the extension and what the device offers; without
/// pipelines the pipeline tracers do; `AnyCameraTracer` takes the path there is.
pub fn tracers_refuse_a_device_without_their_path() {
    let all = headless("tracers_refuse_a_device_without_their_path");
    let offered = all.context().tracing();
    drop(all);
    let cfg = CountingBoxConfig::default();
    for hidden in [TracingPath::RayQuery, TracingPath::RayTracingPipeline] {
        let mut hide = TracingPaths::NONE;
        match hidden {
            TracingPath::RayQuery => hide.ray_query = true,
            TracingPath::RayTracingPipeline => hide.ray_tracing_pipeline = true,
        }
        let options = HeadlessOptions {
            validation: validation(),
            device: std::env::var(lipac_vk::DEVICE_ENV).ok(),
            hide,
        };
        let h = match HeadlessContext::with_options(&options) {
            Ok(h) => h,
            Err(e) => {
                // Only a device with no other path may refuse.
                let other = match hidden {
                    TracingPath::RayQuery => offered.ray_tracing_pipeline,
                    TracingPath::RayTracingPipeline => offered.ray_query,
                };
                assert!(!other, "hiding {hidden} failed: {e}");
                assert!(matches!(e, VkError::NoSuitableDevice { .. }), "{e}");
                assert!(e.to_string().contains("hidden by LIPAC_VK_HIDE"), "{e}");
                continue;
            }
        };
        let ctx = h.context();
        assert!(!ctx.tracing().has(hidden));
        assert!(
            h.summary().contains("hidden by LIPAC_VK_HIDE"),
            "{}",
            h.summary()
        );
        let e = match hidden {
            TracingPath::RayQuery => CameraTracer::new(ctx, &cfg).unwrap_err(),
            TracingPath::RayTracingPipeline => PipelineTestTracer::new(ctx, &cfg, 3).unwrap_err(),
        };
        let offers = if hidden == TracingPath::RayQuery {
            "ray-tracing pipelines only"
        } else {
            "ray queries only"
        };
        assert_eq!(
            e.to_string(),
            format!(
                "{} needs {}; this device offers {offers}",
                if hidden == TracingPath::RayQuery {
                    "CameraTracer"
                } else {
                    "PipelineTestTracer"
                },
                hidden.extension()
            )
        );
        if hidden == TracingPath::RayQuery {
            let e = RayQueryTestPipeline::new(ctx, &cfg).unwrap_err();
            assert!(matches!(e, VkError::MissingFeature { .. }), "{e}");
        } else {
            let e = PipelineCameraTracer::new(ctx, &cfg, 3).unwrap_err();
            assert!(matches!(e, VkError::MissingFeature { .. }), "{e}");
        }
        let any = lipac_vk::AnyCameraTracer::new(ctx, &cfg, 3, None).unwrap();
        assert_ne!(any.path(), hidden);
        assert!(lipac_vk::AnyCameraTracer::new(ctx, &cfg, 3, Some(hidden)).is_err());
        drop(any);
        assert_no_validation_errors(&h);
    }
}
