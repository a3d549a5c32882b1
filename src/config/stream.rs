//! `[stream]`: the live data stream (off unless `udp` is set). It sends to loopback only
//! unless `allow_remote = true`: the datagrams carry the run's forces in clear, to
//! whoever listens on that address. Not reloaded by SIGHUP.
use std::net::SocketAddr;

use serde::Deserialize;

use crate::checks::{Checker, ConfigError, Range};

// The accepted range, documented with the same words in config/sim.toml.
/// 0: no haptic stream; at most one datagram per tick of the 1 kHz loop.
const HAPTIC_HZ: Range = Range::new(1.0, 1000.0, "Hz").or_zero();

#[derive(Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub(crate) struct RawStream {
    udp: Option<String>,
    allow_remote: Option<bool>,
    haptic_hz: Option<f64>,
}

/// Validated `[stream]`.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct StreamConfig {
    /// Where the datagrams go; None: no stream.
    pub udp: Option<SocketAddr>,
    /// Datagrams of the haptic loop's state per second; 0: none (estimates only).
    pub haptic_hz: f64,
}

impl StreamConfig {
    pub(crate) fn validate(raw: RawStream, check: &Checker) -> Result<StreamConfig, ConfigError> {
        let allow_remote = raw.allow_remote.unwrap_or(false);
        let udp = raw
            .udp
            .map(|text| destination(&text, allow_remote, check))
            .transpose()?;
        let haptic_hz = check.number_or("stream.haptic_hz", raw.haptic_hz, 0.0, HAPTIC_HZ)?;
        Ok(StreamConfig { udp, haptic_hz })
    }
}

/// `stream.udp`: one receiver's address and port, on loopback unless allowed.
fn destination(text: &str, allow_remote: bool, check: &Checker) -> Result<SocketAddr, ConfigError> {
    let quoted = format!("{text:?}");
    let addr: SocketAddr = text.trim().parse().map_err(|_| {
        check.invalid(
            "stream.udp",
            &quoted,
            "must be an address and port such as \"127.0.0.1:9870\"",
        )
    })?;
    if addr.ip().is_unspecified() || addr.port() == 0 {
        return Err(check.invalid(
            "stream.udp",
            quoted,
            "must name the receiver: an address other than 0.0.0.0 or ::, and a port other \
             than 0",
        ));
    }
    if !addr.ip().is_loopback() && !allow_remote {
        return Err(check.invalid(
            "stream.udp",
            quoted,
            "is not a loopback address: the stream is not encrypted and anyone on that \
             network may read it; set stream.allow_remote = true to send it there anyway",
        ));
    }
    Ok(addr)
}

#[cfg(test)]
mod tests {
    use crate::config::Config;
    use std::path::Path;

    fn parse(section: &str) -> Result<super::StreamConfig, String> {
        let text = format!(
            "[cantilever]\nlength_um = 400\nspring_constant_n_per_m = 1\n[stream]\n{section}"
        );
        Config::from_toml_str(&text, Path::new("lab.toml"))
            .map(|c| c.stream)
            .map_err(|e| e.to_string())
    }

    #[test]
    fn off_by_default_and_loopback_accepted() {
        let s = parse("").unwrap();
        assert_eq!(s, super::StreamConfig::default());
        assert!(s.udp.is_none() && s.haptic_hz == 0.0);
        let s = parse("udp = \"127.0.0.1:9870\"\nhaptic_hz = 1000\n").unwrap();
        assert_eq!(s.udp.unwrap().port(), 9870);
        assert_eq!(s.haptic_hz, 1000.0);
        assert!(parse("udp = \"[::1]:9870\"\n").is_ok());
    }

    #[test]
    fn remote_addresses_need_allow_remote() {
        let err = parse("udp = \"192.168.1.20:9870\"\n").unwrap_err();
        assert!(
            err.starts_with("lab.toml: stream.udp is not a loopback address")
                && err.contains("stream.allow_remote = true")
                && err.ends_with("got \"192.168.1.20:9870\""),
            "{err}"
        );
        let s = parse("udp = \"192.168.1.20:9870\"\nallow_remote = true\n").unwrap();
        assert_eq!(s.udp.unwrap().to_string(), "192.168.1.20:9870");
    }

    #[test]
    fn bad_values_name_key_and_value() {
        for (line, value) in [
            ("udp = \"localhost:9870\"", "\"localhost:9870\""),
            ("udp = \"127.0.0.1\"", "\"127.0.0.1\""),
            ("udp = \"127.0.0.1:0\"", "\"127.0.0.1:0\""),
            (
                "udp = \"0.0.0.0:9870\"\nallow_remote = true",
                "\"0.0.0.0:9870\"",
            ),
        ] {
            let err = parse(line).unwrap_err();
            assert!(
                err.starts_with("lab.toml: stream.udp ") && err.ends_with(value),
                "{err}"
            );
        }
        assert_eq!(
            parse("haptic_hz = 2000\n").unwrap_err(),
            "lab.toml: stream.haptic_hz = 2000 is out of range: accepted 0 or 1 to 1000 Hz"
        );
        assert!(parse("haptic_hz = 0.5\n").is_err());
        assert!(parse("port = 3\n").unwrap_err().contains("port"));
    }
}
