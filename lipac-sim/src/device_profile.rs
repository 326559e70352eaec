//! Device profiles: what one GPU's acceleration structures take and how
//! fast it builds them, as measured by lipac-vk's `device_profile` example
//! (`cargo run --release -p lipac-vk --example device_profile -- --out
//! FILE`), for the comparison's memory axis ([`crate::memory::MemoryModel`])
//! and its modelled GPU time ([`crate::metrics::GpuModel`]): `lipac
//! compare|replay|sweep --device-profile FILE`. The format is
//! docs/MEMORY_MODEL.md's "Device profiles"; profiles of known devices
//! ship in `lipac-sim/profiles/`.
//!
//! Without a profile the comparison uses [`DeviceProfile::builtin`]:
//! lavapipe's sizes and the published rates of
//! [`GpuModel::PUBLISHED`], exactly the results of
//! earlier versions.
//!
//! ```
//! use lipac_sim::device_profile::DeviceProfile;
//! let json = r#"{
//!   "format": "lipac-device-profile", "version": 1, "name": "example",
//!   "source": "written by hand for this doc test",
//!   "blas": { "sizes": [ { "triangles": 512, "built_bytes": 47104, "compacted_bytes": 38912 } ],
//!             "builds": [ { "meshes": 256, "triangles_per_mesh": 512, "ms": 2.18 } ] },
//!   "tlas": { "sizes": [ { "instances": 1000000, "bytes": 161000000 } ],
//!             "builds": [ { "instances": 1000000, "ms": 1.69 } ] }
//! }"#;
//! let p = DeviceProfile::from_json(json).unwrap();
//! let memory = p.memory_model();
//! assert_eq!(memory.blas_bytes(1024), 92 * 1024);
//! assert_eq!(memory.tlas_bytes_per_instance(), 161);
//! // A malformed profile is an error that says what is wrong.
//! let bad = json.replace("\"version\": 1", "\"version\": 7");
//! assert!(DeviceProfile::from_json(&bad).unwrap_err().to_string().contains("version 7"));
//! ```

use std::path::Path;

use serde::{Deserialize, Serialize};

use crate::error::SimError;
use crate::memory::{MemoryModel, SizeCurve, BUILD_SCRATCH_BYTES};
use crate::metrics::GpuModel;

/// The `format` field of every profile.
pub const PROFILE_FORMAT: &str = "lipac-device-profile";
/// The format version this crate reads and writes.
pub const PROFILE_VERSION: u32 = 1;
/// Largest profile file read (bytes).
pub const MAX_PROFILE_BYTES: u64 = 1 << 20;
/// Most entries of any list of a profile.
pub const MAX_PROFILE_ENTRIES: usize = 256;
/// Most bytes per triangle or per instance a size may claim.
pub const MAX_BYTES_PER_ITEM: u64 = 1 << 20;
/// Longest text field (characters).
const MAX_TEXT: usize = 4096;

/// One measured BLAS size.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct BlasSize {
    /// Triangles of the mesh.
    pub triangles: u64,
    /// `accelerationStructureSize` of the build.
    pub built_bytes: u64,
    /// The compacted size (absent: not measured, the built size is used).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub compacted_bytes: Option<u64>,
    /// `buildScratchSize`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub build_scratch_bytes: Option<u64>,
    /// `updateScratchSize` (a build allowing updates).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub update_scratch_bytes: Option<u64>,
}

/// One timed batch of BLAS builds.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct BlasBuild {
    /// BLASes in the batch.
    pub meshes: u32,
    /// Triangles of each.
    pub triangles_per_mesh: u64,
    /// GPU time of the batch (median), ms.
    pub ms: f64,
}

/// One measured TLAS size.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TlasSize {
    /// Instances.
    pub instances: u64,
    /// `accelerationStructureSize`.
    pub bytes: u64,
    /// `buildScratchSize`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub build_scratch_bytes: Option<u64>,
}

/// One timed TLAS build.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TlasBuild {
    /// Instances.
    pub instances: u64,
    /// GPU time (median), ms.
    pub ms: f64,
}

/// GPU Algorithms 1 and 2 at one size (lipac-vk's synthetic frame).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PassTimes {
    /// Instance slots.
    pub slots: u64,
    /// Algorithm 1 (TLAS assembly), µs (median).
    pub algorithm1_us: f64,
    /// Algorithm 2 (hit feedback), µs (median).
    pub algorithm2_us: f64,
}

