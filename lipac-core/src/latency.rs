//! Latency mitigation (paper §3.6): instances that newly appear in the view
//! frustum are activated on the CPU in the same frame, instead of waiting
//! frames for hit feedback to be read back and their BLASes to be built.
//!
//! Each frame the engine calls [`LatencyMitigation::update`] with the camera;
//! it tests every live instance's AABB against the [`Frustum`] and returns the
//! slots that are in the frustum now but were not at the previous update
//! (newly registered instances included) and pass the
//! [`ActivationHeuristic`]. The caller makes sure those have a BLAS and sets
//! them [`InstanceState::Active`]; hit feedback deactivates the unimportant
//! ones again soon after.
//!
//! Cost: one frustum test per live slot per update, over the dense
//! [`InstanceRecord`](crate::layout::InstanceRecord) array, and one bit of
//! memory per slot.

use crate::error::CoreError;
use crate::hitbox_index::HitboxIndex;
use crate::layout::InstanceState;
use crate::math::Aabb;
use crate::registry::InstanceRegistry;
use glam::{Mat4, Vec3};

/// Relative slack of the plane test, so that `f32` rounding in the caller's
/// own clip-space computation can never make it reject a visible box.
const PLANE_SLACK: f64 = 1e-6;

/// A view frustum as six planes, extracted from a view-projection matrix.
///
/// Convention: `glam` column vectors, `clip = view_proj * (world, 1)`, and the
/// Vulkan / Direct3D clip volume `-w <= x <= w`, `-w <= y <= w`,
/// `0 <= z <= w` (depth 0..1). Reversed-Z and infinite far planes fit that
/// volume as well (a plane without a normal then always passes); a flipped Y
/// axis does not matter. OpenGL's `-w <= z` depth range does not: its near
/// plane would be placed too close, which errs on the accepting side.
///
/// ```
/// use glam::camera::rh::{proj, view};
/// use glam::Vec3;
/// use lipac_core::latency::Frustum;
///
/// let view = view::look_to_mat4(Vec3::ZERO, Vec3::NEG_Z, Vec3::Y);
/// let proj = proj::vulkan::perspective(60f32.to_radians(), 16.0 / 9.0, 0.1, 1000.0);
/// let frustum = Frustum::from_view_projection(proj * view)?;
/// assert!(frustum.intersects(Vec3::new(-1.0, -1.0, -11.0), Vec3::new(1.0, 1.0, -9.0)));
/// assert!(!frustum.intersects(Vec3::new(-1.0, -1.0, 9.0), Vec3::new(1.0, 1.0, 11.0))); // behind
/// # Ok::<(), lipac_core::error::CoreError>(())
/// ```
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Frustum {
    /// `[a, b, c, d]`: inside where `a x + b y + c z + d >= 0` (in `f64`).
    planes: [[f64; 4]; 6],
}

impl Frustum {
    /// Extracts the planes of `view_proj` (Gribb–Hartmann), in `f64`. Fails
    /// with [`CoreError::NonFinite`] for a matrix with NaN or infinite
    /// entries.
    pub fn from_view_projection(view_proj: Mat4) -> Result<Self, CoreError> {
        if !view_proj.is_finite() {
            return Err(CoreError::NonFinite {
                what: "view-projection matrix",
            });
        }
        let cols = view_proj.to_cols_array_2d();
        let row = |i: usize| cols.map(|c| f64::from(c[i]));
        let (r0, r1, r2, r3) = (row(0), row(1), row(2), row(3));
        let add = |a: [f64; 4], b: [f64; 4]| [a[0] + b[0], a[1] + b[1], a[2] + b[2], a[3] + b[3]];
        let sub = |a: [f64; 4], b: [f64; 4]| [a[0] - b[0], a[1] - b[1], a[2] - b[2], a[3] - b[3]];
        Ok(Self {
            // -w <= x, x <= w, -w <= y, y <= w, 0 <= z, z <= w.
            planes: [
                add(r3, r0),
                sub(r3, r0),
                add(r3, r1),
                sub(r3, r1),
                r2,
                sub(r3, r2),
            ],
        })
    }

