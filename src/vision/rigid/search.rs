//! Where a rigid probe may be in a frame with no prior: a polarity-gated Hough search
//! on the coarse detection image for the two apex edges, which agree on one rotation
//! and meet at the apex, and for one more edge at a distance from the apex that gives
//! the scale.
//!
//! A pixel of the detection image votes for an edge only at the rotations its
//! gradient direction allows (the edge's calibrated inward normal and polarity turned
//! by psi, within a degree and a half), so clutter of the wrong direction or polarity
//! casts no vote. Per rotation bin the apex edges' best lines are paired; each pair
//! places the apex; the scale edge's best line at the distances the scale range allows
//! gives the scale. The best placements, scored by their summed votes, go on to the
//! fit and the verification; when none verifies, apexes inside the first apex edge's
//! runs compete too (`Search::placements_within_runs`).

use super::{Bounds, Pose, RigidEdge, RigidTemplate};
use crate::vision::claim::{claimed, Claim};
use crate::vision::geometry::{
    add, clip_to_rect, nearest_pixel, rotate, scale, sub, truncate_index, Line,
};
use crate::vision::pyramid::Pyramid;
use crate::vision::ScaleRange;

/// Width of a rotation bin, radians.
const PSI_STEP: f64 = std::f64::consts::PI / 180.0;
/// A pixel votes in its own rotation bin and this many either side.
const SPREAD_BINS: usize = 1;
/// Gradient magnitudes below this many times the gradient noise do not vote.
const VOTE_NOISE: f32 = 2.0;
/// Lines kept per apex edge and rotation bin.
const LINES_PER_BIN: usize = 3;
/// Fewest smoothed votes (about twice the pixels) a line needs; a first apex edge's
/// line only as a peak (its end then places the apex).
const MIN_VOTES: f32 = 12.0;
const MIN_PEAK_VOTES: f32 = 4.0;
/// A detection pixel supports a line within this distance when its gradient is
/// within this angle of the line's, and a run of support bridges this many pixels
/// without it (a particle or scratch across the edge, 8 frame pixels at the usual
/// binning; twice that joins an edge to lines beyond its end).
const RUN_HALF_WIDTH: i32 = 1;
const RUN_ANGLE_RAD: f64 = 0.35;
/// The first apex edge's pixels support its line within this distance, frame pixels
/// (and at least [`RUN_HALF_WIDTH`]): a line of the search's bins (a degree, a pixel)
/// through a long edge drifts from it toward its ends, and a needle's flank of
/// 600 px, searched at full resolution for its short end face, lay 2.6 px from its
/// line at the tip (tool seed 13), where its run stopped short. The other apex edge
/// is short enough not to drift.
const FLANK_HALF_WIDTH_PX: f64 = 2.0;
const RUN_GAP: usize = 4;
/// Placements handed to the fit, best first.
pub const MAX_PLACEMENTS: usize = 6;
/// Placements this close in rotation (bins) and apex (detection pixels) are one.
const SAME_PSI_BINS: f64 = 2.5;
const SAME_APEX_PX: f64 = 4.0;
/// A run's end is a candidate apex when the run spans this many detection pixels (a
/// pixel or two of support is the noise's).
const MIN_RUN_PX: f64 = 2.0;
/// The second apex edge is looked for over at least this many detection pixels from
/// a candidate apex.
const MIN_END_FACE_PX: f64 = 3.0;
/// The most edges that vote: the two apex edges and the one farthest from the apex.
const VOTING_EDGES: usize = 3;
/// An edge gives the scale when it lies at least this far from the apex, reference
/// pixels.
const MIN_SCALE_OFFSET_PX: f64 = 2.0;
/// A placement's apex edges count this many votes per detection pixel supporting them
/// from its apex, as a line's smoothed votes count about two per pixel.
const VOTES_PER_PIXEL: f32 = 2.0;

/// A placement and its votes.
#[derive(Debug, Clone, Copy)]
struct Scored {
    pose: Pose,
    votes: f32,
    /// Where the search made it (rotation bin, line, apex): placements of equal
    /// votes rank in this order.
    order: u32,
}

/// Apexes a search makes on one line of the first apex edge: its run's end, one
/// inside its runs, and one where each line of the other apex edge crosses it.
const APEXES_PER_LINE: usize = 2 + LINES_PER_BIN;

