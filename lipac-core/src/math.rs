//! Small geometric types shared by the core: axis-aligned boxes and the
//! row-major 3x4 transform of `VkTransformMatrixKHR`.

use glam::{Affine3A, Mat3A, Vec3, Vec3A};

/// An axis-aligned bounding box in world space.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Aabb {
    /// Minimum corner.
    pub min: Vec3,
    /// Maximum corner.
    pub max: Vec3,
}

impl Aabb {
    /// A box from its corners (not validated; see [`Aabb::is_valid`]).
    pub const fn new(min: Vec3, max: Vec3) -> Self {
        Self { min, max }
    }
    /// Centre of the box.
    pub fn center(&self) -> Vec3 {
        (self.min + self.max) * 0.5
    }
    /// Extent (`max - min`).
    pub fn size(&self) -> Vec3 {
        self.max - self.min
    }
    /// Finite corners with `min <= max` on every axis (zero extent allowed).
    pub fn is_valid(&self) -> bool {
        self.min.is_finite() && self.max.is_finite() && self.min.cmple(self.max).all()
    }
}

/// Converts an affine transform into the row-major 3x4 layout of
/// `VkTransformMatrixKHR`.
pub fn affine_to_rows(a: &Affine3A) -> [f32; 12] {
    let m = a.matrix3;
    let t = a.translation;
    [
        m.x_axis.x, m.y_axis.x, m.z_axis.x, t.x, //
        m.x_axis.y, m.y_axis.y, m.z_axis.y, t.y, //
        m.x_axis.z, m.y_axis.z, m.z_axis.z, t.z,
    ]
}

/// Converts a row-major 3x4 matrix back into an affine transform.
pub fn rows_to_affine(r: &[f32; 12]) -> Affine3A {
    Affine3A {
        matrix3: Mat3A::from_cols(
            Vec3A::new(r[0], r[4], r[8]),
            Vec3A::new(r[1], r[5], r[9]),
            Vec3A::new(r[2], r[6], r[10]),
        ),
        translation: Vec3A::new(r[3], r[7], r[11]),
    }
}

#[cfg(test)]
mod tests;
