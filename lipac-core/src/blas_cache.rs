//! Shared-BLAS cache: reference counts, lifecycle, memory budget, eviction
//! and deferred frees (thesis §3.3.1, "Sharing BLASes between instances",
//! "BLAS compaction", "Mesh LOD handling").
//!
//! # What it holds
//!
//! * **Shared BLASes**, one per [`BlasKey`] `(mesh, lod, variant)`, reference
//!   counted ([`BlasCache::acquire_shared`] / [`BlasCache::release`]); an
//!   unreferenced one stays cached until evicted.
//! * **Unique BLASes** ([`BlasCache::create_unique`]): one user, never shared,
//!   compacted or cached; releasing one frees it.
//!
//! An entry goes through [`BlasState`]; its address is valid from `Built` on
//! and through compaction until the compacted copy is acknowledged.
//!
//! # What a caller must know
//!
//! * The memory budget is checked on every reservation
//!   ([`BlasCache::try_reserve_build`], [`BlasCache::try_begin_compaction`])
//!   and acknowledgement; a reservation that cannot fit even after evicting
//!   every unreferenced, idle entry is refused without evicting anything.
//! * A BLAS released or evicted in frame `f` is handed back for destruction by
//!   [`BlasCache::begin_frame`]`(g)` only once `g >= f + frames_in_flight`.
//! * Limits: frames up to [`MAX_FRAME`] (`2^63 - 1`, else
//!   [`BlasError::FrameOutOfRange`]); byte counts up to [`MAX_BLAS_BYTES`]
//!   (2^48, else [`BlasError::InvalidAck`]); [`CacheStats`] totals saturate
//!   at `u64::MAX`.
//!
//! Lifecycle, eviction order, deferred frees and the limits in detail:
//! `docs/BLAS.md`.
//!
//! ```
//! use lipac_core::blas_cache::{BlasCache, CacheConfig, Lookup};
//! use lipac_core::blas_ids::{BlasKey, BuildId, Lod};
//! use lipac_core::MeshId;
//!
//! let mut cache = BlasCache::new(CacheConfig { frames_in_flight: 2, ..CacheConfig::default() })?;
//! cache.begin_frame(1)?;
//! let key = BlasKey { mesh: MeshId(7), lod: Lod(0), variant: 0 };
//! let Lookup::Miss(id) = cache.acquire_shared(key, true)? else { unreachable!() };
//! assert!(cache.try_reserve_build(id, 4096, 1024, BuildId(1))?);
//! cache.ack_built(BuildId(1), 4000, 0xA000)?;
//! assert_eq!(cache.address(id), Some(0xA000));
//! cache.release(id)?; // stays cached, unreferenced
//! assert!(matches!(cache.acquire_shared(key, true)?, Lookup::Hit(_)));
//! # Ok::<(), lipac_core::blas_cache::BlasError>(())
//! ```

use std::collections::{BTreeSet, HashMap, HashSet};
use std::fmt;

use slotmap::SlotMap;

use crate::blas_ids::{BlasId, BlasKey, BuildId, InstanceKey, Lod, MeshId};

/// The largest frame number [`BlasCache::begin_frame`] accepts: `2^63 - 1`
/// (at 10 000 frames per second, 29 million years). Below it, a frame plus
/// any `u32` count of frames (frames in flight, hysteresis, slot staggering)
/// is exact in a `u64`, so no frame arithmetic can overflow.
pub const MAX_FRAME: u64 = (1 << 63) - 1;

/// The largest byte count the cache takes in one value (a reserved estimate,
/// scratch, an acknowledged or compacted size): 2^48 bytes (256 TiB), far
/// above any device's memory. Larger values are refused as corrupt input
/// ([`BlasError::InvalidAck`]).
pub const MAX_BLAS_BYTES: u64 = 1 << 48;

/// Configuration of a [`BlasCache`].
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct CacheConfig {
    /// Upper bound on live BLAS bytes (shared + unique + compacted, builds in
    /// flight counted at their reserved estimate).
    pub memory_budget: u64,
    /// Frames the GPU may be behind the host; frees wait this many frames.
    pub frames_in_flight: u32,
    /// Unreferenced shared entries unused for more than this many frames are
    /// evicted at [`BlasCache::begin_frame`].
    pub max_unused_frames: u32,
}

