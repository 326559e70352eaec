//! The `lipac` binary never destroys a user's file, reads every input once
//! (FIFOs, standard input), refuses sizes it cannot allocate, and names
//! where a replay failed (issue 12). Unix only (symbolic links, FIFOs).
#![cfg(unix)]

use std::io::Write;
use std::path::{Path, PathBuf};
use std::process::{Command, Output, Stdio};

use lipac_core::trace::*;

fn lipac() -> Command {
    Command::new(env!("CARGO_BIN_EXE_lipac"))
}

fn run(cmd: &mut Command) -> Output {
    cmd.stdin(Stdio::null()).output().expect("lipac runs")
}

fn stderr(o: &Output) -> String {
    String::from_utf8_lossy(&o.stderr).into_owned()
}

fn data(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../tests/data")
        .join(name)
}

/// A fresh folder for one test.
fn scratch(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("lipac-cli-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

/// Files in `dir` (names), sorted.
fn listing(dir: &Path) -> Vec<String> {
    let mut v: Vec<String> = std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    v.sort();
    v
}

#[test]
fn convert_onto_its_input_keeps_the_input() {
    let dir = scratch("convert-self");
    let x = dir.join("x.lipactrace");
    let original = std::fs::read(data("tiny.lipactrace")).unwrap();
    std::fs::write(&x, &original).unwrap();
    let o = run(lipac().args(["convert"]).arg(&x).arg(&x));
    assert!(!o.status.success());
    assert!(stderr(&o).contains("is the input"), "{}", stderr(&o));
    assert_eq!(std::fs::read(&x).unwrap(), original);

    // Through a symbolic link, and through a hard link.
    let link = dir.join("alias.jsonl");
    std::os::unix::fs::symlink(&x, &link).unwrap();
    let o = run(lipac().args(["convert"]).arg(&x).arg(&link));
    assert!(!o.status.success(), "{}", stderr(&o));
    assert_eq!(std::fs::read(&x).unwrap(), original);
    let hard = dir.join("hard.jsonl");
    std::fs::hard_link(&x, &hard).unwrap();
    let o = run(lipac().args(["convert"]).arg(&hard).arg(&x));
    assert!(!o.status.success(), "{}", stderr(&o));
    assert_eq!(std::fs::read(&x).unwrap(), original);
    assert_eq!(listing(&dir), ["alias.jsonl", "hard.jsonl", "x.lipactrace"]);
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn a_failed_convert_leaves_the_output_untouched() {
    let dir = scratch("convert-fail");
    let keep = dir.join("keep.jsonl");
    std::fs::write(&keep, b"precious").unwrap();
    let o = run(lipac().args(["convert", "/nonexistent/trace"]).arg(&keep));
    assert!(!o.status.success());
    assert_eq!(std::fs::read(&keep).unwrap(), b"precious");
    // A corrupt input found only half-way: still untouched, no leftovers.
    let mut bad = std::fs::read(data("tiny.lipactrace")).unwrap();
    let n = bad.len();
    bad.truncate(n - 5);
    let bad_path = dir.join("cut.lipactrace");
    std::fs::write(&bad_path, &bad).unwrap();
    let o = run(lipac().arg("convert").arg(&bad_path).arg(&keep));
    assert!(!o.status.success());
    assert!(stderr(&o).contains("cut.lipactrace"), "{}", stderr(&o));
    assert_eq!(std::fs::read(&keep).unwrap(), b"precious");
    assert_eq!(listing(&dir), ["cut.lipactrace", "keep.jsonl"]);
    // A good conversion replaces it, written through a symbolic link.
    let link = dir.join("link.jsonl");
    std::os::unix::fs::symlink(&keep, &link).unwrap();
    let o = run(lipac()
        .arg("convert")
        .arg(data("tiny.lipactrace"))
        .arg(&link));
    assert!(o.status.success(), "{}", stderr(&o));
    assert_eq!(
        std::fs::read(&keep).unwrap(),
        std::fs::read(data("tiny.jsonl")).unwrap()
    );
    assert!(std::fs::symlink_metadata(&link)
        .unwrap()
        .file_type()
        .is_symlink());
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn record_checks_its_arguments_before_creating_anything() {
    let dir = scratch("record-args");
    let keep = dir.join("keep.lipactrace");
    std::fs::write(&keep, b"precious").unwrap();
    for args in [
        &["--frames", "0"][..],
        &["--height", "0"][..],
        &["--width", "0"][..],
        &["--width", "4294967295", "--height", "4294967295"][..],
    ] {
        let o = run(lipac()
            .args(["record", "--scene", "small"])
            .args(args)
            .arg(&keep));
        assert!(!o.status.success(), "{args:?}");
        assert!(!stderr(&o).is_empty(), "{args:?}");
        assert_eq!(std::fs::read(&keep).unwrap(), b"precious", "{args:?}");
        let fresh = dir.join("fresh.lipactrace");
        let o = run(lipac()
            .args(["record", "--scene", "small"])
            .args(args)
            .arg(&fresh));
        assert!(!o.status.success(), "{args:?}");
        assert!(!fresh.exists(), "{args:?} created the output");
    }
    let o = run(lipac()
        .args(["record", "--height", "0", "--scene", "small"])
        .arg(&keep));
    assert!(stderr(&o).contains("128 x 0"), "{}", stderr(&o));
    assert_eq!(listing(&dir), ["keep.lipactrace"]);
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn replay_reads_standard_input_and_fifos() {
    let dir = scratch("replay-stdin");
    for name in ["tiny.lipactrace", "tiny.jsonl"] {
        let out = dir.join(format!("report-{name}"));
        let mut child = lipac()
            .args(["replay", "-", "--out"])
            .arg(&out)
            .stdin(Stdio::piped())
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .spawn()
            .unwrap();
        child
            .stdin
            .take()
            .unwrap()
            .write_all(&std::fs::read(data(name)).unwrap())
            .unwrap();
        let o = child.wait_with_output().unwrap();
        assert!(o.status.success(), "{name}: {}", stderr(&o));
        assert!(out.join("report.json").exists(), "{name}");
    }
    // A FIFO: opened once, so the writer's single pass is all it needs.
    let fifo = dir.join("trace.fifo");
    let made = Command::new("mkfifo").arg(&fifo).status();
    if made.is_ok_and(|s| s.success()) {
        let bytes = std::fs::read(data("tiny.lipactrace")).unwrap();
        let writer = {
            let fifo = fifo.clone();
            std::thread::spawn(move || std::fs::write(&fifo, bytes))
        };
        let out = dir.join("converted.jsonl");
        let mut child = lipac()
            .arg("convert")
            .arg(&fifo)
            .arg(&out)
            .stdin(Stdio::null())
            .stdout(Stdio::null())
            .stderr(Stdio::piped())
            .spawn()
            .unwrap();
        let start = std::time::Instant::now();
        let status = loop {
            if let Some(s) = child.try_wait().unwrap() {
                break s;
            }
            assert!(start.elapsed().as_secs() < 60, "convert of a FIFO hangs");
            std::thread::sleep(std::time::Duration::from_millis(20));
        };
        writer.join().unwrap().unwrap();
        assert!(status.success());
        assert_eq!(
            std::fs::read(&out).unwrap(),
            std::fs::read(data("tiny.jsonl")).unwrap()
        );
    }
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn image_sizes_that_cannot_be_allocated_are_refused() {
    let o = run(lipac().args([
        "compare",
        "--scene",
        "small",
        "--frames",
        "1",
        "--width",
        "100000",
        "--height",
        "100000",
        "--out",
        "/nonexistent/never",
    ]));
    assert!(!o.status.success());
    let e = stderr(&o);
    assert!(e.contains("100000 x 100000"), "{e}");
    let o = run(lipac().arg("replay").arg(data("tiny.lipactrace")).args([
        "--width",
        "4294967295",
        "--height",
        "4294967295",
    ]));
    assert!(!o.status.success());
    let e = stderr(&o);
    assert!(e.contains("4294967295 x 4294967295"), "{e}");
    assert!(!e.contains("θd"), "{e}");
}

/// `--warm-start` on `compare` and `replay`: a bad value is refused with
/// its reason before anything is written; `off` and `DIST:SIZE` run.
#[test]
fn warm_start_values_are_checked_before_anything_is_written() {
    let dir = scratch("warm-start");
    for bad in ["bogus", "50", "-1:0.1", "50:NaN", "50:inf"] {
        let out = dir.join(format!("compare-{}", bad.replace(':', "_")));
        let o = run(lipac()
            .args(["compare", "--scene", "small", "--frames", "1"])
            .args([
                "--width",
                "16",
                "--height",
                "9",
                &format!("--warm-start={bad}"),
                "--out",
            ])
            .arg(&out));
        assert!(!o.status.success(), "{bad} accepted");
        let e = stderr(&o);
        assert!(
            e.contains("--warm-start") && e.contains("DIST:SIZE"),
            "{bad}: {e}"
        );
        assert!(!out.exists(), "{bad}: {} written", out.display());
        let out = dir.join("replay-bad");
        let o = run(lipac()
            .arg("replay")
            .arg(data("tiny.lipactrace"))
            .arg(format!("--warm-start={bad}"))
            .arg("--out")
            .arg(&out));
        assert!(!o.status.success(), "replay: {bad} accepted");
        assert!(stderr(&o).contains("--warm-start"), "{}", stderr(&o));
        assert!(!out.exists());
    }
    // The sweep's heuristics follow the same rule (one parser).
    for bad in ["50", "NaN:0.1", "50:inf", "-1:0"] {
        let out = dir.join("sweep-bad");
        let o = run(lipac()
            .args(["sweep", "--scenes", "small", "--frames", "1"])
            .arg(format!("--latency={bad}"))
            .arg("--out")
            .arg(&out));
        assert!(!o.status.success(), "sweep: {bad} accepted");
        let e = stderr(&o);
        assert!(
            e.contains("--latency") && e.contains("DIST:SIZE"),
            "{bad}: {e}"
        );
        assert!(!out.exists());
    }
    for good in ["off", "inf:0", "100:0.05"] {
        let out = dir.join(format!("compare-ok-{}", good.replace(':', "_")));
        let o = run(lipac()
            .args(["compare", "--scene", "small", "--frames", "2"])
            .args([
                "--width",
                "16",
                "--height",
                "9",
                "--strategies",
                "lipac",
                "--threads",
                "1",
                &format!("--warm-start={good}"),
                "--out",
            ])
            .arg(&out));
        assert!(o.status.success(), "{good}: {}", stderr(&o));
        assert!(out.join("report.json").exists());
    }
    let _ = std::fs::remove_dir_all(&dir);
}

fn camera(aspect: f32) -> Camera {
    Camera::look_to(
        glam::Vec3::new(0.0, 1.0, 0.0),
        glam::Vec3::NEG_Z,
        glam::Vec3::Y,
        1.0,
        aspect,
    )
}

fn header() -> TraceHeader {
    TraceHeader {
        scene_name: "cli errors".into(),
        world: WorldInfo {
            min: [-64.0, -64.0],
            max: [64.0, 64.0],
            cell_size: 16.0,
        },
        meshes: vec![MeshInfo {
            id: lipac_core::instance::MeshId(1),
            bounds: lipac_core::math::Aabb::new(glam::Vec3::splat(-1.0), glam::Vec3::splat(1.0)),
            lods: vec![LodInfo {
                triangles: 12,
                geometry: None,
            }],
        }],
    }
}

fn add(id: u64, lo: glam::Vec3, hi: glam::Vec3) -> InstanceEvent {
    // (Half the extent added to `lo`: no overflow for boxes near f32::MAX.)
    let c = lo + (hi - lo) * 0.5;
    InstanceEvent::Add(AddInstance {
        id,
        mesh: lipac_core::instance::MeshId(1),
        lod: 0,
        flags: lipac_core::instance::InstanceFlags::empty(),
        mask: None,
        pose: Pose {
            transform: [1.0, 0.0, 0.0, c.x, 0.0, 1.0, 0.0, c.y, 0.0, 0.0, 1.0, c.z],
            aabb: lipac_core::math::Aabb::new(lo, hi),
        },
        slot: None,
    })
}

fn write_trace(path: &Path, frames: &[Frame]) {
    let mut w = TraceWriter::new(Vec::new(), &header()).unwrap();
    for f in frames {
        w.write_frame(f).unwrap();
    }
    std::fs::write(path, w.finish().unwrap()).unwrap();
}

fn frame(number: u64, aspect: f32, events: Vec<InstanceEvent>) -> Frame {
    let hits = events
        .iter()
        .map(|e| InstanceHits {
            id: e.id(),
            hits: 1,
        })
        .collect();
    Frame {
        number,
        camera: camera(aspect),
        events,
        hits: Some(hits),
        slot_hits: None,
    }
}

#[test]
fn replay_errors_name_file_frame_location_and_value() {
    let dir = scratch("replay-errors");
    let ok = add(1, glam::Vec3::splat(-1.0), glam::Vec3::splat(1.0));
    // An aspect the format accepts (finite, > 0) but no projection can use.
    let path = dir.join("aspect.lipactrace");
    write_trace(
        &path,
        &[frame(0, 1.5, vec![ok.clone()]), frame(7, 1e-45, vec![])],
    );
    let o = run(lipac()
        .arg("replay")
        .arg(&path)
        .arg("--out")
        .arg(dir.join("r1")));
    assert!(!o.status.success());
    let e = stderr(&o);
    assert!(e.contains("aspect.lipactrace"), "{e}");
    // Frame 1's record: preamble 20 + header 95 + frame 0 record 163.
    assert!(
        e.contains("frame record 1 (frame number 7) at byte 278"),
        "{e}"
    );
    assert!(e.contains("aspect 1e-45"), "{e}");

    // An instance far outside the world: printed as given, not as the
    // f32-rounded (infinite) centre.
    let path = dir.join("outside.lipactrace");
    let at = glam::Vec3::new(3e38, -3e38, 3e38);
    let far = add(2, at, at);
    write_trace(&path, &[frame(0, 1.5, vec![ok]), frame(1, 1.5, vec![far])]);
    let o = run(lipac()
        .arg("replay")
        .arg(&path)
        .arg("--out")
        .arg(dir.join("r2")));
    assert!(!o.status.success());
    let e = stderr(&o);
    assert!(e.contains("outside.lipactrace"), "{e}");
    assert!(e.contains("frame record 1, frame number 1, event 0"), "{e}");
    assert!(e.contains("[3e38, -3e38, 3e38]"), "{e}");
    assert!(!e.contains("inf"), "{e}");
    // An error found after the last frame says so.
    let path = dir.join("nohits.lipactrace");
    let mut f = frame(0, 1.5, vec![]);
    f.hits = None;
    write_trace(&path, &[f]);
    let o = run(lipac()
        .arg("replay")
        .arg(&path)
        .arg("--out")
        .arg(dir.join("r3")));
    assert!(!o.status.success());
    let e = stderr(&o);
    assert!(
        e.contains(
            "after the last frame (frame record 0, frame number 0; end of the trace at byte"
        ),
        "{e}"
    );
    assert!(e.contains("hit counts"), "{e}");
    assert!(!dir.join("r1").exists() && !dir.join("r2").exists() && !dir.join("r3").exists());
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn replay_streams_frames_unless_asked_to_keep_them() {
    let dir = scratch("replay-keep");
    let read_frames = |out: &Path| -> usize {
        let json: serde_json::Value =
            serde_json::from_slice(&std::fs::read(out.join("report.json")).unwrap()).unwrap();
        json["strategies"][0]["frames"]
            .as_array()
            .map_or(0, |a| a.len())
    };
    let (a, b) = (dir.join("streamed"), dir.join("kept"));
    let o = run(lipac()
        .arg("replay")
        .arg(data("tiny.jsonl"))
        .arg("--out")
        .arg(&a));
    assert!(o.status.success(), "{}", stderr(&o));
    let o = run(lipac()
        .arg("replay")
        .arg(data("tiny.jsonl"))
        .arg("--keep-frames")
        .arg("--out")
        .arg(&b));
    assert!(o.status.success(), "{}", stderr(&o));
    // A streaming replay keeps a down-sampled series (every frame of a
    // trace this short; lipac-sim/tests/replay.rs covers long ones).
    assert_eq!(read_frames(&a), 3);
    assert_eq!(read_frames(&b), 3);
    // The report folder is never the trace, nor does it replace it.
    let trace = dir.join("t.lipactrace");
    std::fs::copy(data("tiny.lipactrace"), &trace).unwrap();
    let o = run(lipac().arg("replay").arg(&trace).arg("--out").arg(&trace));
    assert!(!o.status.success());
    assert_eq!(
        std::fs::read(&trace).unwrap(),
        std::fs::read(data("tiny.lipactrace")).unwrap()
    );
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn a_sweep_never_writes_over_the_trace_it_sweeps() {
    // A trace named like one of the sweep's outputs, in the report folder.
    let dir = scratch("sweep-trace");
    let trace = dir.join("sweep.json");
    let record = ["record", "--scene", "small", "--frames", "2"];
    let o = run(lipac()
        .args(record)
        .args(["--format", "binary"])
        .arg(&trace));
    assert!(o.status.success(), "{}", stderr(&o));
    let original = std::fs::read(&trace).unwrap();
    // One configuration and one baseline on 32 x 18.
    let only = [
        "--factors",
        "1",
        "--cells",
        "",
        "--streaks",
        "",
        "--latency",
        "",
    ];
    let small = ["--baselines", "full", "--width", "32", "--height", "18"];
    let sweep_into = |out: &Path| {
        run(lipac()
            .args(["sweep", "--trace"])
            .arg(&trace)
            .args(only)
            .args(small)
            .args(["--threads", "2", "--out"])
            .arg(out))
    };
    let o = sweep_into(&dir);
    assert!(!o.status.success());
    assert!(stderr(&o).contains("is the input"), "{}", stderr(&o));
    assert_eq!(std::fs::read(&trace).unwrap(), original);
    assert_eq!(listing(&dir), ["sweep.json"]);
    // The same sweep into a folder of its own writes the report.
    let out = dir.join("report");
    let o = sweep_into(&out);
    assert!(o.status.success(), "{}", stderr(&o));
    let md = std::fs::read_to_string(out.join("sweep.md")).unwrap();
    assert!(md.contains("## trace sweep.json"), "{md}");
    let _ = std::fs::remove_dir_all(&dir);
}
