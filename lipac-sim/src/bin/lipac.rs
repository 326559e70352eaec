//! `lipac`: culling strategies compared on the CPU laboratory.
//!
//! ```text
//! cargo run --release -p lipac-sim --bin lipac -- compare
//! cargo run --release -p lipac-sim --bin lipac -- run --strategy lipac --scene small
//! cargo run --release -p lipac-sim --bin lipac -- record --scene small --frames 60 small.lipactrace
//! cargo run --release -p lipac-sim --bin lipac -- replay small.lipactrace
//! cargo run --release -p lipac-sim --bin lipac -- sweep --frames 60
//! cargo run --release -p lipac-sim --bin lipac -- sweep --frames 60 --shard 2/3 --out part-2
//! cargo run --release -p lipac-sim --bin lipac -- sweep --merge part-1 part-2 part-3
//! ```

#[path = "../cli/import_cmd.rs"]
mod import_cmd;
#[path = "../cli/output.rs"]
mod output;
#[path = "../cli/trace_cmds.rs"]
mod trace_cmds;

use std::path::{Path, PathBuf};
use std::process::ExitCode;

use clap::{Parser, Subcommand, ValueEnum};
use indicatif::{ProgressBar, ProgressStyle};
use lipac_sim::closed_loop::{self, ClosedLoopOptions, ClosedLoopPath};
use lipac_sim::compare::{
    check_image_size, run_choice_with_snapshots, CompareConfig, LipacStart, SceneChoice,
};
use lipac_sim::device_profile::DeviceProfile;
use lipac_sim::heuristic_arg::parse_heuristic;
use lipac_sim::report::{headline, table, write_report_with_snapshots};
use lipac_sim::strategy::lipac::LipacConfig;
use lipac_sim::strategy::StrategyKind;
use lipac_sim::sweep::{self, SweepConfig};

#[derive(Parser)]
#[command(
    name = "lipac",
    version,
    about = "LiPaC culling strategies compared on a CPU path tracer"
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Clone, Copy, ValueEnum)]
enum SceneArg {
    City,
    Small,
    Mirror,
    /// The paper-scale city: ~120k instances, 8,000 units, half the
    /// buildings fitted to the terrain (about 2.5 minutes on 2 cores).
    PaperCity,
}

impl From<SceneArg> for SceneChoice {
    fn from(s: SceneArg) -> Self {
        match s {
            SceneArg::City => SceneChoice::City,
            SceneArg::Small => SceneChoice::Small,
            SceneArg::Mirror => SceneChoice::Mirror,
            SceneArg::PaperCity => SceneChoice::PaperCity,
        }
    }
}

#[derive(Clone, Copy, ValueEnum)]
enum StrategyArg {
    Full,
    Frustum,
    Heuristic,
    Lipac,
    LipacLatency,
    Oracle,
    Hindsight,
}

impl From<StrategyArg> for StrategyKind {
    fn from(s: StrategyArg) -> Self {
        match s {
            StrategyArg::Full => StrategyKind::Full,
            StrategyArg::Frustum => StrategyKind::Frustum,
            StrategyArg::Heuristic => StrategyKind::Heuristic,
            StrategyArg::Lipac => StrategyKind::Lipac,
            StrategyArg::LipacLatency => StrategyKind::LipacLatency,
            StrategyArg::Oracle => StrategyKind::Oracle,
            StrategyArg::Hindsight => StrategyKind::Hindsight,
        }
    }
}