impl Default for CacheConfig {
    /// 512 MiB budget, 2 frames in flight, eviction after 300 unused frames.
    fn default() -> Self {
        Self {
            memory_budget: 512 << 20,
            frames_in_flight: 2,
            max_unused_frames: 300,
        }
    }
}

/// Who a BLAS belongs to, and what geometry it holds.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum BlasOwner {
    /// A shared BLAS, one per key.
    Shared(BlasKey),
    /// A unique BLAS of one instance.
    Unique {
        /// The owning instance.
        instance: InstanceKey,
        /// Source mesh.
        mesh: MeshId,
        /// Level of detail.
        lod: Lod,
    },
}

impl BlasOwner {
    /// The source mesh.
    pub fn mesh(&self) -> MeshId {
        match *self {
            BlasOwner::Shared(k) => k.mesh,
            BlasOwner::Unique { mesh, .. } => mesh,
        }
    }
    /// The level of detail.
    pub fn lod(&self) -> Lod {
        match *self {
            BlasOwner::Shared(k) => k.lod,
            BlasOwner::Unique { lod, .. } => lod,
        }
    }
    /// Whether this is a shared BLAS.
    pub fn is_shared(&self) -> bool {
        matches!(self, BlasOwner::Shared(_))
    }
}

/// Lifecycle state of a cache entry (see `docs/BLAS.md`, "Lifecycle of an
/// entry").
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum BlasState {
    /// Wanted; nothing allocated yet.
    Requested,
    /// Build handed to the backend; `reserved_bytes` held against the budget.
    Building {
        /// The build operation.
        build: BuildId,
        /// Estimated result size (build sizes query).
        reserved_bytes: u64,
        /// Scratch bytes the build uses until acknowledged.
        scratch_bytes: u64,
    },
    /// Built and usable.
    Built {
        /// Backend-provided address (opaque, non-zero).
        address: u64,
        /// Actual size.
        bytes: u64,
    },
    /// Built; the compacted size is known (static shared BLASes only).
    SizeQueried {
        /// Address of the uncompacted BLAS.
        address: u64,
        /// Size of the uncompacted BLAS.
        bytes: u64,
        /// Size after compaction.
        compacted_bytes: u64,
    },
    /// A compaction copy is in flight; the uncompacted BLAS is still used.
    Compacting {
        /// Address of the uncompacted BLAS.
        address: u64,
        /// Size of the uncompacted BLAS.
        bytes: u64,
        /// Size reserved for the compacted copy.
        compacted_bytes: u64,
        /// The compaction operation.
        op: BuildId,
    },
    /// Compacted and usable.
    Compacted {
        /// Address of the compacted BLAS.
        address: u64,
        /// Its size.
        bytes: u64,
    },
}

impl BlasState {
    /// Address usable for TLAS assembly, if the BLAS is built.
    pub fn address(&self) -> Option<u64> {
        match *self {
            BlasState::Requested | BlasState::Building { .. } => None,
            BlasState::Built { address, .. }
            | BlasState::SizeQueried { address, .. }
            | BlasState::Compacting { address, .. }
            | BlasState::Compacted { address, .. } => Some(address),
        }
    }
    fn in_flight(&self) -> bool {
        matches!(
            self,
            BlasState::Building { .. } | BlasState::Compacting { .. }
        )
    }
}

/// Read-only view of one cache entry.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct BlasInfo {
    /// Owner and geometry.
    pub owner: BlasOwner,
    /// Lifecycle state.
    pub state: BlasState,
    /// Number of users.
    pub refs: u32,
    /// Whether the BLAS is built with compaction allowed (static shared).
    pub compactable: bool,
    /// Frame of the last use (last acquire, or when the last user let go).
    pub last_used: u64,
}

/// Result of [`BlasCache::acquire_shared`].
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Lookup {
    /// The entry existed (in any state); one more reference was taken.
    Hit(BlasId),
    /// The entry was created in [`BlasState::Requested`] with one reference.
    Miss(BlasId),
}

impl Lookup {
    /// The entry either way.
    pub fn id(self) -> BlasId {
        match self {
            Lookup::Hit(id) | Lookup::Miss(id) => id,
        }
    }
}

/// A BLAS the backend may now destroy.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct BlasFree {
    /// The entry it belonged to (may already be gone from the cache).
    pub blas: BlasId,
    /// The operation that created this acceleration structure (a build or a
    /// compaction copy).
    pub created_by: BuildId,
    /// Its address as acknowledged.
    pub address: u64,
    /// Its size.
    pub bytes: u64,
}

