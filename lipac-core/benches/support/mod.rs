//! Shared by `benches/allocator.rs` and `examples/fragmentation.rs`: a
//! seeded PRNG (from lipac-test-support), seeded allocation traces, and one adapter trait over lipac's
//! [`TlsfAllocator`], `offset-allocator` and `rlsf`.
#![allow(dead_code)]

use std::alloc::Layout;
use std::mem::MaybeUninit;
use std::ptr::NonNull;

use lipac_core::allocator::{AllocHandle, TlsfAllocator};

// ---- PRNG -----------------------------------------------------------------

/// The seeded generator of every trace: lipac-test-support's SplitMix64
/// (same stream as the copy that lived here).
pub use lipac_test_support::{Rng64, SplitMix64};

/// Zipf(s) over ranks `0..n` by inverse CDF.
pub struct Zipf {
    cdf: Vec<f64>,
}

impl Zipf {
    pub fn new(n: usize, s: f64) -> Self {
        let mut acc = 0.0;
        let cdf = (1..=n)
            .map(|k| {
                acc += 1.0 / (k as f64).powf(s);
                acc
            })
            .collect();
        Zipf { cdf }
    }
    pub fn sample(&self, rng: &mut SplitMix64) -> usize {
        let u = rng.unit_f64() * self.cdf[self.cdf.len() - 1];
        self.cdf
            .partition_point(|&c| c <= u)
            .min(self.cdf.len() - 1)
    }
}

// ---- traces ---------------------------------------------------------------

/// One trace operation. Every allocation gets a fresh slot number.
#[derive(Clone, Copy, Debug)]
pub enum Op {
    Alloc { slot: u32, size: u32 },
    Free { slot: u32 },
}

/// A pre-generated trace: `setup` brings the buffer to its working state
/// (not timed), `ops` is the timed part, `ramp` keeps going with a bias to
/// allocation until the buffer must overflow (fragmentation report only).
pub struct Trace {
    pub name: &'static str,
    pub capacity: u32,
    pub setup: Vec<Op>,
    pub ops: Vec<Op>,
    pub ramp: Vec<Op>,
    pub slots: usize,
}

impl Trace {
    /// Allocate+free pairs in the timed part (allocs and frees over 2).
    pub fn pairs(&self) -> u64 {
        self.ops.len() as u64 / 2
    }
}

/// Generator state: live slots with their sizes and a model of used bytes.
struct Gen {
    rng: SplitMix64,
    next_slot: u32,
    live: Vec<(u32, u32, u32)>, // (slot, size, tag: e.g. mesh*8+lod)
    used: u64,
}

impl Gen {
    fn new(seed: u64) -> Self {
        Gen {
            rng: SplitMix64::new(seed),
            next_slot: 0,
            live: Vec::new(),
            used: 0,
        }
    }
    fn alloc(&mut self, out: &mut Vec<Op>, size: u32, tag: u32) {
        let slot = self.next_slot;
        self.next_slot += 1;
        out.push(Op::Alloc { slot, size });
        self.live.push((slot, size, tag));
        self.used += u64::from(size);
    }
    fn free_at(&mut self, out: &mut Vec<Op>, i: usize) -> (u32, u32) {
        let (slot, size, tag) = self.live.swap_remove(i);
        out.push(Op::Free { slot });
        self.used -= u64::from(size);
        (size, tag)
    }
    fn free_random(&mut self, out: &mut Vec<Op>) -> (u32, u32) {
        let i = self.rng.below_usize(self.live.len());
        self.free_at(out, i)
    }
}

const CHURN_STEPS: usize = 20_000;

/// Steady churn at `occupancy` with log-uniform sizes 64 B .. 64 KiB.
pub fn churn(name: &'static str, occupancy: f64, seed: u64) -> Trace {
    let capacity: u32 = 64 << 20;
    let target = (f64::from(capacity) * occupancy) as u64;
    let mut g = Gen::new(seed);
    let size = |g: &mut Gen| g.rng.log_uniform(64, 64 << 10);
    let (mut setup, mut ops, mut ramp) = (Vec::new(), Vec::new(), Vec::new());
    while g.used < target {
        let s = size(&mut g);
        g.alloc(&mut setup, s, 0);
    }
    for _ in 0..CHURN_STEPS {
        g.free_random(&mut ops);
        let s = size(&mut g);
        g.alloc(&mut ops, s, 0);
    }
    while g.used < u64::from(capacity) * 3 / 2 {
        if g.rng.unit_f64() < 0.6 {
            let s = size(&mut g);
            g.alloc(&mut ramp, s, 0);
        } else {
            g.free_random(&mut ramp);
        }
    }
    let slots = g.next_slot as usize;
    Trace {
        name,
        capacity,
        setup,
        ops,
        ramp,
        slots,
    }
}

