//! One rule for every file a `lipac` command writes (docs/RELIABILITY.md):
//! a command that fails — bad arguments, a missing or unreadable input,
//! an input that fails half way, an output that is one of its inputs
//! (also through a link) — leaves every file that was there
//! byte-identical, and creates nothing.
//!
//! [`FILE_TABLE`] holds, per subcommand of the CLI definition, the cases
//! of each kind (or why a kind does not apply); the test takes the list of
//! subcommands from [`Cli`] itself, so a subcommand added without an entry
//! fails it. Every case runs the CLI in a child process of this test binary
//! (as the `lipac` binary does: [`Cli::try_parse_from`], then [`run`]), on
//! a folder of inputs and earlier outputs that is compared, file by file,
//! before and after. Each case names a piece of the error it must print,
//! so a case that fails for another reason than the one it is there for
//! (a mistyped flag) fails the test. Unix only (symbolic links).

#![cfg(unix)]

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::{Command as Process, Output, Stdio};

use clap::CommandFactory;

use super::*;

/// The environment variable that makes this test binary run the CLI
/// (arguments as a JSON array) instead of the table.
const CHILD_ARGS: &str = "LIPAC_FILE_TABLE_ARGS";
/// The test's own name, for the child's test filter.
const TEST_NAME: &str = "tests::every_failing_command_keeps_every_file";

/// The cases of one kind: command lines (relative paths resolve in the
/// fixture folder) each with a piece of the error it must print, or why
/// the kind does not apply to the command.
enum Cases {
    Run(&'static [(&'static [&'static str], &'static str)]),
    NotApplicable(&'static str),
}

/// The cases of one subcommand.
struct Entry {
    command: &'static str,
    bad_arguments: Cases,
    missing_input: Cases,
    unreadable_input: Cases,
    fails_half_way: Cases,
    output_is_input: Cases,
    output_is_input_through_a_link: Cases,
}

use Cases::{NotApplicable as Na, Run};

/// Sweep flags for a tiny sweep: one configuration and one baseline on
/// 8 x 8 pixels, one render thread.
macro_rules! tiny_sweep {
    ($($a:literal),*) => {
        &[
            "sweep", $($a,)* "--factors", "1", "--cells", "", "--streaks", "", "--latency", "",
            "--baselines", "full", "--width", "8", "--height", "8", "--threads", "1",
        ]
    };
}

/// Compare and run, as tiny: the small scene, 8 x 8 pixels, one thread
/// (`--frames 1` unless the case gives its own).
macro_rules! tiny_scene {
    ($cmd:literal, $($a:literal),*) => {
        &[$cmd, "--scene", "small", "--height", "8", "--threads", "1", $($a),*]
    };
}

const NO_INPUT: &str = "reads no file";

