//! Snapshots of chosen frames: the full strategy's picture is the ground
//! truth's pixel for pixel, heat maps are black exactly where the error is
//! zero, TLAS maps agree with the TLAS, and the files come out as PNGs.

use lipac_sim::compare::{run_choice_with_snapshots, CompareConfig, SceneChoice};
use lipac_sim::report::write_report_with_snapshots;
use lipac_sim::snapshot::{Snapshot, MAP_SIZE};
use lipac_sim::strategy::StrategyKind;
use lipac_sim::tlas_map::MapState;

/// (width, height, RGB pixels) of a PNG.
fn decode(bytes: &[u8]) -> (u32, u32, Vec<u8>) {
    let mut r = png::Decoder::new(std::io::Cursor::new(bytes))
        .read_info()
        .unwrap();
    let mut buf = vec![0; r.output_buffer_size().unwrap()];
    let info = r.next_frame(&mut buf).unwrap();
    assert_eq!(info.color_type, png::ColorType::Rgb);
    buf.truncate(info.buffer_size());
    (info.width, info.height, buf)
}

fn run(frames: u32, snapshots: &[u32]) -> (lipac_sim::compare::CompareReport, Vec<Snapshot>) {
    let config = CompareConfig {
        frames: Some(frames),
        width: 40,
        height: 24,
        strategies: vec![StrategyKind::Full, StrategyKind::Lipac],
        // The full strategy renders on its own: its picture equal to the
        // ground truth's is then a property of the renderer.
        share_ground_truth: false,
        threads: 2,
        adaptive_levels: None,
        lipac_cell_size: None,
        lipac_rise_shift: None,
        // The paper's cold start: every hitbox inactive at frame 0.
        lipac_start: lipac_sim::compare::LipacStart::Cold,
        lipac_warm_start_at_cuts: false,
        lipac_warm_start_hold: None,
        device: Default::default(),
    };
    run_choice_with_snapshots(SceneChoice::Small, None, &config, snapshots, &mut |_, _| {}).unwrap()
}

#[test]
fn snapshots_show_the_ground_truth_the_error_and_the_tlas() {
    let (r, snaps) = run(6, &[0, 5, 99]);
    // Frame 99 is past the end: ignored.
    assert_eq!(snaps.iter().map(|s| s.frame).collect::<Vec<_>>(), [0, 5]);
    for s in &snaps {
        assert_eq!(s.ground_truth.len(), 40 * 24);
        assert_eq!(s.strategies.len(), 2);
        let (gw, gh, gt) = decode(&s.ground_truth_png().unwrap());
        assert_eq!((gw, gh), (40, 24));
        assert!(gt.iter().any(|&c| c > 0), "ground truth is black");

        // The full strategy: the ground truth pixel for pixel, no error.
        let full = &s.strategies[0];
        assert_eq!(full.name, "full");
        assert_eq!(full.indirect, s.ground_truth);
        assert_eq!(decode(&s.strategy_png(0).unwrap()).2, gt);
        assert!(decode(&s.heat_png(0).unwrap()).2.iter().all(|&c| c == 0));
        assert_eq!(full.map.count(MapState::Omitted), 0);
        assert_eq!(full.map.count(MapState::Inactive), 0);
        assert!(full.map.hitboxes.is_empty());
        assert!(full.map.active_hitboxes.is_empty(), "no hitboxes");

        // LiPaC: the heat map is black exactly where its light equals the
        // ground truth's.
        let lipac = &s.strategies[1];
        let m = &r.strategy("lipac").unwrap().frames[s.frame as usize];
        assert_eq!(lipac.error, m.error);
        let (_, _, heat) = decode(&s.heat_png(1).unwrap());
        let mut differing = 0;
        for (p, (a, b)) in lipac.indirect.iter().zip(&s.ground_truth).enumerate() {
            let black = heat[3 * p..3 * p + 3] == [0, 0, 0];
            assert_eq!(black, a == b, "pixel {p}: {a} vs {b}");
            differing += usize::from(a != b);
        }
        // LiPaC starts cold: some pixels differ, and its error says so.
        assert_eq!(differing > 0, lipac.error > 0.0);
        // Its map holds what its TLAS held: the counting boxes are the
        // omitted instances' and the inactive hitboxes'.
        let omitted = lipac
            .map
            .instances
            .iter()
            .filter(|i| i.state == MapState::Omitted)
            .count();
        assert_eq!(
            (omitted + lipac.map.hitboxes.len()) as u64,
            m.counting_boxes,
            "frame {}",
            s.frame
        );
        assert!(lipac.map.count(MapState::Active) < full.map.count(MapState::Active));
        // It starts with every hitbox inactive and has activated some
        // by frame 5.
        assert_eq!(lipac.map.active_hitboxes.is_empty(), s.frame == 0);
        // Its active hitboxes (from its Manager) are none of the inactive
        // ones (from its counting records; a merged box's index is its
        // tree node's).
        for a in &lipac.map.active_hitboxes {
            assert!(
                lipac
                    .map
                    .hitboxes
                    .iter()
                    .all(|h| h.merged || h.index != a.index),
                "hitbox {} both active and inactive",
                a.index
            );
        }
    }
    // LiPaC starts with everything culled.
    assert!(snaps[0].strategies[1].error > 0.0);
}