/// Geometry-instance data: 48 meshes (Zipf popularity, s = 1.1) × 4 LODs
/// (each LOD a quarter of the previous), instances added, removed and
/// switching LOD (free old range, allocate the new LOD's) at ~75 %
/// occupancy.
pub fn instances(seed: u64) -> Trace {
    const MESHES: usize = 48;
    const LODS: u32 = 4;
    let capacity: u32 = 128 << 20;
    let target = u64::from(capacity) * 3 / 4;
    let mut g = Gen::new(seed);
    let base: Vec<u32> = (0..MESHES)
        .map(|_| g.rng.log_uniform(32 << 10, 2 << 20) / 256 * 256)
        .collect();
    let zipf = Zipf::new(MESHES, 1.1);
    let lod_size = |mesh: usize, lod: u32| (base[mesh] >> (2 * lod)).max(256);
    let add = |g: &mut Gen, out: &mut Vec<Op>| {
        let mesh = zipf.sample(&mut g.rng);
        let lod = g.rng.below_usize(LODS as usize) as u32;
        g.alloc(out, lod_size(mesh, lod), mesh as u32 * 8 + lod);
    };
    let swap = |g: &mut Gen, out: &mut Vec<Op>| {
        let i = g.rng.below_usize(g.live.len());
        let (_, tag) = g.free_at(out, i);
        let (mesh, lod) = ((tag / 8) as usize, tag % 8);
        let new_lod = if lod == 0 || (lod + 1 < LODS && g.rng.unit_f64() < 0.5) {
            lod + 1
        } else {
            lod - 1
        };
        g.alloc(out, lod_size(mesh, new_lod), mesh as u32 * 8 + new_lod);
    };
    let (mut setup, mut ops, mut ramp) = (Vec::new(), Vec::new(), Vec::new());
    while g.used < target {
        add(&mut g, &mut setup);
    }
    for _ in 0..CHURN_STEPS {
        let r = g.rng.unit_f64();
        if r < 0.5 {
            swap(&mut g, &mut ops);
        } else if g.used > target {
            g.free_random(&mut ops);
        } else {
            add(&mut g, &mut ops);
        }
    }
    while g.used < u64::from(capacity) * 3 / 2 {
        let r = g.rng.unit_f64();
        if r < 0.2 {
            swap(&mut g, &mut ramp);
        } else if r < 0.4 {
            g.free_random(&mut ramp);
        } else {
            add(&mut g, &mut ramp);
        }
    }
    let slots = g.next_slot as usize;
    Trace {
        name: "instances_zipf_lod",
        capacity,
        setup,
        ops,
        ramp,
        slots,
    }
}

/// One request size that falls strictly between size classes of both
/// lipac's TLSF and offset-allocator (both 8 bins per octave).
pub const BETWEEN_BINS_SIZE: u32 = 5000;

/// Whether offset-allocator (3-bit mantissa bins) files `size` between two
/// bin boundaries, i.e. rounds requests of it up to the next bin.
pub fn offset_allocator_between_bins(size: u32) -> bool {
    if size < 8 {
        return false;
    }
    let shift = 31 - size.leading_zeros() - 3;
    size & ((1 << shift) - 1) != 0
}

/// Many allocations of one size that falls between bins: churn at 90 %.
pub fn between_bins(seed: u64) -> Trace {
    let capacity: u32 = 32 << 20;
    let size = BETWEEN_BINS_SIZE;
    let target = u64::from(capacity) * 9 / 10;
    let mut g = Gen::new(seed);
    let (mut setup, mut ops, mut ramp) = (Vec::new(), Vec::new(), Vec::new());
    while g.used < target {
        g.alloc(&mut setup, size, 0);
    }
    for _ in 0..CHURN_STEPS {
        g.free_random(&mut ops);
        g.alloc(&mut ops, size, 0);
    }
    while g.used < u64::from(capacity) * 3 / 2 {
        if g.rng.unit_f64() < 0.6 {
            g.alloc(&mut ramp, size, 0);
        } else {
            g.free_random(&mut ramp);
        }
    }
    let slots = g.next_slot as usize;
    Trace {
        name: "between_bins_5000",
        capacity,
        setup,
        ops,
        ramp,
        slots,
    }
}