/// Every subcommand and its cases (the fixture's files: [`Fixture::new`]).
const FILE_TABLE: &[Entry] = &[
    Entry {
        command: "record",
        bad_arguments: Run(&[
            (
                &[
                    "record",
                    "--scene",
                    "small",
                    "--frames",
                    "0",
                    "out/keep.lipactrace",
                ],
                "--frames 0",
            ),
            (
                &[
                    "record",
                    "--scene",
                    "small",
                    "--width",
                    "0",
                    "out/keep.lipactrace",
                ],
                "0 x 72",
            ),
            // The output is a folder of the user's.
            (
                &["record", "--scene", "small", "--frames", "1", "out/report"],
                "is a folder",
            ),
        ]),
        missing_input: Na(NO_INPUT),
        unreadable_input: Na(NO_INPUT),
        fails_half_way: Na("renders a built-in scene: nothing to fail on"),
        output_is_input: Na(NO_INPUT),
        output_is_input_through_a_link: Na(NO_INPUT),
    },
    Entry {
        command: "convert",
        bad_arguments: Run(&[(&["convert", "in/small.lipactrace"], "required")]),
        missing_input: Run(&[(
            &["convert", "in/nope.lipactrace", "out/keep.jsonl"],
            "No such file",
        )]),
        unreadable_input: Run(&[(&["convert", "in", "out/keep.jsonl"], "directory")]),
        fails_half_way: Run(&[(
            &["convert", "in/half.lipactrace", "out/keep.jsonl"],
            "half.lipactrace",
        )]),
        output_is_input: Run(&[(
            &["convert", "in/small.lipactrace", "in/small.lipactrace"],
            "is the input",
        )]),
        output_is_input_through_a_link: Run(&[(
            &["convert", "in/small.lipactrace", "in/link.lipactrace"],
            "is the input",
        )]),
    },
    Entry {
        command: "import",
        bad_arguments: Run(&[
            (
                &[
                    "import",
                    "in/s.gltf",
                    "out/keep.lipactrace",
                    "--frames",
                    "0",
                ],
                "--frames 0",
            ),
            (
                &[
                    "import",
                    "in/s.gltf",
                    "out/keep.lipactrace",
                    "--height",
                    "0",
                ],
                "--height 0",
            ),
        ]),
        missing_input: Run(&[
            (
                &["import", "in/nope.gltf", "out/keep.lipactrace"],
                "No such file",
            ),
            // Its buffer file is missing.
            (
                &["import", "in/lost.gltf", "out/keep.lipactrace"],
                "lost.bin",
            ),
        ]),
        unreadable_input: Run(&[(&["import", "in", "out/keep.lipactrace"], "directory")]),
        fails_half_way: Run(&[(
            &["import", "in/overrun.gltf", "out/keep.lipactrace"],
            "overrun",
        )]),
        output_is_input: Run(&[
            (&["import", "in/s.gltf", "in/s.gltf"], "is the input"),
            // The glTF's buffer file, read after the glTF.
            (&["import", "in/x.gltf", "in/x.bin"], "is the input"),
        ]),
        output_is_input_through_a_link: Run(&[(
            &["import", "in/s.gltf", "in/gltf-link"],
            "is the input",
        )]),
    },
    Entry {
        command: "replay",
        bad_arguments: Run(&[
            (
                &[
                    "replay",
                    "in/small.lipactrace",
                    "--width",
                    "0",
                    "--out",
                    "out/report",
                ],
                "0",
            ),
            (
                &[
                    "replay",
                    "in/small.lipactrace",
                    "--warm-start",
                    "bogus",
                    "--out",
                    "out/report",
                ],
                "--warm-start",
            ),
        ]),
        missing_input: Run(&[(
            &["replay", "in/nope.lipactrace", "--out", "out/report"],
            "nope.lipactrace",
        )]),
        unreadable_input: Run(&[(&["replay", "in", "--out", "out/report"], "directory")]),
        fails_half_way: Run(&[(
            &[
                "replay",
                "in/half.lipactrace",
                "--width",
                "8",
                "--height",
                "8",
                "--threads",
                "1",
                "--out",
                "out/report",
            ],
            "half.lipactrace",
        )]),
        output_is_input: Run(&[
            (
                &[
                    "replay",
                    "in/small.lipactrace",
                    "--out",
                    "in/small.lipactrace",
                ],
                "is the input",
            ),
            // A trace named like a report file, in the report folder.
            (
                &[
                    "replay",
                    "in/r/report.json",
                    "--width",
                    "8",
                    "--height",
                    "8",
                    "--threads",
                    "1",
                    "--out",
                    "in/r",
                ],
                "is the input",
            ),
        ]),
        output_is_input_through_a_link: Run(&[(
            &[
                "replay",
                "in/small.lipactrace",
                "--out",
                "in/link.lipactrace",
            ],
            "is the input",
        )]),
    },
    Entry {
        command: "compare",
        bad_arguments: Run(&[
            (
                tiny_scene!(
                    "compare",
                    "--frames",
                    "0",
                    "--width",
                    "8",
                    "--out",
                    "out/report"
                ),
                "--frames 0",
            ),
            (
                tiny_scene!(
                    "compare",
                    "--frames",
                    "1",
                    "--width",
                    "8",
                    "--memory-budget",
                    "1e30",
                    "--out",
                    "out/report"
                ),
                "--memory-budget",
            ),
            (
                tiny_scene!(
                    "compare",
                    "--frames",
                    "1",
                    "--width",
                    "8",
                    "--warm-start",
                    "bogus",
                    "--out",
                    "out/report"
                ),
                "--warm-start",
            ),
            // The report folder is a file of the user's.
            (
                tiny_scene!(
                    "compare",
                    "--frames",
                    "1",
                    "--width",
                    "8",
                    "--strategies",
                    "full",
                    "--out",
                    "out/keep.lipactrace"
                ),
                "not a folder",
            ),
        ]),
        missing_input: Na(NO_INPUT),
        unreadable_input: Na(NO_INPUT),
        // The report cannot be written (a file where its parent folder
        // would be): found after the run.
        fails_half_way: Run(&[(
            tiny_scene!(
                "compare",
                "--frames",
                "1",
                "--width",
                "8",
                "--strategies",
                "full",
                "--out",
                "out/keep.lipactrace/report"
            ),
            "keep.lipactrace",
        )]),
        output_is_input: Na(NO_INPUT),
        output_is_input_through_a_link: Na(NO_INPUT),
    },
    Entry {
        command: "run",
        bad_arguments: Run(&[
            (
                tiny_scene!(
                    "run",
                    "--frames",
                    "1",
                    "--width",
                    "0",
                    "--out",
                    "out/report"
                ),
                "0 x 8",
            ),
            (
                tiny_scene!(
                    "run",
                    "--frames",
                    "1",
                    "--width",
                    "8",
                    "--strategy",
                    "full",
                    "--out",
                    "out/keep.lipactrace"
                ),
                "not a folder",
            ),
        ]),
        missing_input: Na(NO_INPUT),
        unreadable_input: Na(NO_INPUT),
        fails_half_way: Run(&[(
            tiny_scene!(
                "run",
                "--frames",
                "1",
                "--width",
                "8",
                "--strategy",
                "full",
                "--out",
                "out/keep.lipactrace/report"
            ),
            "keep.lipactrace",
        )]),
        output_is_input: Na(NO_INPUT),
        output_is_input_through_a_link: Na(NO_INPUT),
    },
    Entry {
        command: "sweep",
        bad_arguments: Run(&[
            (
                &[
                    "sweep",
                    "--scenes",
                    "small",
                    "--latency",
                    "50",
                    "--out",
                    "out/report",
                ],
                "--latency",
            ),
            (
                &[
                    "sweep",
                    "--scenes",
                    "small",
                    "--width",
                    "0",
                    "--out",
                    "out/report",
                ],
                "0",
            ),
            (
                &[
                    "sweep",
                    "--trace",
                    "in/small.lipactrace",
                    "--shard",
                    "3/2",
                    "--out",
                    "out/report",
                ],
                "K/N",
            ),
            (&["sweep", "--merge", "--out", "out/report"], "DIR"),
            (
                &[
                    "sweep",
                    "--merge",
                    "in/part",
                    "--shard",
                    "1/2",
                    "--out",
                    "out/report",
                ],
                "cannot be used with",
            ),
        ]),
        missing_input: Run(&[
            (
                tiny_sweep!("--trace", "in/nope.lipactrace", "--out", "out/report"),
                "nope.lipactrace",
            ),
            (
                &["sweep", "--merge", "in/nope", "--out", "out/report"],
                "nope",
            ),
            (
                &["sweep", "--replot", "in/nope.json", "--out", "out/report"],
                "nope.json",
            ),
            // A folder without shard files.
            (
                &["sweep", "--merge", "in/r", "--out", "out/report"],
                "no sweep-shard",
            ),
        ]),
        unreadable_input: Run(&[
            (tiny_sweep!("--trace", "in", "--out", "out/report"), "in"),
            (
                &["sweep", "--replot", "in", "--out", "out/report"],
                "directory",
            ),
        ]),
        fails_half_way: Run(&[
            (
                tiny_sweep!("--trace", "in/half.lipactrace", "--out", "out/report"),
                "half.lipactrace",
            ),
            (
                tiny_sweep!(
                    "--trace",
                    "in/half.lipactrace",
                    "--shard",
                    "1/2",
                    "--out",
                    "out/report"
                ),
                "half.lipactrace",
            ),
            // One shard of two.
            (
                &["sweep", "--merge", "in/one", "--out", "out/report"],
                "missing shard",
            ),
            // A shard claiming 4294967295 parts: refused, not allocated.
            (
                &["sweep", "--merge", "in/huge", "--out", "out/report"],
                "4294967295",
            ),
            (
                &[
                    "sweep",
                    "--merge",
                    "in/huge",
                    "in/part",
                    "--out",
                    "out/report",
                ],
                "4294967295",
            ),
            // A shard file cut short, a report cut short.
            (
                &["sweep", "--merge", "in/cut", "--out", "out/report"],
                "EOF",
            ),
            (
                &[
                    "sweep",
                    "--replot",
                    "in/cut/sweep.json",
                    "--out",
                    "out/report",
                ],
                "EOF",
            ),
        ]),
        output_is_input: Run(&[
            (
                tiny_sweep!(
                    "--trace",
                    "in/small.lipactrace",
                    "--out",
                    "in/small.lipactrace"
                ),
                "is the input",
            ),
            // A trace named like a sweep output, in the output folder.
            (
                tiny_sweep!("--trace", "in/sw/sweep.json", "--out", "in/sw"),
                "is the input",
            ),
            (
                &["sweep", "--merge", "in/part", "--out", "in/part"],
                "is the input",
            ),
            (
                &[
                    "sweep",
                    "--replot",
                    "in/merged/sweep.json",
                    "--out",
                    "in/merged",
                ],
                "is the input",
            ),
        ]),
        output_is_input_through_a_link: Run(&[
            (
                tiny_sweep!(
                    "--trace",
                    "in/small.lipactrace",
                    "--out",
                    "in/link.lipactrace"
                ),
                "is the input",
            ),
            (
                &["sweep", "--merge", "in/part", "--out", "in/part-link"],
                "is the input",
            ),
            (
                &[
                    "sweep",
                    "--replot",
                    "in/merged/sweep.json",
                    "--out",
                    "in/merged-link",
                ],
                "is the input",
            ),
        ]),
    },
];

