//! The configurations a sweep runs ([`Variant`]s of a [`SweepConfig`]):
//! the baselines, LiPaC with scaled thresholds ([`scaled_thresholds`]),
//! with latency mitigation, with other cell sizes and streak lengths, and
//! with other decayed-rule settings ([`parse_decayed_spec`]).

use std::path::PathBuf;

use lipac_core::hitbox_tree::MAX_MERGE_LEVELS;
use lipac_core::latency::ActivationHeuristic;
use lipac_core::thresholds::{DecayedSettings, DecisionRule, Thresholds};
use serde::{Deserialize, Serialize};

use crate::compare::{make_strategy, Contender, LipacStart, SceneChoice};
use crate::device_profile::DeviceProfile;
use crate::error::SimError;
use crate::scene::Scene;
use crate::strategy::hindsight::Hindsight;
use crate::strategy::lipac::{Lipac, LipacConfig};
use crate::strategy::StrategyKind;
use crate::trace_scene::TraceSceneOptions;

/// What a variant varies.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub enum Family {
    /// A baseline strategy (full, frustum, heuristic, oracle).
    Baseline,
    /// LiPaC with its thresholds scaled by a factor.
    Thresholds,
    /// LiPaC with latency mitigation.
    Latency,
    /// LiPaC with another hitbox cell size.
    CellSize,
    /// LiPaC with other streak lengths n_a / n_d.
    Streaks,
    /// LiPaC with other decayed-rule settings (rise shift, rates).
    Decayed,
}

impl Family {
    /// Name.
    pub fn name(self) -> &'static str {
        match self {
            Self::Baseline => "baseline",
            Self::Thresholds => "thresholds",
            Self::Latency => "latency",
            Self::CellSize => "cell size",
            Self::Streaks => "streaks",
            Self::Decayed => "decayed rule",
        }
    }
}

/// One configuration of a sweep.
#[derive(Clone, Debug, PartialEq)]
pub struct Variant {
    /// Report name (unique).
    pub name: String,
    /// What it varies.
    pub family: Family,
    /// The strategy.
    pub kind: StrategyKind,
    /// LiPaC's settings (`None` for the baselines).
    pub lipac: Option<LipacConfig>,
    /// Threshold factor (LiPaC variants).
    pub factor: Option<f64>,
    /// The window of a [`StrategyKind::Hindsight`] reference, in frames.
    pub hindsight: Option<u32>,
}

/// Settings of a sweep.
#[derive(Clone, Debug, PartialEq)]
pub struct SweepConfig {
    /// Scenes, each with its fly-through.
    pub scenes: Vec<SceneChoice>,
    /// Scene seed (`None`: each scene's own).
    pub seed: Option<u64>,
    /// Frames per scene (`None`: the whole fly-through).
    pub frames: Option<u32>,
    /// Image width.
    pub width: u32,
    /// Image height.
    pub height: u32,
    /// Baseline strategies.
    pub baselines: Vec<StrategyKind>,
    /// Windows of [`crate::strategy::hindsight::Hindsight`] references
    /// run beside the baselines, in frames (each at least 1; named
    /// "hindsight K").
    pub hindsight: Vec<u32>,
    /// Threshold factors of plain LiPaC (default cells, n_a = 4, n_d = 15).
    pub factors: Vec<f64>,
    /// Latency-mitigation heuristics, each run as LiPaC + latency
    /// mitigation at factor 1.
    pub latency: Vec<ActivationHeuristic>,
    /// Further hitbox cell sizes (metres), at factor 1.
    pub cell_sizes: Vec<f64>,
    /// Further `(n_a, n_d)` streak lengths, at factor 1.
    pub streaks: Vec<(u32, u32)>,
    /// Further decayed-rule settings (in place of
    /// [`LipacConfig::DEFAULT_DECAYED`]), at factor 1, each optionally with
    /// its own cell size and latency mitigation ([`parse_decayed_variant`]).
    pub decayed: Vec<DecayedVariant>,
    /// Render threads (0 = all cores).
    pub threads: usize,
    /// Sweep this recorded trace (replayed in geometry mode, as `lipac
    /// replay` does: a trace of a built-in scene, or one whose header
    /// carries its meshes' geometry) instead of `scenes`, which must then
    /// be empty; `seed` and `frames` do not apply.
    pub trace: Option<PathBuf>,
    /// How a [`SweepConfig::trace`] of another scene than the built-in
    /// ones is traced (box proxies, vegetation, sun and sky), as `lipac
    /// replay` takes them.
    pub trace_options: TraceSceneOptions,
    /// Every LiPaC configuration warm-starts again at each camera cut
    /// ([`LipacConfig::warm_start_at_cuts`]): on a trace at the cuts the
    /// replay finds ([`crate::camera::FlyCamera::is_cut_from`]); the
    /// scenes' fly-throughs have none.
    pub warm_start_at_cuts: bool,
    /// Frames every LiPaC configuration holds what a warm start activates
    /// ([`LipacConfig::warm_start_hold`]; `None`: as configured, 0).
    pub warm_start_hold: Option<u32>,
    /// How every LiPaC configuration starts ([`LipacStart`]: as
    /// configured, cold, or warm with a heuristic); said in each
    /// configuration's name unless it is the configured start.
    pub lipac_start: LipacStart,
    /// The device profile of every scene's memory axis and modelled GPU
    /// time ([`crate::compare::CompareConfig::device`]).
    pub device: DeviceProfile,
}