/// Cache statistics.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct CacheStats {
    /// Bytes of uncompacted shared BLASes (built, or reserved while building).
    pub shared_bytes: u64,
    /// Bytes of unique BLASes (built, or reserved while building).
    pub unique_bytes: u64,
    /// Bytes of compacted shared BLASes (and reserved compaction targets).
    pub compacted_bytes: u64,
    /// Scratch bytes of builds handed out and not yet acknowledged.
    pub scratch_in_use: u64,
    /// Acquisitions that found an entry.
    pub hits: u64,
    /// Acquisitions that created an entry.
    pub misses: u64,
    /// Shared entries evicted (budget or age).
    pub evictions: u64,
    /// Frees waiting for frames in flight.
    pub pending_frees: usize,
    /// Bytes of those frees.
    pub pending_free_bytes: u64,
    /// Entries in the cache (any state, shared and unique).
    pub entries: usize,
}

impl CacheStats {
    /// Bytes counted against the budget.
    pub fn live_bytes(&self) -> u64 {
        self.shared_bytes
            .saturating_add(self.unique_bytes)
            .saturating_add(self.compacted_bytes)
    }
}

/// Errors of the cache.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum BlasError {
    /// A configuration value is out of range.
    InvalidConfig(&'static str),
    /// `begin_frame` was called with a frame not after the previous one.
    NonMonotonicFrame {
        /// The current frame.
        previous: u64,
        /// The frame given.
        got: u64,
    },
    /// `begin_frame` was called with a frame above [`MAX_FRAME`].
    FrameOutOfRange {
        /// The frame given.
        frame: u64,
        /// The largest frame allowed ([`MAX_FRAME`]).
        max: u64,
    },
    /// The handle names no live entry.
    StaleBlas(BlasId),
    /// The operation id was never handed out, or already acknowledged.
    UnknownBuild(BuildId),
    /// The entry is not in a state the call applies to.
    WrongState {
        /// The entry.
        blas: BlasId,
        /// What the call expected.
        expected: &'static str,
    },
    /// Release of an entry without users.
    NotReferenced(BlasId),
    /// More than `u32::MAX` users.
    RefcountOverflow(BlasId),
    /// A size of zero or above [`MAX_BLAS_BYTES`], or an address of zero
    /// (0 means "no BLAS").
    InvalidAck(&'static str),
}

impl fmt::Display for BlasError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            BlasError::InvalidConfig(what) => write!(f, "invalid BLAS cache configuration: {what}"),
            BlasError::NonMonotonicFrame { previous, got } => {
                write!(f, "frame {got} does not follow frame {previous}")
            }
            BlasError::FrameOutOfRange { frame, max } => {
                write!(f, "frame {frame} is above the largest frame number {max}")
            }
            BlasError::StaleBlas(id) => write!(f, "stale BLAS handle {id:?}"),
            BlasError::UnknownBuild(b) => write!(f, "{b} is unknown or already acknowledged"),
            BlasError::WrongState { blas, expected } => {
                write!(f, "BLAS {blas:?} is not {expected}")
            }
            BlasError::NotReferenced(id) => write!(f, "BLAS {id:?} has no users to release"),
            BlasError::RefcountOverflow(id) => write!(f, "BLAS {id:?} has too many users"),
            BlasError::InvalidAck(what) => write!(f, "invalid acknowledgement: {what}"),
        }
    }
}

impl std::error::Error for BlasError {}

#[derive(Clone, Debug)]
struct Entry {
    info: BlasInfo,
    /// The operation that created the live (uncompacted or compacted) AS.
    created_by: BuildId,
    /// Compacted-size query outstanding for this build.
    size_query: Option<BuildId>,
}

#[derive(Clone, Copy, Default)]
struct Bytes {
    shared: u64,
    unique: u64,
    compacted: u64,
    scratch: u64,
}

fn contribution(e: &Entry) -> Bytes {
    let mut b = Bytes::default();
    let main = match e.info.state {
        BlasState::Requested | BlasState::Compacted { .. } => 0,
        BlasState::Building {
            reserved_bytes,
            scratch_bytes,
            ..
        } => {
            b.scratch = scratch_bytes;
            reserved_bytes
        }
        BlasState::Built { bytes, .. } | BlasState::SizeQueried { bytes, .. } => bytes,
        BlasState::Compacting {
            bytes,
            compacted_bytes,
            ..
        } => {
            b.compacted = compacted_bytes;
            bytes
        }
    };
    if let BlasState::Compacted { bytes, .. } = e.info.state {
        b.compacted = bytes;
    }
    if e.info.owner.is_shared() {
        b.shared = main;
    } else {
        b.unique = main;
    }
    b
}

