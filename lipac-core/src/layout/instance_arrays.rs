//! The instance buffer as three per-slot arrays (the hot/cold split,
//! `docs/HOT_COLD.md`): [`InstanceHot`] (what Algorithms 1 and 2 decide on,
//! every slot, every frame) and the cold parts, read only where Algorithm 1
//! emits a record: [`InstanceTlas`] (the slot's TLAS record,
//! ready to copy, for an active slot) and [`InstanceBounds`] (the AABB, for
//! an omitted slot's counting box). [`InstanceArrays`] holds them with
//! equal lengths and keeps [`instance_bits::HAS_BLAS`] equal to `blas != 0`;
//! [`InstanceRecord`] is the joined view of one slot.

use bytemuck::{Pod, Zeroable};

use super::{instance_bits, InstanceRecord, InstanceState, TlasInstance};

/// The hot part of a slot (8 bytes): its hitbox and its packed bits
/// ([`instance_bits`]). Algorithm 2 reads only these (and the hit counter),
/// and writes only the state bits.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Pod, Zeroable)]
pub struct InstanceHot {
    /// Index of the hitbox that holds the AABB centre.
    pub hitbox: u32,
    /// State, flags, mask and instance flags; see [`instance_bits`].
    pub packed: u32,
}

impl InstanceHot {
    /// The instance's current state.
    pub fn state(&self) -> InstanceState {
        InstanceState::from_bits(self.packed)
    }
    /// Replaces the state bits.
    pub fn set_state(&mut self, state: InstanceState) {
        self.packed = (self.packed & !instance_bits::STATE_MASK) | state as u32;
    }
    /// Whether the slot holds a live instance.
    pub fn is_alive(&self) -> bool {
        self.packed & instance_bits::ALIVE != 0
    }
    /// Whether the instance needs a unique BLAS.
    pub fn needs_unique_blas(&self) -> bool {
        self.packed & instance_bits::UNIQUE_BLAS != 0
    }
    /// Whether the instance is pinned ([`instance_bits::PINNED`]).
    pub fn is_pinned(&self) -> bool {
        self.packed & instance_bits::PINNED != 0
    }
    /// Whether the instance has a BLAS ([`instance_bits::HAS_BLAS`]).
    pub fn has_blas(&self) -> bool {
        self.packed & instance_bits::HAS_BLAS != 0
    }
    /// The engine's visibility mask.
    pub fn mask(&self) -> u8 {
        (self.packed >> instance_bits::MASK_SHIFT) as u8
    }
    /// The instance's `VkGeometryInstanceFlagsKHR`.
    pub fn vk_flags(&self) -> u8 {
        (self.packed >> instance_bits::VK_FLAGS_SHIFT) as u8
    }
}

/// The slot's own TLAS record, ready to copy (64 bytes, 64-byte aligned:
/// one cache line): what Algorithm 1 emits for an active instance with a
/// BLAS, `VkAccelerationStructureInstanceKHR` exactly. Written by the CPU
/// with the record: the transform, custom index = slot, the mask and
/// instance flags of [`InstanceHot::packed`], the SBT offset (24 bits) and
/// the BLAS address. Read by Algorithm 1 only for a slot it emits as
/// active.
#[repr(C, align(64))]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct InstanceTlas {
    /// The record as Algorithm 1 emits it.
    pub record: TlasInstance,
}

/// The AABB and LOD of a slot (28 bytes): read by Algorithm 1 only for an
/// omitted slot (its counting box), and by the CPU (frustum tests, the
/// hitbox index, the hitbox extents' heights).
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct InstanceBounds {
    /// World-space AABB minimum.
    pub aabb_min: [f32; 3],
    /// World-space AABB maximum.
    pub aabb_max: [f32; 3],
    /// Mesh LOD currently selected (informational for backends).
    pub lod: u32,
}

