//! Cameras and camera paths: the paper's fly-through, a camera jump (cold
//! start) and static views. A camera generates primary rays and a
//! view-projection matrix for frustum tests.

use glam::{Mat4, Vec3};
use lipac_core::latency::Frustum;

use crate::error::SimError;
use crate::scene::{Scene, FPS};

/// The laboratory's yaw/pitch pinhole camera. A trace stores a
/// [`lipac_core::trace::Camera`] instead; [`crate::record`] converts between
/// them. `yaw` 0 looks along +z, positive yaw turns towards +x; `pitch` is up
/// from the horizon (radians).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FlyCamera {
    /// Eye position.
    pub position: Vec3,
    /// Heading, radians.
    pub yaw: f32,
    /// Elevation, radians.
    pub pitch: f32,
    /// Vertical field of view, radians.
    pub vfov: f32,
    /// Width / height.
    pub aspect: f32,
}

/// The eye moving more than this many metres in one frame is a cut
/// ([`FlyCamera::is_cut_from`]).
pub const CUT_DISTANCE: f32 = 100.0;
/// The view turning by more than this (radians) in one frame is a cut
/// ([`FlyCamera::is_cut_from`]).
pub const CUT_TURN: f32 = std::f32::consts::FRAC_PI_2;

/// Near plane of [`FlyCamera::view_proj`].
pub const NEAR: f32 = 0.1;
/// Far plane of [`FlyCamera::view_proj`].
pub const FAR: f32 = 20_000.0;

impl FlyCamera {
    /// A validated camera (finite values, `0 < vfov < pi`, `aspect > 0`).
    pub fn new(
        position: Vec3,
        yaw: f32,
        pitch: f32,
        vfov: f32,
        aspect: f32,
    ) -> Result<Self, SimError> {
        if !position.is_finite() || ![yaw, pitch, vfov, aspect].iter().all(|v| v.is_finite()) {
            return Err(SimError::NonFinite("camera parameters"));
        }
        if !(vfov > 0.0 && vfov < std::f32::consts::PI) || aspect <= 0.0 {
            return Err(SimError::BadConfig(
                "camera needs 0 < vfov < pi and aspect > 0",
            ));
        }
        Ok(Self {
            position,
            yaw,
            pitch,
            vfov,
            aspect,
        })
    }
    /// A camera at `position` looking at `target`.
    pub fn look_at(position: Vec3, target: Vec3, vfov: f32, aspect: f32) -> Result<Self, SimError> {
        let d = target - position;
        if !d.is_finite() || d.length_squared() == 0.0 {
            return Err(SimError::BadConfig("look_at needs distinct finite points"));
        }
        let yaw = d.x.atan2(d.z);
        let pitch = (d.y / d.length()).clamp(-1.0, 1.0).asin();
        Self::new(position, yaw, pitch, vfov, aspect)
    }
    /// Unit view direction.
    pub fn forward(&self) -> Vec3 {
        let (sy, cy) = self.yaw.sin_cos();
        let (sp, cp) = self.pitch.sin_cos();
        Vec3::new(cp * sy, sp, cp * cy)
    }
    /// Whether going from `previous` to this camera is a cut (a teleport or
    /// a cinematic cut, not motion): the eye moved more than
    /// [`CUT_DISTANCE`] metres or the view turned by more than
    /// [`CUT_TURN`] radians in one frame. A replay finds a trace's cuts
    /// this way (traces do not mark them); the built-in paths move at most
    /// 15 m and a few degrees per frame, their jumps 850 m.
    ///
    /// ```
    /// use glam::Vec3;
    /// use lipac_sim::camera::FlyCamera;
    /// let a = FlyCamera::new(Vec3::ZERO, 0.0, 0.0, 1.0, 1.5).unwrap();
    /// let walk = FlyCamera::new(Vec3::new(0.0, 0.0, 20.0), 0.3, 0.0, 1.0, 1.5).unwrap();
    /// let far = FlyCamera::new(Vec3::new(0.0, 0.0, 500.0), 0.0, 0.0, 1.0, 1.5).unwrap();
    /// let behind = FlyCamera::new(Vec3::ZERO, 3.0, 0.0, 1.0, 1.5).unwrap();
    /// assert!(!walk.is_cut_from(&a));
    /// assert!(far.is_cut_from(&a) && behind.is_cut_from(&a));
    /// ```
    pub fn is_cut_from(&self, previous: &FlyCamera) -> bool {
        self.position.distance(previous.position) > CUT_DISTANCE
            || self.forward().dot(previous.forward()) < CUT_TURN.cos()
    }
    /// Unit right and up vectors of the image plane.
    pub fn basis(&self) -> (Vec3, Vec3) {
        let f = self.forward();
        let right = f.cross(Vec3::Y).try_normalize().unwrap_or(Vec3::X);
        let up = right.cross(f);
        (right, up)
    }
    /// Unit direction of the primary ray through pixel `(px, py)` of a
    /// `width` x `height` image (row 0 at the top), through the pixel centre
    /// offset by `jitter` (each in `[-0.5, 0.5]`).
    pub fn ray_direction(
        &self,
        px: u32,
        py: u32,
        width: u32,
        height: u32,
        jitter: (f32, f32),
    ) -> Vec3 {
        let (right, up) = self.basis();
        let th = (0.5 * self.vfov).tan();
        let sx =
            ((px as f32 + 0.5 + jitter.0) / width.max(1) as f32 * 2.0 - 1.0) * th * self.aspect;
        let sy = (1.0 - (py as f32 + 0.5 + jitter.1) / height.max(1) as f32 * 2.0) * th;
        (self.forward() + right * sx + up * sy).normalize()
    }
    /// View-projection matrix for Vulkan: right-handed view, NDC depth
    /// `0..1` ([`NEAR`]..[`FAR`]) and NDC y pointing down (row 0 of the
    /// image at y = -1).
    pub fn view_proj(&self) -> Mat4 {
        let view = glam::camera::rh::view::look_to_mat4(self.position, self.forward(), Vec3::Y);
        glam::camera::rh::proj::vulkan::perspective(self.vfov, self.aspect, NEAR, FAR) * view
    }
    /// The view frustum of [`Self::view_proj`] (lipac-core's conservative
    /// plane test, the one latency mitigation uses).
    ///
    /// ```
    /// use lipac_sim::camera::FlyCamera;
    /// use lipac_core::math::Aabb;
    /// use glam::Vec3;
    /// let cam = FlyCamera::new(Vec3::ZERO, 0.0, 0.0, 1.0, 1.0).unwrap();
    /// let ahead = Aabb::new(Vec3::new(-1.0, -1.0, 9.0), Vec3::new(1.0, 1.0, 11.0));
    /// let behind = Aabb::new(Vec3::new(-1.0, -1.0, -11.0), Vec3::new(1.0, 1.0, -9.0));
    /// let frustum = cam.frustum().unwrap();
    /// assert!(frustum.intersects_aabb(&ahead));
    /// assert!(!frustum.intersects_aabb(&behind));
    /// ```
    pub fn frustum(&self) -> Result<Frustum, SimError> {
        Frustum::from_view_projection(self.view_proj()).map_err(SimError::core)
    }
}

