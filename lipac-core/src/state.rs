//! The LiPaC state machine: instance and hitbox states and what moves them.
//!
//! All transitions happen on the GPU in Algorithm 2
//! ([`crate::feedback::process_feedback`]); line numbers are those of the
//! paper's Algorithm 2 (thesis Algorithm 5). Algorithm 1
//! ([`crate::assembly::assemble_tlas`]) only reads the states to decide what
//! goes into the TLAS.
//!
//! A hitbox is active or inactive (1 bit and a 7-bit streak in
//! [`HitboxRecord::packed`](crate::layout::HitboxRecord)); an instance is
//! inactive, omitted or active (2 bits in
//! [`InstanceRecord::packed`](crate::layout::InstanceRecord), see
//! [`InstanceState`](crate::layout::InstanceState)). The rules a caller
//! relies on:
//!
//! * A transition with a command (`add`/`remove`, [`crate::command`]) happens
//!   only if the command fits the bounded buffer, else it is retried next
//!   frame; no instance emits more than one command per frame.
//! * Only instances that need a unique BLAS are ever omitted.
//! * An active instance whose BLAS is not built yet (`blas == 0`) is in
//!   neither the TLAS nor a counting box.
//! * The CPU sets states only at registration and in latency mitigation
//!   (§3.6).
//!
//! The diagrams and every transition: `docs/ARCHITECTURE.md`, "The state
//! machine", and `docs/ALGORITHMS.md`.
