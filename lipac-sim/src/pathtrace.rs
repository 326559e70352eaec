//! The hybrid path tracer of the paper's §3.1 on the CPU.
//!
//! * **Primary hits** come from the *full* scene TLAS ([`FrameScene::full`]),
//!   standing in for rasterized G-buffers: culled instances stay visible.
//!   Primary hits are not counted by default (rasterization runs no hit
//!   shaders); see [`PathTraceConfig::count_primary`].
//! * **Bounces** (cosine-weighted diffuse, perfect mirrors) trace the culled
//!   TLAS ([`FrameScene::traced`]) with pass-through counting boxes; every
//!   real closest hit counts into the hit instance's counter, a counted box
//!   into its instance or hitbox counter.
//! * **Sun shadows** at every shading point: a shadow ray against the culled
//!   TLAS (passing through and counting boxes, real hits not counted), then
//!   the *rasterized-shadow fallback*: the paper draws the shadows of
//!   instances culled from ray tracing, and of all vegetation (which shadow
//!   rays mask out), into a shadow map. We model an ideal shadow map (no
//!   aliasing, no bias) as an any-hit ray against the full TLAS restricted to
//!   exactly that caster set: instances *not* in [`FrameScene::traced_slots`],
//!   plus vegetation when [`PathTraceConfig::shadow_mask`] lacks the
//!   vegetation bit. The point is lit when neither blocks the sun. With the
//!   unculled TLAS as `traced`, the two caster sets partition the scene, so
//!   the culled render of an unculled TLAS equals ground truth.
//! * **Russian roulette** from bounce [`PathTraceConfig::rr_start`].
//!
//! * **Primary hits** are the same for every render of a frame: traced once
//!   ([`primary_hits`]), they are shared by [`render_with_primary`].
//!
//! Random numbers are [`crate::rng::sample`]`(frame, pixel, bounce, dim)`:
//! a render and its ground truth use identical numbers, and results do not
//! depend on the thread count (counters are sums).

use std::time::Instant;

use glam::{Vec3, Vec3A};

use crate::blas::BlasStore;
use crate::camera::FlyCamera;
use crate::error::SimError;
use crate::mesh::material as material_of;
use crate::rng::sample;
use crate::tlas::{masks, CpuTlas};
use crate::traversal::{occluded_by, trace, Counters, Hit, Ray, SlotSet, TraceResult};
use rayon::prelude::*;

/// Settings of [`render`].
#[derive(Clone, Debug, PartialEq)]
pub struct PathTraceConfig {
    /// Image width in pixels.
    pub width: u32,
    /// Image height in pixels.
    pub height: u32,
    /// Maximum number of bounces after the primary hit.
    pub max_bounces: u32,
    /// First bounce (1-based) at which Russian roulette may end a path.
    pub rr_start: u32,
    /// Unit direction towards the sun.
    pub sun_direction: Vec3,
    /// Sun irradiance (on a surface facing it), linear RGB.
    pub sun_irradiance: Vec3,
    /// Constant sky radiance, linear RGB.
    pub sky_radiance: Vec3,
    /// Mask of bounce rays (default: everything, counting boxes included).
    pub bounce_mask: u8,
    /// Mask of shadow rays (default: opaque geometry and counting boxes;
    /// vegetation shadows come from the rasterized fallback).
    pub shadow_mask: u8,
    /// Count primary hits into the instance counters.
    pub count_primary: bool,
    /// Worker threads (0 = all available cores); called inside a rayon
    /// pool (as the comparison does), the render uses that pool instead.
    pub threads: usize,
}

impl Default for PathTraceConfig {
    fn default() -> Self {
        Self {
            width: 160,
            height: 90,
            max_bounces: 3,
            rr_start: 2,
            sun_direction: Vec3::new(0.35, 0.8, 0.25).normalize(),
            sun_irradiance: Vec3::new(3.0, 2.9, 2.7),
            sky_radiance: Vec3::new(0.35, 0.45, 0.6),
            bounce_mask: masks::ALL,
            shadow_mask: masks::GEOMETRY | masks::COUNTING,
            count_primary: false,
            threads: 0,
        }
    }
}

