//! One probe's sections: `[cantilever]` (its force model, optional) and `[tracker]` with
//! its `[tracker.calibration]`. A lab file gives them once, at the top level, for one
//! probe, or once per `[[probe]]` entry for several probes in one SEM view (each entry
//! named, its keys then spelt `probe[i].cantilever.length_um` in messages).

use std::path::Path;

use serde::Deserialize;

use crate::checks::{Checker, ConfigError, List, Range};
use crate::hw::config::RawDevice;
use crate::model::Cantilever;
use crate::sim::config::{RawSimProbe, SimProbe};
use crate::vision::{
    CalibrationConfig, PixelOrigin, ScaleRange, Threshold, TrackerConfig, DEFAULT_WINDOW_DEG,
    MAX_EDGES, MAX_EDGE_BIAS_PX, PYRAMID_EDGES,
};
pub use crate::vision::{MAX_PROBES, SINGLE_NAME};

// The accepted ranges of `[cantilever]` and `[tracker]`, documented with the same words
// in config/probe.example.toml. The cantilever's span what AFM cantilevers are made as:
// from short high-frequency levers (10 um) to the longest soft ones (under 1 mm), from
// the softest contact-mode levers (0.001 N/m) to diamond-like indentation ones (1000
// N/m), of polymers (about 2 GPa) to diamond (about 1000 GPa).
const LENGTH_UM: Range = Range::new(10.0, 1000.0, "um");
const SPRING_CONSTANT_N_PER_M: Range = Range::new(0.001, 1000.0, "N/m");
const YOUNGS_MODULUS_GPA: Range = Range::new(1.0, 1000.0, "GPa");
const WIDTH_UM: Range = Range::new(1.0, 200.0, "um");
const THICKNESS_UM: Range = Range::new(0.1, 20.0, "um");
/// Wider than 45 degrees the search windows of neighbouring edges overlap; narrower than
/// 1 degree no deflection fits in the window.
pub const WINDOW_DEG: Range = Range::new(1.0, 45.0, "deg");
const EDGE_BIAS_PX: Range = Range::new(-MAX_EDGE_BIAS_PX, MAX_EDGE_BIAS_PX, "px");
/// `tracker.scale_range`'s bounds: frame pixels per reference pixel, the widest any
/// probe's search covers.
const SCALE: Range = Range::new(0.05, 12.0, "");
/// A click lies in a frame, and a frame is at most 16384 pixels wide (`frames.width`).
const CLICK_PX: Range = Range::new(-0.5, 16384.0, "px");
/// Longest probe name, characters (it names files: `out.<name>.csv`).
const MAX_NAME_CHARS: usize = 32;

/// One validated probe: what tracks it and, for a cantilever, what turns its bending
/// into a force.
#[derive(Debug, Clone, PartialEq)]
pub struct ProbeConfig {
    /// `[[probe]] name`; a single probe given at the top level is named [`SINGLE_NAME`].
    pub name: String,
    /// None: a probe without a force model (a tungsten needle, a gripper jaw), tracked
    /// for its pose only: its estimates carry no force, and `run` refuses it.
    pub cantilever: Option<Cantilever>,
    pub tracker: TrackerConfig,
    /// The haptic device feels it (and drives its positioner) when it is the probe
    /// switched to: a probe with a cantilever, unless `felt = false`.
    pub felt: bool,
    /// `pressing_force_sign` of the entry: the sign of its tracked force while it
    /// presses (a probe entering the view from the other side bends the other way on
    /// screen); None: `[teleop]`'s.
    pub pressing_force_sign: Option<f64>,
    /// Where the simulated lab shows it and starts its positioner.
    pub sim: SimProbe,
    /// How its keys are spelt in messages: empty at the top level, `probe[i].` for
    /// entry i.
    prefix: String,
}

