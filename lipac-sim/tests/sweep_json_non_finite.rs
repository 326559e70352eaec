//! An infinite or undefined error (a strategy against a black ground truth)
//! survives the sweep's JSON: `sweep --merge` reads a shard holding one and
//! `sweep --replot` reads the merged `sweep.json` back, figure for figure.
//! (serde_json alone writes a non-finite `f64` as `null`, which it then
//! refuses to read as an `f64`.)

use std::path::{Path, PathBuf};
use std::process::Command;

use lipac_sim::compare::SceneChoice;
use lipac_sim::strategy::StrategyKind;
use lipac_sim::sweep::shard::{run_shard, write_shard, Shard};
use lipac_sim::sweep::{SweepConfig, SweepReport};

fn temp(name: &str) -> PathBuf {
    std::env::temp_dir().join(format!("lipac-nonfinite-{}-{name}", std::process::id()))
}

fn lipac(args: &[&str], paths: &[&Path]) {
    let o = Command::new(env!("CARGO_BIN_EXE_lipac"))
        .args(args)
        .args(paths)
        .output()
        .unwrap();
    assert!(
        o.status.success(),
        "lipac {args:?}: {}",
        String::from_utf8_lossy(&o.stderr)
    );
}

fn read(path: &Path) -> (String, SweepReport) {
    let text = std::fs::read_to_string(path).unwrap();
    let report = serde_json::from_str(&text).unwrap_or_else(|e| panic!("{path:?}: {e}"));
    (text, report)
}

#[test]
fn infinite_errors_survive_merge_and_replot() {
    let config = SweepConfig {
        scenes: vec![SceneChoice::Small],
        seed: None,
        frames: Some(2),
        width: 32,
        height: 18,
        baselines: vec![StrategyKind::Full],
        hindsight: Vec::new(),
        factors: vec![1.0],
        latency: vec![],
        cell_sizes: vec![],
        streaks: vec![],
        decayed: vec![],
        threads: 2,
        trace: None,
        trace_options: Default::default(),
        warm_start_at_cuts: false,
        warm_start_hold: None,
        lipac_start: Default::default(),
        device: Default::default(),
    };
    let mut shard = run_shard(&config, Shard::new(1, 1).unwrap(), &mut |_, _, _, _| {}).unwrap();
    assert!(shard.points.len() >= 2, "{} points", shard.points.len());
    // What a black ground truth gives: an infinite error in one frame
    // (so the maximum and mean too), an undefined one in another point.
    let p = &mut shard.points[0];
    p.frame_errors[0] = f64::INFINITY;
    p.summary.max_error = f64::INFINITY;
    p.summary.mean_error = f64::INFINITY;
    shard.points[1].frame_errors[1] = f64::NAN;
    let root = temp("root");
    let part = root.join("part");
    let file = write_shard(&shard, &part).unwrap();
    assert!(std::fs::read_to_string(&file).unwrap().contains(r#""inf""#));

    let merged = root.join("merged");
    lipac(&["sweep", "--merge"], &[&part, Path::new("--out"), &merged]);
    let (text, m) = read(&merged.join("sweep.json"));
    // Written as strings, not as null (which serde_json cannot read back).
    let v: serde_json::Value = serde_json::from_str(&text).unwrap();
    let p0 = &v["points"][0];
    assert_eq!(p0["frame_errors"][0], "inf");
    assert_eq!(p0["summary"]["max_error"], "inf");
    assert_eq!(v["points"][1]["frame_errors"][1], "nan");
    assert!(p0["frame_errors"][1].is_number());
    let check = |r: &SweepReport| {
        let p = &r.points[0];
        assert_eq!(p.frame_errors[0], f64::INFINITY);
        assert_eq!(p.summary.max_error, f64::INFINITY);
        assert_eq!(p.summary.mean_error, f64::INFINITY);
        assert!(r.points[1].frame_errors[1].is_nan());
        // The finite figures bit for bit.
        assert_eq!(
            p.frame_errors[1].to_bits(),
            shard.points[0].frame_errors[1].to_bits()
        );
    };
    check(&m);

    let replotted = root.join("replotted");
    lipac(
        &["sweep", "--replot"],
        &[&merged.join("sweep.json"), Path::new("--out"), &replotted],
    );
    let (_, r) = read(&replotted.join("sweep.json"));
    check(&r);
    assert_eq!(r.points.len(), m.points.len());
    std::fs::remove_dir_all(&root).unwrap();
}