impl PathTraceConfig {
    pub(crate) fn validate(&self) -> Result<(), SimError> {
        if self.width == 0 || self.height == 0 {
            return Err(SimError::BadConfig("image size must be positive"));
        }
        if !self.sun_direction.is_finite()
            || !self.sun_irradiance.is_finite()
            || !self.sky_radiance.is_finite()
        {
            return Err(SimError::NonFinite("sun and sky"));
        }
        if self.sun_direction.length_squared() < 1e-12 {
            return Err(SimError::BadConfig("sun direction must be non-zero"));
        }
        Ok(())
    }
}

/// What one frame renders against.
#[derive(Clone, Copy, Debug)]
pub struct FrameScene<'a> {
    /// The BLASes both TLASes reference.
    pub store: &'a BlasStore,
    /// The full (unculled) scene: primary hits and rasterized shadows.
    pub full: &'a CpuTlas,
    /// The culled TLAS that bounce and shadow rays trace.
    pub traced: &'a CpuTlas,
    /// Custom indices (instance slots, as in `full`) whose geometry is in
    /// `traced` ([`SlotSet::from_geometry_records`]).
    pub traced_slots: &'a SlotSet,
}

/// Rays traced in one frame.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct RayStats {
    /// Primary rays (against the full TLAS).
    pub primary: u64,
    /// Bounce rays (against the traced TLAS).
    pub bounce: u64,
    /// Shadow rays (against the traced TLAS).
    pub shadow: u64,
    /// Rasterized-shadow fallback queries (against the full TLAS).
    pub raster_shadow: u64,
}

impl RayStats {
    fn add(&mut self, o: &RayStats) {
        self.primary += o.primary;
        self.bounce += o.bounce;
        self.shadow += o.shadow;
        self.raster_shadow += o.raster_shadow;
    }
}

/// The result of [`render`].
#[derive(Clone, Debug, PartialEq)]
pub struct FrameOutput {
    /// Image width.
    pub width: u32,
    /// Image height.
    pub height: u32,
    /// Per pixel (row-major, row 0 at the top): direct sun light at the
    /// primary hit (or the sky).
    pub direct: Vec<Vec3>,
    /// Per pixel: indirect light leaving the primary hit towards the camera
    /// (all paths with at least one bounce).
    pub indirect: Vec<Vec3>,
    /// Hit counters of this frame.
    pub counters: Counters,
    /// Rays traced.
    pub rays: RayStats,
    /// CPU time, summed over threads, spent tracing the bounce and shadow
    /// rays against the traced (culled) TLAS, in nanoseconds. Primary hits and
    /// the rasterized-shadow fallback stand in for rasterization, which every
    /// strategy pays alike, and are not included. Not deterministic; see
    /// [`FrameOutput::without_timings`].
    pub traced_ns: u64,
}

impl FrameOutput {
    /// A copy with the timing zeroed, for bitwise comparisons of renders.
    pub fn without_timings(&self) -> Self {
        Self {
            traced_ns: 0,
            ..self.clone()
        }
    }
}

/// Relative RMSE of `image` against `reference`:
/// `sqrt(sum |a - b|^2 / sum |b|^2)` over all pixels and channels. Zero for
/// identical images; infinite when the reference is black and `image` not.
///
/// ```
/// use glam::Vec3;
/// use lipac_sim::pathtrace::relative_rmse;
/// let r = vec![Vec3::ONE; 4];
/// assert_eq!(relative_rmse(&r, &r).unwrap(), 0.0);
/// let half: Vec<Vec3> = r.iter().map(|v| *v * 0.5).collect();
/// assert!((relative_rmse(&half, &r).unwrap() - 0.5).abs() < 1e-9);
/// ```
pub fn relative_rmse(image: &[Vec3], reference: &[Vec3]) -> Result<f64, SimError> {
    if image.len() != reference.len() {
        return Err(SimError::SizeMismatch {
            a: image.len(),
            b: reference.len(),
        });
    }
    let (mut num, mut den) = (0.0f64, 0.0f64);
    for (a, b) in image.iter().zip(reference) {
        if !a.is_finite() || !b.is_finite() {
            return Err(SimError::NonFinite("image pixels"));
        }
        let d = (*a - *b).as_dvec3();
        num += d.length_squared();
        den += b.as_dvec3().length_squared();
    }
    Ok(if num == 0.0 {
        0.0
    } else if den == 0.0 {
        f64::INFINITY
    } else {
        (num / den).sqrt()
    })
}

/// Offset along the normal that keeps secondary rays off their surface.
#[inline]
fn offset(p: Vec3A, n: Vec3A) -> Vec3A {
    let scale = 1e-3 * (1.0 + p.abs().max_element() / 256.0);
    p + n * scale
}

