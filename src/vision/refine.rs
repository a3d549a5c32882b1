//! Sub-pixel refinement on the full-resolution grey levels.
//!
//! Thresholding and edge maps throw away where, inside a pixel, an edge lies; the grey
//! levels keep it. Around each found edge a band of pixels is fitted with a blurred step
//!
//!     I(p) = level + slope * u + contrast * Phi(d(p) / blur),
//!     d(p) = n(psi) . (p - origin) - offset  [- bend * w(p)^3 on the beam edge]
//!
//! (`Phi` the normal CDF, `u` the position along the edge, for slow shading), by robust
//! (Huber) Gauss-Newton. In tracking mode one rotation `psi` is shared by all edges,
//! which is what a rigid tip means; in calibration mode each edge turns on its own.
//! The beam edge is curved along the elastica: its offset from the free-end tangent
//! grows as the cube of the distance `w` from the free end (the bending moment grows
//! linearly from zero there), so a cubic term lets a long stretch of it pin down the
//! end tangent instead of biasing it.

use image::GrayImage;

use super::geometry::{along, dot, rotate, sub, Line};

/// Most samples per edge (longer bands are strided), for the final and the coarse fit.
const MAX_SAMPLES_PER_EDGE: usize = 2400;
const MAX_SAMPLES_PER_EDGE_COARSE: usize = 400;
/// Gauss-Newton iterations at most (final, coarse), of which the first few on every
/// other pixel.
const ITERATIONS: usize = 5;
const ITERATIONS_COARSE: usize = 3;
const SUBSAMPLED_ITERATIONS: usize = 1;
/// Converged when a step moves the rotation and every offset less than this.
const DONE_TURN_RAD: f64 = 5e-6;
const DONE_OFFSET_PX: f64 = 5e-3;
/// Normalisation of the along-edge coordinates (keeps the normal equations balanced).
const ALONG_UNIT_PX: f64 = 100.0;
const N_PARAMS: usize = 8 + 3 * PHOTO;
/// Parameter layout.
const P_TURN: usize = 0; // 3 rotations (only the first in shared mode)
const P_OFFSET: usize = 3; // 3 offsets
const P_BEND: usize = 6;
const P_BLUR: usize = 7;
const P_PHOTO: usize = 8; // per edge: level, level slope, contrast, contrast slope
const PHOTO: usize = 4;

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
}

/// The band that may carry a bend (the beam edge).
const RED_BAND: usize = 0;

/// The bend coefficient is the offset of the beam edge from its free-end tangent at this
/// distance beyond the start of the bend, pixels.
pub const BEND_UNIT_PX: f64 = 100.0;

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
}

/// Result of a fit.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FitResult {
    pub edges: [Option<EdgeResult>; 3],
    /// Shared rotation relative to the starting normals (tracking mode), radians.
    pub turn: f64,
    /// 1-sigma uncertainty of `turn` from the normal equations, radians.
    pub turn_sigma: f64,
    pub blur: f64,
    /// Bend coefficient: offset (pixels) of the beam edge from its free-end tangent at
    /// twice the distance from the free end to the middle of its band.
    pub bend: f64,
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

/// Reusable buffers of the fit.
#[derive(Debug)]
pub struct Refiner {
    samples: Vec<Sample>,
    /// The samples of each edge (contiguous).
    ranges: [std::ops::Range<usize>; 3],
    chunk_ok: [bool; 3 * CHUNKS_PER_EDGE],
    chunk_sq: [f64; 3 * CHUNKS_PER_EDGE],
    chunk_n: [u32; 3 * CHUNKS_PER_EDGE],
}

