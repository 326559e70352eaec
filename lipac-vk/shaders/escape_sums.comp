#version 460
// escape_sums.comp -- the escape fraction's two sums of one frame
// (lipac_core::controller::EscapeSample, as Manager::process_feedback takes
// it on the CPU), after the trace and before Algorithm 2: counting-box hits
// (every hitbox's hit count, and the hits of live omitted instances) and
// traced hits (the hits of every other live instance). One item per slot,
// then one per hitbox; each sum is 64 bits (low word, high word), reduced in
// the work group first, then added to the buffer with the carry.
#extension GL_GOOGLE_include_directive : require
#include "lipac_layout.glsl"

layout(local_size_x = 64) in;

// The hot instance array (8 B per slot): the state bits are all it needs.
layout(std430, set = 0, binding = 0) readonly buffer InstancesHot { LipacInstanceHot instanceHot[]; };
layout(std430, set = 0, binding = 1) readonly buffer InstanceHits { uint instanceHits[]; };
layout(std430, set = 0, binding = 2) readonly buffer Hitboxes { LipacHitboxRecord hitboxes[]; };
// [box hits low, high, traced hits low, high], zeroed before the pass.
layout(std430, set = 0, binding = 3) buffer Sums { uint sums[4]; };

layout(push_constant) uniform EscapePush {
    uint instanceCount;
    uint hitboxCount;
} pc;

shared uint groupSums[4];

// sum (low, high) += n
uvec2 add64(uvec2 sum, uint n) {
    uint lo = sum.x + n;
    return uvec2(lo, sum.y + (lo < n ? 1u : 0u));
}

void main() {
    if (gl_LocalInvocationID.x == 0u) {
        groupSums[0] = 0u;
        groupSums[1] = 0u;
        groupSums[2] = 0u;
        groupSums[3] = 0u;
    }
    barrier();
    uvec2 boxes = uvec2(0u);
    uvec2 traced = uvec2(0u);
    uint items = pc.instanceCount + pc.hitboxCount;
    for (uint i = gl_GlobalInvocationID.x; i < items; i += gl_NumWorkGroups.x * gl_WorkGroupSize.x) {
        if (i < pc.instanceCount) {
            uint n = instanceHits[i];
            if (n == 0u) {
                continue;  // adds nothing: the hot record is not read
            }
            uint packed = instanceHot[i].packed;
            if ((packed & LIPAC_INSTANCE_ALIVE) == 0u) {
                continue;
            }
            if (lipacInstanceState(packed) == LIPAC_STATE_OMITTED) {
                boxes = add64(boxes, n);
            } else {
                traced = add64(traced, n);
            }
        } else {
            boxes = add64(boxes, hitboxes[i - pc.instanceCount].packed >> LIPAC_HITBOX_HITS_SHIFT);
        }
    }
    if (boxes != uvec2(0u)) {
        uint was = atomicAdd(groupSums[0], boxes.x);
        atomicAdd(groupSums[1], boxes.y + (was + boxes.x < was ? 1u : 0u));
    }
    if (traced != uvec2(0u)) {
        uint was = atomicAdd(groupSums[2], traced.x);
        atomicAdd(groupSums[3], traced.y + (was + traced.x < was ? 1u : 0u));
    }
    barrier();
    if (gl_LocalInvocationID.x == 0u) {
        for (uint k = 0u; k < 4u; k += 2u) {
            uint lo = groupSums[k];
            uint hi = groupSums[k + 1u];
            if (lo != 0u || hi != 0u) {
                uint was = atomicAdd(sums[k], lo);
                atomicAdd(sums[k + 1u], hi + (was + lo < was ? 1u : 0u));
            }
        }
    }
}