impl ProbeConfig {
    /// The full name of this probe's `key` (`tracker.calibration` is
    /// `probe[1].tracker.calibration` for entry 1), as messages give it.
    pub fn key(&self, key: &str) -> String {
        format!("{}{key}", self.prefix)
    }
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct RawCantilever {
    length_um: Option<f64>,
    spring_constant_n_per_m: Option<f64>,
    youngs_modulus_gpa: Option<f64>,
    width_um: Option<f64>,
    thickness_um: Option<f64>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct RawTracker {
    threshold: Option<toml::Value>,
    window_deg: Option<f64>,
    pixel_origin: Option<String>,
    edge_bias_px: Option<f64>,
    scale_range: Option<List<f64, 2>>,
    calibration: Option<RawCalibration>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawCalibration {
    reference_image: String,
    /// Each click `[x, y]`; read as a list so that a third coordinate is refused
    /// rather than silently dropped. The AFM pyramid's shorthand.
    red: Option<Vec<Vec<f64>>>,
    blue: Option<Vec<Vec<f64>>>,
    green: Option<Vec<Vec<f64>>>,
    /// Any probe: `[tracker.calibration.edges]`, name = clicks, in the file's order,
    /// and the two edges meeting at the tip point.
    edges: Option<toml::Table>,
    apex: Option<Vec<String>>,
}

/// One `[[probe]]` entry.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct RawProbe {
    name: Option<String>,
    cantilever: Option<RawCantilever>,
    tracker: Option<RawTracker>,
    /// Its positioner's DAQ outputs, read as `[daq]` is.
    daq: Option<RawDevice>,
    felt: Option<bool>,
    pressing_force_sign: Option<f64>,
    sim: Option<RawSimProbe>,
}

/// The probes of a file and, for each in order, the DAQ section of its positioner with
/// the name messages give it.
pub(super) struct Probes {
    pub probes: Vec<ProbeConfig>,
    pub positioners: Vec<(String, RawDevice)>,
}

/// The probes of a file: its top-level `[cantilever]`, `[tracker]` and `[daq]` (one
/// probe) or its `[[probe]]` entries (one to [`MAX_PROBES`], each named, the names
/// unique, each with its own `[probe.daq]`), not both.
pub(super) fn probes(
    check: &Checker,
    cantilever: Option<RawCantilever>,
    tracker: Option<RawTracker>,
    daq: Option<RawDevice>,
    entries: Option<Vec<RawProbe>>,
) -> Result<Probes, ConfigError> {
    let Some(entries) = entries else {
        let single = Section {
            check,
            prefix: String::new(),
        };
        let raw = RawProbe {
            name: None,
            cantilever,
            tracker,
            daq: None,
            felt: None,
            pressing_force_sign: None,
            sim: None,
        };
        return Ok(Probes {
            probes: vec![single.probe(SINGLE_NAME.to_string(), raw, (0, 1))?],
            positioners: vec![("daq".into(), daq.unwrap_or_default())],
        });
    };
    if cantilever.is_some() || tracker.is_some() {
        return Err(check.inconsistent(
            "give one probe as [cantilever] and [tracker], or several as [[probe]] entries \
             (each with its own cantilever and tracker), not both"
                .into(),
        ));
    }
    if daq.is_some() {
        return Err(check.inconsistent(
            "[daq] drives the positioner of a lone probe: with [[probe]] entries, give each \
             probe's positioner as its [probe.daq] (the simulated stage when left out)"
                .into(),
        ));
    }
    if entries.is_empty() || entries.len() > MAX_PROBES {
        return Err(check.invalid(
            "probe",
            format_args!("{} entries", entries.len()),
            &format!("needs 1 to {MAX_PROBES} [[probe]] entries (an S100 carries up to four positioners)"),
        ));
    }
    let count = entries.len();
    let mut probes: Vec<ProbeConfig> = Vec::with_capacity(count);
    let mut positioners = Vec::with_capacity(count);
    for (i, mut raw) in entries.into_iter().enumerate() {
        let section = Section {
            check,
            prefix: format!("probe[{i}]."),
        };
        let name = section.name(raw.name.take())?;
        if probes.iter().any(|p| p.name == name) {
            return Err(check.invalid(
                &section.key("name"),
                format_args!("{name:?}"),
                "must differ from every earlier probe's name",
            ));
        }
        positioners.push((section.key("daq"), raw.daq.take().unwrap_or_default()));
        probes.push(section.probe(name, raw, (i, count))?);
    }
    Ok(Probes {
        probes,
        positioners,
    })
}

/// The sections of one probe, its keys spelt with `prefix`.
struct Section<'a> {
    check: &'a Checker<'a>,
    prefix: String,
}

impl Section<'_> {
    fn key(&self, key: &str) -> String {
        format!("{}{key}", self.prefix)
    }

