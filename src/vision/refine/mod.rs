//! Sub-pixel refinement on the full-resolution grey levels.
//!
//! Thresholding and edge maps throw away where, inside a pixel, an edge lies; the grey
//! levels keep it. Around each found edge a band of pixels is fitted with a blurred step
//!
//! ```text
//! I(p) = level + slope * u + (contrast + cslope * u) * Phi(d(p) / blur)
//!        + own[stretch(p)] * (1 - Phi(d(p) / blur)),
//! d(p) = n(psi) . (p - origin) - offset  [- bend * w(p)^3 on the beam edge]
//! ```
//!
//! (`Phi` the normal CDF, `u` the position along the edge, for slow shading and the
//! probe's brightness ramp, with a prior that the probe side's is small; `own` each
//! stretch's outside level on top of the linear one, with a zero-mean prior, for a
//! substrate or particle beside part of the edge), by robust (Huber) Gauss-Newton. In
//! tracking mode one rotation `psi` is shared by all edges, which is what a rigid tip
//! means; in calibration mode each edge turns on its own, and its rotation's standard
//! error is also read from the spread of its stretches (`EdgeResult::turn_sigma_robust`),
//! which background texture beside the edge widens.
//! The beam edge is straight along the rigid block at its end and curves behind it
//! along the elastica: its offset from the free-end tangent grows as the cube of the
//! distance `w` behind the block (the bending moment grows linearly from there), so a
//! cubic term, with a prior from the exact elastica (`bands::bend_prior`), lets a long
//! stretch of beam pin the tangent down instead of biasing it. Stretches whose
//! residuals stand out (a particle on the edge) are left out.
//!
//! `kernel` is the inner loop, `gauss` the tabulated normal CDF, `solve` the small
//! dense algebra, `result` what a converged fit reports and its standard errors.

use image::GrayImage;

use super::geometry::{along, dot, sub, Line};
use super::template::{PerEdge, EDGES, RED};

mod gauss;
mod kernel;
mod result;
mod solve;
#[cfg(test)]
mod tests;

use result::{common_noise, tie_precision, tie_sigma, turn_sigma};
use solve::{apply, solve, Normal};

/// Most samples per edge (longer bands are strided), for the final and the coarse fit.
const MAX_SAMPLES_PER_EDGE: usize = 2400;
const MAX_SAMPLES_PER_EDGE_COARSE: usize = 400;
/// Gauss-Newton iterations at most (final, coarse), of which the first few on every
/// other pixel.
const ITERATIONS: usize = 5;
const ITERATIONS_COARSE: usize = 3;
/// Converged when a step moves every rotation and offset less than this.
const DONE_TURN_RAD: f64 = 5e-6;
const DONE_OFFSET_PX: f64 = 5e-3;
/// With the edges' rotations shared or tied (tracking) the fit has also converged when
/// a step moves the tip's rotation by at most this share of its own standard error (the
/// same normal equations' `turn_sigma`) and the offsets by less than
/// [`DONE_SHARED_OFFSET_PX`]: a noisy frame (turn_sigma 2e-4 to 1e-3 rad) stops one or
/// two iterations before its steps fall under 5e-6 rad, which its noise does not need.
/// Near the solution each step is about a sixth of the one before (measured on seed
/// 31's suite; the robust weights and the model's curvature make the convergence
/// linear), so stopping after a step of 0.3 sigma leaves about 0.06 sigma. Measured
/// over 40 rendered suites against a rule of 0.05 sigma and 0.01 px: RMS error 0.03539
/// -> 0.03532 deg, the same detections, each frame's angle within 0.38 of its sigma
/// (0.07 at the 99th percentile), and the final fit 2.5 iterations instead of 3.9 (with
/// the warm start of [`Refiner::fit`]). Not before the second iteration after the
/// outlier stretches are rejected unless the fit starts from a measured noise: the one
/// right after would otherwise weight the residuals by the noise measured with the
/// outliers in, and a small step there does not mean the next one is (a harsh frame
/// moved half a sigma after it).
const DONE_TURN_SIGMAS: f64 = 0.3;
/// A step of the offsets that small leaves the apex about 0.015 px from where more
/// iterations would put it (the apex's own error: 0.03-0.23 px median by look).
const DONE_SHARED_OFFSET_PX: f64 = 0.03;
/// Normalisation of the along-edge coordinates (keeps the normal equations balanced).
const ALONG_UNIT_PX: f64 = 100.0;
/// Prior standard deviation of the grey-level slope along an edge on the probe's side
/// (level slope plus contrast slope), grey levels per [`ALONG_UNIT_PX`], around zero.
/// The charged probe is evenly bright but for slow shading and a brightness ramp across
/// the field (SEM frames; about 2 per 100 px in the public samples). A short edge's free
/// slopes trade against its rotation (a turn looks partly like a level ramp across a
/// band a few blurs wide); a long edge measures them far better than this and is not
/// held. The outside's slope stays free: particles and the substrate make the
/// background vary along an edge, and holding it costs cluttered frames accuracy.
/// Measured on the rendered suite (docs/tracker-notes.md): suite RMS angle error
/// 0.0426 -> 0.0371 deg, frames above 0.2 deg 22 -> 9 of 2,859; 0.7 and 1.5 measure
/// the same, 6 loses a third of the gain.
const PROBE_SLOPE_SIGMA: f64 = 2.5;
/// Parameter layout: a rotation per edge (only the first in shared mode), an offset per
/// edge, the beam edge's bend, the blur, then per edge its photometry (level, level
/// slope, contrast, contrast slope).
const P_TURN: usize = 0;
const P_OFFSET: usize = P_TURN + EDGES;
const P_BEND: usize = P_OFFSET + EDGES;
const P_BLUR: usize = P_BEND + 1;
const P_PHOTO: usize = P_BLUR + 1;
const PHOTO: usize = 4;
const N_PARAMS: usize = P_PHOTO + EDGES * PHOTO;