#[derive(Clone, Copy, Debug, PartialEq)]
struct Key {
    frame: f32,
    position: Vec3,
    yaw: f32,
    pitch: f32,
}

/// A camera path over a number of frames.
#[derive(Clone, Debug, PartialEq)]
pub struct CameraPath {
    segments: Vec<Vec<Key>>,
    /// First frame of each segment after the first (jumps).
    cuts: Vec<u32>,
    frames: u32,
    vfov: f32,
    aspect: f32,
}

fn interpolate(keys: &[Key], frame: f32) -> Key {
    if keys.len() == 1 || frame <= keys[0].frame {
        return keys[0];
    }
    let last = keys.len() - 1;
    if frame >= keys[last].frame {
        return keys[last];
    }
    let i = keys
        .windows(2)
        .position(|w| frame < w[1].frame)
        .unwrap_or(last - 1);
    let (k1, k2) = (keys[i], keys[i + 1]);
    let t = (frame - k1.frame) / (k2.frame - k1.frame);
    // Smoothstep the parameter so each key is a rest point (no velocity jumps),
    // and blend linearly between the two keys: the camera never leaves the
    // segment between them. (A Catmull-Rom spline through unevenly spaced keys
    // overshot: the descent to street level dipped below the terrain.)
    let s = t * t * (3.0 - 2.0 * t);
    let c = |f: fn(&Key) -> f32| f(&k1) + (f(&k2) - f(&k1)) * s;
    Key {
        frame,
        position: Vec3::new(
            c(|k| k.position.x),
            c(|k| k.position.y),
            c(|k| k.position.z),
        ),
        yaw: c(|k| k.yaw),
        pitch: c(|k| k.pitch),
    }
}

impl CameraPath {
    /// Number of frames.
    pub fn frames(&self) -> u32 {
        self.frames
    }
    /// Frames at which the camera jumps (cold starts).
    pub fn cuts(&self) -> &[u32] {
        &self.cuts
    }
    /// The camera at `frame` (clamped to the path).
    pub fn camera_at(&self, frame: u32) -> FlyCamera {
        let seg = self.cuts.iter().filter(|&&c| frame >= c).count();
        let k = interpolate(&self.segments[seg], frame as f32);
        FlyCamera {
            position: k.position,
            yaw: k.yaw,
            pitch: k.pitch,
            vfov: self.vfov,
            aspect: self.aspect,
        }
    }