impl Default for SweepConfig {
    /// City and mirror scenes, the whole fly-through at 128 x 72; full,
    /// frustum, heuristic and oracle; factors 0.5, 1, 2, 4; latency
    /// mitigation with the default heuristic and a wider one (100 m, 0.05);
    /// 16 m and 64 m cells besides the default 32 m;
    /// `(n_a, n_d)` = (1, 15) and (4, 30); no other decayed-rule settings;
    /// no hindsight references.
    fn default() -> Self {
        Self {
            scenes: vec![SceneChoice::City, SceneChoice::Mirror],
            seed: None,
            frames: None,
            width: 128,
            height: 72,
            baselines: vec![
                StrategyKind::Full,
                StrategyKind::Frustum,
                StrategyKind::Heuristic,
                StrategyKind::Oracle,
            ],
            hindsight: Vec::new(),
            factors: vec![0.5, 1.0, 2.0, 4.0],
            latency: vec![
                ActivationHeuristic::default(),
                ActivationHeuristic {
                    max_distance: 100.0,
                    min_projected_size: 0.05,
                    surround_radius: 0.0,
                },
            ],
            cell_sizes: vec![16.0, 64.0],
            streaks: vec![(1, 15), (4, 30)],
            decayed: Vec::new(),
            threads: 0,
            trace: None,
            trace_options: TraceSceneOptions::default(),
            warm_start_at_cuts: false,
            warm_start_hold: None,
            lipac_start: LipacStart::Default,
            device: DeviceProfile::builtin(),
        }
    }
}

/// LiPaC's thresholds for `rays_per_frame` camera rays scaled by `factor`
/// (see the module docs).
///
/// ```
/// use lipac_sim::sweep::scaled_thresholds;
/// let t = scaled_thresholds(1920 * 1080, 0.5).unwrap();
/// assert_eq!((t.theta_a, t.theta_d, t.sigma_a, t.sigma_o), (500, 50, 500, 50));
/// assert!(scaled_thresholds(9216, f64::NAN).is_err());
/// ```
pub fn scaled_thresholds(rays_per_frame: u64, factor: f64) -> Result<Thresholds, SimError> {
    if !factor.is_finite() || factor <= 0.0 {
        return Err(SimError::BadConfig(
            "threshold factors must be finite and positive",
        ));
    }
    Thresholds::for_rays_per_frame(rays_per_frame as f64 * factor).map_err(SimError::core)
}

