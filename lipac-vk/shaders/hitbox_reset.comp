#version 460
// hitbox_reset.comp -- Algorithm 1 pass 0 (lipac_core::assembly::begin_frame):
// every hitbox's hit count becomes 0; the active bit, streak, rate and extent
// (minY, maxY, cost: the CPU's, lipac_core::hitbox_extents, written by
// upload_records.comp) stay.
#extension GL_GOOGLE_include_directive : require
#include "lipac_assembly.glsl"

void main() {
    LIPAC_FOR_EACH(i, pc.hitboxCount) {
        hitboxes[i].packed &= 0xFFu;
    }
}