/// What a folder holds: every file's bytes, every link's target, every
/// folder, by path relative to the root.
#[derive(Debug, PartialEq)]
enum Node {
    File(Vec<u8>),
    Link(PathBuf),
    Folder,
}

fn snapshot(root: &Path) -> BTreeMap<PathBuf, Node> {
    fn walk(root: &Path, rel: &Path, out: &mut BTreeMap<PathBuf, Node>) {
        for e in std::fs::read_dir(root.join(rel)).unwrap() {
            let e = e.unwrap();
            let rel = rel.join(e.file_name());
            let t = e.file_type().unwrap();
            if t.is_symlink() {
                out.insert(
                    rel.clone(),
                    Node::Link(std::fs::read_link(e.path()).unwrap()),
                );
            } else if t.is_dir() {
                out.insert(rel.clone(), Node::Folder);
                walk(root, &rel, out);
            } else {
                out.insert(rel, Node::File(std::fs::read(e.path()).unwrap()));
            }
        }
    }
    let mut out = BTreeMap::new();
    walk(root, Path::new(""), &mut out);
    out
}

/// Runs the CLI with `args` in a child process, in folder `dir`.
fn lipac(dir: &Path, args: &[&str]) -> Output {
    Process::new(std::env::current_exe().unwrap())
        .args(["--exact", TEST_NAME, "--nocapture", "--test-threads=1"])
        .env(CHILD_ARGS, serde_json::to_string(args).unwrap())
        .env("RUST_BACKTRACE", "0")
        .current_dir(dir)
        .stdin(Stdio::null())
        .output()
        .unwrap()
}

