//! Real out-of-device-memory on the local GPU: a buffer larger than the
//! device-local heap, then the heap filled buffer by buffer until the
//! driver refuses. Each must come back as lipac's out-of-memory error (no
//! panic, no abort), everything freed afterwards (the context's memory
//! statistics back to zero), and GPU Algorithms 1 and 2 must run again and
//! equal the CPU reference. (Failing every allocation of a frame loop on
//! purpose is lipac-vk's `allocation_faults` test.)
//!
//! ```text
//! cargo run --release -p lipac-vk --example device_oom -- --out oom.json [--check-slots 100k]
//! ```
//!
//! On a CPU implementation (lavapipe) the heap is the host's memory: the
//! fill is not run there, and the single buffer only where the device
//! allows a buffer that large; both say "not run" and why. Exits 1 when a
//! case that ran failed.

mod gpu;

use ash::vk;
use gpu::device::GpuDevice;
use gpu::frame::CpuFrame;
use gpu::{arg_value, parse_count, Bench, Res};
use lipac_vk::{BlasBatch, Buffer, MemoryLocation, ScratchBuffer, UnitCube, VkError};
use serde::Serialize;
use std::io::Write;

#[derive(Serialize)]
struct Case {
    name: &'static str,
    /// `passed`, `failed` or `not run`.
    status: &'static str,
    detail: String,
}

#[derive(Serialize)]
struct Report {
    format: &'static str,
    version: u32,
    device: String,
    device_type: String,
    device_local_heap_bytes: u64,
    max_buffer_size: u64,
    max_memory_allocation_size: u64,
    cases: Vec<Case>,
    ok: bool,
}

fn oom(e: &VkError) -> bool {
    matches!(
        e,
        VkError::Vulkan {
            result: vk::Result::ERROR_OUT_OF_DEVICE_MEMORY,
            ..
        }
    )
}

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let Some(out) = arg_value(&args, "--out") else {
        eprintln!("usage: device_oom --out FILE.json [--check-slots 100k]");
        std::process::exit(2);
    };
    let slots = match parse_count(&arg_value(&args, "--check-slots").unwrap_or("100k".into())) {
        Ok(s) if s > 0 && s <= lipac_core::layout::MAX_SLOTS => s,
        _ => {
            eprintln!("device_oom: --check-slots: a count 1..=2^24");
            std::process::exit(2);
        }
    };
    let mut file = match std::fs::OpenOptions::new()
        .write(true)
        .create_new(true)
        .open(&out)
    {
        Ok(f) => f,
        Err(e) => {
            eprintln!("device_oom: --out {out}: {e} (it is never overwritten)");
            std::process::exit(2);
        }
    };
    let dev = match GpuDevice::new() {
        Ok(d) => d,
        Err(e) => {
            eprintln!("device_oom: no usable Vulkan device: {e}");
            std::process::exit(2);
        }
    };
    println!("device_oom: {}", dev.describe());
    let cases = run(&dev, slots);
    let i = &dev.info;
    let report = Report {
        format: "lipac-device-oom",
        version: 1,
        device: i.name.clone(),
        device_type: i.device_type.clone(),
        device_local_heap_bytes: i.device_local_heap(),
        max_buffer_size: i.max_buffer_size,
        max_memory_allocation_size: i.max_memory_allocation_size,
        ok: cases.iter().all(|c| c.status != "failed"),
        cases,
    };
    let errors = dev.validation_errors();
    drop(dev);
    for c in &report.cases {
        println!("device_oom: {}: {} ({})", c.name, c.status, c.detail);
    }
    let text = serde_json::to_string_pretty(&report).unwrap_or_default();
    if let Err(e) = file.write_all(text.as_bytes()) {
        eprintln!("device_oom: writing {out}: {e}");
        std::process::exit(1);
    }
    if !errors.is_empty() {
        eprintln!("device_oom: validation errors: {errors:?}");
        std::process::exit(1);
    }
    if !report.ok {
        std::process::exit(1);
    }
}

