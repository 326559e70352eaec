//! `lipac record`, `lipac replay` and `lipac convert`: recorded instance
//! traces on the command line (logic in `lipac_sim::record` and
//! `lipac_sim::replay`).

use std::path::{Path, PathBuf};
use std::process::ExitCode;

use clap::{Args, ValueEnum};
use lipac_core::trace::{binary_to_jsonl, jsonl_to_binary, TraceFormat, TraceLimits};
use lipac_sim::compare::{check_image_size, LipacStart};
use lipac_sim::record::{record, CameraChoice, RecordConfig};
use lipac_sim::replay::{ReplayConfig, ReplayMode};
use lipac_sim::report::{headline, table, write_report_with_snapshots};
use lipac_sim::trace_scene::{replay_path, replay_stream, TraceSceneOptions};
use lipac_sim::SimError;

use crate::output::{check_not_input, check_out_dir, io_err, open_input, publish_dir, OutputFile};
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
    /// The trace (binary or JSON lines, detected; `-` = standard input).
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
    /// Worker threads: strategies, image rows and BLAS refits (0 = all cores).
    #[arg(long, default_value_t = 0)]
    threads: usize,
    /// Report folder.
    #[arg(long, default_value = "lipac-report")]
    out: PathBuf,
    /// Frame numbers to take pictures of, as `lipac compare --snapshots`
    /// (geometry mode only).
    #[arg(long, value_delimiter = ',')]
    snapshots: Vec<u32>,
    /// Keep every frame's metrics in the report (hits-only mode: the
    /// per-frame plots and frames.csv). Without it the summaries still cover
    /// every frame and memory does not grow with the trace's length.
    #[arg(long)]
    keep_frames: bool,
    /// LiPaC's start (geometry mode): `off` for the paper's cold start, or
    /// `DIST:SIZE[:RADIUS]` for a warm start at the first frame (as `lipac
    /// compare --warm-start`). Default: LiPaC's configured start (the whole
    /// view and 800 m around the camera).
    #[arg(long)]
    warm_start: Option<String>,
    /// Geometry mode: LiPaC warm-starts again at each camera cut (as
    /// `lipac compare --warm-start-at-cuts`). A trace does not mark its
    /// cuts: a frame whose camera moved more than 100 m or turned more
    /// than 90° since the last one is taken for a cut.
    #[arg(long)]
    warm_start_at_cuts: bool,
    /// Geometry mode: frames without a hit that LiPaC holds what a warm
    /// start activates (as `lipac compare --warm-start-hold`).
    #[arg(long)]
    warm_start_hold: Option<u32>,
    /// A device profile for the memory axis and the modelled GPU time (as
    /// `lipac compare --device-profile`).
    #[arg(long, value_name = "FILE")]
    device_profile: Option<PathBuf>,
    #[command(flatten)]
    scene: TraceSceneArgs,
}

/// How a trace of another scene than the built-in ones is traced
/// (`lipac replay`, `lipac sweep --trace`).
#[derive(Args)]
pub struct TraceSceneArgs {
    /// Geometry mode of a trace of another scene: trace a box over the
    /// bounds of a mesh without geometry instead of failing.
    #[arg(long)]
    box_proxy: bool,
    /// Geometry mode of a trace of another scene: trace vegetation opaque
    /// (default: alpha-tested with the built-in trees' leaf pattern).
    #[arg(long)]
    no_vegetation_alpha: bool,
    /// Geometry mode of a trace of another scene: a JSON scene file
    /// overriding sun and sky, vegetation alpha and box proxies (see
    /// docs/trace-format.md); the flags above win over it.
    #[arg(long)]
    scene_file: Option<PathBuf>,
}

/// `lipac convert`.
#[derive(Args)]
pub struct ConvertArgs {
    /// Input trace (encoding detected; `-` = standard input).
    input: PathBuf,
    /// Output trace (the other encoding); written beside, then renamed into
    /// place; never the input.
    output: PathBuf,
}

fn fail(e: impl std::fmt::Display) -> ExitCode {
    eprintln!("lipac: {e}");
    ExitCode::FAILURE
}

pub fn run_record(a: RecordArgs) -> ExitCode {
    match record_main(&a) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => fail(e),
    }
}

fn record_main(a: &RecordArgs) -> Result<(), String> {
    // Arguments first: nothing is created for a command that cannot run.
    if a.frames == Some(0) {
        return Err("--frames 0: nothing to record (give at least 1)".into());
    }
    check_image_size(a.width, a.height).map_err(|e| e.to_string())?;
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
        aspect: a.width as f32 / a.height as f32,
        geometry: a.geometry,
    };
    let mut out = OutputFile::create(&a.out, &[])?;
    let (_, s) = record(&config, format, out.writer()).map_err(|e| e.to_string())?;
    out.commit()?;
    println!(
        "{} frames, {} instances, {} updates -> {}",
        s.frames,
        s.instances,
        s.updates,
        a.out.display()
    );
    Ok(())
}