fn text(o: &Output) -> String {
    String::from_utf8_lossy(&o.stderr).into_owned()
}

/// A minimal glTF: one triangle (u16 indices claiming `index_count`), its
/// 44-byte buffer at `uri`.
fn gltf(uri: &str, index_count: u64) -> String {
    format!(
        r#"{{"asset":{{"version":"2.0"}},"scene":0,"scenes":[{{"nodes":[0]}}],"nodes":[{{"mesh":0}}],
"meshes":[{{"primitives":[{{"attributes":{{"POSITION":0}},"indices":1}}]}}],
"accessors":[{{"bufferView":0,"componentType":5126,"count":3,"type":"VEC3","min":[0,0,0],"max":[1,0,1]}},
{{"bufferView":1,"componentType":5123,"count":{index_count},"type":"SCALAR"}}],
"bufferViews":[{{"buffer":0,"byteOffset":0,"byteLength":36}},{{"buffer":0,"byteOffset":36,"byteLength":6}}],
"buffers":[{{"byteLength":44,"uri":"{uri}"}}]}}"#
    )
}

fn gltf_buffer() -> Vec<u8> {
    let mut b: Vec<u8> = [0.0f32, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0]
        .iter()
        .flat_map(|v| v.to_le_bytes())
        .collect();
    b.extend([0u16, 1, 2, 0].iter().flat_map(|v| v.to_le_bytes()));
    b
}

