//! The stream's datagrams: one JSON object each, built into a reused buffer. The field
//! names and units are an interface (docs/stream.md); a value the daemon does not know
//! (no detection, no stylus reading) is `null`, never a made-up number.
use std::fmt;

use serde::{Serialize, Serializer};

use crate::config::PixelOrigin;
use crate::control::Published;
use crate::daemon::tick_record::TickRecord;
use crate::session::utc::{civil_from_days, UtcAnchor};

/// A Unix time printed as RFC 3339 UTC with microseconds: `2026-12-03T00:01:10.123456Z`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Utc(pub f64);

impl fmt::Display for Utc {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let micros = (self.0 * 1e6).round() as i64;
        let secs = micros.div_euclid(1_000_000);
        let (year, month, day) = civil_from_days(secs.div_euclid(86_400));
        let rem = secs.rem_euclid(86_400);
        write!(
            f,
            "{year:04}-{month:02}-{day:02}T{:02}:{:02}:{:02}.{:06}Z",
            rem / 3600,
            rem / 60 % 60,
            rem % 60,
            micros.rem_euclid(1_000_000)
        )
    }
}

impl Serialize for Utc {
    fn serialize<S: Serializer>(&self, serializer: S) -> Result<S::Ok, S::Error> {
        if self.0.is_finite() {
            serializer.collect_str(self)
        } else {
            serializer.serialize_none()
        }
    }
}

/// A number, or None (JSON null) when it is not finite.
fn known(v: f64) -> Option<f64> {
    v.is_finite().then_some(v)
}

#[derive(Serialize)]
struct EstimateDatagram {
    kind: &'static str,
    /// The probe's place among the configured probes (0: the first, or the lone one).
    probe: usize,
    seq: u64,
    frame_seq: u64,
    utc: Utc,
    unix_s: f64,
    t_s: f64,
    detected: bool,
    angle_deg: Option<f64>,
    #[serde(rename = "force_nN")]
    force_nn: Option<f64>,
    tip_x: Option<f64>,
    tip_y: Option<f64>,
    confidence: f64,
    angle_sigma_deg: Option<f64>,
    force_saturated: bool,
    felt: bool,
}

#[derive(Serialize)]
struct HapticDatagram {
    kind: &'static str,
    /// The probe the stylus feels and drives, by its place among the probes.
    probe: usize,
    seq: u64,
    utc: Utc,
    unix_s: f64,
    t_s: f64,
    state: &'static str,
    position_mm: [Option<f64>; 3],
    #[serde(rename = "stylus_force_N")]
    stylus_force_n: [Option<f64>; 3],
    stage_velocity_um_s: [Option<f64>; 3],
    #[serde(rename = "rendered_force_nN")]
    rendered_force_nn: Option<f64>,
    press_blocked: bool,
}

/// How datagrams are stamped and where their pixels count from.
#[derive(Debug, Clone, Copy)]
pub struct Format {
    /// The session's anchor (session.json), so the stream and the CSVs share one UTC.
    pub anchor: UtcAnchor,
    /// `tracker.pixel_origin`, as in estimates.csv.
    pub pixel_origin: PixelOrigin,
}

impl Format {
    /// Writes the datagram of a published estimate into `out` (cleared first).
    pub fn estimate(&self, out: &mut Vec<u8>, p: &Published) {
        let e = &p.estimate;
        let apex = e.apex_px.map(|a| self.pixel_origin.output(a));
        let tip = [0, 1].map(|i| e.shown(apex.map(|a| a[i])));
        let unix_s = self.anchor.unix_ns(p.frame_time_s) as f64 * 1e-9;
        let datagram = EstimateDatagram {
            kind: "estimate",
            probe: p.probe,
            seq: p.seq,
            frame_seq: p.frame_sequence,
            utc: Utc(unix_s),
            unix_s,
            t_s: p.frame_time_s,
            detected: e.detected,
            angle_deg: e.shown(e.angle_deg),
            force_nn: e.shown(e.force_nn),
            tip_x: tip[0],
            tip_y: tip[1],
            confidence: e.confidence,
            angle_sigma_deg: e.shown(e.angle_sigma_deg),
            force_saturated: e.force_saturated,
            felt: e.felt_force_nn().is_some(),
        };
        write(out, &datagram);
    }

