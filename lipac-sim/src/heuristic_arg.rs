//! The command line's latency-mitigation and warm-start heuristics,
//! `DIST` and `SIZE` split by a separator: one reading and one rule for
//! every flag and setting that takes one (`compare --warm-start DIST:SIZE`,
//! `sweep --latency DIST:SIZE`, a sweep setting's `+DIST/SIZE`).

use lipac_core::latency::ActivationHeuristic;

/// The heuristic `DIST<sep>SIZE`: instances within `DIST` metres of the
/// camera or of projected size at least `SIZE`. `DIST` is a number ≥ 0 or
/// `inf` (no distance limit: `inf<sep>0` is the whole view); `SIZE` a
/// finite number ≥ 0. Anything else is an error that says so, quoting
/// `spec`.
///
/// ```
/// use lipac_sim::heuristic_arg::parse_heuristic;
/// let h = parse_heuristic("100:0.05", ':').unwrap();
/// assert_eq!((h.max_distance, h.min_projected_size), (100.0, 0.05));
/// let h = parse_heuristic(" inf / 0 ", '/').unwrap();
/// assert_eq!((h.max_distance, h.min_projected_size), (f32::INFINITY, 0.0));
/// for bad in ["", "50", "-1:0", "50:NaN", "NaN:0.1", "50:inf", "a:b", "50/0.1"] {
///     assert!(parse_heuristic(bad, ':').is_err(), "{bad}");
/// }
/// ```
pub fn parse_heuristic(spec: &str, sep: char) -> Result<ActivationHeuristic, String> {
    let bad = || {
        format!(
            "`{spec}`: expected DIST{sep}SIZE, a distance >= 0 in metres (`inf`: no limit) \
             and a finite projected size >= 0"
        )
    };
    let (d, p) = spec.split_once(sep).ok_or_else(bad)?;
    let (Ok(d), Ok(p)) = (d.trim().parse::<f32>(), p.trim().parse::<f32>()) else {
        return Err(bad());
    };
    if !(d >= 0.0 && p >= 0.0 && p.is_finite()) {
        return Err(bad());
    }
    Ok(ActivationHeuristic {
        max_distance: d,
        min_projected_size: p,
    })
}
