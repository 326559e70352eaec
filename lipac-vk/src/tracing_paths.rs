//! Which ways of tracing rays a device context offers lipac's tracers:
//! ray queries (`VK_KHR_ray_query`, from compute shaders) and ray-tracing
//! pipelines (`VK_KHR_ray_tracing_pipeline`). The culling loop (Algorithms 1
//! and 2, BLAS/TLAS builds, uploads, read-back) needs neither; only the
//! components that trace rays do, each the path it traces with.

use crate::error::{Result, VkError};
use std::fmt;

/// The tracing paths of a device context ([`crate::DeviceContext::tracing`]).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub struct TracingPaths {
    /// `VK_KHR_ray_query` with the `rayQuery` feature enabled: ray queries
    /// in compute shaders ([`crate::RayQueryTestPipeline`],
    /// [`crate::CameraTracer`], [`crate::MergedTraceTestPipeline`]).
    pub ray_query: bool,
    /// `VK_KHR_ray_tracing_pipeline` with the `rayTracingPipeline` feature
    /// enabled: ray-tracing pipelines ([`crate::PipelineTestTracer`],
    /// [`crate::PipelineCameraTracer`]).
    pub ray_tracing_pipeline: bool,
}

/// A way of tracing rays: what a tracer needs and what a device offers.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum TracingPath {
    /// Ray queries from compute shaders (`VK_KHR_ray_query`).
    RayQuery,
    /// Ray-tracing pipelines (`VK_KHR_ray_tracing_pipeline`).
    RayTracingPipeline,
}

impl TracingPath {
    /// The Vulkan extension the path needs.
    pub fn extension(self) -> &'static str {
        match self {
            Self::RayQuery => "VK_KHR_ray_query",
            Self::RayTracingPipeline => "VK_KHR_ray_tracing_pipeline",
        }
    }

    /// A short name (`ray-query`, `pipeline`), as command-line options take it.
    pub fn name(self) -> &'static str {
        match self {
            Self::RayQuery => "ray-query",
            Self::RayTracingPipeline => "pipeline",
        }
    }
}

impl fmt::Display for TracingPath {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            Self::RayQuery => "ray queries",
            Self::RayTracingPipeline => "ray-tracing pipelines",
        })
    }
}

impl std::str::FromStr for TracingPath {
    type Err = VkError;
    fn from_str(s: &str) -> Result<Self> {
        match s {
            "ray-query" | "ray_query" | "rayquery" => Ok(Self::RayQuery),
            "pipeline" | "ray-tracing-pipeline" | "ray_tracing_pipeline" => {
                Ok(Self::RayTracingPipeline)
            }
            other => Err(VkError::InvalidArgument(format!(
                "unknown tracing path {other:?} (ray-query or pipeline)"
            ))),
        }
    }
}

impl TracingPaths {
    /// Neither path.
    pub const NONE: Self = Self {
        ray_query: false,
        ray_tracing_pipeline: false,
    };
    /// Both paths.
    pub const ALL: Self = Self {
        ray_query: true,
        ray_tracing_pipeline: true,
    };

    /// Whether `path` is offered.
    pub fn has(&self, path: TracingPath) -> bool {
        match path {
            TracingPath::RayQuery => self.ray_query,
            TracingPath::RayTracingPipeline => self.ray_tracing_pipeline,
        }
    }

    /// Whether any path is offered.
    pub fn any(&self) -> bool {
        self.ray_query || self.ray_tracing_pipeline
    }

    /// The path a tracer should use when it may choose: ray queries when
    /// offered (one compute dispatch, no shader binding table), else the
    /// ray-tracing pipeline; `None` without either.
    pub fn preferred(&self) -> Option<TracingPath> {
        if self.ray_query {
            Some(TracingPath::RayQuery)
        } else if self.ray_tracing_pipeline {
            Some(TracingPath::RayTracingPipeline)
        } else {
            None
        }
    }

    /// `Ok` when `path` is offered; else [`VkError::MissingFeature`] naming
    /// `component`, the extension it needs and what the device offers.
    ///
    /// # Errors
    ///
    /// [`VkError::MissingFeature`].
    pub fn require(&self, path: TracingPath, component: &'static str) -> Result<()> {
        if self.has(path) {
            Ok(())
        } else {
            Err(VkError::MissingFeature {
                component,
                needs: path.extension(),
                offers: self.to_string(),
            })
        }
    }
}

impl fmt::Display for TracingPaths {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match (self.ray_query, self.ray_tracing_pipeline) {
            (true, true) => f.write_str("ray queries and ray-tracing pipelines"),
            (true, false) => f.write_str("ray queries only"),
            (false, true) => f.write_str("ray-tracing pipelines only"),
            (false, false) => f.write_str("no tracing path"),
        }
    }
}

/// The `VK_KHR_ray_tracing_pipeline` properties a shader binding table is
/// laid out with ([`crate::SbtLayout`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct RayTracingPipelineProperties {
    /// `shaderGroupHandleSize`: bytes of one shader group handle.
    pub handle_size: u32,
    /// `shaderGroupHandleAlignment`: every record's stride is a multiple.
    pub handle_alignment: u32,
    /// `shaderGroupBaseAlignment`: every region's start address is a multiple.
    pub base_alignment: u32,
    /// `maxShaderGroupStride`: the largest record stride.
    pub max_stride: u32,
    /// `maxRayRecursionDepth`.
    pub max_recursion_depth: u32,
}

#[cfg(test)]
mod tests;