/// The shared/unique BLAS cache. See the module docs; policies in
/// `docs/BLAS.md`.
#[derive(Debug)]
pub struct BlasCache {
    config: CacheConfig,
    frame: u64,
    started: bool,
    entries: SlotMap<BlasId, Entry>,
    shared: HashMap<BlasKey, BlasId>,
    /// Build / compaction operations awaiting acknowledgement.
    ops: HashMap<BuildId, BlasId>,
    /// Size queries awaiting acknowledgement, by build.
    size_queries: HashMap<BuildId, BlasId>,
    /// Size queries whose BLAS was evicted meanwhile (acks are ignored).
    dead_queries: HashSet<BuildId>,
    compaction_ready: BTreeSet<BlasId>,
    pending_frees: Vec<(u64, BlasFree)>,
    // Byte totals in u128: sums of u64 values over at most 2^32 entries
    // cannot wrap (see the limits in the module docs).
    shared_bytes: u128,
    unique_bytes: u128,
    compacted_bytes: u128,
    scratch_bytes: u128,
    pending_free_bytes: u128,
    hits: u64,
    misses: u64,
    evictions: u64,
}

impl BlasCache {
    /// Creates an empty cache. Fails when `memory_budget` is zero.
    pub fn new(config: CacheConfig) -> Result<Self, BlasError> {
        if config.memory_budget == 0 {
            return Err(BlasError::InvalidConfig("memory_budget must be > 0"));
        }
        Ok(Self {
            config,
            frame: 0,
            started: false,
            entries: SlotMap::with_key(),
            shared: HashMap::new(),
            ops: HashMap::new(),
            size_queries: HashMap::new(),
            dead_queries: HashSet::new(),
            compaction_ready: BTreeSet::new(),
            pending_frees: Vec::new(),
            shared_bytes: 0,
            unique_bytes: 0,
            compacted_bytes: 0,
            scratch_bytes: 0,
            pending_free_bytes: 0,
            hits: 0,
            misses: 0,
            evictions: 0,
        })
    }

    /// The configuration.
    pub fn config(&self) -> &CacheConfig {
        &self.config
    }

    /// The current frame (0 before the first [`BlasCache::begin_frame`]).
    pub fn frame(&self) -> u64 {
        self.frame
    }

    /// Starts frame `frame` (strictly after the previous one): evicts entries
    /// unused for more than `max_unused_frames` frames and returns the BLASes
    /// that no frame in flight can use any more, for the backend to destroy.
    ///
    /// Fails, changing nothing, for a frame not after the current one or
    /// above [`MAX_FRAME`].
    pub fn begin_frame(&mut self, frame: u64) -> Result<Vec<BlasFree>, BlasError> {
        if frame > MAX_FRAME {
            return Err(BlasError::FrameOutOfRange {
                frame,
                max: MAX_FRAME,
            });
        }
        if self.started && frame <= self.frame {
            return Err(BlasError::NonMonotonicFrame {
                previous: self.frame,
                got: frame,
            });
        }
        self.started = true;
        self.frame = frame;
        let max_unused = u64::from(self.config.max_unused_frames);
        let old: Vec<BlasId> = self
            .entries
            .iter()
            .filter(|(_, e)| Self::evictable(e) && frame - e.info.last_used.min(frame) > max_unused)
            .map(|(id, _)| id)
            .collect();
        for id in old {
            self.evict(id);
        }
        let mut ready = Vec::new();
        self.pending_frees.retain(|(safe, free)| {
            if *safe <= frame {
                ready.push(*free);
                false
            } else {
                true
            }
        });
        for f in &ready {
            self.pending_free_bytes -= u128::from(f.bytes);
        }
        Ok(ready)
    }

