//! Configuration in two steps: serde structs that mirror the TOML file exactly
//! (`deny_unknown_fields`, so a misspelt key is an error, not a silent default), then
//! [`Config::validate`]-style checks that turn them into a [`Config`] whose fields can
//! be trusted (finite, positive, consistent).
//!
//! Every error names the file, the key and the offending value, e.g.
//! `probe.toml: cantilever.length_um must be > 0, got -3`.
//! The documented defaults of every key live in `config/`.

use std::path::{Path, PathBuf};

use serde::Deserialize;

pub mod daemon;
pub mod monitor;
pub mod stream;

use self::daemon::RawDaemon;
pub use self::daemon::{DaemonConfig, LoopOptions};
pub use self::monitor::MonitorConfig;
use self::monitor::RawMonitor;
use self::stream::RawStream;
pub use self::stream::StreamConfig;
pub(crate) use crate::checks::Checker;
pub use crate::checks::{ConfigError, Number, Range, Zero};
use crate::control::{RawSafety, RawTeleop, TeleopGains};
use crate::hw::config::{DevicesConfig, RawDevice};
use crate::model::Cantilever;
use crate::sim::config::{RawSim, SimConfig};
pub use crate::vision::{
    CalibrationConfig, PixelOrigin, Threshold, TrackerConfig, DEFAULT_WINDOW_DEG, MAX_EDGE_BIAS_PX,
};

