// lipac_layout.glsl -- lipac's GPU records, declared exactly as
// lipac-core/src/layout.rs (std430; byte offsets in the comments).
//
// 64-bit device addresses are uvec2 (x = low word, y = high word), so no
// shaderInt64 is needed. Include from any shader that reads or writes lipac's
// buffers; the helpers below are what lipac's own passes use.
#ifndef LIPAC_LAYOUT_GLSL
#define LIPAC_LAYOUT_GLSL

// VkAccelerationStructureInstanceKHR (64 B).
struct LipacTlasInstance {
    float transform[12];        //  0: row-major 3x4
    uint customIndexAndMask;    // 48: custom index bits 0..24, mask bits 24..32
    uint sbtOffsetAndFlags;     // 52: SBT offset bits 0..24, instance flags bits 24..32
    uvec2 reference;            // 56: BLAS address; 0 = inactive record
};

// The instance buffer is three arrays indexed by slot (docs/HOT_COLD.md):
// LipacInstanceHot (every slot, every frame: Algorithms 1 and 2), the slot's
// own TLAS record as a LipacTlasInstance (lipac_core::layout::InstanceTlas:
// Algorithm 1 copies it for an active slot) and LipacInstanceBounds
// (Algorithm 1, omitted slots). The counting boxes' heights are the CPU's
// hitbox extents, uploaded into the hitbox records.

// lipac_core::layout::InstanceHot (8 B).
struct LipacInstanceHot {
    uint hitbox;                // 0
    uint packed;                // 4: see LIPAC_INSTANCE_*
};

// lipac_core::layout::InstanceBounds (28 B; std430 stride 28).
struct LipacInstanceBounds {
    float aabbMin[3];           //  0
    float aabbMax[3];           // 12
    uint lod;                   // 24
};

// lipac_core::layout::InstanceRecord (96 B): one slot joined, the staging
// format of upload_records.comp.
struct LipacInstanceRecord {
    float transform[12];        //  0
    float aabbMin[3];           // 48
    uint hitbox;                // 60
    float aabbMax[3];           // 64
    uint packed;                // 76: see LIPAC_INSTANCE_*
    uvec2 blas;                 // 80: 0 = no BLAS yet
    uint sbtOffset;             // 88
    uint lod;                   // 92
};

// lipac_core::layout::HitboxRecord (20 B). minY/maxY hold f32 bits; they
// and cost are the hitbox's extent, the CPU's (lipac_core::hitbox_extents),
// written only by upload_records.comp.
struct LipacHitboxRecord {
    uint minY;                  // 0
    uint maxY;                  // 4
    uint packed;                // 8: see LIPAC_HITBOX_*
    uint rate;                  // 12: decayed hit rate, 16.16 (lipacDecayRate)
    uint cost;                  // 16: inactive instances, shared (low 16) / unique (high 16)
};

// instance_bits
#define LIPAC_INSTANCE_STATE_MASK 3u
#define LIPAC_STATE_INACTIVE 0u
#define LIPAC_STATE_OMITTED 1u
#define LIPAC_STATE_ACTIVE 2u
#define LIPAC_INSTANCE_ALIVE 4u
#define LIPAC_INSTANCE_UNIQUE_BLAS 8u
#define LIPAC_INSTANCE_PINNED 64u
#define LIPAC_INSTANCE_HAS_BLAS 128u
#define LIPAC_INSTANCE_MASK_SHIFT 8u
#define LIPAC_INSTANCE_VK_FLAGS_SHIFT 16u

// hitbox_bits
#define LIPAC_HITBOX_ACTIVE 1u
#define LIPAC_HITBOX_STREAK_SHIFT 1u
#define LIPAC_HITBOX_STREAK_MAX 0x7Fu
#define LIPAC_HITBOX_HITS_SHIFT 8u
#define LIPAC_HITBOX_HITS_MAX 0xFFFFFFu
#define LIPAC_HITBOX_COST_SHARED 1u
#define LIPAC_HITBOX_COST_UNIQUE 0x10000u

// lipac_core::thresholds::decay_rate: one frame of the decayed hit rate
// (16.16), rate - (rate >> k) + ((min(hits, 65535) << 16) >> k), k in 1..16.
// Never overflows (see the Rust docs).
uint lipacDecayRate(uint rate, uint hits, uint shift) {
    uint k = clamp(shift, 1u, 16u);
    uint h = min(hits, 0xFFFFu);
    return rate - (rate >> k) + ((h << 16) >> k);
}

