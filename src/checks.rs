//! The validation toolkit every configuration section is checked with: the error a
//! configuration file gets ([`ConfigError`], naming file, key and value), the accepted
//! range of a number ([`Range`]), fixed-size TOML lists (`List`), the `Checker` that
//! knows which file it checks, and sections whose keys depend on a choice (`tagged`:
//! `backend = "..."` selects the struct of keys that exist; `NoKeys` for a choice with
//! none). It imports nothing of the crate, so each module can validate its own section
//! without reaching up into `config`.
use std::fmt;
use std::path::{Path, PathBuf};

use serde::de::Error as _;
use serde::{Deserialize, Deserializer};

/// Something wrong with a configuration file.
#[derive(Debug, thiserror::Error)]
pub enum ConfigError {
    #[error("{file}: cannot read: {source}")]
    Read {
        file: PathBuf,
        source: std::io::Error,
    },
    #[error("{file}: {message}")]
    Parse { file: PathBuf, message: String },
    #[error("{file}: {key} = {value} is out of range: accepted {accepted}")]
    OutOfRange {
        file: PathBuf,
        key: String,
        value: String,
        accepted: Range,
    },
    #[error("{file}: {key} {reason}, got {value}")]
    Invalid {
        file: PathBuf,
        key: String,
        value: String,
        reason: String,
    },
    #[error("{file}: {message}")]
    Inconsistent { file: PathBuf, message: String },
}

/// The accepted values of a number a lab types, with its unit: the one rule every
/// numeric key is checked against (`Checker::number`), so every refusal reads the same
/// (`probe.toml: cantilever.length_um = 1e308 is out of range: accepted 10 to 1000 um`)
/// and `config/` documents each key's range in the same words.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Range {
    pub lo: f64,
    pub hi: f64,
    /// Printed after the bounds; empty for a plain count.
    pub unit: &'static str,
    pub zero: Zero,
}

/// How a range treats 0.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Zero {
    /// Like any other value: accepted when inside the bounds.
    AsRange,
    /// Also accepted below the bounds (0 switches the feature off).
    Allowed,
    /// Refused although inside the bounds (a signed factor that must not vanish).
    Refused,
}

impl Range {
    /// `lo` to `hi`, both included.
    pub const fn new(lo: f64, hi: f64, unit: &'static str) -> Range {
        Range {
            lo,
            hi,
            unit,
            zero: Zero::AsRange,
        }
    }

    /// The same range, and 0 as well.
    pub const fn or_zero(self) -> Range {
        Range {
            zero: Zero::Allowed,
            ..self
        }
    }

    /// The same range without 0.
    pub const fn except_zero(self) -> Range {
        Range {
            zero: Zero::Refused,
            ..self
        }
    }

    /// Whether `value` is accepted (never a NaN or an infinity).
    pub fn contains(&self, value: f64) -> bool {
        match self.zero {
            Zero::Allowed if value == 0.0 => true,
            Zero::Refused if value == 0.0 => false,
            _ => value.is_finite() && (self.lo..=self.hi).contains(&value),
        }
    }
}

impl fmt::Display for Range {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        if self.zero == Zero::Allowed {
            f.write_str("0 or ")?;
        }
        write!(f, "{} to {}", Number(self.lo), Number(self.hi))?;
        if !self.unit.is_empty() {
            write!(f, " {}", self.unit)?;
        }
        if self.zero == Zero::Refused {
            f.write_str(", not 0")?;
        }
        Ok(())
    }
}

/// A number as a person reads it in a message: plain between 1e-4 and 1e7, else with an
/// exponent (`1e300`, not 301 digits), and `nan`/`inf` spelt as in TOML.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Number(pub f64);

impl fmt::Display for Number {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let v = self.0;
        if v.is_nan() {
            f.write_str("nan")
        } else if v.is_infinite() {
            f.write_str(if v > 0.0 { "inf" } else { "-inf" })
        } else if v == 0.0 || (1e-4..1e7).contains(&v.abs()) {
            write!(f, "{v}")
        } else {
            write!(f, "{v:e}")
        }
    }
}

