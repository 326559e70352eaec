use super::*;
use crate::grid::{GridConfig, HitboxGrid};
use crate::instance::{InstanceDesc, MeshId};
use crate::registry::{InstanceHandle, RegistryConfig};
use glam::camera::rh::{proj, view};
use glam::Affine3A;
use proptest::prelude::*;

/// Camera at the origin looking down -Z with a 90° vertical field of view,
/// aspect 1, near 1, far 100: the frustum is |x| <= -z, |y| <= -z,
/// 1 <= -z <= 100.
fn forward_frustum() -> Frustum {
    let view = view::look_to_mat4(Vec3::ZERO, Vec3::NEG_Z, Vec3::Y);
    let proj = proj::vulkan::perspective(90f32.to_radians(), 1.0, 1.0, 100.0);
    Frustum::from_view_projection(proj * view).unwrap()
}

fn b(min: [f32; 3], max: [f32; 3]) -> (Vec3, Vec3) {
    (Vec3::from(min), Vec3::from(max))
}

#[test]
fn frustum_known_boxes() {
    let f = forward_frustum();
    let cases = [
        (b([-1.0, -1.0, -11.0], [1.0, 1.0, -9.0]), true, "ahead"),
        (b([-1.0, -1.0, 9.0], [1.0, 1.0, 11.0]), false, "behind"),
        (
            b([-1.0, -1.0, -150.0], [1.0, 1.0, -120.0]),
            false,
            "beyond far",
        ),
        (
            b([-1.0, -1.0, -101.0], [1.0, 1.0, -99.0]),
            true,
            "across far",
        ),
        (b([-100.0, -1.0, -11.0], [-90.0, 1.0, -9.0]), false, "left"),
        (b([-1.0, 30.0, -11.0], [1.0, 40.0, -9.0]), false, "above"),
        (b([-0.2, -0.2, -0.5], [0.2, 0.2, 2.0]), false, "before near"),
        (b([-0.2, -0.2, -1.5], [0.2, 0.2, 2.0]), true, "across near"),
        (b([-500.0; 3], [500.0; 3]), true, "encloses everything"),
        // Touching the right plane x = -z exactly at (10, 0, -10).
        (b([10.0, -1.0, -10.0], [12.0, 1.0, -10.0]), true, "touching"),
        (
            b([10.01, -1.0, -10.0], [12.0, 1.0, -10.0]),
            false,
            "just off",
        ),
    ];
    for ((min, max), want, what) in cases {
        assert_eq!(f.intersects(min, max), want, "{what}");
    }
    assert!(f.contains_point(Vec3::new(0.0, 0.0, -50.0)));
    assert!(!f.contains_point(Vec3::new(0.0, 0.0, -0.5)));
}

#[test]
fn frustum_rejects_non_finite_matrices() {
    let mut m = Mat4::IDENTITY;
    m.w_axis.x = f32::NAN;
    assert_eq!(
        Frustum::from_view_projection(m),
        Err(CoreError::NonFinite {
            what: "view-projection matrix"
        })
    );
}

#[test]
fn infinite_and_reversed_projections_keep_the_near_plane() {
    let view = view::look_to_mat4(Vec3::ZERO, Vec3::NEG_Z, Vec3::Y);
    for proj in [
        proj::directx::perspective_infinite(1.0, 1.0, 0.5),
        proj::directx::perspective_infinite_reverse(1.0, 1.0, 0.5),
    ] {
        let f = Frustum::from_view_projection(proj * view).unwrap();
        assert!(f.contains_point(Vec3::new(0.0, 0.0, -1e6)));
        assert!(f.contains_point(Vec3::new(0.0, 0.0, -0.6)));
        assert!(!f.contains_point(Vec3::new(0.0, 0.0, -0.4)));
        assert!(!f.contains_point(Vec3::new(0.0, 0.0, 10.0)));
    }
}

/// `clip = m * (p, 1)` in f64 of the f32 matrix: the exact frustum.
fn clip(m: &Mat4, p: [f64; 3]) -> [f64; 4] {
    let cols = m.to_cols_array_2d();
    let mut out = [0.0; 4];
    for (i, o) in out.iter_mut().enumerate() {
        *o = (0..3).map(|j| f64::from(cols[j][i]) * p[j]).sum::<f64>() + f64::from(cols[3][i]);
    }
    out
}

/// Signed "inside" distances of the six clip inequalities
/// (-w <= x <= w, -w <= y <= w, 0 <= z <= w).
fn clip_margins([x, y, z, w]: [f64; 4]) -> [f64; 6] {
    [w + x, w - x, w + y, w - y, z, w - z]
}

