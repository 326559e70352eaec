// lipac_counting.glsl -- counting-box pass-through for engines' ray-query shaders.
//
// LiPaC puts two kinds of *counting boxes* into the TLAS: unit-cube instances
// spanning an omitted instance's AABB, and unit-cube instances spanning an
// inactive hitbox. A counting box is not geometry: a ray that reaches it counts
// one hit (for the instance slot or the hitbox whose index is the box's
// instance custom index) and goes on as if the box were not there. A ray counts
// at most one box, the nearest one, and only if that box lies before the
// closest real hit. Boxes are told apart from real instances by their
// instance SBT record offset.
//
// Requires `#extension GL_EXT_ray_query : require` before the #include.
//
// Define before including (plain macros or names of specialization constants):
//   LIPAC_SBT_OMITTED_BOX   uint: SBT record offset of omitted-instance boxes
//   LIPAC_SBT_HITBOX_BOX    uint: SBT record offset of hitbox boxes
//   LIPAC_COUNT_INSTANCE(i) statement counting one hit for instance slot i
//                           (typically atomicAdd(instanceHits[i], 1u))
//   LIPAC_COUNT_HITBOX(i)   statement counting one hit for hitbox i; or instead
//                           LIPAC_HITBOX_RECORDS: the name of a buffer array of
//                           LipacHitboxRecord (lipac_layout.glsl, included for
//                           you then), and the hook becomes a saturating add of
//                           one hit to the record's 24-bit count
//                           (LIPAC_HITBOX_ADD_HITS, an atomicCompSwap loop),
//                           which is what lipac's Algorithm 2 expects
// Optional:
//   LIPAC_COUNTING_MASK     uint cull-mask bits that only counting boxes carry
//                           (default 0x80u); cleared when the ray is continued
//                           past an opaque box
//   LIPAC_COUNT_COMMITTED_HITS  if defined, the closest real hit is counted too
//                           with LIPAC_COUNT_INSTANCE(custom index)
//   LIPAC_CANDIDATE_TRIANGLE(rq)  statement run for a non-opaque candidate
//                           triangle that is not a counting box (alpha test);
//                           default: rayQueryConfirmIntersectionEXT(rq)
//   LIPAC_CANDIDATE_AABB(rq) statement run for a candidate procedural AABB;
//                           default: nothing (AABBs are ignored)
//
// Boxes should be instances with VK_GEOMETRY_INSTANCE_FORCE_NO_OPAQUE_BIT_KHR
// and TRIANGLE_FACING_CULL_DISABLE: then they show up as candidates and are
// skipped inside one traversal. Opaque boxes work as well: a committed box is
// counted and the ray is continued from the box hit with LIPAC_COUNTING_MASK
// cleared (the path a ray-tracing-pipeline closest-hit shader takes, see
// lipacIsCountingBox / lipacCountBox / lipacMaskOutCountingBoxes).
// Do not pass gl_RayFlagsOpaqueEXT: it would make boxes opaque (still counted,
// at the cost of a second traversal). With gl_RayFlagsTerminateOnFirstHitEXT
// (shadow rays) a box nearer than the reported hit may go uncounted.
#ifndef LIPAC_COUNTING_GLSL
#define LIPAC_COUNTING_GLSL

#ifndef LIPAC_SBT_OMITTED_BOX
#error "lipac_counting.glsl: define LIPAC_SBT_OMITTED_BOX before including"
#endif
#ifndef LIPAC_SBT_HITBOX_BOX
#error "lipac_counting.glsl: define LIPAC_SBT_HITBOX_BOX before including"
#endif
#if !defined(LIPAC_COUNT_HITBOX) && defined(LIPAC_HITBOX_RECORDS)
#include "lipac_layout.glsl"
#define LIPAC_COUNT_HITBOX(i) \
    if ((i) < uint(LIPAC_HITBOX_RECORDS.length())) LIPAC_HITBOX_ADD_HITS(LIPAC_HITBOX_RECORDS[(i)].packed, 1u)
#endif
#ifndef LIPAC_COUNT_HITBOX
#error "lipac_counting.glsl: define LIPAC_COUNT_HITBOX(i) or LIPAC_HITBOX_RECORDS before including"
#endif
#ifndef LIPAC_COUNT_INSTANCE
#error "lipac_counting.glsl: define LIPAC_COUNT_INSTANCE(i) before including"
#endif
#ifndef LIPAC_COUNTING_MASK
#define LIPAC_COUNTING_MASK 0x80u
#endif
#ifndef LIPAC_CANDIDATE_TRIANGLE
#define LIPAC_CANDIDATE_TRIANGLE(rq) rayQueryConfirmIntersectionEXT(rq)
#endif
#ifndef LIPAC_CANDIDATE_AABB
#define LIPAC_CANDIDATE_AABB(rq)
#endif

// Whether an instance SBT record offset marks a counting box.
bool lipacIsCountingBox(uint sbtOffset) {
    return sbtOffset == uint(LIPAC_SBT_OMITTED_BOX) || sbtOffset == uint(LIPAC_SBT_HITBOX_BOX);
}

