//! # lipac-sim
//!
//! The CPU laboratory of lipac: procedural scenes, camera paths, a path tracer
//! producing real hit feedback, ground truth and culling strategies compared.
#![forbid(unsafe_code)]
#![warn(missing_docs)]

pub mod blas;
pub mod camera;
pub mod closed_loop;
pub mod compare;
pub mod cpu_backend;
pub mod device_profile;
pub mod error;
pub mod heuristic_arg;
pub mod html;
pub mod import;
pub mod json_float;
pub mod memory;
pub mod mesh;
pub mod metrics;
pub mod pathtrace;
pub mod plots;
pub mod record;
pub mod replay;
pub mod report;
pub mod rng;
pub mod scene;
pub mod scene_blas;
pub mod snapshot;
pub mod strategy;
pub mod sweep;
pub mod tlas;
pub mod tlas_map;
pub mod trace_scene;
pub mod traversal;

pub use error::SimError;
