#version 460
// hitbox_reset.comp -- Algorithm 1 pass 0 (lipac_core::assembly::begin_frame):
// every hitbox's height range becomes empty, its hit count and cost word 0;
// the active bit, streak and rate stay. The range is stored as ordered keys (lipacOrderedKey)
// of +inf / -inf for the atomicMin / atomicMax of assemble_instances.comp;
// assemble_hitboxes.comp turns keys back into f32 bits.
#extension GL_GOOGLE_include_directive : require
#include "lipac_assembly.glsl"

void main() {
    LIPAC_FOR_EACH(i, pc.hitboxCount) {
        hitboxes[i].minY = lipacOrderedKey(0x7F800000u);  // +inf
        hitboxes[i].maxY = lipacOrderedKey(0xFF800000u);  // -inf
        hitboxes[i].packed &= 0xFFu;
        hitboxes[i].cost = 0u;
    }
}