// Counts one hit on the box with this SBT record offset and custom index.
void lipacCountBox(uint sbtOffset, uint customIndex) {
    if (sbtOffset == uint(LIPAC_SBT_HITBOX_BOX)) {
        LIPAC_COUNT_HITBOX(customIndex);
    } else if (sbtOffset == uint(LIPAC_SBT_OMITTED_BOX)) {
        LIPAC_COUNT_INSTANCE(customIndex);
    }
}

// The cull mask for continuing a ray after it counted a box.
uint lipacMaskOutCountingBoxes(uint cullMask) {
    return cullMask & ~uint(LIPAC_COUNTING_MASK);
}

// The closest real (non-box) hit of a ray.
struct LipacHit {
    bool hit;            // false: the ray missed all real geometry
    float t;             // hit distance (tMax on a miss)
    uint customIndex;    // instance custom index
    uint instanceId;     // index of the instance in the TLAS
    uint sbtOffset;      // instance SBT record offset
    uint geometryIndex;
    uint primitiveIndex;
    vec2 barycentrics;
    bool frontFace;
    bool countedBox;     // the ray counted a box on its way
};

// Traces one ray through `tlas`, counting at most one counting box (the
// nearest, if it lies before the closest real hit), and returns the closest
// real hit.
LipacHit lipacTraceCounting(accelerationStructureEXT tlas, uint rayFlags, uint cullMask,
                            vec3 origin, float tMin, vec3 direction, float tMax) {
    LipacHit res;
    res.hit = false;
    res.t = tMax;
    res.customIndex = 0u;
    res.instanceId = 0u;
    res.sbtOffset = 0u;
    res.geometryIndex = 0u;
    res.primitiveIndex = 0u;
    res.barycentrics = vec2(0.0);
    res.frontFace = false;
    res.countedBox = false;

    float boxT = tMax;
    uint boxSbt = 0u;
    uint boxIndex = 0u;
    bool haveBox = false;
    float start = tMin;
    uint mask = cullMask;

    // Pass 0 traces with boxes; a second pass only runs when an opaque box
    // was committed: it continues from that box with boxes masked out.
    for (int pass = 0; pass < 2; ++pass) {
        rayQueryEXT rq;
        rayQueryInitializeEXT(rq, tlas, rayFlags, mask, origin, start, direction, tMax);
        while (rayQueryProceedEXT(rq)) {
            uint type = rayQueryGetIntersectionTypeEXT(rq, false);
            if (type == gl_RayQueryCandidateIntersectionTriangleEXT) {
                uint sbt = rayQueryGetIntersectionInstanceShaderBindingTableRecordOffsetEXT(rq, false);
                if (lipacIsCountingBox(sbt)) {
                    float t = rayQueryGetIntersectionTEXT(rq, false);
                    if (!haveBox || t < boxT) {
                        haveBox = true;
                        boxT = t;
                        boxSbt = sbt;
                        boxIndex = uint(rayQueryGetIntersectionInstanceCustomIndexEXT(rq, false));
                    }
                } else {
                    LIPAC_CANDIDATE_TRIANGLE(rq);
                }
            } else {
                LIPAC_CANDIDATE_AABB(rq);
            }
        }
        uint committed = rayQueryGetIntersectionTypeEXT(rq, true);
        if (committed == gl_RayQueryCommittedIntersectionNoneEXT) {
            break;
        }
        float t = rayQueryGetIntersectionTEXT(rq, true);
        uint sbt = rayQueryGetIntersectionInstanceShaderBindingTableRecordOffsetEXT(rq, true);
        if (pass == 0 && lipacIsCountingBox(sbt)) {
            // An opaque box was committed: it is a box hit like a candidate.
            if (!haveBox || t < boxT) {
                haveBox = true;
                boxT = t;
                boxSbt = sbt;
                boxIndex = uint(rayQueryGetIntersectionInstanceCustomIndexEXT(rq, true));
            }
            start = t;
            mask = lipacMaskOutCountingBoxes(cullMask);
            continue;
        }
        res.hit = true;
        res.t = t;
        res.customIndex = uint(rayQueryGetIntersectionInstanceCustomIndexEXT(rq, true));
        res.instanceId = uint(rayQueryGetIntersectionInstanceIdEXT(rq, true));
        res.sbtOffset = sbt;
        res.geometryIndex = uint(rayQueryGetIntersectionGeometryIndexEXT(rq, true));
        res.primitiveIndex = uint(rayQueryGetIntersectionPrimitiveIndexEXT(rq, true));
        res.barycentrics = rayQueryGetIntersectionBarycentricsEXT(rq, true);
        res.frontFace = rayQueryGetIntersectionFrontFaceEXT(rq, true);
        break;
    }

    if (haveBox && boxT <= res.t) {
        lipacCountBox(boxSbt, boxIndex);
        res.countedBox = true;
    }
#ifdef LIPAC_COUNT_COMMITTED_HITS
    if (res.hit) {
        LIPAC_COUNT_INSTANCE(res.customIndex);
    }
#endif
    return res;
}

#endif // LIPAC_COUNTING_GLSL
