//! The GPU benchmark: GPU Algorithms 1 and 2 (checked against lipac-core's
//! CPU reference first), the record upload, the TLAS build and BLAS
//! batches, timed with Vulkan timestamps (median of `--reps` runs, each
//! starting from memory), beside a compute shader streaming exactly the
//! bytes each pass must read (and, for Algorithm 1, write): the ratio says
//! how far a pass is from the memory traffic it cannot avoid. A 1 GiB
//! stream gives the bandwidth reached; clocks are warmed up first.
//!
//! ```text
//! cargo run --release -p lipac-vk --example gpu_bench -- --out bench.json
//!     [--slots 100k,1M,10M] [--reps 40] [--blas 256x512,16x131072]
//!     [--warmup-ms 1000] [--evict-mib 256] [--bandwidth-mib 1024]
//! ```
//!
//! Runs on any Vulkan 1.3 device with acceleration structures and either
//! tracing path (ray queries are not needed); `LIPAC_VK_DEVICE` picks one,
//! `LIPAC_VALIDATION=1` enables the validation layer (its errors fail the
//! run). Writes JSON to `--out`
//! (never over an existing file); exits 1 when a check or measurement
//! failed (the JSON says which). docs/BENCHMARKS.md, "GPU benchmark".

mod gpu;

use gpu::accel::{blas_batch, BlasBatchResult, GridMesh, STATIC_BLAS_FLAGS};
use gpu::device::GpuDevice;
use gpu::frame::{CpuFrame, FrameResult};
use gpu::timing::Stats;
use gpu::{arg_value, parse_count, Bench, Res};
use lipac_vk::{BlasBatch, ScratchBuffer, UnitCube};
use serde::Serialize;
use std::io::Write;

struct Options {
    out: Option<String>,
    slots: Vec<u32>,
    reps: u32,
    blas: Vec<(u32, u32)>,
    warmup_ms: u64,
    evict_mib: u64,
    bandwidth_mib: u64,
}

const USAGE: &str = "usage: gpu_bench --out FILE.json [--slots 100k,1M,10M] [--reps 40] \
[--blas 256x512,16x131072] [--warmup-ms 1000] [--evict-mib 256] [--bandwidth-mib 1024]";

fn options(args: &[String]) -> Result<Options, String> {
    let known = [
        "--out",
        "--slots",
        "--reps",
        "--blas",
        "--warmup-ms",
        "--evict-mib",
        "--bandwidth-mib",
    ];
    let mut i = 0;
    while i < args.len() {
        if !known.contains(&args[i].as_str()) || i + 1 >= args.len() {
            return Err(format!("unexpected `{}`\n{USAGE}", args[i]));
        }
        i += 2;
    }
    let num = |name: &str, default: u64| -> Result<u64, String> {
        arg_value(args, name).map_or(Ok(default), |v| {
            v.parse()
                .map_err(|_| format!("{name}: `{v}` is not a number"))
        })
    };
    let slots = arg_value(args, "--slots")
        .unwrap_or_else(|| "100k,1M,10M".into())
        .split(',')
        .map(parse_count)
        .collect::<Result<Vec<_>, _>>()?;
    if slots
        .iter()
        .any(|&s| s == 0 || s > lipac_core::layout::MAX_SLOTS)
    {
        return Err(format!(
            "--slots: each count must be 1..={}",
            lipac_core::layout::MAX_SLOTS
        ));
    }
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
    let reps = num("--reps", 40)?;
    if reps == 0 || reps > 10_000 {
        return Err("--reps: 1..=10000".into());
    }
    Ok(Options {
        out: arg_value(args, "--out"),
        slots,
        reps: reps as u32,
        blas,
        warmup_ms: num("--warmup-ms", 1000)?,
        evict_mib: num("--evict-mib", 256)?,
        bandwidth_mib: num("--bandwidth-mib", 1024)?.max(1),
    })
}

#[derive(Serialize)]
struct DeviceJson {
    name: String,
    device_type: String,
    vendor_id: u32,
    device_id: u32,
    driver: String,
    vulkan: String,
    ray_query: bool,
    ray_tracing_pipeline: bool,
    device_local_heap_bytes: u64,
}

