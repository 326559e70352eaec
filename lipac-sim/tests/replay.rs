//! Recorded traces replayed: `record` → `replay` reproduces `compare`
//! exactly; hits-only replay of long traces stays bounded; the golden trace
//! replays; the CLI reports corrupt traces with frame and byte offset.

use std::process::Command;

use glam::Vec3;
use lipac_core::instance::{InstanceFlags, MeshId};
use lipac_core::math::Aabb;
use lipac_core::trace::{
    AddInstance, Camera, Frame, InstanceEvent, InstanceHits, LodInfo, MeshInfo, Pose, TraceFormat,
    TraceHeader, TraceWriter, UpdateInstance, WorldInfo,
};
use lipac_sim::compare::{run_choice, CompareConfig, CompareReport, SceneChoice};
use lipac_sim::record::{record, CameraChoice, RecordConfig};
use lipac_sim::replay::hits::{replay_hits_with, MAX_SERIES_FRAMES};
use lipac_sim::replay::{replay, ReplayConfig, ReplayMode, TraceInput};
use lipac_sim::strategy::StrategyKind;

const FRAMES: u32 = 12;
const W: u32 = 32;
const H: u32 = 18;

fn recorded(format: TraceFormat) -> Vec<u8> {
    let config = RecordConfig {
        scene: SceneChoice::Small,
        seed: None,
        camera: CameraChoice::Flythrough,
        frames: Some(FRAMES),
        aspect: W as f32 / H as f32,
        geometry: false,
    };
    record(&config, format, Vec::new()).expect("record").0
}

fn assert_same(a: &CompareReport, b: &CompareReport) {
    assert_eq!(
        (
            &a.scene,
            a.instances,
            a.frames,
            a.rays_per_frame,
            a.thresholds
        ),
        (
            &b.scene,
            b.instances,
            b.frames,
            b.rays_per_frame,
            b.thresholds
        )
    );
    assert_eq!(a.strategies.len(), b.strategies.len());
    for (x, y) in a.strategies.iter().zip(&b.strategies) {
        assert_eq!(x.name, y.name);
        assert_eq!(x.last_geometry, y.last_geometry, "{}", x.name);
        assert_eq!(x.frames.len(), y.frames.len());
        for (m, n) in x.frames.iter().zip(&y.frames) {
            assert_eq!(
                m.error.to_bits(),
                n.error.to_bits(),
                "{} frame {}",
                x.name,
                m.frame
            );
            assert_eq!(m.without_timings(), n.without_timings(), "{}", x.name);
        }
        let (s, t) = (&x.summary, &y.summary);
        assert_eq!(s.mean_error.to_bits(), t.mean_error.to_bits());
        assert_eq!(s.mean_mib.to_bits(), t.mean_mib.to_bits());
        assert_eq!(s.mean_latency.to_bits(), t.mean_latency.to_bits());
        assert_eq!(
            (
                s.builds,
                s.state_changes,
                s.cycles,
                s.p95_latency,
                s.never_active
            ),
            (
                t.builds,
                t.state_changes,
                t.cycles,
                t.p95_latency,
                t.never_active
            )
        );
    }
}

#[test]
fn record_then_replay_reproduces_compare_exactly() {
    let strategies = vec![
        StrategyKind::Full,
        StrategyKind::Lipac,
        StrategyKind::Oracle,
    ];
    let compared = run_choice(
        SceneChoice::Small,
        None,
        &CompareConfig {
            frames: Some(FRAMES),
            width: W,
            height: H,
            strategies: strategies.clone(),
            share_ground_truth: true,
            threads: 2,
            adaptive_levels: None,
            lipac_cell_size: None,
            lipac_rise_shift: None,
            lipac_start: lipac_sim::compare::LipacStart::Default,
            lipac_warm_start_at_cuts: false,
            lipac_warm_start_hold: None,
            device: Default::default(),
        },
        &mut |_, _| {},
    )
    .expect("compare");
    let config = ReplayConfig {
        strategies,
        width: W,
        height: H,
        threads: 2,
        ..ReplayConfig::default()
    };
    for format in [TraceFormat::Binary, TraceFormat::Jsonl] {
        let bytes = recorded(format);
        let input = TraceInput::new(format, bytes.as_slice()).unwrap();
        let replayed = replay(input, &config, &mut |_| {}).expect("replay");
        assert_same(&compared, &replayed);
        // The check can fail: LiPaC's numbers differ from the full scene's.
        assert_ne!(
            compared.strategy("lipac").unwrap().summary.mean_mib,
            compared.strategy("full").unwrap().summary.mean_mib
        );
    }
}

