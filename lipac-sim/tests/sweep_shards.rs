//! `lipac sweep --shard K/N` + `--merge`: the merged shards are the report
//! of one run, figure for figure (timings masked), and merge refuses
//! shards that do not make up one sweep.

use std::path::PathBuf;

use lipac_core::latency::ActivationHeuristic;
use lipac_sim::compare::SceneChoice;
use lipac_sim::strategy::StrategyKind;
use lipac_sim::sweep::shard::{merge, read_shards, run_shard, write_shard, Shard, SweepShard};
use lipac_sim::sweep::{self, SweepConfig, SweepReport};
use serde_json::Value;

fn tiny(frames: u32) -> SweepConfig {
    SweepConfig {
        scenes: vec![SceneChoice::Small, SceneChoice::City],
        seed: None,
        frames: Some(frames),
        width: 64,
        height: 36,
        baselines: vec![StrategyKind::Full, StrategyKind::Frustum],
        hindsight: Vec::new(),
        // 2304 rays: ×1 gives θa = 2, ×4 gives θa = 4.
        factors: vec![1.0, 4.0],
        latency: vec![ActivationHeuristic::default()],
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
    }
}

/// Timing fields (and the frame-time front, computed from them; the
/// modelled GPU times follow from counts and are kept)
/// replaced by null; everything else kept as written to sweep.json.
fn masked(r: &SweepReport) -> Value {
    const TIMINGS: [&str; 10] = [
        "wall_s",
        "ground_truth_ms",
        "mean_trace_ms",
        "mean_tlas_build_ms",
        "mean_strategy_ms",
        "mean_blas_build_ms",
        "mean_blas_refit_ms",
        "mean_frame_ms",
        "median_frame_ms",
        "front_time",
    ];
    fn walk(v: &mut Value) {
        match v {
            Value::Object(m) => {
                for (k, x) in m.iter_mut() {
                    if TIMINGS.contains(&k.as_str()) {
                        *x = Value::Null;
                    } else {
                        walk(x);
                    }
                }
            }
            Value::Array(a) => a.iter_mut().for_each(walk),
            _ => {}
        }
    }
    let mut v = serde_json::to_value(r).unwrap();
    walk(&mut v);
    v
}

fn temp(name: &str) -> PathBuf {
    std::env::temp_dir().join(format!("lipac-shards-{}-{name}", std::process::id()))
}

#[test]
fn three_shards_merge_into_the_report_of_one_run() {
    let config = tiny(2);
    let whole = sweep::run(&config, &mut |_, _, _, _| {}).unwrap();
    // 2 scenes × 5 variants = 10 pairs: 3 + 3 + 4, so shard 2 cuts both
    // scenes (each renders its ground truth twice).
    let mut dirs = Vec::new();
    let mut touched = Vec::new();
    for k in 1..=3 {
        let mut scenes_seen = Vec::new();
        let part = run_shard(&config, Shard::new(k, 3).unwrap(), &mut |si, _, _, _| {
            if !scenes_seen.contains(&si) {
                scenes_seen.push(si)
            }
        })
        .unwrap();
        assert_eq!(part.points.len(), [3, 3, 4][k as usize - 1]);
        touched.push(scenes_seen);
        let dir = temp(&format!("part-{k}"));
        let path = write_shard(&part, &dir).unwrap();
        assert_eq!(
            path.file_name().unwrap().to_str(),
            Some(format!("sweep-shard-{k}-of-3.json").as_str())
        );
        dirs.push(dir);
    }
    assert_eq!(touched, [vec![0], vec![0, 1], vec![1]]);
    // Any order of folders.
    dirs.reverse();
    let shards = read_shards(&dirs).unwrap();
    assert_eq!(shards.len(), 3);
    let merged = merge(&shards).unwrap();
    assert_eq!(masked(&merged), masked(&whole));
    // The comparison is exact, not approximate: per-frame errors bit for bit.
    for (a, b) in merged.points.iter().zip(&whole.points) {
        let bits = |p: &sweep::SweepPoint| -> Vec<u64> {
            p.frame_errors.iter().map(|e| e.to_bits()).collect()
        };
        assert_eq!(bits(a), bits(b), "{} {}", a.scene, a.name);
    }
    // And the comparison can fail: the mask hides timings, not figures.
    let mut tampered = merged.clone();
    tampered.points[7].frame_errors[1] =
        f64::from_bits(merged.points[7].frame_errors[1].to_bits() ^ 1);
    assert_ne!(masked(&tampered), masked(&whole));
    let mut tampered = merged.clone();
    tampered.scenes[1].traced_rays_per_frame += 1.0;
    assert_ne!(masked(&tampered), masked(&whole));
    // Merged shards write the same files as a run.
    let out = temp("merged");
    let written = sweep::write_sweep(&merged, &out).unwrap();
    assert_eq!(written.len(), sweep::SWEEP_FILES.len());
    for d in dirs.iter().chain([&out]) {
        std::fs::remove_dir_all(d).unwrap();
    }
}

