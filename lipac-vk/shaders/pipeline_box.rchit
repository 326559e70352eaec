#version 460
// pipeline_box.rchit -- closest-hit of a counting box's hit group (an opaque
// box was the closest hit): counts the nearest box and has the ray continued
// past it (lipacBoxClosestHit). BOX_SBT: the SBT offset of the box kind this
// hit group stands for.
#extension GL_GOOGLE_include_directive : require
#define LIPAC_CLOSEST_HIT_SHADER

layout(push_constant) uniform Push {
    uint gridNx;
    uint gridNz;
    uint adaptiveLevels;
    uint mergedSbt;
    float minBoxExtent;
} pc;

#include "pipeline_common.glsl"
#include "lipac_counting_pipeline.glsl"

layout(constant_id = 3) const uint BOX_SBT = 1;
hitAttributeEXT vec2 attribs;

void main() {
    lipacBoxClosestHit(BOX_SBT, attribs);
}
