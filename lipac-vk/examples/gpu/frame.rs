//! The synthetic frame of lipac-core's `benches/algorithms.rs` (n slots,
//! ~16 instances per hitbox on a square grid of 16 m cells, a quarter of
//! the hitboxes active, a mix of states, 1 % dead slots), on the GPU: its
//! buffers, GPU Algorithms 1 and 2 checked against lipac-core's CPU
//! reference, and their timings beside the stream of exactly the bytes
//! each must read (docs/HOT_COLD.md).

use super::timing::Stats;
use super::{fill, stream, Bench, Res};
use ash::vk;
use glam::{Vec2, Vec3};
use lipac_core::assembly::{assemble_tlas, AssemblyConfig, AssemblyStats};
use lipac_core::command::CommandBuffer;
use lipac_core::culling::Uploads;
use lipac_core::feedback::process_feedback;
use lipac_core::hitbox_extents::write_extents;
use lipac_core::hitbox_index::HitboxIndex;
use lipac_core::layout::{
    hitbox_bits, instance_bits, tlas_multiset, HitboxRecord, InstanceArrays, InstanceHot,
    InstanceRecord, InstanceState, TlasInstance,
};
use lipac_core::thresholds::Thresholds;
use lipac_vk::{
    hitbox_bounds, AssemblyBuffers, AssemblyPipeline, Buffer, FeedbackBuffers, FeedbackPipeline,
    GpuTlas, InstanceBuffers, RecordUploader, ScratchBuffer, UploadTargets,
};
use serde::Serialize;

const CELL: f32 = 16.0;
const BUILD_INPUT: vk::BufferUsageFlags =
    vk::BufferUsageFlags::ACCELERATION_STRUCTURE_BUILD_INPUT_READ_ONLY_KHR;

/// Square grid of `w * w` cells of [`CELL`] metres.
pub struct Grid {
    pub w: u32,
}

impl HitboxIndex for Grid {
    fn len(&self) -> u32 {
        self.w * self.w
    }
    fn hitbox_at(&self, p: Vec3) -> Option<u32> {
        let (x, z) = ((p.x / CELL).floor(), (p.z / CELL).floor());
        let w = self.w as f32;
        (x >= 0.0 && z >= 0.0 && x < w && z < w).then(|| z as u32 * self.w + x as u32)
    }
    fn xz_bounds(&self, i: u32) -> Option<(Vec2, Vec2)> {
        (i < self.len()).then(|| {
            let lo = Vec2::new((i % self.w) as f32, (i / self.w) as f32) * CELL;
            (lo, lo + Vec2::splat(CELL))
        })
    }
}

/// xorshift64 (the CPU bench's generator, inlined: examples do not link
/// the dev-only test support crate).
struct Rng(u64);

impl Rng {
    fn next(&mut self) -> u32 {
        let mut x = self.0;
        x ^= x << 13;
        x ^= x >> 7;
        x ^= x << 17;
        self.0 = x;
        (x >> 32) as u32
    }
    fn chance(&mut self, p: f32) -> bool {
        (self.next() as f32) < p * u32::MAX as f32
    }
    fn unit(&mut self) -> f32 {
        self.next() as f32 / u32::MAX as f32
    }
}

/// The frame on the CPU.
pub struct CpuFrame {
    pub grid: Grid,
    pub arrays: InstanceArrays,
    pub hits: Vec<u32>,
    /// With the CPU's extents ([`write_extents`]).
    pub hitboxes: Vec<HitboxRecord>,
    pub config: AssemblyConfig,
    pub thresholds: Thresholds,
}