#[derive(clap::Args)]
struct Common {
    /// Frames to render (default: the whole fly-through, 270).
    #[arg(long)]
    frames: Option<u32>,
    /// Image width.
    #[arg(long, default_value_t = 128)]
    width: u32,
    /// Image height.
    #[arg(long, default_value_t = 72)]
    height: u32,
    /// Scene.
    #[arg(long, value_enum, default_value = "city")]
    scene: SceneArg,
    /// Scene seed (default: the scene's own).
    #[arg(long)]
    seed: Option<u64>,
    /// Worker threads: strategies, image rows and BLAS refits (0 = all cores).
    #[arg(long, default_value_t = 0)]
    threads: usize,
    /// LiPaC's adaptive hitboxes: merge levels of cold hitboxes into one
    /// counting box (0 = off, one box per inactive hitbox; up to 4:
    /// 16 x 16 hitboxes per box; default 3,
    /// `LipacConfig::DEFAULT_ADAPTIVE_LEVELS`). docs/ADAPTIVE_HITBOXES.md.
    #[arg(long)]
    adaptive_levels: Option<u8>,
    /// LiPaC's hitbox cell size in metres (default 32, `LipacConfig::DEFAULT_CELL_SIZE`;
    /// the paper's 16).
    #[arg(long)]
    cell_size: Option<f64>,
    /// LiPaC's decayed rule rises with this shift (1..=3, its decay shift)
    /// when a frame's hits exceed the rate: 1 climbs half way in one frame
    /// (lower latency and error; docs/EVALUATION.md "A faster rise than
    /// decay"), 3 is the symmetric rule. Default: 1
    /// (`LipacConfig::DEFAULT_DECAYED`).
    #[arg(long)]
    rise_shift: Option<u32>,
    /// LiPaC's start: `off` for the paper's cold start (nothing traced but
    /// the pinned instances until the first read-back), or
    /// `DIST:SIZE[:RADIUS]` for a warm start at the level load that
    /// activates what is in view within DIST metres or of projected size
    /// at least SIZE (`inf:0`: the whole view), in view meaning in the
    /// frustum or within RADIUS metres in any direction, its builds
    /// unbudgeted. Default: LiPaC's configured start (`inf:0:800`).
    /// docs/EVALUATION.md "Cold start, and the levers together".
    #[arg(long)]
    warm_start: Option<String>,
    /// LiPaC warm-starts at every camera cut too (`--camera jump`), as at
    /// the load (its builds unbudgeted); off by default (its memory peak).
    #[arg(long)]
    warm_start_at_cuts: bool,
    /// Frames without a hit that LiPaC holds what a warm start activates
    /// before hit feedback culls it (decayed rule). Default: 0, the first
    /// frame's feedback decides. docs/EVALUATION.md "A warm start around
    /// the camera, held".
    #[arg(long)]
    warm_start_hold: Option<u32>,
    /// Report folder.
    #[arg(long, default_value = "lipac-report")]
    out: PathBuf,
    /// A device profile (JSON, `lipac-sim/profiles/`; made by lipac-vk's
    /// `device_profile` example): its acceleration-structure sizes make the
    /// memory axis, its build rates the modelled GPU time. Default: the
    /// built-in profile (lavapipe's sizes, published rates).
    #[arg(long, value_name = "FILE")]
    device_profile: Option<PathBuf>,
    /// Frames to take pictures of (e.g. `0,90,180`): the indirect light of
    /// the ground truth and each strategy, error heat maps and TLAS maps, in
    /// report.html and under snapshots/.
    #[arg(long, value_delimiter = ',')]
    snapshots: Vec<u32>,
}

/// Closed-loop thresholds (docs/EVALUATION.md, "Closed-loop thresholds").
#[derive(clap::Args, Default)]
struct ClosedLoopArgs {
    /// Adds `lipac-budget`: LiPaC whose Manager holds this
    /// acceleration-structure memory budget, MiB (as the report counts it).
    #[arg(long, value_name = "MiB")]
    memory_budget: Option<f64>,
    /// Adds `lipac-escape`: LiPaC whose Manager holds this escape fraction
    /// (share of counted hits ending in counting boxes, in (0, 1)).
    #[arg(long, value_name = "F")]
    escape_target: Option<f64>,
    /// Camera path: the fly-through, or two views with a jump at frame 135.
    #[arg(long, value_enum, default_value = "flythrough")]
    camera: CameraArg,
}

#[derive(Clone, Copy, Default, ValueEnum)]
enum CameraArg {
    #[default]
    Flythrough,
    Jump,
}