/// The CPU instance buffer: one [`InstanceHot`], [`InstanceTlas`] and
/// [`InstanceBounds`] per slot, always of equal
/// lengths, with [`instance_bits::HAS_BLAS`] set exactly where the BLAS
/// address is nonzero and each TLAS record holding its slot, mask, flags,
/// SBT offset and BLAS address (every write goes through
/// [`InstanceArrays::set`], [`InstanceArrays::push`] or
/// [`InstanceArrays::set_blas`]; [`InstanceArrays::hot_mut`] is for the
/// state bits only).
///
/// ```
/// use lipac_core::layout::{instance_bits, InstanceArrays, InstanceRecord, InstanceState};
///
/// let rec = InstanceRecord { packed: instance_bits::ALIVE, blas: 0x100, ..Default::default() };
/// let mut arrays = InstanceArrays::from_records(&[InstanceRecord::default(), rec]);
/// assert_eq!(arrays.len(), 2);
/// assert!(arrays.hot()[1].has_blas() && !arrays.hot()[0].has_blas());
/// arrays.set_state(1, InstanceState::Active);
/// assert_eq!(arrays.get(1).unwrap().state(), InstanceState::Active);
/// assert_eq!(arrays.set_blas(1, 0), Some(0x100));
/// assert!(!arrays.hot()[1].has_blas());
/// ```
#[derive(Clone, Debug, Default, PartialEq)]
pub struct InstanceArrays {
    hot: Vec<InstanceHot>,
    tlas: Vec<InstanceTlas>,
    bounds: Vec<InstanceBounds>,
}

impl InstanceArrays {
    /// No slots.
    pub fn new() -> Self {
        Self::default()
    }

    /// The arrays holding `records`, slot for slot
    /// ([`instance_bits::HAS_BLAS`] derived from each BLAS address).
    pub fn from_records(records: &[InstanceRecord]) -> Self {
        let mut a = Self::new();
        // The records are in memory already: room for as many again (if
        // refused, the arrays grow as they are pushed).
        let _ = a.reserve_exact(records.len());
        for r in records {
            a.push(r);
        }
        a
    }

    /// The arrays from their parts as a GPU buffer holds them (e.g. read
    /// back), or `None` when the lengths differ. Taken as they are: neither
    /// [`instance_bits::HAS_BLAS`] nor the TLAS records are checked against
    /// each other.
    pub fn from_parts(
        hot: Vec<InstanceHot>,
        tlas: Vec<InstanceTlas>,
        bounds: Vec<InstanceBounds>,
    ) -> Option<Self> {
        let n = hot.len();
        (tlas.len() == n && bounds.len() == n).then_some(Self { hot, tlas, bounds })
    }

    /// Number of slots.
    pub fn len(&self) -> usize {
        self.hot.len()
    }

    /// Whether there are no slots.
    pub fn is_empty(&self) -> bool {
        self.hot.is_empty()
    }

    /// The hot array, one per slot.
    pub fn hot(&self) -> &[InstanceHot] {
        &self.hot
    }

    /// The hot array for Algorithm 2, which writes the state bits. Other
    /// bits written here are not checked: keep [`instance_bits::HAS_BLAS`]
    /// as [`InstanceArrays::set_blas`] leaves it.
    pub fn hot_mut(&mut self) -> &mut [InstanceHot] {
        &mut self.hot
    }

    /// The TLAS records, one per slot.
    pub fn tlas(&self) -> &[InstanceTlas] {
        &self.tlas
    }

    /// The AABBs and LODs, one per slot.
    pub fn bounds(&self) -> &[InstanceBounds] {
        &self.bounds
    }

    /// The joined record of `slot`, or `None` past the end.
    pub fn get(&self, slot: usize) -> Option<InstanceRecord> {
        Some(InstanceRecord::from_parts(
            self.hot.get(slot)?,
            self.tlas.get(slot)?,
            self.bounds.get(slot)?,
        ))
    }

    /// Replaces the record of `slot` (its [`instance_bits::HAS_BLAS`]
    /// derived from its BLAS address; its SBT offset kept to 24 bits);
    /// `false` (nothing changed) past the end.
    pub fn set(&mut self, slot: usize, record: &InstanceRecord) -> bool {
        if slot >= self.len() {
            return false;
        }
        self.hot[slot] = record.hot();
        self.tlas[slot] = record.tlas(slot as u32);
        self.bounds[slot] = record.bounds();
        true
    }

    /// Appends a slot holding `record`.
    pub fn push(&mut self, record: &InstanceRecord) {
        let slot = self.len() as u32;
        self.hot.push(record.hot());
        self.tlas.push(record.tlas(slot));
        self.bounds.push(record.bounds());
    }

    /// Grows (with dead slots, every word zero, as a GPU buffer grows with
    /// a fill) or shrinks the arrays to `len` slots. (A record written by
    /// [`InstanceArrays::set`], a dead one too, holds its slot in its TLAS
    /// record; a grown slot holds 0 until written.)
    pub fn resize(&mut self, len: usize) {
        self.hot.resize(len, InstanceHot::default());
        self.tlas.resize(len, InstanceTlas::default());
        self.bounds.resize(len, InstanceBounds::default());
    }