/// Decayed-rule settings from `K_UP[:A/D[:IA/IO[:HALF_LIFE]]]`: the rise
/// shift ([`lipac_core::thresholds::DecayedRule::rise_shift`]; `-` keeps the
/// decay shift), then optionally the hitbox activation / deactivation and
/// the instance activation / omit rates in hits per frame at 1080p (like
/// [`LipacConfig::DEFAULT_DECAYED`]'s 150/30) and the decay half-life in
/// frames; what is not given is `base`'s.
/// Checked against the rays only when the sweep builds its variants.
///
/// ```
/// use lipac_sim::sweep::parse_decayed_spec;
/// use lipac_sim::strategy::lipac::LipacConfig;
/// let base = LipacConfig::DEFAULT_DECAYED;
/// let s = parse_decayed_spec("1:200/40:100/20", &base).unwrap();
/// assert_eq!(s.rise_shift, Some(1));
/// assert_eq!((s.activate, s.deactivate, s.instance_activate, s.instance_omit), (200.0, 40.0, 100.0, 20.0));
/// assert_eq!(parse_decayed_spec("2", &base).unwrap().activate, base.activate);
/// assert_eq!(parse_decayed_spec("-:300/60", &base).unwrap().rise_shift, None);
/// assert_eq!(parse_decayed_spec("1:150/30:150/30:2.4", &base).unwrap().half_life_frames, 2.4);
/// assert!(parse_decayed_spec("1:200", &base).is_err());
/// assert!(parse_decayed_spec("x", &base).is_err());
/// ```
pub fn parse_decayed_spec(spec: &str, base: &DecayedSettings) -> Result<DecayedSettings, String> {
    let mut parts = spec.trim().split(':');
    let mut s = *base;
    let rise = parts.next().unwrap_or("").trim();
    s.rise_shift =
        if rise == "-" {
            None
        } else {
            Some(rise.parse().map_err(|_| {
                format!("decayed rule `{spec}`: rise shift `{rise}` is not a number")
            })?)
        };
    let pair = |p: &str| -> Result<(f64, f64), String> {
        let (a, b) = p
            .split_once('/')
            .ok_or_else(|| format!("decayed rule `{spec}`: expected `upper/lower`, got `{p}`"))?;
        match (a.trim().parse(), b.trim().parse()) {
            (Ok(a), Ok(b)) => Ok((a, b)),
            _ => Err(format!("decayed rule `{spec}`: `{p}` is not two numbers")),
        }
    };
    if let Some(p) = parts.next() {
        (s.activate, s.deactivate) = pair(p)?;
    }
    if let Some(p) = parts.next() {
        (s.instance_activate, s.instance_omit) = pair(p)?;
    }
    if let Some(p) = parts.next() {
        s.half_life_frames = p
            .trim()
            .parse()
            .map_err(|_| format!("decayed rule `{spec}`: half-life `{p}` is not a number"))?;
    }
    if parts.next().is_some() {
        return Err(format!("decayed rule `{spec}`: at most four `:` parts"));
    }
    Ok(s)
}

/// A decayed-rule variant's report name: `lipac rise K a/d ia/io`, and
/// `hl H` when the half-life is not the default's.
fn decayed_name(s: &DecayedSettings) -> String {
    let rise = s
        .rise_shift
        .map_or_else(|| "-".to_string(), |k| k.to_string());
    let half_life = if s.half_life_frames == LipacConfig::DEFAULT_DECAYED.half_life_frames {
        String::new()
    } else {
        format!(" hl {}", s.half_life_frames)
    };
    format!(
        "lipac rise {rise} {}/{} {}/{}{half_life}",
        s.activate, s.deactivate, s.instance_activate, s.instance_omit
    )
}

fn fmt_factor(f: f64) -> String {
    format!("×{f}")
}

