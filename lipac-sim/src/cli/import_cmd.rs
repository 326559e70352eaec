//! `lipac import`: a glTF scene as a trace with geometry (logic in
//! `lipac_sim::import`).

use std::io::Read;
use std::path::{Path, PathBuf};
use std::process::ExitCode;

use clap::{Args, ValueEnum};
use lipac_core::trace::TraceFormat;
use lipac_sim::import::camera_path::CameraSource;
use lipac_sim::import::{import_gltf, write_trace, FlagRules, ImportConfig, ImportSummary};
use lipac_sim::SimError;

use crate::output::{check_not_input, io_err, open_input, OutputFile};

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
    match import_main(&a) {
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
            eprintln!("lipac: {e}");
            ExitCode::FAILURE
        }
    }
}

/// The import, by the rule of every command (`output.rs`): arguments
/// first, the output never one of the files read (the glTF and its buffer
/// files), written beside and renamed into place only when complete.
fn import_main(a: &ImportArgs) -> Result<ImportSummary, String> {
    if a.frames == 0 {
        return Err("--frames 0: nothing to import (give at least 1)".into());
    }
    if a.width == 0 || a.height == 0 {
        return Err(format!(
            "--width {} --height {}: the cameras' aspect needs both above 0",
            a.width, a.height
        ));
    }
    let mut rules = FlagRules::default();
    if let Some(v) = &a.vegetation {
        rules.vegetation.clone_from(v);
    }
    if let Some(v) = &a.animated {
        rules.animated.clone_from(v);
    }
    let config = ImportConfig {
        frames: a.frames,
        camera: match a.camera {
            ImportCameraArg::Auto => CameraSource::Auto,
            ImportCameraArg::File => CameraSource::File,
            ImportCameraArg::Orbit => CameraSource::Orbit,
            ImportCameraArg::Flythrough => CameraSource::Flythrough,
        },
        aspect: a.width as f32 / a.height as f32,
        rules,
    };
    let format = if a.out.extension().is_some_and(|e| e == "jsonl") {
        TraceFormat::Jsonl
    } else {
        TraceFormat::Binary
    };
    check_not_input(&a.out, &[&a.input])?;
    let at_input = |e: SimError| format!("{}: {e}", a.input.display());
    let mut bytes = Vec::new();
    open_input(&a.input)?
        .read_to_end(&mut bytes)
        .map_err(|e| io_err(&a.input, e))?;
    let name = format!(
        "gltf:{}",
        a.input.file_name().unwrap_or_default().to_string_lossy()
    );
    let imported = import_gltf(&bytes, a.input.parent(), &name, &config).map_err(at_input)?;
    drop(bytes);
    // The buffer files the glTF named were read too.
    let mut inputs: Vec<&Path> = vec![&a.input];
    inputs.extend(imported.files_read.iter().map(PathBuf::as_path));
    let mut out = OutputFile::create(&a.out, &inputs)?;
    write_trace(&imported, format, out.writer()).map_err(|e| io_err(&a.out, e))?;
    out.commit()?;
    Ok(imported.summary)
}
