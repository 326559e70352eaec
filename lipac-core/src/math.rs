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
mod tests {
    use lipac_test_support::{Rng64, SplitMix64};

    use super::*;

    #[test]
    fn rows_round_trip_and_apply() {
        let a = Affine3A::from_scale_rotation_translation(
            Vec3::new(2.0, 3.0, 4.0),
            glam::Quat::from_rotation_y(0.5),
            Vec3::new(10.0, -5.0, 7.0),
        );
        let r = affine_to_rows(&a);
        let p = Vec3::new(1.0, 2.0, 3.0);
        let by_rows = Vec3::new(
            r[0] * p.x + r[1] * p.y + r[2] * p.z + r[3],
            r[4] * p.x + r[5] * p.y + r[6] * p.z + r[7],
            r[8] * p.x + r[9] * p.y + r[10] * p.z + r[11],
        );
        assert!((by_rows - a.transform_point3(p)).length() < 1e-5);
        assert_eq!(rows_to_affine(&r), a);
    }

    /// The registry keeps an instance's transform only as the rows of its
    /// GPU record and rebuilds the `Affine3A` from them, so the round trip
    /// must be exact for every bit pattern (signed zeros, subnormals, NaN
    /// payloads included), not just within a tolerance.
    #[test]
    fn rows_round_trip_is_bit_exact() {
        let bits = |a: &Affine3A| -> Vec<u32> {
            let c = a.to_cols_array();
            c.iter().map(|v| v.to_bits()).collect()
        };
        let mut rng = SplitMix64::new(0x2545_F491_4F6C_DD1D);
        let special = [
            0.0,
            -0.0,
            f32::MIN_POSITIVE / 2.0,
            -1e-45,
            f32::MAX,
            f32::MIN,
        ];
        for case in 0..10_000u32 {
            let mut r = [0f32; 12];
            for (i, v) in r.iter_mut().enumerate() {
                let state = rng.next_u64();
                *v = if case % 4 == 0 {
                    special[(state % special.len() as u64) as usize]
                } else {
                    f32::from_bits((state >> 32) as u32 ^ i as u32)
                };
            }
            let a = rows_to_affine(&r);
            let back = affine_to_rows(&a);
            let same: Vec<u32> = back.iter().map(|v| v.to_bits()).collect();
            let want: Vec<u32> = r.iter().map(|v| v.to_bits()).collect();
            assert_eq!(same, want, "rows -> affine -> rows, case {case}");
            assert_eq!(bits(&rows_to_affine(&affine_to_rows(&a))), bits(&a));
        }
    }

    #[test]
    fn aabb_validity() {
        assert!(Aabb::new(Vec3::ZERO, Vec3::ZERO).is_valid());
        assert!(!Aabb::new(Vec3::ONE, Vec3::ZERO).is_valid());
        assert!(!Aabb::new(Vec3::new(f32::NAN, 0.0, 0.0), Vec3::ONE).is_valid());
    }
}