/// A TOML list of exactly `N` items. serde's own `[T; N]` lets the TOML reader drop
/// extra items silently (`[2.0, 2.0, 2.0, 9.0]` read as three axes), so every
/// fixed-size list in a configuration is read through this.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct List<T, const N: usize>(pub [T; N]);

impl<'de, T: Deserialize<'de>, const N: usize> Deserialize<'de> for List<T, N> {
    fn deserialize<D: Deserializer<'de>>(deserializer: D) -> Result<Self, D::Error> {
        let items = Vec::<T>::deserialize(deserializer)?;
        let len = items.len();
        let expected = format!("a list of {N} items");
        items
            .try_into()
            .map(List)
            .map_err(|_| D::Error::invalid_length(len, &expected.as_str()))
    }
}

/// Validation helpers that know which file they are checking.
pub(crate) struct Checker<'a> {
    pub(crate) file: &'a Path,
}

impl Checker<'_> {
    pub(crate) fn invalid(&self, key: &str, value: impl fmt::Display, reason: &str) -> ConfigError {
        ConfigError::Invalid {
            file: self.file.to_path_buf(),
            key: key.to_string(),
            value: value.to_string(),
            reason: reason.to_string(),
        }
    }

    pub(crate) fn inconsistent(&self, message: String) -> ConfigError {
        ConfigError::Inconsistent {
            file: self.file.to_path_buf(),
            message,
        }
    }

    /// A number in `range`; out of it (or not finite), an error naming the key, the
    /// value and the accepted range.
    pub(crate) fn number(&self, key: &str, value: f64, range: Range) -> Result<f64, ConfigError> {
        if range.contains(value) {
            Ok(value)
        } else {
            Err(self.out_of_range(key, Number(value), range))
        }
    }

    /// An optional number: checked against `range` when given, else `default`.
    pub(crate) fn number_or(
        &self,
        key: &str,
        value: Option<f64>,
        default: f64,
        range: Range,
    ) -> Result<f64, ConfigError> {
        value.map_or(Ok(default), |v| self.number(key, v, range))
    }

    /// A whole number in `range`.
    pub(crate) fn whole(&self, key: &str, value: i64, range: Range) -> Result<i64, ConfigError> {
        // Exact: every bound in use is far below 2^53.
        if range.contains(value as f64) {
            Ok(value)
        } else {
            Err(self.out_of_range(key, value, range))
        }
    }

    /// One number per axis, each in `range`; an error names the axis (`key[1]`).
    pub(crate) fn vector3(
        &self,
        key: &str,
        v: [f64; 3],
        range: Range,
    ) -> Result<nalgebra::Vector3<f64>, ConfigError> {
        for (axis, &value) in v.iter().enumerate() {
            self.number(&format!("{key}[{axis}]"), value, range)?;
        }
        Ok(nalgebra::Vector3::from(v))
    }

    fn out_of_range(&self, key: &str, value: impl fmt::Display, range: Range) -> ConfigError {
        ConfigError::OutOfRange {
            file: self.file.to_path_buf(),
            key: key.to_string(),
            value: value.to_string(),
            accepted: range,
        }
    }

    /// A direction: finite, normalised here (it must not be zero).
    pub(crate) fn unit_vector(
        &self,
        key: &str,
        v: [f64; 3],
    ) -> Result<nalgebra::Vector3<f64>, ConfigError> {
        let vector = nalgebra::Vector3::from(v);
        let norm = vector.norm();
        if norm.is_finite() && norm > 1e-9 {
            Ok(vector / norm)
        } else {
            Err(self.invalid(
                key,
                format_args!("{v:?}"),
                "must be a finite, non-zero direction",
            ))
        }
    }

    /// A 3x3 matrix given as rows that is orthonormal (rotation or signed permutation).
    pub(crate) fn orthonormal(
        &self,
        key: &str,
        rows: [[f64; 3]; 3],
    ) -> Result<nalgebra::Matrix3<f64>, ConfigError> {
        let m = nalgebra::Matrix3::from_fn(|r, c| rows[r][c]);
        let error = (m * m.transpose() - nalgebra::Matrix3::identity())
            .abs()
            .max();
        if error.is_finite() && error < 1e-6 {
            Ok(m)
        } else {
            Err(self.invalid(
                key,
                format_args!("{rows:?}"),
                "must be orthonormal (a rotation or a signed permutation of the axes)",
            ))
        }
    }
}