    /// The six planes `[a, b, c, d]` (not normalised); a point is inside
    /// where `a x + b y + c z + d >= 0` for all of them. Order: left, right,
    /// bottom, top (in clip space), near, far.
    pub fn planes(&self) -> &[[f64; 4]; 6] {
        &self.planes
    }

    /// Whether the box `min..max` may intersect the frustum.
    ///
    /// Conservative: never `false` for a box that intersects the frustum. It
    /// is exact whenever one frustum plane separates the box from the
    /// frustum; a box near a frustum edge that no single plane separates is
    /// reported as intersecting.
    pub fn intersects(&self, min: Vec3, max: Vec3) -> bool {
        let (min, max) = (min.to_array(), max.to_array());
        self.planes.iter().all(|p| {
            let mut dist = p[3];
            let mut magnitude = p[3].abs();
            for axis in 0..3 {
                // The corner farthest along the plane normal (the p-vertex).
                let v = if p[axis] >= 0.0 { max[axis] } else { min[axis] };
                let term = p[axis] * f64::from(v);
                dist += term;
                magnitude += term.abs();
            }
            dist >= -PLANE_SLACK * magnitude
        })
    }

    /// [`Frustum::intersects`] for an [`Aabb`].
    pub fn intersects_aabb(&self, aabb: &Aabb) -> bool {
        self.intersects(aabb.min, aabb.max)
    }

    /// Whether the point `p` is inside (within the same slack).
    pub fn contains_point(&self, p: Vec3) -> bool {
        self.intersects(p, p)
    }
}

/// Which newly visible instances are activated at once (§3.6 leaves the
/// heuristic open; this is the paper's "distance to camera and size").
///
/// An instance is accepted if it is **near** — the distance from the camera to
/// its AABB (0 inside it) is at most `max_distance` — **or large** — its
/// bounding-sphere radius (half the AABB diagonal) divided by the distance
/// from the camera to the AABB centre is at least `min_projected_size` (a
/// camera inside the bounding sphere always counts as large). The projected
/// size is roughly the tangent of the half-angle the instance subtends.
///
/// `max_distance = f32::INFINITY` or `min_projected_size = 0` accept every
/// newly visible instance.
///
/// What counts as *visible* is the frustum, and with a `surround_radius`
/// also every instance within that distance of the camera in any
/// direction: off-screen geometry near the camera shadows and reflects
/// into the view (the frustum + radius baseline's 800 m). `0` (the
/// default) is the frustum alone.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ActivationHeuristic {
    /// Distance (metres) within which every newly visible instance is
    /// accepted. Default 50.
    pub max_distance: f32,
    /// Smallest `radius / distance` of a farther instance to be accepted.
    /// Default 0.1 (a 10 m radius building at 100 m).
    pub min_projected_size: f32,
    /// Distance (metres) from the camera to an instance's AABB within
    /// which it counts as visible whether or not it is in the frustum.
    /// Default 0: the frustum alone.
    pub surround_radius: f32,
}

impl Default for ActivationHeuristic {
    fn default() -> Self {
        Self {
            max_distance: 50.0,
            min_projected_size: 0.1,
            surround_radius: 0.0,
        }
    }
}

impl ActivationHeuristic {
    fn validate(&self) -> Result<(), CoreError> {
        for (name, v) in [
            ("max_distance", self.max_distance),
            ("min_projected_size", self.min_projected_size),
            ("surround_radius", self.surround_radius),
        ] {
            if v.is_nan() || v < 0.0 {
                return Err(CoreError::InvalidConfig {
                    what: format!("activation heuristic {name} = {v} must be >= 0"),
                });
            }
        }
        Ok(())
    }

    /// Whether an instance with bounds `aabb` seen from `camera` is accepted.
    pub fn accepts(&self, camera: Vec3, aabb: &Aabb) -> bool {
        let near = distance_to_box(camera, aabb);
        if near <= self.max_distance {
            return true;
        }
        let radius = 0.5 * aabb.size().length();
        let to_center = aabb.center().distance(camera);
        to_center <= radius || radius >= self.min_projected_size * to_center
    }

