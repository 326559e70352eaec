//! Prints the acceleration-structure sizes the device reports: BLAS bytes per
//! triangle (built and compacted) for grids of N triangles, and TLAS bytes per
//! instance. Run: `cargo run --release -p lipac-vk --example as_sizes`.

use ash::vk;
use lipac_vk::{
    BlasBatch, Buffer, GpuBlas, GpuTlas, HeadlessContext, IndexFormat, MemoryLocation, OneShot,
    ScratchBuffer, TriangleGeometry, UnitCube, Validation, VkError,
};

/// An n x n grid of quads (2 n^2 triangles) with a bumpy height.
fn grid(n: u32) -> (Vec<[f32; 3]>, Vec<u32>) {
    let mut v = Vec::new();
    for j in 0..=n {
        for i in 0..=n {
            let (x, y) = (i as f32 / n as f32, j as f32 / n as f32);
            v.push([x, y, 0.05 * (17.0 * x).sin() * (13.0 * y).cos()]);
        }
    }
    let mut idx = Vec::new();
    let at = |i: u32, j: u32| j * (n + 1) + i;
    for j in 0..n {
        for i in 0..n {
            idx.extend([
                at(i, j),
                at(i + 1, j),
                at(i, j + 1),
                at(i + 1, j),
                at(i + 1, j + 1),
                at(i, j + 1),
            ]);
        }
    }
    (v, idx)
}

fn main() -> Result<(), VkError> {
    let headless = match HeadlessContext::new(Validation::Off) {
        Ok(h) => h,
        Err(e) => {
            eprintln!("as_sizes: {e}");
            std::process::exit(2);
        }
    };
    let ctx = headless.context();
    println!("device: {}", ctx.device_name());
    println!(
        "minAccelerationStructureScratchOffsetAlignment: {}",
        ctx.limits().min_scratch_offset_alignment
    );
    let flags = vk::BuildAccelerationStructureFlagsKHR::PREFER_FAST_TRACE
        | vk::BuildAccelerationStructureFlagsKHR::ALLOW_COMPACTION;
    let usage = vk::BufferUsageFlags::ACCELERATION_STRUCTURE_BUILD_INPUT_READ_ONLY_KHR;

    let cube = UnitCube::new(ctx)?;
    let mut inputs = Vec::new();
    let mut batch = BlasBatch::new();
    batch.push(&[cube.geometry()], flags)?;
    for n in [1u32, 4, 16, 64, 256] {
        let (v, i) = grid(n);
        let vb = Buffer::with_data(ctx, usage, MemoryLocation::CpuToGpu, &v)?;
        let ib = Buffer::with_data(ctx, usage, MemoryLocation::CpuToGpu, &i)?;
        let g = TriangleGeometry::indexed(
            &vb,
            0,
            12,
            v.len() as u32,
            &ib,
            0,
            IndexFormat::U32,
            (i.len() / 3) as u32,
        )?;
        batch.push(&[g], flags)?;
        inputs.push((vb, ib));
    }
    let mut scratch = ScratchBuffer::new(ctx);
    let mut one_shot = OneShot::new(ctx)?;
    let built = one_shot.run(|rec| batch.record(rec, &mut scratch))?;
    let compacted = built
        .compaction
        .as_ref()
        .map(|q| q.read_sizes())
        .transpose()?
        .unwrap_or_default();
    println!();
    println!("| BLAS | triangles | size (B) | B/triangle | compacted (B) | B/triangle compacted | build scratch (B) |");
    println!("| --- | ---: | ---: | ---: | ---: | ---: | ---: |");
    for (i, blas) in built.blases.iter().enumerate() {
        let name = if i == 0 {
            "unit cube".to_owned()
        } else {
            "grid".to_owned()
        };
        let c = compacted
            .iter()
            .find(|(k, _)| *k == i)
            .map_or(0, |(_, s)| *s);
        row(&name, blas, c);
    }
    println!();
    println!("| TLAS instances | size (B) | B/instance | build scratch (B) |");
    println!("| ---: | ---: | ---: | ---: |");
    let one = GpuTlas::query_sizes(
        ctx,
        1,
        vk::BuildAccelerationStructureFlagsKHR::PREFER_FAST_TRACE,
    )?;
    for n in [1u32, 16, 1024, 65_536, 1_000_000] {
        let s = GpuTlas::query_sizes(
            ctx,
            n,
            vk::BuildAccelerationStructureFlagsKHR::PREFER_FAST_TRACE,
        )?;
        let per = if n > 1 {
            format!(
                "{:.1}",
                (s.acceleration_structure - one.acceleration_structure) as f64 / (n - 1) as f64
            )
        } else {
            "-".into()
        };
        println!(
            "| {n} | {} | {per} | {} |",
            s.acceleration_structure, s.build_scratch
        );
    }
    // The TLAS object holds exactly the queried size.
    let tlas = GpuTlas::new(
        ctx,
        1024,
        vk::BuildAccelerationStructureFlagsKHR::PREFER_FAST_TRACE,
    )?;
    println!(
        "\nTLAS(1024) storage: {} B in a {} B allocation",
        tlas.sizes().acceleration_structure,
        tlas.accel().memory_bytes()
    );
    Ok(())
}

fn row(name: &str, blas: &GpuBlas, compacted: u64) {
    let t = blas.triangle_count() as f64;
    println!(
        "| {name} | {} | {} | {:.1} | {} | {:.1} | {} |",
        blas.triangle_count(),
        blas.size(),
        blas.size() as f64 / t,
        compacted,
        compacted as f64 / t,
        blas.build_sizes().build_scratch
    );
}
