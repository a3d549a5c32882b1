//! Wall-clock anchors for a session's times. Every time a run records is seconds on the
//! daemon's monotonic [`Clock`] since its start (t = 0); a [`UtcAnchor`] says which UTC
//! time t = 0 was, so the CSVs can be lined up with other instruments' logs.
//! Written into `session.json` by the recorder, read back by `replay`.
use std::time::{SystemTime, UNIX_EPOCH};

use serde::{Deserialize, Serialize};

use crate::hw::Clock;

/// The UTC time of a clock's t = 0, and the clock's CLOCK_MONOTONIC time there.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub struct UtcAnchor {
    /// t = 0 in nanoseconds since 1970-01-01T00:00:00Z.
    pub t0_unix_ns: i64,
    /// t = 0 in CLOCK_MONOTONIC nanoseconds (the pipe protocol's capture times).
    pub t0_monotonic_ns: u64,
}

impl UtcAnchor {
    /// Measures `clock`'s t = 0 against the system's UTC clock now.
    pub fn measure(clock: &Clock) -> UtcAnchor {
        let before_s = clock.now_s();
        let unix_ns = SystemTime::now()
            .duration_since(UNIX_EPOCH)
            .map_or(0, |d| d.as_nanos() as i64);
        let after_s = clock.now_s();
        let t_s = 0.5 * (before_s + after_s);
        UtcAnchor {
            t0_unix_ns: unix_ns - (t_s * 1e9).round() as i64,
            t0_monotonic_ns: clock.monotonic_ns_at(0.0),
        }
    }

    /// UTC minus CLOCK_MONOTONIC, nanoseconds: add it to a CLOCK_MONOTONIC time to get
    /// Unix time.
    pub fn utc_minus_monotonic_ns(&self) -> i64 {
        self.t0_unix_ns - self.t0_monotonic_ns as i64
    }

    /// Nanoseconds since the Unix epoch of `t_s` seconds on the clock.
    pub fn unix_ns(&self, t_s: f64) -> i64 {
        self.t0_unix_ns + (t_s * 1e9).round() as i64
    }

    /// `t_s` as ISO 8601 UTC with microseconds, `2026-12-03T00:01:08.123456Z`.
    pub fn utc(&self, t_s: f64) -> String {
        if !t_s.is_finite() {
            return String::new();
        }
        format_utc_ns(self.unix_ns(t_s))
    }

    /// Seconds on the clock of a CLOCK_MONOTONIC time in nanoseconds.
    pub fn seconds_at(&self, monotonic_ns: u64) -> f64 {
        (i128::from(monotonic_ns) - i128::from(self.t0_monotonic_ns)) as f64 * 1e-9
    }
}

/// ISO 8601 UTC with microseconds (rounded down) of nanoseconds since the Unix epoch.
pub fn format_utc_ns(unix_ns: i64) -> String {
    let secs = unix_ns.div_euclid(1_000_000_000);
    let micros = unix_ns.rem_euclid(1_000_000_000) / 1000;
    let (year, month, day) = civil_from_days(secs.div_euclid(86_400));
    let rem = secs.rem_euclid(86_400);
    format!(
        "{year:04}-{month:02}-{day:02}T{:02}:{:02}:{:02}.{micros:06}Z",
        rem / 3600,
        rem % 3600 / 60,
        rem % 60
    )
}

/// Year, month, day of a day count since 1970-01-01 (proleptic Gregorian).
pub fn civil_from_days(days: i64) -> (i64, i64, i64) {
    let z = days + 719_468;
    let era = z.div_euclid(146_097);
    let doe = z - era * 146_097;
    let yoe = (doe - doe / 1460 + doe / 36_524 - doe / 146_096) / 365;
    let doy = doe - (365 * yoe + yoe / 4 - yoe / 100);
    let mp = (5 * doy + 2) / 153;
    let day = doy - (153 * mp + 2) / 5 + 1;
    let month = if mp < 10 { mp + 3 } else { mp - 9 };
    (yoe + era * 400 + i64::from(month <= 2), month, day)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A capture time half a nanosecond off a printed microsecond's boundary prints
    /// alike once held to whole nanoseconds: live, and read back from the recording.
    #[test]
    fn a_time_held_to_whole_nanoseconds_reads_back_to_the_bit() {
        let clock = Clock::start();
        let anchor = UtcAnchor::measure(&clock);
        for t in [0.057_136_499_6, 0.057_136_500_4, 12.345_678_5, 1.0 / 3.0] {
            let held = clock.to_whole_ns(t);
            let read_back = anchor.seconds_at(clock.monotonic_ns_at(t));
            assert_eq!(held.to_bits(), read_back.to_bits(), "{t}");
            assert_eq!(format!("{held:.6}"), format!("{read_back:.6}"));
            assert!((held - t).abs() <= 0.5e-9, "{t} -> {held}");
        }
    }

    #[test]
    fn formats_utc_with_microseconds() {
        assert_eq!(format_utc_ns(0), "1970-01-01T00:00:00.000000Z");
        assert_eq!(
            format_utc_ns(951_782_400_000_000_000 + 1_234_567_890),
            "2000-02-29T00:00:01.234567Z"
        );
        assert_eq!(format_utc_ns(-1000), "1969-12-31T23:59:59.999999Z");
    }

    #[test]
    fn the_anchor_matches_the_system_clock() {
        let clock = Clock::start();
        std::thread::sleep(std::time::Duration::from_millis(5));
        let anchor = UtcAnchor::measure(&clock);
        let now_unix_ns = SystemTime::now()
            .duration_since(UNIX_EPOCH)
            .unwrap()
            .as_nanos() as i64;
        let error_ns = anchor.unix_ns(clock.now_s()) - now_unix_ns;
        assert!(error_ns.abs() < 2_000_000, "{error_ns} ns");
        assert_eq!(anchor.seconds_at(clock.monotonic_ns_at(1.5)), 1.5);
        assert_eq!(
            anchor.t0_unix_ns - anchor.utc_minus_monotonic_ns(),
            anchor.t0_monotonic_ns as i64
        );
        assert_eq!(anchor.utc(f64::NAN), "");
    }
}