    /// Whether an instance with bounds `aabb` counts as visible from
    /// `camera` though outside the frustum: within
    /// [`ActivationHeuristic::surround_radius`] of it.
    pub fn surrounds(&self, camera: Vec3, aabb: &Aabb) -> bool {
        self.surround_radius > 0.0 && distance_to_box(camera, aabb) <= self.surround_radius
    }
}

/// Distance from `p` to the box (0 inside it).
fn distance_to_box(p: Vec3, aabb: &Aabb) -> f32 {
    p.clamp(aabb.min, aabb.max).distance(p)
}

/// Counts of one [`LatencyMitigation::update`].
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct LatencySummary {
    /// Live instances tested against the frustum.
    pub tested: u32,
    /// Of those, in the frustum now (or within the surround radius).
    pub in_frustum: u32,
    /// Of those, not in the frustum at the previous update (or new since).
    pub newly_visible: u32,
    /// Newly visible instances that are already active (not returned).
    pub already_active: u32,
    /// Newly visible, not yet active, and accepted by the heuristic: the
    /// slots returned.
    pub accepted: u32,
}

/// Per-slot memory of which instances were in the frustum at the previous
/// update.
///
/// ```
/// use glam::camera::rh::{proj, view};
/// use glam::{Affine3A, Vec3};
/// use lipac_core::grid::{GridConfig, HitboxGrid};
/// use lipac_core::instance::{InstanceDesc, MeshId};
/// use lipac_core::latency::{ActivationHeuristic, Frustum, LatencyMitigation};
/// use lipac_core::math::Aabb;
/// use lipac_core::registry::{InstanceRegistry, RegistryConfig};
///
/// let mut reg = InstanceRegistry::new(HitboxGrid::new(GridConfig::default())?, RegistryConfig::default())?;
/// let c = Vec3::new(0.0, 0.0, -20.0);
/// let aabb = Aabb::new(c - Vec3::ONE, c + Vec3::ONE);
/// reg.register(InstanceDesc::new(MeshId(0), Affine3A::from_translation(c), aabb))?;
///
/// let camera = Vec3::ZERO;
/// let view = view::look_to_mat4(camera, Vec3::NEG_Z, Vec3::Y);
/// let proj = proj::vulkan::perspective(1.0, 1.5, 0.1, 500.0);
/// let frustum = Frustum::from_view_projection(proj * view)?;
///
/// let mut lm = LatencyMitigation::new(ActivationHeuristic::default())?;
/// let mut activate = Vec::new();
/// let summary = lm.update(&reg, camera, &frustum, &mut activate)?;
/// assert_eq!(activate, vec![0]); // activate slot 0 this frame
/// assert_eq!(summary.newly_visible, 1);
/// // Next frame it is no longer *newly* visible.
/// lm.update(&reg, camera, &frustum, &mut activate)?;
/// assert!(activate.is_empty());
/// # Ok::<(), lipac_core::error::CoreError>(())
/// ```
#[derive(Clone, Debug, Default)]
pub struct LatencyMitigation {
    heuristic: ActivationHeuristic,
    /// Bit per slot: in the frustum at the previous update.
    visible: Vec<u64>,
    /// The registry's registration count at the previous update: slots whose
    /// occupant has a serial at or above it hold a new instance.
    seen_registrations: u64,
}

impl LatencyMitigation {
    /// A fresh tracker (nothing seen yet). Rejects a heuristic with NaN or
    /// negative values.
    pub fn new(heuristic: ActivationHeuristic) -> Result<Self, CoreError> {
        heuristic.validate()?;
        Ok(Self {
            heuristic,
            ..Self::default()
        })
    }

    /// The heuristic in use.
    pub fn heuristic(&self) -> ActivationHeuristic {
        self.heuristic
    }

    /// Replaces the heuristic (validated as in [`LatencyMitigation::new`]).
    pub fn set_heuristic(&mut self, heuristic: ActivationHeuristic) -> Result<(), CoreError> {
        heuristic.validate()?;
        self.heuristic = heuristic;
        Ok(())
    }

