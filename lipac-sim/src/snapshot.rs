//! Pictures of chosen frames (the paper's Fig. 8): the indirect light of the
//! ground truth and of each strategy, each strategy's error as a heat map,
//! and its TLAS map ([`crate::tlas_map`]).
//!
//! A [`Snapshot`] is captured by the comparison for each frame asked for
//! ([`crate::compare::Comparison::capture_frames`]). All images of one
//! frame share the ground truth's exposure: its mean indirect luminance maps
//! to a mid tone (Reinhard tone mapping, then sRGB), so brighter or darker
//! strategies look brighter or darker. The heat map shows each pixel's
//! error `|strategy − ground truth|` (RGB length) on the same scale, through
//! [`heat_color`]: black is exactly zero, white is at or above the scale
//! ([`Snapshot::scale`]).
//!
//! ```
//! use lipac_sim::snapshot::heat_color;
//! assert_eq!(heat_color(0.0), [0, 0, 0]);
//! assert_eq!(heat_color(1.0), [252, 255, 164]);
//! ```

use std::path::{Path, PathBuf};

use glam::Vec3;

use crate::error::SimError;
use crate::tlas_map::TlasMap;

/// One strategy in a snapshot.
#[derive(Clone, Debug, PartialEq)]
pub struct StrategySnapshot {
    /// Strategy name (as in the report).
    pub name: String,
    /// Its indirect light, row-major, row 0 at the top.
    pub indirect: Vec<Vec3>,
    /// Its relative RMSE against the ground truth this frame.
    pub error: f64,
    /// Its TLAS this frame.
    pub map: TlasMap,
}

/// The pictures of one frame.
#[derive(Clone, Debug, PartialEq)]
pub struct Snapshot {
    /// Frame number.
    pub frame: u32,
    /// Image width.
    pub width: u32,
    /// Image height.
    pub height: u32,
    /// The ground truth's indirect light.
    pub ground_truth: Vec<Vec3>,
    /// Per strategy, in report order.
    pub strategies: Vec<StrategySnapshot>,
}

/// Side of the TLAS map images, pixels.
pub const MAP_SIZE: u32 = 640;

fn luminance(c: Vec3) -> f32 {
    0.2126 * c.x + 0.7152 * c.y + 0.0722 * c.z
}

impl Snapshot {
    /// The frame's error scale: the 99th percentile of the ground truth's
    /// indirect luminance (1 when it is black), the top of the heat map's
    /// colour scale.
    pub fn scale(&self) -> f32 {
        let mut l: Vec<f32> = self
            .ground_truth
            .iter()
            .map(|&c| luminance(c))
            .filter(|v| v.is_finite() && *v > 0.0)
            .collect();
        if l.is_empty() {
            return 1.0;
        }
        l.sort_by(f32::total_cmp);
        l[((l.len() - 1) as f32 * 0.99) as usize].max(1e-6)
    }

    /// The frame's exposure: the ground truth's mean indirect luminance
    /// (1 when it is black); [`tonemap`] maps it to a mid tone.
    pub fn exposure(&self) -> f32 {
        let l: Vec<f32> = self
            .ground_truth
            .iter()
            .map(|&c| luminance(c))
            .filter(|v| v.is_finite() && *v > 0.0)
            .collect();
        if l.is_empty() {
            1.0
        } else {
            (l.iter().sum::<f32>() / l.len() as f32).max(1e-6)
        }
    }

    /// The ground truth's image as PNG.
    pub fn ground_truth_png(&self) -> Result<Vec<u8>, SimError> {
        encode_png(
            self.width,
            self.height,
            &tonemap(&self.ground_truth, self.exposure()),
        )
    }

    /// Strategy `i`'s image as PNG (same exposure as the ground truth).
    pub fn strategy_png(&self, i: usize) -> Result<Vec<u8>, SimError> {
        let s = self.get(i)?;
        encode_png(
            self.width,
            self.height,
            &tonemap(&s.indirect, self.exposure()),
        )
    }

    /// Strategy `i`'s error heat map as PNG.
    pub fn heat_png(&self, i: usize) -> Result<Vec<u8>, SimError> {
        let s = self.get(i)?;
        let rgb = heat_map(&s.indirect, &self.ground_truth, self.scale())?;
        encode_png(self.width, self.height, &rgb)
    }