#[test]
fn report_folder_holds_the_pictures() {
    let (r, snaps) = run(3, &[2]);
    let dir = std::env::temp_dir().join(format!("lipac-snapshots-test-{}", std::process::id()));
    let written = write_report_with_snapshots(&r, &snaps, &dir).unwrap();
    let frame = dir.join("snapshots").join("frame-0002");
    for name in [
        "ground-truth.png",
        "full.png",
        "full-error.png",
        "full-map.png",
        "lipac.png",
        "lipac-error.png",
        "lipac-map.png",
    ] {
        let p = frame.join(name);
        assert!(written.contains(&p), "{name}");
        let (w, h, px) = decode(&std::fs::read(&p).unwrap());
        if name.ends_with("-map.png") {
            assert_eq!((w, h), (MAP_SIZE, MAP_SIZE));
            // Active instances are drawn in the active colour.
            assert!(px.chunks(3).any(|c| c == [0x1f, 0x4e, 0xb4]), "{name}");
        } else {
            assert_eq!((w, h), (40, 24));
        }
    }
    let html = std::fs::read_to_string(dir.join("report.html")).unwrap();
    // Every picture embedded: per strategy image, heat map and map, the
    // ground truth and the colour scale.
    assert_eq!(
        html.matches("src=\"data:image/png;base64,").count(),
        2 * 3 + 2
    );
    assert!(html.contains("<h3>Frame 2</h3>"));
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn a_geometry_replay_takes_the_same_snapshots_as_compare() {
    use lipac_core::trace::TraceFormat;
    use lipac_sim::record::{record, CameraChoice, RecordConfig};
    use lipac_sim::replay::{replay_with_snapshots, ReplayConfig, ReplayMode, TraceInput};
    let rec = RecordConfig {
        scene: SceneChoice::Small,
        seed: None,
        camera: CameraChoice::Flythrough,
        frames: Some(3),
        aspect: 40.0 / 24.0,
        geometry: false,
    };
    let bytes = record(&rec, TraceFormat::Binary, Vec::new()).unwrap().0;
    let config = ReplayConfig {
        strategies: vec![StrategyKind::Full, StrategyKind::Lipac],
        width: 40,
        height: 24,
        threads: 2,
        snapshots: vec![2],
        lipac_start: lipac_sim::compare::LipacStart::Cold, // as run()
        ..ReplayConfig::default()
    };
    let input = TraceInput::new(TraceFormat::Binary, bytes.as_slice()).unwrap();
    let (_, replayed) = replay_with_snapshots(input, &config, &mut |_| {}).unwrap();
    let (_, compared) = run(3, &[2]);
    assert_eq!(replayed.len(), 1);
    assert_eq!(replayed[0].ground_truth, compared[0].ground_truth);
    assert_eq!(
        replayed[0].strategies[1].indirect,
        compared[0].strategies[1].indirect
    );
    // Hits-only replays render nothing: asking for pictures is an error.
    let input = TraceInput::new(TraceFormat::Binary, bytes.as_slice()).unwrap();
    let hits_only = ReplayConfig {
        mode: Some(ReplayMode::HitsOnly),
        ..config
    };
    let err = replay_with_snapshots(input, &hits_only, &mut |_| {}).unwrap_err();
    assert!(err.to_string().contains("geometry mode"), "{err}");
}
