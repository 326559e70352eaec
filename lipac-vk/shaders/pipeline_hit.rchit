#version 460
// pipeline_hit.rchit -- closest-hit of real geometry for lipac's pipeline
// tracers: records the hit in the payload, counts the box recorded before it
// and the hit (lipacClosestHit). The shader record holds the record's SBT
// offset, reported as the hit's.
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

layout(shaderRecordEXT, std430) buffer ShaderRecord { uint recordSbtOffset; };
hitAttributeEXT vec2 attribs;

void main() {
    lipacClosestHit(attribs, recordSbtOffset);
}
