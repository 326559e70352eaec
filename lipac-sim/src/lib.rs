//! # lipac-sim
//!
//! The CPU laboratory of lipac: procedural scenes, camera paths, a path tracer
//! producing real hit feedback, ground truth and culling strategies compared.
#![forbid(unsafe_code)]
#![warn(missing_docs)]
