//! `--device-profile`: a profile's acceleration-structure sizes make the
//! report's memory axis and its rates the modelled GPU time, the report
//! names it, and a malformed profile is a clear error that writes nothing.
//! Without a profile the results are the built-in model's.

use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};

use lipac_sim::compare::{run_choice, CompareConfig, CompareReport, SceneChoice};
use lipac_sim::device_profile::DeviceProfile;
use lipac_sim::memory::MemoryModel;
use lipac_sim::strategy::StrategyKind;

fn profile(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("profiles")
        .join(name)
}

fn compare(device: DeviceProfile) -> CompareReport {
    let config = CompareConfig {
        frames: Some(6),
        width: 32,
        height: 18,
        strategies: vec![StrategyKind::Full, StrategyKind::Lipac],
        threads: 2,
        device,
        ..CompareConfig::default()
    };
    run_choice(SceneChoice::Small, None, &config, &mut |_, _| {}).unwrap()
}

#[test]
fn a_profile_changes_the_memory_axis_and_the_gpu_model() {
    let h200 = DeviceProfile::load(&profile("nvidia-h200.json")).unwrap();
    let builtin = compare(DeviceProfile::builtin());
    let device = compare(h200.clone());
    let (mb, mh) = (MemoryModel::default(), h200.memory_model());
    assert!(builtin.device_profile.is_builtin());
    assert_eq!(device.device_profile.name, "nvidia-h200");
    assert_eq!(device.gpu_model, h200.gpu_model());
    for (b, h) in builtin.strategies.iter().zip(&device.strategies) {
        assert_eq!(b.name, h.name);
        for (fb, fh) in b.frames.iter().zip(&h.frames) {
            // The TLAS is each model's size of the records traced.
            assert_eq!(fb.tlas_bytes, mb.tlas_bytes(fb.tlas_instances));
            assert_eq!(fh.tlas_bytes, mh.tlas_bytes(fh.tlas_instances));
        }
        let bytes = |r: &lipac_sim::compare::StrategyRun| {
            r.frames.iter().map(|m| m.blas_bytes).max().unwrap_or(0)
        };
        // 92 B per triangle against lavapipe's 104: less BLAS memory.
        assert!(
            bytes(h) < bytes(b),
            "{}: {} vs {}",
            b.name,
            bytes(h),
            bytes(b)
        );
        assert!(h.summary.mean_mib < b.summary.mean_mib, "{}", b.name);
        assert_ne!(
            h.summary.mean_gpu_frame_ms, b.summary.mean_gpu_frame_ms,
            "{}",
            b.name
        );
    }
    // The full scene's records do not depend on the device: its BLAS
    // bytes are the same BLASes at the other sizes.
    let full = |r: &CompareReport| r.strategy("full").unwrap().frames[0].tlas_instances;
    assert_eq!(full(&builtin), full(&device));
}

#[test]
fn no_profile_is_the_builtin_model() {
    let r = compare(DeviceProfile::builtin());
    let m = lipac_sim::metrics::GpuModel::PUBLISHED;
    assert_eq!(r.gpu_model, m);
    for s in &r.strategies {
        for f in &s.frames {
            assert_eq!(
                f.tlas_bytes,
                lipac_sim::memory::tlas_bytes(f.tlas_instances)
            );
        }
    }
}

fn lipac() -> Command {
    Command::new(env!("CARGO_BIN_EXE_lipac"))
}

fn scratch(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("lipac-profile-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

fn args(out: &Path) -> Vec<String> {
    [
        "compare",
        "--scene",
        "small",
        "--frames",
        "3",
        "--width",
        "24",
        "--height",
        "16",
        "--threads",
        "2",
        "--strategies",
        "full,lipac",
        "--out",
    ]
    .iter()
    .map(|s| s.to_string())
    .chain([out.display().to_string()])
    .collect()
}

#[test]
fn the_cli_reports_the_profile_and_refuses_a_malformed_one() {
    let dir = scratch("cli");
    let out = dir.join("report");
    let o = lipac()
        .args(args(&out))
        .arg("--device-profile")
        .arg(profile("nvidia-h200.json"))
        .stdin(Stdio::null())
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let md = std::fs::read_to_string(out.join("report.md")).unwrap();
    assert!(md.contains("device profile nvidia-h200"), "{md}");
    assert!(md.contains("92 at 512 triangles"), "{md}");
    let json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("report.json")).unwrap()).unwrap();
    assert_eq!(json["device_profile"]["name"], "nvidia-h200");
    let html = std::fs::read_to_string(out.join("report.html")).unwrap();
    assert!(html.contains("nvidia-h200"));

    // Without the flag: the built-in profile, named as such.
    let plain = dir.join("plain");
    let o = lipac()
        .args(args(&plain))
        .stdin(Stdio::null())
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let md = std::fs::read_to_string(plain.join("report.md")).unwrap();
    assert!(md.contains("the built-in device profile"), "{md}");

    // A malformed profile: a clear error naming the file and the field,
    // and no report.
    let bad = dir.join("bad.json");
    let text = std::fs::read_to_string(profile("nvidia-h200.json"))
        .unwrap()
        .replace("\"version\": 1", "\"version\": 9");
    std::fs::write(&bad, text).unwrap();
    let none = dir.join("none");
    let o = lipac()
        .args(args(&none))
        .arg("--device-profile")
        .arg(&bad)
        .stdin(Stdio::null())
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success());
    assert!(
        err.contains("bad.json") && err.contains("version 9"),
        "{err}"
    );
    assert!(!none.exists());
    // The profile is an input: never the report folder.
    let own = dir.join("own.json");
    let original = std::fs::read(profile("nvidia-h200.json")).unwrap();
    std::fs::write(&own, &original).unwrap();
    let o = lipac()
        .args(args(&own))
        .arg("--device-profile")
        .arg(&own)
        .stdin(Stdio::null())
        .output()
        .unwrap();
    assert!(!o.status.success());
    assert_eq!(std::fs::read(&own).unwrap(), original);
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn replay_takes_the_profile_too() {
    let dir = scratch("replay");
    let trace = Path::new(env!("CARGO_MANIFEST_DIR")).join("../tests/data/tiny.lipactrace");
    for (flag, name) in [(true, "nvidia-h200"), (false, "built-in")] {
        let out = dir.join(name);
        let mut cmd = lipac();
        cmd.arg("replay").arg(&trace).arg("--out").arg(&out);
        if flag {
            cmd.arg("--device-profile").arg(profile("nvidia-h200.json"));
        }
        let o = cmd.stdin(Stdio::null()).output().unwrap();
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        let json: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(out.join("report.json")).unwrap())
                .unwrap();
        assert_eq!(json["device_profile"]["name"], name);
    }
    let _ = std::fs::remove_dir_all(&dir);
}