impl Default for Refiner {
    fn default() -> Self {
        Refiner {
            samples: Vec::new(),
            ranges: [0..0, 0..0, 0..0],
            chunk_ok: [true; 3 * CHUNKS_PER_EDGE],
            chunk_sq: [0.0; 3 * CHUNKS_PER_EDGE],
            chunk_n: [0; 3 * CHUNKS_PER_EDGE],
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

impl Refiner {
    /// Fits the bands on `frame`. `shared` ties the edges to one rotation; `coarse`
    /// uses fewer pixels and iterations (to place the bands of the final fit).
    pub fn fit(
        &mut self,
        frame: &GrayImage,
        bands: &[Option<Band>; 3],
        shared: bool,
        blur0: f64,
        coarse: bool,
    ) -> Option<FitResult> {
        let half_width = half_width(blur0);
        let (max_samples, iterations_max) = if coarse {
            (MAX_SAMPLES_PER_EDGE_COARSE, ITERATIONS_COARSE)
        } else {
            (MAX_SAMPLES_PER_EDGE, ITERATIONS)
        };
        self.samples.clear();
        let mut frames: [Option<EdgeFrame>; 3] = [None; 3];
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
        x[P_BEND] = bands[RED_BAND].map_or(0.0, |b| b.bend0);
        self.init_photometry(&frames, &mut x);
        let mut noise = [f64::INFINITY; 3];
        let mut last = None;
        self.chunk_ok = [true; 3 * CHUNKS_PER_EDGE];
        let mut iterations = 0;
        for iter in 0..iterations_max {
            iterations += 1;
            // The first iterations, far from the solution, on every other pixel.
            let step = if iter < SUBSAMPLED_ITERATIONS { 2 } else { 1 };
            let mut ne = self.normal_equations(&frames, &x, &noise, shared, step);
            if let Some(b) = bands[RED_BAND].filter(|b| b.bend_sigma.is_finite()) {
                // The physics' expectation of the bend as one more observation, weighted
                // like the pixels (whose sums the normal equations hold).
                let n2 = ne.noise[RED_BAND].min(1e6).powi(2);
                let weight = n2 / (b.bend_sigma * b.bend_sigma * step as f64);
                ne.h[P_BEND][P_BEND] += weight;
                ne.g[P_BEND] += weight * (b.bend0 - x[P_BEND]);
            }
            let step = solve(&ne.h, &ne.g, &ne.fixed)?;
            noise = ne.noise;
            apply(&mut x, &step);
            if iter <= SUBSAMPLED_ITERATIONS {
                self.reject_chunks();
            }
            let done = (P_TURN..P_TURN + 3).all(|k| step[k].abs() < DONE_TURN_RAD)
                && (P_OFFSET..P_OFFSET + 3).all(|k| step[k].abs() < DONE_OFFSET_PX);
            last = Some(ne);
            if done && iter > SUBSAMPLED_ITERATIONS {
                break;
            }
        }
        let ne = last?;
        if std::env::var("NF_DEBUG").is_ok() {
            eprintln!(
                "fit: {} samples {:?}, {} iterations",
                self.samples.len(),
                self.ranges,
                iterations
            );
        }
        Some(self.result(&frames, &x, &ne, shared))
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
                let (px, py) = if horizontal { (a, c) } else { (c, a) };
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
        for e in 0..3 {
            let range = e * CHUNKS_PER_EDGE..(e + 1) * CHUNKS_PER_EDGE;
            let mut means = [0.0f64; CHUNKS_PER_EDGE];
            let mut n = 0;
            for c in range.clone() {
                if self.chunk_n[c] >= 8 {
                    means[n] = self.chunk_sq[c] / self.chunk_n[c] as f64;
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
                if self.chunk_n[c] >= 8 {
                    let mean = self.chunk_sq[c] / self.chunk_n[c] as f64;
                    self.chunk_ok[c] = mean <= CHUNK_OUTLIER_RATIO * median;
                }
            }
        }
    }

    /// Starting levels: mean outside and inside the line, per edge.
    fn init_photometry(&self, frames: &[Option<EdgeFrame>; 3], x: &mut [f64; N_PARAMS]) {
        let mut acc = [[0.0f64; 4]; 3];
        for s in &self.samples {
            let e = s.edge as usize;
            let Some(f) = &frames[e] else { continue };
            let d = dot(f.normal0, sub([s.x as f64, s.y as f64], f.origin));
            let side = if d > 0.0 { 2 } else { 0 };
            if d.abs() > 1.5 {
                acc[e][side] += s.value as f64;
                acc[e][side + 1] += 1.0;
            }
        }
        for e in 0..3 {
            let out = acc[e][0] / acc[e][1].max(1.0);
            let inside = acc[e][2] / acc[e][3].max(1.0);
            x[P_PHOTO + PHOTO * e] = out;
            x[P_PHOTO + PHOTO * e + 2] = inside - out;
        }
    }

    fn normal_equations(
        &mut self,
        frames: &[Option<EdgeFrame>; 3],
        x: &[f64; N_PARAMS],
        noise: &[f64; 3],
        shared: bool,
        step: usize,
    ) -> Normal {
        let mut ne = Normal::default();
        self.chunk_sq = [0.0; 3 * CHUNKS_PER_EDGE];
        self.chunk_n = [0; 3 * CHUNKS_PER_EDGE];
        let mut sq = [0.0f64; 3];
        let mut wsum = [0.0f64; 3];
        let blur = x[P_BLUR];
        let normals: [[f64; 2]; 3] = std::array::from_fn(|e| {
            let turn = if shared { x[P_TURN] } else { x[P_TURN + e] };
            frames[e].map_or([0.0, 0.0], |f| rotate(f.normal0, turn))
        });
        for (e, f) in frames.iter().enumerate() {
            let Some(f) = f else { continue };
            let turn_index = if shared { P_TURN } else { P_TURN + e };
            let p0 = P_PHOTO + PHOTO * e;
            let slots = [
                turn_index,
                P_OFFSET + e,
                P_BEND,
                P_BLUR,
                p0,
                p0 + 1,
                p0 + 2,
                p0 + 3,
            ];
            let params = EdgeParams {
                normal: normals[e],
                along: along(normals[e]),
                offset: x[P_OFFSET + e],
                bend: x[P_BEND],
                blur,
                photo: [x[p0], x[p0 + 1], x[p0 + 2], x[p0 + 3]],
                huber: 1.5 * noise[e],
            };
            let range = self.ranges[e].clone();
            let acc = accumulate_edge(
                &self.samples[range],
                step,
                f,
                &params,
                &self.chunk_ok,
                &mut self.chunk_sq,
                &mut self.chunk_n,
            );
            sq[e] = acc.sq;
            wsum[e] = acc.wsum;
            let mut k = 0;
            for i in 0..8 {
                ne.g[slots[i]] += acc.g[i];
                for j in i..8 {
                    ne.h[slots[i]][slots[j]] += acc.h[k];
                    if i != j {
                        ne.h[slots[j]][slots[i]] += acc.h[k];
                    }
                    k += 1;
                }
            }
        }
        for e in 0..3 {
            ne.noise[e] = if wsum[e] > 0.0 {
                (sq[e] / wsum[e]).sqrt().max(0.5)
            } else {
                f64::INFINITY
            };
            if frames[e].is_none() {
                ne.fixed[P_OFFSET + e] = true;
                ne.fixed[P_TURN + e] = true;
                for k in 0..PHOTO {
                    ne.fixed[P_PHOTO + PHOTO * e + k] = true;
                }
            }
        }
        if shared {
            ne.fixed[P_TURN + 1] = true;
            ne.fixed[P_TURN + 2] = true;
        }
        if !frames.iter().flatten().any(|f| f.curved) {
            ne.fixed[P_BEND] = true;
        }
        if std::env::var("NF_NOCSLOPE").is_ok() {
            for e in 0..3 {
                ne.fixed[P_PHOTO + PHOTO * e + 3] = true;
            }
        }
        ne
    }

    fn result(
        &self,
        frames: &[Option<EdgeFrame>; 3],
        x: &[f64; N_PARAMS],
        ne: &Normal,
        shared: bool,
    ) -> FitResult {
        let mut edges = [None; 3];
        for (e, f) in frames.iter().enumerate() {
            let Some(f) = f else { continue };
            let turn = if shared { x[P_TURN] } else { x[P_TURN + e] };
            let normal = rotate(f.normal0, turn);
            let line = Line {
                normal,
                rho: dot(normal, f.origin) + x[P_OFFSET + e],
            };
            edges[e] = Some(EdgeResult {
                line,
                contrast: x[P_PHOTO + PHOTO * e + 2],
                level: x[P_PHOTO + PHOTO * e],
                noise: ne.noise[e],
                samples: self.samples.iter().filter(|s| s.edge as usize == e).count(),
                turn,
            });
        }
        let noise = ne
            .noise
            .iter()
            .copied()
            .filter(|n| n.is_finite())
            .fold(0.0, f64::max);
        let var = variance(&ne.h, &ne.fixed, P_TURN).unwrap_or(f64::INFINITY);
        FitResult {
            edges,
            turn: x[P_TURN],
            turn_sigma: noise * var.sqrt(),
            blur: x[P_BLUR],
            bend: x[P_BEND],
        }
    }
}

/// The current parameters of one edge, as the inner loop needs them.
struct EdgeParams {
    normal: [f64; 2],
    along: [f64; 2],
    offset: f64,
    bend: f64,
    blur: f64,
    /// level, level slope, contrast, contrast slope
    photo: [f64; 4],
    /// Huber threshold on the residual, grey levels.
    huber: f64,
}

/// One edge's contribution to the normal equations, in the local parameter order
/// (turn, offset, bend, blur, level, level slope, contrast, contrast slope); `h` is
/// the upper triangle row by row.
struct EdgeSums {
    h: [f64; 36],
    g: [f64; 8],
    sq: f64,
    wsum: f64,
}

/// The inner loop of the fit: residual, robust weight and Jacobian of every sample of
/// one edge, accumulated. Stretch statistics are gathered for every sample; samples of
/// rejected stretches contribute nothing else. Samples go four at a time through
/// lane arrays, which the compiler turns into vector arithmetic for the 44 products per
/// sample of the normal equations.
// Lane loops are indexed on purpose: that is the shape the vectoriser recognises.
#[allow(clippy::needless_range_loop)]
fn accumulate_edge(
    samples: &[Sample],
    step: usize,
    f: &EdgeFrame,
    p: &EdgeParams,
    chunk_ok: &[bool],
    chunk_sq: &mut [f64],
    chunk_n: &mut [u32],
) -> EdgeSums {
    // The normal matrix is accumulated in f32 lanes (its rounding only slows the
    // convergence a little), flushed into f64 every BLOCK samples; the gradient, which
    // decides where the fit stops, stays in f64.
    const LANES: usize = 4;
    const BLOCK: usize = 64;
    let mut h_total = [0.0f64; 36];
    let mut h = [[0.0f32; LANES]; 36];
    let mut g = [[0.0f64; LANES]; 8];
    let (mut sq, mut wsum) = (0.0, 0.0);
    let inv_blur = 1.0 / p.blur;
    let corner_t = dot(p.along, sub(f.corner, f.origin));
    let mut j = [[0.0f64; LANES]; 8];
    let mut wt = [0.0f64; LANES];
    let mut res = [0.0f64; LANES];
    let mut lane = 0;
    let mut pending = 0;
    let flush = |j: &[[f64; LANES]; 8],
                 wt: &[f64; LANES],
                 res: &[f64; LANES],
                 h: &mut [[f32; LANES]; 36],
                 g: &mut [[f64; LANES]; 8]| {
        let mut jf = [[0.0f32; LANES]; 8];
        let mut wf = [[0.0f32; LANES]; 8];
        for a in 0..8 {
            for l in 0..LANES {
                let wa = wt[l] * j[a][l];
                g[a][l] += wa * res[l];
                jf[a][l] = j[a][l] as f32;
                wf[a][l] = wa as f32;
            }
        }
        let mut k = 0;
        for a in 0..8 {
            for b in a..8 {
                for l in 0..LANES {
                    h[k][l] += wf[a][l] * jf[b][l];
                }
                k += 1;
            }
        }
    };
    let drain = |h: &mut [[f32; LANES]; 36], total: &mut [f64; 36]| {
        for (t, v) in total.iter_mut().zip(h.iter_mut()) {
            *t += v.iter().map(|&x| x as f64).sum::<f64>();
            *v = [0.0; LANES];
        }
    };
    for s in samples.iter().step_by(step) {
        let rel = [s.x as f64 - f.origin[0], s.y as f64 - f.origin[1]];
        let u = p.along[0] * rel[0] + p.along[1] * rel[1];
        let w = if f.curved {
            (f.towards * (u - corner_t)).max(0.0) * (1.0 / BEND_UNIT_PX)
        } else {
            0.0
        };
        let w3 = w * w * w;
        let d = p.normal[0] * rel[0] + p.normal[1] * rel[1] - p.offset - p.bend * w3;
        let z = d * inv_blur;
        let (cdf, pdf) = cdf_pdf(z);
        let un = u * (1.0 / ALONG_UNIT_PX);
        let contrast = p.photo[2] + p.photo[3] * un;
        let r = s.value as f64 - (p.photo[0] + p.photo[1] * un + contrast * cdf);
        let c = s.chunk as usize;
        chunk_sq[c] += r * r;
        chunk_n[c] += 1;
        if !chunk_ok[c] {
            continue;
        }
        let weight = if r.abs() <= p.huber {
            1.0
        } else {
            p.huber / r.abs()
        };
        sq += weight * r * r;
        wsum += weight;
        let dd = contrast * pdf * inv_blur;
        let jac = [-dd * u, -dd, -dd * w3, -dd * z, 1.0, un, cdf, cdf * un];
        for (ja, v) in j.iter_mut().zip(jac) {
            ja[lane] = v;
        }
        wt[lane] = weight;
        res[lane] = r;
        lane += 1;
        if lane == LANES {
            flush(&j, &wt, &res, &mut h, &mut g);
            lane = 0;
            pending += LANES;
            if pending >= BLOCK {
                drain(&mut h, &mut h_total);
                pending = 0;
            }
        }
    }
    if lane > 0 {
        for l in lane..LANES {
            wt[l] = 0.0;
        }
        flush(&j, &wt, &res, &mut h, &mut g);
    }
    drain(&mut h, &mut h_total);
    EdgeSums {
        h: h_total,
        g: g.map(|v| v.iter().sum()),
        sq,
        wsum,
    }
}

/// Half-width of the band of pixels fitted around an edge, for a blur (pixels).
pub fn half_width(blur: f64) -> f64 {
    2.0 * blur + 2.5
}

/// The normal CDF and density tabulated on [-CDF_RANGE, CDF_RANGE] every 1/CDF_STEPS:
/// the inner loop's exponentials were half the cost of a frame.
const CDF_RANGE: f64 = 8.0;
const CDF_STEPS: f64 = 16.0;
const CDF_NODES: usize = (2.0 * CDF_RANGE * CDF_STEPS) as usize + 2;
static CDF_TABLE: std::sync::OnceLock<[[f64; 2]; CDF_NODES]> = std::sync::OnceLock::new();

fn cdf_table() -> &'static [[f64; 2]; CDF_NODES] {
    CDF_TABLE.get_or_init(|| {
        let mut t = [[0.0; 2]; CDF_NODES];
        for (k, node) in t.iter_mut().enumerate() {
            let z = -CDF_RANGE + k as f64 / CDF_STEPS;
            *node = [normal_cdf(z), normal_pdf(z)];
        }
        t
    })
}

/// Standard normal CDF (cubic Hermite between the tabulated values and slopes, error
/// below 1e-7) and density (linear, error below 2e-4), outside the table 0/1 and 0.
#[inline]
fn cdf_pdf(z: f64) -> (f64, f64) {
    let pos = (z + CDF_RANGE) * CDF_STEPS;
    if pos <= 0.0 {
        return (0.0, 0.0);
    }
    let k = pos as usize;
    if k + 1 >= CDF_NODES {
        return (1.0, 0.0);
    }
    let table = cdf_table();
    let (a, b) = (table[k], table[k + 1]);
    let t = pos - k as f64;
    let h = 1.0 / CDF_STEPS;
    let (t2, t3) = (t * t, t * t * t);
    let cdf = (2.0 * t3 - 3.0 * t2 + 1.0) * a[0]
        + (t3 - 2.0 * t2 + t) * h * a[1]
        + (-2.0 * t3 + 3.0 * t2) * b[0]
        + (t3 - t2) * h * b[1];
    (cdf, a[1] + t * (b[1] - a[1]))
}

/// Standard normal density.
fn normal_pdf(z: f64) -> f64 {
    0.398_942_280_401_432_7 * (-0.5 * z * z).exp()
}

/// Accumulated normal equations `h * step = g` of one iteration.
#[derive(Debug, Clone, Copy)]
struct Normal {
    h: [[f64; N_PARAMS]; N_PARAMS],
    g: [f64; N_PARAMS],
    fixed: [bool; N_PARAMS],
    noise: [f64; 3],
}

impl Default for Normal {
    fn default() -> Self {
        Normal {
            h: [[0.0; N_PARAMS]; N_PARAMS],
            g: [0.0; N_PARAMS],
            fixed: [false; N_PARAMS],
            noise: [f64::INFINITY; 3],
        }
    }
}

/// Solves the damped normal equations with the fixed parameters held. The system is
/// scaled to a unit diagonal first, so "no information about a parameter" (a bend with
/// no bent pixels, a band of one flat level) is recognised relative to the others and
/// that parameter is held instead of failing the solve.
// Index loops mirror the textbook formulas of the small dense solves below.
#[allow(clippy::needless_range_loop)]
fn solve(
    h: &[[f64; N_PARAMS]; N_PARAMS],
    g: &[f64; N_PARAMS],
    fixed: &[bool; N_PARAMS],
) -> Option<[f64; N_PARAMS]> {
    let max_diag = (0..N_PARAMS).map(|i| h[i][i]).fold(0.0, f64::max);
    if max_diag.partial_cmp(&0.0) != Some(std::cmp::Ordering::Greater) || !max_diag.is_finite() {
        return None;
    }
    let mut scale = [0.0; N_PARAMS];
    for i in 0..N_PARAMS {
        let held = fixed[i]
            || h[i][i].partial_cmp(&(1e-14 * max_diag)) != Some(std::cmp::Ordering::Greater);
        scale[i] = if held { 0.0 } else { 1.0 / h[i][i].sqrt() };
    }
    let mut a = [[0.0; N_PARAMS]; N_PARAMS];
    let mut b = [0.0; N_PARAMS];
    for i in 0..N_PARAMS {
        for k in 0..N_PARAMS {
            a[i][k] = h[i][k] * scale[i] * scale[k];
        }
        a[i][i] = if scale[i] == 0.0 { 1.0 } else { 1.0 + 1e-9 };
        b[i] = g[i] * scale[i];
    }
    cholesky_solve(&mut a, &mut b);
    for i in 0..N_PARAMS {
        b[i] *= scale[i];
        if !b[i].is_finite() {
            return None;
        }
    }
    Some(b)
}

/// Variance factor of parameter `k` ((H^-1)_kk), free parameters only.
fn variance(h: &[[f64; N_PARAMS]; N_PARAMS], fixed: &[bool; N_PARAMS], k: usize) -> Option<f64> {
    let mut e = [0.0; N_PARAMS];
    e[k] = 1.0;
    let x = solve(h, &e, fixed)?;
    Some(x[k].max(0.0))
}

/// In-place Cholesky solve of a symmetric positive semi-definite system; a parameter
/// whose pivot vanishes (dependent on the others) is held at a zero step.
#[allow(clippy::needless_range_loop)]
fn cholesky_solve(a: &mut [[f64; N_PARAMS]; N_PARAMS], b: &mut [f64; N_PARAMS]) {
    for j in 0..N_PARAMS {
        let mut d = a[j][j];
        for k in 0..j {
            d -= a[j][k] * a[j][k];
        }
        if d <= 1e-10 {
            // No independent information left in this parameter: hold it.
            for i in j + 1..N_PARAMS {
                a[i][j] = 0.0;
            }
            a[j][j] = f64::INFINITY;
            continue;
        }
        let d = d.sqrt();
        a[j][j] = d;
        for i in j + 1..N_PARAMS {
            let mut s = a[i][j];
            for k in 0..j {
                s -= a[i][k] * a[j][k];
            }
            a[i][j] = s / d;
        }
    }
    for i in 0..N_PARAMS {
        let mut s = b[i];
        for k in 0..i {
            s -= a[i][k] * b[k];
        }
        b[i] = s / a[i][i];
    }
    for i in (0..N_PARAMS).rev() {
        let mut s = b[i];
        for k in i + 1..N_PARAMS {
            s -= a[k][i] * b[k];
        }
        b[i] = s / a[i][i];
    }
}

/// Applies a Gauss-Newton step with trust limits on the geometric parameters.
fn apply(x: &mut [f64; N_PARAMS], step: &[f64; N_PARAMS]) {
    for (k, (xk, &dk)) in x.iter_mut().zip(step).enumerate() {
        let limited = match k {
            P_TURN..=2 => dk.clamp(-0.02, 0.02),
            P_OFFSET..=5 => dk.clamp(-1.5, 1.5),
            P_BEND => dk.clamp(-2.0, 2.0),
            P_BLUR => dk.clamp(-0.3, 0.3),
            _ => dk,
        };
        *xk += limited;
    }
    x[P_BLUR] = x[P_BLUR].clamp(0.3, 4.0);
}

/// Standard normal CDF via erf (Abramowitz & Stegun 7.1.26, |error| < 1.5e-7).
pub fn normal_cdf(z: f64) -> f64 {
    let x = z * std::f64::consts::FRAC_1_SQRT_2;
    let t = 1.0 / (1.0 + 0.327_591_1 * x.abs());
    let poly = t
        * (0.254_829_592
            + t * (-0.284_496_736
                + t * (1.421_413_741 + t * (-1.453_152_027 + t * 1.061_405_429))));
    let erf = 1.0 - poly * (-x * x).exp();
    0.5 * (1.0 + erf.copysign(x))
}

#[cfg(test)]
mod tests {
    use super::*;
    use image::Luma;

    /// A blurred bright half-plane `n . p > rho` with noise-free grey levels.
    fn half_plane(normal_angle: f64, rho: f64, blur: f64) -> GrayImage {
        let n = [normal_angle.cos(), normal_angle.sin()];
        GrayImage::from_fn(200, 150, |x, y| {
            let d = n[0] * x as f64 + n[1] * y as f64 - rho;
            Luma([(60.0 + 150.0 * normal_cdf(d / blur)).round() as u8])
        })
    }

    #[test]
    fn tabulated_cdf_matches_the_direct_one() {
        for i in -1000..=1000 {
            let z = i as f64 * 0.0093;
            let (c, p) = cdf_pdf(z);
            assert!((c - normal_cdf(z)).abs() < 3e-7, "{z}");
            assert!((p - normal_pdf(z)).abs() < 2e-4, "{z}");
        }
    }

    #[test]
    fn cdf_matches_known_values() {
        assert!((normal_cdf(0.0) - 0.5).abs() < 1e-7);
        assert!((normal_cdf(1.0) - 0.841_344_746).abs() < 2e-7);
        assert!((normal_cdf(-2.0) - 0.022_750_132).abs() < 2e-7);
    }

    #[test]
    fn recovers_a_tilted_edge_to_a_hundredth_of_a_pixel() {
        let angle = 100f64.to_radians();
        let img = half_plane(angle, 60.0, 1.2);
        // Start 0.8 deg and 0.7 px off.
        let start = 100.8f64.to_radians();
        let n0 = [start.cos(), start.sin()];
        let line = Line {
            normal: n0,
            rho: 60.7,
        };
        let band = Band {
            start: line.foot([20.0, 70.0]),
            end: line.foot([180.0, 70.0]),
            line,
            bend_from: None,
            bend0: 0.0,
            bend_sigma: f64::INFINITY,
        };
        let mut r = Refiner::default();
        let fit = r
            .fit(&img, &[None, Some(band), None], false, 1.0, false)
            .unwrap();
        let e = fit.edges[1].unwrap();
        let got = e.line.normal[1].atan2(e.line.normal[0]);
        assert!(
            (got - angle).abs().to_degrees() < 0.01,
            "{}",
            got.to_degrees()
        );
        let truth = Line {
            normal: [angle.cos(), angle.sin()],
            rho: 60.0,
        };
        let p = e.line.foot([100.0, 60.0]);
        assert!(truth.depth(p).abs() < 0.02, "{}", truth.depth(p));
        assert!((e.contrast - 150.0).abs() < 2.0 && (fit.blur - 1.2).abs() < 0.1);
    }
}

#[cfg(test)]
mod debug_refine {
    use super::*;
    use std::path::Path;

    #[test]
    #[ignore]
    fn single_band_on_sample() {
        let f = std::env::var("FRAME").unwrap();
        let img = image::open(
            Path::new(env!("CARGO_MANIFEST_DIR"))
                .join("tests/data/samples")
                .join(f),
        )
        .unwrap()
        .to_luma8();
        let v: Vec<f64> = std::env::var("BAND")
            .unwrap()
            .split(',')
            .map(|s| s.parse().unwrap())
            .collect();
        let (p0, p1) = ([v[0], v[1]], [v[2], v[3]]);
        let d = [(p1[0] - p0[0]), (p1[1] - p0[1])];
        let len = d[0].hypot(d[1]);
        let mut n = [-d[1] / len, d[0] / len];
        // Orient the normal to the bright side.
        let probe = |p: [f64; 2]| img.get_pixel(p[0] as u32, p[1] as u32)[0] as f64;
        let mid = [0.5 * (p0[0] + p1[0]), 0.5 * (p0[1] + p1[1])];
        if probe([mid[0] + 4.0 * n[0], mid[1] + 4.0 * n[1]])
            < probe([mid[0] - 4.0 * n[0], mid[1] - 4.0 * n[1]])
        {
            n = [-n[0], -n[1]];
        }
        let line = Line::through(p0, n);
        let band = Band {
            start: p0,
            end: p1,
            line,
            bend_from: None,
            bend0: 0.0,
            bend_sigma: f64::INFINITY,
        };
        let mut r = Refiner::default();
        let fit = r
            .fit(&img, &[None, Some(band), None], false, 1.2, false)
            .unwrap();
        let e = fit.edges[1].unwrap();
        let dd = along(e.line.normal);
        let mut a = -(dd[1].atan2(dd[0])).to_degrees();
        while a > 90.0 {
            a -= 180.0;
        }
        while a <= -90.0 {
            a += 180.0;
        }
        println!(
            "orientation {a:.4} blur {:.2} contrast {:.1} noise {:.1} samples {} rejected {}",
            fit.blur,
            e.contrast,
            e.noise,
            e.samples,
            r.chunk_ok.iter().filter(|ok| !**ok).count()
        );
    }
}
