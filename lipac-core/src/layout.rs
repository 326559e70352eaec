//! GPU buffer layouts shared by the CPU reference and every backend.
//!
//! Everything here is `#[repr(C)]` and [`bytemuck::Pod`], so a backend uploads
//! these records byte for byte and its shaders declare the same structs
//! (see `lipac-vk/shaders/lipac_layout.glsl`). The CPU reference algorithms in
//! this crate read and write exactly these records, which is what makes
//! "GPU output equals CPU reference" a meaningful test.
//!
//! | record | bytes | what |
//! | --- | --- | --- |
//! | [`TlasInstance`] | 64 | `VkAccelerationStructureInstanceKHR` |
//! | [`InstanceRecord`] | 96 | per-instance state, one slot's view (and the upload staging format) |
//! | [`InstanceHot`] | 8 | per slot: hitbox and packed bits, read by Algorithms 1 and 2 every frame |
//! | [`InstanceTlas`] | 64 | per slot: its own TLAS record, copied by Algorithm 1 for an active slot |
//! | [`InstanceBounds`] | 28 | per slot: AABB and LOD, read by Algorithm 1 for an omitted slot |
//! | [`HitboxRecord`] | 20 | per-hitbox state (the paper's 12 bytes, a decayed hit rate and a cost word) |
//! | hit counter | 4 | one `u32` per instance slot (the paper's 4 bytes) |
//! | instance rate | 4 | one `u32` per slot: decayed hit rate (16.16) of a unique-BLAS instance |
//!
//! The instance buffer is held as three arrays indexed by slot
//! ([`InstanceArrays`]: hot, TLAS records, bounds), so that the per-frame
//! decisions touch 8 bytes per slot instead of 96; an [`InstanceRecord`] is
//! the joined view of one slot. Bytes per pass: `docs/HOT_COLD.md`.

use bytemuck::{Pod, Zeroable};

/// Largest GPU slot index plus one: the TLAS custom index has 24 bits.
pub const MAX_SLOTS: u32 = 1 << 24;

/// One TLAS instance, laid out exactly as `VkAccelerationStructureInstanceKHR`
/// (and D3D12's `D3D12_RAYTRACING_INSTANCE_DESC`).
///
/// Bit fields are packed little-endian as the C declaration does:
/// `instanceCustomIndex:24, mask:8` share one `u32`, and so do
/// `instanceShaderBindingTableRecordOffset:24, flags:8`.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct TlasInstance {
    /// Row-major 3x4 object-to-world matrix (`VkTransformMatrixKHR`).
    pub transform: [f32; 12],
    /// Custom index in bits 0..24, visibility mask in bits 24..32.
    pub custom_index_and_mask: u32,
    /// SBT record offset in bits 0..24, `VkGeometryInstanceFlagsKHR` in bits 24..32.
    pub sbt_offset_and_flags: u32,
    /// Device address (or handle) of the BLAS; 0 marks an inactive record.
    pub acceleration_structure_reference: u64,
}

impl TlasInstance {
    /// Packs the record from its fields; `custom_index` and `sbt_offset` are
    /// truncated to 24 bits.
    pub fn new(
        transform: [f32; 12],
        custom_index: u32,
        mask: u8,
        sbt_offset: u32,
        flags: u8,
        blas: u64,
    ) -> Self {
        Self {
            transform,
            custom_index_and_mask: (custom_index & 0x00FF_FFFF) | (u32::from(mask) << 24),
            sbt_offset_and_flags: (sbt_offset & 0x00FF_FFFF) | (u32::from(flags) << 24),
            acceleration_structure_reference: blas,
        }
    }
    /// The 24-bit custom index.
    pub fn custom_index(&self) -> u32 {
        self.custom_index_and_mask & 0x00FF_FFFF
    }
    /// The 8-bit visibility mask.
    pub fn mask(&self) -> u8 {
        (self.custom_index_and_mask >> 24) as u8
    }
    /// The 24-bit shader binding table record offset.
    pub fn sbt_offset(&self) -> u32 {
        self.sbt_offset_and_flags & 0x00FF_FFFF
    }
    /// The 8-bit `VkGeometryInstanceFlagsKHR`.
    pub fn flags(&self) -> u8 {
        (self.sbt_offset_and_flags >> 24) as u8
    }
    /// The record's 64 bytes as 16 little-endian words, exactly as a GPU
    /// buffer holds it: floats compare by bit pattern (`-0.0 != 0.0`, NaN
    /// payloads count), the BLAS reference is words 14 (low) and 15 (high).
    pub fn to_bits(&self) -> [u32; 16] {
        bytemuck::cast(*self)
    }
}

