//! The paper-scale city ([`SceneConfig::paper_city`]) through the
//! comparison, on its reduced variant (a sixteenth of the area) at a tiny
//! resolution: unique BLASes dominate the full scene's memory as in the
//! paper's Fig. 7, and the run is deterministic.

use lipac_sim::camera::CameraPath;
use lipac_sim::compare::{run, CompareConfig, SceneChoice};
use lipac_sim::scene::{flags, Scene, SceneConfig};
use lipac_sim::strategy::StrategyKind;

#[test]
fn unique_blases_dominate_the_full_paper_city() {
    let lite = SceneConfig::paper_city_lite();
    let scene = Scene::generate(&lite).unwrap();
    let unique = scene.instances().iter().filter(|i| i.is_unique()).count();
    assert!(unique > 1500, "{unique}");
    assert_eq!(
        scene
            .instances()
            .iter()
            .filter(|i| i.flags & flags::ANIMATED != 0)
            .count(),
        500
    );
    let path = CameraPath::flythrough(&scene, 32.0 / 18.0);
    let config = CompareConfig {
        frames: Some(2),
        width: 32,
        height: 18,
        strategies: vec![StrategyKind::Full, StrategyKind::Oracle],
        threads: 2,
        ..CompareConfig::default()
    };
    let run = || {
        let mut s = Scene::generate(&lite).unwrap();
        run("paper-city-lite", &mut s, &path, &config, &mut |_, _| {}).unwrap()
    };
    let r = run();
    let full = r.strategy("full").unwrap();
    for m in &full.frames {
        let split = m.blas_split;
        let total = m.total_bytes() as f64;
        // Unique BLASes (units, buildings fitted to the terrain) are most
        // of the full scene's memory, about twice terrain, shared BLASes
        // and the TLAS together (71 % here, 72 % over the full-size city's
        // fly-through; with the city's box units it would be under 60 %).
        assert!(
            split.unique as f64 > 0.65 * total,
            "frame {}: unique {} of {}",
            m.frame,
            split.unique,
            total
        );
    }
    // The oracle keeps only what the ground truth's paths hit: far less.
    let oracle = r.strategy("oracle").unwrap();
    assert!(oracle.summary.mean_mib * 2.0 < full.summary.mean_mib);
    // Deterministic: the same figures again.
    let again = run();
    for (a, b) in r.strategies.iter().zip(&again.strategies) {
        for (m, n) in a.frames.iter().zip(&b.frames) {
            assert_eq!(m.without_timings(), n.without_timings());
        }
    }
    // The full-size scene is the paper-scale one behind `--scene paper-city`.
    assert_eq!(
        SceneChoice::PaperCity.config(None),
        SceneConfig::paper_city()
    );
    assert_eq!(
        SceneChoice::from_name("paper-city"),
        Some(SceneChoice::PaperCity)
    );
}
