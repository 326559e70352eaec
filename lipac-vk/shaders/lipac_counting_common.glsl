// lipac_counting_common.glsl -- what lipac_counting.glsl (ray queries) and
// lipac_counting_pipeline.glsl (ray-tracing pipelines) share: the macro
// checks, lipacIsCountingBox, lipacCountBox, lipacMaskOutCountingBoxes, the
// merged-box resolution (lipacMergedLeaf, lipacBoxEntry) and LipacHit. Not
// included on its own: both tracing includes include it (ship it next to
// them), and their headers list the macros to define.
#ifndef LIPAC_COUNTING_COMMON_GLSL
#define LIPAC_COUNTING_COMMON_GLSL

#ifndef LIPAC_SBT_OMITTED_BOX
#error "lipac counting include: define LIPAC_SBT_OMITTED_BOX before including"
#endif
#ifndef LIPAC_SBT_HITBOX_BOX
#error "lipac counting include: define LIPAC_SBT_HITBOX_BOX before including"
#endif
#if !defined(LIPAC_COUNT_HITBOX) && defined(LIPAC_HITBOX_RECORDS)
#include "lipac_layout.glsl"
#define LIPAC_COUNT_HITBOX(i) \
    if ((i) < uint(LIPAC_HITBOX_RECORDS.length())) LIPAC_HITBOX_ADD_HITS(LIPAC_HITBOX_RECORDS[(i)].packed, 1u)
#endif
#ifndef LIPAC_COUNT_HITBOX
#error "lipac counting include: define LIPAC_COUNT_HITBOX(i) or LIPAC_HITBOX_RECORDS before including"
#endif
#ifndef LIPAC_COUNT_INSTANCE
#error "lipac counting include: define LIPAC_COUNT_INSTANCE(i) before including"
#endif
#ifndef LIPAC_COUNTING_MASK
#define LIPAC_COUNTING_MASK 0x80u
#endif


// Whether an instance SBT record offset marks a counting box.
bool lipacIsCountingBox(uint sbtOffset) {
#ifdef LIPAC_SBT_MERGED_BOX
    if (uint(LIPAC_ADAPTIVE_LEVELS) != 0u && sbtOffset == uint(LIPAC_SBT_MERGED_BOX)) {
        return true;
    }
#endif
    return sbtOffset == uint(LIPAC_SBT_OMITTED_BOX) || sbtOffset == uint(LIPAC_SBT_HITBOX_BOX);
}

#ifdef LIPAC_SBT_MERGED_BOX
#ifndef LIPAC_HITBOX_RECORDS
#error "lipac counting include: LIPAC_SBT_MERGED_BOX needs LIPAC_HITBOX_RECORDS"
#endif
#include "lipac_layout.glsl"
// Entry and exit of the ray into [lo, hi], clipped to [tMin, tMax].
bool lipacSlab(vec3 lo, vec3 hi, vec3 o, vec3 invD, float tMin, float tMax,
               out float tNear, out float tFar) {
    vec3 t0 = (lo - o) * invD;
    vec3 t1 = (hi - o) * invD;
    vec3 a = min(t0, t1);
    vec3 b = max(t0, t1);
    tNear = max(max(a.x, a.y), max(a.z, tMin));
    tFar = min(min(b.x, b.y), min(b.z, tMax));
    return tNear <= tFar;
}

// The nearest box of merged box `id`'s leaf hitboxes the ray enters in
// [tMin, tMax]: its entry distance and hitbox index.
bool lipacMergedLeaf(uint id, vec3 o, vec3 d, float tMin, float tMax,
                     out float tLeaf, out uint leaf) {
    tLeaf = tMax;
    leaf = 0u;
    uint nx = uint(LIPAC_GRID_NX);
    uint nz = uint(LIPAC_GRID_NZ);
    uint level = 0u;
    uint base = 0u;
    uint w = 1u;
    for (uint l = 1u; l <= uint(LIPAC_ADAPTIVE_LEVELS); ++l) {
        uint wl = (nx + (1u << l) - 1u) >> l;
        uint hl = (nz + (1u << l) - 1u) >> l;
        if (id < base + wl * hl) {
            level = l;
            w = wl;
            break;
        }
        base += wl * hl;
    }
    if (level == 0u) {
        return false;
    }
    uint k = id - base;
    uint x0 = (k % w) << level, z0 = (k / w) << level;
    uint x1 = min(x0 + (1u << level), nx), z1 = min(z0 + (1u << level), nz);
    vec3 invD = 1.0 / d;
    float ext = float(LIPAC_MIN_BOX_EXTENT);
    bool found = false;
    for (uint z = z0; z < z1; ++z) {
        for (uint x = x0; x < x1; ++x) {
            uint i = x + z * nx;
            LipacHitboxRecord h = LIPAC_HITBOX_RECORDS[i];
            float minY = uintBitsToFloat(h.minY);
            float maxY = uintBitsToFloat(h.maxY);
            if ((h.packed & 1u) != 0u || minY > maxY) {
                continue;
            }
            // The leaf's box as Algorithm 1 emits it (lipacAxisMap per axis,
            // [t, t + s]): bit for bit what lipacBoxEntry tests for the
            // leaf's own box in a TLAS without merging.
            vec4 b = LIPAC_HITBOX_BOUNDS[i];
            float tx, sx, ty, sy, tz, sz;
            if (!lipacAxisMap(b.x, b.z, ext, tx, sx) || !lipacAxisMap(minY, maxY, ext, ty, sy) ||
                !lipacAxisMap(b.y, b.w, ext, tz, sz)) {
                continue;
            }
            precise vec3 lo = vec3(tx, ty, tz);
            precise vec3 hi = lo + vec3(sx, sy, sz);
            float tn, tf;
            if (lipacSlab(lo, hi, o, invD, tMin, tMax, tn, tf) &&
                (!found || tn < tLeaf)) {
                found = true;
                tLeaf = tn;
                leaf = i;
            }
        }
    }
    return found;
}
#endif

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

#ifdef LIPAC_SBT_MERGED_BOX
// Start of the box instance `m` (object to world of the unit cube) along the
// ray within [tMin, tMax]: its entry, or tMin from inside; false on a miss.
bool lipacBoxEntry(mat4x3 m, vec3 o, vec3 invD, float tMin, float tMax, out float tIn,
                   out float tOut) {
    precise vec3 lo = m[3];
    precise vec3 hi = lo + vec3(m[0].x, m[1].y, m[2].z);
    return lipacSlab(lo, hi, o, invD, tMin, tMax, tIn, tOut);
}
#endif


#endif // LIPAC_COUNTING_COMMON_GLSL
