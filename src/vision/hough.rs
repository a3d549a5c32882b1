//! Polarity-gated Hough line search, one accumulator per tip edge.
//!
//! The paper searches each edge's lines on a slope-intercept mesh of points rotated so
//! that the edge is horizontal, within +-window of its calibrated orientation. Here the
//! mesh is (psi, rho): psi is the rotation of the tip from the reference (the same for
//! all three edges), rho the offset of the line along the edge's rotated normal, which
//! is the same parametrisation without the blow-up of slopes. Two refinements:
//! - Polarity: the probe is bright, so an edge pixel can belong to edge e only if its
//!   gradient points along e's inward normal turned by some psi in the window. Each
//!   pixel then votes only for the few psi its own gradient direction allows, instead
//!   of all of them: clutter of the wrong direction or polarity casts no vote.
//! - Peaks are read with a 3-bin rho smoothing and 5x5 non-maximum suppression, and the
//!   best few per edge are kept as line candidates for the joint rigid-tip search.
//!   The [1 2 1] smoothing rewards votes that fall in one rho bin, so a line peaks at
//!   the psi that aligns it best even when the neighbouring psi bins hold its votes too.

use super::edges::EdgePoint;
use super::geometry::{truncate_index, wrap_pi};
use super::simd::dispatch;
use super::template::{PerEdge, EDGES};

/// Width of a psi bin, radians.
pub const PSI_STEP_RAD: f64 = std::f64::consts::PI / 180.0;
/// Peaks kept per edge. A long straight line peaks again at neighbouring rotations
/// (their lines cross it and collect its pixels near the crossing); polished, those
/// peaks find the line again and are dropped. Keeping more peaks than candidates
/// (`candidates::CANDIDATES_PER_EDGE`) lets a shorter line beside long ones (a face
/// beside the stripes of a patterned sample) still reach the search.
pub const PEAKS_PER_EDGE: usize = 26;
/// Peaks kept per edge by a wide search, the most [`Hough::find_peaks`] keeps: it lets
/// a short face beside many long lines reach the search.
pub const WIDE_PEAKS_PER_EDGE: usize = 40;
/// Fewest (smoothed, so twice the pixel count) votes for a peak.
const MIN_VOTES: u16 = 10;

/// A local maximum of one edge's accumulator.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Peak {
    pub edge: usize,
    /// Tip rotation, image radians.
    pub psi: f64,
    pub rho: f64,
    pub votes: u16,
}

/// Accumulators over (edge, psi, rho) for one detection-image size and window.
#[derive(Debug, Default)]
pub struct Hough {
    n_psi: usize,
    n_rho: usize,
    psi_min: f64,
    rho_min: f64,
    window_rad: f64,
    /// Inward normal angles of the three edges in the reference, image radians.
    normal_angles: PerEdge<f64>,
    /// cos / sin of (normal angle + psi) per edge and psi bin.
    cos: Vec<f32>,
    sin: Vec<f32>,
    acc: Vec<u16>,
    smooth: Vec<u16>,
    /// Per (edge, psi) row, the rho bins holding votes, and those `smooth` was written
    /// in: only they are scanned and cleared (an empty row is `(MAX, 0)`).
    votes_span: Vec<(usize, usize)>,
    smooth_span: Vec<(usize, usize)>,
    pub peaks: Vec<Peak>,
    /// Pixels of the detection image (the most edge points there can be).
    pixels: usize,
    /// Per edge, the indices of the points that voted for it (polarity-compatible).
    pub voters: PerEdge<Vec<u32>>,
    /// Scratch of `find_peaks`: which cells of a row are the maximum of their row.
    row_max: Vec<u8>,
}

