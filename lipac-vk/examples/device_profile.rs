//! Measures the local GPU into a device profile for lipac-sim (`lipac
//! compare|replay|sweep --device-profile FILE`; format in
//! docs/MEMORY_MODEL.md, "Device profiles"): BLAS bytes per triangle built
//! and compacted by mesh size, TLAS bytes by instance count, BLAS batch
//! and TLAS build times, and GPU Algorithms 1 and 2 (checked against the
//! CPU reference first).
//!
//! ```text
//! cargo run --release -p lipac-vk --example device_profile -- --out profile.json
//!     [--name NAME] [--slots 1M] [--tlas 1M] [--blas 256x512,16x131072] [--reps 40]
//! ```
//!
//! Runs on any Vulkan 1.3 device with acceleration structures and either
//! tracing path (`LIPAC_VK_DEVICE` picks one). Never writes over an
//! existing file.

mod gpu;

use gpu::accel::{blas_batch, blas_sizes, tlas_build, tlas_sizes, GridMesh, STATIC_BLAS_FLAGS};
use gpu::device::GpuDevice;
use gpu::frame::CpuFrame;
use gpu::{arg_value, parse_count, Bench, Res};
use lipac_sim::device_profile::{
    BlasBuild, BlasProfile, BlasSize, DeviceProfile, PassTimes, TlasBuild, TlasProfile, TlasSize,
    PROFILE_FORMAT, PROFILE_VERSION,
};
use lipac_vk::{BlasBatch, ScratchBuffer, UnitCube};
use std::io::Write;

const USAGE: &str = "usage: device_profile --out FILE.json [--name NAME] [--slots 1M] \
[--tlas 1M] [--blas 256x512,16x131072] [--reps 40] [--warmup-ms 1000] [--evict-mib 256]";

struct Options {
    out: String,
    name: Option<String>,
    slots: u32,
    tlas: u32,
    blas: Vec<(u32, u32)>,
    reps: u32,
    warmup_ms: u64,
    evict_mib: u64,
}

fn options(args: &[String]) -> Result<Options, String> {
    let known = [
        "--out",
        "--name",
        "--slots",
        "--tlas",
        "--blas",
        "--reps",
        "--warmup-ms",
        "--evict-mib",
    ];
    let mut i = 0;
    while i < args.len() {
        if !known.contains(&args[i].as_str()) || i + 1 >= args.len() {
            return Err(format!("unexpected `{}`\n{USAGE}", args[i]));
        }
        i += 2;
    }
    let count = |name: &str, default: &str| {
        parse_count(&arg_value(args, name).unwrap_or_else(|| default.into()))
            .map_err(|e| format!("{name}: {e}"))
    };
    let num = |name: &str, default: u64| -> Result<u64, String> {
        arg_value(args, name).map_or(Ok(default), |v| {
            v.parse()
                .map_err(|_| format!("{name}: `{v}` is not a number"))
        })
    };
    let blas = arg_value(args, "--blas")
        .unwrap_or_else(|| "256x512,16x131072".into())
        .split(',')
        .map(|spec| {
            let (m, t) = spec
                .split_once('x')
                .ok_or_else(|| format!("--blas: `{spec}` is not MESHESxTRIANGLES"))?;
            let (m, t) = (parse_count(m)?, parse_count(t)?);
            let side = ((f64::from(t) / 2.0).sqrt().round()) as u32;
            if m == 0 || side == 0 || 2 * side * side != t {
                return Err(format!(
                    "--blas: `{spec}`: at least one mesh of 2 n² triangles (512, 131072, ...)"
                ));
            }
            Ok((m, side))
        })
        .collect::<Result<Vec<_>, String>>()?;
    let slots = count("--slots", "1M")?;
    let tlas = count("--tlas", "1M")?;
    if slots == 0 || slots > lipac_core::layout::MAX_SLOTS || tlas == 0 {
        return Err("--slots and --tlas: at least 1 (slots at most 2^24)".into());
    }
    let reps = num("--reps", 40)?;
    if reps == 0 || reps > 10_000 {
        return Err("--reps: 1..=10000".into());
    }
    Ok(Options {
        out: arg_value(args, "--out").ok_or_else(|| format!("--out is required\n{USAGE}"))?,
        name: arg_value(args, "--name"),
        slots,
        tlas,
        blas,
        reps: reps as u32,
        warmup_ms: num("--warmup-ms", 1000)?,
        evict_mib: num("--evict-mib", 256)?,
    })
}

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let opts = match options(&args) {
        Ok(o) => o,
        Err(e) => {
            eprintln!("device_profile: {e}");
            std::process::exit(2);
        }
    };
    let mut file = match std::fs::OpenOptions::new()
        .write(true)
        .create_new(true)
        .open(&opts.out)
    {
        Ok(f) => f,
        Err(e) => {
            eprintln!(
                "device_profile: --out {}: {e} (it is never overwritten)",
                opts.out
            );
            std::process::exit(2);
        }
    };
    let dev = match GpuDevice::new() {
        Ok(d) => d,
        Err(e) => {
            eprintln!("device_profile: no usable Vulkan device: {e}");
            std::process::exit(2);
        }
    };
    println!("device_profile: {}", dev.describe());
    let profile = match measure(&dev, &opts, &args) {
        Ok(p) => p,
        Err(e) => {
            eprintln!("device_profile: {e}");
            std::process::exit(1);
        }
    };
    let errors = dev.validation_errors();
    drop(dev);
    if !errors.is_empty() {
        eprintln!("device_profile: {} validation errors:", errors.len());
        for e in &errors {
            eprintln!("  {e}");
        }
        std::process::exit(1);
    }
    // What lipac-sim reads back: the profile must pass its checks.
    let text = profile.to_json();
    if let Err(e) = DeviceProfile::from_json(&text) {
        eprintln!("device_profile: the measured profile does not validate: {e}");
        std::process::exit(1);
    }
    if let Err(e) = file.write_all(text.as_bytes()) {
        eprintln!("device_profile: writing {}: {e}", opts.out);
        std::process::exit(1);
    }
    println!("device_profile: wrote {}", opts.out);
}

