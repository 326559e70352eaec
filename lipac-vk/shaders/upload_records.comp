#version 460
// upload_records.comp -- the GPU version of lipac_core::culling::apply_uploads:
// scatters CPU-written instance records (staged joined, 96 B each) into the
// GPU's three instance arrays (hot, the slot's TLAS record, bounds)
// WITHOUT overwriting the state bits of the GPU's hot record (Algorithm 2
// owns them), then applies the CPU's explicit state overrides and hitbox
// active overrides, raises decayed rates to the CPU's rate floors (a held
// warm start) and writes the hitbox extents that changed (minY, maxY, cost:
// the CPU's, lipac_core::hitbox_extents).
// lipac_vk::RecordUploader records it twice:
//   pass 0: one thread per staged record (hot: hitbox, packed with the
//           destination's LIPAC_INSTANCE_STATE_MASK bits kept; TLAS
//           record: transform, slot | mask << 24,
//           SBT offset | flags << 24, BLAS address, as
//           lipac_core::layout::InstanceRecord::tlas builds it; bounds: the
//           AABB and the LOD), then one per hitbox override (active bit set,
//           streak zeroed, hits and extent kept), one per hitbox rate floor
//           (rate = max(rate, floor)), one per instance rate floor (the
//           slot's rate likewise) and one per hitbox extent (minY, maxY and
//           cost replaced);
//   pass 1 (after a barrier): one thread per state override.
// The host removes duplicate slots/indices (the last override wins, as on the
// CPU; the largest floor), so no two threads of a pass write the same word.
#extension GL_GOOGLE_include_directive : require
#include "lipac_layout.glsl"

layout(local_size_x = 64) in;

// The arrays as raw words (bit-exact copies, no float loads).
#define RECORD_WORDS 24u  // InstanceRecord: transform 0..12, aabbMin 12..15, hitbox 15,
                          // aabbMax 16..19, packed 19, blas 20..22, sbtOffset 22, lod 23
#define HOT_WORDS 2u      // InstanceHot: hitbox 0, packed 1
#define TLAS_WORDS 16u    // InstanceTlas: transform 0..12, customIndexAndMask 12,
                          // sbtOffsetAndFlags 13, reference 14..16
#define BOUNDS_WORDS 7u   // InstanceBounds: aabbMin 0..3, aabbMax 3..6, lod 6

layout(std430, set = 0, binding = 0) buffer InstancesHot { uint hotWords[]; };
layout(std430, set = 0, binding = 1) buffer Hitboxes { LipacHitboxRecord hitboxes[]; };
layout(std430, set = 0, binding = 2) readonly buffer StagedRecords { uint stagedWords[]; };
layout(std430, set = 0, binding = 3) readonly buffer StagedSlots { uint stagedSlots[]; };
layout(std430, set = 0, binding = 4) readonly buffer StateOverrides { uvec2 stateOverrides[]; };
layout(std430, set = 0, binding = 5) readonly buffer HitboxOverrides { uvec2 hitboxOverrides[]; };
layout(std430, set = 0, binding = 6) writeonly buffer InstancesTlas { uint tlasWords[]; };
layout(std430, set = 0, binding = 7) buffer InstanceRates { uint instanceRates[]; };
layout(std430, set = 0, binding = 8) readonly buffer HitboxRateFloors { uvec2 hitboxFloors[]; };
layout(std430, set = 0, binding = 9) readonly buffer InstanceRateFloors { uvec2 instanceFloors[]; };
layout(std430, set = 0, binding = 10) writeonly buffer InstancesBounds { uint boundsWords[]; };
// x = hitbox index, y = minY bits, z = maxY bits, w = cost.
layout(std430, set = 0, binding = 11) readonly buffer HitboxExtents { uvec4 extents[]; };

layout(push_constant) uniform UploadPush {
    uint pass;
    uint recordCount;
    uint stateCount;
    uint hitboxCount;
    uint slotCapacity;
    uint hitboxCapacity;
    uint hitboxFloorCount;
    uint instanceFloorCount;
    uint extentCount;
} pc;