fn inside(c: [f64; 4]) -> bool {
    clip_margins(c).iter().all(|&m| m >= 0.0)
}

#[derive(Clone, Copy, Debug)]
enum Projection {
    Finite,
    Infinite,
    Reversed,
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(400))]
    #[test]
    fn frustum_never_rejects_a_box_with_a_point_inside(
        eye in prop::array::uniform3(-100.0f32..100.0),
        yaw in -3.2f32..3.2,
        pitch in -1.5f32..1.5,
        fov in 0.3f32..2.5,
        aspect in 0.5f32..3.0,
        near in 0.05f32..2.0,
        far_factor in 10.0f32..1000.0,
        kind in prop_oneof![Just(Projection::Finite), Just(Projection::Infinite), Just(Projection::Reversed)],
        offset in prop::array::uniform3(-150.0f32..150.0),
        half in prop::array::uniform3(0.0f32..30.0),
    ) {
        let eye = Vec3::from(eye);
        let dir = Vec3::new(yaw.sin() * pitch.cos(), pitch.sin(), -yaw.cos() * pitch.cos());
        let view = view::look_to_mat4(eye, dir, Vec3::Y);
        let projection = match kind {
            Projection::Finite => proj::vulkan::perspective(fov, aspect, near, near * far_factor),
            Projection::Infinite => proj::directx::perspective_infinite(fov, aspect, near),
            Projection::Reversed => proj::directx::perspective_infinite_reverse(fov, aspect, near),
        };
        let vp = projection * view;
        let f = Frustum::from_view_projection(vp).unwrap();
        let center = eye + Vec3::from(offset);
        let (min, max) = (center - Vec3::from(half), center + Vec3::from(half));

        // Brute force: sample the box on a 6x6x6 lattice (corners included).
        let n = 5;
        let mut any_inside = false;
        for i in 0..=n {
            for j in 0..=n {
                for k in 0..=n {
                    let t = [i, j, k].map(|v| f64::from(v) / f64::from(n));
                    let p = [0, 1, 2].map(|a| {
                        f64::from(min[a]) + (f64::from(max[a]) - f64::from(min[a])) * t[a]
                    });
                    any_inside |= inside(clip(&vp, p));
                }
            }
        }
        if any_inside {
            prop_assert!(f.intersects(min, max), "visible box rejected");
        }

        // Exact where one plane separates: all corners clearly outside the
        // same clip inequality => rejected.
        let corners: Vec<[f64; 6]> = (0..8)
            .map(|c| {
                let p = Vec3::select(glam::BVec3::new(c & 1 != 0, c & 2 != 0, c & 4 != 0), max, min);
                clip_margins(clip(&vp, p.to_array().map(f64::from)))
            })
            .collect();
        let separated = (0..6).any(|plane| {
            corners.iter().all(|c| c[plane] < -1e-3 * (1.0 + c[plane].abs()))
        });
        if separated {
            prop_assert!(!f.intersects(min, max), "separated box accepted");
        }
    }
}

// ---------------------------------------------------------------------------
// LatencyMitigation.

fn registry(quarantine_frames: u32) -> InstanceRegistry {
    InstanceRegistry::new(
        HitboxGrid::new(GridConfig::default()).unwrap(),
        RegistryConfig {
            quarantine_frames,
            ..RegistryConfig::default()
        },
    )
    .unwrap()
}

fn cube(r: &mut InstanceRegistry, center: Vec3, half: f32) -> InstanceHandle {
    let aabb = Aabb::new(center - Vec3::splat(half), center + Vec3::splat(half));
    r.register(InstanceDesc::new(
        MeshId(0),
        Affine3A::from_translation(center),
        aabb,
    ))
    .unwrap()
}

fn looking(dir: Vec3) -> Frustum {
    let view = view::look_to_mat4(Vec3::ZERO, dir, Vec3::Y);
    let proj = proj::vulkan::perspective(90f32.to_radians(), 1.0, 0.1, 1000.0);
    Frustum::from_view_projection(proj * view).unwrap()
}

