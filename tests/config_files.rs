//! Every configuration file shipped in `config/` must load and validate.
use std::path::Path;

use nanoforce::config::Config;

#[test]
fn shipped_example_probe_config_is_valid() {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("config/probe.example.toml");
    let cfg = Config::load(&path).unwrap_or_else(|e| panic!("{e}"));
    assert_eq!(cfg.probes[0].cantilever.map(|c| c.length_um), Some(434.675));
    assert!(cfg.probes[0].tracker.calibration.is_some());
}

#[test]
fn public_sample_configs_are_valid() {
    for name in ["mixed", "sequence"] {
        let path = Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("tests/data/samples")
            .join(name)
            .join("probe.toml");
        let cfg = Config::load(&path).unwrap_or_else(|e| panic!("{e}"));
        let cal = cfg.probes[0]
            .tracker
            .calibration
            .clone()
            .expect("calibration block");
        assert!(
            cal.reference_image.exists(),
            "{}",
            cal.reference_image.display()
        );
    }
}

#[test]
fn shipped_sim_config_is_valid_and_matches_the_defaults() {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("config/sim.toml");
    let cfg = Config::load(&path).unwrap_or_else(|e| panic!("{e}"));
    assert!(cfg.devices.all_simulated());
    // The file documents the defaults: a config without those sections means the same.
    let bare = Config::from_toml_str(
        "[cantilever]\nlength_um = 434.675\nspring_constant_n_per_m = 0.06\n",
        Path::new("bare.toml"),
    )
    .unwrap();
    assert_eq!(cfg.sim, bare.sim);
    assert_eq!(cfg.daemon, bare.daemon);
    let mut teleop = cfg.teleop.clone();
    teleop.safety.max_contact_force_nn = bare.teleop.safety.max_contact_force_nn;
    assert_eq!(teleop, bare.teleop);
}

// Every number a lab types has a physical range, documented next to its key in config/
// with the words the refusal prints. The tests below read each shipped file, find every
// numeric key (scalars and per-axis lists), and check that: the documented range is the
// one the code enforces, its bounds and any value between them load, and any value
// outside (including nan and inf) is refused with the file, key, value and range named.

use nanoforce::config::Number;
use proptest::prelude::*;
use proptest::test_runner::{Config as ProptestConfig, TestRunner};

const FILES: [&str; 3] = ["sim.toml", "probe.example.toml", "lab.example.toml"];
/// Numeric keys whose rule is not a range (an id, a sign, a direction); `[daemon]`'s
/// keys are checked in its own module.
const NOT_RANGES: [&str; 3] = [
    "sim.sem.seed",
    "teleop.pressing_force_sign",
    "teleop.press_direction_stage",
];
/// A key whose in-range values need another key moved out of the way first.
const COUPLED: [(&str, &str, &str, &str); 2] = [
    ("teleop.deadband_mm", "safety", "recentre_radius_mm", "0.1"),
    (
        "safety.recentre_radius_mm",
        "teleop",
        "deadband_mm",
        "[20.0, 20.0, 20.0]",
    ),
];
/// Keys that cannot take every value of their range alone: `[min, max]`'s first element
/// (min < max).
const IN_RANGE_UNCHECKED: [&str; 1] = ["daq.x.range_v"];

/// Whether an in-range value loads, or is refused only because it names an output
/// line another axis drives (one output line drives one axis: any subdevice, channel,
/// counter or direction key can take another axis's line within its range).
fn loads_in_range(loaded: &Result<Config, String>) -> bool {
    match loaded {
        Ok(_) => true,
        Err(msg) => msg.contains("drive the same output"),
    }
}

/// One numeric key of a shipped file.
#[derive(Debug, Clone)]
struct Entry {
    file: &'static str,
    text: String,
    line: usize,
    /// `section.key`.
    name: String,
    /// The key's value: one number, or the numbers of a flat list (the first is varied).
    values: Vec<String>,
    is_list: bool,
    whole: bool,
    /// The comments that document it: on its line and the indented lines below, the
    /// comment lines just above, and its paragraph's opening comments.
    doc: String,
}

fn comment(line: &str) -> Option<&str> {
    line.trim_start().strip_prefix('#')
}