    /// Takes a reference on the shared BLAS `key`, creating it (a miss, state
    /// [`BlasState::Requested`]) when absent. `compactable` marks a static
    /// BLAS to be compacted after its build; it is taken from the creating
    /// call only.
    pub fn acquire_shared(&mut self, key: BlasKey, compactable: bool) -> Result<Lookup, BlasError> {
        if let Some(&id) = self.shared.get(&key) {
            self.acquire(id)?;
            self.hits += 1;
            return Ok(Lookup::Hit(id));
        }
        self.misses += 1;
        let id = self.entries.insert(Entry {
            info: BlasInfo {
                owner: BlasOwner::Shared(key),
                state: BlasState::Requested,
                refs: 1,
                compactable,
                last_used: self.frame,
            },
            created_by: BuildId(0),
            size_query: None,
        });
        self.shared.insert(key, id);
        Ok(Lookup::Miss(id))
    }

    /// Creates a unique BLAS for `instance` (state `Requested`, one reference).
    /// Unique BLASes are never compacted, shared or cached.
    pub fn create_unique(&mut self, instance: InstanceKey, mesh: MeshId, lod: Lod) -> BlasId {
        self.entries.insert(Entry {
            info: BlasInfo {
                owner: BlasOwner::Unique {
                    instance,
                    mesh,
                    lod,
                },
                state: BlasState::Requested,
                refs: 1,
                compactable: false,
                last_used: self.frame,
            },
            created_by: BuildId(0),
            size_query: None,
        })
    }

    /// Takes one more reference on an existing entry.
    pub fn acquire(&mut self, id: BlasId) -> Result<(), BlasError> {
        let frame = self.frame;
        let e = self.entries.get_mut(id).ok_or(BlasError::StaleBlas(id))?;
        e.info.refs = e
            .info
            .refs
            .checked_add(1)
            .ok_or(BlasError::RefcountOverflow(id))?;
        e.info.last_used = frame;
        Ok(())
    }

    /// Drops one reference. An entry without users that was never handed to
    /// the backend is removed; an unreferenced unique BLAS is freed (deferred)
    /// once no GPU operation on it is in flight; an unreferenced shared BLAS
    /// stays cached until evicted.
    pub fn release(&mut self, id: BlasId) -> Result<(), BlasError> {
        let frame = self.frame;
        let e = self.entries.get_mut(id).ok_or(BlasError::StaleBlas(id))?;
        if e.info.refs == 0 {
            return Err(BlasError::NotReferenced(id));
        }
        e.info.refs -= 1;
        e.info.last_used = frame;
        if e.info.refs > 0 {
            return Ok(());
        }
        match e.info.state {
            BlasState::Requested => self.remove(id),
            _ if e.info.owner.is_shared() || e.info.state.in_flight() => {}
            _ => self.remove(id),
        }
        Ok(())
    }

    /// Hands the `Requested` entry `id` to a build with operation id `build`,
    /// reserving `reserved_bytes` (the estimated result size) against the
    /// budget, evicting unreferenced entries if needed. Returns `false`, with
    /// nothing evicted and the entry left `Requested`, when it cannot fit.
    pub fn try_reserve_build(
        &mut self,
        id: BlasId,
        reserved_bytes: u64,
        scratch_bytes: u64,
        build: BuildId,
    ) -> Result<bool, BlasError> {
        let e = self.entries.get(id).ok_or(BlasError::StaleBlas(id))?;
        if e.info.state != BlasState::Requested {
            return Err(BlasError::WrongState {
                blas: id,
                expected: "Requested",
            });
        }
        if self.ops.contains_key(&build) {
            return Err(BlasError::InvalidAck("operation id already in flight"));
        }
        if reserved_bytes > MAX_BLAS_BYTES || scratch_bytes > MAX_BLAS_BYTES {
            return Err(BlasError::InvalidAck(
                "reserved or scratch size above MAX_BLAS_BYTES",
            ));
        }
        if !self.make_room(reserved_bytes) {
            return Ok(false);
        }
        self.update(id, |e| {
            e.info.state = BlasState::Building {
                build,
                reserved_bytes,
                scratch_bytes,
            }
        });
        self.ops.insert(build, id);
        Ok(true)
    }