#[test]
fn a_moved_camera_changes_the_replay() {
    // The replay really uses the recorded camera: shifting it changes the
    // error of LiPaC, and a pose that disagrees with the scene is refused.
    let bytes = recorded(TraceFormat::Binary);
    let mut r = TraceInput::new(TraceFormat::Binary, bytes.as_slice()).unwrap();
    let header = r.header().clone();
    let mut frames = Vec::new();
    let mut f = lipac_sim::replay::empty_frame();
    while r.next_frame_into(&mut f).unwrap() {
        frames.push(f.clone());
    }
    let write = |frames: &[Frame]| {
        let mut w = TraceWriter::new(Vec::new(), &header).unwrap();
        for f in frames {
            w.write_frame(f).unwrap();
        }
        w.finish().unwrap()
    };
    let config = ReplayConfig {
        strategies: vec![StrategyKind::Full, StrategyKind::Lipac],
        width: W,
        height: H,
        threads: 2,
        ..ReplayConfig::default()
    };
    let run = |b: &[u8]| {
        replay(
            TraceInput::new(TraceFormat::Binary, b).unwrap(),
            &config,
            &mut |_| {},
        )
    };
    let base = run(&write(&frames)).unwrap();
    let mut moved = frames.clone();
    for f in &mut moved {
        f.camera.position.y += 30.0;
    }
    let other = run(&write(&moved)).unwrap();
    let errors = |r: &CompareReport| {
        r.strategy("lipac")
            .unwrap()
            .frames
            .iter()
            .map(|m| m.error.to_bits())
            .collect::<Vec<_>>()
    };
    assert_ne!(errors(&base), errors(&other));
    let mut edited = frames.clone();
    let update = edited[3]
        .events
        .iter_mut()
        .find_map(|e| match e {
            InstanceEvent::Update(u) if u.pose.is_some() => Some(u),
            _ => None,
        })
        .expect("a unit moves in frame 3");
    update.pose.as_mut().unwrap().transform[3] += 1.0;
    let update_aabb = &mut update.pose.as_mut().unwrap().aabb;
    update_aabb.min.x += 1.0;
    update_aabb.max.x += 1.0;
    let err = run(&write(&edited)).unwrap_err().to_string();
    assert!(
        err.contains("frame number 3") && err.contains("differs"),
        "{err}"
    );
}

fn camera() -> Camera {
    Camera::look_to(
        Vec3::new(0.0, 10.0, 0.0),
        Vec3::new(1.0, -0.2, 0.3),
        Vec3::Y,
        1.0,
        16.0 / 9.0,
    )
}

fn pose_at(x: f32, z: f32) -> Pose {
    Pose {
        transform: [1.0, 0.0, 0.0, x, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0, z],
        aabb: Aabb::new(
            Vec3::new(x - 1.0, 0.0, z - 1.0),
            Vec3::new(x + 1.0, 2.0, z + 1.0),
        ),
    }
}

fn synthetic_header() -> TraceHeader {
    TraceHeader {
        scene_name: "synthetic churn".into(),
        world: WorldInfo {
            min: [0.0, 0.0],
            max: [256.0, 256.0],
            cell_size: 16.0,
        },
        meshes: vec![MeshInfo {
            id: MeshId(3),
            bounds: Aabb::new(Vec3::new(-1.0, 0.0, -1.0), Vec3::new(1.0, 2.0, 1.0)),
            lods: vec![
                LodInfo {
                    triangles: 1000,
                    geometry: None,
                },
                LodInfo {
                    triangles: 100,
                    geometry: None,
                },
            ],
        }],
    }
}