/// The keys of a choice that has none (`backend = "sim"`, `output = "none"`).
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(crate) struct NoKeys {}

/// Reads the table `name` into `T`, an enum tagged by its key `tag` (`default` when the
/// table has none): the tag selects the variant, and the variant's struct the keys that
/// exist. Errors name the key: `frames.device is not a key of frames.backend = "pipe"
/// (its keys: path, format, width, height, timeout_ms)`.
pub(crate) fn tagged<T: serde::de::DeserializeOwned>(
    check: &Checker,
    name: &str,
    tag: &str,
    default: Option<&str>,
    mut table: toml::Table,
) -> Result<T, ConfigError> {
    if let (false, Some(default)) = (table.contains_key(tag), default) {
        table.insert(tag.into(), default.into());
    }
    let read = |table: toml::Table| -> Result<T, String> {
        toml::Value::Table(table)
            .try_into()
            .map_err(|e: toml::de::Error| e.message().to_string())
    };
    let message = match read(table.clone()) {
        Ok(raw) => return Ok(raw),
        Err(message) => message,
    };
    // serde's words, with the key they are about.
    let chosen = table
        .get(tag)
        .map(|v| format!("{name}.{tag} = {v}"))
        .unwrap_or_default();
    let listed = |text: &str| {
        let list = text
            .trim_start_matches(", expected ")
            .trim_start_matches("one of ");
        list.replace('`', "")
    };
    let explained = if let Some((key, rest)) = message
        .strip_prefix("unknown field `")
        .and_then(|m| m.split_once('`'))
    {
        if rest.starts_with(", there are no fields") {
            format!("{name}.{key} is not a key of {chosen}, which has none")
        } else {
            format!(
                "{name}.{key} is not a key of {chosen} (its keys: {})",
                listed(rest)
            )
        }
    } else if let Some((_, rest)) = message
        .strip_prefix("unknown variant `")
        .and_then(|m| m.split_once('`'))
    {
        format!("{chosen} is not one of: {}", listed(rest))
    } else if message == format!("missing field `{tag}`") {
        // The values there are: what an empty one is told.
        table.insert(tag.into(), "".into());
        let choices = read(table)
            .err()
            .and_then(|m| m.split_once('`').map(|(_, r)| r.to_string()))
            .and_then(|r| r.split_once('`').map(|(_, r)| listed(r)))
            .unwrap_or_default();
        format!("missing {name}.{tag} (one of: {choices})")
    } else {
        format!("[{name}]: {message}")
    };
    Err(check.inconsistent(explained))
}

/// A required key of a backend.
pub(crate) fn required<T>(
    check: &Checker,
    key: &str,
    backend: &str,
    value: Option<T>,
) -> Result<T, ConfigError> {
    value
        .ok_or_else(|| check.inconsistent(format!("missing {key} (needed by backend {backend:?})")))
}

/// A whole number in `lo..=hi` (`unit` as the message prints it, empty for a count).
pub(crate) fn in_range(
    check: &Checker,
    key: &str,
    value: i64,
    (lo, hi): (i64, i64),
    unit: &'static str,
) -> Result<u32, ConfigError> {
    // In range, so it fits (every `hi` in use is below 2^32).
    let range = Range::new(lo as f64, hi as f64, unit);
    check.whole(key, value, range).map(|v| v as u32)
}