fn run(dev: &GpuDevice, slots: u32) -> Vec<Case> {
    let mut cases = Vec::new();
    let ctx = dev.ctx();
    let info = &dev.info;
    let heap = info.device_local_heap();
    let usage = vk::BufferUsageFlags::STORAGE_BUFFER;
    let freed = || {
        let s = ctx.memory_stats();
        (s.buffers == 0 && s.bytes == 0)
            .then_some(())
            .ok_or_else(|| format!("{} buffers ({} B) still held", s.buffers, s.bytes))
    };

    // 1. One buffer larger than the heap.
    let big = heap.saturating_add(1 << 30);
    cases.push(if big > info.max_buffer_size {
        Case {
            name: "a buffer larger than the device-local heap",
            status: "not run",
            detail: format!(
                "maxBufferSize {} B is below heap + 1 GiB = {big} B",
                info.max_buffer_size
            ),
        }
    } else {
        let r = Buffer::new(ctx, big, usage, MemoryLocation::GpuOnly);
        match (r, freed()) {
            (Err(e), Ok(())) if oom(&e) => Case {
                name: "a buffer larger than the device-local heap",
                status: "passed",
                detail: format!("{big} B: {e}; nothing held after"),
            },
            (Err(e), held) => Case {
                name: "a buffer larger than the device-local heap",
                status: "failed",
                detail: format!("{big} B: {e}, not out of memory ({held:?})"),
            },
            (Ok(_), _) => Case {
                name: "a buffer larger than the device-local heap",
                status: "failed",
                detail: format!("{big} B were allocated on a {heap} B heap"),
            },
        }
    });

    // 2. The heap filled until the driver refuses.
    let name = "device-local memory filled until the driver refuses";
    cases.push(if info.is_cpu() {
        Case {
            name,
            status: "not run",
            detail: "a CPU implementation's heap is the host's memory".into(),
        }
    } else {
        let chunk = (heap / 16)
            .min(info.max_buffer_size)
            .min(info.max_memory_allocation_size.max(1 << 20))
            .max(1 << 20);
        let start = std::time::Instant::now();
        let mut held = Vec::new();
        let mut total = 0u64;
        let outcome = loop {
            if total > heap {
                break Err(format!(
                    "the driver gave {total} B on a {heap} B heap without refusing"
                ));
            }
            if start.elapsed().as_secs() > 60 {
                break Err(format!("no refusal within 60 s ({total} B held)"));
            }
            match Buffer::new(ctx, chunk, usage, MemoryLocation::GpuOnly) {
                Ok(b) => {
                    total += b.allocation_size();
                    held.push(b);
                }
                Err(e) if oom(&e) => break Ok(e),
                Err(e) => break Err(format!("{e}: not out of memory")),
            }
        };
        let n = held.len();
        drop(held);
        match (outcome, freed()) {
            (Ok(e), Ok(())) => Case {
                name,
                status: "passed",
                detail: format!(
                    "{n} buffers of {chunk} B ({total} B of a {heap} B heap) held, the next \
                     refused in {:.2} s: {e}; all freed",
                    start.elapsed().as_secs_f64()
                ),
            },
            (Ok(e), Err(held)) => Case {
                name,
                status: "failed",
                detail: format!("refused ({e}) but {held}"),
            },
            (Err(why), _) => Case {
                name,
                status: "failed",
                detail: why,
            },
        }
    });

    // 3. With memory back, GPU Algorithms 1 and 2 run and equal the CPU.
    let name = "GPU Algorithms 1 and 2 equal the CPU reference after the refusals";
    let check = || -> Res<String> {
        let mut b = Bench::new(dev, 1, 0)?;
        let cube = UnitCube::new(ctx)?;
        let mut batch = BlasBatch::new();
        batch.push(&[cube.geometry()], gpu::accel::STATIC_BLAS_FLAGS)?;
        let mut scratch = ScratchBuffer::new(ctx);
        let built = b.one_shot.run(|rec| batch.record(rec, &mut scratch))?;
        let a = built.blases[0].device_address();
        let f = gpu::frame::run(&mut b, &CpuFrame::synthetic(slots as usize, a, a))?;
        Ok(format!(
            "{} slots: {}; {}",
            f.slots, f.algorithm1.check, f.algorithm2.check
        ))
    };
    cases.push(match check() {
        Ok(detail) => match freed() {
            Ok(()) => Case {
                name,
                status: "passed",
                detail,
            },
            Err(held) => Case {
                name,
                status: "failed",
                detail: held,
            },
        },
        Err(e) => Case {
            name,
            status: "failed",
            detail: e.to_string(),
        },
    });
    cases
}
