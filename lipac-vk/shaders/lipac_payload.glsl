// lipac_payload.glsl -- LipacPayload, the part of a ray-tracing-pipeline
// payload lipac_counting_pipeline.glsl uses: include this, declare the
// payload (a LipacPayload, or a struct with one as a member), define
// LIPAC_PAYLOAD as its lvalue, then include lipac_counting_pipeline.glsl.
#ifndef LIPAC_PAYLOAD_GLSL
#define LIPAC_PAYLOAD_GLSL

// LipacPayload::state bits.
#define LIPAC_PAYLOAD_HAVE_BOX 1u       // boxT/boxSbt/boxIndex hold the nearest box
#define LIPAC_PAYLOAD_COUNTED_BOX 2u    // that box was counted
#define LIPAC_PAYLOAD_BOX_COMMITTED 4u  // the closest hit was an opaque box: continue from t
#define LIPAC_PAYLOAD_HIT 8u            // a real hit at t
#define LIPAC_PAYLOAD_BOXES_ONLY 16u    // merged boxes: the boxes-alone trace
#define LIPAC_PAYLOAD_CONTINUED 32u     // the trace continued past an opaque box

// What the shaders of one ray share (52 bytes).
struct LipacPayload {
    uint state;
    float boxT;          // nearest box's distance
    uint boxSbt;         // its SBT offset (kind)
    uint boxIndex;       // its custom index (slot or hitbox)
    float t;             // the real hit's distance, or the opaque box's
    float tMax;          // the ray's tMax
    uint customIndex;
    uint instanceId;
    uint sbtOffset;
    uint geometryIndex;
    uint primitiveIndex;
    uint frontFace;
    vec2 barycentrics;
};

#endif // LIPAC_PAYLOAD_GLSL
