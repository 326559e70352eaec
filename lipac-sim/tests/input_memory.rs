//! Memory follows what an input carries, not the counts it claims: each
//! reader of lipac-sim runs within a budget checked by a counting global
//! allocator ([`cap::Cap`]).
//!
//! * a hits-only replay of a 283-byte trace whose header declares a
//!   4096 x 4096 grid (1.4 GB before: a record per declared cell);
//! * `sweep --merge` of a shard claiming 4294967295 parts (34 GB before),
//!   and of one whose plan claims 10^4 x 10^4 runs it does not carry;
//! * a glTF import whose index accessor claims 2^40 indices, one whose
//!   200 primitives share an accessor of 1.2 MB (a budget of 8 x the
//!   buffers), one placing a triangle 100,000 times under 200 nodes with
//!   4000-byte names (names shared, not copied per instance), and one of
//!   u32::MAX frames (its frames are made as they are written).
//!
//! The allocator is limited around each case: an allocation past the
//! budget fails, which aborts the process instead of taking the machine's
//! memory. Each case runs in a child process of this test binary, so an
//! abort fails the test cleanly and no other test's allocations count.

use std::alloc::System;
use std::path::PathBuf;

use cap::Cap;
use lipac_sim::import::{import_gltf, ImportConfig};
use lipac_sim::replay::ReplayConfig;
use lipac_sim::sweep::shard::{merge, read_shards, Shard, SweepPlan, SweepShard, SHARD_FORMAT};
use lipac_sim::trace_scene::{replay_path, TraceSceneOptions};

#[global_allocator]
static ALLOC: Cap<System> = Cap::new(System, usize::MAX);

/// Runs `f` with at most `budget` bytes allocated on top of what is live
/// now.
fn within<T>(budget: usize, f: impl FnOnce() -> T) -> T {
    let base = ALLOC.allocated();
    ALLOC
        .set_limit(base + budget)
        .expect("limit above what is allocated");
    let out = f();
    ALLOC.set_limit(usize::MAX).expect("lift the limit");
    out
}

const MIB: usize = 1 << 20;