impl ClosedLoopArgs {
    fn options(&self) -> Option<ClosedLoopOptions> {
        let camera = match self.camera {
            CameraArg::Flythrough => ClosedLoopPath::Flythrough,
            CameraArg::Jump => ClosedLoopPath::Jump,
        };
        let o = ClosedLoopOptions {
            memory_budget_mib: self.memory_budget,
            escape_target: self.escape_target,
            camera,
        };
        (o != ClosedLoopOptions::default()).then_some(o)
    }
}

#[derive(Subcommand)]
enum Command {
    /// Every strategy side by side against the ground truth (the main job).
    Compare {
        #[command(flatten)]
        common: Common,
        /// Strategies to compare (default: all).
        #[arg(long, value_enum, value_delimiter = ',')]
        strategies: Vec<StrategyArg>,
        #[command(flatten)]
        closed_loop: ClosedLoopArgs,
    },
    /// One strategy against the ground truth.
    Run {
        #[command(flatten)]
        common: Common,
        /// The strategy.
        #[arg(long, value_enum, default_value = "lipac")]
        strategy: StrategyArg,
    },
    /// Records a built-in scene and camera path as a trace.
    Record(trace_cmds::RecordArgs),
    /// Runs the strategies on a recorded trace (the same report as compare).
    Replay(trace_cmds::ReplayArgs),
    /// Converts a trace between binary and JSON lines.
    Convert(trace_cmds::ConvertArgs),
    /// Turns a glTF scene (.gltf/.glb) into a trace with geometry.
    Import(import_cmd::ImportArgs),
    /// Run time, memory and builds against error over many configurations
    /// (threshold factors, latency mitigation, cell sizes, streaks,
    /// baselines), with Pareto plots.
    Sweep(SweepArgs),
}