fn base64(bytes: &[u8]) -> String {
    const A: &[u8] = b"ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
    let mut s = String::new();
    for c in bytes.chunks(3) {
        let n = (u32::from(c[0]) << 16)
            | (u32::from(*c.get(1).unwrap_or(&0)) << 8)
            | u32::from(*c.get(2).unwrap_or(&0));
        for k in 0..4 {
            s.push(if k <= c.len() {
                A[(n >> (18 - 6 * k) & 63) as usize] as char
            } else {
                '='
            });
        }
    }
    s
}

/// The folder every case runs in: `in/` the inputs, `out/` earlier outputs
/// of the user's.
struct Fixture {
    dir: PathBuf,
}

impl Fixture {
    fn new() -> Self {
        let dir = std::env::temp_dir().join(format!("lipac-file-table-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        for d in ["in/r", "in/sw", "in/one", "in/cut", "in/huge", "out/report"] {
            std::fs::create_dir_all(dir.join(d)).unwrap();
        }
        let ok = |o: Output| assert!(o.status.success(), "fixture: {}", text(&o));
        // A trace of the small scene, and the same cut 5 bytes short.
        ok(lipac(
            &dir,
            &[
                "record",
                "--scene",
                "small",
                "--frames",
                "2",
                "--width",
                "8",
                "--height",
                "8",
                "in/small.lipactrace",
            ],
        ));
        let trace = std::fs::read(dir.join("in/small.lipactrace")).unwrap();
        std::fs::write(dir.join("in/half.lipactrace"), &trace[..trace.len() - 5]).unwrap();
        std::fs::write(dir.join("in/r/report.json"), &trace).unwrap();
        std::fs::write(dir.join("in/sw/sweep.json"), &trace).unwrap();
        std::os::unix::fs::symlink("small.lipactrace", dir.join("in/link.lipactrace")).unwrap();
        // Both shards of a sweep of the trace and their merged report;
        // shard 1 alone, claiming 4294967295 parts, and cut short; the
        // report cut short.
        for k in ["1/2", "2/2"] {
            let mut shard: Vec<&str> = tiny_sweep!("--trace", "in/small.lipactrace").to_vec();
            shard.extend(["--shard", k, "--out", "in/part"]);
            ok(lipac(&dir, &shard));
        }
        ok(lipac(
            &dir,
            &["sweep", "--merge", "in/part", "--out", "in/merged"],
        ));
        let json = std::fs::read_to_string(dir.join("in/part/sweep-shard-1-of-2.json")).unwrap();
        std::fs::write(dir.join("in/one/sweep-shard-1-of-2.json"), &json).unwrap();
        let huge = json.replacen(r#""count":2"#, r#""count":4294967295"#, 1);
        assert_ne!(huge, json, "the shard file names its count");
        std::fs::write(dir.join("in/huge/sweep-shard-1-of-2.json"), huge).unwrap();
        std::fs::write(
            dir.join("in/cut/sweep-shard-1-of-2.json"),
            &json[..json.len() / 2],
        )
        .unwrap();
        let report = std::fs::read_to_string(dir.join("in/merged/sweep.json")).unwrap();
        std::fs::write(dir.join("in/cut/sweep.json"), &report[..report.len() / 2]).unwrap();
        std::os::unix::fs::symlink("part", dir.join("in/part-link")).unwrap();
        std::os::unix::fs::symlink("merged", dir.join("in/merged-link")).unwrap();
        // glTF files: embedded, with a buffer file, with a lost buffer
        // file, and an index accessor of 2^40 indices in its 6-byte view.
        let bin = gltf_buffer();
        let embedded = format!("data:application/octet-stream;base64,{}", base64(&bin));
        std::fs::write(dir.join("in/s.gltf"), gltf(&embedded, 3)).unwrap();
        std::fs::write(dir.join("in/x.gltf"), gltf("x.bin", 3)).unwrap();
        std::fs::write(dir.join("in/x.bin"), &bin).unwrap();
        std::fs::write(dir.join("in/lost.gltf"), gltf("lost.bin", 3)).unwrap();
        std::fs::write(dir.join("in/overrun.gltf"), gltf(&embedded, 1 << 40)).unwrap();
        std::os::unix::fs::symlink("s.gltf", dir.join("in/gltf-link")).unwrap();
        // Earlier outputs of the user's.
        std::fs::write(dir.join("out/keep.lipactrace"), b"KEEP trace").unwrap();
        std::fs::write(dir.join("out/keep.jsonl"), b"KEEP jsonl").unwrap();
        std::fs::write(dir.join("out/report/report.md"), b"KEEP report").unwrap();
        Self { dir }
    }
}

impl Drop for Fixture {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.dir);
    }
}

