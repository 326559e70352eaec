#version 460
// upload_records.comp -- the GPU version of lipac_core::culling::apply_uploads:
// scatters CPU-written instance records into the GPU instance buffer WITHOUT
// overwriting the state bits of the GPU copy (Algorithm 2 owns them), then
// applies the CPU's explicit state overrides and hitbox active overrides.
// lipac_vk::RecordUploader records it twice:
//   pass 0: one thread per staged record (copy all 24 words, keep the
//           destination's LIPAC_INSTANCE_STATE_MASK bits of `packed`), then one
//           per hitbox override (active bit set, streak zeroed, hits and
//           heights kept);
//   pass 1 (after a barrier): one thread per state override.
// The host removes duplicate slots/indices (the last override wins, as on the
// CPU), so no two threads of a pass write the same word.
#extension GL_GOOGLE_include_directive : require
#include "lipac_layout.glsl"

layout(local_size_x = 64) in;

// InstanceRecord as 24 raw words (bit-exact copies, no float loads).
#define RECORD_WORDS 24u
#define PACKED_WORD 19u  // offsetof(InstanceRecord, packed) / 4

layout(std430, set = 0, binding = 0) buffer Instances { uint instanceWords[]; };
layout(std430, set = 0, binding = 1) buffer Hitboxes { LipacHitboxRecord hitboxes[]; };
layout(std430, set = 0, binding = 2) readonly buffer StagedRecords { uint stagedWords[]; };
layout(std430, set = 0, binding = 3) readonly buffer StagedSlots { uint stagedSlots[]; };
layout(std430, set = 0, binding = 4) readonly buffer StateOverrides { uvec2 stateOverrides[]; };
layout(std430, set = 0, binding = 5) readonly buffer HitboxOverrides { uvec2 hitboxOverrides[]; };

layout(push_constant) uniform UploadPush {
    uint pass;
    uint recordCount;
    uint stateCount;
    uint hitboxCount;
    uint slotCapacity;
    uint hitboxCapacity;
} pc;

void main() {
    uint stride = gl_NumWorkGroups.x * gl_WorkGroupSize.x;
    if (pc.pass == 0u) {
        for (uint i = gl_GlobalInvocationID.x; i < pc.recordCount + pc.hitboxCount; i += stride) {
            if (i < pc.recordCount) {
                uint slot = stagedSlots[i];
                if (slot >= pc.slotCapacity) {
                    continue;
                }
                uint dst = slot * RECORD_WORDS;
                uint src = i * RECORD_WORDS;
                for (uint w = 0u; w < RECORD_WORDS; ++w) {
                    if (w == PACKED_WORD) {
                        uint state = instanceWords[dst + w] & LIPAC_INSTANCE_STATE_MASK;
                        instanceWords[dst + w] =
                            (stagedWords[src + w] & ~LIPAC_INSTANCE_STATE_MASK) | state;
                    } else {
                        instanceWords[dst + w] = stagedWords[src + w];
                    }
                }
            } else {
                uvec2 o = hitboxOverrides[i - pc.recordCount];
                if (o.x >= pc.hitboxCapacity) {
                    continue;
                }
                uint keep = ~((LIPAC_HITBOX_STREAK_MAX << LIPAC_HITBOX_STREAK_SHIFT) | LIPAC_HITBOX_ACTIVE);
                hitboxes[o.x].packed = (hitboxes[o.x].packed & keep) | (o.y != 0u ? LIPAC_HITBOX_ACTIVE : 0u);
            }
        }
    } else {
        for (uint i = gl_GlobalInvocationID.x; i < pc.stateCount; i += stride) {
            uvec2 o = stateOverrides[i];
            if (o.x >= pc.slotCapacity) {
                continue;
            }
            uint at = o.x * RECORD_WORDS + PACKED_WORD;
            instanceWords[at] = (instanceWords[at] & ~LIPAC_INSTANCE_STATE_MASK) | (o.y & LIPAC_INSTANCE_STATE_MASK);
        }
    }
}
