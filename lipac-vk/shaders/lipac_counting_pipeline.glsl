// lipac_counting_pipeline.glsl -- counting boxes for engines that trace with
// ray-tracing pipelines (VK_KHR_ray_tracing_pipeline). The same counts, ray
// for ray, as lipac_counting.glsl's ray-query path: a ray counts at most one
// counting box, the nearest, and only if it lies before the closest real hit;
// boxes are not geometry (rays go on through them, shadow rays included).
//
// As the paper does, counting happens in the hit shaders: the closest-hit
// shader of a counting box counts it and tells the ray generation shader
// (through the payload) to continue the ray from the box with
// LIPAC_COUNTING_MASK cleared; a non-opaque box is recorded by its any-hit
// shader (nearest so far, intersection ignored) and counted by the closest-hit
// shader of the real hit behind it or the miss shader. Real hits are counted
// in their closest-hit shader (LIPAC_COUNT_COMMITTED_HITS).
//
// Requires `#extension GL_EXT_ray_tracing : require`, and
// lipac_counting_common.glsl, lipac_payload.glsl (and lipac_layout.glsl) next
// to this file. Every
// stage includes it with the same macros as lipac_counting.glsl takes
// (LIPAC_SBT_OMITTED_BOX, LIPAC_SBT_HITBOX_BOX, LIPAC_COUNT_INSTANCE(i),
// LIPAC_COUNT_HITBOX(i) or LIPAC_HITBOX_RECORDS, optional LIPAC_COUNTING_MASK,
// LIPAC_COUNT_COMMITTED_HITS, the merged-box macros), plus:
//   LIPAC_PAYLOAD           the LipacPayload (lipac_payload.glsl: include it
//                           first, declare the payload, then include this)
//                           lvalue of the stage's payload:
//                           in ray generation the rayPayloadEXT variable (or
//                           a member of it), in hit and miss shaders the
//                           rayPayloadInEXT one
//   one of LIPAC_RAYGEN_SHADER, LIPAC_ANY_HIT_SHADER, LIPAC_CLOSEST_HIT_SHADER,
//   LIPAC_MISS_SHADER       the stage (hit-shader built-ins exist only there)
// Ray generation, optional:
//   LIPAC_PAYLOAD_LOCATION  location of the payload variable (default 0)
//   LIPAC_SBT_RECORD_OFFSET, LIPAC_SBT_RECORD_STRIDE, LIPAC_MISS_INDEX
//                           traceRayEXT's SBT arguments (default 0, 1, 0)
//
// Shader binding table: the hit group a box instance selects (its instance
// SBT offset LIPAC_SBT_OMITTED_BOX / _HITBOX_BOX / _MERGED_BOX, plus
// LIPAC_SBT_RECORD_OFFSET; the unit cube has one geometry) runs
//   any-hit:     if (lipacBoxAnyHit(KIND)) ignoreIntersectionEXT;
//   closest-hit: lipacBoxClosestHit(KIND, barycentrics);
// where KIND is that SBT offset (a specialization constant per stage, say).
// Real geometry's closest-hit shaders call lipacClosestHit(barycentrics,
// sbtOffset) (sbtOffset: whatever the engine knows, e.g. from its shader
// record; lipac only reports it), the miss shader lipacMiss(). An engine
// any-hit shader (alpha test) of real geometry starts with
// `if (lipacInBoxPass()) ignoreIntersectionEXT;` when real instances could
// carry the counting mask bits.
//
// Ray generation traces with
//   LipacHit h = lipacTraceCountingPipeline(tlas, flags, cullMask, o, tMin, d, tMax);
// which issues one traceRayEXT, a second one from an opaque box the ray
// counted (boxes masked out), or, with merged boxes (adaptive hitboxes), one
// for the boxes alone and one for the real hit, as the ray-query path does.
// The payload carries the nearest box between the shaders. Shadow rays: trace
// them with the same call (no gl_RayFlagsSkipClosestHitShaderEXT, which it
// clears, and no gl_RayFlagsTerminateOnFirstHitEXT, with which a box nearer
// than the reported hit may go uncounted, as with ray queries): a box never
// occludes.
#ifndef LIPAC_COUNTING_PIPELINE_GLSL
#define LIPAC_COUNTING_PIPELINE_GLSL