/// A validated configuration.
#[derive(Debug, Clone, PartialEq)]
pub struct Config {
    /// The file it was read from (used in messages and to resolve relative paths).
    pub path: PathBuf,
    /// None: a probe without a force model (a tungsten needle, a gripper jaw), tracked
    /// for its pose only: its estimates carry no force, and `run` refuses it.
    pub cantilever: Option<Cantilever>,
    pub tracker: TrackerConfig,
    /// `[teleop]` and `[safety]`: the gains SIGHUP may reload.
    pub teleop: TeleopGains,
    /// `[frames]`, `[daq]`, `[haptic]`: which backend drives each device.
    pub devices: DevicesConfig,
    pub daemon: DaemonConfig,
    /// `[monitor]`: the live web page (off by default) and recorded thumbnails.
    pub monitor: MonitorConfig,
    /// `[stream]`: the live data stream over UDP (off by default).
    pub stream: StreamConfig,
    /// `[sim]`: the simulated lab, used by every `"sim"` backend.
    pub sim: SimConfig,
}

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
/// A click lies in a frame, and a frame is at most 16384 pixels wide (`frames.width`).
const CLICK_PX: Range = Range::new(-0.5, 16384.0, "px");

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawConfig {
    cantilever: Option<RawCantilever>,
    tracker: Option<RawTracker>,
    teleop: Option<RawTeleop>,
    safety: Option<RawSafety>,
    frames: Option<RawDevice>,
    daq: Option<RawDevice>,
    haptic: Option<RawDevice>,
    daemon: Option<RawDaemon>,
    monitor: Option<RawMonitor>,
    stream: Option<RawStream>,
    sim: Option<RawSim>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawCantilever {
    length_um: Option<f64>,
    spring_constant_n_per_m: Option<f64>,
    youngs_modulus_gpa: Option<f64>,
    width_um: Option<f64>,
    thickness_um: Option<f64>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawTracker {
    threshold: Option<toml::Value>,
    window_deg: Option<f64>,
    pixel_origin: Option<String>,
    edge_bias_px: Option<f64>,
    calibration: Option<RawCalibration>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawCalibration {
    reference_image: String,
    /// Each click `[x, y]`; read as a list so that a third coordinate is refused
    /// rather than silently dropped.
    red: Vec<Vec<f64>>,
    blue: Vec<Vec<f64>>,
    green: Vec<Vec<f64>>,
}

impl Config {
    /// Reads and validates a configuration file.
    pub fn load(path: &Path) -> Result<Config, ConfigError> {
        let text = std::fs::read_to_string(path).map_err(|source| ConfigError::Read {
            file: path.to_path_buf(),
            source,
        })?;
        Config::from_toml_str(&text, path)
    }

    /// Parses and validates TOML text; `path` names it in messages and anchors relative paths.
    pub fn from_toml_str(text: &str, path: &Path) -> Result<Config, ConfigError> {
        let raw: RawConfig = toml::from_str(text).map_err(|err| ConfigError::Parse {
            file: path.to_path_buf(),
            message: err.to_string().trim_end().to_string(),
        })?;
        let check = Checker { file: path };
        let cantilever = raw
            .cantilever
            .map(|raw| check.cantilever(raw))
            .transpose()?;
        let tracker = match raw.tracker {
            Some(raw) => check.tracker(raw)?,
            None => TrackerConfig::default(),
        };
        let mut teleop = TeleopGains::validate(
            raw.teleop.unwrap_or_default(),
            raw.safety.unwrap_or_default(),
            &check,
        )?;
        if let Some(cantilever) = cantilever {
            teleop.cantilever = cantilever;
        }
        let devices = DevicesConfig::validate(
            raw.frames.unwrap_or_default(),
            raw.daq.unwrap_or_default(),
            raw.haptic.unwrap_or_default(),
            &check,
        )?;
        let daemon = DaemonConfig::validate(raw.daemon.unwrap_or_default(), &check)?;
        let monitor = MonitorConfig::validate(raw.monitor.unwrap_or_default(), &check)?;
        let stream = StreamConfig::validate(raw.stream.unwrap_or_default(), &check)?;
        let sim = SimConfig::validate(raw.sim.unwrap_or_default(), &check)?;
        Ok(Config {
            path: path.to_path_buf(),
            cantilever,
            tracker,
            teleop,
            devices,
            daemon,
            monitor,
            stream,
            sim,
        })
    }
}

impl Checker<'_> {
    fn cantilever(&self, raw: RawCantilever) -> Result<Cantilever, ConfigError> {
        let length_um = match raw.length_um {
            Some(v) => self.number("cantilever.length_um", v, LENGTH_UM)?,
            None => return Err(self.inconsistent("missing cantilever.length_um".into())),
        };
        let section = [raw.youngs_modulus_gpa, raw.width_um, raw.thickness_um];
        let any_section = section.iter().any(Option::is_some);
        let flexural_rigidity_n_m2 = match (raw.spring_constant_n_per_m, any_section) {
            (Some(_), true) => {
                return Err(self.inconsistent(
                    "cantilever: give either spring_constant_n_per_m or \
                     youngs_modulus_gpa + width_um + thickness_um, not both"
                        .into(),
                ))
            }
            (None, false) => {
                return Err(self.inconsistent(
                    "cantilever: missing stiffness: give spring_constant_n_per_m, or \
                     youngs_modulus_gpa + width_um + thickness_um"
                        .into(),
                ))
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
                            return Err(self.inconsistent(format!(
                                "missing {name} (the cross-section needs youngs_modulus_gpa, \
                                 width_um and thickness_um)"
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
        let window_deg = self.number_or(
            "tracker.window_deg",
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
        let edge_bias_px =
            self.number_or("tracker.edge_bias_px", raw.edge_bias_px, 0.0, EDGE_BIAS_PX)?;
        let calibration = raw
            .calibration
            .map(|c| self.calibration(c, pixel_origin))
            .transpose()?;
        Ok(TrackerConfig {
            threshold,
            window_deg,
            pixel_origin,
            edge_bias_px,
            calibration,
        })
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
        let red = self.clicks("red", raw.red)?;
        let blue = self.clicks("blue", raw.blue)?;
        let green = self.clicks("green", raw.green)?;
        let base = self.file.parent().unwrap_or(Path::new(""));
        Ok(CalibrationConfig {
            reference_image: base.join(raw.reference_image),
            red,
            blue,
            green,
        }
        .counted_from(origin))
    }

    /// The clicks on one edge: two or more pixels `[x, y]`, at least 2 px apart.
    fn clicks(&self, name: &str, raw: Vec<Vec<f64>>) -> Result<Vec<[f64; 2]>, ConfigError> {
        let key = format!("tracker.calibration.{name}");
        if raw.len() < 2 {
            return Err(self.invalid(
                &key,
                format_args!("{} point(s)", raw.len()),
                "needs at least two clicked pixels",
            ));
        }
        let mut points = Vec::with_capacity(raw.len());
        for (i, p) in raw.iter().enumerate() {
            let key = format!("{key}[{i}]");
            let &[x, y] = p.as_slice() else {
                return Err(self.invalid(
                    &key,
                    format_args!("{p:?}"),
                    "must be one pixel [x, y] (two numbers)",
                ));
            };
            points.push([
                self.number(&format!("{key}[0]"), x, CLICK_PX)?,
                self.number(&format!("{key}[1]"), y, CLICK_PX)?,
            ]);
        }
        let spread = points
            .iter()
            .map(|p| (p[0] - points[0][0]).hypot(p[1] - points[0][1]))
            .fold(0.0, f64::max);
        if spread < 2.0 {
            return Err(self.invalid(
                &key,
                format_args!("{points:?}"),
                "needs points at least 2 px apart to define a direction",
            ));
        }
        Ok(points)
    }
}

/// Reading a lab file of one cantilever and the sections a test gives, for the tests of
/// the sections other modules own (`[frames]`, `[daq]`, `[haptic]`).
#[cfg(test)]
pub(crate) mod testing {
    use std::path::Path;

    use super::{Config, ConfigError};

    const BASE: &str = "[cantilever]\nlength_um = 400\nspring_constant_n_per_m = 1\n";

    pub(crate) fn parse(sections: &str) -> Result<Config, ConfigError> {
        Config::from_toml_str(&format!("{BASE}{sections}"), Path::new("lab.toml"))
    }

    pub(crate) fn error_of(sections: &str) -> String {
        parse(sections).unwrap_err().to_string()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn parse(text: &str) -> Result<Config, ConfigError> {
        Config::from_toml_str(text, Path::new("probe.toml"))
    }

    const SAMPLE: &str = r#"
[cantilever]
length_um = 434.675
spring_constant_n_per_m = 0.0600

[tracker]
threshold = "otsu"
window_deg = 20.0

[tracker.calibration]
reference_image = "reference.png"
red = [[156.8, 33.4], [228.3, 57.3], [299.9, 81.0]]
blue = [[230.7, 114.2], [245.4, 153.4], [260.6, 192.0]]
green = [[282.5, 199.8], [298.4, 170.9], [314.8, 142.9]]
"#;

    #[test]
    fn sample_config_parses() {
        let cfg = Config::from_toml_str(SAMPLE, Path::new("/data/s/probe.toml")).unwrap();
        let cantilever = cfg.cantilever.unwrap();
        assert_eq!(cantilever.length_um, 434.675);
        let ei = 0.06 * (434.675e-6f64).powi(3) / 3.0;
        assert!((cantilever.flexural_rigidity_n_m2 / ei - 1.0).abs() < 1e-14);
        assert_eq!(cfg.tracker.threshold, Threshold::Otsu);
        let cal = cfg.tracker.calibration.unwrap();
        assert_eq!(cal.reference_image, Path::new("/data/s/reference.png"));
        assert_eq!(cal.green.len(), 3);
    }

    #[test]
    fn integer_threshold_and_integer_stiffness() {
        let cfg = parse(
            "[cantilever]\nlength_um = 383\nspring_constant_n_per_m = 40\n[tracker]\nthreshold = 146\n",
        )
        .unwrap();
        assert_eq!(cfg.tracker.threshold, Threshold::Level(146));
        assert_eq!(cfg.tracker.window_deg, DEFAULT_WINDOW_DEG);
    }

    #[test]
    fn cross_section_stiffness() {
        let cfg = parse(
            "[cantilever]\nlength_um = 450\nyoungs_modulus_gpa = 169\nwidth_um = 50\nthickness_um = 2\n",
        )
        .unwrap();
        let ei = 169e9 * 50e-6 * (2e-6f64).powi(3) / 12.0;
        assert!((cfg.cantilever.unwrap().flexural_rigidity_n_m2 / ei - 1.0).abs() < 1e-14);
    }

    fn error_of(text: &str) -> String {
        parse(text).unwrap_err().to_string()
    }

    #[test]
    fn pixel_origin_and_edge_bias() {
        let cfg = parse(SAMPLE).unwrap();
        assert_eq!(cfg.tracker.pixel_origin, PixelOrigin::Centre);
        assert_eq!(cfg.tracker.edge_bias_px, 0.0);
        let text = SAMPLE.replace(
            "window_deg = 20.0\n",
            "window_deg = 20.0\npixel_origin = \"Corner\"\nedge_bias_px = 0.3\n",
        );
        let cfg = parse(&text).unwrap();
        assert_eq!(cfg.tracker.pixel_origin, PixelOrigin::Corner);
        assert_eq!(cfg.tracker.edge_bias_px, 0.3);
        // Clicks counted from the corner are kept counted from the pixel centre.
        let cal = cfg.tracker.calibration.unwrap();
        assert_eq!(cal.red[0], [156.3, 32.9]);
        assert_eq!(cal.green[2], [314.3, 142.4]);
        assert_eq!(PixelOrigin::Corner.output([1.0, 2.0]), [1.5, 2.5]);
        assert_eq!(PixelOrigin::Centre.output([1.0, 2.0]), [1.0, 2.0]);
        assert_eq!(PixelOrigin::parse("center"), Some(PixelOrigin::Centre));

        let with = |line: &str| {
            error_of(&SAMPLE.replace(
                "window_deg = 20.0\n",
                &format!("window_deg = 20.0\n{line}\n"),
            ))
        };
        let msg = with("pixel_origin = \"top-left\"");
        assert!(
            msg.contains("tracker.pixel_origin")
                && msg.contains("\"top-left\"")
                && msg.contains("corner"),
            "{msg}"
        );
        let msg = with("edge_bias_px = 3.5");
        assert!(
            msg.ends_with("tracker.edge_bias_px = 3.5 is out of range: accepted -2 to 2 px"),
            "{msg}"
        );
        assert!(with("edge_bias_px = nan").contains("tracker.edge_bias_px"));
        assert!(with("pixel_origin = 1").contains("pixel_origin"));
    }

    #[test]
    fn negative_length_names_file_key_and_value() {
        let msg = error_of("[cantilever]\nlength_um = -3\nspring_constant_n_per_m = 1\n");
        assert_eq!(
            msg,
            "probe.toml: cantilever.length_um = -3 is out of range: accepted 10 to 1000 um"
        );
    }

    #[test]
    fn non_finite_values_are_rejected() {
        let msg = error_of("[cantilever]\nlength_um = 400\nspring_constant_n_per_m = nan\n");
        assert!(msg.contains("cantilever.spring_constant_n_per_m"), "{msg}");
        assert!(msg.contains("= nan is out of range"), "{msg}");
        let msg = error_of("[cantilever]\nlength_um = inf\nspring_constant_n_per_m = 1\n");
        assert!(
            msg.contains("cantilever.length_um") && msg.contains("inf"),
            "{msg}"
        );
        let msg = error_of(
            "[cantilever]\nlength_um = 400\nyoungs_modulus_gpa = 169\nwidth_um = 0\nthickness_um = 2\n",
        );
        assert!(msg.contains("cantilever.width_um = 0 is out"), "{msg}");
    }

    #[test]
    fn absurd_cantilevers_name_the_accepted_range() {
        let msg = error_of("[cantilever]\nlength_um = 400\nspring_constant_n_per_m = 1e300\n");
        assert_eq!(
            msg,
            "probe.toml: cantilever.spring_constant_n_per_m = 1e300 is out of range: \
             accepted 0.001 to 1000 N/m"
        );
        let msg = error_of("[cantilever]\nlength_um = 1e308\nspring_constant_n_per_m = 1\n");
        assert_eq!(
            msg,
            "probe.toml: cantilever.length_um = 1e308 is out of range: accepted 10 to 1000 um"
        );
        let msg = error_of(
            "[cantilever]\nlength_um = 400\nyoungs_modulus_gpa = 169\nwidth_um = 50\n\
             thickness_um = -inf\n",
        );
        assert_eq!(
            msg,
            "probe.toml: cantilever.thickness_um = -inf is out of range: \
             accepted 0.1 to 20 um"
        );
        // The bounds themselves are accepted.
        for (length, k) in [(10.0, 0.001), (1000.0, 1000.0)] {
            let text =
                format!("[cantilever]\nlength_um = {length:?}\nspring_constant_n_per_m = {k:?}\n");
            assert!(parse(&text).is_ok(), "{text}");
        }
    }

    #[test]
    fn clicks_are_two_coordinates_inside_a_frame() {
        let three = SAMPLE.replace("[156.8, 33.4]", "[1.0, 2.0, 3.0]");
        assert_eq!(
            error_of(&three),
            "probe.toml: tracker.calibration.red[0] must be one pixel [x, y] (two numbers), \
             got [1.0, 2.0, 3.0]"
        );
        let one = SAMPLE.replace("[245.4, 153.4]", "[245.4]");
        assert!(
            error_of(&one).starts_with("probe.toml: tracker.calibration.blue[1] must be one pixel"),
            "{one}"
        );
        let far = SAMPLE.replace("[314.8, 142.9]", "[314.8, 1e9]");
        assert_eq!(
            error_of(&far),
            "probe.toml: tracker.calibration.green[2][1] = 1e9 is out of range: \
             accepted -0.5 to 16384 px"
        );
    }

    #[test]
    fn numbers_print_as_a_person_reads_them() {
        let shown = [
            1e300,
            1e-8,
            0.06,
            434.675,
            -3.0,
            0.0,
            5e6,
            f64::NAN,
            f64::NEG_INFINITY,
        ]
        .map(|v| Number(v).to_string());
        assert_eq!(
            shown,
            ["1e300", "1e-8", "0.06", "434.675", "-3", "0", "5000000", "nan", "-inf"]
        );
        assert_eq!(
            Range::new(0.5, 3600.0, "s").or_zero().to_string(),
            "0 or 0.5 to 3600 s"
        );
        assert!(Range::new(0.5, 3600.0, "s").or_zero().contains(0.0));
        assert!(!Range::new(-1.0, 1.0, "V").except_zero().contains(0.0));
        assert!(!Range::new(0.0, 1.0, "").contains(f64::NAN));
    }

    #[test]
    fn both_or_neither_stiffness_is_an_error() {
        let both = error_of(
            "[cantilever]\nlength_um = 400\nspring_constant_n_per_m = 1\nyoungs_modulus_gpa = 169\n",
        );
        assert!(
            both.starts_with("probe.toml: ") && both.contains("not both"),
            "{both}"
        );
        let neither = error_of("[cantilever]\nlength_um = 400\n");
        assert!(neither.contains("missing stiffness"), "{neither}");
        let partial = error_of("[cantilever]\nlength_um = 400\nyoungs_modulus_gpa = 169\n");
        assert!(partial.contains("missing cantilever.width_um"), "{partial}");
    }

    #[test]
    fn unknown_key_names_file_and_key() {
        let msg = error_of("[cantilever]\nlength_um = 400\nspring_k = 3\n");
        assert!(msg.starts_with("probe.toml: "), "{msg}");
        assert!(msg.contains("spring_k"), "{msg}");
        let msg =
            error_of("[cantilever]\nlength_um = 400\nspring_constant_n_per_m = 1\n[trackr]\n");
        assert!(msg.contains("trackr"), "{msg}");
    }

    #[test]
    fn wrong_type_is_an_error() {
        let msg = error_of("[cantilever]\nlength_um = \"long\"\nspring_constant_n_per_m = 1\n");
        assert!(msg.contains("length_um") && msg.contains("long"), "{msg}");
    }

    #[test]
    fn tracker_fields_are_checked() {
        let base = "[cantilever]\nlength_um = 400\nspring_constant_n_per_m = 1\n[tracker]\n";
        let msg = error_of(&format!("{base}threshold = 300\n"));
        assert_eq!(
            msg,
            "probe.toml: tracker.threshold must be a grey level 0..=255 or \"otsu\", got 300"
        );
        let msg = error_of(&format!("{base}threshold = \"mean\"\n"));
        assert!(msg.contains("\"mean\""), "{msg}");
        let msg = error_of(&format!("{base}window_deg = 0\n"));
        assert!(msg.contains("tracker.window_deg = 0 is out"), "{msg}");
        let msg = error_of(&format!(
            "{base}[tracker.calibration]\nreference_image = \"r.png\"\nred = [[1.0, 2.0]]\n\
             blue = [[0.0, 0.0], [9.0, 9.0]]\ngreen = [[0.0, 0.0], [9.0, 9.0]]\n"
        ));
        assert!(
            msg.contains("tracker.calibration.red") && msg.contains("1 point"),
            "{msg}"
        );
    }

    #[test]
    fn a_probe_without_a_cantilever_has_no_force_model() {
        let cfg = parse("[tracker]\nthreshold = 100\n").unwrap();
        assert_eq!(cfg.cantilever, None);
        // A half-given [cantilever] is still an error.
        let msg = error_of("[cantilever]\nwidth_um = 50\n");
        assert!(msg.contains("missing cantilever.length_um"), "{msg}");
    }

    #[test]
    fn unreadable_file_names_it() {
        let err = Config::load(Path::new("/nonexistent/probe.toml")).unwrap_err();
        assert!(err
            .to_string()
            .starts_with("/nonexistent/probe.toml: cannot read"));
    }
}
