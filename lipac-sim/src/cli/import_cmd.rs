//! `lipac import`: a glTF scene as a trace with geometry (logic in
//! `lipac_sim::import`).

use std::io::{BufWriter, Write};
use std::path::PathBuf;
use std::process::ExitCode;

use clap::{Args, ValueEnum};
use lipac_core::trace::TraceFormat;
use lipac_sim::import::camera_path::CameraSource;
use lipac_sim::import::{import_gltf, write_trace, FlagRules, ImportConfig};
use lipac_sim::SimError;

#[derive(Clone, Copy, ValueEnum)]
pub enum ImportCameraArg {
    /// The file's cameras, else an orbit.
    Auto,
    /// The file's cameras.
    File,
    /// An orbit around the scene.
    Orbit,
    /// A straight flight across the scene.
    Flythrough,
}

/// `lipac import`.
#[derive(Args)]
pub struct ImportArgs {
    /// The glTF file (`.gltf` with embedded or sibling buffers, or `.glb`).
    input: PathBuf,
    /// Output trace (`.jsonl` = JSON lines, else binary).
    out: PathBuf,
    /// Frames to write.
    #[arg(long, default_value_t = 120)]
    frames: u32,
    /// Camera path.
    #[arg(long, value_enum, default_value = "auto")]
    camera: ImportCameraArg,
    /// Image width the cameras' aspect is for.
    #[arg(long, default_value_t = 128)]
    width: u32,
    /// Image height the cameras' aspect is for.
    #[arg(long, default_value_t = 72)]
    height: u32,
    /// Name patterns (comma-separated, case-insensitive) flagging vegetation
    /// (default: tree,veg,foliage,leaf,leaves,grass,bush,plant).
    #[arg(long, value_delimiter = ',')]
    vegetation: Option<Vec<String>>,
    /// Name patterns flagging animated instances (default:
    /// anim,character,npc,vehicle).
    #[arg(long, value_delimiter = ',')]
    animated: Option<Vec<String>>,
}

pub fn run_import(a: ImportArgs) -> ExitCode {
    let mut rules = FlagRules::default();
    if let Some(v) = a.vegetation {
        rules.vegetation = v;
    }
    if let Some(v) = a.animated {
        rules.animated = v;
    }
    let config = ImportConfig {
        frames: a.frames,
        camera: match a.camera {
            ImportCameraArg::Auto => CameraSource::Auto,
            ImportCameraArg::File => CameraSource::File,
            ImportCameraArg::Orbit => CameraSource::Orbit,
            ImportCameraArg::Flythrough => CameraSource::Flythrough,
        },
        aspect: a.width as f32 / a.height.max(1) as f32,
        rules,
    };
    let format = if a.out.extension().is_some_and(|e| e == "jsonl") {
        TraceFormat::Jsonl
    } else {
        TraceFormat::Binary
    };
    let io = |e: std::io::Error, p: &PathBuf| SimError::Io(format!("{}: {e}", p.display()));
    let result = (|| -> Result<_, SimError> {
        let bytes = std::fs::read(&a.input).map_err(|e| io(e, &a.input))?;
        let name = format!(
            "gltf:{}",
            a.input.file_name().unwrap_or_default().to_string_lossy()
        );
        let imported = import_gltf(&bytes, a.input.parent(), &name, &config)?;
        let file = std::fs::File::create(&a.out).map_err(|e| io(e, &a.out))?;
        let mut w = write_trace(&imported, format, BufWriter::new(file))?;
        w.flush().map_err(|e| io(e, &a.out))?;
        Ok(imported.summary)
    })();
    match result {
        Ok(s) => {
            println!(
                "{} meshes ({} with the file's LODs; triangles per LOD {} / {} / {}), \
                 {} instances ({} GPU-instanced, \
                 {} vegetation, {} animated, {} pinned), \
                 {} frames, cameras from {}{} -> {}",
                s.meshes,
                s.file_lods,
                s.triangles[0],
                s.triangles[1],
                s.triangles[2],
                s.instances,
                s.gpu_instanced,
                s.vegetation,
                s.animated,
                s.pinned,
                s.frames,
                if s.file_cameras {
                    "the file"
                } else {
                    "a generated path"
                },
                if s.skipped_primitives > 0 {
                    format!(", {} non-triangle primitives skipped", s.skipped_primitives)
                } else {
                    String::new()
                },
                a.out.display()
            );
            ExitCode::SUCCESS
        }
        Err(e) => {
            let _ = std::fs::remove_file(&a.out);
            eprintln!("lipac: {}: {e}", a.input.display());
            ExitCode::FAILURE
        }
    }
}