/// The stretch of one edge to fit.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Band {
    /// Ends of the stretch (on or near `line`).
    pub start: [f64; 2],
    pub end: [f64; 2],
    /// Current line estimate (inward normal).
    pub line: Line,
    /// For the beam edge: where the beam starts to bend (the back of the rigid block),
    /// from which the cubic bend grows into the band.
    pub bend_from: Option<[f64; 2]>,
    /// Expected bend: offset (pixels, along the inward normal) at [`BEND_UNIT_PX`] from
    /// `bend_from`; the band follows the bent edge, and the fit starts from it.
    pub bend0: f64,
    /// Standard deviation of the prior on the bend around `bend0` (infinite: no prior).
    pub bend_sigma: f64,
    /// The face this one meets at a convex corner (the apex), with its margin: near it
    /// the grey levels are the blurred wedge, not one blurred step, so a pixel is left
    /// out when it lies within `margin` pixels of that face's inside and not clearly
    /// outside this one. The band can then run up to the corner instead of stopping
    /// several blurs short of it, where the ends that pin the rotation down are.
    pub partner: Option<Partner>,
    /// The face (the beam's lower face) this one meets at a concave corner, at its far
    /// end: there the probe is the union of the two, so a pixel is left out when it
    /// lies within `margin` of that face's inside and not clearly inside this one.
    pub base: Option<Partner>,
}

/// A neighbouring face of a band's edge (see [`Band::partner`] and [`Band::base`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Partner {
    /// Its line, inward normal.
    pub line: Line,
    /// How far (pixels) its blurred step reaches, plus its placement's uncertainty.
    pub margin_px: f64,
}

impl Band {
    /// Whether pixel `p` sees a neighbouring face as well as this edge, so that the
    /// single blurred step does not describe it.
    fn near_corner(&self, p: [f64; 2]) -> bool {
        let own = self.line.depth(p);
        let apex = self
            .partner
            .is_some_and(|q| q.line.depth(p) < q.margin_px && own > -q.margin_px);
        let base = self
            .base
            .is_some_and(|q| q.line.depth(p) > -q.margin_px && own < q.margin_px);
        apex || base
    }
}

/// The outer part of a band (pixels) where only every other pixel is fitted.
const LEVEL_ONLY_PX: f64 = 2.0;

/// The bend coefficient is the offset of the beam edge from its free-end tangent at this
/// distance beyond the start of the bend, pixels.
pub const BEND_UNIT_PX: f64 = 100.0;

/// How the edges' rotations are tied together in a fit.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Turns {
    /// Each edge turns on its own (calibration).
    Free,
    /// One rotation for all edges: a rigid tip (placing the bands).
    Shared,
    /// Each edge turns by the tip's rotation plus its own deviation, a zero-mean one
    /// with that edge's calibration standard error. The reference measured each
    /// edge's orientation only that well, so a frame's edge that agrees with the
    /// others better than its calibration should not outvote them: the tip's rotation
    /// is the generalised least-squares mean of the edges' own, weighted by their
    /// frame and calibration variances together, and its standard error includes the
    /// calibration's (see [`Tie`]).
    Tied(Tie),
}