    /// A camera standing still for `frames` frames.
    pub fn fixed(camera: FlyCamera, frames: u32) -> Self {
        let k = Key {
            frame: 0.0,
            position: camera.position,
            yaw: camera.yaw,
            pitch: camera.pitch,
        };
        Self {
            segments: vec![vec![k]],
            cuts: Vec::new(),
            frames,
            vfov: camera.vfov,
            aspect: camera.aspect,
        }
    }

    /// `a` for `at` frames, then `b` until `frames` (a camera jump).
    pub fn jump(a: FlyCamera, b: FlyCamera, at: u32, frames: u32) -> Self {
        let ka = Key {
            frame: 0.0,
            position: a.position,
            yaw: a.yaw,
            pitch: a.pitch,
        };
        let kb = Key {
            frame: at as f32,
            position: b.position,
            yaw: b.yaw,
            pitch: b.pitch,
        };
        Self {
            segments: vec![vec![ka], vec![kb]],
            cuts: vec![at],
            frames,
            vfov: a.vfov,
            aspect: a.aspect,
        }
    }

    /// The paper's fly-through (9 s at 30 fps = 270 frames): high above the
    /// city looking down, down to the busy street, along it at street level,
    /// then a tilt up to the horizon.
    pub fn flythrough(scene: &Scene, aspect: f32) -> Self {
        let ext = scene.config().extent;
        let (axis, line) = scene.busy_street();
        // Work in (along, across) street coordinates, then map to x/z.
        let at = |along: f32, across_off: f32, height: f32| {
            let (x, z) = if axis == 0 {
                (along, line + across_off)
            } else {
                (line + across_off, along)
            };
            Vec3::new(x, scene.height(x, z) + height, z)
        };
        let heading = if axis == 0 {
            std::f32::consts::FRAC_PI_2
        } else {
            0.0
        };
        let mid = 0.5 * ext;
        let s = (ext / 2048.0).clamp(0.1, 1.0);
        let f = |sec: f32| sec * FPS;
        let keys = vec![
            Key {
                frame: f(0.0),
                position: at(mid - 700.0 * s, -400.0 * s, 650.0 * s),
                yaw: heading + 0.5,
                pitch: -0.75,
            },
            Key {
                frame: f(3.0),
                position: at(mid - 160.0 * s, 0.0, 40.0 * s.max(0.5)),
                yaw: heading,
                pitch: -0.3,
            },
            Key {
                frame: f(4.0),
                position: at(mid - 100.0 * s, 0.0, 6.0),
                yaw: heading,
                pitch: -0.15,
            },
            Key {
                frame: f(7.0),
                position: at(mid + 40.0 * s, 0.0, 6.0),
                yaw: heading,
                pitch: -0.15,
            },
            Key {
                frame: f(9.0),
                position: at(mid + 70.0 * s, 0.0, 6.0),
                yaw: heading,
                pitch: 0.02,
            },
        ];
        Self {
            segments: vec![keys],
            cuts: Vec::new(),
            frames: f(9.0) as u32,
            vfov: 60f32.to_radians(),
            aspect,
        }
    }

    /// A cold-start jump: 2 s over the busy street, then a jump to a street
    /// view on the far side of the city for another 2 s.
    pub fn city_jump(scene: &Scene, aspect: f32) -> Self {
        let ext = scene.config().extent;
        let (axis, line) = scene.busy_street();
        let p = |x: f32, z: f32, h: f32| Vec3::new(x, scene.height(x, z) + h, z);
        let vfov = 60f32.to_radians();
        let (a_pos, b_pos) = if axis == 0 {
            (p(0.45 * ext, line, 8.0), p(0.2 * ext, 0.8 * ext, 8.0))
        } else {
            (p(line, 0.45 * ext, 8.0), p(0.8 * ext, 0.2 * ext, 8.0))
        };
        let a = FlyCamera {
            position: a_pos,
            yaw: if axis == 0 { 1.57 } else { 0.0 },
            pitch: -0.1,
            vfov,
            aspect,
        };
        let b = FlyCamera {
            position: b_pos,
            yaw: 2.4,
            pitch: -0.05,
            vfov,
            aspect,
        };
        Self::jump(a, b, (2.0 * FPS) as u32, (4.0 * FPS) as u32)
    }
}

#[cfg(test)]
mod tests;