impl CpuFrame {
    /// `n` slots; every instance with a BLAS references `blas` (a real
    /// BLAS, so the assembled records build a valid TLAS), counting boxes
    /// `unit_cube`.
    pub fn synthetic(n: usize, blas: u64, unit_cube: u64) -> Self {
        let w = ((n as f64 / 16.0).sqrt().ceil() as u32).max(1);
        let grid = Grid { w };
        let mut rng = Rng(0x9E37_79B9_7F4A_7C15 ^ n as u64);
        let mut hitboxes: Vec<HitboxRecord> = (0..grid.len())
            .map(|_| {
                let mut h = HitboxRecord::default();
                if rng.chance(0.25) {
                    h.packed = hitbox_bits::ACTIVE;
                }
                h
            })
            .collect();
        let mut instances = Vec::with_capacity(n);
        let mut hits = Vec::with_capacity(n);
        for slot in 0..n {
            let hb = if rng.chance(0.9) {
                (slot / 16) as u32 % grid.len()
            } else {
                rng.next() % grid.len()
            };
            let (lo, _) = grid.xz_bounds(hb).unwrap_or_default();
            let p = Vec3::new(lo.x + rng.unit() * 14.0, 0.0, lo.y + rng.unit() * 14.0);
            let size = Vec3::new(1.0 + rng.unit(), 2.0 + 8.0 * rng.unit(), 1.0 + rng.unit());
            let unique = rng.chance(0.15);
            let active_hb = hitboxes[hb as usize].is_active();
            let r = rng.unit();
            let state = match (active_hb, unique) {
                (true, false) if r < 0.95 => InstanceState::Active,
                (true, true) if r < 0.6 => InstanceState::Omitted,
                (true, true) if r < 0.95 => InstanceState::Active,
                (false, _) if r < 0.01 => InstanceState::Active,
                _ => InstanceState::Inactive,
            };
            let mut packed = instance_bits::ALIVE | (0x7F << instance_bits::MASK_SHIFT);
            if unique {
                packed |= instance_bits::UNIQUE_BLAS;
            }
            if rng.chance(0.01) {
                packed &= !instance_bits::ALIVE;
            }
            let mut m = InstanceRecord {
                transform: [1.0, 0.0, 0.0, p.x, 0.0, 1.0, 0.0, p.y, 0.0, 0.0, 1.0, p.z],
                aabb_min: p.to_array(),
                aabb_max: (p + size).to_array(),
                hitbox: hb,
                packed,
                blas: if rng.chance(0.98) { blas } else { 0 },
                sbt_offset: 0,
                lod: 0,
            };
            m.set_state(state);
            instances.push(m);
            hits.push(match state {
                InstanceState::Inactive => 0,
                _ if rng.chance(0.05) => rng.next() % 2000,
                _ => rng.next() % 64,
            });
        }
        let arrays = InstanceArrays::from_records(&instances);
        write_extents(&arrays, &mut hitboxes);
        Self {
            grid,
            arrays,
            hits,
            hitboxes,
            config: AssemblyConfig::new(unit_cube),
            thresholds: Thresholds::paper(),
        }
    }

    pub fn slots(&self) -> usize {
        self.arrays.len()
    }
}

/// The frame's buffers on the GPU (device-local), with pristine copies of
/// what the passes write, restored before every timed run.
pub struct GpuFrame {
    pub hot: Buffer,
    pub tlas: Buffer,
    pub bounds: Buffer,
    pub hits: Buffer,
    pub rates: Buffer,
    pub hitboxes: Buffer,
    pub hitbox_bounds: Buffer,
    pub tlas_out: Buffer,
    pub tlas_counter: Buffer,
    pub commands: Buffer,
    pub command_counter: Buffer,
    pub hot_pristine: Buffer,
    pub hitboxes_pristine: Buffer,
}

impl GpuFrame {
    pub fn upload(b: &mut Bench<'_>, f: &CpuFrame) -> Res<Self> {
        let n = f.slots();
        let none = vk::BufferUsageFlags::empty();
        let tlas_capacity = n + f.hitboxes.len();
        let ctx = b.ctx().clone();
        let tlas_out = Buffer::named(
            &ctx,
            "gpu bench TLAS records",
            (tlas_capacity * 64) as u64,
            super::STORAGE_XFER | BUILD_INPUT,
            lipac_vk::MemoryLocation::GpuOnly,
        )?;
        let commands = Buffer::named(
            &ctx,
            "gpu bench commands",
            (n.max(1) * 4) as u64,
            super::STORAGE_XFER,
            lipac_vk::MemoryLocation::GpuOnly,
        )?;
        Ok(Self {
            hot: b.upload("hot", none, f.arrays.hot())?,
            tlas: b.upload("slot TLAS records", none, f.arrays.tlas())?,
            bounds: b.upload("bounds", none, f.arrays.bounds())?,
            hits: b.upload("hits", none, &f.hits)?,
            rates: b.upload("rates", none, &vec![0u32; n])?,
            hitboxes: b.upload("hitboxes", none, &f.hitboxes)?,
            hitbox_bounds: b.upload("hitbox bounds", none, &hitbox_bounds(&f.grid))?,
            tlas_out,
            tlas_counter: b.upload("TLAS counter", none, &[0u32; 4])?,
            commands,
            command_counter: b.upload("command counter", none, &[0u32; 4])?,
            hot_pristine: b.upload("hot (pristine)", none, f.arrays.hot())?,
            hitboxes_pristine: b.upload("hitboxes (pristine)", none, &f.hitboxes)?,
        })
    }