/// Adversarial: half the buffer in 256-byte ranges, free every other one
/// (isolated holes that cannot merge), then allocate 384-byte ranges that
/// fit none of the holes.
pub fn free_every_other() -> Trace {
    let capacity: u32 = 16 << 20;
    let n = capacity / 2 / 256;
    let mut g = Gen::new(0);
    let (mut setup, mut ops, mut ramp) = (Vec::new(), Vec::new(), Vec::new());
    for _ in 0..n {
        g.alloc(&mut setup, 256, 0);
    }
    for slot in (0..n).step_by(2) {
        ops.push(Op::Free { slot });
    }
    for _ in 0..n / 2 {
        g.alloc(&mut ops, 384, 0);
    }
    for _ in 0..capacity / 384 {
        g.alloc(&mut ramp, 384, 0);
    }
    let slots = g.next_slot as usize;
    Trace {
        name: "free_every_other",
        capacity,
        setup,
        ops,
        ramp,
        slots,
    }
}

/// All traces, in report order.
pub fn all_traces() -> Vec<Trace> {
    vec![
        churn("churn_50", 0.50, 1),
        churn("churn_75", 0.75, 2),
        churn("churn_90", 0.90, 3),
        instances(4),
        between_bins(5),
        free_every_other(),
    ]
}

// ---- adapters -------------------------------------------------------------

/// What the bench and the report need of a range allocator.
pub trait RangeAlloc {
    type Id: Copy;
    /// Allocates `size` bytes; `None` when out of space.
    fn allocate(&mut self, size: u32) -> Option<(Self::Id, u64)>;
    /// Frees a live allocation.
    fn free(&mut self, id: Self::Id);
    /// `(largest free block, total free bytes)` if the allocator reports it.
    fn free_report(&self) -> Option<(u64, u64)>;
}

pub struct Lipac(pub TlsfAllocator);

/// Block records every adapter sets up front (offset-allocator's
/// `max_allocs`; lipac reserves as many, and can grow beyond).
pub const BLOCK_RECORDS: u32 = 1 << 18;

impl Lipac {
    pub fn new(capacity: u32) -> Self {
        let mut a = TlsfAllocator::new(u64::from(capacity));
        a.reserve_blocks(BLOCK_RECORDS as usize).unwrap();
        Lipac(a)
    }
}

impl RangeAlloc for Lipac {
    type Id = AllocHandle;
    #[inline]
    fn allocate(&mut self, size: u32) -> Option<(AllocHandle, u64)> {
        self.0
            .allocate(u64::from(size))
            .ok()
            .map(|a| (a.handle, a.offset))
    }
    #[inline]
    fn free(&mut self, id: AllocHandle) {
        self.0.free(id).expect("trace frees live handles only");
    }
    fn free_report(&self) -> Option<(u64, u64)> {
        let s = self.0.stats();
        Some((s.largest_free_block, s.free_bytes))
    }
}

pub struct OffsetAlloc(pub offset_allocator::Allocator);

impl OffsetAlloc {
    pub fn new(capacity: u32) -> Self {
        OffsetAlloc(offset_allocator::Allocator::with_max_allocs(
            capacity,
            BLOCK_RECORDS,
        ))
    }
}

impl RangeAlloc for OffsetAlloc {
    type Id = offset_allocator::Allocation;
    #[inline]
    fn allocate(&mut self, size: u32) -> Option<(Self::Id, u64)> {
        self.0.allocate(size).map(|a| (a, u64::from(a.offset)))
    }
    #[inline]
    fn free(&mut self, id: Self::Id) {
        self.0.free(id);
    }
    fn free_report(&self) -> Option<(u64, u64)> {
        let r = self.0.storage_report();
        Some((
            u64::from(r.largest_free_region),
            u64::from(r.total_free_space),
        ))
    }
}

/// rlsf's `Tlsf` over a real byte arena (a CPU memory allocator: block
/// headers live in the arena, sizes round up to 32 bytes). CPU reference.
pub type RlsfTlsf = rlsf::Tlsf<'static, u32, u32, 28, 32>;

/// A pre-touched byte arena that outlives every [`Rlsf`] built on it.
pub struct Arena(Box<[MaybeUninit<u8>]>);

impl Arena {
    pub fn new(capacity: u32) -> Self {
        // Touch every page now so page faults stay out of the timings.
        Arena(vec![MaybeUninit::new(1u8); capacity as usize].into_boxed_slice())
    }
}

pub struct Rlsf {
    tlsf: RlsfTlsf,
    base: usize,
}