/// The records as a sorted multiset of their bit patterns
/// ([`TlasInstance::to_bits`]): two TLAS buffers that hold the same records
/// in any order, bit for bit, give equal vectors.
///
/// ```
/// use lipac_core::layout::{tlas_multiset, TlasInstance};
///
/// let a = TlasInstance::new([1.0; 12], 3, 0xFF, 0, 0, 0x100);
/// let b = TlasInstance::new([2.0; 12], 4, 0xFF, 0, 0, 0x200);
/// assert_eq!(tlas_multiset(&[a, b]), tlas_multiset(&[b, a]));
/// assert_ne!(tlas_multiset(&[a, a]), tlas_multiset(&[a, b]));
/// ```
pub fn tlas_multiset(records: &[TlasInstance]) -> Vec<[u32; 16]> {
    let mut v: Vec<[u32; 16]> = records.iter().map(TlasInstance::to_bits).collect();
    v.sort_unstable();
    v
}

/// `VK_GEOMETRY_INSTANCE_TRIANGLE_FACING_CULL_DISABLE_BIT_KHR`.
pub const VK_INSTANCE_CULL_DISABLE: u8 = 0x1;
/// `VK_GEOMETRY_INSTANCE_TRIANGLE_FLIP_FACING_BIT_KHR`.
pub const VK_INSTANCE_FLIP_FACING: u8 = 0x2;
/// `VK_GEOMETRY_INSTANCE_FORCE_OPAQUE_BIT_KHR`.
pub const VK_INSTANCE_FORCE_OPAQUE: u8 = 0x4;
/// `VK_GEOMETRY_INSTANCE_FORCE_NO_OPAQUE_BIT_KHR`.
pub const VK_INSTANCE_FORCE_NO_OPAQUE: u8 = 0x8;

/// State of one instance as the GPU sees it (two bits in
/// [`InstanceRecord::packed`]). Names follow the paper: `added` = *active*,
/// `removed` = *inactive*.
#[repr(u8)]
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum InstanceState {
    /// Only its hitbox represents it (paper: *inactive* / `removed`).
    Inactive = 0,
    /// Its AABB is a unit-cube counting box in the TLAS (paper: *omitted*).
    Omitted = 1,
    /// Its own BLAS is in the TLAS once built (paper: *active* / `added`).
    Active = 2,
}

impl InstanceState {
    /// Decodes the two state bits; the unused value 3 reads as `Inactive`.
    pub fn from_bits(bits: u32) -> Self {
        match bits & 0b11 {
            1 => Self::Omitted,
            2 => Self::Active,
            _ => Self::Inactive,
        }
    }
}

/// Bits of [`InstanceRecord::packed`].
pub mod instance_bits {
    /// Bits 0..2: [`super::InstanceState`].
    pub const STATE_MASK: u32 = 0b11;
    /// Bit 2: the slot holds a live instance.
    pub const ALIVE: u32 = 1 << 2;
    /// Bit 3: the instance needs a unique BLAS (animated, deformed, terrain-adapted).
    pub const UNIQUE_BLAS: u32 = 1 << 3;
    /// Bit 4: vegetation (alpha tested; shadow rays may mask it out).
    pub const VEGETATION: u32 = 1 << 4;
    /// Bit 5: static (its shared BLAS may be compacted).
    pub const STATIC: u32 = 1 << 5;
    /// Bit 6: pinned: always traced with its own BLAS (terrain, the player,
    /// large occluders, emitters); never culled, never a counting box, and
    /// skipped by Algorithm 2's decisions.
    pub const PINNED: u32 = 1 << 6;
    /// Bit 7: the instance has a BLAS (its TLAS record's reference,
    /// [`super::InstanceTlas`], is nonzero). Kept by [`super::InstanceArrays`] from the BLAS address, so
    /// that Algorithms 1 and 2 decide without reading the cold record.
    pub const HAS_BLAS: u32 = 1 << 7;
    /// Bits 8..16: the engine's TLAS visibility mask for this instance.
    pub const MASK_SHIFT: u32 = 8;
    /// Bits 16..24: `VkGeometryInstanceFlagsKHR` for this instance.
    pub const VK_FLAGS_SHIFT: u32 = 16;
}