#[derive(Serialize)]
struct Bandwidth {
    bytes: u64,
    read: Stats,
    gb_per_s: f64,
}

#[derive(Serialize)]
struct SizeOutcome {
    slots: u32,
    #[serde(skip_serializing_if = "Option::is_none")]
    result: Option<FrameResult>,
    #[serde(skip_serializing_if = "Option::is_none")]
    error: Option<String>,
}

#[derive(Serialize)]
struct BlasOutcome {
    meshes: u32,
    triangles_per_mesh: u32,
    #[serde(skip_serializing_if = "Option::is_none")]
    result: Option<BlasBatchResult>,
    #[serde(skip_serializing_if = "Option::is_none")]
    error: Option<String>,
}

#[derive(Serialize)]
struct Report {
    format: &'static str,
    version: u32,
    command: String,
    device: DeviceJson,
    reps: u32,
    warmup_ms: f64,
    evict_bytes: u64,
    bandwidth: Option<Bandwidth>,
    frames: Vec<SizeOutcome>,
    blas_batches: Vec<BlasOutcome>,
    validation_errors: Vec<String>,
    ok: bool,
}

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let opts = match options(&args) {
        Ok(o) => o,
        Err(e) => {
            eprintln!("gpu_bench: {e}");
            std::process::exit(2);
        }
    };
    // Refuse an existing output before measuring anything.
    let out_file = match &opts.out {
        Some(p) => match std::fs::OpenOptions::new()
            .write(true)
            .create_new(true)
            .open(p)
        {
            Ok(f) => Some((p.clone(), f)),
            Err(e) => {
                eprintln!("gpu_bench: --out {p}: {e} (it is never overwritten)");
                std::process::exit(2);
            }
        },
        None => None,
    };
    let dev = match GpuDevice::new() {
        Ok(d) => d,
        Err(e) => {
            eprintln!("gpu_bench: no usable Vulkan device: {e}");
            std::process::exit(2);
        }
    };
    println!("gpu_bench: {}", dev.describe());
    let report = match run(&dev, &opts, &args) {
        Ok(r) => r,
        Err(e) => {
            eprintln!("gpu_bench: {e}");
            std::process::exit(1);
        }
    };
    let ok = report.ok;
    if let Some((path, mut f)) = out_file {
        let text = serde_json::to_string_pretty(&report).unwrap_or_default();
        if let Err(e) = f.write_all(text.as_bytes()) {
            eprintln!("gpu_bench: writing {path}: {e}");
            std::process::exit(1);
        }
        println!("gpu_bench: wrote {path}");
    }
    drop(dev);
    if !ok {
        eprintln!("gpu_bench: FAILED (see the errors above)");
        std::process::exit(1);
    }
}