/// The calibration's standard errors of the edges' orientations, radians by edge
/// index, as a [`Turns::Tied`] fit takes them.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Tie {
    /// From the reference's pixel noise (the calibration fit's normal equations): the
    /// edges are weighed by these.
    pub weigh: PerEdge<f64>,
    /// What the reference's reading may be off by, background structure included
    /// (`EdgeResult::turn_sigma_robust`): the tip's standard error carries these,
    /// combined with the weights the first ones give.
    pub error: PerEdge<f64>,
}

/// Smallest calibration standard error of an edge's orientation that [`Turns::Tied`]
/// takes, radians (0.001 deg): below it the tie is rigid for all purposes, and a
/// vanishing one would make the normal equations singular.
const MIN_TIE_SIGMA_RAD: f64 = 1.745e-5;

/// What the fit found for one edge.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct EdgeResult {
    /// The edge line (for the beam: its tangent at the corner).
    pub line: Line,
    /// Grey-level step from outside to inside the probe.
    pub contrast: f64,
    /// Grey level just outside.
    pub level: f64,
    /// RMS of the weighted residuals, grey levels.
    pub noise: f64,
    /// Pixels used.
    pub samples: usize,
    /// Rotation of this edge relative to its starting normal, radians.
    pub turn: f64,
    /// 1-sigma uncertainty of `turn` from this frame's noise (radians; with one shared
    /// rotation, the shared one's).
    pub turn_sigma: f64,
    /// With free rotations (calibration), the cluster-robust standard error of `turn`
    /// when it exceeds `turn_sigma`: from the spread of the band's stretches' scores
    /// (weighted residuals times Jacobians), each through the M-estimator's normal
    /// matrix without that stretch (`Refiner::clustered_turn_sigma`). Background
    /// structure beside an edge leaves residuals correlated along it over several
    /// pixels, which `turn_sigma`, counting every pixel as independent, takes for
    /// noise; the stretches' scores spread with it. Otherwise `turn_sigma`.
    pub turn_sigma_robust: f64,
}

/// Result of a fit.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FitResult {
    pub edges: PerEdge<Option<EdgeResult>>,
    /// The tip's rotation relative to the starting normals (shared or tied edges),
    /// radians.
    pub turn: f64,
    /// 1-sigma uncertainty of `turn`, radians: from the normal equations, and with tied
    /// edges the calibration's share from its pixel noise (`Tie::weigh`) as well: how
    /// well this frame determines the rotation.
    pub turn_sigma: f64,
    /// The same with the calibration's whole error (`Tie::error`) in place of its pixel
    /// noise's: what the rotation may be off by, the standard error to report.
    pub turn_error_sigma: f64,
    pub blur: f64,
    /// Bend coefficient: offset (pixels) of the beam edge from its free-end tangent at
    /// twice the distance from the free end to the middle of its band.
    pub bend: f64,
}

impl FitResult {
    /// Each edge's residual noise (infinite where no edge was fitted): what a later fit
    /// of the same frame starts from (`noise0` of [`Refiner::fit`]).
    pub fn noise(&self) -> PerEdge<f64> {
        self.edges.map(|r| r.map_or(f64::INFINITY, |r| r.noise))
    }
}

#[derive(Debug, Clone, Copy)]
struct Sample {
    x: f32,
    y: f32,
    value: f32,
    edge: u8,
    /// Stretch of the band the pixel belongs to (see [`CHUNKS_PER_EDGE`]).
    chunk: u8,
}

/// Each band is cut into at most this many stretches along the edge; a stretch whose
/// residuals are far above the edge's typical level (a particle sitting on the edge, a
/// scratch crossing it) is left out of the fit, which a per-pixel robust weight cannot
/// do when the intruder is only a few noise sigmas bright.
const CHUNKS_PER_EDGE: usize = 32;
/// Shortest stretch, pixels along the band's major axis.
const CHUNK_MIN_LINES: f64 = 10.0;
/// A stretch is an outlier when its mean squared residual exceeds this many times the
/// median over the edge's stretches.
const CHUNK_OUTLIER_RATIO: f64 = 1.7;
/// Prior standard deviation of a stretch's own outside level around its edge's linear
/// one, grey levels.
pub(super) const STRETCH_LEVEL_SIGMA: f64 = 40.0;

