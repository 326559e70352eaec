//! What a backend reports back to the [`Manager`](super::Manager) when work
//! of a [`ManagerPlan`](super::ManagerPlan) has finished on its device.

use crate::blas_ids::BuildId;

/// One acknowledgement, handed to
/// [`Manager::handle_ack`](super::Manager::handle_ack) whenever the backend
/// learns that a planned operation completed (never before: a GPU backend
/// acknowledges after its timeline passed the submission).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Ack {
    /// A BLAS build of the plan finished (updates need no acknowledgement).
    Built {
        /// The build ([`BlasBuild::id`](crate::build_plan::BlasBuild::id)).
        build: BuildId,
        /// The BLAS's real result size in bytes.
        result_bytes: u64,
        /// The BLAS's device address.
        address: u64,
    },
    /// The compacted-size query after build `build` returned.
    CompactedSize {
        /// The build whose BLAS was queried.
        build: BuildId,
        /// The compacted size in bytes.
        compacted_bytes: u64,
    },
    /// Compaction `op` (a copy into a smaller BLAS) finished.
    Compacted {
        /// The compaction
        /// ([`CompactionPlan::id`](crate::build_plan::CompactionPlan::id)).
        op: BuildId,
        /// The compacted BLAS's device address.
        address: u64,
    },
}
