//! The error type of the laboratory.

use std::fmt;

/// Everything that can go wrong when a caller hands the laboratory bad input.
#[derive(Clone, Debug, PartialEq)]
pub enum SimError {
    /// A mesh id that the [`crate::mesh::MeshLibrary`] does not hold.
    UnknownMesh(u32),
    /// A LOD index outside `0..LOD_COUNT`.
    BadLod(usize),
    /// A BLAS handle that was removed or never issued.
    StaleBlas,
    /// A TLAS record's `acceleration_structure_reference` names no live BLAS.
    UnknownBlasReference {
        /// Index of the record in the slice passed to the TLAS build.
        record: usize,
        /// The reference it carries.
        reference: u64,
    },
    /// A transform with NaN/inf entries or a (near-)singular linear part.
    BadTransform {
        /// Index of the record (or instance) that carries it.
        record: usize,
    },
    /// A value that must be finite was NaN or infinite.
    NonFinite(&'static str),
    /// A refit was asked with a different triangle count than the BLAS was built with.
    RefitCountMismatch {
        /// Triangles the BLAS holds.
        expected: usize,
        /// Triangles handed to the refit.
        got: usize,
    },
    /// An instance slot outside the scene.
    UnknownInstance(u32),
    /// A geometry request for an instance that shares its mesh (has no unique geometry).
    NotUnique(u32),
    /// A configuration value out of its range.
    BadConfig(&'static str),
    /// A configuration value out of its range, naming the value as given.
    BadValue(String),
    /// Two images (or buffers) that must match in size do not.
    SizeMismatch {
        /// Length of the first.
        a: usize,
        /// Length of the second.
        b: usize,
    },
    /// lipac-core refused an operation (its error, rendered as text).
    Core(String),
    /// Writing a report failed.
    Io(String),
    /// A trace could not be read or written (byte offset or line, frame and
    /// what was wrong).
    Trace(Box<lipac_core::trace::TraceError>),
    /// A valid trace that cannot be replayed as asked (e.g. a strategy that
    /// needs geometry on a hits-only trace).
    Replay(String),
    /// A scene file could not be imported (`crate::import`).
    Import(String),
    /// Sweep shards that do not merge into one sweep (missing, repeated,
    /// from other settings).
    Shard(String),
    /// A device profile that cannot be used (`crate::device_profile`): the
    /// file, and what is wrong.
    DeviceProfile(String),
}

impl fmt::Display for SimError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Self::UnknownMesh(id) => write!(f, "unknown mesh id {id}"),
            Self::BadLod(l) => write!(f, "LOD {l} out of range (0..3)"),
            Self::StaleBlas => write!(f, "stale or unknown BLAS handle"),
            Self::UnknownBlasReference { record, reference } => write!(
                f,
                "TLAS record {record} references BLAS {reference:#x}, which is not live"
            ),
            Self::BadTransform { record } => {
                write!(f, "transform of record {record} is non-finite or singular")
            }
            Self::NonFinite(what) => write!(f, "{what} must be finite"),
            Self::RefitCountMismatch { expected, got } => write!(
                f,
                "refit needs the same triangle count as the build ({expected}), got {got}"
            ),
            Self::UnknownInstance(i) => write!(f, "unknown instance slot {i}"),
            Self::NotUnique(i) => {
                write!(f, "instance {i} shares its mesh; it has no unique geometry")
            }
            Self::BadConfig(what) => write!(f, "bad configuration: {what}"),
            Self::BadValue(what) => write!(f, "bad configuration: {what}"),
            Self::SizeMismatch { a, b } => write!(f, "sizes differ: {a} vs {b}"),
            Self::Core(what) => write!(f, "lipac-core: {what}"),
            Self::Io(what) => write!(f, "i/o: {what}"),
            Self::Trace(e) => write!(f, "{e}"),
            Self::Replay(what) => write!(f, "cannot replay: {what}"),
            Self::Import(what) => write!(f, "cannot import: {what}"),
            Self::Shard(what) => write!(f, "cannot merge sweep shards: {what}"),
            Self::DeviceProfile(what) => write!(f, "device profile: {what}"),
        }
    }
}

impl std::error::Error for SimError {}

impl SimError {
    /// Wraps an error of lipac-core (or any other displayable error).
    pub fn core(e: impl fmt::Display) -> Self {
        Self::Core(e.to_string())
    }
}

impl From<std::io::Error> for SimError {
    fn from(e: std::io::Error) -> Self {
        Self::Io(e.to_string())
    }
}

impl From<lipac_core::trace::TraceError> for SimError {
    fn from(e: lipac_core::trace::TraceError) -> Self {
        Self::Trace(Box::new(e))
    }
}
