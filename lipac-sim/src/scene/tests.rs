use super::*;

#[test]
fn city_has_the_advertised_population() {
    let s = Scene::generate(&SceneConfig::city()).unwrap();
    let count = |f: u8| s.instances().iter().filter(|i| i.flags & f != 0).count();
    let buildings = s
        .instances()
        .iter()
        .filter(|i| i.flags & (flags::TERRAIN | flags::VEGETATION | flags::ANIMATED) == 0)
        .count();
    assert!(buildings > 3000, "{buildings}");
    assert_eq!(count(flags::ANIMATED), 5000);
    assert!(count(flags::VEGETATION) > 5000);
    assert!(count(flags::TERRAIN_ADAPTED) > 200);
    assert!(s.library().len() >= 30);
    let est = SceneConfig::city().estimated_instances() as f64;
    let n = s.instances().len() as f64;
    assert!((n / est - 1.0).abs() < 0.1, "estimate {est} vs {n}");
}

#[test]
fn units_move_along_streets_deterministically() {
    let mut s = Scene::generate(&SceneConfig::small()).unwrap();
    let u = s.units()[0];
    let p0 = s.instances()[u.slot as usize].transform.translation;
    s.set_frame(30);
    let p1 = s.instances()[u.slot as usize].transform.translation;
    let moved = (Vec3::from(p1) - Vec3::from(p0)).length();
    assert!((1.0..=1.81).contains(&moved), "moved {moved}");
    // Lane coordinate fixed.
    let lane = if u.axis == 0 { p1.z } else { p1.x };
    assert_eq!(lane, u.lane);
    s.set_frame(0);
    assert_eq!(s.instances()[u.slot as usize].transform.translation, p0);
}

#[test]
fn unique_geometry_is_refused_for_shared_instances() {
    let s = Scene::generate(&SceneConfig::small()).unwrap();
    let shared = s.instances().iter().position(|i| !i.is_unique()).unwrap() as u32;
    let mut out = LodTriangles::default();
    assert_eq!(
        s.unique_geometry(shared, 0, 0, &mut out),
        Err(SimError::NotUnique(shared))
    );
    let adapted = s
        .instances()
        .iter()
        .position(|i| i.flags & flags::TERRAIN_ADAPTED != 0)
        .unwrap() as u32;
    s.unique_geometry(adapted, 1, 0, &mut out).unwrap();
    let inst = s.instances()[adapted as usize];
    // The world-space bottom follows the terrain and stays inside the instance AABB.
    let b = out.bounds();
    assert!(b.min.y + inst.transform.translation.y >= inst.aabb.min.y - 1e-3);
    assert!(s.unique_geometry(u32::MAX - 1, 0, 0, &mut out).is_err());
}

#[test]
fn bad_configs_are_rejected() {
    let mut c = SceneConfig::small();
    c.extent = f32::NAN;
    assert!(Scene::generate(&c).is_err());
    let mut c = SceneConfig::small();
    c.block = 0.0;
    assert!(Scene::generate(&c).is_err());
}

#[test]
fn the_paper_city_has_the_papers_population_and_is_deterministic() {
    let c = SceneConfig::paper_city();
    let s = Scene::generate(&c).unwrap();
    let n = s.instances().len();
    let count = |f: u8| s.instances().iter().filter(|i| i.flags & f != 0).count();
    // The paper: more than a hundred thousand instances, more than six
    // thousand animated units, buildings fitted to the terrain.
    assert!(n >= 100_000, "{n}");
    assert!(count(flags::ANIMATED) >= 6000);
    let buildings = s
        .instances()
        .iter()
        .filter(|i| i.flags & (flags::TERRAIN | flags::VEGETATION | flags::ANIMATED) == 0)
        .count();
    let adapted = count(flags::TERRAIN_ADAPTED);
    assert!(buildings > 30_000, "{buildings}");
    assert!(
        (0.45..0.55).contains(&(adapted as f64 / buildings as f64)),
        "{adapted} of {buildings}"
    );
    let est = c.estimated_instances() as f64;
    assert!((n as f64 / est - 1.0).abs() < 0.1, "estimate {est} vs {n}");
    // Deterministic from the seed, and the seed matters.
    let again = Scene::generate(&c).unwrap();
    assert_eq!(s.instances(), again.instances());
    let other = Scene::generate(&SceneConfig { seed: 2, ..c }).unwrap();
    assert_ne!(s.instances(), other.instances());
}
