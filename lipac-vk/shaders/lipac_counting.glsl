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
// Requires `#extension GL_EXT_ray_query : require` before the #include, and
// lipac_counting_common.glsl (and lipac_layout.glsl) next to this file.
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
// Adaptive hitboxes (lipac_core::hitbox_tree; merged counting boxes stand for
// several inactive hitboxes), all of these or none:
//   LIPAC_SBT_MERGED_BOX    uint: SBT record offset of merged boxes
//   LIPAC_HITBOX_RECORDS    (as above) the hitbox records Algorithm 1 left
//                           (heights, active bits)
//   LIPAC_HITBOX_BOUNDS     name of a buffer array of vec4 per hitbox: its
//                           x/z bounds (lo.x, lo.z, hi.x, hi.z), lipac_vk's
//                           hitbox bounds buffer
//   LIPAC_GRID_NX, LIPAC_GRID_NZ, LIPAC_ADAPTIVE_LEVELS  uint: the grid and
//                           the merge levels; LIPAC_MIN_BOX_EXTENT float:
//                           AssemblyConfig::min_box_extent, sanitised (finite
//                           and >= 0, else 0). lipac_vk::MergedBoxes holds all
//                           five per frame (LipacVk::merged_boxes); typically
//                           push constants, so that one shader serves both:
//                           LIPAC_ADAPTIVE_LEVELS == 0 at run time takes the
//                           leaf-only path below (one query) and no SBT offset
//                           is taken for a merged box.
// A merged box is resolved to its leaf hitboxes' boxes: the ray counts the
// nearest leaf box it enters (as hitbox LIPAC_SBT_HITBOX_BOX, index = the
// leaf), or meets no box there and goes on, so the counts are those of one
// box per hitbox. Each leaf box is the one Algorithm 1 would emit for it
// (lipacAxisMap, [t, t + s]), tested with the same slab arithmetic as a leaf
// box met in the TLAS, so a ray meets the same leaf at the same distance as
// in the TLAS without merging. The trace then takes two queries: the boxes alone (every
// box face a candidate, gl_RayFlagsNoOpaqueEXT), then the closest real hit
// with boxes masked out; the nearest box counts if it starts before that
// hit, its start being its entry (tMin for a ray starting inside it), as in
// lipac-sim's tracer.
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

#include "lipac_counting_common.glsl"

#ifndef LIPAC_CANDIDATE_TRIANGLE
#define LIPAC_CANDIDATE_TRIANGLE(rq) rayQueryConfirmIntersectionEXT(rq)
#endif
#ifndef LIPAC_CANDIDATE_AABB
#define LIPAC_CANDIDATE_AABB(rq)
#endif

#ifdef LIPAC_SBT_MERGED_BOX
// lipacTraceCounting with merged boxes (see the header).
LipacHit lipacTraceCountingMerged(accelerationStructureEXT tlas, uint rayFlags, uint cullMask,
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

    bool haveBox = false;
    float boxT = tMax;
    uint boxSbt = 0u;
    uint boxIndex = 0u;
    vec3 invD = 1.0 / direction;
    uint boxMask = cullMask & uint(LIPAC_COUNTING_MASK);

    // The boxes alone, every box face on the ray as a candidate (NoOpaque:
    // nothing is committed before the nearest box is known); a box found is
    // confirmed, which culls only faces beyond it (boxes have disjoint x/z
    // footprints, so none that could start before it).
    if (boxMask != 0u) {
        uint flags = (rayFlags & ~(gl_RayFlagsOpaqueEXT | gl_RayFlagsTerminateOnFirstHitEXT)) |
                     gl_RayFlagsNoOpaqueEXT;
        rayQueryEXT rq;
        rayQueryInitializeEXT(rq, tlas, flags, boxMask, origin, tMin, direction, tMax);
        while (rayQueryProceedEXT(rq)) {
            if (rayQueryGetIntersectionTypeEXT(rq, false) !=
                gl_RayQueryCandidateIntersectionTriangleEXT) {
                continue;
            }
            uint sbt = rayQueryGetIntersectionInstanceShaderBindingTableRecordOffsetEXT(rq, false);
            if (!lipacIsCountingBox(sbt)) {
                continue;
            }
            uint index = uint(rayQueryGetIntersectionInstanceCustomIndexEXT(rq, false));
            float t, tOut;
            if (sbt == uint(LIPAC_SBT_MERGED_BOX)) {
                uint leaf;
                if (!lipacMergedLeaf(index, origin, direction, tMin, tMax, t, leaf)) {
                    continue;
                }
                sbt = uint(LIPAC_SBT_HITBOX_BOX);
                index = leaf;
            } else if (!lipacBoxEntry(rayQueryGetIntersectionObjectToWorldEXT(rq, false), origin,
                                      invD, tMin, tMax, t, tOut)) {
                t = rayQueryGetIntersectionTEXT(rq, false);
            }
            if (!haveBox || t < boxT) {
                haveBox = true;
                boxT = t;
                boxSbt = sbt;
                boxIndex = index;
                rayQueryConfirmIntersectionEXT(rq);
            }
        }
    }

    // The closest real hit, boxes masked out.
    rayQueryEXT rq;
    rayQueryInitializeEXT(rq, tlas, rayFlags, lipacMaskOutCountingBoxes(cullMask), origin, tMin,
                          direction, tMax);
    while (rayQueryProceedEXT(rq)) {
        if (rayQueryGetIntersectionTypeEXT(rq, false) ==
            gl_RayQueryCandidateIntersectionTriangleEXT) {
            LIPAC_CANDIDATE_TRIANGLE(rq);
        } else {
            LIPAC_CANDIDATE_AABB(rq);
        }
    }
    if (rayQueryGetIntersectionTypeEXT(rq, true) != gl_RayQueryCommittedIntersectionNoneEXT) {
        res.hit = true;
        res.t = rayQueryGetIntersectionTEXT(rq, true);
        res.customIndex = uint(rayQueryGetIntersectionInstanceCustomIndexEXT(rq, true));
        res.instanceId = uint(rayQueryGetIntersectionInstanceIdEXT(rq, true));
        res.sbtOffset =
            rayQueryGetIntersectionInstanceShaderBindingTableRecordOffsetEXT(rq, true);
        res.geometryIndex = uint(rayQueryGetIntersectionGeometryIndexEXT(rq, true));
        res.primitiveIndex = uint(rayQueryGetIntersectionPrimitiveIndexEXT(rq, true));
        res.barycentrics = rayQueryGetIntersectionBarycentricsEXT(rq, true);
        res.frontFace = rayQueryGetIntersectionFrontFaceEXT(rq, true);
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
#endif

// Traces one ray through `tlas`, counting at most one counting box (the
// nearest, if it lies before the closest real hit), and returns the closest
// real hit.
LipacHit lipacTraceCounting(accelerationStructureEXT tlas, uint rayFlags, uint cullMask,
                            vec3 origin, float tMin, vec3 direction, float tMax) {
#ifdef LIPAC_SBT_MERGED_BOX
    if (uint(LIPAC_ADAPTIVE_LEVELS) != 0u) {
        return lipacTraceCountingMerged(tlas, rayFlags, cullMask, origin, tMin, direction,
                                        tMax);
    }
#endif
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