    fn get(&self, i: usize) -> Result<&StrategySnapshot, SimError> {
        self.strategies
            .get(i)
            .ok_or(SimError::BadConfig("no such strategy in the snapshot"))
    }

    /// The folder name of this frame's files: `frame-0090`.
    pub fn folder(&self) -> String {
        format!("frame-{:04}", self.frame)
    }
}

/// File-name form of a strategy name: `lipac-latency`, `lipac-x4`.
pub fn file_stem(name: &str) -> String {
    let s: String = name
        .chars()
        .map(|c| match c {
            '×' => 'x',
            c if c.is_ascii_alphanumeric() || c == '-' => c,
            _ => '-',
        })
        .collect();
    let mut out = String::new();
    for part in s.split('-').filter(|p| !p.is_empty()) {
        if !out.is_empty() {
            out.push('-');
        }
        out.push_str(part);
    }
    if out.is_empty() {
        out.push('x');
    }
    out
}

fn srgb(v: f32) -> u8 {
    let v = if v.is_finite() {
        v.clamp(0.0, 1.0)
    } else {
        1.0
    };
    let s = if v <= 0.003_130_8 {
        12.92 * v
    } else {
        1.055 * v.powf(1.0 / 2.4) - 0.055
    };
    (s * 255.0 + 0.5) as u8
}

/// Linear RGB tone-mapped for display: `v = 0.6 · c / exposure` per
/// channel, then Reinhard `v / (1 + v)`, then sRGB: 8-bit RGB. Black stays
/// black; `exposure` (a luminance) maps to a mid tone.
pub fn tonemap(image: &[Vec3], exposure: f32) -> Vec<u8> {
    let k = if exposure > 0.0 && exposure.is_finite() {
        0.6 / exposure
    } else {
        0.6
    };
    let map = |c: f32| {
        let v = (c * k).max(0.0);
        srgb(v / (1.0 + v))
    };
    image
        .iter()
        .flat_map(|c| [map(c.x), map(c.y), map(c.z)])
        .collect()
}

/// Stops of the heat map's colour scale (an inferno-like ramp).
const HEAT: [(f32, [f32; 3]); 5] = [
    (0.0, [0.0, 0.0, 0.0]),
    (0.3, [87.0, 16.0, 110.0]),
    (0.55, [188.0, 55.0, 84.0]),
    (0.8, [249.0, 142.0, 9.0]),
    (1.0, [252.0, 255.0, 164.0]),
];

/// The heat map's colour of `t` (0 = black, 1 and above = pale yellow).
pub fn heat_color(t: f32) -> [u8; 3] {
    let t = if t.is_nan() { 1.0 } else { t.clamp(0.0, 1.0) };
    let i = HEAT.iter().position(|s| s.0 >= t).unwrap_or(HEAT.len() - 1);
    if i == 0 {
        return HEAT[0].1.map(|c| c as u8);
    }
    let (a, b) = (HEAT[i - 1], HEAT[i]);
    let f = (t - a.0) / (b.0 - a.0);
    [0, 1, 2].map(|k| (a.1[k] + (b.1[k] - a.1[k]) * f + 0.5) as u8)
}

/// Per pixel `heat_color(|image − reference| / scale)`: 8-bit RGB.
pub fn heat_map(image: &[Vec3], reference: &[Vec3], scale: f32) -> Result<Vec<u8>, SimError> {
    if image.len() != reference.len() {
        return Err(SimError::SizeMismatch {
            a: image.len(),
            b: reference.len(),
        });
    }
    let k = if scale > 0.0 && scale.is_finite() {
        1.0 / scale
    } else {
        1.0
    };
    Ok(image
        .iter()
        .zip(reference)
        .flat_map(|(a, b)| {
            let e = (*a - *b).length();
            if e == 0.0 {
                [0, 0, 0]
            } else {
                heat_color(e * k)
            }
        })
        .collect())
}

