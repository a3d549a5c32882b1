//! Configuration in two steps: serde structs that mirror the TOML file exactly
//! (`deny_unknown_fields`, so a misspelt key is an error, not a silent default), then
//! `validate`-style checks that turn them into a [`Config`] whose fields can
//! be trusted (finite, positive, consistent).
//!
//! Every error names the file, the key and the offending value, e.g.
//! `probe.toml: cantilever.length_um must be > 0, got -3`.
//! The documented defaults of every key live in `config/`.

use std::path::{Path, PathBuf};

use serde::Deserialize;

pub mod daemon;
pub mod monitor;
pub mod probe;
pub mod stream;

use self::daemon::RawDaemon;
pub use self::daemon::{DaemonConfig, LoopOptions};
pub use self::monitor::MonitorConfig;
use self::monitor::RawMonitor;
pub use self::probe::{ProbeConfig, MAX_PROBES, SINGLE_NAME, WINDOW_DEG};
use self::probe::{RawCantilever, RawProbe, RawTracker};
use self::stream::RawStream;
pub use self::stream::StreamConfig;
pub(crate) use crate::checks::Checker;
pub use crate::checks::{ConfigError, Number, Range, Zero};
use crate::control::{RawSafety, RawTeleop, TeleopGains};
use crate::hw::config::{DevicesConfig, RawDevice};
use crate::sim::config::{RawSim, SimConfig};
pub use crate::vision::{
    CalibrationConfig, PixelOrigin, Threshold, TrackerConfig, DEFAULT_WINDOW_DEG, MAX_EDGE_BIAS_PX,
};

/// A validated configuration.
#[derive(Debug, Clone, PartialEq)]
pub struct Config {
    /// The file it was read from (used in messages and to resolve relative paths).
    pub path: PathBuf,
    /// The probes in view, at least one: the top-level `[cantilever]` and `[tracker]`
    /// (one probe, named `probe`) or the `[[probe]]` entries, in file order.
    pub probes: Vec<ProbeConfig>,
    /// `[teleop]` and `[safety]`: the gains SIGHUP may reload.
    pub teleop: TeleopGains,
    /// `[frames]`, `[haptic]` and each probe's `[daq]`: which backend drives each
    /// device.
    pub devices: DevicesConfig,
    pub daemon: DaemonConfig,
    /// `[monitor]`: the live web page (off by default) and recorded thumbnails.
    pub monitor: MonitorConfig,
    /// `[stream]`: the live data stream over UDP (off by default).
    pub stream: StreamConfig,
    /// `[sim]`: the simulated lab, used by every `"sim"` backend.
    pub sim: SimConfig,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawConfig {
    cantilever: Option<RawCantilever>,
    tracker: Option<RawTracker>,
    probe: Option<Vec<RawProbe>>,
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
        let probe::Probes {
            probes,
            positioners,
        } = probe::probes(&check, raw.cantilever, raw.tracker, raw.daq, raw.probe)?;
        let mut teleop = TeleopGains::validate(
            raw.teleop.unwrap_or_default(),
            raw.safety.unwrap_or_default(),
            &check,
        )?;
        if let Some(cantilever) = probes[0].cantilever {
            teleop.cantilever = cantilever;
        }
        let devices = DevicesConfig::validate(
            raw.frames.unwrap_or_default(),
            positioners,
            raw.haptic.unwrap_or_default(),
            &check,
        )?;
        let daemon = DaemonConfig::validate(raw.daemon.unwrap_or_default(), &check)?;
        let monitor = MonitorConfig::validate(raw.monitor.unwrap_or_default(), &check)?;
        let stream = StreamConfig::validate(raw.stream.unwrap_or_default(), &check)?;
        let sim = SimConfig::validate(raw.sim.unwrap_or_default(), &check)?;
        Ok(Config {
            path: path.to_path_buf(),
            probes,
            teleop,
            devices,
            daemon,
            monitor,
            stream,
            sim,
        })
    }
}