#[derive(clap::Args)]
struct SweepArgs {
    /// Scenes.
    #[arg(long, value_enum, value_delimiter = ',', default_value = "city,mirror")]
    scenes: Vec<SceneArg>,
    /// Frames per scene (default: the whole fly-through, 270).
    #[arg(long)]
    frames: Option<u32>,
    /// Image width.
    #[arg(long, default_value_t = 128)]
    width: u32,
    /// Image height.
    #[arg(long, default_value_t = 72)]
    height: u32,
    /// Factors LiPaC's scaled thresholds are multiplied by (θd and σo
    /// follow at 1/10).
    #[arg(long, value_delimiter = ',', default_value = "0.5,1,2,4")]
    factors: Vec<f64>,
    /// Further hitbox cell sizes in metres (LiPaC at factor 1; the base is
    /// lipac-sim's default, 32 m); empty for none.
    #[arg(long, value_delimiter = ',', default_value = "16,64")]
    cells: Vec<String>,
    /// Further streak lengths `n_a:n_d` (LiPaC at factor 1).
    #[arg(long, value_delimiter = ',', default_value = "1:15,4:30")]
    streaks: Vec<String>,
    /// Latency-mitigation heuristics `max_distance:min_projected_size`,
    /// optionally `:surround_radius` (LiPaC + latency mitigation at factor
    /// 1).
    #[arg(long, value_delimiter = ',', default_value = "50:0.1,100:0.05")]
    latency: Vec<String>,
    /// Further decayed-rule settings (LiPaC at factor 1), each
    /// `K_UP[:A/D[:IA/IO[:HALF_LIFE]]]`: the rise shift (1..=the decay
    /// shift, 3; `-` for the decay shift), then optionally the hitbox
    /// activation / deactivation and instance activation / omit rates in
    /// hits per frame at 1080p (default 100/0.2:100/0.2) and the decay
    /// half-life in frames (default 5). E.g. `1,2,1:200/40,1:150/30:150/30:2.4`;
    /// write `--decayed=-:100/20` when the first one starts with `-`. A
    /// setting may end in `@CELL` (its own hitbox cell size in metres),
    /// then `%LEVELS` (adaptive hitboxes' merge levels, 0..=4, as
    /// `compare --adaptive-levels`), then `~HOLD` (its own
    /// `--warm-start-hold`), then `^off` or `^DIST/SIZE[/RADIUS]` (its own
    /// `--warm-start`), then `+DIST/SIZE[/RADIUS]` (latency
    /// mitigation, as `--latency`) and then `!` (the terrain not pinned:
    /// culled like any instance), e.g. `1:5/1:5/1@32%3+100/0.05` or
    /// `-:2400/480:2400/480!` or `1@256~14`.
    #[arg(long, value_delimiter = ',')]
    decayed: Vec<String>,
    /// Baseline strategies.
    #[arg(
        long,
        value_enum,
        value_delimiter = ',',
        default_value = "full,frustum,heuristic,oracle"
    )]
    baselines: Vec<StrategyArg>,
    /// Hindsight references beside the baselines, one per window in
    /// frames, e.g. `1,2,4,8`: each traces what the ground truth hit in
    /// that many past frames (and the pinned terrain), as a causal
    /// predictor with perfect memory of past hits would; named
    /// "hindsight K", never on a front.
    #[arg(long, value_delimiter = ',')]
    hindsight: Vec<u32>,
    /// Scene seed (default: each scene's own).
    #[arg(long)]
    seed: Option<u64>,
    /// Sweep a recorded trace instead of the scenes (`lipac record`'s, or
    /// one whose header carries its meshes' geometry): every
    /// configuration replays it in geometry mode as `lipac replay` does.
    /// Not with --scenes, --seed or --frames.
    #[arg(long, conflicts_with_all = ["scenes", "seed", "frames"])]
    trace: Option<PathBuf>,
    #[command(flatten)]
    trace_scene: trace_cmds::TraceSceneArgs,
    /// Every LiPaC configuration warm-starts again at each camera cut (as
    /// `lipac compare --warm-start-at-cuts`); a trace's cuts are found
    /// from its cameras (more than 100 m or 90° in one frame), the
    /// scenes' fly-throughs have none.
    #[arg(long)]
    warm_start_at_cuts: bool,
    /// Frames every LiPaC configuration holds what a warm start activates
    /// (as `lipac compare --warm-start-hold`); named in each
    /// configuration ("held N").
    #[arg(long)]
    warm_start_hold: Option<u32>,
    /// How every LiPaC configuration starts: `off` (the paper's cold
    /// start) or `DIST:SIZE[:RADIUS]` (as `lipac compare --warm-start`);
    /// named in each configuration. Default: LiPaC's configured start
    /// (`inf:0:800`).
    #[arg(long)]
    warm_start: Option<String>,
    /// Worker threads: strategies, image rows and BLAS refits (0 = all cores).
    #[arg(long, default_value_t = 0)]
    threads: usize,
    /// Output folder.
    #[arg(long, default_value = "lipac-sweep")]
    out: PathBuf,
    /// Render nothing: read this sweep.json, recompute the Pareto fronts and
    /// write the outputs again (e.g. after a plot change).
    #[arg(long, conflicts_with_all = ["shard", "merge"])]
    replot: Option<PathBuf>,
    /// Run only part K of N (1 <= K <= N) of the sweep and write its
    /// results to `--out` as sweep-shard-K-of-N.json; run all N with the
    /// same other flags (e.g. one per machine), then `--merge` them.
    #[arg(long, value_name = "K/N")]
    shard: Option<sweep::shard::Shard>,
    /// Render nothing: combine the shard files in these folders (or files)
    /// into the report of one run, written to `--out`.
    #[arg(long, value_name = "DIR", num_args = 1.., conflicts_with = "shard")]
    merge: Vec<PathBuf>,
    /// A device profile for the memory axis and the modelled GPU time (as
    /// `lipac compare --device-profile`; shards of one sweep must share it).
    #[arg(long, value_name = "FILE")]
    device_profile: Option<PathBuf>,
}

fn pair<A: std::str::FromStr, B: std::str::FromStr>(s: &str, what: &str) -> Result<(A, B), String> {
    let (a, b) = s
        .split_once(':')
        .ok_or_else(|| format!("{what} `{s}`: expected `a:b`"))?;
    match (a.trim().parse(), b.trim().parse()) {
        (Ok(a), Ok(b)) => Ok((a, b)),
        _ => Err(format!("{what} `{s}`: not two numbers")),
    }
}

