#version 460
// assemble_instances.comp -- Algorithm 1 pass 1, one thread per slot
// (lipac_core::assembly::assemble_tlas, first loop):
//   active with a BLAS -> its own TLAS record, copied as the CPU wrote it
//                         (instanceTlas: transform, custom index = slot,
//                         mask, SBT offset, flags, BLAS address), appended
//                         via the counter;
//   omitted            -> a unit-cube counting box over its AABB
//                         (instanceBounds);
//   inactive           -> nothing: its hitbox's counting box stands for it,
//                         and that box's heights and cost word are the CPU's
//                         extents (lipac_core::hitbox_extents).
// An active or omitted instance whose hitbox is inactive counts as inactive
// (its remove command may still be waiting for room in the command buffer).
// A pinned instance counts as active whatever its state bits and hitbox.
// Every slot's hot record is read; the TLAS record or the bounds only of a
// slot that emits a record (LIPAC_INSTANCE_HAS_BLAS decides "active without
// a BLAS" without it). Pass 1 never writes the hitbox records, so reading
// their packed words here is safe. Dead slots and non-finite omitted AABBs
// are skipped, as on the CPU.
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
                tlasOut[at] = instanceTlas[slot];
            }
        } else if (state == LIPAC_STATE_OMITTED) {
            float mn[3] = instanceBounds[slot].aabbMin;
            float mx[3] = instanceBounds[slot].aabbMax;
            lipacAppendCountingBox(vec3(mn[0], mn[1], mn[2]), vec3(mx[0], mx[1], mx[2]),
                                   slot, pc.omittedSbt);
        }
    }
}
