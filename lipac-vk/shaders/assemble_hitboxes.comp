#version 460
// assemble_hitboxes.comp -- Algorithm 1 pass 2, one thread per hitbox
// (lipac_core::assembly::assemble_tlas, second loop): appends a counting box
// spanning the cell's x/z bounds and [minY, maxY] for each inactive hitbox
// whose extent is not empty (minY <= maxY as floats; the extent is the
// CPU's, lipac_core::hitbox_extents, never NaN; flat ranges are padded to
// minExtent like omitted boxes). With adaptive hitboxes (pc.adaptiveLevels >
// 0) it emits nothing: assemble_merged.comp emits the boxes.
#extension GL_GOOGLE_include_directive : require
#include "lipac_assembly.glsl"

void main() {
    if (pc.adaptiveLevels > 0u) {
        return;
    }
    LIPAC_FOR_EACH(i, pc.hitboxCount) {
        LipacHitboxRecord h = hitboxes[i];
        float minY = uintBitsToFloat(h.minY);
        float maxY = uintBitsToFloat(h.maxY);
        if ((h.packed & LIPAC_HITBOX_ACTIVE) != 0u || minY > maxY) {
            continue;
        }
        vec4 b = hitboxBounds[i];
        lipacAppendCountingBox(vec3(b.x, minY, b.y), vec3(b.z, maxY, b.w), i, pc.hitboxSbt);
    }
}
