//! `lipac record`, `lipac replay` and `lipac convert`: recorded instance
//! traces on the command line (logic in `lipac_sim::record` and
//! `lipac_sim::replay`).

use std::fs::File;
use std::io::{BufReader, BufWriter, Read, Write};
use std::path::{Path, PathBuf};
use std::process::ExitCode;

use clap::{Args, ValueEnum};
use lipac_core::trace::{binary_to_jsonl, jsonl_to_binary, TraceFormat, TraceLimits};
use lipac_sim::record::{record, CameraChoice, RecordConfig};
use lipac_sim::replay::{ReplayConfig, ReplayMode};
use lipac_sim::report::{headline, table, write_report_with_snapshots};
use lipac_sim::trace_scene::{replay_path, TraceSceneOptions};
use lipac_sim::SimError;

use crate::{SceneArg, StrategyArg};

#[derive(Clone, Copy, ValueEnum)]
pub enum CameraArg {
    Flythrough,
    Jump,
    Static,
}

#[derive(Clone, Copy, ValueEnum)]
pub enum FormatArg {
    Binary,
    Jsonl,
}

#[derive(Clone, Copy, ValueEnum)]
pub enum ModeArg {
    Geometry,
    HitsOnly,
}

/// `lipac record`.
#[derive(Args)]
pub struct RecordArgs {
    /// Scene.
    #[arg(long, value_enum, default_value = "city")]
    scene: SceneArg,
    /// Camera path.
    #[arg(long, value_enum, default_value = "flythrough")]
    camera: CameraArg,
    /// Frames (default: the whole path).
    #[arg(long)]
    frames: Option<u32>,
    /// Scene seed (default: the scene's own).
    #[arg(long)]
    seed: Option<u64>,
    /// Write the meshes' triangles into the header.
    #[arg(long)]
    geometry: bool,
    /// Encoding (default: from OUT's extension, `.jsonl` = JSON lines, else binary).
    #[arg(long, value_enum)]
    format: Option<FormatArg>,
    /// Image width the camera's aspect is for.
    #[arg(long, default_value_t = 128)]
    width: u32,
    /// Image height the camera's aspect is for.
    #[arg(long, default_value_t = 72)]
    height: u32,
    /// Output file.
    out: PathBuf,
}

/// `lipac replay`.
#[derive(Args)]
pub struct ReplayArgs {
    /// The trace (binary or JSON lines, detected).
    file: PathBuf,
    /// Strategies (default: every one the mode supports).
    #[arg(long, value_enum, value_delimiter = ',')]
    strategies: Vec<StrategyArg>,
    /// Mode (default: geometry for traces of built-in scenes, else hits only).
    #[arg(long, value_enum)]
    mode: Option<ModeArg>,
    /// Image width.
    #[arg(long, default_value_t = 128)]
    width: u32,
    /// Image height.
    #[arg(long, default_value_t = 72)]
    height: u32,
    /// Render threads (0 = all cores).
    #[arg(long, default_value_t = 0)]
    threads: usize,
    /// Report folder.
    #[arg(long, default_value = "lipac-report")]
    out: PathBuf,
    /// Frame numbers to take pictures of, as `lipac compare --snapshots`
    /// (geometry mode only).
    #[arg(long, value_delimiter = ',')]
    snapshots: Vec<u32>,
    /// Geometry mode of a trace of another scene: trace a box over the
    /// bounds of a mesh without geometry instead of failing.
    #[arg(long)]
    box_proxy: bool,
    /// Geometry mode of a trace of another scene: a JSON scene file
    /// overriding sun and sky (see docs/trace-format.md).
    #[arg(long)]
    scene_file: Option<PathBuf>,
}

/// `lipac convert`.
#[derive(Args)]
pub struct ConvertArgs {
    /// Input trace (encoding detected).
    input: PathBuf,
    /// Output trace (the other encoding).
    output: PathBuf,
}

fn fail(e: impl std::fmt::Display) -> ExitCode {
    eprintln!("lipac: {e}");
    ExitCode::FAILURE
}

fn io_at(path: &Path) -> impl Fn(std::io::Error) -> SimError + '_ {
    move |e| SimError::Io(format!("{}: {e}", path.display()))
}

