#version 460
// trace_merged.comp -- trace_counting.comp with adaptive hitboxes: merged
// counting boxes (lipac_core::hitbox_tree) are resolved to their leaf
// hitboxes' boxes (LIPAC_SBT_MERGED_BOX and friends in lipac_counting.glsl);
// the grid, levels, merged SBT offset and minimum box extent are push
// constants, the hitbox bounds binding 5. Otherwise as trace_counting.comp:
// hitbox boxes count straight into the HitboxRecord buffer (LIPAC_HITBOX_RECORDS:
// a saturating add of one hit to the 24-bit count, as Algorithm 2 expects),
// instance boxes (and committed real hits) into the per-slot u32 counters.
// No host step between the trace and GPU Algorithm 2.
#extension GL_EXT_ray_query : require
#extension GL_GOOGLE_include_directive : require

layout(local_size_x = 64) in;

layout(constant_id = 0) const uint SBT_OMITTED_BOX = 1;
layout(constant_id = 1) const uint SBT_HITBOX_BOX = 2;
layout(constant_id = 2) const uint COUNTING_MASK = 0x80;

#include "lipac_layout.glsl"

layout(set = 0, binding = 0) uniform accelerationStructureEXT tlas;

struct Ray {
    vec4 originTMin;     // xyz origin, w tMin
    vec4 directionTMax;  // xyz direction, w tMax
};
layout(std430, set = 0, binding = 1) readonly buffer Rays { Ray rays[]; };

struct Result {
    uint customIndex;    // 0xFFFFFFFF on a miss
    uint sbtOffset;
    float t;             // -1 on a miss
    uint flags;          // bit 0: hit, bit 1: counted a box
};
layout(std430, set = 0, binding = 2) writeonly buffer Results { Result results[]; };
layout(std430, set = 0, binding = 3) buffer InstanceHits { uint instanceHits[]; };
layout(std430, set = 0, binding = 4) buffer Hitboxes { LipacHitboxRecord hitboxes[]; };
layout(std430, set = 0, binding = 5) readonly buffer HitboxBounds { vec4 hitboxBounds[]; };

layout(push_constant) uniform Push {
    uint rayCount;
    uint cullMask;
    uint rayFlags;
    uint gridNx;
    uint gridNz;
    uint adaptiveLevels;
    uint mergedSbt;
    float minBoxExtent;
} pc;

#define LIPAC_SBT_OMITTED_BOX SBT_OMITTED_BOX
#define LIPAC_SBT_HITBOX_BOX SBT_HITBOX_BOX
#define LIPAC_COUNTING_MASK COUNTING_MASK
#define LIPAC_COUNT_INSTANCE(i) if ((i) < uint(instanceHits.length())) { atomicAdd(instanceHits[(i)], 1u); }
#define LIPAC_HITBOX_RECORDS hitboxes
#define LIPAC_COUNT_COMMITTED_HITS
#define LIPAC_SBT_MERGED_BOX pc.mergedSbt
#define LIPAC_HITBOX_BOUNDS hitboxBounds
#define LIPAC_GRID_NX pc.gridNx
#define LIPAC_GRID_NZ pc.gridNz
#define LIPAC_ADAPTIVE_LEVELS pc.adaptiveLevels
#define LIPAC_MIN_BOX_EXTENT pc.minBoxExtent
#include "lipac_counting.glsl"

void main() {
    uint i = gl_GlobalInvocationID.x;
    if (i >= pc.rayCount) {
        return;
    }
    Ray ray = rays[i];
    LipacHit h = lipacTraceCounting(tlas, pc.rayFlags, pc.cullMask, ray.originTMin.xyz,
                                    ray.originTMin.w, ray.directionTMax.xyz, ray.directionTMax.w);
    Result r;
    r.customIndex = h.hit ? h.customIndex : 0xFFFFFFFFu;
    r.sbtOffset = h.hit ? h.sbtOffset : 0xFFFFFFFFu;
    r.t = h.hit ? h.t : -1.0;
    r.flags = (h.hit ? 1u : 0u) | (h.countedBox ? 2u : 0u);
    results[i] = r;
}