/// A short name: `lavapipe` for llvmpipe, else the device name in lower
/// case with dashes.
fn default_name(device: &str) -> String {
    if device.starts_with("llvmpipe") {
        return "lavapipe".into();
    }
    let mut s: String = device
        .chars()
        .map(|c| {
            if c.is_ascii_alphanumeric() {
                c.to_ascii_lowercase()
            } else {
                '-'
            }
        })
        .collect();
    while s.contains("--") {
        s = s.replace("--", "-");
    }
    s.trim_matches('-').to_owned()
}

fn measure(dev: &GpuDevice, opts: &Options, args: &[String]) -> Res<DeviceProfile> {
    let info = &dev.info;
    let mut b = Bench::new(dev, opts.reps, opts.evict_mib << 20)?;
    let ctx = b.ctx().clone();

    // Sizes: grids of 2, 32, 512, 8192 and 131072 triangles (one shape
    // family, so sizes grow with the count), built with lipac's
    // static-BLAS flags, compacted. The unit cube is printed beside them.
    let cube = UnitCube::new(&ctx)?;
    let mut grids = Vec::new();
    for side in [1u32, 4, 16, 64, 256] {
        grids.push(GridMesh::new(&mut b, side)?);
    }
    let refs: Vec<&GridMesh> = grids.iter().collect();
    let mut sizes = blas_sizes(&mut b, &refs)?;
    let mut batch = BlasBatch::new();
    batch.push(&[cube.geometry()], STATIC_BLAS_FLAGS)?;
    let mut scratch = ScratchBuffer::new(&ctx);
    let cube_built = b.one_shot.run(|rec| batch.record(rec, &mut scratch))?;
    let cube_compacted = cube_built
        .compaction
        .as_ref()
        .map(|q| q.read_sizes())
        .transpose()?
        .and_then(|v| v.first().map(|p| p.1));
    let cube_blas = cube_built.blases.into_iter().next().ok_or("no cube BLAS")?;
    println!(
        "unit cube (12 triangles): {} B built, {} B compacted",
        cube_blas.size(),
        cube_compacted.unwrap_or(cube_blas.size())
    );
    sizes.sort_by_key(|s| s.triangles);
    println!(
        "| BLAS triangles | built B | B/triangle | compacted B | B/triangle | build scratch B |"
    );
    println!("| ---: | ---: | ---: | ---: | ---: | ---: |");
    for s in &sizes {
        println!(
            "| {} | {} | {:.1} | {} | {:.1} | {} |",
            s.triangles,
            s.built_bytes,
            s.built_bytes as f64 / s.triangles as f64,
            s.compacted_bytes,
            s.compacted_bytes as f64 / s.triangles as f64,
            s.build_scratch_bytes
        );
    }
    let tlas = tlas_sizes(&b, &[1, 16, 1024, 65_536, 1_000_000])?;
    println!("\n| TLAS instances | bytes | B/instance |");
    println!("| ---: | ---: | ---: |");
    for t in &tlas {
        println!(
            "| {} | {} | {:.1} |",
            t.instances,
            t.bytes,
            t.bytes as f64 / t.instances as f64
        );
    }

    // Clocks up before timing.
    let source = b.random_buffer("warm-up source", 256 << 20, 0xB4D_5EED)?;
    let (warm_ms, _) = b.warm_up(&source, opts.warmup_ms)?;
    drop(source);
    println!("\ndevice_profile: warm-up {warm_ms:.0} ms");

    let mut builds = Vec::new();
    for &(meshes, side) in &opts.blas {
        let mesh = GridMesh::new(&mut b, side)?;
        let r = blas_batch(&mut b, &mesh, meshes)?;
        println!(
            "BLAS batch {meshes} x {}: {:.1} µs, {:.1} M triangles/s",
            r.triangles_per_mesh,
            r.build.median_us,
            r.triangles_per_s / 1e6
        );
        builds.push(BlasBuild {
            meshes,
            triangles_per_mesh: r.triangles_per_mesh,
            ms: r.build.median_us / 1e3,
        });
    }
    let t = tlas_build(&mut b, &cube_blas, opts.tlas)?;
    println!(
        "TLAS of {} instances: {:.1} µs ({:.1} M instances/s)",
        t.instances,
        t.build.median_us,
        t.instances_per_s / 1e6
    );
    let address = cube_blas.device_address();
    let frame = CpuFrame::synthetic(opts.slots as usize, address, address);
    let f = gpu::frame::run(&mut b, &frame)?;
    println!(
        "Algorithms 1 / 2 at {} slots: {:.1} / {:.1} µs ({} and {})",
        f.slots,
        f.algorithm1.time.median_us,
        f.algorithm2.time.median_us,
        f.algorithm1.check,
        f.algorithm2.check
    );
    drop((cube_blas, cube, scratch, grids));

    let command = std::iter::once("device_profile".to_owned())
        .chain(args.iter().cloned())
        .collect::<Vec<_>>()
        .join(" ");
    Ok(DeviceProfile {
        format: PROFILE_FORMAT.into(),
        version: PROFILE_VERSION,
        name: opts
            .name
            .clone()
            .unwrap_or_else(|| default_name(&info.name)),
        device: info.name.clone(),
        driver: info.driver.clone(),
        source: format!(
            "measured by lipac-vk's device_profile example (`{command}`; Vulkan timestamps, \
             median of {} runs after {warm_ms:.0} ms of warm-up)",
            opts.reps
        ),
        blas: BlasProfile {
            sizes: sizes
                .iter()
                .map(|s| BlasSize {
                    triangles: s.triangles,
                    built_bytes: s.built_bytes,
                    compacted_bytes: Some(s.compacted_bytes),
                    build_scratch_bytes: Some(s.build_scratch_bytes),
                    update_scratch_bytes: Some(s.update_scratch_bytes),
                })
                .collect(),
            min_bytes: None,
            builds,
        },
        tlas: TlasProfile {
            sizes: tlas
                .iter()
                .map(|t| TlasSize {
                    instances: t.instances,
                    bytes: t.bytes,
                    build_scratch_bytes: Some(t.build_scratch_bytes),
                })
                .collect(),
            builds: vec![TlasBuild {
                instances: t.instances,
                ms: t.build.median_us / 1e3,
            }],
        },
        passes: vec![PassTimes {
            slots: f.slots,
            algorithm1_us: f.algorithm1.time.median_us,
            algorithm2_us: f.algorithm2.time.median_us,
        }],
        bandwidth_gb_per_s: None,
    })
}