/// The accumulators of the search, reused from frame to frame.
#[derive(Debug, Default)]
pub struct Search {
    n_psi: usize,
    n_rho: usize,
    psi_min: f64,
    rho_min: f64,
    centre: [f64; 2],
    /// Per voting edge, cos and sin of its normal turned by each rotation bin.
    trig: Vec<(f32, f32)>,
    acc: Vec<f32>,
    smooth: Vec<f32>,
    scored: Vec<Scored>,
    /// The last search's placements with the apex inside a run of the first apex
    /// edge ([`Search::placements_within_runs`]).
    within: Vec<Scored>,
    /// Whether `within` holds the last search's scores (they do not depend on the
    /// bodies ruled out, so a frame searched again with more of them reuses them).
    within_scored: bool,
    /// Per voting edge, its gradient's direction in the reference (image angle).
    directions: [f64; VOTING_EDGES],
    /// Gradient magnitude a pixel needs to vote or support.
    threshold: f32,
}

impl Search {
    /// The best placements of `template` in the detection image `pyr`, best first,
    /// into `out` (frame pixels); none with its apex on an `excluded` body.
    pub fn placements(
        &mut self,
        pyr: &Pyramid,
        template: &RigidTemplate,
        bounds: &Bounds,
        excluded: &[Option<Claim>],
        out: &mut Vec<Pose>,
    ) {
        let window_rad = bounds.window_rad;
        out.clear();
        let (all_voting, edges) = voting_edges(template);
        let voting = &all_voting[..edges];
        let (w, h) = (pyr.width, pyr.height);
        let half_window = window_rad + SPREAD_BINS as f64 * PSI_STEP;
        self.n_psi = (2.0 * half_window / PSI_STEP).ceil() as usize + 1;
        self.psi_min = -half_window;
        self.centre = [0.5 * w as f64, 0.5 * h as f64];
        let reach = (self.centre[0].hypot(self.centre[1])).ceil() + 2.0;
        self.rho_min = -reach;
        self.n_rho = (2.0 * reach) as usize + 1;
        let cells = edges * self.n_psi * self.n_rho;
        self.acc.clear();
        self.acc.resize(cells, 0.0);
        self.trig.clear();
        for &e in voting {
            let n = template.edges[e].normal;
            let alpha = n[1].atan2(n[0]);
            for i in 0..self.n_psi {
                let (s, c) = (alpha + self.psi_min + i as f64 * PSI_STEP).sin_cos();
                self.trig.push((c as f32, s as f32));
            }
        }
        let gradient_directions = all_voting.map(|e| {
            let edge = &template.edges[e];
            let alpha = edge.normal[1].atan2(edge.normal[0]);
            if edge.polarity > 0.0 {
                alpha
            } else {
                alpha + std::f64::consts::PI
            }
        });
        let threshold = VOTE_NOISE * pyr.gradient_noise();
        self.threshold = threshold;
        self.directions = gradient_directions;
        let (n_psi, n_rho) = (self.n_psi, self.n_rho);
        let (cx, cy) = (self.centre[0] as f32, self.centre[1] as f32);
        let rho_min = self.rho_min as f32;
        // In f32 with truncations of non-negative values: this loop runs over every
        // strong gradient of the frame, where a libm atan2 in f64 and `round` calls
        // took a sixth of the tracking time (perf).
        let directions32 = gradient_directions.map(|d| d as f32);
        let (psi_min, reach) = (self.psi_min as f32, (window_rad + 0.5 * PSI_STEP) as f32);
        let step = PSI_STEP as f32;
        for y in 2..h.saturating_sub(2) {
            for x in 2..w.saturating_sub(2) {
                let i = y * w + x;
                if pyr.mag[i] < threshold {
                    continue;
                }
                let theta = pyr.gy[i].atan2(pyr.gx[i]);
                let (dx, dy) = (x as f32 - cx, y as f32 - cy);
                for (k, beta) in directions32[..edges].iter().enumerate() {
                    let psi = wrap_pi_f32(theta - beta);
                    if psi.abs() > reach {
                        continue;
                    }
                    // Within the window the bin and its neighbours lie in the
                    // accumulator; the clamp keeps rounding at its ends from stepping out.
                    let bin = truncate_index((psi - psi_min) / step + 0.5)
                        .clamp(SPREAD_BINS, n_psi - 1 - SPREAD_BINS);
                    for row in bin - SPREAD_BINS..=bin + SPREAD_BINS {
                        let (c, s) = self.trig[k * n_psi + row];
                        let r = c * dx + s * dy - rho_min + 0.5;
                        if r >= 0.0 {
                            let r = truncate_index(r);
                            if r < n_rho {
                                self.acc[(k * n_psi + row) * n_rho + r] += 1.0;
                            }
                        }
                    }
                }
            }
        }
        self.smooth.clear();
        self.smooth.resize(cells, 0.0);
        for row in 0..edges * n_psi {
            let a = &self.acc[row * n_rho..(row + 1) * n_rho];
            let s = &mut self.smooth[row * n_rho..(row + 1) * n_rho];
            for r in 1..n_rho - 1 {
                s[r] = a[r - 1] + 2.0 * a[r] + a[r + 1];
            }
        }
        self.score(pyr, template, voting, bounds.scales, Apexes::RunEnds);
        self.within_scored = false;
        self.select(pyr, excluded, out);
    }