#include "lipac_counting_common.glsl"
#include "lipac_payload.glsl"

#ifndef LIPAC_PAYLOAD
#error "lipac_counting_pipeline.glsl: define LIPAC_PAYLOAD before including"
#endif
#if !defined(LIPAC_RAYGEN_SHADER) && !defined(LIPAC_ANY_HIT_SHADER) && \
    !defined(LIPAC_CLOSEST_HIT_SHADER) && !defined(LIPAC_MISS_SHADER)
#error "lipac_counting_pipeline.glsl: define the stage (LIPAC_RAYGEN_SHADER, ...) before including"
#endif
#ifndef LIPAC_PAYLOAD_LOCATION
#define LIPAC_PAYLOAD_LOCATION 0
#endif
#ifndef LIPAC_SBT_RECORD_OFFSET
#define LIPAC_SBT_RECORD_OFFSET 0
#endif
#ifndef LIPAC_SBT_RECORD_STRIDE
#define LIPAC_SBT_RECORD_STRIDE 1
#endif
#ifndef LIPAC_MISS_INDEX
#define LIPAC_MISS_INDEX 0
#endif

// Whether a box at distance t is nearer than the one recorded.
bool lipacPayloadNearer(float t) {
    return (LIPAC_PAYLOAD.state & LIPAC_PAYLOAD_HAVE_BOX) == 0u || t < LIPAC_PAYLOAD.boxT;
}

void lipacPayloadRecordBox(float t, uint sbt, uint index) {
    LIPAC_PAYLOAD.state |= LIPAC_PAYLOAD_HAVE_BOX;
    LIPAC_PAYLOAD.boxT = t;
    LIPAC_PAYLOAD.boxSbt = sbt;
    LIPAC_PAYLOAD.boxIndex = index;
}

// Counts the recorded box once, if it lies at or before distance t.
void lipacPayloadCountBoxBefore(float t) {
    if ((LIPAC_PAYLOAD.state & (LIPAC_PAYLOAD_HAVE_BOX | LIPAC_PAYLOAD_COUNTED_BOX)) ==
            LIPAC_PAYLOAD_HAVE_BOX &&
        LIPAC_PAYLOAD.boxT <= t) {
        lipacCountBox(LIPAC_PAYLOAD.boxSbt, LIPAC_PAYLOAD.boxIndex);
        LIPAC_PAYLOAD.state |= LIPAC_PAYLOAD_COUNTED_BOX;
    }
}

// Whether this is the boxes-alone trace of merged boxes (any-hit shaders of
// real geometry ignore every intersection then).
bool lipacInBoxPass() {
    return (LIPAC_PAYLOAD.state & LIPAC_PAYLOAD_BOXES_ONLY) != 0u;
}

#if defined(LIPAC_ANY_HIT_SHADER)
// Any-hit of a counting box's hit group (`boxSbt`: the SBT offset the hit
// group stands for). Returns true when the intersection is to be ignored
// (the caller runs ignoreIntersectionEXT), false to accept it. Mirrors the
// ray-query candidate loop: the nearest box is recorded and skipped; in the
// boxes-alone trace of merged boxes a merged box resolves to its nearest leaf
// box, and a nearer box is accepted (committed, as
// rayQueryConfirmIntersectionEXT), which culls faces beyond it.
bool lipacBoxAnyHit(uint boxSbt) {
    bool boxesOnly = lipacInBoxPass();
    if (!lipacIsCountingBox(boxSbt)) {
        return boxesOnly;
    }
    uint index = uint(gl_InstanceCustomIndexEXT);
#ifdef LIPAC_SBT_MERGED_BOX
    if (boxesOnly) {
        vec3 o = gl_WorldRayOriginEXT;
        vec3 d = gl_WorldRayDirectionEXT;
        float tMin = gl_RayTminEXT;
        float tMax = LIPAC_PAYLOAD.tMax;
        uint sbt = boxSbt;
        float t, tOut;
        if (sbt == uint(LIPAC_SBT_MERGED_BOX)) {
            uint leaf;
            if (!lipacMergedLeaf(index, o, d, tMin, tMax, t, leaf)) {
                return true;
            }
            sbt = uint(LIPAC_SBT_HITBOX_BOX);
            index = leaf;
        } else if (!lipacBoxEntry(gl_ObjectToWorldEXT, o, 1.0 / d, tMin, tMax, t, tOut)) {
            t = gl_HitTEXT;
        }
        if (lipacPayloadNearer(t)) {
            lipacPayloadRecordBox(t, sbt, index);
            return false;
        }
        return true;
    }
#endif
    float t = gl_HitTEXT;
    if (lipacPayloadNearer(t)) {
        lipacPayloadRecordBox(t, boxSbt, index);
    }
    return true;
}
#endif

