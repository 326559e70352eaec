//! GPU timestamps (`vkCmdWriteTimestamp2`) in pairs around recorded work,
//! and the statistics of repeated runs.

use ash::vk;
use lipac_vk::{DeviceContext, Recorder, VkError};

/// A timestamp query pool of `2 * pairs` queries.
pub struct Timestamps {
    ctx: DeviceContext,
    pool: vk::QueryPool,
    pairs: u32,
    period_ns: f64,
    mask: u64,
}

impl Timestamps {
    /// A pool for `pairs` intervals; `period_ns` and `valid_bits` from the
    /// device and its queue family.
    pub fn new(
        ctx: &DeviceContext,
        pairs: u32,
        period_ns: f64,
        valid_bits: u32,
    ) -> Result<Self, VkError> {
        if valid_bits == 0 || period_ns <= 0.0 {
            return Err(VkError::InvalidArgument(
                "the queue family writes no timestamps".into(),
            ));
        }
        let info = vk::QueryPoolCreateInfo::default()
            .query_type(vk::QueryType::TIMESTAMP)
            .query_count(2 * pairs);
        // SAFETY: valid device and create info.
        let pool = unsafe { ctx.device().create_query_pool(&info, None) }
            .map_err(|e| VkError::vk("vkCreateQueryPool", e))?;
        let mask = if valid_bits >= 64 {
            u64::MAX
        } else {
            (1u64 << valid_bits) - 1
        };
        Ok(Self {
            ctx: ctx.clone(),
            pool,
            pairs,
            period_ns,
            mask,
        })
    }

    /// Records the reset of every query (before the first [`Self::begin`]).
    pub fn reset(&self, rec: &mut Recorder<'_>) {
        // SAFETY: recording on this device, outside a render pass; the pool
        // is this device's.
        unsafe {
            self.ctx
                .device()
                .cmd_reset_query_pool(rec.raw(), self.pool, 0, 2 * self.pairs)
        };
    }

    fn write(&self, rec: &mut Recorder<'_>, query: u32) {
        // SAFETY: recording on this device (synchronization2 enabled); the
        // query is in range and was reset in this command buffer before.
        unsafe {
            self.ctx.device().cmd_write_timestamp2(
                rec.raw(),
                vk::PipelineStageFlags2::ALL_COMMANDS,
                self.pool,
                query,
            )
        };
    }

    /// Timestamp at the start of interval `i`: written once every earlier
    /// command has finished.
    pub fn begin(&self, rec: &mut Recorder<'_>, i: u32) {
        self.write(rec, 2 * i);
    }

    /// Timestamp at the end of interval `i`.
    pub fn end(&self, rec: &mut Recorder<'_>, i: u32) {
        self.write(rec, 2 * i + 1);
    }

    /// The first `n` intervals, in nanoseconds (after the submission that
    /// wrote them has completed).
    pub fn read_ns(&self, n: u32) -> Result<Vec<f64>, VkError> {
        let mut raw = vec![0u64; 2 * n as usize];
        // SAFETY: the queries were written by a completed submission; the
        // output holds 2n 64-bit values.
        unsafe {
            self.ctx.device().get_query_pool_results(
                self.pool,
                0,
                &mut raw,
                vk::QueryResultFlags::TYPE_64 | vk::QueryResultFlags::WAIT,
            )
        }
        .map_err(|e| VkError::vk("vkGetQueryPoolResults", e))?;
        Ok(raw
            .chunks_exact(2)
            .map(|p| {
                let ticks = (p[1] & self.mask).wrapping_sub(p[0] & self.mask) & self.mask;
                ticks as f64 * self.period_ns
            })
            .collect())
    }
}

impl Drop for Timestamps {
    fn drop(&mut self) {
        // SAFETY: the pool belongs to this device and no pending work uses it
        // (every submission was waited for).
        unsafe { self.ctx.device().destroy_query_pool(self.pool, None) };
    }
}

/// Median, minimum and maximum of repeated times, in microseconds.
#[derive(Clone, Copy, Debug, Default, serde::Serialize)]
pub struct Stats {
    pub median_us: f64,
    pub min_us: f64,
    pub max_us: f64,
    pub runs: usize,
}

impl Stats {
    /// Of times in nanoseconds.
    pub fn of_ns(ns: &[f64]) -> Self {
        if ns.is_empty() {
            return Self::default();
        }
        let mut v: Vec<f64> = ns.iter().map(|t| t / 1e3).collect();
        v.sort_by(f64::total_cmp);
        let median_us = if v.len() % 2 == 1 {
            v[v.len() / 2]
        } else {
            0.5 * (v[v.len() / 2 - 1] + v[v.len() / 2])
        };
        Self {
            median_us,
            min_us: v[0],
            max_us: v[v.len() - 1],
            runs: v.len(),
        }
    }
}