impl Hough {
    /// Sizes the accumulators; cheap when nothing changed.
    pub fn configure(
        &mut self,
        width: usize,
        height: usize,
        window_rad: f64,
        normal_angles: PerEdge<f64>,
    ) {
        self.pixels = width * height;
        let n_psi = 2 * (window_rad / PSI_STEP_RAD).ceil() as usize + 1;
        let diag = ((width * width + height * height) as f64).sqrt().ceil();
        let n_rho = 2 * diag as usize + 3;
        if n_psi == self.n_psi && n_rho == self.n_rho && normal_angles == self.normal_angles {
            return;
        }
        self.n_psi = n_psi;
        self.n_rho = n_rho;
        self.psi_min = -((n_psi / 2) as f64) * PSI_STEP_RAD;
        self.rho_min = -diag - 1.0;
        self.window_rad = window_rad;
        self.normal_angles = normal_angles;
        self.cos.clear();
        self.sin.clear();
        for nu in normal_angles {
            for k in 0..n_psi {
                let a = nu + self.psi_of(k);
                self.cos.push(a.cos() as f32);
                self.sin.push(a.sin() as f32);
            }
        }
        self.acc.clear();
        self.acc.resize(EDGES * n_psi * n_rho, 0);
        self.smooth.clear();
        self.smooth.resize(EDGES * n_psi * n_rho, 0);
        self.votes_span.clear();
        self.votes_span.resize(EDGES * n_psi, (usize::MAX, 0));
        self.smooth_span.clear();
        self.smooth_span.resize(EDGES * n_psi, (usize::MAX, 0));
        self.peaks.reserve(EDGES * WIDE_PEAKS_PER_EDGE);
    }

    fn psi_of(&self, k: usize) -> f64 {
        self.psi_min + k as f64 * PSI_STEP_RAD
    }

    /// Votes every edge point into the accumulators of the edges its polarity allows.
    /// `noise` is the gradient noise; weaker pixels get a wider direction tolerance.
    pub fn vote(&mut self, points: &[EdgePoint], noise: f32) {
        vote(self, points, noise);
    }

    /// [`Self::vote`]'s body (see [`vote`]).
    #[inline(always)]
    fn vote_body(&mut self, points: &[EdgePoint], noise: f32) {
        let (n_psi, n_rho) = (self.n_psi, self.n_rho);
        for (row, span) in self.votes_span.iter_mut().enumerate() {
            if span.0 <= span.1 {
                self.acc[row * n_rho + span.0..=row * n_rho + span.1].fill(0);
            }
            *span = (usize::MAX, 0);
        }
        for v in &mut self.voters {
            v.clear();
            // Room for every pixel of the image: no growth after warm-up.
            v.reserve(self.pixels);
        }
        // Offset so that bins are found by truncation of a positive number.
        let rho_shift = (0.5 - self.rho_min) as f32;
        for (index, p) in points.iter().enumerate() {
            let tol = (1.5 * noise / p.mag) as f64 + 1.5f64.to_radians();
            let tol = tol.clamp(2f64.to_radians(), 8f64.to_radians());
            for e in 0..EDGES {
                let psi = wrap_pi(p.angle as f64 - self.normal_angles[e]);
                if psi.abs() > self.window_rad + tol {
                    continue;
                }
                self.voters[e].push(index as u32);
                let lo = (((psi - tol - self.psi_min) / PSI_STEP_RAD).ceil()).max(0.0) as usize;
                let hi = (((psi + tol - self.psi_min) / PSI_STEP_RAD).floor() as isize)
                    .min(n_psi as isize - 1);
                for k in lo as isize..=hi {
                    let k = k as usize;
                    let row = e * n_psi + k;
                    let rho = p.x * self.cos[row] + p.y * self.sin[row];
                    // Positive: rho_min lies a pixel below any rho.
                    let bin = truncate_index(rho + rho_shift);
                    let cell = &mut self.acc[row * n_rho + bin];
                    *cell = cell.saturating_add(1);
                    let span = &mut self.votes_span[row];
                    *span = (span.0.min(bin), span.1.max(bin));
                }
            }
        }
    }

    /// Fills `self.peaks` with up to `most` best local maxima per edge
    /// ([`PEAKS_PER_EDGE`], or [`WIDE_PEAKS_PER_EDGE`] in a wide search; at most that).
    pub fn find_peaks(&mut self, most: usize) {
        find_peaks(self, most.min(WIDE_PEAKS_PER_EDGE));
    }