#if defined(LIPAC_CLOSEST_HIT_SHADER)
// Closest-hit of real geometry: records the hit, counts the box recorded
// before it (if any lies before it) and, with LIPAC_COUNT_COMMITTED_HITS,
// the hit. `sbtOffset` is reported as LipacHit::sbtOffset.
void lipacClosestHit(vec2 barycentrics, uint sbtOffset) {
    float t = gl_HitTEXT;
    LIPAC_PAYLOAD.state |= LIPAC_PAYLOAD_HIT;
    LIPAC_PAYLOAD.t = t;
    LIPAC_PAYLOAD.customIndex = uint(gl_InstanceCustomIndexEXT);
    LIPAC_PAYLOAD.instanceId = uint(gl_InstanceID);
    LIPAC_PAYLOAD.sbtOffset = sbtOffset;
    LIPAC_PAYLOAD.geometryIndex = uint(gl_GeometryIndexEXT);
    LIPAC_PAYLOAD.primitiveIndex = uint(gl_PrimitiveID);
    LIPAC_PAYLOAD.frontFace = gl_HitKindEXT == gl_HitKindFrontFacingTriangleEXT ? 1u : 0u;
    LIPAC_PAYLOAD.barycentrics = barycentrics;
    lipacPayloadCountBoxBefore(t);
#ifdef LIPAC_COUNT_COMMITTED_HITS
    LIPAC_COUNT_INSTANCE(LIPAC_PAYLOAD.customIndex);
#endif
}

// Closest-hit of a counting box's hit group (an opaque box was the closest
// hit; `boxSbt`: the SBT offset the hit group stands for). Counts the nearest
// box (this one, or a nearer non-opaque one recorded on the way) and makes
// lipacTraceCountingPipeline continue the ray from here with boxes masked
// out. A hit group at an offset that is no box (or a box met after the ray
// was continued) is a real hit, as on the ray-query path.
void lipacBoxClosestHit(uint boxSbt, vec2 barycentrics) {
    if (!lipacIsCountingBox(boxSbt) ||
        (LIPAC_PAYLOAD.state & LIPAC_PAYLOAD_CONTINUED) != 0u) {
        lipacClosestHit(barycentrics, boxSbt);
        return;
    }
    float t = gl_HitTEXT;
    if (lipacPayloadNearer(t)) {
        lipacPayloadRecordBox(t, boxSbt, uint(gl_InstanceCustomIndexEXT));
    }
    // Whatever the continued ray meets lies at or beyond t.
    lipacPayloadCountBoxBefore(t);
    LIPAC_PAYLOAD.state |= LIPAC_PAYLOAD_BOX_COMMITTED;
    LIPAC_PAYLOAD.t = t;
}
#endif

#if defined(LIPAC_MISS_SHADER)
// Miss: counts the recorded box (it lies before tMax).
void lipacMiss() {
    if (!lipacInBoxPass()) {
        lipacPayloadCountBoxBefore(LIPAC_PAYLOAD.tMax);
    }
}
#endif