    /// The best placements of the last search (on `pyr`) with apexes inside the first
    /// apex edge's runs competing too, where the other apex edge shows best among the
    /// pixels supporting the line, into `out`, best first, but for those `tried`; none
    /// with its apex on an `excluded` body. For a frame none of whose placements
    /// verified: a flank running on past the tip along a line of the background (a
    /// band, another body's outline of its direction) ends its run beyond the end
    /// face, and neither the run's end nor a line of the end face, too short to be
    /// voted for, places the apex at the tip. They are scored once per search: a frame
    /// searched again with more bodies ruled out reuses the scores.
    pub fn placements_within_runs(
        &mut self,
        pyr: &Pyramid,
        template: &RigidTemplate,
        bounds: &Bounds,
        excluded: &[Option<Claim>],
        tried: &[Pose],
        out: &mut Vec<Pose>,
    ) {
        if !self.within_scored {
            let (all_voting, edges) = voting_edges(template);
            self.score(
                pyr,
                template,
                &all_voting[..edges],
                bounds.scales,
                Apexes::WithinRunsToo,
            );
            self.within_scored = true;
        }
        select_from(&self.within, pyr, excluded, out);
        out.retain(|p| !tried.contains(p));
    }

    /// The best placements of the last search (on `pyr`), best first, into `out`; none
    /// with its apex on an `excluded` body. Searching again with more bodies ruled out
    /// needs no new votes.
    pub fn select(&self, pyr: &Pyramid, excluded: &[Option<Claim>], out: &mut Vec<Pose>) {
        select_from(&self.scored, pyr, excluded, out);
    }

    /// Scores every pairing of the apex edges' lines per rotation bin, the scale edge
    /// looked for at the distances `scales` allow, with the apexes `apexes` names.
    fn score(
        &mut self,
        pyr: &Pyramid,
        template: &RigidTemplate,
        voting: &[usize],
        scales: ScaleRange,
        apexes_made: Apexes,
    ) {
        // Out of `self` while it fills, so that the first round's list can be read
        // beside the second's; moved back (with its buffer) when sorted.
        let mut scored = std::mem::take(self.list(apexes_made));
        scored.clear();
        let (n_psi, n_rho) = (self.n_psi, self.n_rho);
        let row = |k: usize, i: usize| (k * n_psi + i) * n_rho;
        let factor = f64::from(pyr.factor);
        for i in 0..n_psi {
            let psi = self.psi_min + i as f64 * PSI_STEP;
            let a = peaks(&self.smooth[row(0, i)..row(0, i) + n_rho]);
            let b = peaks(&self.smooth[row(1, i)..row(1, i) + n_rho])
                .map(|p| p.filter(|&(_, v)| v >= MIN_VOTES));
            let line = |k: usize, r: usize| {
                let (c, s) = self.trig[k * n_psi + i];
                let normal = [f64::from(c), f64::from(s)];
                Line {
                    normal,
                    rho: r as f64 + self.rho_min,
                }
            };
            let first = &template.edges[voting[0]];
            let toward = if first.extent[1].abs() <= first.extent[0].abs() {
                1.0
            } else {
                -1.0
            };
            let [first_face, end_face] = [0, 1].map(|k| {
                ApexEdge::of(
                    &template.edges[voting[k]],
                    psi,
                    scales.lo / factor,
                    Support::new(
                        self.directions[k] + psi,
                        self.threshold,
                        if k == 0 {
                            flank_half_width(pyr.factor)
                        } else {
                            RUN_HALF_WIDTH
                        },
                    ),
                )
            });
            let lines = a
                .iter()
                .enumerate()
                .filter_map(|(k, p)| p.map(|(r, _)| (k, r)));
            for (k, ra) in lines {
                let (flank, supports) = (line(0, ra), &first_face.supports);
                // The apex where the first apex edge's support ends, and where each of
                // the second's lines crosses it; or, with apexes inside runs too, only
                // the one inside a run (the others are the last search's, added below).
                let mut apexes = [None; APEXES_PER_LINE];
                match apexes_made {
                    Apexes::RunEnds => {
                        apexes[0] = run_end(pyr, &flank, self.centre, supports, toward, &end_face);
                        for (slot, p) in apexes[2..].iter_mut().zip(&b) {
                            *slot = p.and_then(|(rb, _)| flank.intersect(&line(1, rb)));
                        }
                    }
                    Apexes::WithinRunsToo => {
                        apexes[1] = within_runs(pyr, &flank, self.centre, supports, &end_face);
                    }
                }
                let made = apexes.iter().enumerate();
                for (slot, apex) in made.filter_map(|(slot, p)| p.map(|p| (slot, p))) {
                    let order = ((i * LINES_PER_BIN + k) * APEXES_PER_LINE + slot) as u32;
                    let apex_det = [apex[0] + self.centre[0], apex[1] + self.centre[1]];
                    if !(apex_det[0] >= 0.0
                        && apex_det[1] >= 0.0
                        && apex_det[0] <= (pyr.width - 1) as f64
                        && apex_det[1] <= (pyr.height - 1) as f64)
                    {
                        continue;
                    }
                    // The apex edges by their support from this apex, not their lines'
                    // votes: a longer line at this rotation (another probe's beam, a
                    // line of the ground) crossed by any line of the second edge's
                    // direction would outvote the tool, and its crossings far from
                    // either edge's pixels fill the placements.
                    let [va, vb] = [&first_face, &end_face]
                        .map(|edge| VOTES_PER_PIXEL * edge.support(pyr, apex_det) as f32);
                    let (scale, vc) = match voting.get(2) {
                        Some(&e) => {
                            let offset = template.edges[e].offset / factor;
                            let (c, s) = self.trig[2 * n_psi + i];
                            let at_apex =
                                f64::from(c) * apex[0] + f64::from(s) * apex[1] - self.rho_min;
                            let r0 = at_apex + scales.lo * offset;
                            let r1 = at_apex + scales.hi * offset;
                            let (lo, hi) =
                                (r0.min(r1).max(0.0), r0.max(r1).min((n_rho - 1) as f64));
                            let cells = &self.smooth[row(2, i)..row(2, i) + n_rho];
                            let mut best = (f64::NAN, 0.0f32);
                            let mut r = lo.ceil() as usize;
                            while (r as f64) <= hi {
                                if cells[r] > best.1 {
                                    best = ((r as f64 - at_apex) / offset, cells[r]);
                                }
                                r += 1;
                            }
                            if best.1 < MIN_VOTES {
                                continue;
                            }
                            best
                        }
                        None => (1.0, 0.0),
                    };
                    scored.push(Scored {
                        pose: Pose {
                            psi,
                            scale,
                            apex: pyr.to_frame(apex_det),
                        },
                        votes: va + vb + vc,
                        order,
                    });
                }
            }
        }
        if apexes_made == Apexes::WithinRunsToo {
            scored.extend_from_slice(&self.scored);
        }
        scored.sort_by(|x, y| y.votes.total_cmp(&x.votes).then(x.order.cmp(&y.order)));
        *self.list(apexes_made) = scored;
    }