    /// Forgets what was visible: the next update treats every instance in the
    /// frustum as newly visible.
    pub fn reset(&mut self) {
        self.visible.clear();
        self.seen_registrations = 0;
    }

    /// Heap bytes held (one bit per slot).
    pub(crate) fn heap_bytes(&self) -> u64 {
        crate::memory::vec_bytes::<u64>(self.visible.capacity())
    }

    /// Whether the instance in `slot` was in the frustum at the last update.
    pub fn was_visible(&self, slot: u32) -> bool {
        self.visible
            .get((slot / 64) as usize)
            .is_some_and(|w| w & (1 << (slot % 64)) != 0)
    }

    /// Tests every live instance of `registry` against `frustum`, remembers
    /// the result, and fills `activate` (cleared first) with the slots, in
    /// ascending order, that are newly in the frustum, not already
    /// [`InstanceState::Active`], and accepted by the heuristic from
    /// `camera`. An instance whose AABB contains `camera` counts as in the
    /// frustum even if it ends before the near plane (rays start inside it),
    /// and so does one within the heuristic's
    /// [`ActivationHeuristic::surround_radius`].
    ///
    /// Removed instances are forgotten, and a reused slot counts as a new
    /// instance even if updates were skipped in between. Use one tracker per
    /// registry. Fails only for a non-finite `camera`, changing nothing.
    pub fn update<H: HitboxIndex>(
        &mut self,
        registry: &InstanceRegistry<H>,
        camera: Vec3,
        frustum: &Frustum,
        activate: &mut Vec<u32>,
    ) -> Result<LatencySummary, CoreError> {
        let records = registry.records();
        self.update_with(
            registry,
            camera,
            frustum,
            |slot| records.hot()[slot as usize].state() == InstanceState::Active,
            activate,
        )
    }

    /// [`LatencyMitigation::update`] with `is_active(slot)` telling which
    /// live slots are already active (instead of the records' state bits):
    /// [`crate::culling::Culling`] passes its commanded state, so that a CPU
    /// and a GPU backend (whose CPU records do not carry the GPU's state)
    /// decide alike.
    pub fn update_with<H: HitboxIndex>(
        &mut self,
        registry: &InstanceRegistry<H>,
        camera: Vec3,
        frustum: &Frustum,
        is_active: impl Fn(u32) -> bool,
        activate: &mut Vec<u32>,
    ) -> Result<LatencySummary, CoreError> {
        if !camera.is_finite() {
            return Err(CoreError::NonFinite {
                what: "camera position",
            });
        }
        activate.clear();
        let records = registry.records();
        self.visible.resize(records.len().div_ceil(64), 0);
        let mut summary = LatencySummary::default();
        for (slot, record) in (0u32..).zip(records.bounds()) {
            let (word, bit) = ((slot / 64) as usize, 1u64 << (slot % 64));
            let was = self.visible[word] & bit != 0;
            self.visible[word] &= !bit;
            let Some(serial) = registry.serial_at(slot) else {
                continue; // dead or quarantined: forget it
            };
            summary.tested += 1;
            let aabb = Aabb::new(record.aabb_min.into(), record.aabb_max.into());
            // A box around the camera is in view even where it ends before
            // the near plane: every primary ray starts inside it.
            let around_camera = camera.cmpge(aabb.min).all() && camera.cmple(aabb.max).all();
            if !around_camera
                && !frustum.intersects_aabb(&aabb)
                && !self.heuristic.surrounds(camera, &aabb)
            {
                continue;
            }
            self.visible[word] |= bit;
            summary.in_frustum += 1;
            if was && serial < self.seen_registrations {
                continue;
            }
            summary.newly_visible += 1;
            if is_active(slot) {
                summary.already_active += 1;
            } else if self.heuristic.accepts(camera, &aabb) {
                summary.accepted += 1;
                activate.push(slot);
            }
        }
        self.seen_registrations = registry.registration_count();
        Ok(summary)
    }
}

#[cfg(test)]
mod tests;
