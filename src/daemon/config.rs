//! `[daemon]`: how the daemon runs (real-time settings of the haptic loop, telemetry,
//! where sessions are recorded). Not reloaded by SIGHUP.
use std::path::PathBuf;

use serde::Deserialize;

use super::LoopOptions;
use crate::config::{Checker, ConfigError};

#[derive(Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub(crate) struct RawDaemon {
    rt_priority: Option<i64>,
    lock_memory: Option<bool>,
    spin_us: Option<i64>,
    telemetry_every: Option<i64>,
    state_dir: Option<String>,
}

/// Validated `[daemon]`.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct DaemonConfig {
    pub loop_options: LoopOptions,
    /// Where sessions are recorded; None: `$STATE_DIRECTORY` or the user's state dir.
    pub state_dir: Option<PathBuf>,
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
        Ok(DaemonConfig {
            loop_options: LoopOptions {
                rt_priority,
                lock_memory: raw.lock_memory.unwrap_or(d.lock_memory),
                spin_us,
                telemetry_every,
            },
            state_dir,
        })
    }
}
