//! Line candidates: each Hough peak polished into a least-squares line through the edge
//! pixels that support it (right distance, right gradient direction), with a support
//! profile along it. The profile answers, in O(1), "how much of this stretch of the
//! line is edge?", which is what the rigid-tip search asks thousands of times.

use super::edges::EdgePoint;
use super::geometry::{along, clip_to_rect, dot, scale, sub, wrap_pi};
use super::hough::{Peak, WIDE_PEAKS_PER_EDGE};
use super::template::{PerEdge, EDGES};

/// Inlier band half-width around a candidate line, detection pixels.
const INLIER_PX: f64 = 1.5;
/// Smallest cosine between a pixel's gradient and the line's normal (0.2 rad).
const INLIER_COS: f64 = 0.980_066_577_841_241_6;
/// Two candidates of one edge closer than this in angle and offset are one line.
const DUPLICATE_ANGLE_RAD: f64 = 0.02;
const DUPLICATE_PX: f64 = 1.0;
/// A raw peak this close to a listed candidate is not polished again.
const COVERED_ANGLE_RAD: f64 = 0.026;
const COVERED_PX: f64 = 1.5;
/// Line candidates kept per edge: the distinct lines of its strongest Hough peaks.
pub const CANDIDATES_PER_EDGE: usize = 16;
/// Candidates per edge of a wide search (with [`WIDE_PEAKS_PER_EDGE`] peaks).
pub const WIDE_CANDIDATES_PER_EDGE: usize = 24;

/// Profile bins per candidate (longer lines are clipped; the detection image is small).
pub const PROFILE_BINS: usize = 1024;

/// A polished line for one edge.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Candidate {
    pub edge: usize,
    /// Tip rotation this line implies, image radians.
    pub psi: f64,
    /// Inward unit normal (detection image).
    pub normal: [f64; 2],
    /// Centroid of the supporting pixels; `t` coordinates are measured from here.
    pub centroid: [f64; 2],
    /// 1-sigma uncertainty of `psi` from the fit, radians.
    pub psi_sigma: f64,
    pub count: u32,
    /// `t` of the first profile bin and the bin width (pixels along the line).
    t_first: f64,
    bin: f64,
    bins: usize,
    /// Index of this candidate's prefix sums in the shared buffer.
    slot: usize,
}

/// The candidates of one frame and their shared profile storage.
#[derive(Debug, Default)]
pub struct Candidates {
    pub list: Vec<Candidate>,
    prefix: Vec<u16>,
    marks: Vec<u8>,
}

impl Candidates {
    /// Polishes every peak into a candidate, keeping at most `per_edge` per edge
    /// ([`CANDIDATES_PER_EDGE`], or [`WIDE_CANDIDATES_PER_EDGE`] in a wide search);
    /// `voters[e]` lists the points that could belong to edge e (the Hough stage's
    /// polarity test).
    pub fn build(
        &mut self,
        peaks: &[Peak],
        points: &[EdgePoint],
        voters: &PerEdge<Vec<u32>>,
        normal_angles: PerEdge<f64>,
        size: [usize; 2],
        per_edge: usize,
    ) {
        self.list.clear();
        // Sized for the most peaks there can be: no growth from frame to frame.
        let most = EDGES * WIDE_PEAKS_PER_EDGE;
        debug_assert!(peaks.len() <= most);
        self.list.reserve(most);
        self.prefix.resize(most * (PROFILE_BINS + 1), 0);
        self.marks.resize(PROFILE_BINS, 0);
        for (slot, peak) in peaks.iter().enumerate() {
            if self.list.iter().filter(|o| o.edge == peak.edge).count() >= per_edge {
                continue;
            }
            let nu = normal_angles[peak.edge] + peak.psi;
            let mut normal = [nu.cos(), nu.sin()];
            let mut rho = peak.rho;
            if self.covered(peak.edge, peak.psi, normal, rho) {
                continue;
            }
            let mine = Voters {
                points,
                index: &voters[peak.edge],
            };
            let mut fit = None;
            for band in [INLIER_PX + 0.5, INLIER_PX] {
                match fit_line(&mine, normal, rho, band) {
                    Some(f) => {
                        normal = f.normal;
                        rho = dot(normal, f.centroid);
                        fit = Some(f);
                    }
                    None => break,
                }
            }
            let Some(fit) = fit else { continue };
            let psi = wrap_pi(normal[1].atan2(normal[0]) - normal_angles[peak.edge]);
            let mut cand = Candidate {
                edge: peak.edge,
                psi,
                normal,
                centroid: fit.centroid,
                psi_sigma: fit.psi_sigma,
                count: fit.count,
                t_first: 0.0,
                bin: 1.0,
                bins: 0,
                slot,
            };
            if !self.duplicate(&cand) && self.profile(&mut cand, &mine, size) {
                self.list.push(cand);
            }
        }
    }