#[test]
fn heuristic_accepts_near_or_large() {
    let h = ActivationHeuristic::default(); // 50 m, 0.1
    let cam = Vec3::ZERO;
    let cube = |c: Vec3, half: f32| Aabb::new(c - Vec3::splat(half), c + Vec3::splat(half));
    // Near: box face at 39 m.
    assert!(h.accepts(cam, &cube(Vec3::new(0.0, 0.0, -40.0), 1.0)));
    // Far and small: radius √3 ≈ 1.73 at 100 m → 0.017 < 0.1.
    assert!(!h.accepts(cam, &cube(Vec3::new(0.0, 0.0, -100.0), 1.0)));
    let lenient = ActivationHeuristic {
        min_projected_size: 0.01,
        ..h
    };
    assert!(lenient.accepts(cam, &cube(Vec3::new(0.0, 0.0, -100.0), 1.0)));
    // Far and large: radius 8√3 ≈ 13.9 at 120 m → 0.115 >= 0.1 (face at 112 m).
    assert!(h.accepts(cam, &cube(Vec3::new(0.0, 0.0, -120.0), 8.0)));
    // Same box at 150 m: 0.092 < 0.1.
    assert!(!h.accepts(cam, &cube(Vec3::new(0.0, 0.0, -150.0), 8.0)));
    // Camera inside the box: always.
    let strict = ActivationHeuristic {
        max_distance: 0.0,
        min_projected_size: f32::INFINITY,
        surround_radius: 0.0,
    };
    assert!(strict.accepts(cam, &cube(Vec3::new(0.5, 0.0, 0.0), 1.0)));
    assert!(!strict.accepts(cam, &cube(Vec3::new(5.0, 0.0, 0.0), 1.0)));
}

#[test]
fn invalid_heuristics_are_rejected() {
    for h in [
        ActivationHeuristic {
            max_distance: f32::NAN,
            ..Default::default()
        },
        ActivationHeuristic {
            min_projected_size: -0.1,
            ..Default::default()
        },
        ActivationHeuristic {
            surround_radius: f32::NAN,
            ..Default::default()
        },
        ActivationHeuristic {
            surround_radius: -1.0,
            ..Default::default()
        },
    ] {
        assert!(matches!(
            LatencyMitigation::new(h),
            Err(CoreError::InvalidConfig { .. })
        ));
        let mut lm = LatencyMitigation::default();
        assert!(lm.set_heuristic(h).is_err());
        assert_eq!(lm.heuristic(), ActivationHeuristic::default());
    }
}

#[test]
fn newly_visible_across_frames() {
    let mut r = registry(4);
    let near = cube(&mut r, Vec3::new(0.0, 0.0, -20.0), 1.0); // slot 0
    let small_far = cube(&mut r, Vec3::new(0.0, 0.0, -300.0), 1.0); // slot 1
    let big_far = cube(&mut r, Vec3::new(0.0, 0.0, -200.0), 30.0); // slot 2
    let behind = cube(&mut r, Vec3::new(0.0, 0.0, 20.0), 1.0); // slot 3
    assert_eq!(
        [near, small_far, big_far, behind].map(|h| r.slot(h).unwrap()),
        [0, 1, 2, 3]
    );
    let mut lm = LatencyMitigation::new(ActivationHeuristic::default()).unwrap();
    let mut out = vec![99];
    let cam = Vec3::ZERO;

    let s = lm.update(&r, cam, &looking(Vec3::NEG_Z), &mut out).unwrap();
    assert_eq!(out, vec![0, 2]);
    assert_eq!(
        s,
        LatencySummary {
            tested: 4,
            in_frustum: 3,
            newly_visible: 3,
            already_active: 0,
            accepted: 2
        }
    );
    assert!(lm.was_visible(1) && !lm.was_visible(3));

    // Same view: nothing is new.
    let s = lm.update(&r, cam, &looking(Vec3::NEG_Z), &mut out).unwrap();
    assert!(out.is_empty());
    assert_eq!((s.in_frustum, s.newly_visible), (3, 0));

    // Turn around: only the one behind is new.
    let s = lm.update(&r, cam, &looking(Vec3::Z), &mut out).unwrap();
    assert_eq!(out, vec![3]);
    assert_eq!((s.in_frustum, s.newly_visible), (1, 1));

    // Activate slot 0 meanwhile; turning back reports it as already active.
    r.set_state(0, InstanceState::Active).unwrap();
    let s = lm.update(&r, cam, &looking(Vec3::NEG_Z), &mut out).unwrap();
    assert_eq!(out, vec![2]);
    assert_eq!((s.newly_visible, s.already_active, s.accepted), (3, 1, 1));

    // A new instance in view is newly visible without any camera change.
    let fresh = cube(&mut r, Vec3::new(5.0, 0.0, -30.0), 1.0);
    lm.update(&r, cam, &looking(Vec3::NEG_Z), &mut out).unwrap();
    assert_eq!(out, vec![r.slot(fresh).unwrap()]);

    // Non-finite camera: error, nothing changes.
    out.push(42);
    assert!(lm
        .update(&r, Vec3::splat(f32::NAN), &looking(Vec3::NEG_Z), &mut out)
        .is_err());
    assert_eq!(out, vec![4, 42]);
}