    fn number(&self, key: &str, value: f64, range: Range) -> Result<f64, ConfigError> {
        self.check.number(&self.key(key), value, range)
    }

    fn invalid(&self, key: &str, value: impl std::fmt::Display, reason: &str) -> ConfigError {
        self.check.invalid(&self.key(key), value, reason)
    }

    /// A probe's name: it names files (`out.<name>.csv`), so letters, digits, `-` and
    /// `_`, at most [`MAX_NAME_CHARS`].
    fn name(&self, raw: Option<String>) -> Result<String, ConfigError> {
        let Some(name) = raw else {
            return Err(self.check.inconsistent(format!(
                "missing {} (each [[probe]] is named: it names its results file)",
                self.key("name")
            )));
        };
        let fits = !name.is_empty()
            && name.chars().count() <= MAX_NAME_CHARS
            && name
                .chars()
                .all(|c| c.is_ascii_alphanumeric() || c == '-' || c == '_');
        if !fits {
            return Err(self.invalid(
                "name",
                format_args!("{name:?}"),
                &format!(
                    "must be 1 to {MAX_NAME_CHARS} letters, digits, '-' or '_' (it names \
                     the probe's results file)"
                ),
            ));
        }
        Ok(name)
    }

    /// Probe `k` of `count`.
    fn probe(
        &self,
        name: String,
        raw: RawProbe,
        (k, count): (usize, usize),
    ) -> Result<ProbeConfig, ConfigError> {
        let cantilever = raw.cantilever.map(|c| self.cantilever(c)).transpose()?;
        let tracker = match raw.tracker {
            Some(t) => self.tracker(t)?,
            None => TrackerConfig::default(),
        };
        let felt = match (raw.felt, cantilever) {
            (Some(true), None) => {
                return Err(self.invalid(
                    "felt",
                    true,
                    "needs the probe's [cantilever]: without one it has no force to feel",
                ))
            }
            (felt, cantilever) => felt.unwrap_or(cantilever.is_some()),
        };
        let pressing_force_sign = match raw.pressing_force_sign {
            None => None,
            Some(s) if s == 1.0 || s == -1.0 => Some(s),
            Some(s) => return Err(self.invalid("pressing_force_sign", s, "must be 1 or -1")),
        };
        let sim = SimProbe::validate(raw.sim, &self.prefix, k, count, self.check)?;
        if let (Some(tool), Some(_)) = (sim.tool, cantilever) {
            return Err(self.invalid(
                "sim.tool",
                format_args!("{:?}", tool.name()),
                "must not be given with a [cantilever]: a rigid tool is drawn without one",
            ));
        }
        Ok(ProbeConfig {
            name,
            cantilever,
            tracker,
            felt,
            pressing_force_sign,
            sim,
            prefix: self.prefix.clone(),
        })
    }
    fn cantilever(&self, raw: RawCantilever) -> Result<Cantilever, ConfigError> {
        let length_um = match raw.length_um {
            Some(v) => self.number("cantilever.length_um", v, LENGTH_UM)?,
            None => {
                return Err(self
                    .check
                    .inconsistent(format!("missing {}", self.key("cantilever.length_um"))))
            }
        };
        let section = [raw.youngs_modulus_gpa, raw.width_um, raw.thickness_um];
        let any_section = section.iter().any(Option::is_some);
        let flexural_rigidity_n_m2 = match (raw.spring_constant_n_per_m, any_section) {
            (Some(_), true) => {
                return Err(self.check.inconsistent(format!(
                    "{}: give either spring_constant_n_per_m or \
                     youngs_modulus_gpa + width_um + thickness_um, not both",
                    self.key("cantilever")
                )))
            }
            (None, false) => {
                return Err(self.check.inconsistent(format!(
                    "{}: missing stiffness: give spring_constant_n_per_m, or \
                     youngs_modulus_gpa + width_um + thickness_um",
                    self.key("cantilever")
                )))
            }
            (Some(k), false) => {
                let k = self.number(
                    "cantilever.spring_constant_n_per_m",
                    k,
                    SPRING_CONSTANT_N_PER_M,
                )?;
                Cantilever::rigidity_from_spring_constant(k, length_um)
            }
            (None, true) => {
                let keys = [
                    ("cantilever.youngs_modulus_gpa", YOUNGS_MODULUS_GPA),
                    ("cantilever.width_um", WIDTH_UM),
                    ("cantilever.thickness_um", THICKNESS_UM),
                ];
                let mut values = [0.0; 3];
                for ((slot, value), (name, range)) in values.iter_mut().zip(section).zip(keys) {
                    *slot = match value {
                        Some(v) => self.number(name, v, range)?,
                        None => {
                            return Err(self.check.inconsistent(format!(
                                "missing {} (the cross-section needs youngs_modulus_gpa, \
                                 width_um and thickness_um)",
                                self.key(name)
                            )))
                        }
                    };
                }
                Cantilever::rigidity_from_section(values[0], values[1], values[2])
            }
        };
        Ok(Cantilever::new(length_um, flexural_rigidity_n_m2))
    }