    /// Whether a raw peak already lies on a listed candidate of its edge (then polishing
    /// it would only find that line again).
    fn covered(&self, edge: usize, psi: f64, normal: [f64; 2], rho: f64) -> bool {
        self.list.iter().any(|o| {
            o.edge == edge
                && wrap_pi(o.psi - psi).abs() < COVERED_ANGLE_RAD
                && (dot(normal, o.centroid) - rho).abs() < COVERED_PX
        })
    }

    /// Whether an equivalent line (same edge, direction and position) is already listed:
    /// a long line leaves peaks in several neighbouring cells that polish to one line.
    fn duplicate(&self, c: &Candidate) -> bool {
        self.list.iter().any(|o| {
            o.edge == c.edge
                && wrap_pi(o.psi - c.psi).abs() < DUPLICATE_ANGLE_RAD
                && (dot(o.normal, sub(c.centroid, o.centroid))).abs() < DUPLICATE_PX
                && (dot(c.normal, sub(o.centroid, c.centroid))).abs() < DUPLICATE_PX
        })
    }

    /// Builds the support profile of `c` over the part of its line inside the image.
    fn profile(&mut self, c: &mut Candidate, points: &Voters, size: [usize; 2]) -> bool {
        let d = along(c.normal);
        let hi = [size[0] as f64 - 1.0, size[1] as f64 - 1.0];
        let Some((t0, t1)) = clip_to_rect(c.centroid, d, [0.0, 0.0], hi) else {
            return false;
        };
        // Digital lines have one pixel per `1 / max(|dx|, |dy|)` of length.
        c.bin = 1.0 / d[0].abs().max(d[1].abs());
        c.t_first = t0;
        c.bins = (((t1 - t0) / c.bin).ceil() as usize + 1).min(PROFILE_BINS);
        let marks = &mut self.marks[..c.bins];
        marks.iter_mut().for_each(|m| *m = 0);
        let rho = dot(c.normal, c.centroid);
        for p in points.iter() {
            let q = [p.x as f64, p.y as f64];
            if (dot(c.normal, q) - rho).abs() > INLIER_PX || p.alignment(c.normal) < INLIER_COS {
                continue;
            }
            // Truncation is floor here (non-negative); f64::floor is a libm call on
            // baseline x86-64.
            let i = (dot(d, sub(q, c.centroid)) - t0) / c.bin;
            if i >= 0.0 && (i as usize) < c.bins {
                marks[i as usize] = 1;
            }
        }
        // Close single-bin gaps left by sub-pixel jitter.
        for i in 1..c.bins.saturating_sub(1) {
            if marks[i] == 0 && marks[i - 1] == 1 && marks[i + 1] == 1 {
                marks[i] = 2;
            }
        }
        let prefix = &mut self.prefix[c.slot * (PROFILE_BINS + 1)..][..c.bins + 1];
        prefix[0] = 0;
        for i in 0..c.bins {
            prefix[i + 1] = prefix[i] + (marks[i] != 0) as u16;
        }
        true
    }

    /// Supported and visible length (pixels) of the stretch `[ta, tb]` of candidate `c`'s
    /// line (`t` from its centroid, either order).
    pub fn support(&self, c: &Candidate, ta: f64, tb: f64) -> (f64, f64) {
        let (lo, hi) = (ta.min(tb), ta.max(tb));
        let bin_of = |t: f64| ((t - c.t_first) / c.bin + 0.5).clamp(0.0, c.bins as f64) as usize;
        let (a, b) = (bin_of(lo), bin_of(hi));
        if b <= a {
            return (0.0, 0.0);
        }
        let prefix = &self.prefix[c.slot * (PROFILE_BINS + 1)..];
        let sup = (prefix[b] - prefix[a]) as f64;
        (sup * c.bin, (b - a) as f64 * c.bin)
    }

    /// Where `c`'s profile can contribute to [`Candidates::support`], for bounding it
    /// without the look-ups: the bin width, the `t` range the profile spans, and the
    /// range its supported bins span (`None` without support).
    pub fn reach(&self, c: &Candidate) -> (f64, [f64; 2], Option<[f64; 2]>) {
        let prefix = &self.prefix[c.slot * (PROFILE_BINS + 1)..][..c.bins + 1];
        let t = |k: usize| c.t_first + k as f64 * c.bin;
        let total = prefix[c.bins];
        // Bin k is supported when prefix[k + 1] > prefix[k].
        let supported = (total > 0).then(|| {
            let first = prefix.partition_point(|&p| p == 0) - 1;
            let last = prefix.partition_point(|&p| p < total) - 1;
            [t(first), t(last)]
        });
        (c.bin, [t(0), t(c.bins)], supported)
    }

    /// `t` of frame point `p` on candidate `c`'s line.
    pub fn t_of(c: &Candidate, p: [f64; 2]) -> f64 {
        dot(along(c.normal), sub(p, c.centroid))
    }
}

/// Angle between a gradient direction and a line normal, radians.
pub fn angle_gap(angle: f64, normal: [f64; 2]) -> f64 {
    wrap_pi(angle - normal[1].atan2(normal[0])).abs()
}