#[test]
fn merge_refuses_what_is_not_one_sweep() {
    let config = SweepConfig {
        scenes: vec![SceneChoice::Small],
        baselines: vec![StrategyKind::Full],
        factors: vec![1.0],
        latency: vec![],
        ..tiny(1)
    };
    let part = |k, n, c: &SweepConfig| {
        run_shard(c, Shard::new(k, n).unwrap(), &mut |_, _, _, _| {}).unwrap()
    };
    let (a, b) = (part(1, 2, &config), part(2, 2, &config));
    assert_eq!((a.points.len(), b.points.len()), (1, 1));
    let err = |shards: &[SweepShard]| merge(shards).unwrap_err().to_string();
    assert!(merge(&[a.clone(), b.clone()]).is_ok());
    let alone = err(std::slice::from_ref(&a));
    assert!(alone.contains("missing shards 2/2"), "{alone}");
    assert!(err(&[a.clone(), a.clone(), b.clone()]).contains("1/2 given twice"));
    assert!(err(&[]).contains("no shards"));
    // A shard of a sweep with other settings (more frames).
    let other = part(
        2,
        2,
        &SweepConfig {
            frames: Some(2),
            ..config.clone()
        },
    );
    assert!(err(&[a.clone(), other]).contains("other settings"));
    // A shard run on another device profile (its memory axis differs).
    let h200 = lipac_sim::device_profile::DeviceProfile::load(
        &std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("profiles/nvidia-h200.json"),
    )
    .unwrap();
    let device = part(
        2,
        2,
        &SweepConfig {
            device: h200.clone(),
            ..config.clone()
        },
    );
    assert_eq!(device.plan.device_profile.name, "nvidia-h200");
    assert!(err(&[a.clone(), device.clone()]).contains("other settings"));
    let both = merge(&[
        part(
            1,
            2,
            &SweepConfig {
                device: h200,
                ..config.clone()
            },
        ),
        device,
    ])
    .unwrap();
    assert_eq!(both.device_profile.name, "nvidia-h200");
    assert!(sweep::sweep_markdown(&both).contains("Device profile: nvidia-h200 (NVIDIA H200)"));
    // Another split of the same sweep.
    let third = part(1, 3, &config);
    assert!(err(&[a.clone(), third]).contains("not one of 2 parts"));
    // Render threads are not part of the settings.
    let b4 = part(
        2,
        2,
        &SweepConfig {
            threads: 1,
            ..config.clone()
        },
    );
    assert!(merge(&[b4, a.clone()]).is_ok());
    // A tampered shard that holds another part than its own.
    let mut wrong = b.clone();
    wrong.points = a.points.clone();
    assert!(err(&[a.clone(), wrong]).contains("does not hold its part"));
    // Folders without shard files, and files that are not shards.
    let empty = temp("empty");
    std::fs::create_dir_all(&empty).unwrap();
    assert!(read_shards(std::slice::from_ref(&empty)).is_err());
    let junk = empty.join("sweep-shard-1-of-2.json");
    std::fs::write(&junk, "{}").unwrap();
    assert!(read_shards(&[junk]).is_err());
    std::fs::remove_dir_all(&empty).unwrap();
}

#[test]
fn shard_slices_are_disjoint_and_cover_the_work() {
    for len in [0usize, 1, 5, 10, 27] {
        for n in 1..=12u32 {
            let mut next = 0;
            for k in 1..=n {
                let r = Shard::new(k, n).unwrap().range(len);
                assert_eq!(r.start, next, "{k}/{n} of {len}");
                assert!(r.len() <= len / n as usize + 1);
                next = r.end;
            }
            assert_eq!(next, len);
        }
    }
    assert!(Shard::new(0, 1).is_err() && Shard::new(2, 1).is_err());
    assert_eq!("3/4".parse::<Shard>().unwrap().to_string(), "3/4");
}

#[test]
fn cli_shards_and_merge_write_the_report_of_one_run() {
    let lipac = env!("CARGO_BIN_EXE_lipac");
    let root = temp("cli");
    // --cells= etc.: empty lists, as the help says.
    let sweep_flags = "sweep --scenes small --frames 1 --width 64 --height 36 --factors 1,4 \
                       --cells= --streaks= --latency= --baselines full --threads 2 --out";
    let run = |extra: &[&str], out: &str| {
        std::process::Command::new(lipac)
            .args(sweep_flags.split_whitespace())
            .arg(root.join(out))
            .args(extra)
            .output()
            .unwrap()
    };
    for (k, extra) in [(1, ["--shard", "1/2"]), (2, ["--shard", "2/2"])] {
        let o = run(&extra, &format!("p{k}"));
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        assert!(root
            .join(format!("p{k}/sweep-shard-{k}-of-2.json"))
            .is_file());
        assert!(!root.join(format!("p{k}/sweep.json")).exists());
    }
    assert!(run(&[], "whole").status.success());
    let merged = std::process::Command::new(lipac)
        .args(["sweep", "--merge"])
        .args([root.join("p2"), root.join("p1")])
        .arg("--out")
        .arg(root.join("merged"))
        .output()
        .unwrap();
    assert!(
        merged.status.success(),
        "{}",
        String::from_utf8_lossy(&merged.stderr)
    );
    let read = |d: &str| -> SweepReport {
        serde_json::from_str(&std::fs::read_to_string(root.join(d).join("sweep.json")).unwrap())
            .unwrap()
    };
    let (whole, merged) = (read("whole"), read("merged"));
    assert_eq!(merged.points.len(), 3);
    assert_eq!(masked(&merged), masked(&whole));
    // One shard alone is not a sweep.
    let alone = std::process::Command::new(lipac)
        .args(["sweep", "--merge"])
        .arg(root.join("p1"))
        .arg("--out")
        .arg(root.join("x"))
        .output()
        .unwrap();
    assert!(!alone.status.success());
    assert!(String::from_utf8_lossy(&alone.stderr).contains("missing shards 2/2"));
    assert!(!root.join("x").exists());
    std::fs::remove_dir_all(&root).unwrap();
}
