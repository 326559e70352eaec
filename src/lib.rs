//! # lipac
//!
//! Light path guided culling (LiPaC) for real-time path tracing: this crate
//! re-exports the crate family so that an engine can depend on one name.
//!
//! * [`core`] — renderer-agnostic state (`lipac-core`): instances, hitboxes,
//!   the instance/hitbox state machine, TLAS assembly and feedback processing
//!   (CPU reference), the readback command loop and latency mitigation.
//!   Always there.
//! * `vk` — the Vulkan backend on `ash` (`lipac-vk`); feature `vk`.
//! * `sim` — the CPU laboratory on `obvhs` (`lipac-sim`); feature `sim`.
//! * [`glam`] — the vector-math crate lipac's API takes.
//!
//! docs/INTEGRATION.md (compiled below as doc tests with feature `vk`) adds
//! lipac to an ash engine, tracer included.
//!
//! Both features are off by default, so `lipac = "0.1"` builds neither ash
//! nor obvhs, clap or indicatif:
//!
//! ```toml
//! [dependencies]
//! lipac = { version = "0.1", features = ["vk"] }
//! ```
#![forbid(unsafe_code)]
#![warn(missing_docs)]
#![cfg_attr(docsrs, feature(doc_cfg))]

/// The `glam` that lipac's API takes (transforms, vectors): use it rather
/// than a `glam` dependency of your own, so that the versions match.
pub use glam;
pub use lipac_core as core;
#[cfg(feature = "sim")]
#[cfg_attr(docsrs, doc(cfg(feature = "sim")))]
pub use lipac_sim as sim;
#[cfg(feature = "vk")]
#[cfg_attr(docsrs, doc(cfg(feature = "vk")))]
pub use lipac_vk as vk;

/// The Rust code of `docs/INTEGRATION.md` (adding lipac to an ash engine),
/// compiled as doc tests so that the guide stays true to the API.
#[cfg(all(doctest, feature = "vk"))]
#[doc = include_str!("../docs/INTEGRATION.md")]
pub struct IntegrationGuide;
