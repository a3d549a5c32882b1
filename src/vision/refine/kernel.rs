//! The inner loop of the fit: every sample's residual, robust weight and Jacobian,
//! accumulated into the normal equations (about 44 products per sample and iteration,
//! and ten more for its stretch's own outside level; this is where the tracker spends
//! a quarter to a third of its time). It runs as an AVX2 copy where the CPU has it
//! (`vision::simd`).

use super::gauss::{cdf_pdf_lanes, cdf_table, CdfTable};
use super::solve::Normal;
use super::{
    pixel_weight, EdgeFrame, Refiner, Sample, Stretches, ALONG_UNIT_PX, BEND_UNIT_PX,
    CHUNKS_PER_EDGE, N_PARAMS, PHOTO, P_BEND, P_BLUR, P_OFFSET, P_PHOTO, P_TURN,
    STRETCH_LEVEL_SIGMA,
};
use crate::vision::geometry::{along, dot, rotate, sub};
use crate::vision::simd::dispatch;
use crate::vision::template::{PerEdge, EDGES};

impl Refiner {
    pub(super) fn normal_equations(
        &mut self,
        frames: &PerEdge<Option<EdgeFrame>>,
        x: &[f64; N_PARAMS],
        noise: &PerEdge<f64>,
        shared: bool,
        step: usize,
    ) -> Normal {
        let mut ne = Normal::default();
        let st = &mut self.stretches;
        st.sq = [0.0; EDGES * CHUNKS_PER_EDGE];
        st.n = [0; EDGES * CHUNKS_PER_EDGE];
        st.row = [[0.0; 8]; EDGES * CHUNKS_PER_EDGE];
        st.hh = [0.0; EDGES * CHUNKS_PER_EDGE];
        st.g = [0.0; EDGES * CHUNKS_PER_EDGE];
        let mut sq = [0.0f64; EDGES];
        let mut wsum = [0.0f64; EDGES];
        let normals: PerEdge<[f64; 2]> = std::array::from_fn(|e| {
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
            let params = EdgeParams::new(f, normals[e], x, e, noise[e]);
            let range = self.ranges[e].clone();
            let mut acc =
                accumulate_edge(&self.samples[range], step, f, &params, &mut self.stretches);
            sq[e] = acc.sq;
            wsum[e] = acc.wsum;
            self.slots[e] = slots;
            // The stretches' own outside levels, with their prior, eliminated.
            let weight = pixel_weight(noise[e], STRETCH_LEVEL_SIGMA, step);
            eliminate_stretches(&mut self.stretches, e, weight, &mut acc);
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
        for e in 0..EDGES {
            ne.noise[e] = if wsum[e] > 0.0 {
                (sq[e] / wsum[e]).sqrt().max(0.5)
            } else {
                f64::INFINITY
            };
            if frames[e].is_none() {
                ne.fixed[P_OFFSET + e] = true;
                // An absent edge's own rotation is held; the shared one (slot 0 in
                // tracking mode) belongs to every edge.
                if !shared {
                    ne.fixed[P_TURN + e] = true;
                }
                for k in 0..PHOTO {
                    ne.fixed[P_PHOTO + PHOTO * e + k] = true;
                }
            }
        }
        if shared {
            // One rotation for all: the first edge's.
            for e in 1..EDGES {
                ne.fixed[P_TURN + e] = true;
            }
        }
        if !frames.iter().flatten().any(|f| f.curved) {
            ne.fixed[P_BEND] = true;
        }
        ne
    }
}

/// Eliminates edge `e`'s stretch levels from its sums `acc` (the Schur complement: a
/// stretch level is seen only by its own samples), after adding their prior (zero
/// around the edge's linear outside level, `weight` in the units of the pixel sums).
/// Leaves in `st.hh` and `st.g` each level's own equation, for [`Refiner::step_levels`].
fn eliminate_stretches(st: &mut Stretches, e: usize, weight: f64, acc: &mut EdgeSums) {
    for c in e * CHUNKS_PER_EDGE..(e + 1) * CHUNKS_PER_EDGE {
        if st.hh[c] == 0.0 {
            // No sample of the stretch counts: its level stays where it is.
            continue;
        }
        st.hh[c] += weight;
        st.g[c] -= weight * st.level[c];
        let (row, hh, g) = (st.row[c], st.hh[c], st.g[c]);
        let mut k = 0;
        for i in 0..8 {
            acc.g[i] -= row[i] * g / hh;
            for j in i..8 {
                acc.h[k] -= row[i] * row[j] / hh;
                k += 1;
            }
        }
    }
}

/// The current parameters of one edge, as the inner loop needs them.
struct EdgeParams {
    normal: [f64; 2],
    along: [f64; 2],
    offset: f64,
    bend: f64,
    /// 1 / blur (pixels).
    inv_blur: f64,
    /// Where along the edge (from its origin, pixels) a curved edge starts to bend.
    corner_t: f64,
    /// level, level slope, contrast, contrast slope
    photo: [f64; 4],
    /// Huber threshold on the residual, grey levels.
    huber: f64,
}

impl EdgeParams {
    /// Edge `e`'s parameters in `x` with its line's inward normal `normal`, and the
    /// Huber threshold for its residual noise `noise`.
    fn new(f: &EdgeFrame, normal: [f64; 2], x: &[f64; N_PARAMS], e: usize, noise: f64) -> Self {
        let p0 = P_PHOTO + PHOTO * e;
        EdgeParams {
            normal,
            along: along(normal),
            offset: x[P_OFFSET + e],
            bend: x[P_BEND],
            inv_blur: 1.0 / x[P_BLUR],
            corner_t: dot(along(normal), sub(f.corner, f.origin)),
            photo: [x[p0], x[p0 + 1], x[p0 + 2], x[p0 + 3]],
            huber: 1.5 * noise,
        }
    }
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
#[inline(always)]
fn accumulate_edge_body(
    samples: &[Sample],
    step: usize,
    f: &EdgeFrame,
    p: &EdgeParams,
    st: &mut Stretches,
) -> EdgeSums {
    let mut acc = Accumulator::default();
    let (mut sq, mut wsum) = (0.0, 0.0);
    let table = cdf_table();
    let mut lanes = StretchLanes::default();
    let mut m = ModelLanes::default();
    for first in (0..samples.len()).step_by(LANES * step) {
        let batch = Batch::take(samples, first, step);
        batch.model(table, f, p, &st.level, &mut m);
        let all_ok = batch.sums(&m, st, &mut lanes, &mut sq, &mut wsum);
        if all_ok && acc.lane == 0 {
            // The common case: the batch's lanes are the accumulator's.
            acc.add(&m.jac, &m.weight, &m.r);
        } else {
            for l in (0..batch.len).filter(|&l| st.ok[batch.chunk[l]]) {
                acc.push(&m, l);
            }
        }
    }
    lanes.flush(st);
    let (h, g) = acc.finish();
    EdgeSums { h, g, sq, wsum }
}

dispatch! {
    /// [`accumulate_edge_body`], with AVX2 when the CPU has it (see `vision::simd`).
    fn accumulate_edge(
        samples: &[Sample],
        step: usize,
        f: &EdgeFrame,
        p: &EdgeParams,
        st: &mut Stretches,
    ) -> EdgeSums => accumulate_edge_body
}

/// Samples in flight through [`flush`] at once.
const LANES: usize = 4;

/// The normal matrix is accumulated in f32 lanes (its rounding only slows the
/// convergence a little), flushed into f64 every this many samples; the gradient, which
/// decides where the fit stops, stays in f64.
const BLOCK: usize = 64;

/// One edge's normal equations being summed, lane by lane: lane `l` takes every fourth
/// sample that counts (samples of rejected stretches are skipped, not zeroed).
struct Accumulator {
    h_total: [f64; 36],
    h: [[f32; LANES]; 36],
    g: [[f64; LANES]; 8],
    /// Samples gathered one by one until their lanes are full (after a skipped sample
    /// the batches no longer line up with the lanes).
    j: [[f64; LANES]; 8],
    wt: [f64; LANES],
    res: [f64; LANES],
    lane: usize,
    /// Samples in `h` since the last drain.
    pending: usize,
}

impl Default for Accumulator {
    fn default() -> Self {
        Accumulator {
            h_total: [0.0; 36],
            h: [[0.0; LANES]; 36],
            g: [[0.0; LANES]; 8],
            j: [[0.0; LANES]; 8],
            wt: [0.0; LANES],
            res: [0.0; LANES],
            lane: 0,
            pending: 0,
        }
    }
}

impl Accumulator {
    /// Adds four samples at once (lanes in order).
    #[inline(always)]
    fn add(&mut self, j: &[[f64; LANES]; 8], wt: &[f64; LANES], res: &[f64; LANES]) {
        flush(j, wt, res, &mut self.h, &mut self.g);
        self.pending += LANES;
        if self.pending >= BLOCK {
            self.drain();
        }
    }

    /// Adds lane `l` of `m` in the next free lane.
    #[inline(always)]
    fn push(&mut self, m: &ModelLanes, l: usize) {
        for (ja, v) in self.j.iter_mut().zip(&m.jac) {
            ja[self.lane] = v[l];
        }
        self.wt[self.lane] = m.weight[l];
        self.res[self.lane] = m.r[l];
        self.lane += 1;
        if self.lane == LANES {
            flush(&self.j, &self.wt, &self.res, &mut self.h, &mut self.g);
            self.lane = 0;
            self.pending += LANES;
            if self.pending >= BLOCK {
                self.drain();
            }
        }
    }

    #[inline(always)]
    fn drain(&mut self) {
        for (t, v) in self.h_total.iter_mut().zip(self.h.iter_mut()) {
            *t += v.iter().map(|&x| x as f64).sum::<f64>();
            *v = [0.0; LANES];
        }
        self.pending = 0;
    }

    /// The matrix (upper triangle) and the gradient.
    #[inline(always)]
    fn finish(mut self) -> ([f64; 36], [f64; 8]) {
        if self.lane > 0 {
            // The free lanes add exact zeros.
            self.wt[self.lane..].fill(0.0);
            self.res[self.lane..].fill(0.0);
            for ja in &mut self.j {
                ja[self.lane..].fill(0.0);
            }
            flush(&self.j, &self.wt, &self.res, &mut self.h, &mut self.g);
        }
        self.drain();
        (self.h_total, self.g.map(|v| v.iter().sum()))
    }
}

/// Adds four samples' Jacobians `j`, weights `wt` and residuals `res` to the normal
/// matrix lanes `h` (f32, upper triangle) and the gradient lanes `g`. Inlined: it runs
/// for every four samples, and as a call it kept the lanes in memory.
// Lane loops are indexed on purpose: that is the shape the vectoriser recognises.
#[allow(clippy::needless_range_loop)]
#[inline(always)]
fn flush(
    j: &[[f64; LANES]; 8],
    wt: &[f64; LANES],
    res: &[f64; LANES],
    h: &mut [[f32; LANES]; 36],
    g: &mut [[f64; LANES]; 8],
) {
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
}

/// One stretch's level terms (see [`Stretches`]) being summed lane by lane while the
/// batches stay in that stretch; added to the stretch's sums when they move on.
struct StretchLanes {
    /// The stretch being summed, if any.
    chunk: Option<usize>,
    /// Products of the level's share with the eight local parameters' Jacobians, with
    /// itself and with the residuals, weighted.
    row: [[f64; LANES]; 8],
    hh: [f64; LANES],
    g: [f64; LANES],
}

impl Default for StretchLanes {
    fn default() -> Self {
        StretchLanes {
            chunk: None,
            row: [[0.0; LANES]; 8],
            hh: [0.0; LANES],
            g: [0.0; LANES],
        }
    }
}

impl StretchLanes {
    /// Adds the four samples of `m`, all in stretch `c`.
    // Lane loops are indexed on purpose: that is the shape the vectoriser recognises.
    #[allow(clippy::needless_range_loop)]
    #[inline(always)]
    fn add(&mut self, c: usize, m: &ModelLanes, st: &mut Stretches) {
        if self.chunk != Some(c) {
            self.flush(st);
            self.chunk = Some(c);
        }
        let mut wq = [0.0; LANES];
        for l in 0..LANES {
            wq[l] = m.weight[l] * m.q[l];
            self.hh[l] += wq[l] * m.q[l];
            self.g[l] += wq[l] * m.r[l];
        }
        for a in 0..8 {
            for l in 0..LANES {
                self.row[a][l] += wq[l] * m.jac[a][l];
            }
        }
    }

    /// Adds the lanes to their stretch's sums and empties them.
    #[inline(always)]
    fn flush(&mut self, st: &mut Stretches) {
        let Some(c) = self.chunk.take() else { return };
        st.hh[c] += self.hh.iter().sum::<f64>();
        st.g[c] += self.g.iter().sum::<f64>();
        for (total, lanes) in st.row[c].iter_mut().zip(&self.row) {
            *total += lanes.iter().sum::<f64>();
        }
        *self = StretchLanes::default();
    }
}

/// Up to [`LANES`] samples, unpacked for lane arithmetic.
#[derive(Default)]
struct Batch {
    x: [f64; LANES],
    y: [f64; LANES],
    value: [f64; LANES],
    chunk: [usize; LANES],
    /// Lanes holding a sample (the rest hold zeros).
    len: usize,
}

/// The residuals of a [`Batch`]'s samples and what they add to the normal equations,
/// lane by lane (see the module `refine` for the model).
#[derive(Default)]
struct ModelLanes {
    r: [f64; LANES],
    /// Squared residual, robust (Huber) weight, weighted squared residual.
    r2: [f64; LANES],
    weight: [f64; LANES],
    wr2: [f64; LANES],
    /// Jacobian: turn, offset, bend, blur, level, level slope, contrast, contrast slope.
    jac: [[f64; LANES]; 8],
    /// The stretch level's share of the sample (1 outside the edge, 0 inside).
    q: [f64; LANES],
}

impl Batch {
    /// The samples `first`, `first + step`, ... (up to [`LANES`] of them). A new batch
    /// each time, not one refilled: then the compiler keeps it in registers, where a
    /// refilled one was stored lane by lane and loaded as vectors, and a vector load of
    /// a value stored in pieces waits for the pieces to reach the cache.
    #[inline(always)]
    fn take(samples: &[Sample], first: usize, step: usize) -> Batch {
        let mut batch = Batch::default();
        let rest = &samples[first..];
        if step == 1 && rest.len() >= LANES {
            // The common case, in a shape the compiler unrolls.
            for (l, s) in rest[..LANES].iter().enumerate() {
                batch.set(l, s);
            }
            batch.len = LANES;
            return batch;
        }
        for s in rest.iter().step_by(step).take(LANES) {
            batch.set(batch.len, s);
            batch.len += 1;
        }
        batch
    }

    /// Adds the batch's squared residuals `m.r2` to their stretches' sums and, for the
    /// samples of stretches that count, `m.wr2` to `sq`, the weights to `wsum` and the
    /// stretch level's terms to its normal equations (through `lanes` while the batches
    /// stay in one stretch), sample after sample in the samples' order; returns whether
    /// all four count.
    #[inline(always)]
    fn sums(
        &self,
        m: &ModelLanes,
        st: &mut Stretches,
        lanes: &mut StretchLanes,
        sq: &mut f64,
        wsum: &mut f64,
    ) -> bool {
        let c = self.chunk[0];
        if self.len == LANES && self.chunk == [c; LANES] {
            // The common case: one stretch (its sums kept in registers).
            let mut s = st.sq[c];
            for r2 in m.r2 {
                s += r2;
            }
            st.sq[c] = s;
            st.n[c] += LANES as u32;
            if st.ok[c] {
                for l in 0..LANES {
                    *sq += m.wr2[l];
                    *wsum += m.weight[l];
                }
                lanes.add(c, m, st);
            }
            return st.ok[c];
        }
        lanes.flush(st);
        let mut all_ok = self.len == LANES;
        for l in 0..self.len {
            let c = self.chunk[l];
            st.sq[c] += m.r2[l];
            st.n[c] += 1;
            if st.ok[c] {
                *sq += m.wr2[l];
                *wsum += m.weight[l];
                let wq = m.weight[l] * m.q[l];
                st.hh[c] += wq * m.q[l];
                st.g[c] += wq * m.r[l];
                for (row, jac) in st.row[c].iter_mut().zip(&m.jac) {
                    *row += wq * jac[l];
                }
            } else {
                all_ok = false;
            }
        }
        all_ok
    }

    #[inline(always)]
    fn set(&mut self, l: usize, s: &Sample) {
        (self.x[l], self.y[l]) = (s.x as f64, s.y as f64);
        self.value[l] = s.value as f64;
        self.chunk[l] = s.chunk as usize;
    }

    /// Model, residual, weight and Jacobian of every lane. Each lane computes exactly
    /// what a sample at a time did (same operations, same order), four at a time so
    /// that the compiler turns it into vector arithmetic.
    #[inline(always)]
    fn model(
        &self,
        table: &CdfTable,
        f: &EdgeFrame,
        p: &EdgeParams,
        levels: &[f64],
        m: &mut ModelLanes,
    ) {
        use std::array::from_fn;
        // One simple loop per quantity (each becomes vector arithmetic; as one loop
        // with a branch inside, the compiler left it scalar). Every lane computes what
        // a sample at a time did, in the same order.
        let rx: [f64; LANES] = from_fn(|l| self.x[l] - f.origin[0]);
        let ry: [f64; LANES] = from_fn(|l| self.y[l] - f.origin[1]);
        let u: [f64; LANES] = from_fn(|l| p.along[0] * rx[l] + p.along[1] * ry[l]);
        let w3: [f64; LANES] = if f.curved {
            from_fn(|l| {
                let w = (f.towards * (u[l] - p.corner_t)).max(0.0) * (1.0 / BEND_UNIT_PX);
                w * w * w
            })
        } else {
            [0.0; LANES]
        };
        let z: [f64; LANES] = from_fn(|l| {
            let d = p.normal[0] * rx[l] + p.normal[1] * ry[l] - p.offset - p.bend * w3[l];
            d * p.inv_blur
        });
        let un: [f64; LANES] = from_fn(|l| u[l] * (1.0 / ALONG_UNIT_PX));
        let (cdf, pdf) = cdf_pdf_lanes(table, &z);
        let level: [f64; LANES] = from_fn(|l| levels[self.chunk[l]]);
        let contrast: [f64; LANES] = from_fn(|l| p.photo[2] + p.photo[3] * un[l]);
        let q: [f64; LANES] = from_fn(|l| 1.0 - cdf[l]);
        let r: [f64; LANES] = from_fn(|l| {
            self.value[l]
                - (p.photo[0] + p.photo[1] * un[l] + contrast[l] * cdf[l] + level[l] * q[l])
        });
        let weight: [f64; LANES] = from_fn(|l| {
            if r[l].abs() <= p.huber {
                1.0
            } else {
                p.huber / r[l].abs()
            }
        });
        let dd: [f64; LANES] = from_fn(|l| (contrast[l] - level[l]) * pdf[l] * p.inv_blur);
        m.r = r;
        m.r2 = from_fn(|l| r[l] * r[l]);
        m.weight = weight;
        m.wr2 = from_fn(|l| weight[l] * r[l] * r[l]);
        m.q = q;
        m.jac = [
            from_fn(|l| -dd[l] * u[l]),
            from_fn(|l| -dd[l]),
            from_fn(|l| -dd[l] * w3[l]),
            from_fn(|l| -dd[l] * z[l]),
            [1.0; LANES],
            un,
            cdf,
            from_fn(|l| cdf[l] * un[l]),
        ];
    }
}

/// What one stretch adds to a fit with free rotations, for the rotations'
/// cluster-robust standard errors (`Refiner::clustered_turn_sigma`); local parameter
/// order (see [`EdgeSums`]).
pub(super) struct StretchShare {
    /// Its index among the bands' stretches.
    pub stretch: usize,
    /// Its score: the sum over its samples of robust weight x residual x Jacobian.
    pub score: [f64; 8],
    /// Its share of the normal matrix, its own outside level eliminated (with that
    /// level's prior): with the fit's robust weights, and with the M-estimator's
    /// derivative of the weighted residual (1 within the Huber threshold, 0 beyond).
    pub fitted: [[f64; 8]; 8],
    pub psi: [[f64; 8]; 8],
}

/// A stretch's normal-matrix terms with one kind of sample weight: the local block,
/// the level's products with the local parameters, and with itself.
#[derive(Clone, Copy)]
struct LevelBlock {
    h: [[f64; 8]; 8],
    row: [f64; 8],
    hh: f64,
}

impl LevelBlock {
    const ZERO: LevelBlock = LevelBlock {
        h: [[0.0; 8]; 8],
        row: [0.0; 8],
        hh: 0.0,
    };

    fn add(&mut self, weight: f64, jac: &[f64; 8], q: f64) {
        for a in 0..8 {
            for b in 0..8 {
                self.h[a][b] += weight * jac[a] * jac[b];
            }
            self.row[a] += weight * q * jac[a];
        }
        self.hh += weight * q * q;
    }

    /// The block with the level eliminated (its prior weight `prior` added).
    fn reduced(&self, prior: f64) -> [[f64; 8]; 8] {
        let hh = self.hh + prior;
        std::array::from_fn(|a| {
            std::array::from_fn(|b| self.h[a][b] - self.row[a] * self.row[b] / hh)
        })
    }
}

impl Refiner {
    /// Each counted stretch's [`StretchShare`] at the parameters `x`, each edge's
    /// rotation its own, the Huber thresholds from the residual noises `noise`. A
    /// calibration's cost (one more pass over the samples), not the tracker's.
    pub(super) fn stretch_shares(
        &self,
        frames: &PerEdge<Option<EdgeFrame>>,
        x: &[f64; N_PARAMS],
        noise: &PerEdge<f64>,
    ) -> Vec<StretchShare> {
        let mut score = vec![[0.0; 8]; EDGES * CHUNKS_PER_EDGE];
        let mut blocks = vec![[LevelBlock::ZERO; 2]; EDGES * CHUNKS_PER_EDGE];
        let mut counted = [false; EDGES * CHUNKS_PER_EDGE];
        let table = cdf_table();
        let mut m = ModelLanes::default();
        for (e, f) in frames.iter().enumerate() {
            let Some(f) = f else { continue };
            let normal = rotate(f.normal0, x[P_TURN + e]);
            let params = EdgeParams::new(f, normal, x, e, noise[e]);
            let samples = &self.samples[self.ranges[e].clone()];
            for first in (0..samples.len()).step_by(LANES) {
                let batch = Batch::take(samples, first, 1);
                batch.model(table, f, &params, &self.stretches.level, &mut m);
                for l in 0..batch.len {
                    let c = batch.chunk[l];
                    if !self.stretches.ok[c] {
                        continue;
                    }
                    counted[c] = true;
                    let jac: [f64; 8] = std::array::from_fn(|a| m.jac[a][l]);
                    let psi = m.weight[l] * m.r[l];
                    for (s, j) in score[c].iter_mut().zip(&jac) {
                        *s += psi * j;
                    }
                    let inside = if m.r[l].abs() <= params.huber {
                        1.0
                    } else {
                        0.0
                    };
                    blocks[c][0].add(m.weight[l], &jac, m.q[l]);
                    blocks[c][1].add(inside, &jac, m.q[l]);
                }
            }
        }
        (0..EDGES * CHUNKS_PER_EDGE)
            .filter(|&c| counted[c])
            .map(|c| {
                let prior = pixel_weight(noise[c / CHUNKS_PER_EDGE], STRETCH_LEVEL_SIGMA, 1);
                StretchShare {
                    stretch: c,
                    score: score[c],
                    fitted: blocks[c][0].reduced(prior),
                    psi: blocks[c][1].reduced(prior),
                }
            })
            .collect()
    }
}