impl Rlsf {
    /// # Safety
    /// `arena` must outlive the returned allocator and every other `Rlsf`
    /// built on the same arena must be dropped first (one pool, one owner).
    pub unsafe fn new(arena: &mut Arena) -> Self {
        let mut tlsf = RlsfTlsf::new();
        let ptr = NonNull::from(&mut arena.0[..]);
        let block = NonNull::new(std::ptr::slice_from_raw_parts_mut(
            ptr.as_ptr() as *mut u8,
            arena.0.len(),
        ))
        .expect("non-null arena");
        // SAFETY: the caller keeps the arena alive and unshared while `tlsf`
        // is in use.
        unsafe { tlsf.insert_free_block_ptr(block) };
        Rlsf {
            tlsf,
            base: ptr.as_ptr() as *mut u8 as usize,
        }
    }
}

impl RangeAlloc for Rlsf {
    type Id = NonNull<u8>;
    #[inline]
    fn allocate(&mut self, size: u32) -> Option<(NonNull<u8>, u64)> {
        let layout = Layout::from_size_align(size as usize, 1).ok()?;
        let p = self.tlsf.allocate(layout)?;
        Some((p, (p.as_ptr() as usize - self.base) as u64))
    }
    #[inline]
    fn free(&mut self, id: NonNull<u8>) {
        // SAFETY: `id` came from `allocate` on this `tlsf` with alignment 1
        // and the trace frees it once.
        unsafe { self.tlsf.deallocate(id, 1) }
    }
    fn free_report(&self) -> Option<(u64, u64)> {
        None
    }
}

// ---- driving a trace ------------------------------------------------------

/// Runs `ops`; failed allocations leave their slot empty and their later
/// free is skipped. Returns the number of failed allocations.
#[inline]
pub fn run_ops<A: RangeAlloc>(a: &mut A, ops: &[Op], slots: &mut [Option<A::Id>]) -> usize {
    let mut failed = 0;
    for op in ops {
        match *op {
            Op::Alloc { slot, size } => match a.allocate(size) {
                Some((id, _)) => slots[slot as usize] = Some(id),
                None => failed += 1,
            },
            Op::Free { slot } => {
                if let Some(id) = slots[slot as usize].take() {
                    a.free(id);
                }
            }
        }
    }
    failed
}

/// Where and how a trace first failed to allocate.
pub struct FirstFailure {
    /// `"setup"`, `"ops"`, `"ramp"` or `"none"`.
    pub phase: &'static str,
    /// Live requested bytes / capacity at the failure.
    pub utilisation: f64,
    /// `(largest free, total free)` at the failure, if reported.
    pub free_report: Option<(u64, u64)>,
    /// Highest end offset handed out before the failure / capacity.
    pub high_water: f64,
    /// Highest end offset / capacity after setup and the steady phase
    /// (or at the failure, if that came first): how far the allocator
    /// spreads live data at steady state.
    pub steady_high_water: f64,
}

/// Runs setup, ops and ramp until the first failed allocation.
pub fn first_failure<A: RangeAlloc>(a: &mut A, t: &Trace) -> FirstFailure {
    let mut slots: Vec<Option<(A::Id, u32)>> = vec![None; t.slots];
    let (mut used, mut high) = (0u64, 0u64);
    let cap = f64::from(t.capacity);
    let mut steady = None;
    for (phase, ops) in [("setup", &t.setup), ("ops", &t.ops), ("ramp", &t.ramp)] {
        for op in ops.iter() {
            match *op {
                Op::Alloc { slot, size } => match a.allocate(size) {
                    Some((id, offset)) => {
                        slots[slot as usize] = Some((id, size));
                        used += u64::from(size);
                        high = high.max(offset + u64::from(size));
                    }
                    None => {
                        return FirstFailure {
                            phase,
                            utilisation: used as f64 / cap,
                            free_report: a.free_report(),
                            high_water: high as f64 / cap,
                            steady_high_water: steady.unwrap_or(high) as f64 / cap,
                        }
                    }
                },
                Op::Free { slot } => {
                    if let Some((id, size)) = slots[slot as usize].take() {
                        a.free(id);
                        used -= u64::from(size);
                    }
                }
            }
        }
        if phase == "ops" {
            steady = Some(high);
        }
    }
    FirstFailure {
        phase: "none",
        utilisation: used as f64 / cap,
        free_report: a.free_report(),
        high_water: high as f64 / cap,
        steady_high_water: steady.unwrap_or(high) as f64 / cap,
    }
}