/// A decayed-rule variant of a sweep: the rule's settings and, where given,
/// its own hitbox cell size and latency mitigation, so that the levers that
/// each helped alone can be measured together.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct DecayedVariant {
    /// The rule's settings.
    pub settings: DecayedSettings,
    /// Hitbox cell size in metres (`None`: the base configuration's).
    pub cell_size: Option<f64>,
    /// Latency mitigation (`None`: off, as in the base configuration).
    pub latency: Option<ActivationHeuristic>,
    /// Adaptive hitboxes' merge levels (`None`: the base configuration's,
    /// off; docs/ADAPTIVE_HITBOXES.md).
    pub adaptive_levels: Option<u8>,
    /// The scene's pinned instances (terrain) culled like any other
    /// ([`LipacConfig::honour_pins`] false): a trailing `!`.
    pub unpinned: bool,
    /// Frames a warm start's activations are held without hits
    /// ([`LipacConfig::warm_start_hold`]; `None`: the sweep's
    /// [`SweepConfig::warm_start_hold`]).
    pub warm_start_hold: Option<u32>,
    /// How this setting starts (`None`: the sweep's
    /// [`SweepConfig::lipac_start`]).
    pub start: Option<LipacStart>,
}

/// A decayed-rule variant from
/// `RULE[@CELL][%LEVELS][~HOLD][^START][+DIST/SIZE[/RADIUS]][!]`: `RULE` as
/// [`parse_decayed_spec`] reads it, then optionally `@` and a hitbox cell
/// size in metres, then optionally `%` and the merge levels of adaptive
/// hitboxes (0..=[`MAX_MERGE_LEVELS`]), then optionally `~` and the frames
/// a warm start is held ([`DecayedVariant::warm_start_hold`]), then
/// optionally `^` and how it starts (`off`, or a warm start's
/// `DIST/SIZE[/RADIUS]`: [`DecayedVariant::start`]), then
/// optionally `+` and a latency-mitigation heuristic (maximum distance in
/// metres / minimum projected size / optional surround radius in metres),
/// then optionally `!`: the scene's pinned instances (terrain) culled like
/// any other ([`DecayedVariant::unpinned`]).
///
/// ```
/// use lipac_sim::compare::LipacStart;
/// use lipac_sim::sweep::parse_decayed_variant;
/// use lipac_sim::strategy::lipac::LipacConfig;
/// let base = LipacConfig::DEFAULT_DECAYED;
/// let v = parse_decayed_variant("1:5/1:5/1@128+100/0.05", &base).unwrap();
/// assert_eq!((v.settings.rise_shift, v.settings.activate), (Some(1), 5.0));
/// assert_eq!(v.cell_size, Some(128.0));
/// let h = v.latency.unwrap();
/// assert_eq!((h.max_distance, h.min_projected_size), (100.0, 0.05));
/// let plain = parse_decayed_variant("2", &base).unwrap();
/// assert_eq!((plain.cell_size, plain.latency, plain.adaptive_levels), (None, None, None));
/// let merged = parse_decayed_variant("1:5/1:5/1@32%3", &base).unwrap();
/// assert_eq!((merged.cell_size, merged.adaptive_levels), (Some(32.0), Some(3)));
/// assert!(!merged.unpinned);
/// let free = parse_decayed_variant("-:2400/480:2400/480%3!", &base).unwrap();
/// assert_eq!((free.adaptive_levels, free.unpinned), (Some(3), true));
/// let held = parse_decayed_variant("1@256~14+100/0.05", &base).unwrap();
/// assert_eq!((held.cell_size, held.warm_start_hold), (Some(256.0), Some(14)));
/// assert_eq!(plain.warm_start_hold, None);
/// assert!(parse_decayed_variant("1~-1", &base).is_err());
/// let cold = parse_decayed_variant("-:600/120:600/120@64%4^off!", &base).unwrap();
/// assert_eq!((cold.start, cold.unpinned), (Some(LipacStart::Cold), true));
/// let near = parse_decayed_variant("1~8^inf/0/200", &base).unwrap();
/// let Some(LipacStart::Warm(h)) = near.start else { panic!() };
/// assert_eq!((near.warm_start_hold, h.surround_radius), (Some(8), 200.0));
/// assert!(parse_decayed_variant("1^", &base).is_err());
/// assert!(parse_decayed_variant("1^on", &base).is_err());
/// assert!(parse_decayed_variant("1~x", &base).is_err());
/// assert!(parse_decayed_variant("1!%3", &base).is_err());
/// assert!(parse_decayed_variant("1%9", &base).is_err());
/// assert!(parse_decayed_variant("1@-3", &base).is_err());
/// assert!(parse_decayed_variant("1+100", &base).is_err());
/// assert!(parse_decayed_variant("1+100/NaN", &base).is_err());
/// ```
pub fn parse_decayed_variant(spec: &str, base: &DecayedSettings) -> Result<DecayedVariant, String> {
    let (rest, unpinned) = match spec.strip_suffix('!') {
        Some(rest) => (rest, true),
        None => (spec, false),
    };
    let (rest, latency) = match rest.split_once('+') {
        Some((rest, h)) => {
            let heuristic = crate::heuristic_arg::parse_heuristic(h, '/')
                .map_err(|e| format!("decayed variant `{spec}`: latency mitigation {e}"))?;
            (rest, Some(heuristic))
        }
        None => (rest, None),
    };
    let (rest, start) = match rest.split_once('^') {
        Some((rest, s)) => {
            let start = LipacStart::parse_with(s, '/')
                .map_err(|e| format!("decayed variant `{spec}`: {e}"))?;
            (rest, Some(start))
        }
        None => (rest, None),
    };
    let (rest, warm_start_hold) = optional_suffix(
        spec,
        rest,
        '~',
        "warm-start hold",
        |_: &u32| true,
        "is not a frame count",
    )?;
    let levels_ok = |l: &u8| *l <= MAX_MERGE_LEVELS;
    let levels_are = format!("are not 0..={MAX_MERGE_LEVELS}");
    let (rest, adaptive_levels) =
        optional_suffix(spec, rest, '%', "merge levels", levels_ok, &levels_are)?;
    let cell_ok = |c: &f64| c.is_finite() && *c > 0.0;
    let (rule, cell_size) = optional_suffix(
        spec,
        rest,
        '@',
        "cell size",
        cell_ok,
        "is not a positive number",
    )?;
    Ok(DecayedVariant {
        settings: parse_decayed_spec(rule, base)?,
        cell_size,
        latency,
        adaptive_levels,
        unpinned,
        warm_start_hold,
        start,
    })
}