// lipac_core::thresholds::rise_decay_rate: lipacDecayRate with riseShift
// (clamped to 1..k) when this frame's hits in 16.16 exceed the rate, else
// with shift; riseShift == shift is lipacDecayRate.
uint lipacRiseDecayRate(uint rate, uint hits, uint shift, uint riseShift) {
    uint k = clamp(shift, 1u, 16u);
    uint kUp = clamp(riseShift, 1u, k);
    uint target = min(hits, 0xFFFFu) << 16;
    return lipacDecayRate(rate, hits, target > rate ? kUp : k);
}

// Command words (lipac_core::command).
#define LIPAC_COMMAND_ADD 0u
#define LIPAC_COMMAND_REMOVE 1u

// State of an instance's packed word (the unused value 3 reads as inactive).
uint lipacInstanceState(uint packed) {
    uint s = packed & LIPAC_INSTANCE_STATE_MASK;
    return s == 3u ? LIPAC_STATE_INACTIVE : s;
}

// Adds `n` hits to the 24-bit hit field of a HitboxRecord.packed word in a
// buffer, saturating at LIPAC_HITBOX_HITS_MAX and leaving the low 8 bits
// (active bit, streak) alone. `word` must be an lvalue in a buffer (or shared
// memory), e.g. LIPAC_HITBOX_ADD_HITS(hitboxes[i].packed, 1u). An
// atomicCompSwap loop: a plain atomicAdd of n << 8 would wrap instead.
#define LIPAC_HITBOX_ADD_HITS(word, n)                                                  \
    {                                                                                 \
        uint lipacSeen_ = (word);                                                      \
        for (;;) {                                                                    \
            uint lipacHits_ = lipacSeen_ >> LIPAC_HITBOX_HITS_SHIFT;                   \
            uint lipacSum_ = lipacHits_ + min(uint(n), LIPAC_HITBOX_HITS_MAX);         \
            lipacSum_ = min(lipacSum_, LIPAC_HITBOX_HITS_MAX);                         \
            if (lipacSum_ == lipacHits_) {                                            \
                break;                                                                \
            }                                                                         \
            uint lipacNew_ = (lipacSeen_ & 0xFFu) | (lipacSum_ << LIPAC_HITBOX_HITS_SHIFT); \
            uint lipacWas_ = atomicCompSwap((word), lipacSeen_, lipacNew_);            \
            if (lipacWas_ == lipacSeen_) {                                            \
                break;                                                                \
            }                                                                         \
            lipacSeen_ = lipacWas_;                                                   \
        }                                                                             \
    }

bool lipacIsFiniteBits(uint bits) {
    return (bits & 0x7F800000u) != 0x7F800000u;
}

// f32::next_up for finite x (lipac_core::assembly::next_up), on bits so that
// denormal flushing cannot change the comparison.
float lipacNextUp(float x) {
    uint b = floatBitsToUint(x);
    if ((b & 0x7FFFFFFFu) == 0u) {
        return uintBitsToFloat(1u);
    }
    return uintBitsToFloat((b & 0x80000000u) == 0u ? b + 1u : b - 1u);
}

// lipac_core::assembly::axis_map, the same f32 operations in the same order
// (`precise`: no contraction into fma, no reassociation): a counting box's
// unit-cube map along one axis, translation t and scale s, the box being
// [t, t + s] as the hardware evaluates it. Algorithm 1 emits boxes with it;
// lipac_counting.glsl resolves merged boxes to their leaves' boxes with it.
bool lipacAxisMap(float loIn, float hiIn, float minExtent, out float t, out float s) {
    t = 0.0;
    s = 0.0;
    precise float lo = loIn;
    precise float hi = hiIn;
    if (!lipacIsFiniteBits(floatBitsToUint(lo)) || !lipacIsFiniteBits(floatBitsToUint(hi))) {
        return false;
    }
    if (hi < lo) {
        precise float tmp = lo;
        lo = hi;
        hi = tmp;
    }
    precise float d = hi - lo;
    if (d < minExtent) {
        precise float pad = (minExtent - d) * 0.5;
        lo = lo - pad;
        hi = hi + pad;
    }
    float up = lipacNextUp(lo);
    if (up > hi) {
        hi = up;
    }
    if (!lipacIsFiniteBits(floatBitsToUint(lo)) || !lipacIsFiniteBits(floatBitsToUint(hi))) {
        return false;
    }
    precise float ss = hi - lo;
    for (int k = 0; k < 32; ++k) {
        if (!lipacIsFiniteBits(floatBitsToUint(ss))) {
            return false;
        }
        precise float far = lo + ss;
        if (far >= hi) {
            t = lo;
            s = ss;
            return true;
        }
        ss = lipacNextUp(ss);
    }
    return false;
}

#endif // LIPAC_LAYOUT_GLSL