    /// The list of scored placements a round with `apexes_made` fills.
    fn list(&mut self, apexes_made: Apexes) -> &mut Vec<Scored> {
        match apexes_made {
            Apexes::RunEnds => &mut self.scored,
            Apexes::WithinRunsToo => &mut self.within,
        }
    }
}

/// Where a search places the apex on the first apex edge's lines.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Apexes {
    /// At a run's end (`run_end`) and where the other apex edge's lines cross it.
    RunEnds,
    /// There, and inside a run where the other apex edge shows best (`within_runs`).
    WithinRunsToo,
}

/// The best of `scored`, best first, into `out`: at most [`MAX_PLACEMENTS`], one of
/// each rotation and apex, none with its apex on an `excluded` body.
fn select_from(scored: &[Scored], pyr: &Pyramid, excluded: &[Option<Claim>], out: &mut Vec<Pose>) {
    out.clear();
    for s in scored {
        if out.len() == MAX_PLACEMENTS {
            break;
        }
        let same = |p: &Pose| {
            (p.psi - s.pose.psi).abs() <= SAME_PSI_BINS * PSI_STEP
                && (p.apex[0] - s.pose.apex[0]).hypot(p.apex[1] - s.pose.apex[1])
                    <= SAME_APEX_PX * f64::from(pyr.factor)
        };
        if !out.iter().any(same) && !claimed(excluded, s.pose.apex) {
            out.push(s.pose);
        }
    }
}