/// The BLAS part of a profile.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct BlasProfile {
    /// Sizes by mesh size (at least one; triangles strictly increasing).
    pub sizes: Vec<BlasSize>,
    /// The least bytes any BLAS takes (absent: none beyond the sizes).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub min_bytes: Option<u64>,
    /// Timed builds (absent: the published build rate).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub builds: Vec<BlasBuild>,
}

/// The TLAS part of a profile.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TlasProfile {
    /// Sizes by instance count (at least one; counts strictly increasing).
    pub sizes: Vec<TlasSize>,
    /// Timed builds (absent: the published rate).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub builds: Vec<TlasBuild>,
}

/// A device profile (see the module docs and docs/MEMORY_MODEL.md).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DeviceProfile {
    /// Always [`PROFILE_FORMAT`].
    pub format: String,
    /// [`PROFILE_VERSION`].
    pub version: u32,
    /// A short name the reports use (e.g. `lavapipe`, `nvidia-h200`).
    pub name: String,
    /// The device as Vulkan names it.
    #[serde(default)]
    pub device: String,
    /// Driver name and version.
    #[serde(default)]
    pub driver: String,
    /// How the figures were made: the command and machine, or where they
    /// were transcribed from.
    pub source: String,
    /// BLAS sizes and builds.
    pub blas: BlasProfile,
    /// TLAS sizes and builds.
    pub tlas: TlasProfile,
    /// GPU Algorithms 1 and 2 (informational: the modelled GPU time does
    /// not charge them).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub passes: Vec<PassTimes>,
    /// A streaming read's bandwidth, GB/s (informational).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub bandwidth_gb_per_s: Option<f64>,
}

impl Default for DeviceProfile {
    /// [`DeviceProfile::builtin`].
    fn default() -> Self {
        Self::builtin()
    }
}

fn bad(what: String) -> SimError {
    SimError::DeviceProfile(what)
}

fn finite_positive(v: f64, what: &str) -> Result<(), SimError> {
    if v.is_finite() && v > 0.0 {
        Ok(())
    } else {
        Err(bad(format!("{what} is {v}: must be finite and positive")))
    }
}

fn check_len<T>(v: &[T], what: &str, at_least: usize) -> Result<(), SimError> {
    if v.len() < at_least || v.len() > MAX_PROFILE_ENTRIES {
        return Err(bad(format!(
            "{what}: {} entries (must be {at_least} to {MAX_PROFILE_ENTRIES})",
            v.len()
        )));
    }
    Ok(())
}

/// Counts strictly increasing from 1 and bytes never decreasing, each at
/// most [`MAX_BYTES_PER_ITEM`] per item.
fn check_points(points: &[(u64, u64)], what: &str, unit: &str) -> Result<(), SimError> {
    for (i, &(n, b)) in points.iter().enumerate() {
        if n == 0 || b == 0 {
            return Err(bad(format!(
                "{what}[{i}]: {n} {unit}, {b} bytes (both must be > 0)"
            )));
        }
        if b / n > MAX_BYTES_PER_ITEM {
            return Err(bad(format!(
                "{what}[{i}]: {b} bytes for {n} {unit} is over {MAX_BYTES_PER_ITEM} bytes each"
            )));
        }
        if i > 0 {
            let (pn, pb) = points[i - 1];
            if n <= pn {
                return Err(bad(format!(
                    "{what}[{i}]: {n} {unit} after {pn}: counts must strictly increase"
                )));
            }
            if b < pb {
                return Err(bad(format!(
                    "{what}[{i}]: {b} bytes after {pb}: sizes must not decrease with the count"
                )));
            }
        }
    }
    Ok(())
}

