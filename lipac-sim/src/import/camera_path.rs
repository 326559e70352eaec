//! The camera path of an imported scene: the file's cameras (one: held
//! still; several: flown through in order, position interpolated linearly
//! and orientation spherically) or a generated orbit or fly-through over
//! the scene's bounds.

use glam::Vec3;
use lipac_core::math::Aabb;
use lipac_core::trace::Camera;

use super::gltf::ImportedCamera;

/// Where an imported trace's cameras come from.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum CameraSource {
    /// The file's cameras if it has any, else an orbit.
    #[default]
    Auto,
    /// The file's cameras (an error without any).
    File,
    /// A circle around the scene, looking at its centre.
    Orbit,
    /// A straight flight across the scene at a quarter of its height.
    Flythrough,
}

/// Vertical field of view of generated paths, radians (60°).
pub const DEFAULT_FOV: f32 = std::f32::consts::FRAC_PI_3;

/// The camera of frame `f` of `frames` along the file's `cams` (at least
/// one), with `aspect` where the file gives none.
pub fn file_camera(cams: &[ImportedCamera], f: u32, frames: u32, aspect: f32) -> Camera {
    let c0 = cams[0];
    let (a, b, t) = if cams.len() == 1 || frames <= 1 {
        (c0, c0, 0.0)
    } else {
        let u = f as f32 / (frames - 1) as f32 * (cams.len() - 1) as f32;
        let i = (u.floor() as usize).min(cams.len() - 2);
        (cams[i], cams[i + 1], u - i as f32)
    };
    let fov = a.vertical_fov + (b.vertical_fov - a.vertical_fov) * t;
    Camera {
        position: a.position.lerp(b.position, t),
        orientation: a.orientation.slerp(b.orientation, t).normalize(),
        vertical_fov: fov.clamp(1e-3, std::f32::consts::PI - 1e-3),
        aspect: a
            .aspect
            .filter(|x| *x > 0.0 && x.is_finite())
            .unwrap_or(aspect),
    }
}

/// Frame `f` of `frames` of an orbit around `bounds`: radius 0.8 of the
/// horizontal diagonal, height half the diagonal above the centre.
pub fn orbit(bounds: &Aabb, f: u32, frames: u32, aspect: f32) -> Camera {
    let c = bounds.center();
    let s = bounds.size();
    let diag = Vec3::new(s.x, 0.0, s.z).length().max(s.y).max(1.0);
    let a = std::f32::consts::TAU * f as f32 / frames.max(1) as f32;
    let eye = c + Vec3::new(0.8 * diag * a.cos(), 0.5 * diag, 0.8 * diag * a.sin());
    Camera::look_to(eye, c - eye, Vec3::Y, DEFAULT_FOV, aspect)
}

/// Frame `f` of `frames` of a straight flight along the longer horizontal
/// axis of `bounds`, from just outside one end to just outside the other.
pub fn flythrough(bounds: &Aabb, f: u32, frames: u32, aspect: f32) -> Camera {
    let c = bounds.center();
    let s = bounds.size();
    let t = f as f32 / (frames.max(2) - 1) as f32;
    let along_x = s.x >= s.z;
    let (half, dir) = if along_x {
        (0.55 * s.x, Vec3::X)
    } else {
        (0.55 * s.z, Vec3::Z)
    };
    let h = bounds.min.y + 0.25 * s.y.max(2.0) + 1.0;
    let start = Vec3::new(c.x, h, c.z) - dir * half.max(1.0);
    let eye = start + dir * (2.0 * half.max(1.0) * t);
    Camera::look_to(eye, dir - 0.15 * Vec3::Y, Vec3::Y, DEFAULT_FOV, aspect)
}

#[cfg(test)]
mod tests;