/// Where the apex lies along `line` (detection pixels from `centre`), the first apex
/// edge's line, whose pixels `supports` tells: at an end of a run of pixels
/// supporting it, the end `toward` points to along it (+1: along `along(normal)`).
/// Of the runs' ends, the one where `end_face` (the second apex edge) shows best, if
/// it shows along at least half its length there and better than at the longest
/// run's end; else the longest run's. A faint flank over a textured background is
/// broken into runs, and its longest may end at a band of the background rather than
/// at the tip.
fn run_end(
    pyr: &Pyramid,
    line: &Line,
    centre: [f64; 2],
    supports: &Support,
    toward: f64,
    end_face: &ApexEdge,
) -> Option<[f64; 2]> {
    let n = line.normal;
    let (point, [u0, u1]) = walk(pyr, line, centre)?;
    let supported = |u: f64| supports.near(pyr, point(u), n);
    // The longest run (length, from, to); the best run end by the end face's support
    // (support, position), and the end face's support at the longest run's end.
    let mut longest = (0.0, 0.0, 0.0);
    let mut best_end: Option<(usize, f64)> = None;
    let mut longest_support = 0;
    // Closes the run from `from` to `to`, the longest so far if `is_longest`.
    let mut close = |from: f64, to: f64, is_longest: bool| {
        if to - from < MIN_RUN_PX {
            return;
        }
        let end = if toward > 0.0 { to } else { from };
        let support = end_face.support(pyr, point(end));
        if is_longest {
            longest_support = support;
        }
        if best_end.is_none_or(|(s, _)| support > s) {
            best_end = Some((support, end));
        }
    };
    let (mut start, mut last, mut gap) = (None, 0.0, 0);
    let mut u = u0.ceil();
    while u <= u1 {
        if supported(u) {
            let from = *start.get_or_insert(u);
            gap = 0;
            last = u;
            if u - from > longest.0 {
                longest = (u - from, from, u);
            }
        } else if let Some(from) = start {
            gap += 1;
            if gap > RUN_GAP {
                close(from, last, longest.1 == from);
                start = None;
            }
        }
        u += 1.0;
    }
    if let Some(from) = start {
        close(from, last, longest.1 == from);
    }
    if longest.0 <= 0.0 {
        return None;
    }
    let longest_end = if toward > 0.0 { longest.2 } else { longest.1 };
    let end = match best_end {
        Some((support, end)) if support > longest_support && 2 * support >= end_face.pixels() => {
            end
        }
        _ => longest_end,
    };
    Some(sub(point(end), centre))
}

/// A walk along `line` (detection pixels from `centre`): the detection pixel `u`
/// along the line's direction from its foot, and the range of `u` that stays 2 px
/// inside the detection image; none when the line misses it.
fn walk(
    pyr: &Pyramid,
    line: &Line,
    centre: [f64; 2],
) -> Option<(impl Fn(f64) -> [f64; 2], [f64; 2])> {
    let n = line.normal;
    let t = [n[1], -n[0]];
    let foot = [n[0] * line.rho + centre[0], n[1] * line.rho + centre[1]];
    let (w, h) = (pyr.width as f64, pyr.height as f64);
    let (u0, u1) = clip_to_rect(foot, t, [2.0, 2.0], [w - 3.0, h - 3.0])?;
    Some((move |u: f64| add(foot, scale(t, u)), [u0, u1]))
}

/// Where along `line` (detection pixels from `centre`), the first apex edge's line
/// whose pixels `supports` tells, the other apex edge `end_face` shows best from a
/// pixel supporting the line, if it shows along at least half its length there. Only
/// the pixels from which the end face shows two pixels on are scored: no other is the
/// tip, and each score reads the end face's whole length.
fn within_runs(
    pyr: &Pyramid,
    line: &Line,
    centre: [f64; 2],
    supports: &Support,
    end_face: &ApexEdge,
) -> Option<[f64; 2]> {
    let n = line.normal;
    let (point, [u0, u1]) = walk(pyr, line, centre)?;
    let across = [-end_face.from_apex[1], end_face.from_apex[0]];
    let mut best: Option<(usize, f64)> = None;
    let mut u = u0.ceil();
    while u <= u1 {
        let p = point(u);
        if supports.near(pyr, p, n)
            && end_face
                .supports
                .near(pyr, add(p, scale(end_face.from_apex, 2.0)), across)
        {
            let support = end_face.support(pyr, p);
            if best.is_none_or(|(b, _)| support > b) {
                best = Some((support, u));
            }
        }
        u += 1.0;
    }
    let (support, u) = best?;
    (2 * support >= end_face.pixels()).then(|| sub(point(u), centre))
}

/// A detection pixel supports an edge when its gradient is strong and within
/// [`RUN_ANGLE_RAD`] of the edge's; a line, when it does within `half_width` of it.
struct Support {
    cos: f32,
    sin: f32,
    threshold: f32,
    min_dot: f32,
    half_width: i32,
}

impl Support {
    fn new(direction: f64, threshold: f32, half_width: i32) -> Support {
        Support {
            cos: direction.cos() as f32,
            sin: direction.sin() as f32,
            threshold,
            min_dot: RUN_ANGLE_RAD.cos() as f32 * threshold,
            half_width,
        }
    }