impl DeviceProfile {
    /// The built-in profile: lavapipe's sizes ([`MemoryModel::lavapipe`])
    /// and no timed builds (so [`GpuModel::PUBLISHED`]).
    pub fn builtin() -> Self {
        let m = MemoryModel::lavapipe();
        Self {
            format: PROFILE_FORMAT.into(),
            version: PROFILE_VERSION,
            name: "built-in".into(),
            device: "llvmpipe (lavapipe)".into(),
            driver: String::new(),
            source: "lipac-sim's built-in profile: lavapipe's acceleration-structure sizes \
                     (docs/MEMORY_MODEL.md), published GPU rates (GpuModel::PUBLISHED)"
                .into(),
            blas: BlasProfile {
                sizes: m
                    .blas
                    .points()
                    .iter()
                    .map(|&(triangles, bytes)| BlasSize {
                        triangles,
                        built_bytes: bytes,
                        compacted_bytes: Some(bytes),
                        build_scratch_bytes: Some(BUILD_SCRATCH_BYTES),
                        update_scratch_bytes: Some(BUILD_SCRATCH_BYTES),
                    })
                    .collect(),
                min_bytes: Some(m.blas_min_bytes),
                builds: Vec::new(),
            },
            tlas: TlasProfile {
                sizes: m
                    .tlas
                    .points()
                    .iter()
                    .map(|&(instances, bytes)| TlasSize {
                        instances,
                        bytes,
                        build_scratch_bytes: Some(BUILD_SCRATCH_BYTES),
                    })
                    .collect(),
                builds: Vec::new(),
            },
            passes: Vec::new(),
            bandwidth_gb_per_s: None,
        }
    }

    /// Whether this is [`DeviceProfile::builtin`].
    pub fn is_builtin(&self) -> bool {
        *self == Self::builtin()
    }

    /// Parses and checks a profile ([`DeviceProfile::validate`]).
    ///
    /// # Errors
    ///
    /// [`SimError::DeviceProfile`] naming what is wrong: not JSON, another
    /// format or version, unknown or missing fields, values out of range.
    pub fn from_json(text: &str) -> Result<Self, SimError> {
        let p: Self = serde_json::from_str(text).map_err(|e| bad(format!("not a profile: {e}")))?;
        p.validate()?;
        Ok(p)
    }

    /// Reads and checks the profile at `path` (at most
    /// [`MAX_PROFILE_BYTES`]).
    ///
    /// # Errors
    ///
    /// As [`DeviceProfile::from_json`], prefixed with the path; an
    /// unreadable or too large file.
    pub fn load(path: &Path) -> Result<Self, SimError> {
        use std::io::Read;
        let at = |e: String| bad(format!("{}: {e}", path.display()));
        let file = std::fs::File::open(path).map_err(|e| at(e.to_string()))?;
        let mut text = String::new();
        file.take(MAX_PROFILE_BYTES + 1)
            .read_to_string(&mut text)
            .map_err(|e| at(e.to_string()))?;
        if text.len() as u64 > MAX_PROFILE_BYTES {
            return Err(at(format!(
                "larger than {MAX_PROFILE_BYTES} bytes: not a profile"
            )));
        }
        Self::from_json(&text).map_err(|e| match e {
            SimError::DeviceProfile(m) => at(m),
            e => e,
        })
    }

    /// The profile at `path`, or the built-in one without a path (the
    /// command line's `--device-profile`).
    ///
    /// # Errors
    ///
    /// As [`DeviceProfile::load`].
    pub fn load_or_builtin(path: Option<&Path>) -> Result<Self, SimError> {
        path.map_or_else(|| Ok(Self::builtin()), Self::load)
    }

    /// The profile as pretty JSON.
    pub fn to_json(&self) -> String {
        serde_json::to_string_pretty(self).unwrap_or_default()
    }