/// Reusable buffers of the fit.
#[derive(Debug)]
pub struct Refiner {
    samples: Vec<Sample>,
    /// The samples of each edge (contiguous).
    ranges: PerEdge<std::ops::Range<usize>>,
    stretches: Stretches,
    /// Each edge's eight local parameters' places in the fit's (turn, offset, bend,
    /// blur, level, level slope, contrast, contrast slope).
    slots: PerEdge<[usize; 8]>,
}

/// Per stretch of every band (see [`CHUNKS_PER_EDGE`]): whether it counts, its residual
/// statistics, and its own outside level with what the last normal equations said of it.
#[derive(Debug)]
pub(super) struct Stretches {
    pub ok: [bool; EDGES * CHUNKS_PER_EDGE],
    /// Sum of squared residuals and samples, over every sample (counted or not).
    pub sq: [f64; EDGES * CHUNKS_PER_EDGE],
    pub n: [u32; EDGES * CHUNKS_PER_EDGE],
    /// The stretch's outside level, relative to the edge's linear one (grey levels).
    pub level: [f64; EDGES * CHUNKS_PER_EDGE],
    /// Normal-equation terms of `level`: its products with the edge's eight local
    /// parameters, with itself, and with the residuals (counted samples only).
    pub row: [[f64; 8]; EDGES * CHUNKS_PER_EDGE],
    pub hh: [f64; EDGES * CHUNKS_PER_EDGE],
    pub g: [f64; EDGES * CHUNKS_PER_EDGE],
}

impl Default for Stretches {
    fn default() -> Self {
        Stretches {
            ok: [true; EDGES * CHUNKS_PER_EDGE],
            sq: [0.0; EDGES * CHUNKS_PER_EDGE],
            n: [0; EDGES * CHUNKS_PER_EDGE],
            level: [0.0; EDGES * CHUNKS_PER_EDGE],
            row: [[0.0; 8]; EDGES * CHUNKS_PER_EDGE],
            hh: [0.0; EDGES * CHUNKS_PER_EDGE],
            g: [0.0; EDGES * CHUNKS_PER_EDGE],
        }
    }
}

impl Default for Refiner {
    fn default() -> Self {
        Refiner {
            samples: Vec::new(),
            ranges: [0..0, 0..0, 0..0],
            stretches: Stretches::default(),
            slots: [[0; 8]; EDGES],
        }
    }
}

/// Per-edge frame of reference during the fit.
#[derive(Debug, Clone, Copy)]
struct EdgeFrame {
    origin: [f64; 2],
    normal0: [f64; 2],
    corner: [f64; 2],
    /// +1 or -1: the sign of the along-coordinate from the free end towards the clamp.
    towards: f64,
    curved: bool,
}

impl EdgeFrame {
    /// Signed distance of `p` inside the edge at the starting line and a bend of
    /// `bend` (the kernel's `d`, before the fit moves the line).
    fn depth(&self, p: [f64; 2], bend: f64) -> f64 {
        let rel = sub(p, self.origin);
        let a = along(self.normal0);
        let u = dot(a, rel);
        let corner_t = dot(a, sub(self.corner, self.origin));
        let w = if self.curved {
            (self.towards * (u - corner_t)).max(0.0) / BEND_UNIT_PX
        } else {
            0.0
        };
        dot(self.normal0, rel) - bend * w * w * w
    }
}