    /// [`Self::find_peaks`]'s body (see [`find_peaks`]).
    #[inline(always)]
    fn find_peaks_body(&mut self, most: usize) {
        let (n_psi, n_rho) = (self.n_psi, self.n_rho);
        for row in 0..EDGES * n_psi {
            let dst = &mut self.smooth[row * n_rho..(row + 1) * n_rho];
            let old = self.smooth_span[row];
            if old.0 <= old.1 {
                dst[old.0..=old.1].fill(0);
            }
            let (lo, hi) = self.votes_span[row];
            if lo > hi {
                self.smooth_span[row] = (usize::MAX, 0);
                continue;
            }
            // Votes never land in the first or last bin (rho_min has a margin).
            let (a, b) = (lo.max(2) - 1, (hi + 1).min(n_rho - 2));
            let src = &self.acc[row * n_rho..(row + 1) * n_rho];
            // Shifted slices zipped together: the loop vectorises.
            let (before, at, after) = (&src[a - 1..b], &src[a..=b], &src[a + 1..b + 2]);
            for (((d, &l), &c), &r) in dst[a..=b].iter_mut().zip(before).zip(at).zip(after) {
                *d = l.saturating_add(c.saturating_mul(2)).saturating_add(r);
            }
            self.smooth_span[row] = (a, b);
        }
        self.peaks.clear();
        self.row_max.resize(n_rho, 0);
        for e in 0..EDGES {
            let first = self.peaks.len();
            for k in 0..n_psi {
                let (a, b) = self.smooth_span[e * n_psi + k];
                let (lo, hi) = (a.max(2), b.min(n_rho - 3));
                if lo > hi {
                    continue;
                }
                self.row_maxima(e * n_psi + k, lo, hi);
                // Eight flags at a time: most cells are no maximum of their row.
                for (c, flags) in self.row_max[..hi + 1 - lo].chunks(8).enumerate() {
                    let mut word = [0u8; 8];
                    word[..flags.len()].copy_from_slice(flags);
                    let mut word = u64::from_le_bytes(word);
                    while word != 0 {
                        let i = lo + 8 * c + word.trailing_zeros() as usize / 8;
                        word &= word - 1;
                        let v = self.smooth[(e * n_psi + k) * n_rho + i];
                        if self.is_local_max(e, k, i, v) {
                            let peak = Peak {
                                edge: e,
                                psi: self.psi_of(k),
                                rho: self.rho_min + i as f64,
                                votes: v,
                            };
                            insert_top(&mut self.peaks, first, peak, most);
                        }
                    }
                }
            }
        }
    }

    /// Flags (`row_max[i - lo]` = 1) the cells `lo..=hi` of smoothed row `row` that have
    /// [`MIN_VOTES`] and are the maximum of their five cells in the row (ties broken
    /// as in [`Self::is_local_max`], which they must also pass).
    #[inline(always)]
    fn row_maxima(&mut self, row: usize, lo: usize, hi: usize) {
        let n_rho = self.n_rho;
        let s = &self.smooth[row * n_rho..(row + 1) * n_rho];
        let (m2, m1, c) = (&s[lo - 2..hi - 1], &s[lo - 1..hi], &s[lo..=hi]);
        let (p1, p2) = (&s[lo + 1..hi + 2], &s[lo + 2..hi + 3]);
        let cells = c.iter().zip(m2).zip(m1).zip(p1).zip(p2);
        for (f, ((((&v, &m2), &m1), &p1), &p2)) in self.row_max.iter_mut().zip(cells) {
            let max = (v >= MIN_VOTES) & (v > m2) & (v > m1) & (v >= p1) & (v >= p2);
            *f = max as u8;
        }
    }

    /// Whether cell (e, k, i) with smoothed value v is the maximum of its 5x5
    /// neighbourhood (ties broken towards the lower index).
    #[inline(always)]
    fn is_local_max(&self, e: usize, k: usize, i: usize, v: u16) -> bool {
        let (n_psi, n_rho) = (self.n_psi, self.n_rho);
        for kk in k.saturating_sub(2)..(k + 3).min(n_psi) {
            let row = (e * n_psi + kk) * n_rho;
            for ii in i - 2..=i + 2 {
                let w = self.smooth[row + ii];
                let before = (kk, ii) < (k, i);
                if w > v || (w == v && before) {
                    return false;
                }
            }
        }
        true
    }
}

dispatch! {
    /// [`Hough::vote_body`], with AVX2 when the CPU has it (see `vision::simd`; its
    /// rounding instructions also replace the library calls of `ceil` and `floor`).
    fn vote(hough: &mut Hough, points: &[EdgePoint], noise: f32) => Hough::vote_body
}

dispatch! {
    /// [`Hough::find_peaks_body`], with AVX2 when the CPU has it (see `vision::simd`).
    fn find_peaks(hough: &mut Hough, most: usize) => Hough::find_peaks_body
}

