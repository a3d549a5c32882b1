//! `[monitor]`: the live web page and the thumbnails a recording keeps. The page is off
//! unless `listen` is set, and it listens on loopback only unless `allow_remote = true`
//! (the page has no authentication). Not reloaded by SIGHUP.
use std::net::SocketAddr;

use serde::Deserialize;

use crate::checks::{Checker, ConfigError, Range};

// The accepted ranges, documented with the same words in config/sim.toml.
/// Each page holds a connection and a JPEG stream: a handful of people watch a lab.
const MAX_CLIENTS: Range = Range::new(1.0, 32.0, "");
/// The tracker copies a frame out for every page frame: at most 10 a second.
const FRAME_HZ: Range = Range::new(0.1, 10.0, "Hz");
/// 0: none; the 240 kept thumbnails cover 2 minutes to 10 days.
const THUMBNAIL_EVERY_S: Range = Range::new(0.5, 3600.0, "s").or_zero();

#[derive(Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub(crate) struct RawMonitor {
    listen: Option<String>,
    allow_remote: Option<bool>,
    max_clients: Option<i64>,
    frame_hz: Option<f64>,
    thumbnail_every_s: Option<f64>,
}

/// Validated `[monitor]`.
#[derive(Debug, Clone, PartialEq)]
pub struct MonitorConfig {
    /// Where the page is served; None: no page.
    pub listen: Option<SocketAddr>,
    /// Most live pages at once; more are refused (503).
    pub max_clients: usize,
    /// Frames per second the page shows (and the tracker copies for it), at most 10.
    pub frame_hz: f64,
    /// A recorded session keeps an overlay thumbnail this often; 0: none.
    pub thumbnail_every_s: f64,
}

impl Default for MonitorConfig {
    fn default() -> Self {
        MonitorConfig {
            listen: None,
            max_clients: 4,
            frame_hz: 4.0,
            thumbnail_every_s: 2.0,
        }
    }
}

impl MonitorConfig {
    /// Whether the tracker needs to copy frames out at all.
    pub fn wants_snapshots(&self, recording: bool) -> bool {
        self.listen.is_some() || (recording && self.thumbnail_every_s > 0.0)
    }

    pub(crate) fn validate(raw: RawMonitor, check: &Checker) -> Result<MonitorConfig, ConfigError> {
        let d = MonitorConfig::default();
        let allow_remote = raw.allow_remote.unwrap_or(false);
        let listen = match raw.listen {
            None => None,
            Some(text) => {
                let quoted = format!("{text:?}");
                let addr: SocketAddr = text.trim().parse().map_err(|_| {
                    check.invalid(
                        "monitor.listen",
                        &quoted,
                        "must be an address and port such as \"127.0.0.1:8080\"",
                    )
                })?;
                if !addr.ip().is_loopback() && !allow_remote {
                    return Err(check.invalid(
                        "monitor.listen",
                        quoted,
                        "is not a loopback address: the page has no authentication; set \
                         monitor.allow_remote = true to serve it on the network anyway",
                    ));
                }
                Some(addr)
            }
        };
        let max_clients = match raw.max_clients {
            None => d.max_clients,
            // In range, so it fits.
            Some(n) => check.whole("monitor.max_clients", n, MAX_CLIENTS)? as usize,
        };
        let frame_hz = check.number_or("monitor.frame_hz", raw.frame_hz, d.frame_hz, FRAME_HZ)?;
        let thumbnail_every_s = check.number_or(
            "monitor.thumbnail_every_s",
            raw.thumbnail_every_s,
            d.thumbnail_every_s,
            THUMBNAIL_EVERY_S,
        )?;
        Ok(MonitorConfig {
            listen,
            max_clients,
            frame_hz,
            thumbnail_every_s,
        })
    }
}

#[cfg(test)]
mod tests {
    use crate::config::Config;
    use std::path::Path;

    fn parse(section: &str) -> Result<super::MonitorConfig, String> {
        let text = format!(
            "[cantilever]\nlength_um = 400\nspring_constant_n_per_m = 1\n[monitor]\n{section}"
        );
        Config::from_toml_str(&text, Path::new("lab.toml"))
            .map(|c| c.monitor)
            .map_err(|e| e.to_string())
    }

    #[test]
    fn off_by_default_and_loopback_accepted() {
        let m = parse("").unwrap();
        assert_eq!(m, super::MonitorConfig::default());
        assert!(m.listen.is_none());
        let m = parse("listen = \"127.0.0.1:8080\"\nmax_clients = 2\nframe_hz = 10\n").unwrap();
        assert_eq!(m.listen.unwrap().port(), 8080);
        assert_eq!((m.max_clients, m.frame_hz), (2, 10.0));
        assert!(parse("listen = \"[::1]:9000\"\n").is_ok());
    }

    #[test]
    fn remote_addresses_need_allow_remote() {
        let err = parse("listen = \"0.0.0.0:8080\"\n").unwrap_err();
        assert!(
            err.starts_with("lab.toml: monitor.listen is not a loopback address")
                && err.contains("allow_remote")
                && err.ends_with("got \"0.0.0.0:8080\""),
            "{err}"
        );
        let m = parse("listen = \"0.0.0.0:8080\"\nallow_remote = true\n").unwrap();
        assert!(m.listen.is_some());
    }

    #[test]
    fn bad_values_name_key_and_value() {
        let err = parse("listen = \"localhost\"\n").unwrap_err();
        assert!(
            err.contains("monitor.listen") && err.contains("\"localhost\""),
            "{err}"
        );
        let err = parse("max_clients = 0\n").unwrap_err();
        assert_eq!(
            err,
            "lab.toml: monitor.max_clients = 0 is out of range: accepted 1 to 32"
        );
        let err = parse("frame_hz = 30\n").unwrap_err();
        assert!(
            err.contains("monitor.frame_hz") && err.contains("30"),
            "{err}"
        );
        let err = parse("thumbnail_every_s = 0.1\n").unwrap_err();
        assert!(err.contains("monitor.thumbnail_every_s"), "{err}");
        let err = parse("port = 3\n").unwrap_err();
        assert!(err.contains("port"), "{err}");
    }
}