/// Cosine-weighted direction about unit `n`.
#[inline]
fn cosine_sample(n: Vec3A, u1: f32, u2: f32) -> Vec3A {
    let r = u1.sqrt();
    let phi = std::f32::consts::TAU * u2;
    let (s, c) = phi.sin_cos();
    let (x, y, z) = (r * c, r * s, (1.0 - u1).max(0.0).sqrt());
    let sign = if n.z >= 0.0 { 1.0 } else { -1.0 };
    let a = -1.0 / (sign + n.z);
    let b = n.x * n.y * a;
    let t = Vec3A::new(1.0 + sign * n.x * n.x * a, sign * b, -sign * n.x);
    let bt = Vec3A::new(b, sign + n.y * n.y * a, -n.y);
    (t * x + bt * y + n * z).normalize()
}

struct Worker<'a> {
    fs: FrameScene<'a>,
    cfg: &'a PathTraceConfig,
    sun: Vec3A,
    frame: u32,
    counters: Counters,
    rays: RayStats,
    traced_ns: u64,
}

impl Worker<'_> {
    fn count(&mut self, r: &TraceResult, count_hit: bool) {
        if let Some(b) = &r.counted_box {
            self.counters.count_box(b);
        }
        if count_hit {
            if let Some(h) = &r.hit {
                self.counters.count_instance(h.custom_index);
            }
        }
    }

    /// Sun visibility at `p` (offset already applied).
    fn sun_visible(&mut self, p: Vec3A) -> bool {
        let fs = self.fs;
        self.rays.shadow += 1;
        let ray = Ray::unchecked(p, self.sun, 0.0, f32::INFINITY, self.cfg.shadow_mask);
        if fs.traced.box_count() == 0 || ray.mask & masks::COUNTING == 0 {
            // Nothing to count: a cheaper any-hit query gives the same answer.
            let mask = ray.mask;
            let t = Instant::now();
            let hit = occluded_by(fs.traced, fs.store, &ray, |_, m| m & mask != 0);
            self.traced_ns += elapsed_ns(t);
            if hit {
                return false;
            }
        } else {
            let t = Instant::now();
            let r = trace(fs.traced, fs.store, &ray, None);
            self.traced_ns += elapsed_ns(t);
            self.count(&r, false);
            if r.hit.is_some() {
                return false;
            }
        }
        // Rasterized shadows: culled instances of any kind, plus vegetation
        // when shadow rays mask it out (one any-hit query over both sets).
        self.rays.raster_shadow += 1;
        let slots = fs.traced_slots;
        let veg = self.cfg.shadow_mask & masks::VEGETATION == 0;
        let geometry = masks::ALL & !masks::COUNTING;
        !occluded_by(fs.full, fs.store, &ray, |custom, m| {
            (m & geometry != 0 && !slots.contains(custom)) || (veg && m & masks::VEGETATION != 0)
        })
    }

    /// Direct sun light reflected by a diffuse surface.
    fn direct(&mut self, p: Vec3A, n: Vec3A, albedo: Vec3) -> Vec3 {
        let cos = n.dot(self.sun);
        if cos <= 0.0 || !self.sun_visible(offset(p, n)) {
            return Vec3::ZERO;
        }
        albedo * self.cfg.sun_irradiance * (cos * std::f32::consts::FRAC_1_PI)
    }

    /// Shades pixel (`px`, `py`) whose primary hit is `primary` (traced
    /// by [`primary_hit`]).
    fn pixel(
        &mut self,
        camera: &FlyCamera,
        px: u32,
        py: u32,
        primary: Option<Hit>,
    ) -> (Vec3, Vec3) {
        let cfg = self.cfg;
        let fs = self.fs;
        let pixel = py * cfg.width + px;
        let d0 = primary_direction(camera, cfg, px, py);
        let o0: Vec3A = camera.position.into();
        self.rays.primary += 1;
        if cfg.count_primary {
            // A primary ray never counts a box (its mask leaves them out).
            if let Some(h) = &primary {
                self.counters.count_instance(h.custom_index);
            }
        }
        let Some(h) = primary else {
            return (cfg.sky_radiance, Vec3::ZERO);
        };
        let mut p = o0 + d0 * h.t;
        let mut n: Vec3A = h.normal.into();
        if n.dot(d0) > 0.0 {
            n = -n;
        }
        let mut mat = material_of(h.material);
        let direct = if mat.mirror {
            Vec3::ZERO
        } else {
            self.direct(p, n, mat.albedo)
        };
        let mut indirect = Vec3::ZERO;
        let mut beta = Vec3::ONE;
        let mut dir = d0;
        for bounce in 1..=cfg.max_bounces {
            dir = if mat.mirror {
                dir - n * (2.0 * dir.dot(n))
            } else {
                cosine_sample(
                    n,
                    sample(self.frame, pixel, bounce, 0),
                    sample(self.frame, pixel, bounce, 1),
                )
            };
            beta *= mat.albedo;
            self.rays.bounce += 1;
            let ray = Ray::unchecked(offset(p, n), dir, 0.0, f32::INFINITY, cfg.bounce_mask);
            let t = Instant::now();
            let r = trace(fs.traced, fs.store, &ray, None);
            self.traced_ns += elapsed_ns(t);
            self.count(&r, true);
            let Some(h) = r.hit else {
                indirect += beta * cfg.sky_radiance;
                break;
            };
            p = ray.origin + dir * h.t;
            n = h.normal.into();
            if n.dot(dir) > 0.0 {
                n = -n;
            }
            mat = material_of(h.material);
            if !mat.mirror {
                indirect += beta * self.direct(p, n, mat.albedo);
            }
            if bounce >= cfg.rr_start {
                let q = beta.max_element().clamp(0.05, 0.95);
                if sample(self.frame, pixel, bounce, 2) >= q {
                    break;
                }
                beta /= q;
            }
        }
        (direct, indirect)
    }
}