/// The heat map's colour scale as a `width` x 12 PNG, 0 on the left.
pub fn heat_scale_png(width: u32) -> Result<Vec<u8>, SimError> {
    let w = width.max(2);
    let row: Vec<u8> = (0..w)
        .flat_map(|x| heat_color(x as f32 / (w - 1) as f32))
        .collect();
    encode_png(w, 12, &row.repeat(12))
}

/// 8-bit RGB pixels (row-major) as a PNG file.
pub fn encode_png(width: u32, height: u32, rgb: &[u8]) -> Result<Vec<u8>, SimError> {
    if rgb.len() != width as usize * height as usize * 3 {
        return Err(SimError::SizeMismatch {
            a: rgb.len(),
            b: width as usize * height as usize * 3,
        });
    }
    let mut out = Vec::new();
    {
        let mut enc = png::Encoder::new(&mut out, width, height);
        enc.set_color(png::ColorType::Rgb);
        enc.set_depth(png::BitDepth::Eight);
        // Balanced: a third of the bytes of Fast (2 MB for a 3-snapshot city
        // report.html) for about 0.3 s more per snapshot frame.
        enc.set_compression(png::Compression::Balanced);
        let err = |e: png::EncodingError| SimError::Io(format!("encoding a PNG: {e}"));
        let mut w = enc.write_header().map_err(err)?;
        w.write_image_data(rgb).map_err(err)?;
        w.finish().map_err(err)?;
    }
    Ok(out)
}

/// The encoded PNGs of one [`Snapshot`], made once for both the files and
/// `report.html`.
#[derive(Clone, Debug, PartialEq)]
pub struct Pictures {
    /// [`Snapshot::ground_truth_png`].
    pub ground_truth: Vec<u8>,
    /// Per strategy: [`Snapshot::strategy_png`], [`Snapshot::heat_png`] and
    /// its TLAS map ([`TlasMap::png`] at [`MAP_SIZE`]).
    pub strategies: Vec<[Vec<u8>; 3]>,
}

impl Snapshot {
    /// Every picture of this snapshot, encoded.
    pub fn pictures(&self) -> Result<Pictures, SimError> {
        Ok(Pictures {
            ground_truth: self.ground_truth_png()?,
            strategies: (0..self.strategies.len())
                .map(|i| {
                    Ok([
                        self.strategy_png(i)?,
                        self.heat_png(i)?,
                        self.strategies[i].map.png(MAP_SIZE)?,
                    ])
                })
                .collect::<Result<_, SimError>>()?,
        })
    }
}

/// Writes every snapshot's `pictures` under `dir/snapshots/frame-NNNN/`:
/// `ground-truth.png`, and per strategy `NAME.png`, `NAME-error.png`,
/// `NAME-map.png` (names by [`file_stem`]), plus
/// `dir/snapshots/heat-scale.png`. Returns the paths written.
pub fn write_snapshots(
    snapshots: &[Snapshot],
    pictures: &[Pictures],
    dir: &Path,
) -> Result<Vec<PathBuf>, SimError> {
    let mut paths = Vec::new();
    if snapshots.len() != pictures.len() {
        return Err(SimError::SizeMismatch {
            a: snapshots.len(),
            b: pictures.len(),
        });
    }
    if snapshots.is_empty() {
        return Ok(paths);
    }
    let root = dir.join("snapshots");
    std::fs::create_dir_all(&root)?;
    let mut put = |p: PathBuf, bytes: &[u8]| -> Result<(), SimError> {
        std::fs::write(&p, bytes)?;
        paths.push(p);
        Ok(())
    };
    put(root.join("heat-scale.png"), &heat_scale_png(256)?)?;
    for (s, pics) in snapshots.iter().zip(pictures) {
        let d = root.join(s.folder());
        std::fs::create_dir_all(&d)?;
        put(d.join("ground-truth.png"), &pics.ground_truth)?;
        for (st, [image, heat, map]) in s.strategies.iter().zip(&pics.strategies) {
            let stem = file_stem(&st.name);
            put(d.join(format!("{stem}.png")), image)?;
            put(d.join(format!("{stem}-error.png")), heat)?;
            put(d.join(format!("{stem}-map.png")), map)?;
        }
    }
    Ok(paths)
}

#[cfg(test)]
mod tests;