fn scratch(name: &str) -> PathBuf {
    let dir =
        std::env::temp_dir().join(format!("lipac-input-memory-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

/// One instance in a world declared 4096 x 4096 cells of 1 m, with hit
/// counts (a hits-only trace).
const BIG_GRID: &str = r#"{"format":"lipac-trace","version":1,"scene":"big","world":{"min":[0.0,0.0],"max":[4096.0,4096.0],"cell_size":1.0},"meshes":[{"id":1,"bounds":{"min":[-0.5,-0.5,-0.5],"max":[0.5,0.5,0.5]},"lods":[{"triangles":12}]}]}
{"frame":0,"camera":{"position":[1.0,1.0,1.0],"orientation":[0.0,0.0,0.0,1.0],"vertical_fov":1.0,"aspect":1.5},"events":[{"add":{"id":1,"mesh":1,"lod":0,"flags":[],"transform":[1.0,0.0,0.0,2.0,0.0,1.0,0.0,0.0,0.0,0.0,1.0,2.0],"aabb":{"min":[1.5,-0.5,1.5],"max":[2.5,0.5,2.5]}}}],"hits":[{"id":1,"hits":5}]}
{"end":{"frames":1}}
"#;

fn shard(index: u32, count: u32, scenes: usize, variants: usize) -> SweepShard {
    SweepShard {
        format: SHARD_FORMAT.into(),
        shard: Shard::new(index, count).unwrap(),
        settings: "s".into(),
        plan: SweepPlan {
            width: 8,
            height: 8,
            rays_per_frame: 64,
            scenes: (0..scenes).map(|i| i.to_string()).collect(),
            variants: (0..variants).map(|i| i.to_string()).collect(),
            skipped: Vec::new(),
            device_profile: Default::default(),
        },
        scenes: Vec::new(),
        points: Vec::new(),
        wall_s: 0.0,
    }
}

fn base64(bin: &[u8]) -> String {
    const A: &[u8] = b"ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
    let mut b64 = String::new();
    for c in bin.chunks(3) {
        let n = (u32::from(c[0]) << 16)
            | (u32::from(*c.get(1).unwrap_or(&0)) << 8)
            | u32::from(*c.get(2).unwrap_or(&0));
        for k in 0..4 {
            b64.push(if k <= c.len() {
                A[(n >> (18 - 6 * k) & 63) as usize] as char
            } else {
                '='
            });
        }
    }
    b64
}

fn one_triangle(index_count: u64) -> Vec<u8> {
    let mut bin: Vec<u8> = [0.0f32, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0]
        .iter()
        .flat_map(|v| v.to_le_bytes())
        .collect();
    bin.extend([0u16, 1, 2, 0].iter().flat_map(|v| v.to_le_bytes()));
    let b64 = base64(&bin);
    format!(
        r#"{{"asset":{{"version":"2.0"}},"scene":0,"scenes":[{{"nodes":[0]}}],"nodes":[{{"mesh":0}}],
"meshes":[{{"primitives":[{{"attributes":{{"POSITION":0}},"indices":1}}]}}],
"accessors":[{{"bufferView":0,"componentType":5126,"count":3,"type":"VEC3","min":[0,0,0],"max":[1,0,1]}},
{{"bufferView":1,"componentType":5123,"count":{index_count},"type":"SCALAR"}}],
"bufferViews":[{{"buffer":0,"byteOffset":0,"byteLength":36}},{{"buffer":0,"byteOffset":36,"byteLength":6}}],
"buffers":[{{"byteLength":44,"uri":"data:application/octet-stream;base64,{b64}"}}]}}"#
    )
    .into_bytes()
}

/// `vertices` positions (a fan of triangles in the x/z plane), as
/// (buffer, its base64).
fn positions(vertices: usize) -> (Vec<u8>, String) {
    let bin: Vec<u8> = (0..vertices)
        .flat_map(|i| [i as f32, 0.0, (i % 7) as f32])
        .flat_map(|v| v.to_le_bytes())
        .collect();
    let b64 = base64(&bin);
    (bin, b64)
}

/// One mesh of `primitives` primitives all reading the same accessor of
/// 100,000 positions (1.2 MB): 200 copies are 240 MB.
fn shared_accessor(primitives: usize) -> Vec<u8> {
    let n = 100_000;
    let (bin, b64) = positions(n);
    let prims = vec![r#"{"attributes":{"POSITION":0}}"#; primitives].join(",");
    format!(
        r#"{{"asset":{{"version":"2.0"}},"scene":0,"scenes":[{{"nodes":[0]}}],"nodes":[{{"mesh":0}}],
"meshes":[{{"primitives":[{prims}]}}],
"accessors":[{{"bufferView":0,"componentType":5126,"count":{n},"type":"VEC3","min":[0,0,0],"max":[{},0,6]}}],
"bufferViews":[{{"buffer":0,"byteLength":{}}}],
"buffers":[{{"byteLength":{},"uri":"data:application/octet-stream;base64,{b64}"}}]}}"#,
        n - 1,
        bin.len(),
        bin.len()
    )
    .into_bytes()
}

/// A chain of 200 nodes, each named with 4000 bytes, whose last node
/// places a triangle 100,000 times through EXT_mesh_gpu_instancing: names
/// copied per instance would be 80 GB.
fn deep_instancing() -> Vec<u8> {
    let depth = 200;
    let n = 100_000;
    let (mut bin, _) = positions(n);
    let tri_at = bin.len();
    bin.extend(
        [0.0f32, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0]
            .iter()
            .flat_map(|v| v.to_le_bytes()),
    );
    let b64 = base64(&bin);
    let long = "x".repeat(4000);
    let nodes: Vec<String> = (0..depth)
        .map(|i| {
            if i + 1 < depth {
                format!(r#"{{"name":"n{i}{long}","children":[{}]}}"#, i + 1)
            } else {
                format!(
                    r#"{{"name":"leaf{long}","mesh":0,"extensions":{{"EXT_mesh_gpu_instancing":{{"attributes":{{"TRANSLATION":0}}}}}}}}"#
                )
            }
        })
        .collect();
    format!(
        r#"{{"asset":{{"version":"2.0"}},"extensionsUsed":["EXT_mesh_gpu_instancing"],"scene":0,"scenes":[{{"nodes":[0]}}],
"nodes":[{}],
"meshes":[{{"primitives":[{{"attributes":{{"POSITION":1}}}}]}}],
"accessors":[{{"bufferView":0,"componentType":5126,"count":{n},"type":"VEC3"}},
{{"bufferView":1,"componentType":5126,"count":3,"type":"VEC3","min":[0,0,0],"max":[1,0,1]}}],
"bufferViews":[{{"buffer":0,"byteLength":{tri_at}}},{{"buffer":0,"byteOffset":{tri_at},"byteLength":36}}],
"buffers":[{{"byteLength":{},"uri":"data:application/octet-stream;base64,{b64}"}}]}}"#,
        nodes.join(","),
        bin.len()
    )
    .into_bytes()
}