/// `frames` frames of churn: about `live` instances live, a few added and
/// removed every frame, some moving, hits on a rotating subset.
fn churn(frames: u64, live: u64) -> Vec<u8> {
    let mut w = TraceWriter::new(Vec::new(), &synthetic_header()).unwrap();
    let mut next_id = 0u64;
    let mut alive: std::collections::VecDeque<u64> = Default::default();
    let mut f = Frame {
        number: 0,
        camera: camera(),
        events: Vec::new(),
        hits: Some(Vec::new()),
        slot_hits: None,
    };
    let place = |id: u64| pose_at(8.0 + (id * 37 % 240) as f32, 8.0 + (id * 91 % 240) as f32);
    for n in 0..frames {
        f.number = n;
        f.events.clear();
        let adds = if n == 0 { live } else { 3 };
        if n > 0 {
            for _ in 0..3 {
                let id = alive.pop_front().unwrap();
                f.events.push(InstanceEvent::Remove { id });
            }
        }
        for _ in 0..adds {
            f.events.push(InstanceEvent::Add(AddInstance {
                id: next_id,
                mesh: MeshId(3),
                lod: (next_id % 2) as u32,
                flags: if next_id % 5 == 0 {
                    InstanceFlags::UNIQUE_BLAS
                } else {
                    InstanceFlags::STATIC
                },
                mask: None,
                pose: place(next_id),
                slot: None,
            }));
            alive.push_back(next_id);
            next_id += 1;
        }
        if let Some(&id) = alive.get((n % live) as usize) {
            f.events.push(InstanceEvent::Update(UpdateInstance {
                id,
                pose: Some(place(id + n)),
                lod: Some((n % 2) as u32),
                flags: None,
                mask: None,
            }));
        }
        let hits = f.hits.as_mut().unwrap();
        hits.clear();
        for (i, &id) in alive.iter().enumerate() {
            if (i as u64 + n) % 7 == 0 {
                hits.push(InstanceHits {
                    id,
                    hits: 400 + (id % 300) as u32,
                });
            }
        }
        w.write_frame(&f).unwrap();
    }
    w.finish().unwrap()
}

#[test]
fn hits_only_replay_of_a_long_trace_stays_bounded() {
    let config = ReplayConfig {
        keep_frames: false,
        ..ReplayConfig::default()
    };
    let run = |frames: u64| {
        let bytes = churn(frames, 200);
        let mut input = TraceInput::new(TraceFormat::Binary, bytes.as_slice()).unwrap();
        replay_hits_with(&mut input, &config, &mut |_| {}).expect("hits-only replay")
    };
    let (short, fp_short) = run(500);
    // Below the cap a streaming replay keeps every frame, equal to a replay
    // that keeps them by request (timings aside).
    let kept = {
        let bytes = churn(500, 200);
        let mut input = TraceInput::new(TraceFormat::Binary, bytes.as_slice()).unwrap();
        replay_hits_with(&mut input, &ReplayConfig::default(), &mut |_| {})
            .unwrap()
            .0
    };
    for (a, b) in short.strategies.iter().zip(&kept.strategies) {
        assert_eq!(a.frames.len(), 500);
        for (x, y) in a.frames.iter().zip(&b.frames) {
            let untimed = |m: &lipac_sim::metrics::FrameMetrics| {
                let mut m = m.clone();
                m.strategy_ms = 0.0;
                m.trace_ms = 0.0;
                m.tlas_build_ms = 0.0;
                format!("{m:?}")
            };
            assert_eq!(untimed(x), untimed(y));
        }
    }
    let (long, fp_long) = run(20_000);
    assert_eq!(long.frames, 20_000);
    assert_eq!(fp_long.peak_live, 200);
    // Per-instance tables follow the live set, not the trace: 40x the frames,
    // (almost) the same capacity.
    assert!(
        fp_long.peak_capacity <= fp_short.peak_capacity + fp_short.peak_capacity / 4,
        "{fp_short:?} vs {fp_long:?}"
    );
    assert!(fp_long.peak_frame_events <= 4 * 200, "{fp_long:?}");
    // The per-frame series is down-sampled evenly to at most
    // MAX_SERIES_FRAMES frames, yet the summaries cover every frame.
    for s in &long.strategies {
        let kept: Vec<u32> = s.frames.iter().map(|m| m.frame).collect();
        assert!(
            kept.len() <= MAX_SERIES_FRAMES && kept.len() > MAX_SERIES_FRAMES / 2,
            "{} frames kept",
            kept.len()
        );
        let stride = kept[1] - kept[0];
        assert!(stride > 1 && stride.is_power_of_two(), "stride {stride}");
        assert!(kept.windows(2).all(|w| w[1] - w[0] == stride));
        assert!(20_000 - kept[kept.len() - 1] <= stride);
        assert_eq!(s.summary.frames, 20_000);
        assert!(
            s.summary.mean_error.is_nan(),
            "error is not available without geometry"
        );
    }
    let lipac = long.strategy("lipac").unwrap();
    let full = long.strategy("full").unwrap();
    // The full scene holds the 200 live instances every frame; LiPaC builds
    // BLASes for what the recorded hits ask for.
    assert_eq!(full.summary.mean_instances, 200.0);
    assert_eq!(full.summary.peak_instances, 200);
    assert!(lipac.summary.builds > 0 && lipac.summary.state_changes > 0);
    assert!(short.strategy("lipac").unwrap().summary.builds <= lipac.summary.builds);
}