/// Per-instance state, one per GPU slot (96 bytes, 16-byte aligned size).
///
/// Dead slots have [`instance_bits::ALIVE`] clear and are skipped by both
/// algorithms.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct InstanceRecord {
    /// Row-major 3x4 object-to-world matrix.
    pub transform: [f32; 12],
    /// World-space AABB minimum.
    pub aabb_min: [f32; 3],
    /// Index of the hitbox that holds the AABB centre.
    pub hitbox: u32,
    /// World-space AABB maximum.
    pub aabb_max: [f32; 3],
    /// State, flags, mask and instance flags; see [`instance_bits`].
    pub packed: u32,
    /// Device address of the instance's BLAS (shared or unique); 0 = none yet.
    pub blas: u64,
    /// SBT record offset (hit group) of the instance, 24 bits.
    pub sbt_offset: u32,
    /// Mesh LOD currently selected (informational for backends).
    pub lod: u32,
}

impl InstanceRecord {
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
    /// The engine's visibility mask.
    pub fn mask(&self) -> u8 {
        (self.packed >> instance_bits::MASK_SHIFT) as u8
    }
    /// The instance's `VkGeometryInstanceFlagsKHR`.
    pub fn vk_flags(&self) -> u8 {
        (self.packed >> instance_bits::VK_FLAGS_SHIFT) as u8
    }
    /// The slot's hot part, with [`instance_bits::HAS_BLAS`] set exactly
    /// when [`InstanceRecord::blas`] is nonzero (whatever `packed` says).
    pub fn hot(&self) -> InstanceHot {
        let has = if self.blas != 0 {
            instance_bits::HAS_BLAS
        } else {
            0
        };
        InstanceHot {
            hitbox: self.hitbox,
            packed: (self.packed & !instance_bits::HAS_BLAS) | has,
        }
    }
    /// The slot's own TLAS record if it is in slot `slot`: custom index =
    /// `slot`, the mask and instance flags of `packed`, the SBT offset (24
    /// bits), the BLAS address.
    pub fn tlas(&self, slot: u32) -> InstanceTlas {
        InstanceTlas {
            record: TlasInstance::new(
                self.transform,
                slot,
                self.mask(),
                self.sbt_offset,
                self.vk_flags(),
                self.blas,
            ),
        }
    }
    /// The slot's AABB and LOD.
    pub fn bounds(&self) -> InstanceBounds {
        InstanceBounds {
            aabb_min: self.aabb_min,
            aabb_max: self.aabb_max,
            lod: self.lod,
        }
    }
    /// Joins a slot's parts (the mask and flags are the hot record's).
    pub fn from_parts(hot: &InstanceHot, tlas: &InstanceTlas, bounds: &InstanceBounds) -> Self {
        Self {
            transform: tlas.record.transform,
            aabb_min: bounds.aabb_min,
            hitbox: hot.hitbox,
            aabb_max: bounds.aabb_max,
            packed: hot.packed,
            blas: tlas.record.acceleration_structure_reference,
            sbt_offset: tlas.record.sbt_offset(),
            lod: bounds.lod,
        }
    }
}

mod instance_arrays;

/// Bytes of the instance arrays per slot on the GPU: [`InstanceHot`] +
/// [`InstanceTlas`] + [`InstanceBounds`] (8 + 64 + 28).
pub const INSTANCE_SLOT_BYTES: u64 = (std::mem::size_of::<InstanceHot>()
    + std::mem::size_of::<InstanceTlas>()
    + std::mem::size_of::<InstanceBounds>()) as u64;
pub use instance_arrays::{InstanceArrays, InstanceBounds, InstanceHot, InstanceTlas, Records};