    /// Whether the detection pixel nearest `p` supports the edge (false outside).
    fn at(&self, pyr: &Pyramid, p: [f64; 2]) -> bool {
        let Some(i) = nearest_pixel(p, pyr.width, pyr.height) else {
            return false;
        };
        pyr.mag[i] >= self.threshold
            && pyr.gx[i] * self.cos + pyr.gy[i] * self.sin
                >= self.min_dot * pyr.mag[i] / self.threshold
    }

    /// Whether a detection pixel within `half_width` of `p` along the unit vector
    /// `across` supports the edge.
    fn near(&self, pyr: &Pyramid, p: [f64; 2], across: [f64; 2]) -> bool {
        (-self.half_width..=self.half_width)
            .any(|j| self.at(pyr, add(p, scale(across, f64::from(j)))))
    }
}

/// [`FLANK_HALF_WIDTH_PX`] in detection pixels binned by `factor`.
fn flank_half_width(factor: u32) -> i32 {
    ((FLANK_HALF_WIDTH_PX / f64::from(factor)).round() as i32).max(RUN_HALF_WIDTH)
}

/// An apex edge as a candidate apex would have it: its unit direction from the apex,
/// its length at the smallest scale searched (detection pixels) and the pixels that
/// support it.
struct ApexEdge {
    from_apex: [f64; 2],
    length: f64,
    supports: Support,
}

impl ApexEdge {
    /// Apex edge `edge` turned by `psi`, at `scale` detection pixels per reference
    /// pixel, supported as `supports` says.
    fn of(edge: &RigidEdge, psi: f64, scale: f64, supports: Support) -> ApexEdge {
        let far = if edge.extent[1].abs() >= edge.extent[0].abs() {
            edge.extent[1]
        } else {
            edge.extent[0]
        };
        let to_far = edge.point(far);
        let length = to_far[0].hypot(to_far[1]);
        ApexEdge {
            from_apex: rotate([to_far[0] / length, to_far[1] / length], psi),
            length: (length * scale).max(MIN_END_FACE_PX),
            supports,
        }
    }

    /// Pixels of its length the edge is looked for over, one per detection pixel.
    fn pixels(&self) -> usize {
        self.length as usize
    }

    /// Pixels along the edge from `apex` (detection pixels), one per pixel of its
    /// length, with a pixel within one across it supporting it.
    fn support(&self, pyr: &Pyramid, apex: [f64; 2]) -> usize {
        let across = [-self.from_apex[1], self.from_apex[0]];
        (1..=self.pixels())
            .filter(|&k| {
                let on = add(apex, scale(self.from_apex, k as f64));
                self.supports.near(pyr, on, across)
            })
            .count()
    }
}

/// Wraps an angle difference (within two turns) to (-pi, pi].
fn wrap_pi_f32(a: f32) -> f32 {
    use std::f32::consts::{PI, TAU};
    let mut a = a;
    while a > PI {
        a -= TAU;
    }
    while a <= -PI {
        a += TAU;
    }
    a
}

/// The edges that vote, and how many do: the two apex edges, the longer first (where
/// its support ends places the apex when the other is faint, and a short edge's run
/// says little), then the one farthest from the apex (its distance gives the scale),
/// if any is.
fn voting_edges(template: &RigidTemplate) -> ([usize; VOTING_EDGES], usize) {
    let [a, b] = template.apex_edges;
    let [a, b] = if template.edges[b].length() > template.edges[a].length() {
        [b, a]
    } else {
        [a, b]
    };
    let far = (0..template.edges.len())
        .filter(|e| !template.apex_edges.contains(e))
        .max_by(|&a, &b| {
            template.edges[a]
                .offset
                .abs()
                .total_cmp(&template.edges[b].offset.abs())
        });
    match far.filter(|&e| template.edges[e].offset.abs() >= MIN_SCALE_OFFSET_PX) {
        Some(e) => ([a, b, e], VOTING_EDGES),
        None => ([a, b, a], 2),
    }
}

/// The best local maxima of a row, (rho bin, votes), at least [`MIN_PEAK_VOTES`].
fn peaks(row: &[f32]) -> [Option<(usize, f32)>; LINES_PER_BIN] {
    let mut best = [None; LINES_PER_BIN];
    for r in 1..row.len().saturating_sub(1) {
        let v = row[r];
        if v < MIN_PEAK_VOTES || v < row[r - 1] || v <= row[r + 1] {
            continue;
        }
        let slot = best
            .iter()
            .position(|b: &Option<(usize, f32)>| b.is_none_or(|(_, bv)| v > bv));
        if let Some(k) = slot {
            best[k..].rotate_right(1);
            best[k] = Some((r, v));
        }
    }
    best
}

#[cfg(test)]
mod tests {
    use super::*;
    use image::GrayImage;