impl Config {
    /// Each probe's reference image, in order (None: a probe calibrated by the simulated
    /// SEM); probes calibrated on one image are seen at one scale.
    pub fn reference_images(&self) -> Vec<Option<&Path>> {
        self.probes
            .iter()
            .map(|p| {
                p.tracker
                    .calibration
                    .as_ref()
                    .map(|c| c.reference_image.as_path())
            })
            .collect()
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
        let cantilever = cfg.probes[0].cantilever.unwrap();
        assert_eq!(cantilever.length_um, 434.675);
        let ei = 0.06 * (434.675e-6f64).powi(3) / 3.0;
        assert!((cantilever.flexural_rigidity_n_m2 / ei - 1.0).abs() < 1e-14);
        assert_eq!(cfg.probes[0].tracker.threshold, Threshold::Otsu);
        let cal = cfg.probes[0].tracker.calibration.clone().unwrap();
        assert_eq!(cal.reference_image, Path::new("/data/s/reference.png"));
        assert_eq!(cal.points("green").map(<[_]>::len), Some(3));
    }

    #[test]
    fn integer_threshold_and_integer_stiffness() {
        let cfg = parse(
            "[cantilever]\nlength_um = 383\nspring_constant_n_per_m = 40\n[tracker]\nthreshold = 146\n",
        )
        .unwrap();
        assert_eq!(cfg.probes[0].tracker.threshold, Threshold::Level(146));
        assert_eq!(cfg.probes[0].tracker.window_deg, DEFAULT_WINDOW_DEG);
    }

    #[test]
    fn cross_section_stiffness() {
        let cfg = parse(
            "[cantilever]\nlength_um = 450\nyoungs_modulus_gpa = 169\nwidth_um = 50\nthickness_um = 2\n",
        )
        .unwrap();
        let ei = 169e9 * 50e-6 * (2e-6f64).powi(3) / 12.0;
        assert!(
            (cfg.probes[0].cantilever.unwrap().flexural_rigidity_n_m2 / ei - 1.0).abs() < 1e-14
        );
    }

    fn error_of(text: &str) -> String {
        parse(text).unwrap_err().to_string()
    }