#[test]
fn a_surround_radius_makes_instances_near_the_camera_visible_in_any_direction() {
    let mut r = registry(4);
    cube(&mut r, Vec3::new(0.0, 0.0, 20.0), 1.0); // slot 0: behind, face at 19 m
    cube(&mut r, Vec3::new(0.0, 0.0, 60.0), 1.0); // slot 1: behind, face at 59 m
    cube(&mut r, Vec3::new(0.0, 0.0, -60.0), 1.0); // slot 2: ahead, face at 59 m
    let all = ActivationHeuristic {
        max_distance: f32::INFINITY,
        min_projected_size: 0.0,
        surround_radius: 0.0,
    };
    let cam = Vec3::ZERO;
    let ahead = looking(Vec3::NEG_Z);
    let mut out = Vec::new();

    // The frustum alone: only the one ahead.
    let mut lm = LatencyMitigation::new(all).unwrap();
    lm.update(&r, cam, &ahead, &mut out).unwrap();
    assert_eq!(out, vec![2]);

    // Within 20 m in any direction: the near one behind too, not the far one;
    // the radius is to the box, not to its centre (the face is at 19 m).
    let mut lm = LatencyMitigation::new(ActivationHeuristic {
        surround_radius: 19.5,
        ..all
    })
    .unwrap();
    let s = lm.update(&r, cam, &ahead, &mut out).unwrap();
    assert_eq!(out, vec![0, 2]);
    assert_eq!((s.in_frustum, s.newly_visible), (2, 2));
    assert!(lm.was_visible(0) && !lm.was_visible(1));
    // Still within the radius next frame: not new.
    lm.update(&r, cam, &ahead, &mut out).unwrap();
    assert!(out.is_empty());
    // Moving towards slot 1 brings it within the radius: new.
    let s = lm
        .update(&r, Vec3::new(0.0, 0.0, 40.0), &ahead, &mut out)
        .unwrap();
    assert_eq!(out, vec![1]);
    assert_eq!(s.newly_visible, 1);

    // The heuristic still decides: surrounding but far and small is refused.
    let strict = ActivationHeuristic {
        max_distance: 10.0,
        min_projected_size: 1.0,
        surround_radius: 100.0,
    };
    assert!(strict.surrounds(cam, &Aabb::new(Vec3::splat(49.0), Vec3::splat(50.0))));
    let mut lm = LatencyMitigation::new(strict).unwrap();
    let s = lm.update(&r, cam, &ahead, &mut out).unwrap();
    assert!(out.is_empty());
    assert_eq!((s.in_frustum, s.accepted), (3, 0));
}

#[test]
fn removed_and_reused_slots_are_new_instances() {
    let mut r = registry(0); // immediate reuse: the hardest case
    let a = cube(&mut r, Vec3::new(0.0, 0.0, -20.0), 1.0);
    let mut lm = LatencyMitigation::default();
    let mut out = Vec::new();
    let f = looking(Vec3::NEG_Z);
    lm.update(&r, Vec3::ZERO, &f, &mut out).unwrap();
    assert_eq!(out, vec![0]);

    // Removed and replaced in the same slot between two updates.
    r.remove(a).unwrap();
    let b = cube(&mut r, Vec3::new(1.0, 0.0, -20.0), 1.0);
    assert_eq!(r.slot(b).unwrap(), 0);
    lm.update(&r, Vec3::ZERO, &f, &mut out).unwrap();
    assert_eq!(out, vec![0], "the replacement was not seen as new");

    // Removed and left dead: forgotten.
    r.remove(b).unwrap();
    let s = lm.update(&r, Vec3::ZERO, &f, &mut out).unwrap();
    assert!(out.is_empty());
    assert_eq!(s.tested, 0);
    assert!(!lm.was_visible(0));

    // Replaced twice while updates were skipped.
    let c = cube(&mut r, Vec3::new(0.0, 0.0, -20.0), 1.0);
    lm.update(&r, Vec3::ZERO, &f, &mut out).unwrap();
    assert_eq!(out, vec![0]);
    r.remove(c).unwrap();
    let d = cube(&mut r, Vec3::new(0.0, 0.0, -20.0), 1.0);
    r.remove(d).unwrap();
    cube(&mut r, Vec3::new(0.0, 0.0, -20.0), 1.0);
    lm.update(&r, Vec3::ZERO, &f, &mut out).unwrap();
    assert_eq!(out, vec![0]);

    // reset() forgets everything.
    lm.reset();
    lm.update(&r, Vec3::ZERO, &f, &mut out).unwrap();
    assert_eq!(out, vec![0]);
}
