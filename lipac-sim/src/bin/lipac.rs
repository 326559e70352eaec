//! `lipac`: culling strategies compared on the CPU laboratory.
//!
//! ```text
//! cargo run --release -p lipac-sim --bin lipac -- compare
//! cargo run --release -p lipac-sim --bin lipac -- run --strategy lipac --scene small
//! cargo run --release -p lipac-sim --bin lipac -- record --scene small --frames 60 small.lipactrace
//! cargo run --release -p lipac-sim --bin lipac -- replay small.lipactrace
//! ```

#[path = "../cli/trace_cmds.rs"]
mod trace_cmds;

use std::path::PathBuf;
use std::process::ExitCode;

use clap::{Parser, Subcommand, ValueEnum};
use indicatif::{ProgressBar, ProgressStyle};
use lipac_sim::compare::{run_choice, CompareConfig, SceneChoice};
use lipac_sim::report::{headline, table, write_report};
use lipac_sim::strategy::StrategyKind;

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
}

impl From<SceneArg> for SceneChoice {
    fn from(s: SceneArg) -> Self {
        match s {
            SceneArg::City => SceneChoice::City,
            SceneArg::Small => SceneChoice::Small,
            SceneArg::Mirror => SceneChoice::Mirror,
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
    /// Render threads (0 = all cores).
    #[arg(long, default_value_t = 0)]
    threads: usize,
    /// Report folder.
    #[arg(long, default_value = "lipac-report")]
    out: PathBuf,
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
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    let (common, strategies) = match cli.command {
        Command::Compare { common, strategies } => (common, strategies),
        Command::Run { common, strategy } => (common, vec![strategy]),
        Command::Record(a) => return trace_cmds::run_record(a),
        Command::Replay(a) => return trace_cmds::run_replay(a),
        Command::Convert(a) => return trace_cmds::run_convert(a),
    };
    let strategies: Vec<StrategyKind> = if strategies.is_empty() {
        StrategyKind::ALL.to_vec()
    } else {
        strategies.into_iter().map(Into::into).collect()
    };
    let config = CompareConfig {
        frames: common.frames,
        width: common.width,
        height: common.height,
        strategies,
        share_ground_truth: true,
        threads: common.threads,
    };
    // Hidden when stderr is not a terminal (CI, pipes): indicatif's default.
    let bar = ProgressBar::new(0);
    bar.set_style(
        ProgressStyle::with_template("{bar:40} {pos}/{len} frames  {elapsed} (eta {eta})")
            .unwrap_or_else(|_| ProgressStyle::default_bar()),
    );
    let result = run_choice(
        common.scene.into(),
        common.seed,
        &config,
        &mut |done, total| {
            bar.set_length(u64::from(total));
            bar.set_position(u64::from(done));
        },
    );
    bar.finish_and_clear();
    let report = match result {
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
    match write_report(&report, &common.out) {
        Ok(_) => {
            println!(
                "{} frames in {:.1} s; report in {}/report.md",
                report.frames,
                report.wall_s,
                common.out.display()
            );
            ExitCode::SUCCESS
        }
        Err(e) => {
            eprintln!("lipac: writing the report: {e}");
            ExitCode::FAILURE
        }
    }
}
