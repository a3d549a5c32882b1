//! Verification: is the fitted hypothesis really the probe's tip, and how sure are we?
//!
//! A wrong force is worse than none, so a detection must pass checks that clutter
//! cannot pass by chance, beyond the rigid geometry the search already enforced:
//! - the apex lies in the frame and the rotation inside the search window (the
//!   tracker refuses those first, naming the reason: `Miss::ApexOutside`,
//!   `Miss::RotationOutside`);
//! - every edge the pose puts in view must be there, with a contrast comparable to the
//!   calibrated one (a scratch is a tenth as bright as the probe, a missing edge has
//!   none);
//! - the pyramid between the edges must be bright: the probe is a filled body, while
//!   two crossing scratches or a substrate corner bound nothing;
//! - the fitted rotation must be precise (its standard error from the fit).
//!
//! The confidence multiplies a score in [0, 1] for each; `detected` needs it above
//! [`MIN_CONFIDENCE`].

use image::GrayImage;

use super::geometry::{sub, Line};
use super::refine::FitResult;
use super::template::{PerEdge, Pose, Template, BLUE, EDGES, GREEN};

/// Share of the predicted segments covered by edge pixels from which coverage counts
/// fully (none below 0.3). On harsh frames at high magnification, Canny on the binned
/// image breaks true faces into pieces covering 52-59 % of them while the grey-level fit
/// holds them (docs/tracker.md, step 7); blank frames stay far below 0.5 either way.
const FULL_COVERAGE: f64 = 0.55;
/// Smallest confidence reported as a detection.
pub const MIN_CONFIDENCE: f64 = 0.5;
/// An edge in view with less than this fraction of its calibrated contrast is missing.
pub const MIN_CONTRAST_RATIO: f64 = 0.2;
/// Fewest pyramid-interior samples for the brightness check.
const MIN_INTERIOR_SAMPLES: usize = 8;
/// Most interior samples (a grid is thinned to about this many).
const MAX_INTERIOR_SAMPLES: usize = 400;

/// The evidence for one hypothesis, each part in its natural unit.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Evidence {
    /// Share of the predicted edge segments covered by edge pixels.
    pub coverage: f64,
    /// Smallest fitted/calibrated contrast over the edges in view.
    pub contrast_ratio: f64,
    /// Where the pyramid's median grey level lies between the outside (0) and the edges'
    /// inner level (1).
    pub interior: f64,
    /// Standard error of the rotation, degrees.
    pub turn_sigma_deg: f64,
}

impl Evidence {
    /// The combined confidence in [0, 1]: at most [`coverage_score`] of `coverage`,
    /// which it multiplies by other scores in [0, 1].
    pub fn confidence(&self) -> f64 {
        let coverage = coverage_score(self.coverage);
        let contrast = ramp(self.contrast_ratio, MIN_CONTRAST_RATIO, 0.45);
        let interior = ramp(self.interior, 0.4, 0.75);
        let precision = (-self.turn_sigma_deg / 0.3).exp();
        coverage * contrast * interior * precision
    }
}

/// Linear from 0 at `lo` to 1 at `hi`, clamped to [0, 1].
fn ramp(x: f64, lo: f64, hi: f64) -> f64 {
    ((x - lo) / (hi - lo)).clamp(0.0, 1.0)
}

/// The coverage's score in [0, 1], the first factor of [`Evidence::confidence`]: a
/// bound on the confidence known before the grey-level fit.
pub fn coverage_score(coverage: f64) -> f64 {
    ramp(coverage, 0.3, FULL_COVERAGE)
}

/// The fitted contrast of each edge in view relative to its calibrated contrast; the
/// smallest one (0 if an edge in view was not found at all).
pub fn contrast_ratio(fit: &FitResult, in_view: &PerEdge<bool>, calibrated: &PerEdge<f64>) -> f64 {
    let mut ratio = f64::INFINITY;
    for e in 0..EDGES {
        if !in_view[e] {
            continue;
        }
        // Signed: a darker probe's edges have negative contrasts.
        let scale = calibrated[e].abs().max(1.0).copysign(calibrated[e]);
        let r = fit.edges[e].map_or(0.0, |r| r.contrast / scale);
        ratio = ratio.min(r);
    }
    if ratio.is_finite() {
        ratio
    } else {
        0.0
    }
}