    /// Acknowledges build `build`: the BLAS now has `result_bytes` bytes at
    /// `address`. Compactable BLASes then await a compacted-size query
    /// ([`BlasCache::ack_compacted_size`]). A unique BLAS whose owner let go
    /// meanwhile is freed (deferred). Evicts if the actual size overran the
    /// budget. Returns the entry.
    pub fn ack_built(
        &mut self,
        build: BuildId,
        result_bytes: u64,
        address: u64,
    ) -> Result<BlasId, BlasError> {
        if result_bytes == 0 {
            return Err(BlasError::InvalidAck("result size 0"));
        }
        if result_bytes > MAX_BLAS_BYTES {
            return Err(BlasError::InvalidAck("result size above MAX_BLAS_BYTES"));
        }
        if address == 0 {
            return Err(BlasError::InvalidAck("address 0"));
        }
        let id = *self.ops.get(&build).ok_or(BlasError::UnknownBuild(build))?;
        let e = &self.entries[id];
        if !matches!(e.info.state, BlasState::Building { build: b, .. } if b == build) {
            return Err(BlasError::UnknownBuild(build));
        }
        self.ops.remove(&build);
        let frame = self.frame;
        self.update(id, |e| {
            e.info.state = BlasState::Built {
                address,
                bytes: result_bytes,
            };
            e.created_by = build;
            if e.info.refs == 0 {
                e.info.last_used = frame;
            }
            if e.info.compactable {
                e.size_query = Some(build);
            }
        });
        let e = &self.entries[id];
        if e.info.compactable {
            self.size_queries.insert(build, id);
        }
        if !e.info.owner.is_shared() && e.info.refs == 0 {
            self.remove(id);
        }
        self.make_room(0);
        Ok(id)
    }

    /// Acknowledges the compacted-size query that followed build `build`.
    /// Returns `Ok(None)` when that BLAS was evicted meanwhile (the answer
    /// is dropped), else the entry, now [`BlasState::SizeQueried`].
    pub fn ack_compacted_size(
        &mut self,
        build: BuildId,
        compacted_bytes: u64,
    ) -> Result<Option<BlasId>, BlasError> {
        if self.dead_queries.remove(&build) {
            return Ok(None);
        }
        if compacted_bytes == 0 {
            return Err(BlasError::InvalidAck("compacted size 0"));
        }
        if compacted_bytes > MAX_BLAS_BYTES {
            return Err(BlasError::InvalidAck("compacted size above MAX_BLAS_BYTES"));
        }
        let id = *self
            .size_queries
            .get(&build)
            .ok_or(BlasError::UnknownBuild(build))?;
        self.size_queries.remove(&build);
        self.update(id, |e| {
            e.size_query = None;
            if let BlasState::Built { address, bytes } = e.info.state {
                e.info.state = BlasState::SizeQueried {
                    address,
                    bytes,
                    compacted_bytes: compacted_bytes.min(bytes),
                };
            }
        });
        if matches!(self.entries[id].info.state, BlasState::SizeQueried { .. }) {
            self.compaction_ready.insert(id);
        }
        Ok(Some(id))
    }