#[test]
fn hits_only_keeps_frames_for_the_report_and_refuses_geometry_strategies() {
    let bytes = churn(40, 50);
    let input = TraceInput::new(TraceFormat::Binary, bytes.as_slice()).unwrap();
    let r = replay(input, &ReplayConfig::default(), &mut |_| {}).unwrap();
    assert_eq!(r.strategies.len(), 3);
    let full = r.strategy("full").unwrap();
    assert_eq!(full.frames.len(), 40);
    // The full scene holds every live instance: 50 after the first frame.
    assert!(
        full.frames.iter().all(|m| m.tlas_instances == 50),
        "{:?}",
        full.frames[0]
    );
    let lipac = r.strategy("lipac").unwrap();
    assert!(lipac.frames.iter().any(|m| m.counting_boxes > 0));
    let dir = std::env::temp_dir().join(format!("lipac-replay-report-{}", std::process::id()));
    let files = lipac_sim::report::write_report(&r, &dir).unwrap();
    assert!(files.iter().all(|p| p.exists()));
    let json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(dir.join("report.json")).unwrap()).unwrap();
    assert_eq!(json["strategies"][1]["summary"]["mean_error"], "nan");
    let _ = std::fs::remove_dir_all(&dir);

    let input = TraceInput::new(TraceFormat::Binary, bytes.as_slice()).unwrap();
    let config = ReplayConfig {
        strategies: vec![StrategyKind::Oracle],
        mode: Some(ReplayMode::HitsOnly),
        ..ReplayConfig::default()
    };
    let err = replay(input, &config, &mut |_| {}).unwrap_err().to_string();
    assert!(err.contains("oracle") && err.contains("geometry"), "{err}");
}

fn data(name: &str) -> std::path::PathBuf {
    std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../tests/data")
        .join(name)
}

#[test]
fn golden_trace_replays_in_hits_only_mode() {
    for name in ["tiny.lipactrace", "tiny.jsonl"] {
        let input = TraceInput::open(&data(name)).unwrap();
        let r = replay(input, &ReplayConfig::default(), &mut |_| {}).expect(name);
        // Frames 10 (two adds), 11 (hits on instance 1), 13 (instance 1 removed).
        assert_eq!(r.frames, 3, "{name}");
        let per_frame = |s: &str, f: fn(&lipac_sim::metrics::FrameMetrics) -> u64| {
            r.strategy(s)
                .unwrap()
                .frames
                .iter()
                .map(f)
                .collect::<Vec<_>>()
        };
        assert_eq!(per_frame("full", |m| m.tlas_instances), [2, 2, 1], "{name}");
        assert_eq!(per_frame("full", |m| m.needed_missing), [0, 0, 0], "{name}");
        // LiPaC registers instances inactive: the hit of frame 11 finds
        // instance 1 missing (its feedback arrives with the next frame).
        assert_eq!(
            per_frame("lipac", |m| m.needed_missing),
            [0, 1, 0],
            "{name}"
        );
        assert_eq!(
            per_frame("lipac", |m| m.frame as u64),
            [10, 11, 13],
            "{name}"
        );
    }
}

fn lipac(args: &[&str]) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_lipac"))
        .args(args)
        .output()
        .expect("run lipac")
}