/// Bits of [`HitboxRecord::packed`].
pub mod hitbox_bits {
    /// Bit 0: the hitbox is active (its instances may be in the TLAS).
    pub const ACTIVE: u32 = 1;
    /// Bits 1..8: frames in a row the hitbox has been above θa (while
    /// inactive) or below θd (while active).
    pub const STREAK_SHIFT: u32 = 1;
    /// Mask of the streak counter after shifting.
    pub const STREAK_MAX: u32 = 0x7F;
    /// Bits 8..32: this frame's hit count, saturating at [`HITS_MAX`].
    pub const HITS_SHIFT: u32 = 8;
    /// Largest hit count a hitbox holds.
    pub const HITS_MAX: u32 = (1 << 24) - 1;
    /// [`super::HitboxRecord::cost`]: one inactive shared-BLAS instance
    /// (the low 16 bits count them, wrapping).
    pub const COST_SHARED: u32 = 1;
    /// [`super::HitboxRecord::cost`]: one inactive unique-BLAS instance
    /// (the high 16 bits count them, wrapping).
    pub const COST_UNIQUE: u32 = 1 << 16;
}

/// Per-hitbox state: 20 bytes, the paper's 12 plus the decayed rule's rate
/// and the cost word.
///
/// `min_y`/`max_y` and `cost` are rebuilt every frame by TLAS assembly
/// (Algorithm 1) from the inactive instances of the hitbox; the hit count is
/// this frame's; `rate` carries over frames (the decayed rule,
/// [`crate::thresholds::DecisionRule::Decayed`]; 0 under the paper's rule).
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, Pod, Zeroable)]
pub struct HitboxRecord {
    /// Lowest AABB minimum height of the hitbox's inactive instances.
    pub min_y: f32,
    /// Highest AABB maximum height of the hitbox's inactive instances.
    pub max_y: f32,
    /// Active bit, streak counter and saturating hit count; see [`hitbox_bits`].
    pub packed: u32,
    /// Exponentially decayed hit rate in 16.16 fixed point (hits per frame
    /// · 2^16), updated by Algorithm 2 under the decayed rule
    /// ([`crate::thresholds::decay_rate`]); kept by [`crate::assembly::begin_frame`].
    pub rate: u32,
    /// This frame's inactive instances, by cost: low 16 bits shared-BLAS,
    /// high 16 bits unique-BLAS ones (each a wrapping count, read saturated
    /// at 255 by the cost-aware rule). Zeroed and rebuilt by Algorithm 1.
    pub cost: u32,
}

impl Default for HitboxRecord {
    fn default() -> Self {
        Self {
            min_y: f32::INFINITY,
            max_y: f32::NEG_INFINITY,
            packed: 0,
            rate: 0,
            cost: 0,
        }
    }
}

impl HitboxRecord {
    /// Whether the hitbox is active.
    pub fn is_active(&self) -> bool {
        self.packed & hitbox_bits::ACTIVE != 0
    }
    /// This frame's hit count.
    pub fn hits(&self) -> u32 {
        self.packed >> hitbox_bits::HITS_SHIFT
    }
    /// Frames in a row towards the next state change.
    pub fn streak(&self) -> u32 {
        (self.packed >> hitbox_bits::STREAK_SHIFT) & hitbox_bits::STREAK_MAX
    }
    /// This frame's inactive shared-BLAS instances (from [`Self::cost`]),
    /// saturated at 255.
    pub fn inactive_shared(&self) -> u32 {
        (self.cost & 0xFFFF).min(255)
    }
    /// This frame's inactive unique-BLAS instances (from [`Self::cost`]),
    /// saturated at 255.
    pub fn inactive_unique(&self) -> u32 {
        (self.cost >> 16).min(255)
    }
    /// Adds hits, saturating at [`hitbox_bits::HITS_MAX`].
    pub fn add_hits(&mut self, hits: u32) {
        let total = self.hits().saturating_add(hits).min(hitbox_bits::HITS_MAX);
        self.packed = (self.packed & ((1 << hitbox_bits::HITS_SHIFT) - 1))
            | (total << hitbox_bits::HITS_SHIFT);
    }
}

const _: () = assert!(std::mem::size_of::<TlasInstance>() == 64);
const _: () = assert!(std::mem::size_of::<InstanceRecord>() == 96);
const _: () = assert!(std::mem::size_of::<HitboxRecord>() == 20);
const _: () = assert!(std::mem::size_of::<InstanceHot>() == 8);
const _: () = assert!(std::mem::size_of::<InstanceTlas>() == 64);
const _: () = assert!(std::mem::align_of::<InstanceTlas>() == 64);
const _: () = assert!(std::mem::size_of::<InstanceBounds>() == 28);

#[cfg(test)]
mod tests;