pub fn run_replay(a: ReplayArgs) -> ExitCode {
    match replay_main(&a) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => fail(e),
    }
}

fn replay_main(a: &ReplayArgs) -> Result<(), String> {
    check_image_size(a.width, a.height).map_err(|e| e.to_string())?;
    // The report folder must not be (or hold) the trace: checked before
    // the (possibly long) replay.
    let mut inputs: Vec<&Path> = vec![&a.file];
    inputs.extend(a.device_profile.as_deref());
    check_out_dir(&a.out, &inputs)?;
    let config = ReplayConfig {
        strategies: a.strategies.iter().map(|&s| s.into()).collect(),
        width: a.width,
        height: a.height,
        threads: a.threads,
        mode: a.mode.map(|m| match m {
            ModeArg::Geometry => ReplayMode::Geometry,
            ModeArg::HitsOnly => ReplayMode::HitsOnly,
        }),
        keep_frames: a.keep_frames,
        snapshots: a.snapshots.clone(),
        lipac_start: match a.warm_start.as_deref() {
            None => LipacStart::Default,
            Some(spec) => LipacStart::parse(spec).map_err(|e| format!("--warm-start: {e}"))?,
        },
        warm_start_at_cuts: a.warm_start_at_cuts,
        warm_start_hold: a.warm_start_hold,
        lipac_variants: Vec::new(),
        hindsight_variants: Vec::new(),
        device: lipac_sim::device_profile::DeviceProfile::load_or_builtin(
            a.device_profile.as_deref(),
        )
        .map_err(|e| e.to_string())?,
    };
    let at_file = |e: SimError| format!("{}: {e}", a.file.display());
    let regular_file = std::fs::metadata(&a.file).is_ok_and(|m| m.is_file());
    let options = trace_scene_options(&a.scene).map_err(|e| e.to_string())?;
    let (report, snapshots) = if regular_file {
        // A file can be read twice: traces of other scenes replay with
        // geometry (lipac_sim::trace_scene).
        replay_path(&a.file, &config, &options, &mut |_| {}).map_err(at_file)?
    } else {
        // Standard input or a pipe: read once (a trace of another scene in
        // geometry mode is spooled to a temporary file for its second pass).
        replay_stream(open_input(&a.file)?, &config, &options, &mut |_| {}).map_err(at_file)?
    };
    print!("{}", table(&report));
    if let Some(h) = headline(&report) {
        print!("{h}");
    }
    let mut inputs: Vec<&std::path::Path> = vec![&a.file];
    inputs.extend(a.device_profile.as_deref());
    publish_dir(&a.out, &inputs, |dir| {
        write_report_with_snapshots(&report, &snapshots, dir)
            .map_err(|e| format!("writing the report: {e}"))
    })?;
    println!(
        "{} frames replayed in {:.1} s; report in {}/report.md",
        report.frames,
        report.wall_s,
        a.out.display()
    );
    Ok(())
}

/// The scene file's options (if any), then the flags.
pub fn trace_scene_options(a: &TraceSceneArgs) -> Result<TraceSceneOptions, SimError> {
    let mut o = TraceSceneOptions::default();
    if let Some(p) = a.scene_file.as_deref() {
        o = o.with_json(&std::fs::read_to_string(p).map_err(|e| SimError::Io(io_err(p, e)))?)?;
    }
    o.box_proxy |= a.box_proxy;
    if a.no_vegetation_alpha {
        o.vegetation_alpha = false;
    }
    Ok(o)
}

pub fn run_convert(a: ConvertArgs) -> ExitCode {
    match convert_main(&a) {
        Ok(from) => {
            let to = match from {
                TraceFormat::Binary => "JSON lines",
                TraceFormat::Jsonl => "binary",
            };
            println!("{} -> {} ({to})", a.input.display(), a.output.display());
            ExitCode::SUCCESS
        }
        Err(e) => fail(e),
    }
}

fn convert_main(a: &ConvertArgs) -> Result<TraceFormat, String> {
    // Refused before anything is opened for writing: converting a file onto
    // itself would truncate it before it is read.
    check_not_input(&a.output, &[&a.input])?;
    let input = open_input(&a.input)?;
    let (from, input) = TraceFormat::detect_stream(input).map_err(|e| io_err(&a.input, e))?;
    let from = from.ok_or_else(|| {
        format!(
            "{}: neither a binary trace nor JSON lines",
            a.input.display()
        )
    })?;
    let mut out = OutputFile::create(&a.output, &[&a.input])?;
    let limits = TraceLimits::default();
    match from {
        TraceFormat::Binary => binary_to_jsonl(input, out.writer(), limits).map(|_| ()),
        TraceFormat::Jsonl => jsonl_to_binary(input, out.writer(), limits).map(|_| ()),
    }
    .map_err(|e| format!("{}: {e}", a.input.display()))?;
    out.commit()?;
    Ok(from)
}
