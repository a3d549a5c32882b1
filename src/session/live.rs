//! A session folder recorded by `nanoforce run`, as far as replaying it goes: its
//! `session.json` (the UTC anchor of its times, the frames file) and the configuration
//! it ran with (`config.toml`).
use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use super::utc::{format_utc_ns, UtcAnchor};

/// The session's description file.
pub const SESSION_FILE: &str = "session.json";
/// The configuration the run used.
pub const CONFIG_FILE: &str = "config.toml";

/// `session.json`. Field names are part of the interface (docs/operations.md).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SessionInfo {
    /// The UTC time of t = 0, ISO 8601 (the same instant as `t0_unix_ns`).
    pub t0_utc: String,
    #[serde(flatten)]
    pub anchor: UtcAnchor,
    /// UTC minus CLOCK_MONOTONIC at the start, nanoseconds.
    pub utc_minus_monotonic_ns: i64,
    /// The recorded frames (in the session folder), when the run records them.
    pub frames_file: Option<String>,
    /// The configuration file the run loaded (its copy is `config.toml`; relative paths
    /// in it, such as the reference image, are relative to this file); None: the
    /// built-in simulated lab.
    pub config_file: Option<String>,
    /// The nanoforce version that recorded the session.
    pub version: String,
}

impl SessionInfo {
    pub fn new(
        anchor: UtcAnchor,
        frames_file: Option<&str>,
        config_file: Option<&Path>,
    ) -> SessionInfo {
        SessionInfo {
            t0_utc: format_utc_ns(anchor.t0_unix_ns),
            anchor,
            utc_minus_monotonic_ns: anchor.utc_minus_monotonic_ns(),
            frames_file: frames_file.map(str::to_string),
            config_file: config_file.map(|p| p.to_string_lossy().into_owned()),
            version: env!("CARGO_PKG_VERSION").to_string(),
        }
    }

    /// Reads `dir/session.json`.
    pub fn read(dir: &Path) -> Result<SessionInfo, LiveSessionError> {
        let path = dir.join(SESSION_FILE);
        let text = std::fs::read_to_string(&path).map_err(|source| LiveSessionError::Read {
            path: path.clone(),
            source,
        })?;
        serde_json::from_str(&text).map_err(|e| LiveSessionError::Format {
            path,
            reason: e.to_string(),
        })
    }

    /// The frames file's path in `dir`, when the session has one.
    pub fn frames_path(&self, dir: &Path) -> Option<PathBuf> {
        self.frames_file.as_ref().map(|f| dir.join(f))
    }
}

/// Whether `dir` is a session folder recorded by `nanoforce run`.
pub fn is_live_session(dir: &Path) -> bool {
    dir.join(SESSION_FILE).is_file()
}

#[derive(Debug, thiserror::Error)]
pub enum LiveSessionError {
    #[error("{path}: cannot read: {source}")]
    Read {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error("{path}: not a session description: {reason}")]
    Format { path: PathBuf, reason: String },
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn session_json_round_trip_and_field_names() {
        let anchor = UtcAnchor {
            t0_unix_ns: 1_796_256_068_123_456_789,
            t0_monotonic_ns: 5_000_000_000,
        };
        let info = SessionInfo::new(
            anchor,
            Some("frames.nfrm"),
            Some(Path::new("/etc/lab.toml")),
        );
        let json = serde_json::to_value(&info).unwrap();
        assert_eq!(json["t0_utc"], "2026-12-03T00:01:08.123456Z");
        assert_eq!(json["t0_unix_ns"], 1_796_256_068_123_456_789i64);
        assert_eq!(json["t0_monotonic_ns"], 5_000_000_000u64);
        assert_eq!(json["utc_minus_monotonic_ns"], 1_796_256_063_123_456_789i64);
        assert_eq!(json["frames_file"], "frames.nfrm");
        assert_eq!(json["config_file"], "/etc/lab.toml");
        let dir = tempfile::tempdir().unwrap();
        std::fs::write(dir.path().join(SESSION_FILE), json.to_string()).unwrap();
        assert!(is_live_session(dir.path()));
        assert_eq!(SessionInfo::read(dir.path()).unwrap(), info);
        std::fs::write(dir.path().join(SESSION_FILE), "{").unwrap();
        let err = SessionInfo::read(dir.path()).unwrap_err().to_string();
        assert!(
            err.contains("session.json: not a session description"),
            "{err}"
        );
    }
}
