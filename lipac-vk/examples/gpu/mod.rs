//! Shared by the GPU examples (`gpu_bench`, `device_profile`): the device
//! ([`device::GpuDevice`]), timestamps ([`timing`]), the bandwidth
//! reference ([`stream`]), the synthetic frame of Algorithms 1 and 2 with
//! its CPU reference ([`frame`]), and acceleration-structure builds
//! ([`accel`]).
#![allow(dead_code)]

pub mod accel;
pub mod device;
pub mod frame;
pub mod stream;
pub mod timing;

use ash::vk;
use bytemuck::Pod;
use lipac_vk::{Buffer, DeviceContext, MemoryLocation, OneShot, Recorder, VkError};

use device::GpuDevice;
use stream::StreamKernel;
use timing::{Stats, Timestamps};

/// The examples' error type.
pub type Res<T> = Result<T, Box<dyn std::error::Error>>;

/// Every buffer the examples stage through: storage, copies both ways.
pub const STORAGE_XFER: vk::BufferUsageFlags = vk::BufferUsageFlags::from_raw(
    vk::BufferUsageFlags::STORAGE_BUFFER.as_raw()
        | vk::BufferUsageFlags::TRANSFER_SRC.as_raw()
        | vk::BufferUsageFlags::TRANSFER_DST.as_raw(),
);

/// The device, a one-shot submitter, the stream kernel and the buffers of
/// the cache eviction that precedes every timed run.
pub struct Bench<'a> {
    pub dev: &'a GpuDevice,
    pub one_shot: OneShot,
    pub stream: StreamKernel,
    /// Streamed (read) before every timed run so that the run starts from
    /// memory, not from the cache a previous run or restore filled.
    evict: Option<Buffer>,
    /// A small destination for read-only streams.
    sink: Buffer,
    /// Repetitions of each timed run.
    pub reps: u32,
}

impl<'a> Bench<'a> {
    /// `evict_bytes` of eviction before every timed run (0: none).
    pub fn new(dev: &'a GpuDevice, reps: u32, evict_bytes: u64) -> Res<Self> {
        let ctx = dev.ctx();
        let mut one_shot = OneShot::new(ctx)?;
        let evict = if evict_bytes >= 16 {
            let b = Buffer::named(
                ctx,
                "gpu bench eviction",
                evict_bytes,
                STORAGE_XFER,
                MemoryLocation::GpuOnly,
            )?;
            one_shot.run(|rec| {
                fill(rec, &b, 0x5EED_1234);
                Ok(())
            })?;
            Some(b)
        } else {
            None
        };
        Ok(Self {
            dev,
            one_shot,
            stream: StreamKernel::new(ctx)?,
            evict,
            sink: Buffer::named(
                ctx,
                "gpu bench sink",
                256,
                STORAGE_XFER,
                MemoryLocation::GpuOnly,
            )?,
            reps: reps.max(1),
        })
    }

    pub fn ctx(&self) -> &DeviceContext {
        self.dev.ctx()
    }