impl Refiner {
    /// Fits the bands on `frame`, the edges' rotations tied as `turns` says; `coarse`
    /// uses fewer pixels and iterations (to place the bands of the final fit).
    /// `noise0`, each edge's residual noise from an earlier fit of the same frame (the
    /// coarse pass's), makes the first iteration robust already; without it the first
    /// iteration is plain least squares and measures the noise.
    pub fn fit(
        &mut self,
        frame: &GrayImage,
        bands: &PerEdge<Option<Band>>,
        turns: Turns,
        blur0: f64,
        noise0: Option<PerEdge<f64>>,
        coarse: bool,
    ) -> Option<FitResult> {
        let shared = turns == Turns::Shared;
        let half_width = half_width(blur0);
        // The coarse pass starts far from the solution: its first iteration runs on
        // every other pixel. The final pass starts from the coarse lines.
        let (max_samples, iterations_max, subsampled) = if coarse {
            (MAX_SAMPLES_PER_EDGE_COARSE, ITERATIONS_COARSE, 1)
        } else {
            (MAX_SAMPLES_PER_EDGE, ITERATIONS, 0)
        };
        self.samples.clear();
        // Each band is strided down to at most max_samples plus one line's worth.
        self.samples.reserve(EDGES * (MAX_SAMPLES_PER_EDGE + 1024));
        let mut frames: PerEdge<Option<EdgeFrame>> = [None; EDGES];
        for (e, band) in bands.iter().enumerate() {
            self.ranges[e] = 0..0;
            let Some(b) = band else { continue };
            let first = self.samples.len();
            if self.collect(frame, e, b, half_width, max_samples) < 12 {
                self.samples.truncate(first);
                continue;
            }
            self.ranges[e] = first..self.samples.len();
            let mid = [0.5 * (b.start[0] + b.end[0]), 0.5 * (b.start[1] + b.end[1])];
            let corner = b.bend_from.unwrap_or(b.start);
            frames[e] = Some(EdgeFrame {
                origin: b.line.foot(mid),
                normal0: b.line.normal,
                corner: b.line.foot(corner),
                towards: dot(along(b.line.normal), sub(b.end, b.start)).signum(),
                curved: b.bend_from.is_some(),
            });
        }
        if frames.iter().all(Option::is_none) {
            return None;
        }
        let mut x = [0.0; N_PARAMS];
        x[P_BLUR] = blur0;
        x[P_BEND] = bands[RED].map_or(0.0, |b| b.bend0);
        self.init_photometry(&frames, &mut x);
        let weights = tip_weights(&frames, turns);
        // Infinite noise: no robust weights until the residuals have been seen.
        let mut noise = noise0.unwrap_or([f64::INFINITY; EDGES]);
        // Iterations the robust weights take to settle after the outlier stretches are
        // rejected (see DONE_TURN_SIGMAS): none when every edge starts from a measured
        // noise (an edge the earlier fit did not have starts unweighted).
        let measured = (0..EDGES).all(|e| frames[e].is_none() || noise[e].is_finite());
        let settling = if measured { 0 } else { 1 };
        let mut last = None;
        self.stretches.ok = [true; EDGES * CHUNKS_PER_EDGE];
        for iter in 0..iterations_max {
            // The first iterations, far from the solution, on every other pixel.
            let step = if iter < subsampled { 2 } else { 1 };
            let mut ne = self.normal_equations(&frames, &x, &noise, shared, step);
            if let Turns::Tied(t) = turns {
                tie(&mut ne, &x, &frames, &t.weigh, step);
            }
            // Expectations as observations, weighted like the pixels (whose sums the
            // normal equations hold): the physics' bend, and the slow shading.
            if let Some(b) = bands[RED].filter(|b| b.bend_sigma.is_finite()) {
                let weight = pixel_weight(ne.noise[RED], b.bend_sigma, step);
                prior(&mut ne, &x, &[P_BEND], b.bend0, weight);
            }
            for e in (0..EDGES).filter(|&e| frames[e].is_some()) {
                let weight = pixel_weight(ne.noise[e], PROBE_SLOPE_SIGMA, step);
                // The probe side's slope: level slope plus contrast slope.
                let p0 = P_PHOTO + PHOTO * e;
                prior(&mut ne, &x, &[p0 + 1, p0 + 3], 0.0, weight);
            }
            let step = solve(&ne.h, &ne.g, &ne.fixed)?;
            noise = ne.noise;
            let before = x;
            apply(&mut x, &step);
            self.step_levels(&before, &x);
            if iter <= subsampled {
                self.reject_chunks();
            }
            // The old absolute test from the first full iteration on; the relative one
            // once the robust weights have settled (see DONE_TURN_SIGMAS).
            let done = (iter > subsampled && converged(&step))
                || (iter > subsampled + settling
                    && turns != Turns::Free
                    && converged_tip(&step, &ne, &weights));
            last = Some(ne);
            if done {
                break;
            }
        }
        let ne = last?;
        Some(self.result(&frames, &x, &ne, turns, &weights))
    }