void main() {
    uint stride = gl_NumWorkGroups.x * gl_WorkGroupSize.x;
    if (pc.pass == 0u) {
        uint hitboxesEnd = pc.recordCount + pc.hitboxCount;
        uint hitboxFloorsEnd = hitboxesEnd + pc.hitboxFloorCount;
        uint instanceFloorsEnd = hitboxFloorsEnd + pc.instanceFloorCount;
        uint end = instanceFloorsEnd + pc.extentCount;
        for (uint i = gl_GlobalInvocationID.x; i < end; i += stride) {
            if (i < pc.recordCount) {
                uint slot = stagedSlots[i];
                if (slot >= pc.slotCapacity) {
                    continue;
                }
                uint src = i * RECORD_WORDS;
                uint hot = slot * HOT_WORDS;
                uint state = hotWords[hot + 1u] & LIPAC_INSTANCE_STATE_MASK;
                hotWords[hot] = stagedWords[src + 15u];
                hotWords[hot + 1u] = (stagedWords[src + 19u] & ~LIPAC_INSTANCE_STATE_MASK) | state;
                uint packed = stagedWords[src + 19u];
                uint tlas = slot * TLAS_WORDS;
                for (uint w = 0u; w < 12u; ++w) {
                    tlasWords[tlas + w] = stagedWords[src + w];  // transform
                }
                tlasWords[tlas + 12u] = (slot & 0xFFFFFFu) |
                                        (((packed >> LIPAC_INSTANCE_MASK_SHIFT) & 0xFFu) << 24);
                tlasWords[tlas + 13u] = (stagedWords[src + 22u] & 0xFFFFFFu) |
                                        (((packed >> LIPAC_INSTANCE_VK_FLAGS_SHIFT) & 0xFFu) << 24);
                tlasWords[tlas + 14u] = stagedWords[src + 20u];  // blas (low)
                tlasWords[tlas + 15u] = stagedWords[src + 21u];  // blas (high)
                uint bounds = slot * BOUNDS_WORDS;
                for (uint w = 0u; w < 3u; ++w) {
                    boundsWords[bounds + w] = stagedWords[src + 12u + w];       // aabbMin
                    boundsWords[bounds + 3u + w] = stagedWords[src + 16u + w];  // aabbMax
                }
                boundsWords[bounds + 6u] = stagedWords[src + 23u];  // lod
            } else if (i < hitboxesEnd) {
                uvec2 o = hitboxOverrides[i - pc.recordCount];
                if (o.x >= pc.hitboxCapacity) {
                    continue;
                }
                uint keep = ~((LIPAC_HITBOX_STREAK_MAX << LIPAC_HITBOX_STREAK_SHIFT) | LIPAC_HITBOX_ACTIVE);
                hitboxes[o.x].packed = (hitboxes[o.x].packed & keep) | (o.y != 0u ? LIPAC_HITBOX_ACTIVE : 0u);
            } else if (i < hitboxFloorsEnd) {
                uvec2 f = hitboxFloors[i - hitboxesEnd];
                if (f.x >= pc.hitboxCapacity) {
                    continue;
                }
                hitboxes[f.x].rate = max(hitboxes[f.x].rate, f.y);
            } else if (i < instanceFloorsEnd) {
                uvec2 f = instanceFloors[i - hitboxFloorsEnd];
                if (f.x >= pc.slotCapacity) {
                    continue;
                }
                instanceRates[f.x] = max(instanceRates[f.x], f.y);
            } else {
                uvec4 e = extents[i - instanceFloorsEnd];
                if (e.x >= pc.hitboxCapacity) {
                    continue;
                }
                hitboxes[e.x].minY = e.y;
                hitboxes[e.x].maxY = e.z;
                hitboxes[e.x].cost = e.w;
            }
        }
    } else {
        for (uint i = gl_GlobalInvocationID.x; i < pc.stateCount; i += stride) {
            uvec2 o = stateOverrides[i];
            if (o.x >= pc.slotCapacity) {
                continue;
            }
            uint at = o.x * HOT_WORDS + 1u;
            hotWords[at] = (hotWords[at] & ~LIPAC_INSTANCE_STATE_MASK) | (o.y & LIPAC_INSTANCE_STATE_MASK);
        }
    }
}
