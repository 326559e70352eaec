#version 460
// feedback_accumulate.comp -- Algorithm 2 lines 1-6, one thread per slot:
// the hits of every live active or omitted instance are added to its hitbox,
// saturating the 24-bit count (LIPAC_HITBOX_ADD_HITS, an atomicCompSwap loop).
// Pinned instances' hits stay out.
#extension GL_GOOGLE_include_directive : require
#include "lipac_feedback.glsl"

void main() {
    LIPAC_FOR_EACH(slot, pc.instanceCount) {
        uint n = instanceHits[slot];
        if (n == 0u) {
            continue;  // adds nothing: the hot record is not read
        }
        LipacInstanceHot m = instanceHot[slot];
        uint packed = m.packed;
        uint key = packed & (LIPAC_INSTANCE_ALIVE | LIPAC_INSTANCE_STATE_MASK);
        if (key != (LIPAC_INSTANCE_ALIVE | LIPAC_STATE_OMITTED) &&
            key != (LIPAC_INSTANCE_ALIVE | LIPAC_STATE_ACTIVE) ||
            (packed & LIPAC_INSTANCE_PINNED) != 0u) {
            continue;
        }
        uint h = m.hitbox;
        if (h < pc.hitboxCount) {
            LIPAC_HITBOX_ADD_HITS(hitboxes[h].packed, n);
        }
    }
}