fn entries() -> Vec<Entry> {
    let mut out = Vec::new();
    for file in FILES {
        let path = Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("config")
            .join(file);
        let text = std::fs::read_to_string(&path).unwrap();
        let lines: Vec<&str> = text.lines().collect();
        let mut section = String::new();
        let mut paragraph_doc = String::new();
        let mut paragraph_open = true;
        for (i, line) in lines.iter().enumerate() {
            let trimmed = line.trim();
            if trimmed.is_empty() || trimmed.starts_with('[') {
                if let Some(name) = trimmed.strip_prefix('[') {
                    section = name.trim_end_matches(']').to_string();
                }
                paragraph_doc.clear();
                paragraph_open = true;
                continue;
            }
            if let Some(c) = comment(line) {
                if paragraph_open && !line.starts_with(' ') {
                    paragraph_doc.push_str(c);
                }
                continue;
            }
            paragraph_open = false;
            let Some((key, rest)) = line.split_once('=') else {
                continue;
            };
            let (literal, own) = rest.split_once('#').unwrap_or((rest, ""));
            let literal = literal.trim();
            let name = format!("{section}.{}", key.trim());
            let is_list = literal.starts_with('[');
            let values: Vec<String> = literal
                .trim_matches(|c| c == '[' || c == ']')
                .split(',')
                .map(|v| v.trim().to_string())
                .collect();
            let numeric =
                !literal[1..].contains('[') && values.iter().all(|v| v.parse::<f64>().is_ok());
            if !numeric || section == "daemon" || NOT_RANGES.contains(&name.as_str()) {
                continue;
            }
            let mut doc = own.to_string();
            for below in &lines[i + 1..] {
                match comment(below) {
                    Some(c) if below.starts_with(' ') => doc.push_str(c),
                    _ => break,
                }
            }
            for above in lines[..i].iter().rev() {
                match comment(above) {
                    Some(c) if !above.starts_with(' ') => doc.push_str(c),
                    _ => break,
                }
            }
            doc.push_str(&paragraph_doc);
            let whole = values[0].parse::<i64>().is_ok();
            out.push(Entry {
                file,
                text: text.clone(),
                line: i,
                name,
                values,
                is_list,
                whole,
                doc: doc.split_whitespace().collect::<Vec<_>>().join(" "),
            });
        }
    }
    out
}

impl Entry {
    /// The key as an error names it.
    fn error_key(&self) -> String {
        if self.is_list {
            format!("{}[0]", self.name)
        } else {
            self.name.clone()
        }
    }

    /// The file with this key's (first) number replaced by `value`.
    fn with(&self, value: &str) -> String {
        let mut values = self.values.clone();
        values[0] = value.to_string();
        let literal = if self.is_list {
            format!("[{}]", values.join(", "))
        } else {
            values[0].clone()
        };
        let key = self.name.rsplit('.').next().unwrap();
        let mut lines: Vec<String> = self.text.lines().map(str::to_string).collect();
        lines[self.line] = format!("{key} = {literal}");
        for (name, section, other, replacement) in COUPLED {
            if name == self.name {
                set(&mut lines, section, other, replacement);
            }
        }
        lines.join("\n")
    }

    fn load(&self, value: &str) -> Result<Config, String> {
        Config::from_toml_str(&self.with(value), Path::new(self.file)).map_err(|e| e.to_string())
    }

    /// The accepted range as the code states it (a number far above any range).
    fn accepted(&self) -> String {
        let huge = if self.whole {
            "1000000000000000"
        } else {
            "1e300"
        };
        let msg = self.load(huge).unwrap_err();
        let head = format!(
            "{}: {} = {} is out of range: accepted ",
            self.file,
            self.error_key(),
            if self.whole { huge } else { "1e300" }
        );
        msg.strip_prefix(&head)
            .unwrap_or_else(|| panic!("{}: {msg}", self.name))
            .to_string()
    }
}

/// Sets `key` of `[section]` in the lines of a file.
fn set(lines: &mut [String], section: &str, key: &str, literal: &str) {
    let start = lines
        .iter()
        .position(|l| l.trim() == format!("[{section}]"))
        .unwrap();
    let at = lines[start..]
        .iter()
        .position(|l| l.split('=').next().map(str::trim) == Some(key))
        .unwrap();
    lines[start + at] = format!("{key} = {literal}");
}

/// `[0 or ]LO to HI[ unit][, not 0]`.
#[derive(Debug, Clone, Copy)]
struct Parsed {
    lo: f64,
    hi: f64,
    zero_allowed: bool,
    zero_refused: bool,
}