/// The primary hits of one frame: every camera ray's closest hit in the
/// full TLAS (the stand-in for the rasterized G-buffer, the same for every
/// render of the frame), traced once by [`primary_hits`] and shared by
/// [`render_with_primary`].
#[derive(Clone, Debug, PartialEq)]
pub struct PrimaryHits {
    camera: FlyCamera,
    width: u32,
    height: u32,
    hits: Vec<Option<Hit>>,
}

impl PrimaryHits {
    /// Pixels with a hit (the rest see the sky).
    pub fn hit_count(&self) -> usize {
        self.hits.iter().filter(|h| h.is_some()).count()
    }
}

/// The direction of pixel (`px`, `py`)'s camera ray.
#[inline]
fn primary_direction(camera: &FlyCamera, cfg: &PathTraceConfig, px: u32, py: u32) -> Vec3A {
    camera
        .ray_direction(px, py, cfg.width, cfg.height, (0.0, 0.0))
        .into()
}

/// The closest hit of pixel (`px`, `py`)'s camera ray in `full` (counting
/// boxes masked out).
#[inline]
fn primary_hit(
    full: &CpuTlas,
    store: &BlasStore,
    camera: &FlyCamera,
    cfg: &PathTraceConfig,
    px: u32,
    py: u32,
) -> Option<Hit> {
    let d0 = primary_direction(camera, cfg, px, py);
    let o0: Vec3A = camera.position.into();
    let primary = Ray::unchecked(o0, d0, 0.0, f32::INFINITY, masks::ALL & !masks::COUNTING);
    trace(full, store, &primary, None).hit
}

/// Runs `f` with `threads` workers (0 = all cores): inside a rayon pool
/// (a caller that parallelises more than one render, as the comparison
/// does) in that pool, otherwise in a pool of its own for the call.
fn in_pool<R: Send>(threads: usize, f: impl FnOnce() -> R + Send) -> Result<R, SimError> {
    if rayon::current_thread_index().is_some() {
        return Ok(f());
    }
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(worker_threads(threads))
        .build()
        .map_err(|e| SimError::BadValue(format!("render threads: {e}")))?;
    Ok(pool.install(f))
}

/// Threads that `threads` asks for: 0 = all available cores.
pub(crate) fn worker_threads(threads: usize) -> usize {
    if threads == 0 {
        std::thread::available_parallelism().map_or(1, |n| n.get())
    } else {
        threads
    }
}

/// Rows per unit of parallel work: blocks of rows balance sky-heavy and
/// city-heavy rows across workers.
const BLOCK_ROWS: usize = 4;

