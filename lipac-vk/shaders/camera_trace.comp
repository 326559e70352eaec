#version 460
// camera_trace.comp -- a whole frame's rays generated on the GPU, every ray
// through lipac_counting.glsl: one primary ray per pixel, a sun shadow ray
// and one diffuse bounce from its hit. The stand-in for an engine's own
// ray-query pass (CameraTracer); vk_city renders with it.
//
// Hit counting as an engine ships it: instance boxes and committed real hits
// into the per-slot u32 counters, hitbox boxes straight into the
// HitboxRecord buffer (LIPAC_HITBOX_RECORDS) that Algorithm 2 reads.
// Adaptive hitboxes: merged counting boxes are resolved to their leaf
// hitboxes' boxes as in trace_merged.comp (LIPAC_SBT_MERGED_BOX and friends,
// from push constants: lipac_vk::MergedBoxes, adaptiveLevels 0 = off, the
// leaf-only path), reading the hitbox records and bounds (binding 6).
// Shading reads the instance's geometry data (an RGBA albedo, 4 floats) at
// dataOffsets[customIndex], the range lipac-vk's LipacVk keeps per slot.
#extension GL_EXT_ray_query : require
#extension GL_GOOGLE_include_directive : require

layout(local_size_x = 8, local_size_y = 8) in;

layout(constant_id = 0) const uint SBT_OMITTED_BOX = 1;
layout(constant_id = 1) const uint SBT_HITBOX_BOX = 2;
layout(constant_id = 2) const uint COUNTING_MASK = 0x80;

#include "lipac_layout.glsl"

layout(set = 0, binding = 0) uniform accelerationStructureEXT tlas;
layout(std430, set = 0, binding = 1) buffer InstanceHits { uint instanceHits[]; };
layout(std430, set = 0, binding = 2) buffer Hitboxes { LipacHitboxRecord hitboxes[]; };
layout(std430, set = 0, binding = 3) readonly buffer Data { uint dataWords[]; };
layout(std430, set = 0, binding = 4) readonly buffer DataOffsets { uint dataOffsets[]; };
layout(std430, set = 0, binding = 5) writeonly buffer Image { uint pixels[]; };
layout(std430, set = 0, binding = 6) readonly buffer HitboxBounds { vec4 hitboxBounds[]; };

layout(push_constant) uniform Push {
    vec4 originTMax;   // xyz eye, w tMax
    vec4 forward;      // xyz unit view direction
    vec4 right;        // xyz right * tan(vfov/2) * aspect
    vec4 up;           // xyz up * tan(vfov/2)
    vec4 sun;          // xyz unit direction to the sun
    uint width;
    uint height;
    uint seed;
    uint passes;       // bit 0: shadow rays, bit 1: diffuse bounce
    // lipac_vk::MergedBoxes (adaptiveLevels 0: no merged boxes)
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

uint hash(uint x) {
    x ^= x >> 16; x *= 0x7feb352du;
    x ^= x >> 15; x *= 0x846ca68bu;
    x ^= x >> 16;
    return x;
}

float unitFloat(uint x) {
    return float(hash(x) >> 8) * (1.0 / 16777216.0);
}

vec3 sky(vec3 d) {
    return mix(vec3(0.9, 0.9, 0.95), vec3(0.55, 0.7, 0.9), max(d.y, 0.0));
}

vec3 albedo(uint slot) {
    if (slot >= uint(dataOffsets.length())) {
        return vec3(0.6);
    }
    uint w = dataOffsets[slot] / 4u;
    if (w + 3u >= uint(dataWords.length())) {
        return vec3(0.6);
    }
    return vec3(uintBitsToFloat(dataWords[w]), uintBitsToFloat(dataWords[w + 1u]),
                uintBitsToFloat(dataWords[w + 2u]));
}

void main() {
    uvec2 px = gl_GlobalInvocationID.xy;
    if (px.x >= pc.width || px.y >= pc.height) {
        return;
    }
    vec2 s = (vec2(px) + 0.5) / vec2(pc.width, pc.height) * 2.0 - 1.0;
    vec3 o = pc.originTMax.xyz;
    vec3 d = normalize(pc.forward.xyz + pc.right.xyz * s.x - pc.up.xyz * s.y);
    LipacHit h = lipacTraceCounting(tlas, gl_RayFlagsNoneEXT, 0xFFu, o, 0.0, d, pc.originTMax.w);
    vec3 rgb;
    if (!h.hit) {
        rgb = sky(d);
    } else {
        vec3 p = o + d * (h.t * 0.999);
        vec3 a = albedo(h.customIndex);
        float light = 1.0;
        if ((pc.passes & 1u) != 0u) {
            LipacHit sh = lipacTraceCounting(tlas, gl_RayFlagsNoneEXT, 0xFFu,
                                             p + pc.sun.xyz * 0.05, 0.0, pc.sun.xyz, 1.0e4);
            light = sh.hit ? 0.35 : 1.0;
        }
        vec3 bounce = vec3(0.5);
        if ((pc.passes & 2u) != 0u) {
            // Cosine-weighted around the direction back to the eye (the hit
            // normal is not fetched: a view-facing diffuse lobe).
            uint k = (px.y * pc.width + px.x) * 2u + pc.seed * 0x9E3779B9u;
            float r1 = unitFloat(k), r2 = unitFloat(k + 1u);
            vec3 n = -d;
            vec3 t = normalize(abs(n.y) < 0.99 ? cross(n, vec3(0, 1, 0)) : cross(n, vec3(1, 0, 0)));
            vec3 b = cross(n, t);
            float phi = 6.2831853 * r1;
            vec3 bd = normalize(t * (cos(phi) * sqrt(r2)) + b * (sin(phi) * sqrt(r2)) + n * sqrt(1.0 - r2));
            LipacHit bh = lipacTraceCounting(tlas, gl_RayFlagsNoneEXT, 0xFFu, p + n * 0.05, 0.0, bd, 1.0e4);
            bounce = bh.hit ? albedo(bh.customIndex) * 0.3 : sky(bd);
        }
        float fog = exp(-h.t / 1500.0);
        rgb = a * (0.75 * light + 0.25 * bounce) * fog + vec3(0.7) * (1.0 - fog);
    }
    uvec3 c = uvec3(clamp(rgb, 0.0, 1.0) * 255.0 + 0.5);
    pixels[px.y * pc.width + px.x] = c.r | (c.g << 8) | (c.b << 16) | (255u << 24);
}
