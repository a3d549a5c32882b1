//! `[daemon]`: how the daemon runs (real-time settings of the haptic loop, telemetry,
//! where sessions are recorded). Not reloaded by SIGHUP.
use std::path::PathBuf;

use serde::Deserialize;

use crate::checks::{Checker, ConfigError};

/// Loop settings that are not teleoperation gains.
#[derive(Debug, Clone, PartialEq)]
pub struct LoopOptions {
    /// SCHED_FIFO priority to request (None: leave the scheduler alone).
    pub rt_priority: Option<i32>,
    pub lock_memory: bool,
    /// Busy-wait this long before each deadline for a precise wake-up.
    pub spin_us: u64,
    /// PM QoS limit on CPU wake-up latency held while the loop runs (None: leave the
    /// system's setting).
    pub cpu_latency_us: Option<u32>,
    /// Record every n-th tick in the telemetry.
    pub telemetry_every: u32,
}

impl Default for LoopOptions {
    fn default() -> Self {
        LoopOptions {
            rt_priority: Some(80),
            lock_memory: true,
            spin_us: 60,
            cpu_latency_us: Some(0),
            telemetry_every: 10,
        }
    }
}
#[derive(Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub(crate) struct RawDaemon {
    rt_priority: Option<i64>,
    lock_memory: Option<bool>,
    spin_us: Option<i64>,
    cpu_latency_us: Option<i64>,
    telemetry_every: Option<i64>,
    state_dir: Option<String>,
    recordings_max_mb: Option<i64>,
}

/// Validated `[daemon]`.
#[derive(Debug, Clone, PartialEq)]
pub struct DaemonConfig {
    pub loop_options: LoopOptions,
    /// Where sessions are recorded; None: `$STATE_DIRECTORY` or the user's state dir.
    pub state_dir: Option<PathBuf>,
    /// The session folders together stay below this many MiB: the oldest are deleted.
    pub recordings_max_mb: u64,
}

/// `daemon.recordings_max_mb` when not set.
pub const DEFAULT_RECORDINGS_MAX_MB: u64 = 2048;
/// Its accepted range, MiB (1 MiB .. 1 TiB).
pub const RECORDINGS_MAX_MB_RANGE: std::ops::RangeInclusive<i64> = 1..=1_048_576;

impl Default for DaemonConfig {
    fn default() -> Self {
        DaemonConfig {
            loop_options: LoopOptions::default(),
            state_dir: None,
            recordings_max_mb: DEFAULT_RECORDINGS_MAX_MB,
        }
    }
}

impl DaemonConfig {
    pub(crate) fn validate(raw: RawDaemon, check: &Checker) -> Result<DaemonConfig, ConfigError> {
        let d = LoopOptions::default();
        let rt_priority = match raw.rt_priority {
            None => d.rt_priority,
            Some(0) => None,
            Some(p @ 1..=99) => Some(p as i32),
            Some(p) => {
                return Err(check.invalid(
                    "daemon.rt_priority",
                    p,
                    "must be a SCHED_FIFO priority 1..=99, or 0 for none",
                ))
            }
        };
        let spin_us = match raw.spin_us {
            None => d.spin_us,
            Some(s @ 0..=500) => s as u64,
            Some(s) => return Err(check.invalid("daemon.spin_us", s, "must be in [0, 500] us")),
        };
        let cpu_latency_us = match raw.cpu_latency_us {
            None => d.cpu_latency_us,
            Some(-1) => None,
            Some(us @ 0..=10_000) => Some(us as u32),
            Some(us) => {
                return Err(check.invalid(
                    "daemon.cpu_latency_us",
                    us,
                    "must be in [0, 10000] us, or -1 to leave the system's setting",
                ))
            }
        };
        let telemetry_every = match raw.telemetry_every {
            None => d.telemetry_every,
            Some(n @ 1..=10_000) => n as u32,
            Some(n) => {
                return Err(check.invalid(
                    "daemon.telemetry_every",
                    n,
                    "must be in [1, 10000] ticks",
                ))
            }
        };
        let state_dir = match raw.state_dir {
            Some(s) if s.trim().is_empty() => {
                return Err(check.invalid("daemon.state_dir", "\"\"", "must name a directory"))
            }
            other => other.map(PathBuf::from),
        };
        let recordings_max_mb = match raw.recordings_max_mb {
            None => DEFAULT_RECORDINGS_MAX_MB,
            Some(mb) if RECORDINGS_MAX_MB_RANGE.contains(&mb) => mb as u64,
            Some(mb) => {
                return Err(check.invalid(
                    "daemon.recordings_max_mb",
                    mb,
                    "must be in [1, 1048576] MiB",
                ))
            }
        };
        Ok(DaemonConfig {
            recordings_max_mb,
            loop_options: LoopOptions {
                rt_priority,
                lock_memory: raw.lock_memory.unwrap_or(d.lock_memory),
                spin_us,
                cpu_latency_us,
                telemetry_every,
            },
            state_dir,
        })
    }
}

#[cfg(test)]
mod tests {
    use std::path::Path;

    use crate::cli::run::SIM_CONFIG;
    use crate::config::Config;

    /// The built-in simulated lab with `[daemon]` replaced by `daemon`.
    fn load(daemon: &str) -> Result<Config, String> {
        let base = SIM_CONFIG.split("\n[daemon]").next().unwrap_or_default();
        let rest = SIM_CONFIG.split("\n[monitor]").nth(1).unwrap_or_default();
        let text = format!("{base}\n[daemon]\n{daemon}\n\n[monitor]{rest}");
        Config::from_toml_str(&text, Path::new("lab.toml")).map_err(|e| e.to_string())
    }

    #[test]
    fn real_time_settings_and_their_defaults() {
        let options = load("").unwrap().daemon.loop_options;
        assert_eq!(options.rt_priority, Some(80));
        assert_eq!(options.cpu_latency_us, Some(0));
        let options = load("rt_priority = 0\ncpu_latency_us = -1\nspin_us = 0")
            .unwrap()
            .daemon
            .loop_options;
        assert_eq!(options.rt_priority, None);
        assert_eq!(options.cpu_latency_us, None);
        assert_eq!(options.spin_us, 0);
        let options = load("cpu_latency_us = 20").unwrap().daemon.loop_options;
        assert_eq!(options.cpu_latency_us, Some(20));
        assert_eq!(load("").unwrap().daemon.recordings_max_mb, 2048);
        assert_eq!(
            load("recordings_max_mb = 5")
                .unwrap()
                .daemon
                .recordings_max_mb,
            5
        );
    }

    #[test]
    fn out_of_range_values_name_file_key_and_value() {
        for (line, key, value) in [
            ("rt_priority = 100", "daemon.rt_priority", "100"),
            ("cpu_latency_us = -2", "daemon.cpu_latency_us", "-2"),
            ("spin_us = 501", "daemon.spin_us", "501"),
            ("telemetry_every = 0", "daemon.telemetry_every", "0"),
            ("recordings_max_mb = 0", "daemon.recordings_max_mb", "0"),
            (
                "recordings_max_mb = 1048577",
                "daemon.recordings_max_mb",
                "1048577",
            ),
        ] {
            let err = load(line).unwrap_err();
            assert!(
                err.contains("lab.toml") && err.contains(key) && err.contains(value),
                "{err}"
            );
        }
        assert!(load("spin = 3").unwrap_err().contains("spin"));
    }
}