fn replot(from: &std::path::Path, out: &std::path::Path) -> Result<(), String> {
    output::check_out_dir(out, &[from])?;
    let json = std::fs::read_to_string(from).map_err(|e| format!("{}: {e}", from.display()))?;
    let mut report: sweep::SweepReport =
        serde_json::from_str(&json).map_err(|e| format!("{}: {e}", from.display()))?;
    sweep::mark_fronts(&mut report);
    output::publish_dir(out, &[from], |dir| {
        sweep::write_sweep(&report, dir).map_err(|e| e.to_string())
    })?;
    println!("sweep in {}/sweep.md", out.display());
    Ok(())
}

fn merge(dirs: &[PathBuf], out: &std::path::Path) -> Result<(), String> {
    let inputs: Vec<&std::path::Path> = dirs.iter().map(PathBuf::as_path).collect();
    output::check_out_dir(out, &inputs)?;
    let shards = sweep::shard::read_shards(dirs).map_err(|e| e.to_string())?;
    let report = sweep::shard::merge(&shards).map_err(|e| e.to_string())?;
    print!("{}", sweep::sweep_markdown(&report));
    output::publish_dir(out, &inputs, |dir| {
        sweep::write_sweep(&report, dir).map_err(|e| format!("writing the report: {e}"))
    })?;
    println!(
        "\n{} shards merged; sweep in {}/sweep.md",
        shards.len(),
        out.display()
    );
    Ok(())
}