/// Traces the primary hits of `camera`'s view in `full` (see
/// [`PrimaryHits`]); rows in parallel as in [`render`].
pub fn primary_hits(
    full: &CpuTlas,
    store: &BlasStore,
    camera: &FlyCamera,
    config: &PathTraceConfig,
) -> Result<PrimaryHits, SimError> {
    config.validate()?;
    if !camera.position.is_finite() {
        return Err(SimError::NonFinite("camera position"));
    }
    let (w, h) = (config.width as usize, config.height as usize);
    let mut hits = vec![None; w * h];
    in_pool(config.threads, || {
        hits.par_chunks_mut(BLOCK_ROWS * w)
            .enumerate()
            .for_each(|(i, block)| {
                for (k, hit) in block.iter_mut().enumerate() {
                    let (px, py) = ((k % w) as u32, (i * BLOCK_ROWS + k / w) as u32);
                    *hit = primary_hit(full, store, camera, config, px, py);
                }
            })
    })?;
    Ok(PrimaryHits {
        camera: *camera,
        width: config.width,
        height: config.height,
        hits,
    })
}

/// Renders one frame: 1 sample per pixel, `counters` sized for
/// `instance_slots` instances and `hitboxes` hitboxes.
///
/// See the module docs for the model. Blocks of rows are shared out over
/// `config.threads` workers (or, called inside a rayon pool, that pool's);
/// the output does not depend on them.
pub fn render(
    scene: &FrameScene<'_>,
    camera: &FlyCamera,
    frame: u32,
    config: &PathTraceConfig,
    instance_slots: usize,
    hitboxes: usize,
) -> Result<FrameOutput, SimError> {
    let primary = primary_hits(scene.full, scene.store, camera, config)?;
    render_with_primary(
        scene,
        camera,
        frame,
        config,
        instance_slots,
        hitboxes,
        &primary,
    )
}

/// [`render`] with the frame's primary hits traced already: every render
/// of one frame (the ground truth and each strategy) shares them, since
/// primary rays trace the full TLAS, `scene.full`, which `primary` must have
/// been traced in ([`primary_hits`]). The output equals [`render`]'s.
/// Primary hits of another view or image size are an error.
pub fn render_with_primary(
    scene: &FrameScene<'_>,
    camera: &FlyCamera,
    frame: u32,
    config: &PathTraceConfig,
    instance_slots: usize,
    hitboxes: usize,
    primary: &PrimaryHits,
) -> Result<FrameOutput, SimError> {
    config.validate()?;
    if !camera.position.is_finite() {
        return Err(SimError::NonFinite("camera position"));
    }
    if primary.camera != *camera || primary.width != config.width || primary.height != config.height
    {
        return Err(SimError::BadConfig(
            "primary hits of another view or image size",
        ));
    }
    let w = config.width as usize;
    let n = w * config.height as usize;
    let sun: Vec3A = config.sun_direction.normalize().into();
    let mut direct = vec![Vec3::ZERO; n];
    let mut indirect = vec![Vec3::ZERO; n];
    let block = BLOCK_ROWS * w;
    let new_worker = || Worker {
        fs: *scene,
        cfg: config,
        sun,
        frame,
        counters: Counters::new(instance_slots, hitboxes),
        rays: RayStats::default(),
        traced_ns: 0,
    };
    // Counters are integer sums: the order in which workers merge does not
    // change them.
    let merged = in_pool(config.threads, || {
        direct
            .par_chunks_mut(block)
            .zip(indirect.par_chunks_mut(block))
            .zip(primary.hits.par_chunks(block))
            .enumerate()
            .fold(new_worker, |mut wk, (i, ((d, ind), hits))| {
                for (k, ((dp, ip), hit)) in d.iter_mut().zip(ind.iter_mut()).zip(hits).enumerate() {
                    let (px, py) = ((k % w) as u32, (i * BLOCK_ROWS + k / w) as u32);
                    (*dp, *ip) = wk.pixel(camera, px, py, *hit);
                }
                wk
            })
            .map(|wk| (wk.counters, wk.rays, wk.traced_ns))
            .reduce(
                || {
                    (
                        Counters::new(instance_slots, hitboxes),
                        RayStats::default(),
                        0,
                    )
                },
                |mut a, b| {
                    a.0.merge(&b.0);
                    a.1.add(&b.1);
                    a.2 += b.2;
                    a
                },
            )
    })?;
    let (counters, rays, traced_ns) = merged;
    Ok(FrameOutput {
        width: config.width,
        height: config.height,
        direct,
        indirect,
        counters,
        rays,
        traced_ns,
    })
}

fn elapsed_ns(t: Instant) -> u64 {
    u64::try_from(t.elapsed().as_nanos()).unwrap_or(u64::MAX)
}