    /// A blunt needle's template, its apex edges named end face first.
    fn end_face_first() -> RigidTemplate {
        let mut t = crate::vision::rigid::needle_template();
        t.edges.swap(0, 1);
        t
    }

    /// The detection image (unbinned) of a bright body (200 on 50) below y = 50 from
    /// x = 20 to its end face at x = 150, with the pixels `band` accepts at the body's
    /// level too; the flank's line y = 50 from the centre (100, 50), the body below it
    /// (its normal and gradient point down, +y, and along it +x runs toward the end
    /// face); and the end face, 20 px down from the apex.
    fn body_and_band(band: impl Fn(u32, u32) -> bool) -> (Pyramid, Line, ApexEdge) {
        let frame = GrayImage::from_fn(200, 100, |x, y| {
            let body = (20..150).contains(&x) && y >= 50;
            image::Luma([if body || band(x, y) { 200 } else { 50 }])
        });
        let mut pyr = Pyramid::default();
        pyr.build_binned(&frame, 1);
        let flank = Line {
            normal: [0.0, 1.0],
            rho: 0.0,
        };
        let end_face = ApexEdge {
            from_apex: [0.0, 1.0],
            length: 20.0,
            supports: Support::new(std::f64::consts::PI, 10.0, RUN_HALF_WIDTH),
        };
        (pyr, flank, end_face)
    }

    const CENTRE: [f64; 2] = [100.0, 50.0];

    /// The flank's supporting pixels: gradients pointing down (+y), within the band of
    /// a flank searched unbinned.
    fn flank_supports() -> Support {
        Support::new(std::f64::consts::FRAC_PI_2, 10.0, flank_half_width(1))
    }

    /// Whether `apex` (detection pixels from [`CENTRE`]) lies at the body's tip.
    fn at_tip(apex: [f64; 2]) -> bool {
        (apex[0] + CENTRE[0] - 149.0).abs() <= 1.5 && (apex[1] + CENTRE[1] - 50.0).abs() < 1.0
    }

    /// `end_face` looked for up from the apex, where the body shows nothing.
    fn looking_up(end_face: ApexEdge) -> ApexEdge {
        ApexEdge {
            from_apex: [0.0, -1.0],
            ..end_face
        }
    }

    /// The body with its upper flank hidden over x = 100-110 by a band of the body's
    /// level above it: the flank's support breaks into a long run (to x = 99) and a
    /// short one (to the end, x = 150). The apex is where the end face shows, at the
    /// short run's end, not at the long run's.
    #[test]
    fn the_apex_is_the_run_end_where_the_end_face_shows() {
        let (pyr, flank, end_face) =
            body_and_band(|x, y| (100..=110).contains(&x) && (30..50).contains(&y));
        let apex = run_end(&pyr, &flank, CENTRE, &flank_supports(), 1.0, &end_face).unwrap();
        assert!(at_tip(apex), "{apex:?}");
        // Without the end face there, the longest run's end.
        let elsewhere = looking_up(end_face);
        let apex = run_end(&pyr, &flank, CENTRE, &flank_supports(), 1.0, &elsewhere).unwrap();
        assert!((apex[0] + CENTRE[0] - 99.0).abs() <= 1.5, "{apex:?}");
    }

    /// The body with a band of its level two pixels thick along its upper flank's line
    /// on to x = 190 (a line of the background in line with the flank): the flank's
    /// support runs on to the band's end, where nothing shows the end face. Inside the
    /// run the end face shows at the tip.
    #[test]
    fn the_apex_within_a_run_is_where_the_end_face_shows() {
        let (pyr, flank, end_face) =
            body_and_band(|x, y| (150..190).contains(&x) && (50..52).contains(&y));
        let run = run_end(&pyr, &flank, CENTRE, &flank_supports(), 1.0, &end_face).unwrap();
        assert!((run[0] + CENTRE[0] - 189.0).abs() <= 1.5, "{run:?}");
        let within = within_runs(&pyr, &flank, CENTRE, &flank_supports(), &end_face).unwrap();
        assert!(at_tip(within), "{within:?}");
        // Where the end face shows nowhere along the run, no apex within it.
        let elsewhere = looking_up(end_face);
        assert!(within_runs(&pyr, &flank, CENTRE, &flank_supports(), &elsewhere).is_none());
    }

