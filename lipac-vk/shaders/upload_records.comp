#version 460
// upload_records.comp -- the GPU version of lipac_core::culling::apply_uploads:
// scatters CPU-written instance records (staged joined, 96 B each) into the
// GPU's three instance arrays (hot, heights, cold) WITHOUT overwriting the
// state bits of the GPU's hot record (Algorithm 2 owns them), then applies
// the CPU's explicit state overrides and hitbox active overrides, and raises
// decayed rates to the CPU's rate floors (a held warm start).
// lipac_vk::RecordUploader records it twice:
//   pass 0: one thread per staged record (hot: hitbox, packed with the
//           destination's LIPAC_INSTANCE_STATE_MASK bits kept; heights:
//           the AABB's y words; cold: the other 22 words), then one per
//           hitbox override (active bit set, streak zeroed, hits and heights
//           kept), one per hitbox rate floor (rate = max(rate, floor)) and
//           one per instance rate floor (the slot's rate likewise);
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
#define HEIGHTS_WORDS 2u  // InstanceHeights: minY 0, maxY 1
#define COLD_WORDS 22u    // InstanceCold: transform 0..12, blas 12..14, sbtOffset 14,
                          // lod 15, aabbMin 16..19, aabbMax 19..22

layout(std430, set = 0, binding = 0) buffer InstancesHot { uint hotWords[]; };
layout(std430, set = 0, binding = 1) buffer Hitboxes { LipacHitboxRecord hitboxes[]; };
layout(std430, set = 0, binding = 2) readonly buffer StagedRecords { uint stagedWords[]; };
layout(std430, set = 0, binding = 3) readonly buffer StagedSlots { uint stagedSlots[]; };
layout(std430, set = 0, binding = 4) readonly buffer StateOverrides { uvec2 stateOverrides[]; };
layout(std430, set = 0, binding = 5) readonly buffer HitboxOverrides { uvec2 hitboxOverrides[]; };
layout(std430, set = 0, binding = 6) writeonly buffer InstancesHeights { uint heightsWords[]; };
layout(std430, set = 0, binding = 7) writeonly buffer InstancesCold { uint coldWords[]; };
layout(std430, set = 0, binding = 8) buffer InstanceRates { uint instanceRates[]; };
layout(std430, set = 0, binding = 9) readonly buffer HitboxRateFloors { uvec2 hitboxFloors[]; };
layout(std430, set = 0, binding = 10) readonly buffer InstanceRateFloors { uvec2 instanceFloors[]; };

layout(push_constant) uniform UploadPush {
    uint pass;
    uint recordCount;
    uint stateCount;
    uint hitboxCount;
    uint slotCapacity;
    uint hitboxCapacity;
    uint hitboxFloorCount;
    uint instanceFloorCount;
} pc;

void main() {
    uint stride = gl_NumWorkGroups.x * gl_WorkGroupSize.x;
    if (pc.pass == 0u) {
        uint hitboxesEnd = pc.recordCount + pc.hitboxCount;
        uint hitboxFloorsEnd = hitboxesEnd + pc.hitboxFloorCount;
        uint end = hitboxFloorsEnd + pc.instanceFloorCount;
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
                uint heights = slot * HEIGHTS_WORDS;
                heightsWords[heights] = stagedWords[src + 13u];
                heightsWords[heights + 1u] = stagedWords[src + 17u];
                uint cold = slot * COLD_WORDS;
                for (uint w = 0u; w < 12u; ++w) {
                    coldWords[cold + w] = stagedWords[src + w];  // transform
                }
                coldWords[cold + 12u] = stagedWords[src + 20u];  // blas (low)
                coldWords[cold + 13u] = stagedWords[src + 21u];  // blas (high)
                coldWords[cold + 14u] = stagedWords[src + 22u];  // sbtOffset
                coldWords[cold + 15u] = stagedWords[src + 23u];  // lod
                for (uint w = 0u; w < 3u; ++w) {
                    coldWords[cold + 16u + w] = stagedWords[src + 12u + w];  // aabbMin
                    coldWords[cold + 19u + w] = stagedWords[src + 16u + w];  // aabbMax
                }
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
            } else {
                uvec2 f = instanceFloors[i - hitboxFloorsEnd];
                if (f.x >= pc.slotCapacity) {
                    continue;
                }
                instanceRates[f.x] = max(instanceRates[f.x], f.y);
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