    fn tracker(&self, raw: RawTracker) -> Result<TrackerConfig, ConfigError> {
        let threshold = match raw.threshold {
            None => Threshold::Otsu,
            Some(toml::Value::String(s)) if s.eq_ignore_ascii_case("otsu") => Threshold::Otsu,
            Some(toml::Value::Integer(level)) => match u8::try_from(level) {
                Ok(level) => Threshold::Level(level),
                Err(_) => {
                    return Err(self.invalid(
                        "tracker.threshold",
                        level,
                        "must be a grey level 0..=255 or \"otsu\"",
                    ))
                }
            },
            Some(other) => {
                return Err(self.invalid(
                    "tracker.threshold",
                    other,
                    "must be a grey level 0..=255 or \"otsu\"",
                ))
            }
        };
        let window_deg = self.check.number_or(
            &self.key("tracker.window_deg"),
            raw.window_deg,
            DEFAULT_WINDOW_DEG,
            WINDOW_DEG,
        )?;
        let pixel_origin = match raw.pixel_origin {
            None => PixelOrigin::Centre,
            Some(text) => PixelOrigin::parse(&text).ok_or_else(|| {
                self.invalid(
                    "tracker.pixel_origin",
                    format_args!("{text:?}"),
                    "must be \"centre\" (the default: the top-left pixel's centre is 0, 0) or \
                     \"corner\" (its top-left corner is)",
                )
            })?,
        };
        let edge_bias_px = self.check.number_or(
            &self.key("tracker.edge_bias_px"),
            raw.edge_bias_px,
            0.0,
            EDGE_BIAS_PX,
        )?;
        let scale_range = raw
            .scale_range
            .map(|List([lo, hi])| self.scale_range(lo, hi))
            .transpose()?;
        let calibration = raw
            .calibration
            .map(|c| self.calibration(c, pixel_origin))
            .transpose()?;
        Ok(TrackerConfig {
            threshold,
            window_deg,
            pixel_origin,
            edge_bias_px,
            scale_range,
            calibration,
        })
    }