#if defined(LIPAC_RAYGEN_SHADER)
void lipacPayloadTrace(accelerationStructureEXT tlas, uint flags, uint mask, vec3 origin,
                       float tMin, vec3 direction, float tMax) {
    traceRayEXT(tlas, flags, mask, LIPAC_SBT_RECORD_OFFSET, LIPAC_SBT_RECORD_STRIDE,
                LIPAC_MISS_INDEX, origin, tMin, direction, tMax, LIPAC_PAYLOAD_LOCATION);
}

// Traces one ray through `tlas` with the pipeline, counting at most one
// counting box (the nearest, if it lies before the closest real hit), and
// returns the closest real hit: lipacTraceCounting's result, bit for bit.
LipacHit lipacTraceCountingPipeline(accelerationStructureEXT tlas, uint rayFlags, uint cullMask,
                                    vec3 origin, float tMin, vec3 direction, float tMax) {
    LIPAC_PAYLOAD.state = 0u;
    LIPAC_PAYLOAD.boxT = tMax;
    LIPAC_PAYLOAD.boxSbt = 0u;
    LIPAC_PAYLOAD.boxIndex = 0u;
    LIPAC_PAYLOAD.t = tMax;
    LIPAC_PAYLOAD.tMax = tMax;
    uint flags = rayFlags & ~gl_RayFlagsSkipClosestHitShaderEXT;
#ifdef LIPAC_SBT_MERGED_BOX
    if (uint(LIPAC_ADAPTIVE_LEVELS) != 0u) {
        uint boxMask = cullMask & uint(LIPAC_COUNTING_MASK);
        if (boxMask != 0u) {
            LIPAC_PAYLOAD.state = LIPAC_PAYLOAD_BOXES_ONLY;
            uint boxFlags = (flags & ~(gl_RayFlagsOpaqueEXT | gl_RayFlagsTerminateOnFirstHitEXT)) |
                            gl_RayFlagsNoOpaqueEXT | gl_RayFlagsSkipClosestHitShaderEXT;
            lipacPayloadTrace(tlas, boxFlags, boxMask, origin, tMin, direction, tMax);
            LIPAC_PAYLOAD.state &= ~LIPAC_PAYLOAD_BOXES_ONLY;
        }
        lipacPayloadTrace(tlas, flags, lipacMaskOutCountingBoxes(cullMask), origin, tMin,
                          direction, tMax);
    } else
#endif
    {
        lipacPayloadTrace(tlas, flags, cullMask, origin, tMin, direction, tMax);
        if ((LIPAC_PAYLOAD.state & LIPAC_PAYLOAD_BOX_COMMITTED) != 0u) {
            LIPAC_PAYLOAD.state =
                (LIPAC_PAYLOAD.state & ~LIPAC_PAYLOAD_BOX_COMMITTED) | LIPAC_PAYLOAD_CONTINUED;
            lipacPayloadTrace(tlas, flags, lipacMaskOutCountingBoxes(cullMask), origin,
                              LIPAC_PAYLOAD.t, direction, tMax);
        }
    }
    LipacHit res;
    res.hit = (LIPAC_PAYLOAD.state & LIPAC_PAYLOAD_HIT) != 0u;
    res.t = res.hit ? LIPAC_PAYLOAD.t : tMax;
    res.customIndex = res.hit ? LIPAC_PAYLOAD.customIndex : 0u;
    res.instanceId = res.hit ? LIPAC_PAYLOAD.instanceId : 0u;
    res.sbtOffset = res.hit ? LIPAC_PAYLOAD.sbtOffset : 0u;
    res.geometryIndex = res.hit ? LIPAC_PAYLOAD.geometryIndex : 0u;
    res.primitiveIndex = res.hit ? LIPAC_PAYLOAD.primitiveIndex : 0u;
    res.barycentrics = res.hit ? LIPAC_PAYLOAD.barycentrics : vec2(0.0);
    res.frontFace = res.hit && LIPAC_PAYLOAD.frontFace != 0u;
    res.countedBox = (LIPAC_PAYLOAD.state & LIPAC_PAYLOAD_COUNTED_BOX) != 0u;
    return res;
}
#endif

#endif // LIPAC_COUNTING_PIPELINE_GLSL
