//! Generated LODs: meshoptimizer's simplifier (`meshopt` crate) on an
//! imported mesh, for files that carry no LODs of their own.

use crate::error::SimError;

/// Triangle-count fractions of the generated LODs 1 and 2 (of LOD 0).
pub const LOD_RATIOS: [f32; 2] = [0.5, 0.15];

/// Relative error (of the mesh extent) each generated LOD may reach.
pub const LOD_ERRORS: [f32; 2] = [0.01, 0.05];

/// Indices of `indices` over `positions` simplified towards `ratio` of its
/// triangles within relative error `error` (meshoptimizer's
/// `meshopt_simplify`). Never more triangles than the input; at least one
/// triangle (the input itself if simplification would remove everything).
pub fn simplify(
    positions: &[[f32; 3]],
    indices: &[u32],
    ratio: f32,
    error: f32,
) -> Result<Vec<u32>, SimError> {
    if indices.len() % 3 != 0 || indices.iter().any(|&i| i as usize >= positions.len()) {
        return Err(SimError::Import(
            "simplify: indices out of range or not whole triangles".into(),
        ));
    }
    if !(ratio > 0.0 && ratio <= 1.0 && error >= 0.0) {
        return Err(SimError::Import(
            "simplify: ratio must be in (0, 1] and error >= 0".into(),
        ));
    }
    let bytes: &[u8] = bytemuck::cast_slice(positions);
    let adapter = meshopt::VertexDataAdapter::new(bytes, 12, 0)
        .map_err(|e| SimError::Import(format!("simplify: {e}")))?;
    let target = ((indices.len() / 3) as f32 * ratio).ceil() as usize * 3;
    let out = meshopt::simplify(
        indices,
        &adapter,
        target.max(3),
        error,
        meshopt::SimplifyOptions::None,
        None,
    );
    if out.is_empty() || out.len() > indices.len() {
        Ok(indices.to_vec())
    } else {
        Ok(out)
    }
}

/// LODs 1 and 2 of a mesh ([`LOD_RATIOS`], [`LOD_ERRORS`]), each simplified
/// from the previous one.
pub fn generate_lods(positions: &[[f32; 3]], lod0: &[u32]) -> Result<[Vec<u32>; 2], SimError> {
    let l1 = simplify(positions, lod0, LOD_RATIOS[0], LOD_ERRORS[0])?;
    let r2 = (LOD_RATIOS[1] / LOD_RATIOS[0]).min(1.0);
    let l2 = simplify(positions, &l1, r2, LOD_ERRORS[1])?;
    Ok([l1, l2])
}

#[cfg(test)]
mod tests;