    /// `tracker.scale_range`: two scales in [`SCALE`], the first below the second.
    fn scale_range(&self, lo: f64, hi: f64) -> Result<ScaleRange, ConfigError> {
        let key = self.key("tracker.scale_range");
        self.check.number(&format!("{key}[0]"), lo, SCALE)?;
        self.check.number(&format!("{key}[1]"), hi, SCALE)?;
        if lo >= hi {
            return Err(self.invalid(
                "tracker.scale_range",
                ScaleRange::new(lo, hi),
                "must run upward: [smallest, largest] scale",
            ));
        }
        Ok(ScaleRange::new(lo, hi))
    }

    fn calibration(
        &self,
        raw: RawCalibration,
        origin: PixelOrigin,
    ) -> Result<CalibrationConfig, ConfigError> {
        if raw.reference_image.trim().is_empty() {
            return Err(self.invalid(
                "tracker.calibration.reference_image",
                "\"\"",
                "must name an image file",
            ));
        }
        let base = self.check.file.parent().unwrap_or(Path::new(""));
        let reference_image = base.join(raw.reference_image);
        let section = self.key("tracker.calibration");
        let shorthand = [raw.red, raw.blue, raw.green];
        let config = match raw.edges {
            None => {
                if raw.apex.is_some() {
                    return Err(self.check.inconsistent(format!(
                        "{section}.apex names the edges of [{section}.edges], which is not \
                         given (the pyramid's red, blue and green need no apex)"
                    )));
                }
                let [red, blue, green] = match shorthand {
                    [Some(r), Some(b), Some(g)] => [r, b, g],
                    missing => {
                        let name = PYRAMID_EDGES
                            .iter()
                            .zip(&missing)
                            .find(|(_, m)| m.is_none())
                            .map_or("red", |(n, _)| n);
                        return Err(self.check.inconsistent(format!(
                            "missing {section}.{name}: give the AFM pyramid's red, blue and \
                             green clicks, or name any probe's edges in [{section}.edges] \
                             with its apex"
                        )));
                    }
                };
                CalibrationConfig::pyramid(
                    reference_image,
                    self.clicks("red", red)?,
                    self.clicks("blue", blue)?,
                    self.clicks("green", green)?,
                )
            }
            Some(table) => {
                if shorthand.iter().any(Option::is_some) {
                    return Err(self.check.inconsistent(format!(
                        "{section}: give the edges either as red, blue and green or in \
                         [{section}.edges], not both"
                    )));
                }
                self.named_edges(reference_image, table, raw.apex)?
            }
        };
        Ok(config.counted_from(origin))
    }