pub fn run_record(a: RecordArgs) -> ExitCode {
    let format = match a.format {
        Some(FormatArg::Binary) => TraceFormat::Binary,
        Some(FormatArg::Jsonl) => TraceFormat::Jsonl,
        None if a.out.extension().is_some_and(|e| e == "jsonl") => TraceFormat::Jsonl,
        None => TraceFormat::Binary,
    };
    let config = RecordConfig {
        scene: a.scene.into(),
        seed: a.seed,
        camera: match a.camera {
            CameraArg::Flythrough => CameraChoice::Flythrough,
            CameraArg::Jump => CameraChoice::Jump,
            CameraArg::Static => CameraChoice::Static,
        },
        frames: a.frames,
        aspect: a.width as f32 / a.height.max(1) as f32,
        geometry: a.geometry,
    };
    let result = File::create(&a.out)
        .map_err(io_at(&a.out))
        .and_then(|f| record(&config, format, BufWriter::new(f)))
        .and_then(|(mut w, s)| {
            w.flush().map_err(io_at(&a.out))?;
            Ok(s)
        });
    match result {
        Ok(s) => {
            println!(
                "{} frames, {} instances, {} updates -> {}",
                s.frames,
                s.instances,
                s.updates,
                a.out.display()
            );
            ExitCode::SUCCESS
        }
        Err(e) => fail(e),
    }
}

pub fn run_replay(a: ReplayArgs) -> ExitCode {
    let config = ReplayConfig {
        strategies: a.strategies.into_iter().map(Into::into).collect(),
        width: a.width,
        height: a.height,
        threads: a.threads,
        mode: a.mode.map(|m| match m {
            ModeArg::Geometry => ReplayMode::Geometry,
            ModeArg::HitsOnly => ReplayMode::HitsOnly,
        }),
        keep_frames: true,
        snapshots: a.snapshots,
    };
    let options = match trace_scene_options(a.box_proxy, a.scene_file.as_deref()) {
        Ok(o) => o,
        Err(e) => return fail(e),
    };
    let (report, snapshots) = match replay_path(&a.file, &config, &options, &mut |_| {}) {
        Ok(r) => r,
        Err(e) => return fail(format_args!("{}: {e}", a.file.display())),
    };
    print!("{}", table(&report));
    if let Some(h) = headline(&report) {
        print!("{h}");
    }
    match write_report_with_snapshots(&report, &snapshots, &a.out) {
        Ok(_) => {
            println!(
                "{} frames replayed in {:.1} s; report in {}/report.md",
                report.frames,
                report.wall_s,
                a.out.display()
            );
            ExitCode::SUCCESS
        }
        Err(e) => fail(format_args!("writing the report: {e}")),
    }
}

fn trace_scene_options(
    box_proxy: bool,
    scene_file: Option<&Path>,
) -> Result<TraceSceneOptions, SimError> {
    let o = TraceSceneOptions {
        box_proxy,
        ..TraceSceneOptions::default()
    };
    match scene_file {
        None => Ok(o),
        Some(p) => o.with_json(&std::fs::read_to_string(p).map_err(io_at(p))?),
    }
}

pub fn run_convert(a: ConvertArgs) -> ExitCode {
    let result = (|| -> Result<TraceFormat, SimError> {
        let mut prefix = Vec::new();
        File::open(&a.input)
            .map_err(io_at(&a.input))?
            .take(64)
            .read_to_end(&mut prefix)
            .map_err(io_at(&a.input))?;
        let from = TraceFormat::detect(&prefix).ok_or_else(|| {
            SimError::Io(format!(
                "{}: neither a binary trace nor JSON lines",
                a.input.display()
            ))
        })?;
        let input = BufReader::new(File::open(&a.input).map_err(io_at(&a.input))?);
        let output = BufWriter::new(File::create(&a.output).map_err(io_at(&a.output))?);
        let limits = TraceLimits::default();
        let mut w = match from {
            TraceFormat::Binary => binary_to_jsonl(input, output, limits),
            TraceFormat::Jsonl => jsonl_to_binary(input, output, limits),
        }
        .map_err(|e| SimError::Io(format!("{}: {e}", a.input.display())))?;
        w.flush().map_err(io_at(&a.output))?;
        Ok(from)
    })();
    match result {
        Ok(from) => {
            let to = match from {
                TraceFormat::Binary => "JSON lines",
                TraceFormat::Jsonl => "binary",
            };
            println!("{} -> {} ({to})", a.input.display(), a.output.display());
            ExitCode::SUCCESS
        }
        Err(e) => {
            // Do not leave a half-written output behind.
            let _ = std::fs::remove_file(&a.output);
            fail(e)
        }
    }
}