fn sweep_main(a: SweepArgs) -> ExitCode {
    let done = |r: Result<(), String>| match r {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("lipac sweep: {e}");
            ExitCode::FAILURE
        }
    };
    if let Some(from) = &a.replot {
        return done(replot(from, &a.out));
    }
    if !a.merge.is_empty() {
        return done(merge(&a.merge, &a.out));
    }
    let parsed = (|| -> Result<SweepConfig, String> {
        let streaks = a
            .streaks
            .iter()
            .filter(|s| !s.is_empty())
            .map(|s| pair::<u32, u32>(s, "streak"))
            .collect::<Result<Vec<_>, _>>()?;
        let latency = a
            .latency
            .iter()
            .filter(|s| !s.is_empty())
            .map(|s| parse_heuristic(s, ':').map_err(|e| format!("--latency {e}")))
            .collect::<Result<Vec<_>, _>>()?;
        Ok(SweepConfig {
            scenes: if a.trace.is_some() {
                Vec::new()
            } else {
                a.scenes.iter().map(|&s| s.into()).collect()
            },
            seed: a.seed,
            frames: a.frames,
            width: a.width,
            height: a.height,
            baselines: a.baselines.iter().map(|&s| s.into()).collect(),
            hindsight: a.hindsight.clone(),
            factors: a.factors.clone(),
            latency,
            cell_sizes: a
                .cells
                .iter()
                .filter(|s| !s.is_empty())
                .map(|s| {
                    s.trim()
                        .parse()
                        .map_err(|_| format!("cell size `{s}`: not a number"))
                })
                .collect::<Result<Vec<f64>, _>>()?,
            streaks,
            decayed: a
                .decayed
                .iter()
                .filter(|s| !s.is_empty())
                .map(|s| sweep::parse_decayed_variant(s, &LipacConfig::DEFAULT_DECAYED))
                .collect::<Result<Vec<_>, _>>()?,
            threads: a.threads,
            trace: a.trace.clone(),
            trace_options: trace_cmds::trace_scene_options(&a.trace_scene)
                .map_err(|e| e.to_string())?,
            warm_start_at_cuts: a.warm_start_at_cuts,
            warm_start_hold: a.warm_start_hold,
            lipac_start: match a.warm_start.as_deref() {
                None => LipacStart::Default,
                Some(spec) => LipacStart::parse(spec).map_err(|e| format!("--warm-start: {e}"))?,
            },
            device: DeviceProfile::load_or_builtin(a.device_profile.as_deref())
                .map_err(|e| e.to_string())?,
        })
    })();
    let config = match parsed.and_then(|c| {
        check_image_size(c.width, c.height).map_err(|e| e.to_string())?;
        Ok(c)
    }) {
        Ok(c) => c,
        Err(e) => {
            eprintln!("lipac sweep: {e}");
            return ExitCode::FAILURE;
        }
    };
    let bar = ProgressBar::new(0);
    bar.set_style(
        ProgressStyle::with_template("{msg} {bar:40} {pos}/{len} frames  {elapsed} (eta {eta})")
            .unwrap_or_else(|_| ProgressStyle::default_bar()),
    );
    // The trace is an input: neither the report folder nor any file
    // written into it may be the trace (checked again on writing).
    let inputs: Vec<&Path> = config
        .trace
        .iter()
        .chain(a.device_profile.iter())
        .map(PathBuf::as_path)
        .collect();
    if let Err(e) = output::check_out_dir(&a.out, &inputs) {
        eprintln!("lipac sweep: {e}");
        return ExitCode::FAILURE;
    }
    let names = config.scene_names();
    let mut progress = |si: usize, count: usize, done: u32, total: u32| {
        let name = names.get(si).map_or("", String::as_str);
        bar.set_message(format!("{name} ({}/{count})", si + 1));
        // A trace's length is unknown until its end (total 0).
        bar.set_length(u64::from(total.max(done)));
        bar.set_position(u64::from(done));
    };
    if let Some(shard) = a.shard {
        let result = sweep::shard::run_shard(&config, shard, &mut progress);
        bar.finish_and_clear();
        return done(result.map_err(|e| e.to_string()).and_then(|part| {
            let written = output::publish_dir(&a.out, &inputs, |dir| {
                sweep::shard::write_shard(&part, dir).map_err(|e| e.to_string())
            })?;
            let path = a.out.join(written.file_name().unwrap_or_default());
            println!(
                "shard {shard}: {} of the sweep's {} (scene, configuration) runs, on {} scene(s), in {:.1} s; results in {}",
                part.points.len(),
                part.plan.len(),
                part.scenes.len(),
                part.wall_s,
                path.display()
            );
            Ok(())
        }));
    }
    let result = sweep::run(&config, &mut progress);
    bar.finish_and_clear();
    let report = match result {
        Ok(r) => r,
        Err(e) => {
            eprintln!("lipac sweep: {e}");
            return ExitCode::FAILURE;
        }
    };
    print!("{}", sweep::sweep_markdown(&report));
    match output::publish_dir(&a.out, &inputs, |dir| {
        sweep::write_sweep(&report, dir).map_err(|e| e.to_string())
    }) {
        Ok(_) => {
            println!("\nsweep in {}/sweep.md", a.out.display());
            ExitCode::SUCCESS
        }
        Err(e) => {
            eprintln!("lipac sweep: writing the report: {e}");
            ExitCode::FAILURE
        }
    }
}

fn main() -> ExitCode {
    run(Cli::parse())
}