/// Runs one case (in the child process the test starts).
fn run_case(case: &str) {
    match case {
        "replay-declared-grid" => {
            let dir = scratch(case);
            let path = dir.join("big.jsonl");
            std::fs::write(&path, BIG_GRID).unwrap();
            let config = ReplayConfig {
                width: 16,
                height: 9,
                threads: 1,
                ..ReplayConfig::default()
            };
            let (report, _) = within(32 * MIB, || {
                replay_path(&path, &config, &TraceSceneOptions::default(), &mut |_| {})
            })
            .unwrap();
            // The figures are the dense grid's: every declared cell's
            // hitbox record counted (12 B each) in LiPaC's memory.
            let lipac = report.strategy("lipac").unwrap();
            assert!(lipac.summary.mean_mib > 190.0, "{}", lipac.summary.mean_mib);
            let _ = std::fs::remove_dir_all(&dir);
        }
        "merge-shard-count" => {
            let dir = scratch(case);
            let path = dir.join("sweep-shard-1-of-4294967295.json");
            std::fs::write(
                &path,
                serde_json::to_string(&shard(1, u32::MAX, 1, 1)).unwrap(),
            )
            .unwrap();
            let e = within(MIB, || {
                let shards = read_shards(std::slice::from_ref(&path)).unwrap();
                merge(&shards).unwrap_err()
            });
            assert!(e.to_string().contains("4294967295"), "{e}");
            let _ = std::fs::remove_dir_all(&dir);
        }
        "merge-plan-size" => {
            let shards = vec![shard(1, 1, 10_000, 10_000)];
            let e = within(MIB, || merge(&shards).unwrap_err());
            assert!(e.to_string().contains("10000 scenes x 10000"), "{e}");
        }
        "gltf-index-count" => {
            let bytes = one_triangle(1 << 40);
            let config = ImportConfig {
                frames: 1,
                ..ImportConfig::default()
            };
            let e = within(MIB, || import_gltf(&bytes, None, "t", &config).unwrap_err());
            assert!(e.to_string().contains("overrun"), "{e}");
        }
        "gltf-shared-accessor" => {
            let bytes = shared_accessor(200);
            let config = ImportConfig {
                frames: 1,
                ..ImportConfig::default()
            };
            let e = within(48 * MIB, || {
                import_gltf(&bytes, None, "t", &config).unwrap_err()
            });
            assert!(e.to_string().contains("bytes of geometry"), "{e}");
        }
        "gltf-deep-instancing" => {
            let bytes = deep_instancing();
            let config = ImportConfig {
                frames: 1,
                ..ImportConfig::default()
            };
            // Instances and their frame-0 events (~300 B each), not their
            // names.
            let im = within(96 * MIB, || {
                import_gltf(&bytes, None, "t", &config).unwrap()
            });
            assert_eq!(im.summary.instances, 100_000);
        }
        "import-frames" => {
            let bytes = one_triangle(3);
            let config = ImportConfig {
                frames: u32::MAX,
                ..ImportConfig::default()
            };
            let n = within(4 * MIB, || {
                let im = import_gltf(&bytes, None, "t", &config).unwrap();
                im.frames().take(100).count()
            });
            assert_eq!(n, 100);
        }
        other => panic!("unknown case {other}"),
    }
    println!("{case}: ok");
}

const CASE_VAR: &str = "LIPAC_INPUT_MEMORY_CASE";

/// Each case runs in a child process of this test binary, so that an
/// allocation past the budget (which aborts) fails the test cleanly and no
/// other test's allocations are counted.
#[test]
fn inputs_cost_what_they_carry() {
    if let Ok(case) = std::env::var(CASE_VAR) {
        run_case(&case);
        return;
    }
    let mut failed = Vec::new();
    for case in [
        "replay-declared-grid",
        "merge-shard-count",
        "merge-plan-size",
        "gltf-index-count",
        "gltf-shared-accessor",
        "gltf-deep-instancing",
        "import-frames",
    ] {
        let out = std::process::Command::new(std::env::current_exe().unwrap())
            .args([
                "--exact",
                "inputs_cost_what_they_carry",
                "--nocapture",
                "--test-threads=1",
            ])
            .env(CASE_VAR, case)
            .env("RUST_BACKTRACE", "0")
            .output()
            .unwrap();
        let text = format!(
            "{}{}",
            String::from_utf8_lossy(&out.stdout),
            String::from_utf8_lossy(&out.stderr)
        );
        if !(out.status.success() && text.contains(&format!("{case}: ok"))) {
            failed.push(format!(
                "case {case} failed or went past its memory budget ({:?}):\n{text}",
                out.status
            ));
        }
    }
    assert!(failed.is_empty(), "{}", failed.join("\n"));
}
