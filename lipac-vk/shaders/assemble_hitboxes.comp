#version 460
// assemble_hitboxes.comp -- Algorithm 1 pass 2, one thread per hitbox
// (lipac_core::assembly::assemble_tlas, second loop): turns the height range
// back from ordered keys into f32 bits (every hitbox), then appends a
// counting box spanning the cell's x/z bounds and [minY, maxY] for each
// inactive hitbox with at least one inactive instance (minY <= maxY; flat
// ranges are padded to minExtent like omitted boxes). With adaptive hitboxes
// (pc.adaptiveLevels > 0) it only converts the heights: assemble_merged.comp
// emits the boxes after a barrier (it reads neighbouring hitboxes).
#extension GL_GOOGLE_include_directive : require
#include "lipac_assembly.glsl"

void main() {
    LIPAC_FOR_EACH(i, pc.hitboxCount) {
        LipacHitboxRecord h = hitboxes[i];
        uint minBits = lipacFromOrderedKey(h.minY);
        uint maxBits = lipacFromOrderedKey(h.maxY);
        hitboxes[i].minY = minBits;
        hitboxes[i].maxY = maxBits;
        if (pc.adaptiveLevels > 0u) {
            continue;
        }
        // Keys compare like the floats: minY > maxY means no inactive instance.
        if ((h.packed & LIPAC_HITBOX_ACTIVE) != 0u || h.minY > h.maxY) {
            continue;
        }
        vec4 b = hitboxBounds[i];
        lipacAppendCountingBox(vec3(b.x, uintBitsToFloat(minBits), b.y),
                               vec3(b.z, uintBitsToFloat(maxBits), b.w), i, pc.hitboxSbt);
    }
}