    /// Entries whose compacted size is known and that await compaction, in
    /// handle order.
    pub fn compaction_candidates(&self) -> impl Iterator<Item = BlasId> + '_ {
        self.compaction_ready.iter().copied()
    }

    /// Starts compacting the `SizeQueried` entry `id` with operation `op`,
    /// reserving the compacted size against the budget (evicting if needed).
    /// Returns `false`, changing nothing, when it does not fit.
    pub fn try_begin_compaction(&mut self, id: BlasId, op: BuildId) -> Result<bool, BlasError> {
        let e = self.entries.get(id).ok_or(BlasError::StaleBlas(id))?;
        let BlasState::SizeQueried {
            address,
            bytes,
            compacted_bytes,
        } = e.info.state
        else {
            return Err(BlasError::WrongState {
                blas: id,
                expected: "SizeQueried",
            });
        };
        if self.ops.contains_key(&op) {
            return Err(BlasError::InvalidAck("operation id already in flight"));
        }
        // The entry itself is not evictable while we look for room: mark it
        // in flight first, undo if it does not fit.
        self.update(id, |e| {
            e.info.state = BlasState::Compacting {
                address,
                bytes,
                compacted_bytes: 0,
                op,
            }
        });
        if !self.make_room(compacted_bytes) {
            self.update(id, |e| {
                e.info.state = BlasState::SizeQueried {
                    address,
                    bytes,
                    compacted_bytes,
                }
            });
            return Ok(false);
        }
        self.update(id, |e| {
            e.info.state = BlasState::Compacting {
                address,
                bytes,
                compacted_bytes,
                op,
            }
        });
        self.compaction_ready.remove(&id);
        self.ops.insert(op, id);
        Ok(true)
    }

    /// Acknowledges compaction `op`: the compacted copy lives at `address`;
    /// the uncompacted BLAS is freed (deferred).
    pub fn ack_compacted(&mut self, op: BuildId, address: u64) -> Result<BlasId, BlasError> {
        if address == 0 {
            return Err(BlasError::InvalidAck("address 0"));
        }
        let id = *self.ops.get(&op).ok_or(BlasError::UnknownBuild(op))?;
        let e = &self.entries[id];
        let BlasState::Compacting {
            address: old,
            bytes,
            compacted_bytes,
            op: o,
        } = e.info.state
        else {
            return Err(BlasError::UnknownBuild(op));
        };
        if o != op {
            return Err(BlasError::UnknownBuild(op));
        }
        self.ops.remove(&op);
        let created_by = e.created_by;
        self.defer_free(BlasFree {
            blas: id,
            created_by,
            address: old,
            bytes,
        });
        self.update(id, |e| {
            e.info.state = BlasState::Compacted {
                address,
                bytes: compacted_bytes,
            };
            e.created_by = op;
        });
        Ok(id)
    }

    /// Evicts every unreferenced shared entry that has no GPU operation in
    /// flight (e.g. at a level change). Returns how many were evicted.
    pub fn trim(&mut self) -> usize {
        let ids: Vec<BlasId> = self
            .entries
            .iter()
            .filter(|(_, e)| Self::evictable(e))
            .map(|(id, _)| id)
            .collect();
        for &id in &ids {
            self.evict(id);
        }
        ids.len()
    }

    /// The entry `id`, if live.
    pub fn get(&self, id: BlasId) -> Option<&BlasInfo> {
        self.entries.get(id).map(|e| &e.info)
    }

    /// Every entry with the bytes it counts against the budget (its BLAS,
    /// a build's reserved estimate, a compaction target; scratch not
    /// included), in no particular order: for memory breakdowns (which
    /// bytes are shared in use, shared only cached, unique).
    pub fn entries(&self) -> impl Iterator<Item = (BlasId, &BlasInfo, u64)> + '_ {
        self.entries.iter().map(|(id, e)| {
            let b = contribution(e);
            (
                id,
                &e.info,
                b.shared
                    .saturating_add(b.unique)
                    .saturating_add(b.compacted),
            )
        })
    }

    /// The shared entry for `key`, if cached (any state).
    pub fn lookup(&self, key: &BlasKey) -> Option<BlasId> {
        self.shared.get(key).copied()
    }

    /// Address of entry `id` for TLAS assembly, once built.
    pub fn address(&self, id: BlasId) -> Option<u64> {
        self.entries.get(id).and_then(|e| e.info.state.address())
    }

    /// Address of the shared BLAS `key`, once built.
    pub fn shared_address(&self, key: &BlasKey) -> Option<u64> {
        self.lookup(key).and_then(|id| self.address(id))
    }

    /// The operation (build or compaction) that created the live
    /// acceleration structure of entry `id`, once built.
    pub fn created_by(&self, id: BlasId) -> Option<BuildId> {
        let e = self.entries.get(id)?;
        e.info.state.address().map(|_| e.created_by)
    }

    /// Builds and compactions handed out and not yet acknowledged.
    pub fn in_flight_ops(&self) -> usize {
        self.ops.len()
    }

    /// Number of entries (shared and unique, any state).
    pub fn len(&self) -> usize {
        self.entries.len()
    }

    /// Whether the cache holds no entry.
    pub fn is_empty(&self) -> bool {
        self.entries.is_empty()
    }

    /// Statistics.
    /// Byte totals above `u64::MAX` are reported as `u64::MAX`.
    pub fn stats(&self) -> CacheStats {
        CacheStats {
            shared_bytes: saturate(self.shared_bytes),
            unique_bytes: saturate(self.unique_bytes),
            compacted_bytes: saturate(self.compacted_bytes),
            scratch_in_use: saturate(self.scratch_bytes),
            hits: self.hits,
            misses: self.misses,
            evictions: self.evictions,
            pending_frees: self.pending_frees.len(),
            pending_free_bytes: saturate(self.pending_free_bytes),
            entries: self.entries.len(),
        }
    }

    /// Bytes counted against the budget (saturated at `u64::MAX`).
    pub fn live_bytes(&self) -> u64 {
        saturate(self.live())
    }

    /// Whether `bytes` more would fit after evicting every candidate.
    pub fn could_fit(&self, bytes: u64) -> bool {
        let evictable: u128 = self
            .entries
            .values()
            .filter(|e| Self::evictable(e))
            .map(|e| {
                let b = contribution(e);
                u128::from(b.shared) + u128::from(b.unique) + u128::from(b.compacted)
            })
            .sum();
        self.live() - evictable + u128::from(bytes) <= u128::from(self.config.memory_budget)
    }

    // ---- internals ----

    /// Bytes counted against the budget, exactly.
    fn live(&self) -> u128 {
        self.shared_bytes + self.unique_bytes + self.compacted_bytes
    }

    /// Whether `extra` more bytes fit the budget without evicting.
    fn fits(&self, extra: u64) -> bool {
        self.live() + u128::from(extra) <= u128::from(self.config.memory_budget)
    }

    fn evictable(e: &Entry) -> bool {
        e.info.refs == 0
            && e.info.owner.is_shared()
            && !e.info.state.in_flight()
            && e.info.state != BlasState::Requested
    }

    /// Applies `f` to entry `id`, keeping the byte counters in step.
    fn update(&mut self, id: BlasId, f: impl FnOnce(&mut Entry)) {
        let e = &mut self.entries[id];
        let before = contribution(e);
        f(e);
        let after = contribution(e);
        let step =
            |total: u128, before: u64, after: u64| total - u128::from(before) + u128::from(after);
        self.shared_bytes = step(self.shared_bytes, before.shared, after.shared);
        self.unique_bytes = step(self.unique_bytes, before.unique, after.unique);
        self.compacted_bytes = step(self.compacted_bytes, before.compacted, after.compacted);
        self.scratch_bytes = step(self.scratch_bytes, before.scratch, after.scratch);
    }

    /// Evicts (LRU, then largest) until `extra` more bytes fit. Evicts nothing
    /// and returns `false` if they cannot fit even after evicting everything
    /// evictable.
    fn make_room(&mut self, extra: u64) -> bool {
        if self.fits(extra) {
            return true;
        }
        if !self.could_fit(extra) {
            return false;
        }
        let mut candidates: Vec<(u64, std::cmp::Reverse<u64>, BlasId)> = self
            .entries
            .iter()
            .filter(|(_, e)| Self::evictable(e))
            .map(|(id, e)| {
                let b = contribution(e);
                (
                    e.info.last_used,
                    std::cmp::Reverse(b.shared + b.compacted),
                    id,
                )
            })
            .collect();
        candidates.sort_unstable();
        for (_, _, id) in candidates {
            if self.fits(extra) {
                break;
            }
            self.evict(id);
        }
        self.fits(extra)
    }

    fn evict(&mut self, id: BlasId) {
        self.evictions += 1;
        self.remove(id);
    }

    /// Removes entry `id`, deferring the free of its acceleration structure.
    fn remove(&mut self, id: BlasId) {
        let Some(e) = self.entries.get(id) else {
            return;
        };
        let state = e.info.state;
        let owner = e.info.owner;
        let created_by = e.created_by;
        let size_query = e.size_query;
        debug_assert!(!state.in_flight(), "in-flight entries are never removed");
        if let (Some(address), Some(bytes)) = (state.address(), Self::held_bytes(&state)) {
            self.defer_free(BlasFree {
                blas: id,
                created_by,
                address,
                bytes,
            });
        }
        if let Some(q) = size_query {
            self.size_queries.remove(&q);
            self.dead_queries.insert(q);
        }
        self.update(id, |e| e.info.state = BlasState::Requested);
        self.entries.remove(id);
        self.compaction_ready.remove(&id);
        if let BlasOwner::Shared(key) = owner {
            if self.shared.get(&key) == Some(&id) {
                self.shared.remove(&key);
            }
        }
    }

    fn held_bytes(state: &BlasState) -> Option<u64> {
        match *state {
            BlasState::Built { bytes, .. }
            | BlasState::SizeQueried { bytes, .. }
            | BlasState::Compacted { bytes, .. } => Some(bytes),
            _ => None,
        }
    }

    fn defer_free(&mut self, free: BlasFree) {
        // Exact: frames are at most MAX_FRAME = 2^63 - 1.
        let safe = self.frame + u64::from(self.config.frames_in_flight);
        self.pending_free_bytes += u128::from(free.bytes);
        self.pending_frees.push((safe, free));
    }
}

/// `x`, or `u64::MAX` if it does not fit.
fn saturate(x: u128) -> u64 {
    u64::try_from(x).unwrap_or(u64::MAX)
}

#[cfg(test)]
mod tests;