    /// Adds edge `e`'s band pixels; returns how many.
    fn collect(
        &mut self,
        frame: &GrayImage,
        e: usize,
        b: &Band,
        half_width: f64,
        max_samples: usize,
    ) -> usize {
        let (w, h) = (frame.width() as f64, frame.height() as f64);
        let n = b.line.normal;
        let horizontal = n[1].abs() >= n[0].abs();
        // March along the major axis of the edge; across it, take the band's pixels.
        let (k, j) = if horizontal { (0, 1) } else { (1, 0) };
        let (lo, hi) = (b.start[k].min(b.end[k]), b.start[k].max(b.end[k]));
        let (lo, hi) = (lo.max(1.0).ceil(), hi.min([w, h][k] - 2.0).floor());
        if hi < lo {
            return 0;
        }
        let across = half_width / n[j].abs();
        let inner = (half_width - LEVEL_ONLY_PX) / n[j].abs();
        let per_line = (2.0 * across + 1.0).max(1.0);
        let lines = hi - lo + 1.0;
        let stride = ((lines * per_line) / max_samples as f64).ceil().max(1.0) as usize;
        let chunk_lines = (lines / CHUNKS_PER_EDGE as f64).ceil().max(CHUNK_MIN_LINES);
        let limit = [w, h][j] - 2.0;
        let before = self.samples.len();
        let raw = frame.as_raw();
        let width = frame.width() as usize;
        // A bent beam edge: the band follows n . p = rho + bend0 * w^3.
        let d = along(n);
        let bend = b.bend_from.map(|from| {
            let towards = dot(d, sub(b.end, b.start)).signum();
            (dot(d, from), towards)
        });
        let mut a = lo as i64;
        while a as f64 <= hi {
            // Centre of the band on this line: n_k * a + n_j * c = rho.
            let mut centre = (b.line.rho - n[k] * a as f64) / n[j];
            if let Some((u_from, towards)) = bend {
                let p = if horizontal {
                    [a as f64, centre]
                } else {
                    [centre, a as f64]
                };
                let w = (towards * (dot(d, p) - u_from)).max(0.0) / BEND_UNIT_PX;
                centre += b.bend0 * w * w * w / n[j];
            }
            let c0 = (centre - across).ceil().max(1.0) as i64;
            let c1 = (centre + across).floor().min(limit) as i64;
            for c in c0..=c1 {
                // Pixels more than a couple of blurs from the edge only tell the levels:
                // every other one (a checkerboard) is plenty for that.
                if (c as f64 - centre).abs() > inner && (a + c) % 2 != 0 {
                    continue;
                }
                let (px, py) = if horizontal { (a, c) } else { (c, a) };
                if b.near_corner([px as f64, py as f64]) {
                    continue;
                }
                let value = raw[py as usize * width + px as usize];
                let local = (((a as f64 - lo) / chunk_lines) as usize).min(CHUNKS_PER_EDGE - 1);
                self.samples.push(Sample {
                    x: px as f32,
                    y: py as f32,
                    value: value as f32,
                    edge: e as u8,
                    chunk: (e * CHUNKS_PER_EDGE + local) as u8,
                });
            }
            a += stride as i64;
        }
        self.samples.len() - before
    }

    /// Marks the stretches whose residuals stand out from their edge's (see
    /// [`CHUNKS_PER_EDGE`]); uses the statistics of the last normal equations.
    fn reject_chunks(&mut self) {
        for e in 0..EDGES {
            let range = e * CHUNKS_PER_EDGE..(e + 1) * CHUNKS_PER_EDGE;
            let mut means = [0.0f64; CHUNKS_PER_EDGE];
            let mut n = 0;
            for c in range.clone() {
                if self.stretches.n[c] >= 8 {
                    means[n] = self.stretches.sq[c] / self.stretches.n[c] as f64;
                    n += 1;
                }
            }
            if n < 3 {
                continue;
            }
            let means = &mut means[..n];
            means.sort_by(f64::total_cmp);
            let median = means[n / 2];
            for c in range {
                if self.stretches.n[c] >= 8 {
                    let mean = self.stretches.sq[c] / self.stretches.n[c] as f64;
                    self.stretches.ok[c] = mean <= CHUNK_OUTLIER_RATIO * median;
                }
            }
        }
    }

