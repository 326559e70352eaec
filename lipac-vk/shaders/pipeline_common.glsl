// pipeline_common.glsl -- what every stage of lipac's own ray-tracing-pipeline
// tracers (PipelineTestTracer: pipeline_trace.rgen; PipelineCameraTracer:
// pipeline_camera.rgen; both with pipeline_hit.rchit, pipeline_box.rahit,
// pipeline_box.rchit, pipeline_miss.rmiss) declares: the counting bindings
// (set 0: 0 the TLAS, 1 per-slot u32 hit counters, 2 the hitbox records,
// 3 the hitbox bounds; the ray generation shaders' own from 4), the push
// constants' first five words (lipac_vk::MergedBoxes), the counting
// configuration (specialization constants 0..2) and the payload, then
// lipac_counting_pipeline.glsl. Define the stage macro before including.
#extension GL_EXT_ray_tracing : require

layout(constant_id = 0) const uint SBT_OMITTED_BOX = 1;
layout(constant_id = 1) const uint SBT_HITBOX_BOX = 2;
layout(constant_id = 2) const uint COUNTING_MASK = 0x80;

#include "lipac_layout.glsl"
#include "lipac_payload.glsl"

layout(set = 0, binding = 0) uniform accelerationStructureEXT tlas;
layout(std430, set = 0, binding = 1) buffer InstanceHits { uint instanceHits[]; };
layout(std430, set = 0, binding = 2) buffer Hitboxes { LipacHitboxRecord hitboxes[]; };
layout(std430, set = 0, binding = 3) readonly buffer HitboxBounds { vec4 hitboxBounds[]; };

#ifdef LIPAC_RAYGEN_SHADER
layout(location = 0) rayPayloadEXT LipacPayload payload;
#else
layout(location = 0) rayPayloadInEXT LipacPayload payload;
#endif

#define LIPAC_PAYLOAD payload
#define LIPAC_SBT_OMITTED_BOX SBT_OMITTED_BOX
#define LIPAC_SBT_HITBOX_BOX SBT_HITBOX_BOX
#define LIPAC_COUNTING_MASK COUNTING_MASK
#define LIPAC_COUNT_INSTANCE(i) if ((i) < uint(instanceHits.length())) { atomicAdd(instanceHits[(i)], 1u); }
#define LIPAC_HITBOX_RECORDS hitboxes
#define LIPAC_COUNT_COMMITTED_HITS
#define LIPAC_SBT_MERGED_BOX pc.mergedSbt
#define LIPAC_HITBOX_BOUNDS hitboxBounds
#define LIPAC_GRID_NX pc.gridNx
#define LIPAC_GRID_NZ pc.gridNz
#define LIPAC_ADAPTIVE_LEVELS pc.adaptiveLevels
#define LIPAC_MIN_BOX_EXTENT pc.minBoxExtent
// Every instance selects its hit group by its own SBT offset alone.
#define LIPAC_SBT_RECORD_OFFSET 0
#define LIPAC_SBT_RECORD_STRIDE 0
