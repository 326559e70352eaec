//! The LiPaC state machine: instance and hitbox states and what moves them.
//!
//! All transitions happen on the GPU in Algorithm 2
//! ([`crate::feedback::process_feedback`]); line numbers are those of the
//! paper's Algorithm 2 (thesis Algorithm 5). Algorithm 1
//! ([`crate::assembly::assemble_tlas`]) only reads the states to decide what
//! goes into the TLAS.
//!
//! # Hitbox (1 bit + 7-bit streak in [`HitboxRecord::packed`](crate::layout::HitboxRecord))
//!
//! ```text
//!                hits > θa for n_a frames in a row,
//!                or hits > 2·θa in one frame            (line 9)
//!         +--------------------------------------------------+
//!         |                                                  v
//!   +------------+                                    +------------+
//!   |  inactive  |                                    |   active   |
//!   | (counting  |                                    | (instances |
//!   |  box in    |                                    |  may be in |
//!   |  TLAS)     |                                    |  TLAS)     |
//!   +------------+                                    +------------+
//!         ^                                                  |
//!         +--------------------------------------------------+
//!                hits < θd for n_d frames in a row      (line 11)
//! ```
//!
//! Every hitbox starts inactive. The streak counts the current run of frames
//! above θa (inactive) or below θd (active); a frame outside the run and every
//! state change reset it to 0. A hitbox's hits are the rays that hit its
//! counting box plus the hits of its active and omitted instances (lines
//! 1–6).
//!
//! # Instance (2 bits in [`InstanceRecord::packed`](crate::layout::InstanceRecord))
//!
//! `H` is the instance's hitbox (after lines 7–13 of the same frame), `hits`
//! the instance's own hit count; `+add` / `+remove` mark transitions that
//! append a command ([`crate::command`]).
//!
//! ```text
//!                          H active, shared BLAS, +add (25/26)
//!        +-----------------------------------------------------------------+
//!        |                                                                 v
//!  +----------+   H active, unique BLAS (23)    +---------+  hits > σa  +--------+
//!  | INACTIVE | ------------------------------> | OMITTED | ----------> | ACTIVE |
//!  | hitbox   |                                 | AABB    |  +add       | own    |
//!  | only     | <------------------------------ | counting|  (31/32)   | BLAS   |
//!  +----------+   H inactive (19/20)            | box     | <---------- | in TLAS|
//!        ^                                      +---------+  hits < σo  +--------+
//!        |                                                   +remove      |
//!        |                                                   (34/35,      |
//!        |                                                   unique BLAS, |
//!        |                                                   BLAS built)  |
//!        +----------------------------------------------------------------+
//!                          H inactive, +remove (17/18)
//! ```
//!
//! * Lines 29–37 (omitted ⇄ active by own hits) apply only to instances that
//!   need a unique BLAS; a shared-BLAS instance is never omitted.
//! * In one frame an instance may take line 23 and then line 31 (the blocks
//!   fall through); no instance ever emits more than one command per frame.
//! * A transition with a command happens only if the command fits in the
//!   bounded buffer; otherwise the state stays and the transition is retried
//!   next frame ([`crate::feedback`], "overflow rule").
//! * An *active* instance whose BLAS is not built yet (`blas == 0`) is in
//!   neither the TLAS nor a counting box; it stays active until the CPU builds
//!   its BLAS or its hitbox deactivates.
//! * Dead slots ([`instance_bits::ALIVE`](crate::layout::instance_bits::ALIVE)
//!   clear) take no part.
//!
//! Outside Algorithm 2, the CPU may also set states directly (registration,
//! latency mitigation §3.6) and upload the records.