    /// `[tracker.calibration.edges]` and `apex`: two to [`MAX_EDGES`] edges, each
    /// named and clicked, and the two of them meeting at the tip point. Edges named
    /// red, blue and green without an apex are the AFM pyramid's.
    fn named_edges(
        &self,
        reference_image: std::path::PathBuf,
        table: toml::Table,
        apex: Option<Vec<String>>,
    ) -> Result<CalibrationConfig, ConfigError> {
        let key = self.key("tracker.calibration.edges");
        if !(2..=MAX_EDGES).contains(&table.len()) {
            return Err(self.check.invalid(
                &key,
                format_args!("{} edge(s)", table.len()),
                &format!("needs 2 to {MAX_EDGES} named edges"),
            ));
        }
        let mut edges = Vec::with_capacity(table.len());
        for (name, value) in table {
            let valid = !name.is_empty()
                && name.len() <= MAX_NAME_CHARS
                && name
                    .chars()
                    .all(|c| c.is_ascii_alphanumeric() || c == '_' || c == '-');
            if !valid {
                return Err(self.check.invalid(
                    &key,
                    format_args!("{name:?}"),
                    &format!(
                        "edge names are 1 to {MAX_NAME_CHARS} letters, digits, '_' or '-' \
                         (they name refusals: edge-missing-<name>)"
                    ),
                ));
            }
            let raw: Vec<Vec<f64>> = value.try_into().map_err(|_| {
                self.check.invalid(
                    &format!("{key}.{name}"),
                    "this value",
                    "must be a list of clicked pixels [[x, y], ...]",
                )
            })?;
            let points = self.clicks(&format!("edges.{name}"), raw)?;
            edges.push((name, points));
        }
        let names: Vec<&str> = edges.iter().map(|(n, _)| n.as_str()).collect();
        let pyramid =
            names.len() == PYRAMID_EDGES.len() && PYRAMID_EDGES.iter().all(|n| names.contains(n));
        let apex_key = self.key("tracker.calibration.apex");
        let apex = match apex {
            None if pyramid => None,
            None => {
                return Err(self.check.inconsistent(format!(
                    "missing {apex_key}: name the two edges of [{key}] that meet at the \
                     probe's tip point, e.g. apex = [\"{}\", \"{}\"]",
                    names[0], names[1]
                )))
            }
            Some(apex) => {
                let pair: [String; 2] = apex.clone().try_into().map_err(|_| {
                    self.check
                        .invalid(&apex_key, format_args!("{apex:?}"), "must name two edges")
                })?;
                if let Some(unknown) = pair.iter().find(|a| !names.contains(&a.as_str())) {
                    return Err(self.check.invalid(
                        &apex_key,
                        format_args!("{apex:?}"),
                        &format!(
                            "names {unknown:?}, which is not one of the edges ({})",
                            names.join(", ")
                        ),
                    ));
                }
                if pair[0] == pair[1] {
                    return Err(self.check.invalid(
                        &apex_key,
                        format_args!("{apex:?}"),
                        "must name two different edges",
                    ));
                }
                Some(pair)
            }
        };
        if pyramid && apex.is_none() {
            // The shorthand, in the pyramid's order.
            let take = |n: &str| {
                edges
                    .iter()
                    .find(|(e, _)| e == n)
                    .map(|(_, p)| p.clone())
                    .unwrap_or_default()
            };
            return Ok(CalibrationConfig::pyramid(
                reference_image,
                take("red"),
                take("blue"),
                take("green"),
            ));
        }
        Ok(CalibrationConfig {
            reference_image,
            edges,
            apex,
        })
    }

    /// The clicks on one edge: two or more pixels `[x, y]`, at least 2 px apart.
    fn clicks(&self, name: &str, raw: Vec<Vec<f64>>) -> Result<Vec<[f64; 2]>, ConfigError> {
        let key = self.key(&format!("tracker.calibration.{name}"));
        if raw.len() < 2 {
            return Err(self.check.invalid(
                &key,
                format_args!("{} point(s)", raw.len()),
                "needs at least two clicked pixels",
            ));
        }
        let mut points = Vec::with_capacity(raw.len());
        for (i, p) in raw.iter().enumerate() {
            let key = format!("{key}[{i}]");
            let &[x, y] = p.as_slice() else {
                return Err(self.check.invalid(
                    &key,
                    format_args!("{p:?}"),
                    "must be one pixel [x, y] (two numbers)",
                ));
            };
            points.push([
                self.check.number(&format!("{key}[0]"), x, CLICK_PX)?,
                self.check.number(&format!("{key}[1]"), y, CLICK_PX)?,
            ]);
        }
        let spread = points
            .iter()
            .map(|p| (p[0] - points[0][0]).hypot(p[1] - points[0][1]))
            .fold(0.0, f64::max);
        if spread < 2.0 {
            return Err(self.check.invalid(
                &key,
                format_args!("{points:?}"),
                "needs points at least 2 px apart to define a direction",
            ));
        }
        Ok(points)
    }
}