/// A latency-mitigation heuristic in a configuration's name: ` D m / S`,
/// then ` / R m around` for a surround radius.
fn latency_words(h: &ActivationHeuristic) -> String {
    let mut s = format!(" {} m / {}", h.max_distance, h.min_projected_size);
    if h.surround_radius > 0.0 {
        s.push_str(&format!(" / {} m around", h.surround_radius));
    }
    s
}

/// What a LiPaC configuration's name says of its start: nothing for the
/// configured one.
fn start_name(start: LipacStart) -> String {
    match start {
        LipacStart::Default => String::new(),
        LipacStart::Cold => " + cold start".into(),
        LipacStart::Warm(h) => format!(
            " + warm start {}:{}:{}",
            h.max_distance, h.min_projected_size, h.surround_radius
        ),
    }
}

/// `text` split at `sep` into the rest and a value (`None` without
/// `sep`) that parses as `T` and passes `valid`; otherwise the error
/// "decayed variant `spec`: WHAT `value` EXPECTED".
fn optional_suffix<'a, T: std::str::FromStr>(
    spec: &str,
    text: &'a str,
    sep: char,
    what: &str,
    valid: impl Fn(&T) -> bool,
    expected: &str,
) -> Result<(&'a str, Option<T>), String> {
    let Some((rest, value)) = text.split_once(sep) else {
        return Ok((text, None));
    };
    let v = value
        .trim()
        .parse::<T>()
        .ok()
        .filter(|v| valid(v))
        .ok_or_else(|| format!("decayed variant `{spec}`: {what} `{value}` {expected}"))?;
    Ok((rest, Some(v)))
}

