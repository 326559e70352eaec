//! # lipac-core
//!
//! Renderer-agnostic state of light path guided culling (LiPaC; Kelling,
//! Ströter, Kuijper 2024, and Kelling's 2023 thesis §3.3).
//!
//! The crate is *sans-IO*: it never touches a GPU. It owns the truth about
//! instances and hitboxes and exposes the two GPU algorithms of the paper as
//! CPU reference implementations over exactly the buffer layouts a GPU backend
//! uses ([`layout`]), so that `lipac-vk`'s compute shaders can be tested
//! against them record for record.
#![forbid(unsafe_code)]
#![warn(missing_docs)]

pub mod hitbox_index;
pub mod layout;
pub mod math;
