use super::*;
use glam::Quat;

#[test]
fn file_cameras_are_interpolated_in_order() {
    let cam = |x: f32| ImportedCamera {
        position: Vec3::new(x, 0.0, 0.0),
        orientation: Quat::IDENTITY,
        vertical_fov: 1.0,
        aspect: None,
    };
    let cams = [cam(0.0), cam(10.0), cam(20.0)];
    assert_eq!(file_camera(&cams, 0, 5, 2.0).position.x, 0.0);
    assert_eq!(file_camera(&cams, 4, 5, 2.0).position.x, 20.0);
    assert!((file_camera(&cams, 1, 5, 2.0).position.x - 5.0).abs() < 1e-5);
    assert_eq!(file_camera(&cams, 2, 5, 2.0).aspect, 2.0);
}

#[test]
fn the_orbit_looks_at_the_centre() {
    let b = Aabb::new(Vec3::new(-10.0, 0.0, -10.0), Vec3::new(10.0, 5.0, 10.0));
    for f in 0..8 {
        let c = orbit(&b, f, 8, 1.5);
        let to_centre = (b.center() - c.position).normalize();
        assert!(c.forward().dot(to_centre) > 0.999);
    }
}