    /// The body's flank read along a line turned from it by 1.9 deg, which lies 3 px
    /// inside the body at the tip (unbinned; the 5-tap gradient spreads the step over
    /// two pixels either side): the flank's support runs on to where the line leaves
    /// the band of 2 px, 2 px from the tip, not to 14 px short of it as in a band of
    /// one pixel.
    #[test]
    fn a_line_drifting_from_a_long_flank_ends_its_run_at_the_tip() {
        let (pyr, _, end_face) = body_and_band(|_, _| false);
        let turn = (3.0f64 / 90.0).asin();
        let drifting = Line {
            normal: [-turn.sin(), turn.cos()],
            rho: 40.0 * turn.sin(),
        };
        let apex = run_end(&pyr, &drifting, CENTRE, &flank_supports(), 1.0, &end_face).unwrap();
        assert!((apex[0] + CENTRE[0] - 149.0).abs() <= 2.5, "{apex:?}");
        assert_eq!([1, 2, 4].map(flank_half_width), [2, 1, 1]);
    }

    /// A needle's template (12 px thick, end face 12 px) searched on two bright
    /// needles, one whose upper flank runs on along a band past its end face, beside
    /// particles and scratches: the second round adds the apexes inside runs to the
    /// first round's placements, which keep their votes and their order (equal votes,
    /// as at a needle's tip where its run ends and the end face crosses, in the order
    /// they were made), and searching again with a body ruled out reuses the scores.
    #[test]
    fn the_second_round_keeps_the_first_rounds_placements_in_their_order() {
        let frame = GrayImage::from_fn(240, 160, |x, y| {
            let needle = (20..150).contains(&x) && (40..52).contains(&y)
                || (20..110).contains(&x) && (100..112).contains(&y);
            let band = (150..200).contains(&x) && (40..42).contains(&y);
            let particle = (x as i32 - 60).pow(2) + (y as i32 - 140).pow(2) < 64
                || (x as i32 - 190).pow(2) + (y as i32 - 110).pow(2) < 36;
            let scratch = (x + y) % 37 == 0 && y > 130;
            let level = if needle || band || particle || scratch {
                200
            } else {
                50
            };
            image::Luma([level])
        });
        let mut pyr = Pyramid::default();
        pyr.build_binned(&frame, 1);
        let template = crate::vision::rigid::needle_template();
        let bounds = Bounds {
            window_rad: 20f64.to_radians(),
            scales: ScaleRange { lo: 0.8, hi: 1.25 },
        };
        let none = [None; 3];
        let (mut search, mut out) = (Search::default(), Vec::new());
        search.placements(&pyr, &template, &bounds, &none, &mut out);
        let first: Vec<(Pose, f32)> = search.scored.iter().map(|s| (s.pose, s.votes)).collect();
        assert!(first.len() > MAX_PLACEMENTS, "{}", first.len());
        search.placements_within_runs(&pyr, &template, &bounds, &none, &[], &mut out);
        let within_run = |s: &&Scored| s.order as usize % APEXES_PER_LINE == 1;
        let kept: Vec<(Pose, f32)> = (search.within.iter())
            .filter(|s| !within_run(s))
            .map(|s| (s.pose, s.votes))
            .collect();
        assert_eq!(kept, first);
        assert!(search.within.iter().any(|s| within_run(&s)));
        // Best first; of equal votes, the first made first, as one whole scoring
        // of both rounds would rank them.
        let ranked = |w: &[Scored]| {
            w[0].votes > w[1].votes || (w[0].votes == w[1].votes && w[0].order < w[1].order)
        };
        assert!(search.within.windows(2).all(ranked));
        let ties = search.within.windows(2);
        assert!(ties.filter(|w| w[0].votes == w[1].votes).count() > 0);
        // Ruling out the best placement's apex chooses from the same scores.
        let scores: Vec<(Pose, f32)> = search.within.iter().map(|s| (s.pose, s.votes)).collect();
        let best = crate::vision::Estimate {
            detected: true,
            apex_px: Some(out[0].apex),
            ..crate::vision::Estimate::missed(crate::vision::Miss::NoCandidates, 0.0)
        };
        let ruled_out = [Claim::of(&best), None, None];
        let mut again = Vec::new();
        search.placements_within_runs(&pyr, &template, &bounds, &ruled_out, &[], &mut again);
        let rescored: Vec<(Pose, f32)> = search.within.iter().map(|s| (s.pose, s.votes)).collect();
        assert_eq!(rescored, scores);
        assert!(!again.is_empty() && !again.contains(&out[0]));
        assert!(again.iter().all(|p| !claimed(&ruled_out, p.apex)));
    }

    /// Where the first apex edge's support ends places the apex: the long flank's,
    /// not the short end face's, whichever the configuration names first.
    #[test]
    fn the_longer_apex_edge_votes_first() {
        let t = end_face_first();
        assert_eq!(voting_edges(&t), ([1, 0, 2], 3));
        let mut flank_first = t.clone();
        flank_first.apex_edges = [1, 0];
        assert_eq!(voting_edges(&flank_first), ([1, 0, 2], 3));
    }
}
