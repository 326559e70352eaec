#version 460
// feedback_instances.comp -- Algorithm 2 lines 14-38, one thread per slot
// (lipac_core::feedback::process_feedback, last loop), with the overflow
// rule: a transition that emits a command takes effect only if the command
// got a slot below the capacity; otherwise the instance keeps the state it
// had before that transition and the thread stops (retried next frame).
// Under the decayed rule lines 29-37 decide on the instance's decayed rate
// (instanceRates[slot]): updated from its hits while omitted or active with
// a BLAS, held while active without one, 0 while inactive, dead or shared.
// Reads the hot instance array only: the BLAS test is LIPAC_INSTANCE_HAS_BLAS.
#extension GL_GOOGLE_include_directive : require
#include "lipac_feedback.glsl"

void main() {
    LIPAC_FOR_EACH(slot, pc.instanceCount) {
        uint packed = instanceHot[slot].packed;
        bool decayed = pc.rule == LIPAC_RULE_DECAYED;
        // Dead, or pinned (never moved by Algorithm 2); the rate of either is 0.
        if ((packed & (LIPAC_INSTANCE_ALIVE | LIPAC_INSTANCE_PINNED)) != LIPAC_INSTANCE_ALIVE) {
            if (decayed && instanceRates[slot] != 0u) {
                instanceRates[slot] = 0u;
            }
            continue;
        }
        uint hb = instanceHot[slot].hitbox;
        if (hb >= pc.hitboxCount) {
            continue;
        }
        uint hitboxPacked = hitboxes[hb].packed;
        bool hActive = (hitboxPacked & LIPAC_HITBOX_ACTIVE) != 0u;
        uint hHits = hitboxPacked >> LIPAC_HITBOX_HITS_SHIFT;
        bool unique = (packed & LIPAC_INSTANCE_UNIQUE_BLAS) != 0u;
        uint old = lipacInstanceState(packed);
        uint state = old;
        bool overflow = false;

        if (state == LIPAC_STATE_ACTIVE && !hActive) {
            // Lines 17/18.
            if (lipacPushCommand(lipacCommandWord(slot, LIPAC_COMMAND_REMOVE, hHits))) {
                state = LIPAC_STATE_INACTIVE;
            } else {
                overflow = true;
            }
        } else if (state == LIPAC_STATE_OMITTED && !hActive) {
            // Lines 19/20.
            state = LIPAC_STATE_INACTIVE;
        } else if (state == LIPAC_STATE_INACTIVE && hActive) {
            if (unique) {
                // Line 23.
                state = LIPAC_STATE_OMITTED;
            } else if (lipacPushCommand(lipacCommandWord(slot, LIPAC_COMMAND_ADD, hHits))) {
                // Lines 25/26.
                state = LIPAC_STATE_ACTIVE;
            } else {
                overflow = true;
            }
        }

        if (decayed) {
            uint rate = 0u;
            if (unique) {
                uint hits = instanceHits[slot];
                bool built = (packed & LIPAC_INSTANCE_HAS_BLAS) != 0u;
                if (state == LIPAC_STATE_OMITTED || (state == LIPAC_STATE_ACTIVE && built)) {
                    rate = lipacUpdateRate(instanceRates[slot], hits);
                } else if (state == LIPAC_STATE_ACTIVE) {
                    rate = instanceRates[slot];  // no BLAS yet: no evidence, held
                }
                if (!overflow) {
                    if (state == LIPAC_STATE_OMITTED && rate > pc.rateInstanceActivate) {
                        if (lipacPushCommand(lipacCommandWord(slot, LIPAC_COMMAND_ADD, hits))) {
                            state = LIPAC_STATE_ACTIVE;
                        }
                    } else if (state == LIPAC_STATE_ACTIVE && built && rate < pc.rateInstanceOmit) {
                        if (lipacPushCommand(lipacCommandWord(slot, LIPAC_COMMAND_REMOVE, hits))) {
                            state = LIPAC_STATE_OMITTED;
                        }
                    }
                }
            }
            if (instanceRates[slot] != rate) {
                instanceRates[slot] = rate;
            }
        } else if (unique && !overflow) {
            // Lines 29-37 (M needs a unique BLAS).
            uint hits = instanceHits[slot];
            if (state == LIPAC_STATE_OMITTED && hits > pc.sigmaA) {
                // Lines 31/32.
                if (lipacPushCommand(lipacCommandWord(slot, LIPAC_COMMAND_ADD, hits))) {
                    state = LIPAC_STATE_ACTIVE;
                }
            } else if (state == LIPAC_STATE_ACTIVE && (packed & LIPAC_INSTANCE_HAS_BLAS) != 0u &&
                       hits < pc.sigmaO) {
                // Lines 34/35, only once the BLAS exists.
                if (lipacPushCommand(lipacCommandWord(slot, LIPAC_COMMAND_REMOVE, hits))) {
                    state = LIPAC_STATE_OMITTED;
                }
            }
        }

        if (state != old) {
            instanceHot[slot].packed = (packed & ~LIPAC_INSTANCE_STATE_MASK) | state;
        }
    }
}