    /// Runs `reps` timed repetitions in one submission: per repetition
    /// `prepare` (not timed), the eviction (not timed), then `work` between
    /// two timestamps. Returns the statistics of the `reps` intervals.
    pub fn timed(
        &mut self,
        mut prepare: impl FnMut(&mut Recorder<'_>, u32) -> Result<(), VkError>,
        mut work: impl FnMut(&mut Recorder<'_>, u32) -> Result<(), VkError>,
    ) -> Res<Stats> {
        let info = &self.dev.info;
        let ts = Timestamps::new(
            self.dev.ctx(),
            self.reps,
            info.timestamp_period_ns,
            info.timestamp_valid_bits,
        )?;
        let (stream, evict, sink, reps) = (&self.stream, &self.evict, &self.sink, self.reps);
        self.one_shot.run(|rec| {
            ts.reset(rec);
            for i in 0..reps {
                prepare(rec, i)?;
                if let Some(e) = evict {
                    stream.record(rec, e, sink, e.size() / 16 * 16, 0)?;
                }
                ts.begin(rec, i);
                work(rec, i)?;
                ts.end(rec, i);
            }
            Ok(())
        })?;
        Ok(Stats::of_ns(&ts.read_ns(reps)?))
    }

    /// The reference: reading `read` bytes of `src` and writing `write`
    /// bytes of `dst`, timed like the passes.
    pub fn reference(&mut self, src: &Buffer, dst: &Buffer, read: u64, write: u64) -> Res<Stats> {
        let stream = StreamKernel::new(self.dev.ctx())?;
        self.timed(
            |_, _| Ok(()),
            |rec, _| stream.record(rec, src, dst, read, write),
        )
    }

    /// Streams the eviction buffer (or nothing) for at least `ms`
    /// milliseconds of wall time, so the GPU's clocks are up when timing
    /// starts. Returns the wall time spent and the streams run.
    pub fn warm_up(&mut self, src: &Buffer, ms: u64) -> Res<(f64, u32)> {
        let start = std::time::Instant::now();
        let mut runs = 0;
        let (stream, sink) = (&self.stream, &self.sink);
        while start.elapsed().as_millis() < u128::from(ms) || runs == 0 {
            self.one_shot.run(|rec| {
                for _ in 0..8 {
                    stream.record(rec, src, sink, src.size() / 16 * 16, 0)?;
                }
                Ok(())
            })?;
            runs += 8;
        }
        Ok((start.elapsed().as_secs_f64() * 1e3, runs))
    }

    /// A device-local copy of `data` with `usage` (plus transfers and
    /// storage), uploaded through a host-visible staging buffer.
    pub fn upload<T: Pod>(
        &mut self,
        name: &str,
        usage: vk::BufferUsageFlags,
        data: &[T],
    ) -> Res<Buffer> {
        let bytes: &[u8] = bytemuck::cast_slice(data);
        let size = (bytes.len() as u64).max(16);
        let ctx = self.dev.ctx();
        let dst = Buffer::named(
            ctx,
            name,
            size,
            usage | STORAGE_XFER,
            MemoryLocation::GpuOnly,
        )?;
        if !bytes.is_empty() {
            let staging = Buffer::with_data(
                ctx,
                vk::BufferUsageFlags::TRANSFER_SRC,
                MemoryLocation::CpuToGpu,
                bytes,
            )?;
            self.one_shot.run(|rec| {
                stream::copy(rec, &staging, &dst, bytes.len() as u64);
                Ok(())
            })?;
        } else {
            self.one_shot.run(|rec| {
                fill(rec, &dst, 0);
                Ok(())
            })?;
        }
        Ok(dst)
    }

    /// The first `count` `T`s of a device-local buffer.
    pub fn download<T: Pod>(&mut self, src: &Buffer, count: usize) -> Res<Vec<T>> {
        let bytes = (count * std::mem::size_of::<T>()) as u64;
        if bytes == 0 {
            return Ok(Vec::new());
        }
        let staging = Buffer::new(
            self.dev.ctx(),
            bytes,
            vk::BufferUsageFlags::TRANSFER_DST,
            MemoryLocation::GpuToCpu,
        )?;
        self.one_shot.run(|rec| {
            stream::copy(rec, src, &staging, bytes);
            Ok(())
        })?;
        Ok(staging.read(0, count)?)
    }

    /// A device-local buffer of `bytes` pseudo-random bytes (the stream
    /// sources: never zeros, which some GPUs move faster).
    pub fn random_buffer(&mut self, name: &str, bytes: u64, seed: u64) -> Res<Buffer> {
        let words = bytes.div_ceil(8).max(2) as usize;
        let mut x = seed | 1;
        let data: Vec<u64> = (0..words)
            .map(|_| {
                x ^= x << 13;
                x ^= x >> 7;
                x ^= x << 17;
                x
            })
            .collect();
        self.upload(name, vk::BufferUsageFlags::empty(), &data)
    }
}

/// Records `vkCmdFillBuffer` of the whole buffer with `word`, between barriers.
pub fn fill(rec: &mut Recorder<'_>, b: &Buffer, word: u32) {
    stream::barrier(rec);
    // SAFETY: recording on this device outside a render pass; the buffer is
    // live with TRANSFER_DST usage (the examples create theirs so).
    unsafe {
        rec.context()
            .device()
            .cmd_fill_buffer(rec.raw(), b.raw(), 0, vk::WHOLE_SIZE, word)
    };
    stream::barrier(rec);
}

/// Parses `100k`, `1M`, `10m`, `2500` as a count.
pub fn parse_count(s: &str) -> Result<u32, String> {
    let s = s.trim();
    let (digits, mult) = match s.chars().last() {
        Some('k' | 'K') => (&s[..s.len() - 1], 1_000u64),
        Some('m' | 'M') => (&s[..s.len() - 1], 1_000_000u64),
        _ => (s, 1),
    };
    let v: u64 = digits
        .parse()
        .map_err(|_| format!("`{s}` is not a count (e.g. 100k, 1M, 2500)"))?;
    u32::try_from(v * mult).map_err(|_| format!("`{s}` is too large"))
}

/// The value of `--name VALUE` in `args`, if given.
pub fn arg_value(args: &[String], name: &str) -> Option<String> {
    args.iter()
        .position(|a| a == name)
        .and_then(|i| args.get(i + 1).cloned())
}
