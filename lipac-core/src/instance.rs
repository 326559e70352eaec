//! What an engine tells lipac about one model instance.

use crate::layout::instance_bits;
use crate::math::Aabb;
use glam::Affine3A;
use std::fmt;
use std::ops::{BitAnd, BitOr, BitOrAssign, Not};

/// The engine's id of a mesh. BLASes are shared by `(mesh, LOD)` unless the
/// instance needs a unique one.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct MeshId(pub u32);

/// Per-instance flags. The bit values are those of
/// [`instance_bits`], so they are stored in
/// [`InstanceRecord::packed`](crate::layout::InstanceRecord::packed) as they
/// are.
#[derive(Clone, Copy, Default, PartialEq, Eq, Hash)]
pub struct InstanceFlags(u32);

impl InstanceFlags {
    /// The instance needs its own BLAS (animated, deformed, terrain-adapted);
    /// it goes through the *omitted* state (Algorithm 2).
    pub const UNIQUE_BLAS: Self = Self(instance_bits::UNIQUE_BLAS);
    /// Vegetation (alpha tested; shadow rays may mask it out).
    pub const VEGETATION: Self = Self(instance_bits::VEGETATION);
    /// Static: its shared BLAS may be compacted.
    pub const STATIC: Self = Self(instance_bits::STATIC);
    /// Always traced (terrain, the player, large occluders, emitters): the
    /// instance is active from registration, its BLAS requested at once, it
    /// is never culled nor represented by a counting box, and Algorithm 2
    /// neither moves its state nor counts its hits into its hitbox.
    /// Clearing it (an update) hands the instance back to its hitbox: it
    /// stays active until Algorithm 2's normal rule says otherwise.
    pub const PINNED: Self = Self(instance_bits::PINNED);
    /// Every defined flag.
    pub const ALL: Self = Self(
        instance_bits::UNIQUE_BLAS
            | instance_bits::VEGETATION
            | instance_bits::STATIC
            | instance_bits::PINNED,
    );

    /// No flags.
    pub const fn empty() -> Self {
        Self(0)
    }
    /// The raw bits (a subset of [`InstanceFlags::ALL`]).
    pub const fn bits(self) -> u32 {
        self.0
    }
    /// Flags from raw bits, or `None` if `bits` has undefined bits set.
    pub const fn from_bits(bits: u32) -> Option<Self> {
        if bits & !Self::ALL.0 == 0 {
            Some(Self(bits))
        } else {
            None
        }
    }
    /// Flags from raw bits, dropping undefined bits.
    pub const fn from_bits_truncate(bits: u32) -> Self {
        Self(bits & Self::ALL.0)
    }
    /// Whether every flag of `other` is set.
    pub const fn contains(self, other: Self) -> bool {
        self.0 & other.0 == other.0
    }
    /// Whether no flag is set.
    pub const fn is_empty(self) -> bool {
        self.0 == 0
    }
    /// Sets the flags of `other`.
    pub fn insert(&mut self, other: Self) {
        self.0 |= other.0;
    }
    /// Clears the flags of `other`.
    pub fn remove(&mut self, other: Self) {
        self.0 &= !other.0;
    }
}

impl BitOr for InstanceFlags {
    type Output = Self;
    fn bitor(self, rhs: Self) -> Self {
        Self(self.0 | rhs.0)
    }
}

impl BitOrAssign for InstanceFlags {
    fn bitor_assign(&mut self, rhs: Self) {
        self.0 |= rhs.0;
    }
}

impl BitAnd for InstanceFlags {
    type Output = Self;
    fn bitand(self, rhs: Self) -> Self {
        Self(self.0 & rhs.0)
    }
}

impl Not for InstanceFlags {
    type Output = Self;
    fn not(self) -> Self {
        Self(!self.0 & Self::ALL.0)
    }
}

impl fmt::Debug for InstanceFlags {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let names = [
            (Self::UNIQUE_BLAS, "UNIQUE_BLAS"),
            (Self::VEGETATION, "VEGETATION"),
            (Self::STATIC, "STATIC"),
            (Self::PINNED, "PINNED"),
        ];
        let mut set = names.iter().filter(|(flag, _)| self.contains(*flag));
        write!(f, "InstanceFlags(")?;
        match set.next() {
            None => write!(f, "empty")?,
            Some((_, name)) => {
                write!(f, "{name}")?;
                for (_, name) in set {
                    write!(f, " | {name}")?;
                }
            }
        }
        write!(f, ")")
    }
}

/// Description of one instance, as registered with
/// [`InstanceRegistry`](crate::registry::InstanceRegistry).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct InstanceDesc {
    /// The mesh drawn.
    pub mesh: MeshId,
    /// Selected level of detail of the mesh.
    pub lod: u32,
    /// Object-to-world transform. Must be finite.
    pub transform: Affine3A,
    /// World-space bounds of the transformed mesh (the caller computes them).
    /// Must be finite with `min <= max`; zero extent is allowed.
    pub aabb: Aabb,
    /// Instance flags.
    pub flags: InstanceFlags,
    /// TLAS visibility mask.
    pub mask: u8,
    /// Shader binding table record offset (hit group); 24 bits.
    pub sbt_offset: u32,
    /// `VkGeometryInstanceFlagsKHR` (see `layout::VK_INSTANCE_*`).
    pub vk_flags: u8,
}

impl InstanceDesc {
    /// An instance of LOD 0 with no flags, full mask `0xFF`, SBT offset 0 and
    /// no Vulkan instance flags; set other fields with struct update syntax.
    pub fn new(mesh: MeshId, transform: Affine3A, aabb: Aabb) -> Self {
        Self {
            mesh,
            lod: 0,
            transform,
            aabb,
            flags: InstanceFlags::empty(),
            mask: 0xFF,
            sbt_offset: 0,
            vk_flags: 0,
        }
    }
}

#[cfg(test)]
mod tests;
