#version 460
// feedback_hitboxes.comp -- Algorithm 2 lines 7-13, one thread per hitbox
// (lipac_core::feedback::hitbox_step): activation after nA frames above
// thetaA or one frame above 2 thetaA, deactivation after nD frames below
// thetaD; the 7-bit streak counts the run and resets on a break or a change.
// Hits are kept. Under the decayed rule (pc.rule) the rate is updated
// instead and decides (lipac_core::feedback::hitbox_step_decayed): activate
// above lipacActivationThreshold(cost), deactivate below rateDeactivate,
// streak bits zero.
#extension GL_GOOGLE_include_directive : require
#include "lipac_feedback.glsl"

void main() {
    LIPAC_FOR_EACH(i, pc.hitboxCount) {
        uint packed = hitboxes[i].packed;
        if (pc.rule == LIPAC_RULE_DECAYED) {
            uint rate = lipacUpdateRate(hitboxes[i].rate, packed >> LIPAC_HITBOX_HITS_SHIFT);
            bool on = (packed & LIPAC_HITBOX_ACTIVE) != 0u;
            if (!on) {
                on = rate > lipacActivationThreshold(hitboxes[i].cost);
            } else if (rate < pc.rateDeactivate) {
                on = false;
            }
            hitboxes[i].rate = rate;
            hitboxes[i].packed = (packed & ~((LIPAC_HITBOX_STREAK_MAX << LIPAC_HITBOX_STREAK_SHIFT) | LIPAC_HITBOX_ACTIVE)) |
                                 (on ? 1u : 0u);
            continue;
        }
        uint hits = packed >> LIPAC_HITBOX_HITS_SHIFT;
        bool isActive = (packed & LIPAC_HITBOX_ACTIVE) != 0u;
        uint streak = (packed >> LIPAC_HITBOX_STREAK_SHIFT) & LIPAC_HITBOX_STREAK_MAX;
        if (!isActive) {
            if (hits > 2u * pc.thetaA) {
                isActive = true;  // line 9, single frame
                streak = 0u;
            } else if (hits > pc.thetaA) {
                streak = min(streak + 1u, LIPAC_HITBOX_STREAK_MAX);
                if (streak >= pc.nA) {
                    isActive = true;  // line 9, nA frames
                    streak = 0u;
                }
            } else {
                streak = 0u;
            }
        } else if (hits < pc.thetaD) {
            streak = min(streak + 1u, LIPAC_HITBOX_STREAK_MAX);
            if (streak >= pc.nD) {
                isActive = false;  // line 11
                streak = 0u;
            }
        } else {
            streak = 0u;
        }
        hitboxes[i].packed = (hits << LIPAC_HITBOX_HITS_SHIFT) |
                             (streak << LIPAC_HITBOX_STREAK_SHIFT) | (isActive ? 1u : 0u);
    }
}
