#version 460
// assemble_instances.comp -- Algorithm 1 pass 1, one thread per slot
// (lipac_core::assembly::assemble_tlas, first loop):
//   active with a BLAS -> its own TLAS record (appended via the counter);
//   omitted            -> a unit-cube counting box over its AABB;
//   inactive           -> min/max-reduces its AABB's y range into its hitbox
//                         (atomicMin/atomicMax on ordered keys; NaN ignored
//                         like f32::min/max) and counts into its cost word
//                         (atomicAdd: shared- or unique-BLAS).
// An active or omitted instance whose hitbox is inactive counts as inactive
// (its remove command may still be waiting for room in the command buffer).
// A pinned instance counts as active whatever its state bits and hitbox.
// Every slot's hot record is read; an inactive slot's heights; the cold
// record only of a slot that emits a TLAS record (LIPAC_INSTANCE_HAS_BLAS
// decides "active without a BLAS" without it).
// Pass 1 never writes the hitbox's packed word, so reading it here is safe.
// Dead slots, hitbox indices out of range and non-finite omitted AABBs are
// skipped, as on the CPU.
#extension GL_GOOGLE_include_directive : require
#include "lipac_assembly.glsl"

void main() {
    LIPAC_FOR_EACH(slot, pc.instanceCount) {
        LipacInstanceHot m = instanceHot[slot];
        if ((m.packed & LIPAC_INSTANCE_ALIVE) == 0u) {
            continue;
        }
        // A pinned instance is active whatever its state bits and hitbox say.
        bool pinned = (m.packed & LIPAC_INSTANCE_PINNED) != 0u;
        uint state = pinned ? LIPAC_STATE_ACTIVE : lipacInstanceState(m.packed);
        if (!pinned && state != LIPAC_STATE_INACTIVE && m.hitbox < pc.hitboxCount
                && (hitboxes[m.hitbox].packed & LIPAC_HITBOX_ACTIVE) == 0u) {
            state = LIPAC_STATE_INACTIVE;
        }
        if (state == LIPAC_STATE_ACTIVE) {
            if ((m.packed & LIPAC_INSTANCE_HAS_BLAS) == 0u) {
                continue;  // not built yet
            }
            uint at = atomicAdd(tlasCounter, 1u);
            if (at < pc.tlasCapacity) {
                LipacTlasInstance r;
                r.transform = instanceCold[slot].transform;
                r.customIndexAndMask = (slot & 0xFFFFFFu) | (((m.packed >> LIPAC_INSTANCE_MASK_SHIFT) & 0xFFu) << 24);
                r.sbtOffsetAndFlags = (instanceCold[slot].sbtOffset & 0xFFFFFFu) | (((m.packed >> LIPAC_INSTANCE_VK_FLAGS_SHIFT) & 0xFFu) << 24);
                r.reference = instanceCold[slot].blas;
                tlasOut[at] = r;
            }
        } else if (state == LIPAC_STATE_OMITTED) {
            float mn[3] = instanceCold[slot].aabbMin;
            float mx[3] = instanceCold[slot].aabbMax;
            lipacAppendCountingBox(vec3(mn[0], mn[1], mn[2]), vec3(mx[0], mx[1], mx[2]),
                                   slot, pc.omittedSbt);
        } else {
            if (m.hitbox >= pc.hitboxCount) {
                continue;
            }
            uint lo = floatBitsToUint(instanceHeights[slot].minY);
            uint hi = floatBitsToUint(instanceHeights[slot].maxY);
            if (!lipacIsNanBits(lo)) {
                atomicMin(hitboxes[m.hitbox].minY, lipacOrderedKey(lo));
            }
            if (!lipacIsNanBits(hi)) {
                atomicMax(hitboxes[m.hitbox].maxY, lipacOrderedKey(hi));
            }
            atomicAdd(hitboxes[m.hitbox].cost, (m.packed & LIPAC_INSTANCE_UNIQUE_BLAS) != 0u
                                                   ? LIPAC_HITBOX_COST_UNIQUE
                                                   : LIPAC_HITBOX_COST_SHARED);
        }
    }
}