/// The CLI in this process, when the table runs it as a child: parsed as
/// the binary parses it, run, and the process ends with its status.
fn child(args: &str) -> ! {
    let args: Vec<String> = serde_json::from_str(args).expect("arguments as a JSON array");
    let cli = Cli::try_parse_from(std::iter::once("lipac".to_string()).chain(args))
        .unwrap_or_else(|e| e.exit());
    let code = run(cli);
    std::process::exit(if code == ExitCode::SUCCESS { 0 } else { 1 })
}

#[test]
fn every_failing_command_keeps_every_file() {
    if let Ok(args) = std::env::var(CHILD_ARGS) {
        child(&args);
    }
    // Every subcommand of the CLI definition has an entry, and only those.
    let commands: Vec<String> = Cli::command()
        .get_subcommands()
        .map(|c| c.get_name().to_string())
        .filter(|n| n != "help")
        .collect();
    let table: Vec<&str> = FILE_TABLE.iter().map(|e| e.command).collect();
    for c in &commands {
        assert!(
            table.contains(&c.as_str()),
            "`lipac {c}` has no entry in FILE_TABLE: add its cases (or say why a kind does not apply)"
        );
    }
    for t in &table {
        assert!(
            commands.iter().any(|c| c == t),
            "FILE_TABLE names `{t}`, which the CLI does not have"
        );
    }
    // The sweep's other modes have their rows.
    let sweep_rows: Vec<&[&str]> = FILE_TABLE
        .iter()
        .filter(|e| e.command == "sweep")
        .flat_map(|e| {
            [
                &e.bad_arguments,
                &e.missing_input,
                &e.unreadable_input,
                &e.fails_half_way,
                &e.output_is_input,
                &e.output_is_input_through_a_link,
            ]
        })
        .filter_map(|c| match c {
            Run(cases) => Some(cases.iter().map(|(a, _)| *a)),
            Na(_) => None,
        })
        .flatten()
        .collect();
    for mode in ["--merge", "--replot", "--shard", "--trace"] {
        assert!(
            sweep_rows.iter().filter(|a| a.contains(&mode)).count() >= 2,
            "sweep {mode} has too few cases"
        );
    }

    let mut fx = Fixture::new();
    let mut ran = 0;
    let mut failures = Vec::new();
    for e in FILE_TABLE {
        let kinds = [
            ("bad arguments", &e.bad_arguments),
            ("missing input", &e.missing_input),
            ("unreadable input", &e.unreadable_input),
            ("fails half way", &e.fails_half_way),
            ("output is the input", &e.output_is_input),
            (
                "output is the input through a link",
                &e.output_is_input_through_a_link,
            ),
        ];
        for (kind, cases) in kinds {
            let cases = match cases {
                Run(c) => *c,
                Na(why) => {
                    assert!(
                        !why.is_empty(),
                        "{}: say why {kind} does not apply",
                        e.command
                    );
                    continue;
                }
            };
            assert!(!cases.is_empty(), "{} {kind}: no case", e.command);
            for (args, expect) in cases {
                let before = snapshot(&fx.dir);
                let o = lipac(&fx.dir, args);
                let err = text(&o);
                let line = format!("lipac {} ({kind})", args.join(" "));
                if o.status.success() {
                    failures.push(format!("{line} succeeded:\n{err}"));
                } else if o.status.code().is_none() {
                    // Refused with an error, not killed by a signal.
                    failures.push(format!("{line} died: {:?}\n{err}", o.status));
                } else if !err.contains(expect) {
                    failures.push(format!("{line}: the error does not say {expect:?}:\n{err}"));
                }
                let after = snapshot(&fx.dir);
                if before != after {
                    let changed: Vec<_> = before
                        .keys()
                        .chain(after.keys())
                        .filter(|k| before.get(*k) != after.get(*k))
                        .collect();
                    failures.push(format!("{line} changed {changed:?}:\n{err}"));
                    // The next case starts from the files as they were.
                    drop(fx);
                    fx = Fixture::new();
                }
                ran += 1;
            }
        }
    }
    assert!(failures.is_empty(), "{}", failures.join("\n"));
    assert!(ran >= 40, "{ran} cases ran");
}