impl SweepConfig {
    /// The names of what is swept, in order: the scenes', or `trace FILE`
    /// for [`SweepConfig::trace`].
    pub fn scene_names(&self) -> Vec<String> {
        match &self.trace {
            Some(path) => vec![format!(
                "trace {}",
                path.file_name()
                    .unwrap_or(path.as_os_str())
                    .to_string_lossy()
            )],
            None => self.scenes.iter().map(|s| s.name().to_string()).collect(),
        }
    }

    /// Camera rays per frame.
    pub fn rays_per_frame(&self) -> u64 {
        u64::from(self.width) * u64::from(self.height)
    }

    /// The variants, in report order, and the names of variants dropped as
    /// duplicates of an earlier one (same strategy, same settings).
    pub fn variants(&self) -> Result<(Vec<Variant>, Vec<String>), SimError> {
        let rays = self.rays_per_frame();
        if rays == 0 {
            return Err(SimError::BadConfig("image size must be positive"));
        }
        let mut base = LipacConfig {
            warm_start_at_cuts: self.warm_start_at_cuts,
            ..LipacConfig::for_rays_per_frame(rays)?.with_memory(self.device.memory_model())
        };
        if let Some(frames) = self.warm_start_hold {
            base.warm_start_hold = frames;
        }
        self.lipac_start.apply(&mut base);
        let mut all = Vec::new();
        for &k in &self.baselines {
            if matches!(k, StrategyKind::Lipac | StrategyKind::LipacLatency) {
                return Err(SimError::BadConfig(
                    "LiPaC is swept by factors, not as a baseline",
                ));
            }
            all.push(Variant {
                name: k.name().to_string(),
                family: Family::Baseline,
                kind: k,
                lipac: None,
                factor: None,
                hindsight: (k == StrategyKind::Hindsight).then_some(Hindsight::DEFAULT_FRAMES),
            });
        }
        for &frames in &self.hindsight {
            if frames == 0 {
                return Err(SimError::BadConfig(
                    "hindsight windows must be at least one frame",
                ));
            }
            all.push(Variant {
                name: format!("{} {frames}", StrategyKind::Hindsight.name()),
                family: Family::Baseline,
                kind: StrategyKind::Hindsight,
                lipac: None,
                factor: None,
                hindsight: Some(frames),
            });
        }
        let lipac = |name: String, family, kind, config: LipacConfig, factor| Variant {
            name,
            family,
            kind,
            lipac: Some(config),
            factor: Some(factor),
            hindsight: None,
        };
        for &f in &self.factors {
            // The paper's thresholds scaled as ever; the default decision
            // rule's rates scaled by the same factor.
            let mut thresholds = scaled_thresholds(rays, f)?;
            if let DecisionRule::Decayed(r) = base.thresholds.rule {
                thresholds.rule = DecisionRule::Decayed(r.scaled(f).map_err(SimError::core)?);
            }
            let c = LipacConfig {
                thresholds,
                ..base.clone()
            };
            all.push(lipac(
                format!("lipac {}", fmt_factor(f)),
                Family::Thresholds,
                StrategyKind::Lipac,
                c,
                f,
            ));
        }
        for (i, h) in self.latency.iter().enumerate() {
            let c = LipacConfig {
                latency: Some(*h),
                ..base.clone()
            };
            let name = if i == 0 && *h == ActivationHeuristic::default() {
                "lipac-latency".to_string()
            } else {
                format!("lipac-latency{}", latency_words(h))
            };
            all.push(lipac(
                name,
                Family::Latency,
                StrategyKind::LipacLatency,
                c,
                1.0,
            ));
        }
        for &cell in &self.cell_sizes {
            check_cell_size(cell)?;
            let c = LipacConfig {
                cell_size: cell,
                ..base.clone()
            };
            all.push(lipac(
                format!("lipac {cell} m cells"),
                Family::CellSize,
                StrategyKind::Lipac,
                c,
                1.0,
            ));
        }
        for &(n_a, n_d) in &self.streaks {
            let thresholds = Thresholds {
                n_a,
                n_d,
                ..base.thresholds
            };
            thresholds.validate().map_err(SimError::core)?;
            let c = LipacConfig {
                thresholds,
                ..base.clone()
            };
            all.push(lipac(
                format!("lipac n_a {n_a} n_d {n_d}"),
                Family::Streaks,
                StrategyKind::Lipac,
                c,
                1.0,
            ));
        }
        // Variants (by index in `all`) that set their own hold or start.
        let (mut own_hold, mut own_start) = (Vec::new(), Vec::new());
        for d in &self.decayed {
            let mut c = base.clone().with_decayed_rule(&d.settings, rays)?;
            let mut name = decayed_name(&d.settings);
            if let Some(cell) = d.cell_size {
                check_cell_size(cell)?;
                c.cell_size = cell;
                name.push_str(&format!(" {cell} m cells"));
            }
            if let Some(levels) = d.adaptive_levels {
                c = c.with_adaptive_hitboxes(levels);
                name.push_str(&format!(" merged {levels}"));
            }
            if d.unpinned {
                c.honour_pins = false;
                name.push_str(" unpinned");
            }
            if let Some(frames) = d.warm_start_hold {
                c.warm_start_hold = frames;
                name.push_str(&format!(" held {frames}"));
                own_hold.push(all.len());
            }
            if let Some(start) = d.start {
                start.apply(&mut c);
                name.push_str(&start_name(start));
                own_start.push(all.len());
            }
            let mut kind = StrategyKind::Lipac;
            if let Some(h) = d.latency {
                c.latency = Some(h);
                kind = StrategyKind::LipacLatency;
                name.push_str(&format!(" + latency{}", latency_words(&h)));
            }
            all.push(lipac(name, Family::Decayed, kind, c, 1.0));
        }
        // Said in every LiPaC name, so the report says it too.
        for (i, v) in all
            .iter_mut()
            .enumerate()
            .filter(|(_, v)| v.lipac.is_some())
        {
            if !own_start.contains(&i) {
                v.name.push_str(&start_name(self.lipac_start));
            }
            if self.warm_start_at_cuts {
                v.name.push_str(" + warm start at cuts");
            }
            match self.warm_start_hold {
                Some(frames) if !own_hold.contains(&i) => {
                    v.name.push_str(&format!(" held {frames}"));
                }
                _ => {}
            }
        }
        let mut kept: Vec<Variant> = Vec::new();
        let mut skipped = Vec::new();
        for v in all {
            if kept
                .iter()
                .any(|k| k.kind == v.kind && k.lipac == v.lipac && k.hindsight == v.hindsight)
            {
                skipped.push(v.name);
            } else if kept.iter().any(|k| k.name == v.name) {
                return Err(SimError::BadConfig("two sweep variants share a name"));
            } else {
                kept.push(v);
            }
        }
        if kept.is_empty() {
            return Err(SimError::BadConfig("nothing to sweep"));
        }
        Ok((kept, skipped))
    }
}

/// A swept hitbox cell size must be finite and positive.
fn check_cell_size(cell: f64) -> Result<(), SimError> {
    if cell.is_finite() && cell > 0.0 {
        Ok(())
    } else {
        Err(SimError::BadConfig(
            "cell sizes must be finite and positive",
        ))
    }
}

pub(super) fn make_contender(
    v: &Variant,
    scene: &Scene,
    base: &LipacConfig,
) -> Result<Contender, SimError> {
    let strategy = match (&v.lipac, v.hindsight) {
        (Some(c), _) => Box::new(Lipac::new(scene, c.clone())?) as _,
        (None, Some(frames)) => Box::new(Hindsight::with_memory(scene, frames, &base.memory)?) as _,
        (None, None) => make_strategy(v.kind, scene, base)?,
    };
    Ok(Contender {
        name: v.name.clone(),
        strategy,
    })
}