    #[test]
    fn pixel_origin_and_edge_bias() {
        let cfg = parse(SAMPLE).unwrap();
        assert_eq!(cfg.probes[0].tracker.pixel_origin, PixelOrigin::Centre);
        assert_eq!(cfg.probes[0].tracker.edge_bias_px, 0.0);
        let text = SAMPLE.replace(
            "window_deg = 20.0\n",
            "window_deg = 20.0\npixel_origin = \"Corner\"\nedge_bias_px = 0.3\n",
        );
        let cfg = parse(&text).unwrap();
        assert_eq!(cfg.probes[0].tracker.pixel_origin, PixelOrigin::Corner);
        assert_eq!(cfg.probes[0].tracker.edge_bias_px, 0.3);
        // Clicks counted from the corner are kept counted from the pixel centre.
        let cal = cfg.probes[0].tracker.calibration.clone().unwrap();
        assert_eq!(cal.points("red").unwrap()[0], [156.3, 32.9]);
        assert_eq!(cal.points("green").unwrap()[2], [314.3, 142.4]);
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
    fn scale_range_is_two_scales_running_upward() {
        let with = |line: &str| {
            parse(&SAMPLE.replace(
                "window_deg = 20.0\n",
                &format!("window_deg = 20.0\n{line}\n"),
            ))
        };
        assert_eq!(parse(SAMPLE).unwrap().probes[0].tracker.scale_range, None);
        let cfg = with("scale_range = [0.8, 1.25]").unwrap();
        assert_eq!(
            cfg.probes[0].tracker.scale_range,
            Some(crate::vision::ScaleRange::new(0.8, 1.25))
        );
        let msg = with("scale_range = [1.25, 0.8]").unwrap_err().to_string();
        assert!(
            msg.contains("tracker.scale_range must run upward") && msg.ends_with("[1.25, 0.8]"),
            "{msg}"
        );
        let msg = with("scale_range = [0.01, 2]").unwrap_err().to_string();
        assert!(
            msg.ends_with("tracker.scale_range[0] = 0.01 is out of range: accepted 0.05 to 12"),
            "{msg}"
        );
        let msg = with("scale_range = [0.5, 1, 2]").unwrap_err().to_string();
        assert!(
            msg.contains("scale_range") && msg.contains("2 items"),
            "{msg}"
        );
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
    fn any_probe_names_its_edges_and_its_apex() {
        let needle =
            "[tracker.calibration]\nreference_image = \"r.png\"\napex = [\"upper\", \"end\"]\n\
                      [tracker.calibration.edges]\n\
                      upper = [[120.0, 210.5], [260.0, 236.0], [400.0, 261.5]]\n\
                      lower = [[120.0, 420.0], [260.0, 389.5]]\n\
                      end = [[505.0, 280.0], [507.5, 310.0], [510.0, 340.0]]\n";
        let cfg = parse(needle).unwrap();
        assert!(cfg.probes[0].cantilever.is_none());
        let cal = cfg.probes[0].tracker.calibration.clone().unwrap();
        let names: Vec<&str> = cal.edges.iter().map(|(n, _)| n.as_str()).collect();
        assert_eq!(names, ["upper", "lower", "end"], "the file's order");
        assert_eq!(cal.apex, Some(["upper".to_string(), "end".to_string()]));
        assert_eq!(cal.points("lower").unwrap()[1], [260.0, 389.5]);
        assert!(cal.pyramid_points().is_none());
        // The pyramid's names without an apex are its shorthand, in its order.
        let pyramid = parse(
            "[tracker.calibration]\nreference_image = \"r.png\"\n[tracker.calibration.edges]\n\
             green = [[0.0, 0.0], [9.0, 9.0]]\nred = [[0.0, 5.0], [9.0, 5.0]]\n\
             blue = [[0.0, 9.0], [9.0, 0.0]]\n",
        )
        .unwrap();
        let cal = pyramid.probes[0].tracker.calibration.clone().unwrap();
        assert_eq!(cal.pyramid_points().unwrap()[0], [[0.0, 5.0], [9.0, 5.0]]);
        for (text, expect) in [
            (
                needle.replace("apex = [\"upper\", \"end\"]\n", ""),
                "missing tracker.calibration.apex",
            ),
            (
                needle.replace("\"end\"]", "\"tip\"]"),
                "names \"tip\", which is not one of the edges",
            ),
            (
                needle.replace("\"end\"]", "\"upper\"]"),
                "two different edges",
            ),
            (
                needle.replace("apex = ", "red = [[0.0, 0.0], [9.0, 9.0]]\napex = "),
                "either as red, blue and green or in [tracker.calibration.edges]",
            ),
            (
                needle.replace(
                    "lower = [[120.0, 420.0], [260.0, 389.5]]",
                    "lower = [[120.0, 420.0]]",
                ),
                "tracker.calibration.edges.lower",
            ),
            (
                needle.replace("end = ", "\"an end\" = "),
                "edge names are 1 to",
            ),
        ] {
            let msg = error_of(&text);
            assert!(msg.contains(expect), "{expect}: {msg}");
        }
    }

    #[test]
    fn a_probe_without_a_cantilever_has_no_force_model() {
        let cfg = parse("[tracker]\nthreshold = 100\n").unwrap();
        assert_eq!(cfg.probes[0].cantilever, None);
        // A half-given [cantilever] is still an error.
        let msg = error_of("[cantilever]\nwidth_um = 50\n");
        assert!(msg.contains("missing cantilever.length_um"), "{msg}");
    }

    const TWO: &str = r#"
[[probe]]
name = "left"
[probe.cantilever]
length_um = 400
spring_constant_n_per_m = 1
[probe.tracker]
threshold = 120
[[probe]]
name = "needle"
[probe.tracker]
window_deg = 10
"#;

    #[test]
    fn several_probes_are_named_entries() {
        let cfg = parse(TWO).unwrap();
        let names: Vec<&str> = cfg.probes.iter().map(|p| p.name.as_str()).collect();
        assert_eq!(names, ["left", "needle"]);
        assert_eq!(cfg.probes[0].tracker.threshold, Threshold::Level(120));
        assert!(cfg.probes[0].cantilever.is_some() && cfg.probes[1].cantilever.is_none());
        assert_eq!(cfg.probes[1].tracker.window_deg, 10.0);
        // The first probe's cantilever is the one the haptic loop's gate knows.
        assert_eq!(cfg.teleop.cantilever, cfg.probes[0].cantilever.unwrap());
        // A file of one probe names it `probe`.
        assert_eq!(parse(SAMPLE).unwrap().probes[0].name, SINGLE_NAME);
    }

    #[test]
    fn probe_entries_are_checked_with_their_index() {
        let msg = error_of(&TWO.replace("window_deg = 10", "window_deg = 90"));
        assert!(
            msg.contains("probe[1].tracker.window_deg = 90 is out of range"),
            "{msg}"
        );
        let msg = error_of(&TWO.replace("length_um = 400", "length_um = -4"));
        assert!(msg.contains("probe[0].cantilever.length_um = -4"), "{msg}");
        let msg = error_of(&TWO.replace("name = \"needle\"", "name = \"left\""));
        assert!(
            msg.ends_with(
                "probe[1].name must differ from every earlier probe's name, got \"left\""
            ),
            "{msg}"
        );
        let msg = error_of(&TWO.replace("name = \"needle\"", "name = \"a b\""));
        assert!(
            msg.contains("probe[1].name must be 1 to 32 letters"),
            "{msg}"
        );
        let msg = error_of(&TWO.replace("name = \"needle\"\n", ""));
        assert!(msg.contains("missing probe[1].name"), "{msg}");
        let msg = error_of(&format!("{TWO}[probe.tracker.calibration]\nreference_image = \"r.png\"\nred = [[1.0, 1.0]]\nblue = [[0.0, 0.0], [9.0, 9.0]]\ngreen = [[0.0, 0.0], [9.0, 9.0]]\n"));
        assert!(msg.contains("probe[1].tracker.calibration.red"), "{msg}");
        let five = TWO
            .repeat(3)
            .replace("\"left\"\n[probe.c", "\"x\"\n[probe.c");
        assert!(
            error_of(&five).contains("1 to 4 [[probe]] entries"),
            "{}",
            error_of(&five)
        );
    }

    #[test]
    fn one_probe_or_entries_not_both() {
        let msg = error_of(&format!("[tracker]\nthreshold = 100\n{TWO}"));
        assert!(msg.contains("not both"), "{msg}");
        let msg = error_of(&format!(
            "[cantilever]\nlength_um = 400\nspring_constant_n_per_m = 1\n{TWO}"
        ));
        assert!(msg.contains("not both"), "{msg}");
    }

    #[test]
    fn each_probe_has_its_positioner_and_feel() {
        use crate::hw::config::DaqBackend;
        use crate::scene::Entry;
        let cfg = parse(TWO).unwrap();
        let sections: Vec<&str> = cfg
            .devices
            .positioners
            .iter()
            .map(|p| p.section.as_str())
            .collect();
        assert_eq!(sections, ["probe[0].daq", "probe[1].daq"]);
        assert!(cfg.devices.all_simulated());
        // Felt: the probe with a cantilever; the needle is tracked only.
        assert!(cfg.probes[0].felt && !cfg.probes[1].felt);
        // Placed where the simulated view keeps two probes apart, facing each other.
        assert_eq!(cfg.probes[0].sim.entry, Entry::Left);
        assert_eq!(cfg.probes[1].sim.entry, Entry::Right);
        assert_eq!(parse(SAMPLE).unwrap().devices.positioners[0].section, "daq");

        let comedi = "[probe.daq]\nbackend = \"comedi\"\n[probe.daq.x]\noutput = \"none\"\n\
                      [probe.daq.y]\noutput = \"none\"\n[probe.daq.z]\noutput = \"analog\"\n\
                      subdevice = 1\nchannel = 7\nvolts_per_um_s = 0.1\n";
        let cfg = parse(&format!("{TWO}{comedi}")).unwrap();
        let DaqBackend::Comedi(daq) = &cfg.devices.positioners[1].daq else {
            panic!("the needle's positioner is on the DAQ")
        };
        assert_eq!(daq.device, Path::new("/dev/comedi0"));
        assert_eq!(cfg.devices.positioners[0].daq, DaqBackend::Sim);
        let msg = error_of(&format!(
            "{TWO}{}",
            comedi.replace("channel = 7", "channel = 700")
        ));
        assert!(
            msg.contains("probe[1].daq.z.channel = 700 is out of range"),
            "{msg}"
        );
        let msg = error_of(&format!("{TWO}[probe.daq]\nbackend = \"ni\"\n"));
        assert!(msg.contains("probe[1].daq.backend = \"ni\""), "{msg}");
        // One output line drives one axis: across positioners, and within one.
        let both = format!("{TWO}{comedi}").replace(
            "name = \"left\"\n",
            &format!(
                "name = \"left\"\n{}",
                comedi.replace("channel = 7", "channel = 3")
            ),
        );
        assert!(parse(&both).is_ok(), "channels 3 and 7 differ");
        let msg = error_of(&both.replace("channel = 3", "channel = 7"));
        assert!(
            msg.contains(
                "probe[1].daq.z and probe[0].daq.z drive the same output \
                 (/dev/comedi0 subdevice 1 channel 7): each axis needs its own"
            ),
            "{msg}"
        );
        let twice = comedi.replace(
            "[probe.daq.y]\noutput = \"none\"",
            "[probe.daq.y]\noutput = \"analog\"\nsubdevice = 1\nchannel = 7\nvolts_per_um_s = 0.1",
        );
        let msg = error_of(&format!("{TWO}{twice}"));
        assert!(
            msg.contains("probe[1].daq.z and probe[1].daq.y drive the same output"),
            "{msg}"
        );
        // The lone probe's [daq] has no place beside entries.
        let msg = error_of(&format!("[daq]\nbackend = \"sim\"\n{TWO}"));
        assert!(
            msg.contains("give each probe's positioner as its [probe.daq]"),
            "{msg}"
        );
    }

    #[test]
    fn probe_feel_and_place_are_checked() {
        use crate::scene::ToolKind;
        for (sim, expected) in [
            (
                "entry = \"top\"",
                "probe[1].sim.entry must be \"left\" or \"right\", got \"top\"",
            ),
            (
                "apex_at = [0.5, 1.5]",
                "probe[1].sim.apex_at[1] = 1.5 is out of range",
            ),
            (
                "start_um = -3",
                "probe[1].sim.start_um = -3 is out of range",
            ),
            (
                "tool = \"scalpel\"",
                "probe[1].sim.tool must be \"needle\", \"tipless\" or \"gripper\", got \"scalpel\"",
            ),
        ] {
            let with = format!("window_deg = 10\n[probe.sim]\n{sim}");
            let msg = error_of(&TWO.replace("window_deg = 10", &with));
            assert!(msg.contains(expected), "{msg}");
        }
        // A rigid tool in the simulated view: drawn without a cantilever, so never with one.
        let tool = TWO.replace(
            "window_deg = 10",
            "window_deg = 10\n[probe.sim]\ntool = \"gripper\"",
        );
        assert_eq!(
            parse(&tool).unwrap().probes[1].sim.tool,
            Some(ToolKind::Gripper)
        );
        assert_eq!(parse(TWO).unwrap().probes[1].sim.tool, None);
        let msg = error_of(&TWO.replace(
            "threshold = 120",
            "threshold = 120\n[probe.sim]\ntool = \"needle\"",
        ));
        assert!(
            msg.contains(
                "probe[0].sim.tool must not be given with a [cantilever]: a rigid tool is drawn \
                 without one, got \"needle\""
            ),
            "{msg}"
        );
        let msg = error_of(&TWO.replace("name = \"needle\"", "name = \"needle\"\nfelt = true"));
        assert!(
            msg.contains("probe[1].felt needs the probe's [cantilever]"),
            "{msg}"
        );
        let msg = error_of(&TWO.replace(
            "name = \"left\"",
            "name = \"left\"\npressing_force_sign = 2",
        ));
        assert!(
            msg.contains("probe[0].pressing_force_sign must be 1 or -1, got 2"),
            "{msg}"
        );
        let cfg = parse(&TWO.replace(
            "name = \"left\"",
            "name = \"left\"\npressing_force_sign = -1\nfelt = false",
        ))
        .unwrap();
        assert_eq!(cfg.probes[0].pressing_force_sign, Some(-1.0));
        assert!(!cfg.probes[0].felt);
    }

    #[test]
    fn unreadable_file_names_it() {
        let err = Config::load(Path::new("/nonexistent/probe.toml")).unwrap_err();
        assert!(err
            .to_string()
            .starts_with("/nonexistent/probe.toml: cannot read"));
    }
}