    /// Checks every field (the rules of docs/MEMORY_MODEL.md, "Device
    /// profiles").
    ///
    /// # Errors
    ///
    /// [`SimError::DeviceProfile`] naming the first field that is wrong.
    pub fn validate(&self) -> Result<(), SimError> {
        if self.format != PROFILE_FORMAT {
            return Err(bad(format!(
                "format `{}`: expected `{PROFILE_FORMAT}`",
                self.format
            )));
        }
        if self.version != PROFILE_VERSION {
            return Err(bad(format!(
                "version {}: this lipac reads version {PROFILE_VERSION}",
                self.version
            )));
        }
        if self.name.trim().is_empty() || self.name.len() > 200 {
            return Err(bad("name: must be 1 to 200 characters".into()));
        }
        for (text, what) in [
            (&self.device, "device"),
            (&self.driver, "driver"),
            (&self.source, "source"),
        ] {
            if text.len() > MAX_TEXT {
                return Err(bad(format!("{what}: longer than {MAX_TEXT} characters")));
            }
        }
        if self.source.trim().is_empty() {
            return Err(bad("source: say how the figures were made".into()));
        }
        let b = &self.blas;
        check_len(&b.sizes, "blas.sizes", 1)?;
        let built: Vec<(u64, u64)> = b
            .sizes
            .iter()
            .map(|s| (s.triangles, s.built_bytes))
            .collect();
        check_points(&built, "blas.sizes", "triangles")?;
        for (i, s) in b.sizes.iter().enumerate() {
            if let Some(c) = s.compacted_bytes {
                if c == 0 || c > s.built_bytes {
                    return Err(bad(format!(
                        "blas.sizes[{i}]: compacted {c} bytes of a {} byte BLAS (must be 1..=built)",
                        s.built_bytes
                    )));
                }
            }
            for (v, what) in [
                (s.build_scratch_bytes, "build_scratch_bytes"),
                (s.update_scratch_bytes, "update_scratch_bytes"),
            ] {
                if v.is_some_and(|v| v / s.triangles > MAX_BYTES_PER_ITEM) {
                    return Err(bad(format!("blas.sizes[{i}].{what}: too large")));
                }
            }
        }
        if let Some(m) = b.min_bytes {
            if m == 0 || m > MAX_BYTES_PER_ITEM {
                return Err(bad(format!(
                    "blas.min_bytes {m}: must be 1..={MAX_BYTES_PER_ITEM}"
                )));
            }
        }
        let compacted = self.compacted_points();
        check_points(&compacted, "blas.sizes (compacted)", "triangles")?;
        check_len(&b.builds, "blas.builds", 0)?;
        for (i, x) in b.builds.iter().enumerate() {
            if x.meshes == 0 || x.triangles_per_mesh == 0 {
                return Err(bad(format!(
                    "blas.builds[{i}]: {} meshes of {} triangles (both must be > 0)",
                    x.meshes, x.triangles_per_mesh
                )));
            }
            finite_positive(x.ms, &format!("blas.builds[{i}].ms"))?;
        }
        let t = &self.tlas;
        check_len(&t.sizes, "tlas.sizes", 1)?;
        let tl: Vec<(u64, u64)> = t.sizes.iter().map(|s| (s.instances, s.bytes)).collect();
        check_points(&tl, "tlas.sizes", "instances")?;
        check_len(&t.builds, "tlas.builds", 0)?;
        for (i, x) in t.builds.iter().enumerate() {
            if x.instances == 0 {
                return Err(bad(format!("tlas.builds[{i}]: 0 instances")));
            }
            finite_positive(x.ms, &format!("tlas.builds[{i}].ms"))?;
        }
        check_len(&self.passes, "passes", 0)?;
        for (i, p) in self.passes.iter().enumerate() {
            if p.slots == 0 {
                return Err(bad(format!("passes[{i}]: 0 slots")));
            }
            finite_positive(p.algorithm1_us, &format!("passes[{i}].algorithm1_us"))?;
            finite_positive(p.algorithm2_us, &format!("passes[{i}].algorithm2_us"))?;
        }
        if let Some(bw) = self.bandwidth_gb_per_s {
            finite_positive(bw, "bandwidth_gb_per_s")?;
        }
        Ok(())
    }

    /// `(triangles, compacted bytes)`, the built size where not measured.
    fn compacted_points(&self) -> Vec<(u64, u64)> {
        self.blas
            .sizes
            .iter()
            .map(|s| (s.triangles, s.compacted_bytes.unwrap_or(s.built_bytes)))
            .collect()
    }