    fn instances(&self) -> InstanceBuffers<'_> {
        InstanceBuffers {
            hot: &self.hot,
            tlas: &self.tlas,
            bounds: &self.bounds,
        }
    }

    /// Records the restore of what the passes write.
    fn restore(&self, rec: &mut lipac_vk::Recorder<'_>) {
        stream::copy(rec, &self.hot_pristine, &self.hot, self.hot.size());
        stream::copy(
            rec,
            &self.hitboxes_pristine,
            &self.hitboxes,
            self.hitboxes.size(),
        );
    }
}

/// What a pass must read and write, and its time against the stream of
/// those bytes.
#[derive(Clone, Debug, Default, Serialize)]
pub struct PassResult {
    /// `equal to the CPU reference` once checked.
    pub check: String,
    pub time: Stats,
    pub bytes_read: u64,
    pub bytes_written: u64,
    /// Streaming `bytes_read` (compute shader).
    pub reference_read: Stats,
    /// `time.median / reference_read.median`.
    pub ratio_to_read: f64,
    /// Streaming `bytes_read` and writing `bytes_written` (Algorithm 1).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub reference_read_write: Option<Stats>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub ratio_to_read_write: Option<f64>,
}

/// One size of the frame: the checked and timed passes, the record upload
/// and the TLAS build over Algorithm 1's output.
#[derive(Clone, Debug, Default, Serialize)]
pub struct FrameResult {
    pub slots: u64,
    pub hitboxes: u64,
    /// Algorithm 1's records: active instances, counting boxes of omitted
    /// instances and of inactive hitboxes.
    pub tlas_records: u64,
    pub active: u64,
    pub omitted_boxes: u64,
    pub hitbox_boxes: u64,
    /// Algorithm 2's commands.
    pub commands: u64,
    pub algorithm1: PassResult,
    pub algorithm2: PassResult,
    /// The record upload of 1 % of the slots (in runs of 16).
    pub upload_records: u64,
    pub upload: Stats,
    /// The TLAS build over the slots + hitboxes records Algorithm 1 wrote
    /// (`LipacVk` builds over that count; records past the counter are
    /// zero, inactive).
    pub tlas_build_instances: u64,
    pub tlas_build: Stats,
}

fn ratio(a: &Stats, b: &Stats) -> f64 {
    if b.median_us > 0.0 {
        a.median_us / b.median_us
    } else {
        f64::NAN
    }
}

fn cpu_algorithm1(f: &CpuFrame) -> Res<(Vec<TlasInstance>, Vec<HitboxRecord>, AssemblyStats)> {
    let mut hitboxes = f.hitboxes.clone();
    let mut out = Vec::new();
    let stats = assemble_tlas(&f.arrays, &mut hitboxes, &f.grid, &f.config, &mut out)
        .map_err(|e| format!("CPU Algorithm 1: {e:?}"))?;
    Ok((out, hitboxes, stats))
}