    /// Starting levels: mean outside and inside the line, per edge, and each stretch's
    /// outside level relative to its edge's.
    fn init_photometry(&mut self, frames: &PerEdge<Option<EdgeFrame>>, x: &mut [f64; N_PARAMS]) {
        let mut acc = [[0.0f64; 4]; EDGES];
        let mut outside = [[0.0f64; 2]; EDGES * CHUNKS_PER_EDGE];
        // Stretch by stretch (a stretch's samples are consecutive, and of one edge), the
        // sums kept in registers meanwhile: summed in memory, each addition waited for
        // the store of the one before.
        for run in self.samples.chunk_by(|a, b| a.chunk == b.chunk) {
            let (e, c) = (run[0].edge as usize, run[0].chunk as usize);
            let Some(f) = &frames[e] else { continue };
            let [mut out_sum, mut out_n, mut in_sum, mut in_n] = acc[e];
            let [mut own_sum, mut own_n] = outside[c];
            for s in run {
                let d = f.depth([s.x as f64, s.y as f64], x[P_BEND]);
                if d > 1.5 {
                    in_sum += s.value as f64;
                    in_n += 1.0;
                } else if d < -1.5 {
                    out_sum += s.value as f64;
                    out_n += 1.0;
                    own_sum += s.value as f64;
                    own_n += 1.0;
                }
            }
            acc[e] = [out_sum, out_n, in_sum, in_n];
            outside[c] = [own_sum, own_n];
        }
        for e in 0..EDGES {
            let out = acc[e][0] / acc[e][1].max(1.0);
            let inside = acc[e][2] / acc[e][3].max(1.0);
            x[P_PHOTO + PHOTO * e] = out;
            x[P_PHOTO + PHOTO * e + 2] = inside - out;
            let stretches = e * CHUNKS_PER_EDGE..(e + 1) * CHUNKS_PER_EDGE;
            for (level, &[sum, n]) in self.stretches.level[stretches.clone()]
                .iter_mut()
                .zip(&outside[stretches])
            {
                *level = if n >= 4.0 { sum / n - out } else { 0.0 };
            }
        }
    }

    /// Moves each stretch's outside level with the step the fit took (`before` to
    /// `after`): the level's own equation, with the other parameters' steps
    /// substituted (the elimination of [`Stretches`] in reverse).
    fn step_levels(&mut self, before: &[f64; N_PARAMS], after: &[f64; N_PARAMS]) {
        let st = &mut self.stretches;
        for e in 0..EDGES {
            let slots = self.slots[e];
            let delta: [f64; 8] = std::array::from_fn(|i| after[slots[i]] - before[slots[i]]);
            for c in e * CHUNKS_PER_EDGE..(e + 1) * CHUNKS_PER_EDGE {
                if st.hh[c] > 0.0 {
                    let coupled: f64 = st.row[c].iter().zip(&delta).map(|(r, d)| r * d).sum();
                    st.level[c] += (st.g[c] - coupled) / st.hh[c];
                }
            }
        }
    }

    /// Edge `e`'s typical step from outside to inside and the outside level it starts
    /// from: those of the median stretch by step (weighted by samples) among the ones
    /// that count. Each stretch's step is the contrast and its slope there less the
    /// stretch's own outside level, so a bright substrate beside part of a face does not
    /// pull the face's contrast down as a whole.
    fn step_height(
        &self,
        e: usize,
        f: &EdgeFrame,
        x: &[f64; N_PARAMS],
        normal: [f64; 2],
    ) -> (f64, f64) {
        let base = e * CHUNKS_PER_EDGE;
        let mut along_sum = [0.0f64; CHUNKS_PER_EDGE];
        let mut count = [0u32; CHUNKS_PER_EDGE];
        let d = along(normal);
        // Stretch by stretch, summed in a register (see `init_photometry`).
        for run in self.samples[self.ranges[e].clone()].chunk_by(|a, b| a.chunk == b.chunk) {
            let c = run[0].chunk as usize - base;
            let mut sum = along_sum[c];
            for s in run {
                sum += dot(d, sub([s.x as f64, s.y as f64], f.origin));
            }
            along_sum[c] = sum;
            count[c] += run.len() as u32;
        }
        let p = &x[P_PHOTO + PHOTO * e..P_PHOTO + PHOTO * (e + 1)];
        // (step, outside level, samples) per stretch that counts.
        let mut steps = [(0.0f64, 0.0f64, 0u32); CHUNKS_PER_EDGE];
        let mut n = 0;
        for c in 0..CHUNKS_PER_EDGE {
            if count[c] == 0 || !self.stretches.ok[base + c] {
                continue;
            }
            let un = along_sum[c] / count[c] as f64 / ALONG_UNIT_PX;
            let own = self.stretches.level[base + c];
            steps[n] = (p[2] + p[3] * un - own, p[0] + p[1] * un + own, count[c]);
            n += 1;
        }
        let steps = &mut steps[..n];
        steps.sort_by(|a, b| a.0.total_cmp(&b.0));
        let total: u32 = steps.iter().map(|s| s.2).sum();
        let mut acc = 0;
        for &(step, level, k) in steps.iter() {
            acc += k;
            if 2 * acc >= total {
                return (step, level);
            }
        }
        (p[2], p[0])
    }
}