fn parse_range(text: &str) -> Parsed {
    let zero_allowed = text.starts_with("0 or ");
    let rest = text.trim_start_matches("0 or ");
    let mut words = rest.split(' ');
    let lo = words.next().unwrap().trim_end_matches(',').parse().unwrap();
    assert_eq!(words.next(), Some("to"), "{text}");
    let hi = words.next().unwrap().trim_end_matches(',').parse().unwrap();
    Parsed {
        lo,
        hi,
        zero_allowed,
        zero_refused: text.ends_with(", not 0"),
    }
}

/// A TOML literal for `v` (floats round-trip exactly).
fn literal(v: f64, whole: bool) -> String {
    if whole {
        format!("{}", v as i64)
    } else if v.is_nan() {
        "nan".into()
    } else if v.is_infinite() {
        if v > 0.0 { "inf" } else { "-inf" }.into()
    } else {
        format!("{v:?}")
    }
}

fn inside(range: Parsed, whole: bool, f: f64) -> f64 {
    let (lo, hi) = (range.lo, range.hi);
    let v = if lo > 0.0 && hi / lo > 100.0 {
        lo * (hi / lo).powf(f)
    } else {
        lo + f * (hi - lo)
    };
    let v = v.clamp(lo, hi);
    let v = if whole { v.round() } else { v };
    if range.zero_refused && v == 0.0 {
        hi
    } else {
        v
    }
}

fn outside(range: Parsed, whole: bool, f: f64, above: bool) -> f64 {
    let (lo, hi) = (range.lo, range.hi);
    if whole {
        let step = 1.0 + (f * 1e6).floor();
        return if above { hi + step } else { lo - step };
    }
    let step = |b: f64| b.abs().max(1.0) * (1e-6 + f * 1e3);
    let v = if above { hi + step(hi) } else { lo - step(lo) };
    if range.zero_allowed && v == 0.0 {
        -1.0
    } else {
        v
    }
}

fn refusal(e: &Entry, v: f64, accepted: &str) -> String {
    let shown = if e.whole {
        format!("{}", v as i64)
    } else {
        Number(v).to_string()
    };
    format!(
        "{}: {} = {shown} is out of range: accepted {accepted}",
        e.file,
        e.error_key()
    )
}

#[test]
fn every_numeric_key_documents_the_range_the_code_enforces() {
    let entries = entries();
    // The three files hold this many numeric keys with a range (not counting [daemon]).
    assert!(entries.len() >= 60, "{}", entries.len());
    for e in &entries {
        let accepted = e.accepted();
        assert!(
            e.doc.contains(&format!("accepted {accepted}")),
            "config/{}: {} does not document \"accepted {accepted}\": {:?}",
            e.file,
            e.name,
            e.doc
        );
        let range = parse_range(&accepted);
        if !IN_RANGE_UNCHECKED.contains(&e.name.as_str()) {
            for v in [range.lo, range.hi] {
                let value = literal(v, e.whole);
                let loaded = e.load(&value);
                assert!(loads_in_range(&loaded), "{} = {value}: {loaded:?}", e.name);
            }
        }
        let mut bad = vec![
            outside(range, e.whole, 0.0, true),
            outside(range, e.whole, 0.0, false),
        ];
        if !e.whole {
            bad.extend([f64::NAN, f64::INFINITY, f64::NEG_INFINITY, -1e300]);
        }
        for v in bad {
            let msg = e.load(&literal(v, e.whole)).unwrap_err();
            assert_eq!(msg, refusal(e, v, &accepted));
        }
    }
}

#[test]
fn any_value_in_range_loads_and_any_outside_is_refused() {
    let entries = entries();
    let ranges: Vec<(String, Parsed)> = entries
        .iter()
        .map(|e| {
            let accepted = e.accepted();
            let parsed = parse_range(&accepted);
            (accepted, parsed)
        })
        .collect();
    let mut runner = TestRunner::new(ProptestConfig::with_cases(400));
    let strategy = (0..entries.len(), 0.0..=1.0f64, any::<bool>());
    runner
        .run(&strategy, |(i, f, above)| {
            let e = &entries[i];
            let (accepted, range) = &ranges[i];
            if !IN_RANGE_UNCHECKED.contains(&e.name.as_str()) {
                let v = inside(*range, e.whole, f);
                let loaded = e.load(&literal(v, e.whole));
                prop_assert!(loads_in_range(&loaded), "{} = {v}: {:?}", e.name, loaded);
            }
            let v = outside(*range, e.whole, f, above);
            let msg = e.load(&literal(v, e.whole)).unwrap_err();
            prop_assert_eq!(msg, refusal(e, v, accepted));
            Ok(())
        })
        .unwrap();
}
