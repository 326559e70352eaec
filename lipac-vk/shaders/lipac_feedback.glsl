// lipac_feedback.glsl -- interface shared by lipac's hit-feedback passes
// (Algorithm 2): feedback_accumulate.comp, feedback_hitboxes.comp,
// feedback_instances.comp. One descriptor set layout and one push-constant
// block for all three (lipac_vk::FeedbackPipeline).
#ifndef LIPAC_FEEDBACK_GLSL
#define LIPAC_FEEDBACK_GLSL

#include "lipac_layout.glsl"

layout(local_size_x = 64) in;

// The hot instance array only (8 B per slot): Algorithm 2 never reads the
// cold records (LIPAC_INSTANCE_HAS_BLAS stands for `blas != 0`).
layout(std430, set = 0, binding = 0) buffer InstancesHot { LipacInstanceHot instanceHot[]; };
layout(std430, set = 0, binding = 1) readonly buffer InstanceHits { uint instanceHits[]; };
layout(std430, set = 0, binding = 2) buffer Hitboxes { LipacHitboxRecord hitboxes[]; };
layout(std430, set = 0, binding = 3) writeonly buffer Commands { uint commands[]; };
layout(std430, set = 0, binding = 4) buffer CommandCounter { uint commandCounter; };
// Decayed hit rates (16.16) of unique-BLAS instances, one per slot (the
// decayed rule only; lipac_core::feedback::process_feedback_with_rates).
layout(std430, set = 0, binding = 5) buffer InstanceRates { uint instanceRates[]; };

// lipac_core::thresholds::Thresholds (validated on the host: 2*thetaA fits).
layout(push_constant) uniform FeedbackPush {
    uint thetaA;
    uint thetaD;
    uint sigmaA;
    uint sigmaO;
    uint nA;
    uint nD;
    uint instanceCount;
    uint hitboxCount;
    uint commandCapacity;
    // lipac_core::thresholds::DecisionRule: 0 = paper, 1 = decayed with:
    uint rule;
    uint decayShift;
    uint rateActivate;
    uint rateDeactivate;
    uint rateInstanceActivate;
    uint rateInstanceOmit;
    uint ratePerShared;
    uint ratePerUnique;
    uint decayRiseShift;  // DecayedRule::rise_shift (1..decayShift)
} pc;

// lipac_core::thresholds::DecayedRule::update_rate.
uint lipacUpdateRate(uint rate, uint hits) {
    return lipacRiseDecayRate(rate, hits, pc.decayShift, pc.decayRiseShift);
}

#define LIPAC_RULE_PAPER 0u
#define LIPAC_RULE_DECAYED 1u

// lipac_core::thresholds::DecayedRule::activation_threshold for a hitbox's
// cost word (validated on the host: it fits a uint without saturating).
uint lipacActivationThreshold(uint cost) {
    uint nShared = min(cost & 0xFFFFu, 255u);
    uint nUnique = min(cost >> 16, 255u);
    return pc.rateActivate + pc.ratePerShared * nShared + pc.ratePerUnique * nUnique;
}

#define LIPAC_FOR_EACH(i, count) \
    for (uint i = gl_GlobalInvocationID.x; i < (count); i += gl_NumWorkGroups.x * gl_WorkGroupSize.x)

// lipac_core::command::priority_from_hits: min(127, floor(4 log2(hits + 1))),
// in exact integer arithmetic.
uint lipacPriorityFromHits(uint hits) {
    if (hits == 0xFFFFFFFFu) {
        return 127u;
    }
    uint x = hits + 1u;
    uint k = uint(findMSB(x));
    uint mn = x << (31u - k);
    uint q = (mn >= 2553802834u ? 1u : 0u) + (mn >= 3037000500u ? 1u : 0u) +
             (mn >= 3611622603u ? 1u : 0u);
    return min(4u * k + q, 127u);
}

// The command word (lipac_core::command::Command::encode).
uint lipacCommandWord(uint slot, uint kind, uint hits) {
    return (slot & 0xFFFFFFu) | (kind << 24) | (lipacPriorityFromHits(hits) << 25);
}

// Reserves a slot in the bounded command buffer; returns whether the command
// fits (the overflow rule: a transition that emits a command only takes
// effect if it does). The counter keeps counting past the capacity.
bool lipacPushCommand(uint word) {
    uint at = atomicAdd(commandCounter, 1u);
    if (at >= pc.commandCapacity) {
        return false;
    }
    commands[at] = word;
    return true;
}

#endif // LIPAC_FEEDBACK_GLSL
