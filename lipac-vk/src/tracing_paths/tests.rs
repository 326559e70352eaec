use super::*;

#[test]
fn require_names_the_missing_extension_and_what_is_offered() {
    let pipeline_only = TracingPaths {
        ray_query: false,
        ray_tracing_pipeline: true,
    };
    let e = pipeline_only
        .require(TracingPath::RayQuery, "CameraTracer")
        .unwrap_err();
    assert_eq!(
        e.to_string(),
        "CameraTracer needs VK_KHR_ray_query; this device offers ray-tracing pipelines only"
    );
    assert!(pipeline_only
        .require(TracingPath::RayTracingPipeline, "x")
        .is_ok());
    assert_eq!(
        pipeline_only.preferred(),
        Some(TracingPath::RayTracingPipeline)
    );
    assert_eq!(TracingPaths::ALL.preferred(), Some(TracingPath::RayQuery));
    assert_eq!(TracingPaths::NONE.preferred(), None);
    assert!(!TracingPaths::NONE.any());
    assert_eq!(TracingPaths::NONE.to_string(), "no tracing path");
}

#[test]
fn paths_parse_from_their_names() {
    for p in [TracingPath::RayQuery, TracingPath::RayTracingPipeline] {
        assert_eq!(p.name().parse::<TracingPath>().unwrap(), p);
    }
    assert!("both".parse::<TracingPath>().is_err());
}