    /// The memory model of this device: sizes interpolated between the
    /// measured ones ([`SizeCurve`]); scratch not measured is lavapipe's
    /// [`BUILD_SCRATCH_BYTES`]. Call on a validated profile.
    pub fn memory_model(&self) -> MemoryModel {
        let curve = |points: Vec<(u64, u64)>, fallback: SizeCurve| {
            SizeCurve::new(points).unwrap_or(fallback)
        };
        // Scratch the same at every measured size: that size at any count.
        let scratch_curve = |points: Vec<(u64, u64)>, fallback: SizeCurve| match points.first() {
            Some(&(_, b)) if points.iter().all(|p| p.1 == b) => SizeCurve::constant(b),
            _ => curve(points, fallback),
        };
        let lavapipe = MemoryModel::lavapipe();
        let sizes = &self.blas.sizes;
        let scratch = |f: fn(&BlasSize) -> Option<u64>| -> Vec<(u64, u64)> {
            if sizes.iter().all(|s| f(s).is_some()) {
                let mut v: Vec<(u64, u64)> = sizes
                    .iter()
                    .map(|s| (s.triangles, f(s).unwrap_or(BUILD_SCRATCH_BYTES)))
                    .collect();
                // Scratch need not grow with the count on every device;
                // the curve needs it not to fall: keep the running maximum.
                let mut max = 0;
                for p in &mut v {
                    max = max.max(p.1);
                    p.1 = max;
                }
                v
            } else {
                Vec::new()
            }
        };
        let built: Vec<(u64, u64)> = sizes.iter().map(|s| (s.triangles, s.built_bytes)).collect();
        MemoryModel {
            blas: curve(built, lavapipe.blas.clone()),
            blas_compacted: curve(self.compacted_points(), lavapipe.blas_compacted.clone()),
            blas_min_bytes: self.blas.min_bytes.unwrap_or(1),
            build_scratch: scratch_curve(
                scratch(|s| s.build_scratch_bytes),
                lavapipe.build_scratch.clone(),
            ),
            update_scratch: scratch_curve(
                scratch(|s| s.update_scratch_bytes),
                lavapipe.update_scratch.clone(),
            ),
            tlas: curve(
                self.tlas
                    .sizes
                    .iter()
                    .map(|s| (s.instances, s.bytes))
                    .collect(),
                lavapipe.tlas,
            ),
        }
    }

    /// The modelled GPU time of this device: BLAS builds from the timed
    /// batches (a per-build cost plus a per-triangle rate, fitted by least
    /// squares over the batches' per-BLAS times; one batch gives the rate
    /// alone), TLAS builds from the largest timed build; refits and rays,
    /// which no profile measures, at [`GpuModel::PUBLISHED`]'s rates.
    pub fn gpu_model(&self) -> GpuModel {
        let mut g = GpuModel::PUBLISHED;
        let points: Vec<(f64, f64)> = self
            .blas
            .builds
            .iter()
            .map(|b| {
                (
                    b.triangles_per_mesh as f64,
                    b.ms * 1e-3 / f64::from(b.meshes),
                )
            })
            .collect();
        if let Some((overhead, per_triangle)) = fit_affine(&points) {
            g.build_s_per_blas = overhead;
            g.build_triangles_per_s = 1.0 / per_triangle;
        }
        if let Some(t) = self.tlas.builds.iter().max_by_key(|t| t.instances) {
            g.tlas_instances_per_s = t.instances as f64 / (t.ms * 1e-3);
        }
        g
    }

    /// A few words naming the profile for reports: its name and device
    /// (its `source` is in the report's memory note and JSON).
    pub fn describe(&self) -> String {
        if self.is_builtin() {
            return "built-in (lavapipe's acceleration-structure sizes; published GPU rates)"
                .into();
        }
        if self.device.is_empty() {
            self.name.clone()
        } else {
            format!("{} ({})", self.name, self.device)
        }
    }
}

/// `t = c + n · s` through `(n, t)` points by least squares, with `c >= 0`
/// and `s > 0`: `(c, s)`. One point (or points that do not fit with a
/// positive slope and cost): `c = 0`, `s` = total time over total count.
/// `None` without points.
fn fit_affine(points: &[(f64, f64)]) -> Option<(f64, f64)> {
    if points.is_empty() {
        return None;
    }
    let through_origin = || {
        let (sn, st) = points
            .iter()
            .fold((0.0, 0.0), |(a, b), &(n, t)| (a + n, b + t));
        (0.0, st / sn)
    };
    let k = points.len() as f64;
    let mean_n = points.iter().map(|p| p.0).sum::<f64>() / k;
    let mean_t = points.iter().map(|p| p.1).sum::<f64>() / k;
    let var = points.iter().map(|p| (p.0 - mean_n).powi(2)).sum::<f64>();
    if points.len() < 2 || var <= 0.0 {
        return Some(through_origin());
    }
    let cov = points
        .iter()
        .map(|p| (p.0 - mean_n) * (p.1 - mean_t))
        .sum::<f64>();
    let s = cov / var;
    let c = mean_t - s * mean_n;
    if s > 0.0 && c >= 0.0 && s.is_finite() && c.is_finite() {
        Some((c, s))
    } else {
        Some(through_origin())
    }
}

#[cfg(test)]
mod tests;