/// Checks GPU Algorithms 1 and 2 against the CPU reference on `f`, then
/// times both, the references, the upload and the TLAS build.
/// The BLASes `f`'s records reference must stay alive meanwhile.
pub fn run(b: &mut Bench<'_>, f: &CpuFrame) -> Res<FrameResult> {
    let ctx = b.ctx().clone();
    let n = f.slots();
    let h = f.hitboxes.len();
    let g = GpuFrame::upload(b, f)?;
    let assembly = AssemblyPipeline::new(&ctx)?;
    let feedback = FeedbackPipeline::new(&ctx)?;
    let ab = assembly.bind(&AssemblyBuffers {
        instances: g.instances(),
        hitboxes: &g.hitboxes,
        hitbox_bounds: &g.hitbox_bounds,
        tlas_instances: &g.tlas_out,
        tlas_counter: &g.tlas_counter,
    })?;
    let fb = feedback.bind(&FeedbackBuffers {
        instance_hot: &g.hot,
        instance_hits: &g.hits,
        hitboxes: &g.hitboxes,
        commands: &g.commands,
        command_counter: &g.command_counter,
        instance_rates: &g.rates,
    })?;
    let slots = n as u32;
    let mut out = FrameResult {
        slots: n as u64,
        hitboxes: h as u64,
        ..FrameResult::default()
    };

    // Algorithm 1 against the CPU.
    let (cpu_tlas, cpu_hitboxes, st) = cpu_algorithm1(f)?;
    b.one_shot.run(|rec| {
        fill(rec, &g.tlas_out, 0xA5A5_A5A5);
        assembly.record(rec, &ab, &f.config, slots)
    })?;
    let counter = b.download::<u32>(&g.tlas_counter, 1)?[0] as usize;
    let gpu_tlas: Vec<TlasInstance> = b.download(&g.tlas_out, n + h)?;
    if counter != cpu_tlas.len() {
        return Err(format!(
            "{n} slots: Algorithm 1 wrote {counter} records, the CPU {}",
            cpu_tlas.len()
        )
        .into());
    }
    if tlas_multiset(&gpu_tlas[..counter]) != tlas_multiset(&cpu_tlas) {
        return Err(format!("{n} slots: Algorithm 1's records differ from the CPU's").into());
    }
    if gpu_tlas[counter..]
        .iter()
        .any(|r| bytemuck::bytes_of(r).iter().any(|&x| x != 0))
    {
        return Err(format!("{n} slots: Algorithm 1 left records past its counter").into());
    }
    let gpu_hitboxes: Vec<HitboxRecord> = b.download(&g.hitboxes, h)?;
    if bytemuck::cast_slice::<_, u8>(&gpu_hitboxes) != bytemuck::cast_slice::<_, u8>(&cpu_hitboxes)
    {
        return Err(format!("{n} slots: Algorithm 1's hitbox records differ").into());
    }
    out.tlas_records = counter as u64;
    out.active = u64::from(st.active);
    out.omitted_boxes = u64::from(st.omitted_boxes);
    out.hitbox_boxes = u64::from(st.hitbox_boxes);
    out.algorithm1.check =
        "equal to lipac-core's assemble_tlas (record multiset, hitbox records)".into();

    // Algorithm 2 against the CPU (from the pristine records).
    let mut hot: Vec<InstanceHot> = f.arrays.hot().to_vec();
    let mut hitboxes = f.hitboxes.clone();
    let mut commands = CommandBuffer::new(slots.max(1));
    let fs = process_feedback(
        &mut hot,
        &f.hits,
        &mut hitboxes,
        &f.thresholds,
        &mut commands,
    )
    .map_err(|e| format!("CPU Algorithm 2: {e:?}"))?;
    if fs.overflowed != 0 {
        return Err("the CPU reference overflowed its command buffer".into());
    }
    b.one_shot.run(|rec| {
        g.restore(rec);
        feedback.record(rec, &fb, &f.thresholds, slots)
    })?;
    let requested = b.download::<u32>(&g.command_counter, 1)?[0];
    if requested != commands.requested() {
        return Err(format!(
            "{n} slots: Algorithm 2 requested {requested} commands, the CPU {}",
            commands.requested()
        )
        .into());
    }
    let mut gpu_words: Vec<u32> = b.download(&g.commands, requested as usize)?;
    let mut cpu_words = commands.words().to_vec();
    gpu_words.sort_unstable();
    cpu_words.sort_unstable();
    if gpu_words != cpu_words {
        return Err(format!("{n} slots: Algorithm 2's commands differ from the CPU's").into());
    }
    let gpu_hot: Vec<InstanceHot> = b.download(&g.hot, n)?;
    if bytemuck::cast_slice::<_, u8>(&gpu_hot) != bytemuck::cast_slice::<_, u8>(&hot) {
        return Err(format!("{n} slots: Algorithm 2's instance records differ").into());
    }
    let gpu_hitboxes: Vec<HitboxRecord> = b.download(&g.hitboxes, h)?;
    if bytemuck::cast_slice::<_, u8>(&gpu_hitboxes) != bytemuck::cast_slice::<_, u8>(&hitboxes) {
        return Err(format!("{n} slots: Algorithm 2's hitbox records differ").into());
    }
    out.commands = u64::from(requested);
    out.algorithm2.check =
        "equal to lipac-core's process_feedback (instance and hitbox records, command multiset, counter)"
            .into();

    // The bytes each pass must read (docs/HOT_COLD.md): Algorithm 1 every
    // hot record, the TLAS record of an active slot it emits, the AABB of an
    // omitted one, every hitbox record and its bounds; it writes its
    // records (and the hitboxes' hit words). Algorithm 2 (the paper's rule)
    // every hot record and hit counter and the hitbox records.
    let hot_b = 8 * n as u64;
    let hitbox_b = 20 * h as u64;
    let r1 = hot_b + 64 * out.active + 24 * out.omitted_boxes + hitbox_b + 16 * h as u64;
    let w1 = 64 * out.tlas_records + 4 * h as u64;
    let r2 = hot_b + 4 * n as u64 + hitbox_b;
    let src = b.random_buffer("stream source", r1.max(r2) + 16, 0xC0FFEE ^ n as u64)?;
    let dst = Buffer::named(
        &ctx,
        "stream destination",
        w1.max(16),
        super::STORAGE_XFER,
        lipac_vk::MemoryLocation::GpuOnly,
    )?;

    let config = f.config;
    out.algorithm1.time = b.timed(
        |rec, _| {
            stream::copy(rec, &g.hitboxes_pristine, &g.hitboxes, g.hitboxes.size());
            Ok(())
        },
        |rec, _| assembly.record(rec, &ab, &config, slots),
    )?;
    out.algorithm1.bytes_read = r1;
    out.algorithm1.bytes_written = w1;
    out.algorithm1.reference_read = b.reference(&src, &dst, r1 / 16 * 16, 0)?;
    let rw = b.reference(&src, &dst, r1 / 16 * 16, w1 / 16 * 16)?;
    out.algorithm1.ratio_to_read = ratio(&out.algorithm1.time, &out.algorithm1.reference_read);
    out.algorithm1.ratio_to_read_write = Some(ratio(&out.algorithm1.time, &rw));
    out.algorithm1.reference_read_write = Some(rw);

    let th = f.thresholds;
    out.algorithm2.time = b.timed(
        |rec, _| {
            g.restore(rec);
            Ok(())
        },
        |rec, _| feedback.record(rec, &fb, &th, slots),
    )?;
    out.algorithm2.bytes_read = r2;
    out.algorithm2.reference_read = b.reference(&src, &dst, r2 / 16 * 16, 0)?;
    out.algorithm2.ratio_to_read = ratio(&out.algorithm2.time, &out.algorithm2.reference_read);

    // The record upload: 1 % of the slots, in runs of 16, the same records
    // again (the GPU arrays keep their content; the state bits are kept).
    let uploader = RecordUploader::new(&ctx)?;
    let mut ub = uploader.bind(&UploadTargets {
        instances: g.instances(),
        hitboxes: &g.hitboxes,
        instance_rates: &g.rates,
    })?;
    let uploads = Uploads {
        records: (0..slots)
            .step_by(1600)
            .map(|s| s..(s + 16).min(slots))
            .collect(),
        ..Uploads::default()
    };
    out.upload_records = uploads
        .records
        .iter()
        .map(|r| u64::from(r.len() as u32))
        .sum();
    let arrays = &f.arrays;
    let mut staged: Option<Result<(), lipac_vk::VkError>> = None;
    out.upload = b.timed(
        |_, _| Ok(()),
        |rec, _| {
            let r = uploader.record(rec, &mut ub, &uploads, arrays).map(|_| ());
            if r.is_err() {
                staged = Some(r.clone());
            }
            r
        },
    )?;
    if let Some(Err(e)) = staged {
        return Err(e.into());
    }

    // The TLAS over Algorithm 1's output (as LipacVk builds it).
    b.one_shot
        .run(|rec| assembly.record(rec, &ab, &config, slots))?;
    let count = (n + h) as u32;
    let flags = vk::BuildAccelerationStructureFlagsKHR::PREFER_FAST_TRACE;
    let mut tlas = GpuTlas::new(&ctx, count, flags)?;
    let mut scratch = ScratchBuffer::new(&ctx);
    let mut retired = Vec::new();
    out.tlas_build_instances = u64::from(count);
    out.tlas_build = b.timed(
        |_, _| Ok(()),
        |rec, _| {
            let o = tlas.record_build(rec, &g.tlas_out, 0, count, &mut scratch)?;
            retired.push(o);
            Ok(())
        },
    )?;
    drop(retired);
    Ok(out)
}