/// The points one edge may use.
struct Voters<'a> {
    points: &'a [EdgePoint],
    index: &'a [u32],
}

impl Voters<'_> {
    fn iter(&self) -> impl Iterator<Item = &EdgePoint> + '_ {
        self.index.iter().map(|&i| &self.points[i as usize])
    }
}

struct Fit {
    normal: [f64; 2],
    centroid: [f64; 2],
    psi_sigma: f64,
    count: u32,
}

/// Total-least-squares line through the points within `band` of `normal . p = rho`
/// whose gradient agrees with `normal`; the new normal keeps the old orientation.
fn fit_line(points: &Voters, normal: [f64; 2], rho: f64, band: f64) -> Option<Fit> {
    let (mut n, mut sx, mut sy) = (0.0, 0.0, 0.0);
    let (mut sxx, mut sxy, mut syy) = (0.0, 0.0, 0.0);
    for p in points.iter() {
        let q = [p.x as f64, p.y as f64];
        if (dot(normal, q) - rho).abs() > band || p.alignment(normal) < INLIER_COS {
            continue;
        }
        n += 1.0;
        sx += q[0];
        sy += q[1];
        sxx += q[0] * q[0];
        sxy += q[0] * q[1];
        syy += q[1] * q[1];
    }
    if n < 4.0 {
        return None;
    }
    let c = [sx / n, sy / n];
    let (cxx, cxy, cyy) = (
        sxx / n - c[0] * c[0],
        sxy / n - c[0] * c[1],
        syy / n - c[1] * c[1],
    );
    // Normal = eigenvector of the smaller eigenvalue of the scatter matrix.
    let half_diff = 0.5 * (cxx - cyy);
    let root = (half_diff * half_diff + cxy * cxy).sqrt();
    let small = 0.5 * (cxx + cyy) - root;
    let large = 0.5 * (cxx + cyy) + root;
    let mut nrm = if cxy.abs() > 1e-12 {
        [cxy, small - cxx]
    } else if cxx < cyy {
        [1.0, 0.0]
    } else {
        [0.0, 1.0]
    };
    let len = nrm[0].hypot(nrm[1]);
    nrm = scale(nrm, 1.0 / len);
    if dot(nrm, normal) < 0.0 {
        nrm = scale(nrm, -1.0);
    }
    // Angle uncertainty: residual spread over the spread along the line.
    let resid = small.max(0.0).sqrt().max(0.3);
    let psi_sigma = resid / (large.max(1.0).sqrt() * n.sqrt());
    Some(Fit {
        normal: nrm,
        centroid: c,
        psi_sigma,
        count: n as u32,
    })
}

/// Test input: the candidates of edge 0 polished from `peak` on edge pixels at the
/// steps `at` (1 px apart) along a line from `origin` at `angle` (radians, bright side
/// counter-clockwise of the direction), in a 320x240 detection image.
#[cfg(test)]
pub(super) fn line_candidates(
    origin: [f64; 2],
    angle: f64,
    at: impl Iterator<Item = usize>,
    peak: Peak,
) -> Candidates {
    let normal_angle = angle + std::f64::consts::FRAC_PI_2;
    let pts: Vec<EdgePoint> = at
        .map(|i| EdgePoint {
            x: (origin[0] + i as f64 * angle.cos()) as f32,
            y: (origin[1] + i as f64 * angle.sin()) as f32,
            angle: normal_angle as f32,
            ux: normal_angle.cos() as f32,
            uy: normal_angle.sin() as f32,
            mag: 40.0,
        })
        .collect();
    let mut c = Candidates::default();
    let all: Vec<u32> = (0..pts.len() as u32).collect();
    c.build(
        &[peak],
        &pts,
        &[all.clone(), all.clone(), all],
        [std::f64::consts::FRAC_PI_2, 0.0, 0.0],
        [320, 240],
        CANDIDATES_PER_EDGE,
    );
    c
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn polishing_recovers_a_line_and_its_extent() {
        // A 60-px segment at 3 deg below horizontal, bright below.
        let a = 3f64.to_radians();
        let peak = Peak {
            edge: 0,
            psi: 2f64.to_radians(),
            rho: 78.0,
            votes: 60,
        };
        let c = line_candidates([50.0, 80.0], a, 0..60, peak);
        let cand = c.list[0];
        assert!(
            (cand.psi.to_degrees() - 3.0).abs() < 0.05,
            "{}",
            cand.psi.to_degrees()
        );
        let start = Candidates::t_of(&cand, [50.0, 80.0]);
        let end = Candidates::t_of(&cand, [50.0 + 59.0 * a.cos(), 80.0 + 59.0 * a.sin()]);
        let (sup, vis) = c.support(&cand, start, end);
        assert!(sup > 55.0 && vis > 55.0 && vis < 62.0, "{sup} {vis}");
        let (sup, vis) = c.support(&cand, end + 5.0, end + 40.0);
        assert!(sup < 1.0 && vis > 30.0, "{sup} {vis}");
    }
}
