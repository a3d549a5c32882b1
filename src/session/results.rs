//! The results CSV of a replay: one row per frame. The first six columns are fixed
//! (`frame, detected, angle_deg, force_nN, tip_x, tip_y`, empty when not detected), the
//! rest describe the estimate. Without timing the file is a pure function of the frames
//! and the configuration: a replay run twice gives byte-identical output.
use std::io::{self, Write};

use crate::vision::{Edge, Estimate, Miss};

/// The header; `timing` adds `processing_ms` (which varies from run to run).
pub fn header(timing: bool) -> String {
    let mut h = String::from(
        "frame,detected,angle_deg,force_nN,tip_x,tip_y,confidence,scale,force_saturated,\
         red_support,blue_support,green_support,miss",
    );
    if timing {
        h.push_str(",processing_ms");
    }
    h
}

/// Why there is no estimate, as written in the `miss` column.
pub fn miss_name(miss: Option<Miss>) -> &'static str {
    match miss {
        None => "",
        Some(Miss::NoCandidates) => "no-candidates",
        Some(Miss::Inconsistent) => "inconsistent",
        Some(Miss::LowConfidence) => "low-confidence",
    }
}

/// One row for a tracked frame.
pub fn write_row(
    out: &mut impl Write,
    frame: &str,
    e: &Estimate,
    processing_ms: Option<f64>,
) -> io::Result<()> {
    let fixed = |v: Option<f64>, digits: usize| match v.filter(|v| v.is_finite() && e.detected) {
        Some(v) => format!("{v:.digits$}"),
        None => String::new(),
    };
    let support = |edge: Edge| e.edges[edge.index()].map_or(0, |f| f.support);
    write!(
        out,
        "{},{},{},{},{},{},{:.4},{},{},{},{},{},{}",
        csv_field(frame),
        u8::from(e.detected),
        fixed(e.angle_deg, 6),
        fixed(e.force_nn, 4),
        fixed(e.apex_px.map(|a| a[0]), 3),
        fixed(e.apex_px.map(|a| a[1]), 3),
        e.confidence,
        e.scale.map_or(String::new(), |s| format!("{s:.5}")),
        u8::from(e.force_saturated),
        support(Edge::Red),
        support(Edge::Blue),
        support(Edge::Green),
        miss_name(e.miss),
    )?;
    if let Some(ms) = processing_ms {
        write!(out, ",{ms:.3}")?;
    }
    writeln!(out)
}

/// A row for a frame that could not be decoded: not detected, reason in `miss`.
pub fn write_unreadable(out: &mut impl Write, frame: &str, timing: bool) -> io::Result<()> {
    write!(out, "{},0,,,,,0.0000,,0,0,0,0,unreadable", csv_field(frame))?;
    if timing {
        write!(out, ",")?;
    }
    writeln!(out)
}

/// Quotes a field that holds a comma, quote or newline.
fn csv_field(s: &str) -> String {
    if s.contains([',', '"', '\n']) {
        format!("\"{}\"", s.replace('"', "\"\""))
    } else {
        s.to_string()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn undetected_rows_have_empty_values() {
        let mut out = Vec::new();
        write_row(
            &mut out,
            "f.png",
            &Estimate::missed(Miss::Inconsistent, 0.2),
            None,
        )
        .unwrap();
        assert_eq!(
            String::from_utf8(out).unwrap(),
            "f.png,0,,,,,0.2000,,0,0,0,0,inconsistent\n"
        );
        let mut out = Vec::new();
        write_unreadable(&mut out, "a,b.png", true).unwrap();
        assert_eq!(
            String::from_utf8(out).unwrap(),
            "\"a,b.png\",0,,,,,0.0000,,0,0,0,0,unreadable,\n"
        );
        assert_eq!(header(false).split(',').count(), 13);
    }
}