/// Median grey level inside the predicted pyramid (the triangle apex, blue base, green
/// base, shrunk by `margin` pixels), on a grid of at most [`MAX_INTERIOR_SAMPLES`]
/// points; `None` if too little of it is in view.
pub fn interior_median(frame: &GrayImage, t: &Template, pose: &Pose, margin: f64) -> Option<f64> {
    let apex = pose.apex;
    let base_b = t.segment(pose, BLUE).1;
    let base_g = t.segment(pose, GREEN).1;
    let blue = t.line(pose, BLUE);
    let green = t.line(pose, GREEN);
    let d = sub(base_g, base_b);
    let len = d[0].hypot(d[1]);
    if len < 1e-9 {
        return None;
    }
    let mut base = Line::through(base_b, [-d[1] / len, d[0] / len]);
    if base.depth(apex) < 0.0 {
        base = Line::through(base_b, [d[1] / len, -d[0] / len]);
    }
    let (w, h) = (frame.width() as f64, frame.height() as f64);
    let xs = [apex[0], base_b[0], base_g[0]];
    let ys = [apex[1], base_b[1], base_g[1]];
    let x0 = xs.iter().copied().fold(f64::INFINITY, f64::min).max(1.0);
    let x1 = xs
        .iter()
        .copied()
        .fold(f64::NEG_INFINITY, f64::max)
        .min(w - 2.0);
    let y0 = ys.iter().copied().fold(f64::INFINITY, f64::min).max(1.0);
    let y1 = ys
        .iter()
        .copied()
        .fold(f64::NEG_INFINITY, f64::max)
        .min(h - 2.0);
    if x1 <= x0 || y1 <= y0 {
        return None;
    }
    let step = (((x1 - x0) * (y1 - y0) / MAX_INTERIOR_SAMPLES as f64).sqrt()).max(1.0);
    let mut hist = [0u32; 256];
    let mut count = 0usize;
    let mut y = y0;
    while y <= y1 {
        let mut x = x0;
        while x <= x1 {
            let p = [x, y];
            if blue.depth(p) >= margin && green.depth(p) >= margin && base.depth(p) >= margin {
                hist[frame.get_pixel(x as u32, y as u32)[0] as usize] += 1;
                count += 1;
            }
            x += step;
        }
        y += step;
    }
    if count < MIN_INTERIOR_SAMPLES {
        return None;
    }
    let mut acc = 0;
    for (level, &n) in hist.iter().enumerate() {
        acc += n as usize;
        if 2 * acc >= count {
            return Some(level as f64);
        }
    }
    None
}

/// Where `median` lies between the fitted outside and inside levels of the edges, 0 to 1
/// (0 when there is no usable edge); `polarity` is the calibrated pyramid's (+1
/// brighter than its surroundings, -1 darker), and only edges of that polarity count.
pub fn interior_position(fit: &FitResult, median: f64, polarity: f64) -> f64 {
    let (mut outside, mut inside, mut n) = (0.0, 0.0, 0.0);
    for r in fit.edges.iter().flatten() {
        if r.contrast * polarity > 0.0 {
            outside += r.level;
            inside += r.level + r.contrast;
            n += 1.0;
        }
    }
    if n == 0.0 || (inside - outside) * polarity <= 0.0 {
        return 0.0;
    }
    (median - outside / n) / ((inside - outside) / n)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn confidence_is_at_most_the_coverage_score() {
        for coverage in [0.0, 0.31, 0.42, 0.5, 0.54, 0.55, 0.9] {
            for contrast_ratio in [0.1, 0.3, 0.45, 2.0] {
                for interior in [0.0, 0.6, 0.75, 1.5] {
                    for turn_sigma_deg in [0.0, 0.01, 1.0] {
                        let e = Evidence {
                            coverage,
                            contrast_ratio,
                            interior,
                            turn_sigma_deg,
                        };
                        assert!(e.confidence() <= coverage_score(coverage), "{e:?}");
                    }
                }
            }
        }
    }

    #[test]
    fn confidence_needs_every_kind_of_evidence() {
        let good = Evidence {
            coverage: 0.95,
            contrast_ratio: 0.8,
            interior: 1.0,
            turn_sigma_deg: 0.01,
        };
        assert!(good.confidence() > 0.9);
        for bad in [
            Evidence {
                coverage: 0.35,
                ..good
            },
            Evidence {
                contrast_ratio: 0.15,
                ..good
            },
            Evidence {
                interior: 0.2,
                ..good
            },
            Evidence {
                turn_sigma_deg: 1.0,
                ..good
            },
        ] {
            assert!(bad.confidence() < MIN_CONFIDENCE, "{bad:?}");
        }
    }
}
