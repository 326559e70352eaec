#version 460
// pipeline_miss.rmiss -- miss shader of lipac's pipeline tracers: counts the
// box the ray recorded (lipacMiss).
#extension GL_GOOGLE_include_directive : require
#define LIPAC_MISS_SHADER

layout(push_constant) uniform Push {
    uint gridNx;
    uint gridNz;
    uint adaptiveLevels;
    uint mergedSbt;
    float minBoxExtent;
} pc;

#include "pipeline_common.glsl"
#include "lipac_counting_pipeline.glsl"

void main() {
    lipacMiss();
}