/// Weight of an observation with standard deviation `sigma` in the units of an edge's
/// pixel sums, whose residuals measure `noise` (its square; halved when every other
/// pixel is summed).
pub(super) fn pixel_weight(noise: f64, sigma: f64, step: usize) -> f64 {
    let n2 = noise.min(1e6).powi(2);
    n2 / (sigma * sigma * step as f64)
}

/// Adds the observation "the sum of the parameters `ks` is `mean`" with `weight` (in
/// the units of the pixel sums) to the normal equations.
fn prior(ne: &mut Normal, x: &[f64; N_PARAMS], ks: &[usize], mean: f64, weight: f64) {
    let residual = mean - ks.iter().map(|&k| x[k]).sum::<f64>();
    for &a in ks {
        ne.g[a] += weight * residual;
        for &b in ks {
            ne.h[a][b] += weight;
        }
    }
}

/// Whether `step` moved every rotation and offset less than [`DONE_TURN_RAD`] and
/// [`DONE_OFFSET_PX`].
fn converged(step: &[f64; N_PARAMS]) -> bool {
    (P_TURN..P_TURN + EDGES).all(|k| step[k].abs() < DONE_TURN_RAD)
        && (P_OFFSET..P_OFFSET + EDGES).all(|k| step[k].abs() < DONE_OFFSET_PX)
}

/// Whether `step`, computed from `ne`, moved the tip's rotation (the rotations
/// combined with `weights`) by at most [`DONE_TURN_SIGMAS`] of its standard error from
/// this frame's noise and the offsets less than [`DONE_SHARED_OFFSET_PX`].
fn converged_tip(step: &[f64; N_PARAMS], ne: &Normal, weights: &[f64; N_PARAMS]) -> bool {
    let turn: f64 = weights.iter().zip(step).map(|(w, s)| w * s).sum();
    (P_OFFSET..P_OFFSET + EDGES).all(|k| step[k].abs() < DONE_SHARED_OFFSET_PX)
        && turn.abs() <= DONE_TURN_SIGMAS * turn_sigma(ne, weights)
}

/// The weights over the parameters that make the tip's rotation: the shared rotation,
/// or with tied edges the mean of the edges' rotations weighted by their calibration
/// precision (the generalised least-squares estimate of the tip's rotation; see
/// [`Turns::Tied`]). Free edges: the first edge in view's rotation.
fn tip_weights(frames: &PerEdge<Option<EdgeFrame>>, turns: Turns) -> [f64; N_PARAMS] {
    let mut w = [0.0; N_PARAMS];
    match turns {
        Turns::Shared => w[P_TURN] = 1.0,
        Turns::Tied(t) => {
            let total = tie_precision(frames, &t.weigh);
            for e in (0..EDGES).filter(|&e| frames[e].is_some()) {
                w[P_TURN + e] = tie_sigma(&t.weigh, e).powi(-2) / total;
            }
        }
        Turns::Free => {
            if let Some(e) = (0..EDGES).find(|&e| frames[e].is_some()) {
                w[P_TURN + e] = 1.0;
            }
        }
    }
    w
}

/// Adds the tie of [`Turns::Tied`] to the normal equations: each edge's rotation
/// deviates from the tip's (their precision-weighted mean) with its calibration
/// standard error. The tip's rotation itself is eliminated, which leaves the prior
/// precision `a_i delta_ij - a_i a_j / A` (a_i = sigma_i^-2, A their sum) on the edges'
/// rotations: free along a common turn, stiff against the edges disagreeing.
fn tie(
    ne: &mut Normal,
    x: &[f64; N_PARAMS],
    frames: &PerEdge<Option<EdgeFrame>>,
    sigma: &PerEdge<f64>,
    step: usize,
) {
    let noise = common_noise(ne);
    let a: PerEdge<f64> = std::array::from_fn(|e| {
        if frames[e].is_some() {
            pixel_weight(noise, tie_sigma(sigma, e), step)
        } else {
            0.0
        }
    });
    let total: f64 = a.iter().sum();
    if total <= 0.0 || !total.is_finite() {
        return;
    }
    for i in 0..EDGES {
        for j in 0..EDGES {
            let p = if i == j { a[i] } else { 0.0 } - a[i] * a[j] / total;
            ne.h[P_TURN + i][P_TURN + j] += p;
            ne.g[P_TURN + i] -= p * x[P_TURN + j];
        }
    }
}

/// Half-width of the band of pixels fitted around an edge, for a blur (pixels).
pub fn half_width(blur: f64) -> f64 {
    2.0 * blur + 2.5
}