#[test]
fn cli_reports_corrupt_traces_with_frame_and_offset() {
    let dir = std::env::temp_dir().join(format!("lipac-replay-cli-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let bytes = churn(10, 20);
    // Cut inside the fourth frame record.
    let mut r = lipac_core::trace::TraceReader::new(bytes.as_slice()).unwrap();
    for _ in 0..3 {
        r.skip_frame().unwrap();
    }
    let cut = r.offset() + 10;
    let truncated = dir.join("truncated.lipactrace");
    std::fs::write(&truncated, &bytes[..cut as usize]).unwrap();
    let out = lipac(&[
        "replay",
        truncated.to_str().unwrap(),
        "--out",
        dir.join("r").to_str().unwrap(),
    ]);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success());
    assert!(
        stderr.contains("frame record 3") && stderr.contains("truncated"),
        "{stderr}"
    );
    // The offset named lies inside the cut record.
    let byte: u64 = stderr
        .split("byte ")
        .nth(1)
        .and_then(|t| t.split(|c: char| !c.is_ascii_digit()).next())
        .and_then(|n| n.parse().ok())
        .expect("a byte offset");
    assert!(
        (r.offset()..=cut).contains(&byte),
        "{byte} not in {}..={cut}: {stderr}",
        r.offset()
    );
    assert!(!stderr.contains("panicked"), "{stderr}");

    // A flipped event tag.
    let mut corrupt = bytes.clone();
    let mut r = lipac_core::trace::TraceReader::new(bytes.as_slice()).unwrap();
    r.skip_frame().unwrap();
    let at = r.offset() + 4 + 8 + 12 + 16 + 8 + 4; // first event's tag of frame record 1
    corrupt[at as usize] = 9;
    let path = dir.join("corrupt.lipactrace");
    std::fs::write(&path, &corrupt).unwrap();
    let out = lipac(&[
        "replay",
        path.to_str().unwrap(),
        "--out",
        dir.join("r").to_str().unwrap(),
    ]);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success());
    assert!(
        stderr.contains("frame record 1") && stderr.contains(&format!("byte {at}")),
        "{stderr}"
    );

    // Not a trace at all.
    let junk = dir.join("junk.lipactrace");
    std::fs::write(&junk, b"PK\x03\x04 not a trace").unwrap();
    let out = lipac(&["replay", junk.to_str().unwrap()]);
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("byte 0"));
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn cli_records_converts_and_replays() {
    let dir = std::env::temp_dir().join(format!("lipac-record-cli-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let bin = dir.join("s.lipactrace");
    let jsonl = dir.join("s.jsonl");
    let back = dir.join("back.lipactrace");
    let p = |x: &std::path::Path| x.to_str().unwrap().to_string();
    let out = lipac(&[
        "record",
        "--scene",
        "small",
        "--frames",
        "3",
        "--geometry",
        &p(&bin),
    ]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let out = lipac(&["convert", &p(&bin), &p(&jsonl)]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let out = lipac(&["convert", &p(&jsonl), &p(&back)]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert_eq!(std::fs::read(&bin).unwrap(), std::fs::read(&back).unwrap());
    let text = std::fs::read_to_string(&jsonl).unwrap();
    assert!(text.starts_with("{") && text.contains("lipac-sim:small:seed=7:camera=flythrough"));
    assert!(text.lines().next().unwrap().contains("\"geometry\""));
    let report = dir.join("report");
    let out = lipac(&[
        "replay",
        &p(&jsonl),
        "--strategies",
        "full,lipac",
        "--width",
        "16",
        "--height",
        "9",
        "--threads",
        "2",
        "--out",
        &p(&report),
    ]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(report.join("report.json")).unwrap())
            .unwrap();
    assert_eq!(json["frames"], 3);
    assert_eq!(json["scene"], "small");
    let _ = std::fs::remove_dir_all(&dir);
}

/// A replay finds the recorded jump's cut from the cameras and, asked to,
/// warm-starts LiPaC there as `compare --warm-start-at-cuts` does along
/// the path: the same frames as without before the cut, more of the new
/// view in the TLAS at it.
#[test]
fn a_replay_finds_the_cut_and_warm_starts_there() {
    use lipac_sim::scene::Scene;
    let aspect = W as f32 / H as f32;
    let scene = Scene::generate(&SceneChoice::Small.config(None)).unwrap();
    let path = CameraChoice::Jump.path(&scene, aspect);
    let cut = path.cuts()[0];
    let frames = cut + 4;
    let bytes = record(
        &RecordConfig {
            scene: SceneChoice::Small,
            seed: None,
            camera: CameraChoice::Jump,
            frames: Some(frames),
            aspect,
            geometry: false,
        },
        TraceFormat::Binary,
        Vec::new(),
    )
    .unwrap()
    .0;
    let go = |at_cuts: bool| {
        let config = ReplayConfig {
            strategies: vec![StrategyKind::Lipac],
            width: W,
            height: H,
            threads: 2,
            warm_start_at_cuts: at_cuts,
            warm_start_hold: None,
            ..ReplayConfig::default()
        };
        let input = TraceInput::new(TraceFormat::Binary, bytes.as_slice()).unwrap();
        replay(input, &config, &mut |_| {}).unwrap()
    };
    let (plain, warm) = (go(false), go(true));
    assert_eq!(plain.camera_cuts, [cut]);
    assert_eq!(warm.camera_cuts, [cut]);
    let (a, b) = (
        &plain.strategy("lipac").unwrap().frames,
        &warm.strategy("lipac").unwrap().frames,
    );
    let c = cut as usize;
    for f in 0..c {
        assert_eq!(a[f].tlas_instances, b[f].tlas_instances, "frame {f}");
        assert_eq!(a[f].error.to_bits(), b[f].error.to_bits(), "frame {f}");
    }
    assert!(
        b[c].tlas_instances > a[c].tlas_instances,
        "{} vs {}",
        b[c].tlas_instances,
        a[c].tlas_instances
    );
}