    /// Writes the datagram of one haptic tick, the `seq`-th sent, into `out`.
    pub fn haptic(&self, out: &mut Vec<u8>, seq: u64, r: &TickRecord) {
        let unix_s = self.anchor.unix_ns(r.t_s) as f64 * 1e-9;
        let datagram = HapticDatagram {
            kind: "haptic",
            probe: r.felt_probe,
            seq,
            utc: Utc(unix_s),
            unix_s,
            t_s: r.t_s,
            state: r.state.as_str(),
            position_mm: r.position_mm.map(known),
            stylus_force_n: r.force_n.map(known),
            stage_velocity_um_s: r.velocity_um_s.map(known),
            rendered_force_nn: known(r.rendered_force_nn),
            press_blocked: r.press_blocked,
        };
        write(out, &datagram);
    }
}

fn write(out: &mut Vec<u8>, datagram: &impl Serialize) {
    out.clear();
    // Writing into a Vec cannot fail, and every field serializes.
    let _ = serde_json::to_writer(&mut *out, datagram);
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::control::SafetyState;
    use crate::vision::Estimate;

    #[test]
    fn utc_is_rfc3339_with_microseconds() {
        let shown = [
            0.0,
            951_782_400.0,
            1_796_256_070.123_456,
            -0.5,
            4_102_444_799.999_999_6,
        ]
        .map(|s| Utc(s).to_string());
        assert_eq!(
            shown,
            [
                "1970-01-01T00:00:00.000000Z",
                "2000-02-29T00:00:00.000000Z",
                "2026-12-03T00:01:10.123456Z",
                "1969-12-31T23:59:59.500000Z",
                "2100-01-01T00:00:00.000000Z",
            ]
        );
    }

    fn json(bytes: &[u8]) -> serde_json::Value {
        serde_json::from_slice(bytes).unwrap()
    }

    #[test]
    fn estimate_fields_and_nulls() {
        let format = Format {
            anchor: UtcAnchor {
                t0_unix_ns: 1_796_256_000_000_000_000,
                t0_monotonic_ns: 0,
            },
            pixel_origin: PixelOrigin::Corner,
        };
        let mut out = Vec::new();
        let e = Published {
            probe: 0,
            seq: 7,
            frame_sequence: 9,
            frame_time_s: 70.25,
            published_s: 70.26,
            estimate: Estimate {
                detected: true,
                angle_deg: Some(1.5),
                force_nn: Some(2500.0),
                apex_px: Some([100.0, 200.0]),
                confidence: 0.875,
                ..Estimate::default()
            },
        };
        format.estimate(&mut out, &e);
        let v = json(&out);
        assert_eq!(v["kind"], "estimate");
        assert_eq!(
            (v["seq"].as_u64(), v["frame_seq"].as_u64()),
            (Some(7), Some(9))
        );
        assert_eq!(v["utc"], "2026-12-03T00:01:10.250000Z");
        assert_eq!(v["unix_s"], 1_796_256_070.25);
        assert_eq!(v["t_s"], 70.25);
        assert_eq!(v["force_nN"], 2500.0);
        assert_eq!(
            (v["tip_x"].as_f64(), v["tip_y"].as_f64()),
            (Some(100.5), Some(200.5))
        );
        assert!(v["angle_sigma_deg"].is_null());
        // Not detected: what is unknown is null.
        format.estimate(&mut out, &Published::default());
        let v = json(&out);
        assert_eq!(v["detected"], false);
        for key in ["angle_deg", "force_nN", "tip_x", "tip_y", "angle_sigma_deg"] {
            assert!(v[key].is_null(), "{key}: {v}");
        }
    }

    #[test]
    fn haptic_fields() {
        let format = Format {
            anchor: UtcAnchor {
                t0_unix_ns: 0,
                t0_monotonic_ns: 0,
            },
            pixel_origin: PixelOrigin::Centre,
        };
        let record = TickRecord {
            t_s: 1.0,
            period_us: 1000.0,
            position_mm: [f64::NAN; 3],
            force_n: [0.1, 0.0, -0.2],
            velocity_um_s: [5.0, 0.0, 0.0],
            rendered_force_nn: 150.0,
            state: SafetyState::Engaged,
            press_blocked: true,
            gate_held: 0,
            gate_attenuated: 0,
            felt_probe: 1,
        };
        let mut out = Vec::new();
        format.haptic(&mut out, 3, &record);
        let v = json(&out);
        assert_eq!(v["kind"], "haptic");
        assert_eq!(v["probe"], 1);
        assert_eq!(v["seq"], 3);
        assert_eq!(v["utc"], "1970-01-01T00:00:01.000000Z");
        assert_eq!(v["state"], SafetyState::Engaged.as_str());
        assert!(v["position_mm"][0].is_null());
        assert_eq!(v["stylus_force_N"][2], -0.2);
        assert_eq!(v["stage_velocity_um_s"][0], 5.0);
        assert_eq!(v["rendered_force_nN"], 150.0);
        assert_eq!(v["press_blocked"], true);
    }
}
