// lipac_assembly.glsl -- interface and helpers shared by lipac's TLAS
// assembly passes (Algorithm 1): hitbox_reset.comp, assemble_instances.comp,
// assemble_hitboxes.comp, assemble_merged.comp. One descriptor set layout
// and one push-constant block for all of them (lipac_vk::AssemblyPipeline).
#ifndef LIPAC_ASSEMBLY_GLSL
#define LIPAC_ASSEMBLY_GLSL

#include "lipac_layout.glsl"

layout(local_size_x = 64) in;

layout(std430, set = 0, binding = 0) readonly buffer InstancesHot { LipacInstanceHot instanceHot[]; };
layout(std430, set = 0, binding = 1) buffer Hitboxes { LipacHitboxRecord hitboxes[]; };
// Per hitbox: its cell's x/z bounds (lo.x, lo.z, hi.x, hi.z); NaN = no bounds.
layout(std430, set = 0, binding = 2) readonly buffer HitboxBounds { vec4 hitboxBounds[]; };
layout(std430, set = 0, binding = 3) writeonly buffer TlasOut { LipacTlasInstance tlasOut[]; };
layout(std430, set = 0, binding = 4) buffer TlasCounter { uint tlasCounter; };
// Read by assemble_instances.comp only: the bounds of omitted slots, the
// TLAS records of active ones.
layout(std430, set = 0, binding = 5) readonly buffer InstancesBounds { LipacInstanceBounds instanceBounds[]; };
layout(std430, set = 0, binding = 6) readonly buffer InstancesTlas { LipacTlasInstance instanceTlas[]; };

layout(push_constant) uniform AssemblyPush {
    uvec2 unitCube;          // device address of the unit-cube BLAS
    uint countingMask;       // TLAS mask of counting boxes (8 bits)
    uint omittedSbt;         // SBT offset of omitted-instance boxes
    uint hitboxSbt;          // SBT offset of hitbox boxes
    float minExtent;         // min_box_extent, already sanitised (finite, >= 0)
    uint instanceCount;      // slots to process
    uint hitboxCount;        // hitboxes to process
    uint tlasCapacity;       // records tlasOut can hold
    // Adaptive hitboxes (lipac_core::hitbox_tree; 0 levels = off):
    uint adaptiveLevels;     // merge levels
    uint gridNx;             // the dense grid's cells along x
    uint gridNz;             // ... and z
    uint mergedSbt;          // SBT offset of merged boxes
} pc;

// VK_GEOMETRY_INSTANCE_FORCE_OPAQUE | TRIANGLE_FACING_CULL_DISABLE
// (lipac_core::assembly::COUNTING_BOX_FLAGS).
#define LIPAC_COUNTING_BOX_FLAGS 5u

// Threads stride over the items so that any count fits one dispatch.
#define LIPAC_FOR_EACH(i, count) \
    for (uint i = gl_GlobalInvocationID.x; i < (count); i += gl_NumWorkGroups.x * gl_WorkGroupSize.x)

// Appends a unit-cube counting box over [mn, mx] (unit_cube_transform);
// nothing when a corner is not finite.
void lipacAppendCountingBox(vec3 mn, vec3 mx, uint customIndex, uint sbt) {
    float tx, sx, ty, sy, tz, sz;
    if (!lipacAxisMap(mn.x, mx.x, pc.minExtent, tx, sx) ||
        !lipacAxisMap(mn.y, mx.y, pc.minExtent, ty, sy) ||
        !lipacAxisMap(mn.z, mx.z, pc.minExtent, tz, sz)) {
        return;
    }
    uint at = atomicAdd(tlasCounter, 1u);
    if (at >= pc.tlasCapacity) {
        return;
    }
    LipacTlasInstance r;
    r.transform = float[12](sx, 0.0, 0.0, tx, 0.0, sy, 0.0, ty, 0.0, 0.0, sz, tz);
    r.customIndexAndMask = (customIndex & 0xFFFFFFu) | ((pc.countingMask & 0xFFu) << 24);
    r.sbtOffsetAndFlags = (sbt & 0xFFFFFFu) | (LIPAC_COUNTING_BOX_FLAGS << 24);
    r.reference = pc.unitCube;
    tlasOut[at] = r;
}

#endif // LIPAC_ASSEMBLY_GLSL
