//! The command line's latency-mitigation and warm-start heuristics,
//! `DIST`, `SIZE` and an optional `RADIUS` split by a separator: one
//! reading and one rule for every flag and setting that takes one
//! (`compare --warm-start DIST:SIZE[:RADIUS]`, `sweep --latency
//! DIST:SIZE[:RADIUS]`, a sweep setting's `+DIST/SIZE[/RADIUS]`).

use lipac_core::latency::ActivationHeuristic;

/// The heuristic `DIST<sep>SIZE[<sep>RADIUS]`: instances within `DIST`
/// metres of the camera or of projected size at least `SIZE`, among those
/// in the frustum or within `RADIUS` metres of the camera in any direction
/// ([`ActivationHeuristic::surround_radius`]; without it the frustum
/// alone). `DIST` is a number ≥ 0 or `inf` (no distance limit: `inf<sep>0`
/// is the whole view); `SIZE` and `RADIUS` finite numbers ≥ 0. Anything
/// else is an error that says so, quoting `spec`.
///
/// ```
/// use lipac_sim::heuristic_arg::parse_heuristic;
/// let h = parse_heuristic("100:0.05", ':').unwrap();
/// assert_eq!((h.max_distance, h.min_projected_size, h.surround_radius), (100.0, 0.05, 0.0));
/// let h = parse_heuristic(" inf / 0 ", '/').unwrap();
/// assert_eq!((h.max_distance, h.min_projected_size), (f32::INFINITY, 0.0));
/// let h = parse_heuristic("inf:0:800", ':').unwrap();
/// assert_eq!((h.max_distance, h.surround_radius), (f32::INFINITY, 800.0));
/// for bad in [
///     "", "50", "-1:0", "50:NaN", "NaN:0.1", "50:inf", "a:b", "50/0.1", "50:0:inf",
///     "50:0:-1", "50:0:", "50:0:1:2",
/// ] {
///     assert!(parse_heuristic(bad, ':').is_err(), "{bad}");
/// }
/// ```
pub fn parse_heuristic(spec: &str, sep: char) -> Result<ActivationHeuristic, String> {
    let bad = || {
        format!(
            "`{spec}`: expected DIST{sep}SIZE[{sep}RADIUS], a distance >= 0 in metres (`inf`: \
             no limit), a finite projected size >= 0 and a finite surround radius >= 0 in metres"
        )
    };
    let parts: Vec<&str> = spec.split(sep).collect();
    if !(2..=3).contains(&parts.len()) {
        return Err(bad());
    }
    let number = |s: &str| s.trim().parse::<f32>().map_err(|_| bad());
    let d = number(parts[0])?;
    let p = number(parts[1])?;
    let r = parts.get(2).map_or(Ok(0.0), |s| number(s))?;
    if !(d >= 0.0 && p >= 0.0 && p.is_finite() && r >= 0.0 && r.is_finite()) {
        return Err(bad());
    }
    Ok(ActivationHeuristic {
        max_distance: d,
        min_projected_size: p,
        surround_radius: r,
    })
}