    /// Replaces `slot` by a dead (zeroed) record and returns the old one;
    /// `None` past the end.
    pub fn take(&mut self, slot: usize) -> Option<InstanceRecord> {
        let old = self.get(slot)?;
        self.set(slot, &InstanceRecord::default());
        Some(old)
    }

    /// Replaces the state bits of `slot` and returns the old state; `None`
    /// past the end.
    pub fn set_state(&mut self, slot: usize, state: InstanceState) -> Option<InstanceState> {
        let h = self.hot.get_mut(slot)?;
        let old = h.state();
        h.set_state(state);
        Some(old)
    }

    /// Sets the hitbox of `slot` and returns the old one; `None` past the
    /// end.
    pub fn set_hitbox(&mut self, slot: usize, hitbox: u32) -> Option<u32> {
        let h = self.hot.get_mut(slot)?;
        Some(std::mem::replace(&mut h.hitbox, hitbox))
    }

    /// Sets the BLAS address of `slot` (and [`instance_bits::HAS_BLAS`]
    /// with it) and returns the old address; `None` past the end.
    pub fn set_blas(&mut self, slot: usize, blas: u64) -> Option<u64> {
        let t = self.tlas.get_mut(slot)?;
        let old = std::mem::replace(&mut t.record.acceleration_structure_reference, blas);
        let h = &mut self.hot[slot];
        h.packed &= !instance_bits::HAS_BLAS;
        if blas != 0 {
            h.packed |= instance_bits::HAS_BLAS;
        }
        Some(old)
    }

    /// The joined records, slot by slot (by value).
    pub fn iter(&self) -> Records<'_> {
        Records {
            arrays: self,
            next: 0,
        }
    }

    /// The joined records as a `Vec` (for inspection and tests; not on a
    /// per-frame path).
    pub fn to_vec(&self) -> Vec<InstanceRecord> {
        self.iter().collect()
    }

    /// Reserves room for `additional` more slots in each array; an error
    /// (nothing reserved beyond what could be had) when the memory cannot
    /// be had.
    pub fn reserve_exact(&mut self, additional: usize) -> Result<(), crate::error::CoreError> {
        use crate::memory::try_reserve_exact;
        try_reserve_exact(&mut self.hot, additional, "instance records")?;
        try_reserve_exact(&mut self.tlas, additional, "instance records")?;
        try_reserve_exact(&mut self.bounds, additional, "instance records")
    }

    /// Slots the arrays hold without reallocating.
    pub fn capacity(&self) -> usize {
        self.hot
            .capacity()
            .min(self.tlas.capacity())
            .min(self.bounds.capacity())
    }

    /// Heap bytes of the three arrays, from their capacities.
    pub fn heap_bytes(&self) -> u64 {
        (self.hot.capacity() * std::mem::size_of::<InstanceHot>()
            + self.tlas.capacity() * std::mem::size_of::<InstanceTlas>()
            + self.bounds.capacity() * std::mem::size_of::<InstanceBounds>()) as u64
    }
}

/// Iterator over the joined records of [`InstanceArrays`], from
/// [`InstanceArrays::iter`].
#[derive(Clone, Debug)]
pub struct Records<'a> {
    arrays: &'a InstanceArrays,
    next: usize,
}

impl Iterator for Records<'_> {
    type Item = InstanceRecord;
    fn next(&mut self) -> Option<InstanceRecord> {
        let r = self.arrays.get(self.next)?;
        self.next += 1;
        Some(r)
    }
    fn size_hint(&self) -> (usize, Option<usize>) {
        let n = self.arrays.len().saturating_sub(self.next);
        (n, Some(n))
    }
}

impl ExactSizeIterator for Records<'_> {}

impl<'a> IntoIterator for &'a InstanceArrays {
    type Item = InstanceRecord;
    type IntoIter = Records<'a>;
    fn into_iter(self) -> Records<'a> {
        self.iter()
    }
}

impl FromIterator<InstanceRecord> for InstanceArrays {
    fn from_iter<I: IntoIterator<Item = InstanceRecord>>(iter: I) -> Self {
        let mut a = Self::new();
        for r in iter {
            a.push(&r);
        }
        a
    }
}