/// Inserts `peak` into the descending list `peaks[first..]`, keeping at most `most`
/// entries there.
fn insert_top(peaks: &mut Vec<Peak>, first: usize, peak: Peak, most: usize) {
    let n = peaks.len() - first;
    if n == most && peaks[peaks.len() - 1].votes >= peak.votes {
        return;
    }
    let pos = peaks[first..]
        .iter()
        .position(|q| q.votes < peak.votes)
        .map_or(peaks.len(), |p| p + first);
    if n == most {
        peaks.pop();
    }
    peaks.insert(pos, peak);
}

#[cfg(test)]
mod tests {
    use super::*;

    fn line_points(angle_deg: f64, offset: f64, normal_deg: f64, n: usize) -> Vec<EdgePoint> {
        let a = angle_deg.to_radians();
        let nrm = normal_deg.to_radians();
        (0..n)
            .map(|i| {
                let t = i as f64 - n as f64 / 2.0;
                let (x, y) = (100.0 + t * a.cos(), 100.0 + t * a.sin() + offset);
                EdgePoint {
                    x: x as f32,
                    y: y as f32,
                    angle: nrm as f32,
                    ux: nrm.cos() as f32,
                    uy: nrm.sin() as f32,
                    mag: 50.0,
                }
            })
            .collect()
    }

    #[test]
    fn a_rotated_line_peaks_at_its_rotation_and_only_for_its_polarity() {
        let mut h = Hough::default();
        // Edge 0: horizontal in the reference, bright below (normal at +90 deg).
        let normals = [90f64.to_radians(), 0.0, 180f64.to_radians()];
        h.configure(320, 240, 20f64.to_radians(), normals);
        // The line turned by +7 deg (image angle): normal at 97 deg.
        let pts = line_points(7.0, 0.0, 97.0, 80);
        h.vote(&pts, 1.0);
        h.find_peaks(PEAKS_PER_EDGE);
        let best = h.peaks.iter().find(|p| p.edge == 0).unwrap();
        assert!((best.psi.to_degrees() - 7.0).abs() <= 1.0, "{best:?}");
        assert!(best.votes >= 140, "{best:?}");
        // Edge 1's normal (0 deg) is 97 deg away: no votes at all.
        assert!(h.peaks.iter().all(|p| p.edge != 1));
        // Reversed polarity votes for nothing.
        let flipped = line_points(7.0, 0.0, -83.0, 80);
        h.vote(&flipped, 1.0);
        h.find_peaks(PEAKS_PER_EDGE);
        assert!(h.peaks.is_empty(), "{:?}", h.peaks);
    }

    #[test]
    fn top_list_stays_sorted_and_bounded() {
        let mut v = Vec::new();
        let all: Vec<u16> = (0..40u16).map(|i| (i * 37) % 101).collect();
        for &votes in &all {
            let peak = Peak {
                edge: 0,
                psi: 0.0,
                rho: 0.0,
                votes,
            };
            insert_top(&mut v, 0, peak, PEAKS_PER_EDGE);
        }
        let got: Vec<u16> = v.iter().map(|p| p.votes).collect();
        let mut expected = all.clone();
        expected.sort_by(|a, b| b.cmp(a));
        expected.truncate(PEAKS_PER_EDGE);
        assert_eq!(got, expected);
    }

    /// Thirty long lines of one polarity fill an edge's peaks; a short one beside them
    /// reaches only a wide search's.
    #[test]
    fn a_wide_search_keeps_a_short_line_beside_many_long_ones() {
        let normals = [90f64.to_radians(), 0.0, 180f64.to_radians()];
        let mut pts = Vec::new();
        for k in 0..30 {
            pts.extend(line_points(0.0, -90.0 + 6.0 * f64::from(k), 90.0, 120));
        }
        pts.extend(line_points(0.0, 100.0, 90.0, 25));
        let short_kept = |most: usize| {
            let mut h = Hough::default();
            h.configure(320, 240, 20f64.to_radians(), normals);
            h.vote(&pts, 1.0);
            h.find_peaks(most);
            let short = h.peaks.iter().find(|p| p.edge == 0 && p.votes < 100);
            short.is_some_and(|p| p.psi.abs() < 0.01 && (p.rho - 200.0).abs() <= 1.0)
        };
        assert!(!short_kept(PEAKS_PER_EDGE));
        assert!(short_kept(WIDE_PEAKS_PER_EDGE));
    }
}