/// The command line's work (`main` less the parsing; the file-safety
/// table in `lipac/tests.rs` runs it in child processes).
fn run(cli: Cli) -> ExitCode {
    let (common, strategies, closed_loop) = match cli.command {
        Command::Compare {
            common,
            strategies,
            closed_loop,
        } => (common, strategies, closed_loop.options()),
        Command::Run { common, strategy } => (common, vec![strategy], None),
        Command::Record(a) => return trace_cmds::run_record(a),
        Command::Replay(a) => return trace_cmds::run_replay(a),
        Command::Convert(a) => return trace_cmds::run_convert(a),
        Command::Import(a) => return import_cmd::run_import(a),
        Command::Sweep(args) => return sweep_main(args),
    };
    let strategies: Vec<StrategyKind> = if strategies.is_empty() {
        StrategyKind::DEFAULT.to_vec()
    } else {
        strategies.into_iter().map(Into::into).collect()
    };
    if let Err(e) = check_image_size(common.width, common.height) {
        eprintln!("lipac: {e}");
        return ExitCode::FAILURE;
    }
    if common.frames == Some(0) {
        eprintln!("lipac: --frames 0: nothing to render (give at least 1)");
        return ExitCode::FAILURE;
    }
    let profile_inputs: Vec<&Path> = common.device_profile.iter().map(PathBuf::as_path).collect();
    if let Err(e) = output::check_out_dir(&common.out, &profile_inputs) {
        eprintln!("lipac: {e}");
        return ExitCode::FAILURE;
    }
    let lipac_start = match common.warm_start.as_deref().map(LipacStart::parse) {
        None => LipacStart::Default,
        Some(Ok(start)) => start,
        Some(Err(e)) => {
            eprintln!("lipac: --warm-start: {e}");
            return ExitCode::FAILURE;
        }
    };
    let device = match DeviceProfile::load_or_builtin(common.device_profile.as_deref()) {
        Ok(d) => d,
        Err(e) => {
            eprintln!("lipac: {e}");
            return ExitCode::FAILURE;
        }
    };
    let config = CompareConfig {
        device,
        frames: common.frames,
        width: common.width,
        height: common.height,
        strategies,
        share_ground_truth: true,
        threads: common.threads,
        adaptive_levels: common.adaptive_levels,
        lipac_cell_size: common.cell_size,
        lipac_rise_shift: common.rise_shift,
        lipac_start,
        lipac_warm_start_at_cuts: common.warm_start_at_cuts,
        lipac_warm_start_hold: common.warm_start_hold,
    };
    // Hidden when stderr is not a terminal (CI, pipes): indicatif's default.
    let bar = ProgressBar::new(0);
    bar.set_style(
        ProgressStyle::with_template("{bar:40} {pos}/{len} frames  {elapsed} (eta {eta})")
            .unwrap_or_else(|_| ProgressStyle::default_bar()),
    );
    let mut progress = |done: u32, total: u32| {
        bar.set_length(u64::from(total));
        bar.set_position(u64::from(done));
    };
    let result = match &closed_loop {
        None => run_choice_with_snapshots(
            common.scene.into(),
            common.seed,
            &config,
            &common.snapshots,
            &mut progress,
        ),
        Some(opts) => closed_loop::run(
            common.scene.into(),
            common.seed,
            &config,
            opts,
            &common.snapshots,
            &mut progress,
        ),
    };
    bar.finish_and_clear();
    let (report, snapshots) = match result {
        Ok(r) => r,
        Err(e) => {
            eprintln!("lipac: {e}");
            return ExitCode::FAILURE;
        }
    };
    print!("{}", table(&report));
    if let Some(h) = headline(&report) {
        print!("{h}");
    }
    if closed_loop.is_some() {
        for b in closed_loop::budget_figures(&report, &report.camera_cuts) {
            println!("{}", b.summary_line());
        }
    }
    if let Some(c) = closed_loop::escape_error_correlation(&report) {
        println!(
            "escape fraction vs error over {} (frame, LiPaC run) points: Pearson {:.3}, Spearman {:.3}",
            c.points, c.pearson, c.spearman
        );
    }
    let inputs: Vec<&Path> = common.device_profile.iter().map(PathBuf::as_path).collect();
    match output::publish_dir(&common.out, &inputs, |dir| {
        write_report_with_snapshots(&report, &snapshots, dir).map_err(|e| e.to_string())
    }) {
        Ok(_) => {
            println!(
                "{} frames in {:.1} s; report in {}/report.md and {}/report.html ({} snapshots)",
                report.frames,
                report.wall_s,
                common.out.display(),
                common.out.display(),
                snapshots.len()
            );
            ExitCode::SUCCESS
        }
        Err(e) => {
            eprintln!("lipac: writing the report: {e}");
            ExitCode::FAILURE
        }
    }
}

// The file-safety table of every subcommand (the CLI's own unit test, in
// src/cli/ with the command modules).
#[cfg(test)]
#[path = "../cli/tests.rs"]
mod tests;