fn run(dev: &GpuDevice, opts: &Options, args: &[String]) -> Res<Report> {
    let info = &dev.info;
    let mut b = Bench::new(dev, opts.reps, opts.evict_mib << 20)?;
    let ctx = b.ctx().clone();

    // The unit cube: the BLAS every record of the synthetic frames uses.
    let cube = UnitCube::new(&ctx)?;
    let mut batch = BlasBatch::new();
    batch.push(&[cube.geometry()], STATIC_BLAS_FLAGS)?;
    let mut scratch = ScratchBuffer::new(&ctx);
    let cube_blas = b
        .one_shot
        .run(|rec| batch.record(rec, &mut scratch))?
        .blases
        .remove(0);
    let cube_address = cube_blas.device_address();

    // Clocks up, then the bandwidth of a plain stream.
    let bw_bytes = opts.bandwidth_mib << 20;
    let source = b.random_buffer("bandwidth source", bw_bytes, 0xB4D_5EED)?;
    let (warm_ms, warm_runs) = b.warm_up(&source, opts.warmup_ms)?;
    println!(
        "gpu_bench: warm-up {warm_ms:.0} ms ({warm_runs} streams of {} MiB)",
        opts.bandwidth_mib
    );
    let read = b.reference(&source, &source, bw_bytes / 16 * 16, 0)?;
    let bandwidth = Bandwidth {
        bytes: bw_bytes,
        gb_per_s: bw_bytes as f64 / (read.median_us * 1e-6) / 1e9,
        read,
    };
    println!(
        "gpu_bench: streaming read of {} MiB: {:.1} µs median, {:.1} GB/s",
        opts.bandwidth_mib, bandwidth.read.median_us, bandwidth.gb_per_s
    );
    drop(source);

    let mut ok = true;
    let mut frames = Vec::new();
    println!();
    println!("| slots | Alg. 1 µs | read ref µs | ratio | read+write ref µs | ratio | Alg. 2 µs | read ref µs | ratio | upload µs (records) | TLAS build µs (instances) |");
    println!("| ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: |");
    for &n in &opts.slots {
        let f = CpuFrame::synthetic(n as usize, cube_address, cube_address);
        let outcome = match gpu::frame::run(&mut b, &f) {
            Ok(r) => {
                let a1 = &r.algorithm1;
                let a2 = &r.algorithm2;
                let rw = a1.reference_read_write.unwrap_or_default();
                println!(
                    "| {n} | {:.1} | {:.1} | {:.2} | {:.1} | {:.2} | {:.1} | {:.1} | {:.2} | {:.1} ({}) | {:.1} ({}) |",
                    a1.time.median_us,
                    a1.reference_read.median_us,
                    a1.ratio_to_read,
                    rw.median_us,
                    a1.ratio_to_read_write.unwrap_or(f64::NAN),
                    a2.time.median_us,
                    a2.reference_read.median_us,
                    a2.ratio_to_read,
                    r.upload.median_us,
                    r.upload_records,
                    r.tlas_build.median_us,
                    r.tlas_build_instances
                );
                SizeOutcome {
                    slots: n,
                    result: Some(r),
                    error: None,
                }
            }
            Err(e) => {
                ok = false;
                println!("| {n} | FAILED: {e} |");
                SizeOutcome {
                    slots: n,
                    result: None,
                    error: Some(e.to_string()),
                }
            }
        };
        frames.push(outcome);
    }

    let mut blas_batches = Vec::new();
    println!();
    println!("| BLAS batch | triangles | build µs (median) | Mtriangles/s |");
    println!("| ---: | ---: | ---: | ---: |");
    for &(meshes, side) in &opts.blas {
        let tris = 2 * side * side;
        let r = GridMesh::new(&mut b, side).and_then(|m| blas_batch(&mut b, &m, meshes));
        blas_batches.push(match r {
            Ok(r) => {
                println!(
                    "| {meshes} x {tris} | {} | {:.1} | {:.1} |",
                    u64::from(meshes) * u64::from(tris),
                    r.build.median_us,
                    r.triangles_per_s / 1e6
                );
                BlasOutcome {
                    meshes,
                    triangles_per_mesh: tris,
                    result: Some(r),
                    error: None,
                }
            }
            Err(e) => {
                ok = false;
                println!("| {meshes} x {tris} | FAILED: {e} |");
                BlasOutcome {
                    meshes,
                    triangles_per_mesh: tris,
                    result: None,
                    error: Some(e.to_string()),
                }
            }
        });
    }
    drop((cube_blas, cube, scratch, b));
    let validation_errors = dev.validation_errors();
    if !validation_errors.is_empty() {
        ok = false;
        eprintln!("gpu_bench: {} validation errors:", validation_errors.len());
        for e in &validation_errors {
            eprintln!("  {e}");
        }
    }
    Ok(Report {
        format: "lipac-gpu-bench",
        version: 1,
        command: std::iter::once("gpu_bench".to_owned())
            .chain(args.iter().cloned())
            .collect::<Vec<_>>()
            .join(" "),
        device: DeviceJson {
            name: info.name.clone(),
            device_type: info.device_type.clone(),
            vendor_id: info.vendor_id,
            device_id: info.device_id,
            driver: info.driver.clone(),
            vulkan: info.api_version.clone(),
            ray_query: info.ray_query,
            ray_tracing_pipeline: info.ray_tracing_pipeline,
            device_local_heap_bytes: info.device_local_heap(),
        },
        reps: opts.reps,
        warmup_ms: warm_ms,
        evict_bytes: opts.evict_mib << 20,
        bandwidth: Some(bandwidth),
        frames,
        blas_batches,
        validation_errors,
        ok,
    })
}
