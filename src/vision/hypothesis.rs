//! The rigid-tip search: which combination of line candidates is the tip?
//!
//! The tip is rigid, so all its edges turn by one angle psi, and three lines of fixed
//! directions form a triangle similar to the reference one: the lines' offsets fix the
//! scale and the apex. Every pair or triple of candidates from different edges whose
//! rotations agree is a hypothesis; it is placed (psi, scale, apex) and scored by how
//! well the edge pixels cover the segments the template predicts, minus the uncovered
//! part and minus any edge continuing past a corner (a clutter line runs on through the
//! apex; the probe's edges stop there). A clutter line can win an edge's Hough peak,
//! but not a hypothesis: it would have to agree with the other edges in angle, in
//! position and in extent. Pairs leave the scale free; it is scanned, and the edge left
//! out is checked where the template puts it, directly on the edge map.

use super::candidates::{Candidate, Candidates};
use super::edges::EdgeMap;
use super::geometry::{add, along, clip_to_rect, dot, norm, rotate, scale, sub, wrap_pi};
use super::pyramid::Pyramid;
use super::template::{PerEdge, Pose, Template, EDGES, RED};

/// Scale range searched, detection pixels per reference pixel (before binning).
const SCALE_MIN: f64 = 0.05;
const SCALE_MAX: f64 = 12.0;
/// Log step of the scale scan for pairs, and the most steps from SCALE_MIN to SCALE_MAX.
const SCALE_STEP: f64 = 1.03;
const SCALE_STEPS_MAX: usize = 192;
/// Smallest tip (apex to red line), detection pixels.
const MIN_HEIGHT_PX: f64 = 10.0;
/// Hypotheses kept for the full (walking) evaluation.
const SHORTLIST: usize = 10;
/// A line of a hypothesis must cover at least this much of its predicted segment.
const MIN_MEMBER_PX: f64 = 3.0;
const MIN_MEMBER_FRACTION: f64 = 0.4;
/// Red is scored only this many tip heights beyond the start of the beam's bend: further
/// back the beam may curve away from the tip's tangent.
const RED_SCORE_HEIGHTS: f64 = 1.5;
/// Weight of the beam edge's coverage in a hypothesis' score (see [`edge_score`]).
const RED_WEIGHT: f64 = 0.5;
/// Gradient tolerance when walking a predicted edge, radians.
const WALK_ANGLE_RAD: f64 = 0.25;

/// Coverage of one edge's predicted segment.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Coverage {
    /// Supported and visible length of the predicted segment, detection pixels.
    pub supported: f64,
    pub visible: f64,
    /// Supported length just past the corner end (should be none).
    pub overshoot: f64,
}

impl Coverage {
    pub fn fraction(&self) -> f64 {
        if self.visible > 0.0 {
            self.supported / self.visible
        } else {
            0.0
        }
    }

    /// Supported minus unsupported length, minus twice any overshoot: the log-likelihood
    /// ratio of "tip edge" against "background" for equally reliable edge pixels.
    fn score(&self) -> f64 {
        2.0 * self.supported - self.visible - 2.0 * self.overshoot
    }
}

/// An edge's share of a hypothesis' score. The beam edge counts half: it is a long line
/// whatever the hypothesis, so its length says little about where the tip is.
fn edge_score(e: usize, c: &Coverage) -> f64 {
    if e == RED {
        RED_WEIGHT * c.score()
    } else {
        c.score()
    }
}

fn total_score(cov: &PerEdge<Coverage>) -> f64 {
    (0..EDGES).map(|e| edge_score(e, &cov[e])).sum()
}

/// A placed tip and its evidence.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Hypothesis {
    /// Pose in detection-image coordinates.
    pub pose: Pose,
    /// Candidate index per edge (into `Candidates::list`), if the edge was one.
    pub members: PerEdge<Option<usize>>,
    pub coverage: PerEdge<Coverage>,
    pub score: f64,
    /// For a pair: the scales that explain the pair equally well (the apex moves along
    /// `apex0 + scale * apex1`); the edge left out decides among them.
    pub plateau: Option<Plateau>,
}

/// Scales over which a pair hypothesis scores the same.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Plateau {
    pub apex0: [f64; 2],
    pub apex1: [f64; 2],
    pub scale_lo: f64,
    pub scale_hi: f64,
}

/// Scales tried along a plateau when placing the edge a pair leaves out.
const PLATEAU_STEPS: usize = 10;
/// Scores within this of the best belong to its plateau.
const PLATEAU_TOL: f64 = 1.0;

/// Reusable state of the search.
#[derive(Debug, Default)]
pub struct Search {
    shortlist: Vec<Hypothesis>,
}

/// Restricts the search (coherence): only rotations within `psi_tol` of `psi`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Prior {
    pub psi: f64,
    pub psi_tol: f64,
}

impl Search {
    /// The best-scoring hypothesis, if any pair of candidates is compatible; a
    /// placement whose apex (detection pixels) is `ruled_out` is never shortlisted
    /// (another probe's tip, when several are in view).
    pub fn run(
        &mut self,
        template: &Template,
        cands: &Candidates,
        edges: &EdgeMap,
        prior: Option<Prior>,
        ruled_out: &dyn Fn([f64; 2]) -> bool,
    ) -> Option<Hypothesis> {
        self.shortlist.clear();
        self.shortlist.reserve(SHORTLIST);
        let list = &cands.list;
        let n = list.len();
        let size = [edges.width as f64, edges.height as f64];
        for i in 0..n {
            for j in i + 1..n {
                if list[i].edge == list[j].edge {
                    continue;
                }
                self.consider(template, cands, &[i, j], size, prior, ruled_out);
                for k in j + 1..n {
                    let e = [list[i].edge, list[j].edge, list[k].edge];
                    if e[2] != e[0] && e[2] != e[1] {
                        self.consider(template, cands, &[i, j, k], size, prior, ruled_out);
                    }
                }
            }
        }
        for h in &mut self.shortlist {
            place_missing(template, h, edges);
        }
        // Best first. Each hypothesis is one combination of candidates, so the members
        // break ties and the order is total; sorting in place does not allocate.
        self.shortlist.sort_unstable_by(|a, b| {
            b.score
                .total_cmp(&a.score)
                .then_with(|| a.members.cmp(&b.members))
        });
        self.shortlist.first().copied()
    }

    /// The shortlist of the last [`Search::run`], best first (the tracker's runners-up,
    /// when the best one is not convincing).
    pub fn ranked(&self) -> &[Hypothesis] {
        &self.shortlist
    }

    /// Places and scores the hypothesis made of candidates `idx`; shortlists it.
    fn consider(
        &mut self,
        t: &Template,
        cands: &Candidates,
        idx: &[usize],
        size: [f64; 2],
        prior: Option<Prior>,
        ruled_out: &dyn Fn([f64; 2]) -> bool,
    ) {
        let list = &cands.list;
        let Some(psi) = common_psi(idx.iter().map(|&i| &list[i])) else {
            return;
        };
        if let Some(p) = prior {
            if wrap_pi(psi - p.psi).abs() > p.psi_tol {
                return;
            }
        }
        let mut members = [None; EDGES];
        let mut turned = [([0.0; 2], [0.0; 2]); EDGES];
        let mut reach = [None; EDGES];
        for &i in idx {
            let e = list[i].edge;
            members[e] = Some(i);
            turned[e] = turned_segment(t, psi, e);
            reach[e] = Reach::new(cands, &list[i], turned[e]);
            if reach[e].is_none() {
                // No supported bin: member_cover never accepts it.
                return;
            }
        }
        let partial = |pose: &Pose| -> Option<(PerEdge<Coverage>, f64)> {
            if !plausible(t, pose, size) || reach.iter().flatten().any(|r| !r.may_cover(pose)) {
                return None;
            }
            let mut cov = [Coverage::default(); EDGES];
            for (e, m) in members.iter().enumerate() {
                if let Some(i) = m {
                    cov[e] = member_cover(pose, turned[e], cands, &list[*i])?;
                }
            }
            Some((cov, total_score(&cov)))
        };
        let mut rows = [LineRow::default(); EDGES];
        for (r, &i) in rows.iter_mut().zip(idx) {
            *r = LineRow::new(t, &list[i], psi);
        }
        let best = if idx.len() == EDGES {
            solve3(&rows).and_then(|(apex, scale)| {
                let pose = Pose { psi, scale, apex };
                partial(&pose).map(|(cov, s)| (pose, cov, s, None))
            })
        } else {
            // Only the plausible scales at which both members can find support.
            let within = |a0, a1| {
                let range = plausible_scales(t, size, a0, a1);
                reach.iter().flatten().fold(range, |[lo, hi], r| {
                    let [l, h] = r.scales(a0, a1);
                    [lo.max(l), hi.min(h)]
                })
            };
            scan_scale(&rows[..2], psi, within, partial)
        };
        if let Some((pose, coverage, score, plateau)) = best {
            if ruled_out(pose.apex) {
                return;
            }
            self.shortlist_insert(Hypothesis {
                pose,
                members,
                coverage,
                score,
                plateau,
            });
        }
    }

    fn shortlist_insert(&mut self, h: Hypothesis) {
        if self.shortlist.len() == SHORTLIST {
            let (worst, w) = self
                .shortlist
                .iter()
                .enumerate()
                .min_by(|a, b| a.1.score.total_cmp(&b.1.score))
                .map(|(i, h)| (i, h.score))
                .unwrap_or((0, f64::INFINITY));
            if h.score <= w {
                return;
            }
            self.shortlist.swap_remove(worst);
        }
        self.shortlist.push(h);
    }
}

/// One line of a hypothesis as an equation in the unknown apex and scale:
/// `normal . apex + scale * offset = rho`.
#[derive(Debug, Clone, Copy, Default)]
struct LineRow {
    normal: [f64; 2],
    offset: f64,
    rho: f64,
}

impl LineRow {
    /// Candidate `c` turned to the common rotation `psi` about its centroid.
    fn new(t: &Template, c: &Candidate, psi: f64) -> LineRow {
        let normal = rotate(t.edges[c.edge].normal, psi);
        LineRow {
            normal,
            offset: t.edges[c.edge].offset,
            rho: dot(normal, c.centroid),
        }
    }
}

/// Inverse-variance mean of the candidates' rotations, if they agree.
fn common_psi<'a>(cands: impl Iterator<Item = &'a Candidate> + Clone) -> Option<f64> {
    let (mut sw, mut swp) = (0.0, 0.0);
    let reference = cands.clone().next()?.psi;
    for c in cands.clone() {
        let w = 1.0 / (c.psi_sigma * c.psi_sigma + 1e-6);
        sw += w;
        swp += w * wrap_pi(c.psi - reference);
    }
    let psi = reference + swp / sw;
    for c in cands {
        let tol = 3.0 * c.psi_sigma + 1.5f64.to_radians();
        if wrap_pi(c.psi - psi).abs() > tol {
            return None;
        }
    }
    Some(psi)
}

/// Apex and scale from three lines (Cramer's rule), if well conditioned.
fn solve3(r: &[LineRow; 3]) -> Option<([f64; 2], f64)> {
    let m = r.map(|r| [r.normal[0], r.normal[1], r.offset]);
    let b = r.map(|r| r.rho);
    let det3 = |m: &[[f64; 3]; 3]| {
        m[0][0] * (m[1][1] * m[2][2] - m[1][2] * m[2][1])
            - m[0][1] * (m[1][0] * m[2][2] - m[1][2] * m[2][0])
            + m[0][2] * (m[1][0] * m[2][1] - m[1][1] * m[2][0])
    };
    let d = det3(&m);
    if d.abs() < 1e-6 * r.iter().map(|r| r.offset.abs()).fold(1.0, f64::max) {
        return None;
    }
    let mut x = [0.0; 3];
    for (k, xk) in x.iter_mut().enumerate() {
        let mut mk = m;
        for i in 0..3 {
            mk[i][k] = b[i];
        }
        *xk = det3(&mk) / d;
    }
    Some(([x[0], x[1]], x[2]))
}

/// The scales of the scan, `SCALE_MIN * SCALE_STEP^k` (tabulated: `powi` per step was
/// a few percent of a cluttered frame).
fn scale_grid() -> &'static [f64; SCALE_STEPS_MAX] {
    static GRID: std::sync::OnceLock<[f64; SCALE_STEPS_MAX]> = std::sync::OnceLock::new();
    GRID.get_or_init(|| std::array::from_fn(|k| SCALE_MIN * SCALE_STEP.powi(k as i32)))
}

/// Two lines leave the scale free: the apex moves along `a0 + scale * a1`. Scans the
/// scale on a log grid, over the range `within(a0, a1)` outside which `score` fails,
/// and keeps the best-scoring placement.
fn scan_scale(
    r: &[LineRow],
    psi: f64,
    within: impl Fn([f64; 2], [f64; 2]) -> [f64; 2],
    score: impl Fn(&Pose) -> Option<(PerEdge<Coverage>, f64)>,
) -> Option<(Pose, PerEdge<Coverage>, f64, Option<Plateau>)> {
    let det = r[0].normal[0] * r[1].normal[1] - r[0].normal[1] * r[1].normal[0];
    if det.abs() < 0.05 {
        return None;
    }
    let solve = |b0: f64, b1: f64| {
        [
            (b0 * r[1].normal[1] - r[0].normal[1] * b1) / det,
            (r[0].normal[0] * b1 - b0 * r[1].normal[0]) / det,
        ]
    };
    let a0 = solve(r[0].rho, r[1].rho);
    let a1 = solve(-r[0].offset, -r[1].offset);
    let [lo, hi] = within(a0, a1);
    // Widened by a rounding's worth (the grid's steps are 3 %).
    let (lo, hi) = (lo * (1.0 - 1e-9), hi * (1.0 + 1e-9));
    let grid = scale_grid();
    let (first, last) = (
        grid.partition_point(|&s| s < lo),
        grid.partition_point(|&s| s <= hi.min(SCALE_MAX)),
    );
    let mut best: Option<(Pose, PerEdge<Coverage>, f64)> = None;
    let mut scores = [f64::NEG_INFINITY; SCALE_STEPS_MAX];
    let mut best_k = 0;
    for k in first..last {
        let (slot, scale) = (&mut scores[k], grid[k]);
        let apex = [a0[0] + scale * a1[0], a0[1] + scale * a1[1]];
        let pose = Pose { psi, scale, apex };
        if let Some((cov, s)) = score(&pose) {
            *slot = s;
            if best.as_ref().is_none_or(|b| s > b.2 + 1e-9) {
                best = Some((pose, cov, s));
                best_k = k;
            }
        }
    }
    let (pose, cov, s) = best?;
    let (mut lo, mut hi) = (best_k, best_k);
    while lo > 0 && scores[lo - 1] >= s - PLATEAU_TOL {
        lo -= 1;
    }
    while hi + 1 < SCALE_STEPS_MAX && scores[hi + 1] >= s - PLATEAU_TOL {
        hi += 1;
    }
    let plateau = Plateau {
        apex0: a0,
        apex1: a1,
        scale_lo: SCALE_MIN * SCALE_STEP.powi(lo as i32),
        scale_hi: SCALE_MIN * SCALE_STEP.powi(hi as i32),
    };
    Some((pose, cov, s, Some(plateau)))
}

/// A tip placed at `pose` (frame pixels) on detection image `pyr` with edge map
/// `edges` rather than found: no edge is a candidate line, and each is scored where
/// the pose puts it, directly on the edge map, as a pair's left-out edge is.
pub fn at_pose(t: &Template, pyr: &Pyramid, edges: &EdgeMap, pose: Pose) -> Hypothesis {
    let k = f64::from(pyr.factor);
    let pose = Pose {
        psi: pose.psi,
        scale: pose.scale / k,
        apex: pyr.frame_to_detection(pose.apex),
    };
    let coverage = std::array::from_fn(|e| walk(t, &pose, e, edges));
    Hypothesis {
        pose,
        members: [None; EDGES],
        coverage,
        score: total_score(&coverage),
        plateau: None,
    }
}

/// Scores the edges a hypothesis left out where it puts them (directly on the edge
/// map), choosing for a pair the scale along its plateau that explains them best.
fn place_missing(t: &Template, h: &mut Hypothesis, edges: &EdgeMap) {
    let missing = |h: &Hypothesis, pose: &Pose| -> PerEdge<Option<Coverage>> {
        std::array::from_fn(|e| h.members[e].is_none().then(|| walk(t, pose, e, edges)))
    };
    let total = |h: &Hypothesis, cov: &PerEdge<Option<Coverage>>| -> f64 {
        (0..EDGES)
            .map(|e| edge_score(e, &cov[e].unwrap_or(h.coverage[e])))
            .sum()
    };
    let mut best_pose = h.pose;
    let mut best_cov = missing(h, &h.pose);
    let mut best = total(h, &best_cov);
    if let Some(p) = h.plateau.filter(|p| p.scale_hi > p.scale_lo * SCALE_STEP) {
        let ratio = p.scale_hi / p.scale_lo;
        for k in 0..=PLATEAU_STEPS {
            let scale = p.scale_lo * ratio.powf(k as f64 / PLATEAU_STEPS as f64);
            let apex = [
                p.apex0[0] + scale * p.apex1[0],
                p.apex0[1] + scale * p.apex1[1],
            ];
            let pose = Pose {
                scale,
                apex,
                ..h.pose
            };
            let cov = missing(h, &pose);
            let s = total(h, &cov);
            if s > best + 1e-9 {
                (best, best_pose, best_cov) = (s, pose, cov);
            }
        }
    }
    h.pose = best_pose;
    for (cov, found) in h.coverage.iter_mut().zip(best_cov) {
        if let Some(c) = found {
            *cov = c;
        }
    }
    h.score = best;
}

/// Hypothesis `h` placed at another `scale` (detection pixels per reference pixel),
/// along its plateau for a pair. The edges it left out are given no coverage: they
/// were found on the frame, where the edge map did not show them.
pub fn rescaled(h: &Hypothesis, scale: f64) -> Hypothesis {
    let mut out = *h;
    out.pose.scale = scale;
    if let Some(p) = h.plateau {
        out.pose.apex = [
            p.apex0[0] + scale * p.apex1[0],
            p.apex0[1] + scale * p.apex1[1],
        ];
    }
    for (cov, member) in out.coverage.iter_mut().zip(h.members) {
        if member.is_none() {
            *cov = Coverage::default();
        }
    }
    out
}

/// Whether a pose could be a tip in this image: big enough to see, and with its apex
/// no further outside the image than the image is large.
fn plausible(t: &Template, pose: &Pose, size: [f64; 2]) -> bool {
    if !(SCALE_MIN..=SCALE_MAX).contains(&pose.scale) || t.height * pose.scale < MIN_HEIGHT_PX {
        return false;
    }
    apex_bounds(size)
        .iter()
        .zip(pose.apex)
        .all(|(&[lo, hi], x)| x > lo && x < hi)
}

/// The open bounds of a [`plausible`] apex, per coordinate: no further outside the
/// image than the image is large.
fn apex_bounds(size: [f64; 2]) -> [[f64; 2]; 2] {
    size.map(|s| [-s, 2.0 * s])
}

/// The scales at which a pose whose apex is `a0 + scale * a1` can be [`plausible`] (a
/// superset: the apex's bounds are open there).
fn plausible_scales(t: &Template, size: [f64; 2], a0: [f64; 2], a1: [f64; 2]) -> [f64; 2] {
    let mut range = [SCALE_MIN.max(MIN_HEIGHT_PX / t.height), SCALE_MAX];
    for (i, [lo, hi]) in apex_bounds(size).into_iter().enumerate() {
        // lo < a0 + scale * a1 < hi
        at_most(&mut range, a1[i], hi - a0[i]);
        at_most(&mut range, -a1[i], a0[i] - lo);
    }
    range
}

/// Margin trimmed off each end of a predicted segment (corners are rounded by blur).
fn end_margin(length: f64) -> f64 {
    1.5 + 0.05 * length
}

/// The stretch of edge `e` a hypothesis is scored on (red: only near the tip).
fn segment(t: &Template, pose: &Pose, e: usize) -> ([f64; 2], [f64; 2]) {
    placed(pose, turned_segment(t, pose.psi, e))
}

/// [`segment`] in the reference turned by `psi`, before scaling and moving it to an
/// apex: the search tries many scales at one rotation, and recomputing the rotation's
/// sine and cosine for each was a good part of its cost.
fn turned_segment(t: &Template, psi: f64, e: usize) -> ([f64; 2], [f64; 2]) {
    let edge = &t.edges[e];
    let (a, b) = if e == RED {
        t.red_near_tip(RED_SCORE_HEIGHTS)
    } else {
        (edge.tip_tau, edge.far_tau)
    };
    (rotate(edge.point(a), psi), rotate(edge.point(b), psi))
}

/// A [`turned_segment`] scaled and moved to the pose's apex (what `Template::place`
/// computes, in the same order, so the result is the same to the bit).
fn placed(pose: &Pose, turned: ([f64; 2], [f64; 2])) -> ([f64; 2], [f64; 2]) {
    let place = |q| add(pose.apex, scale(q, pose.scale));
    (place(turned.0), place(turned.1))
}

/// A quick necessary test for [`member_cover`]: bounds of the coverage it would find,
/// from where the candidate's profile and its supported bins lie along its line. The
/// scale scan tries ~190 placements per pair and most fail here, for a few
/// multiply-adds instead of a square root, two divisions and the profile look-ups.
#[derive(Debug, Clone, Copy)]
struct Reach {
    /// `t` along the candidate's line is `dot(dir, p) + base`.
    dir: [f64; 2],
    base: f64,
    /// `t` of the turned segment's ends per unit scale, and its length per unit scale.
    t_tip: f64,
    t_far: f64,
    length: f64,
    bin: f64,
    /// The profile's extent in `t`, and its supported bins' (half a bin later: see
    /// [`Reach::may_cover`]).
    profile: [f64; 2],
    supported: [f64; 2],
}

impl Reach {
    fn new(cands: &Candidates, c: &Candidate, turned: ([f64; 2], [f64; 2])) -> Option<Self> {
        let dir = along(c.normal);
        let (bin, profile, supported) = cands.reach(c);
        let [first, last] = supported?;
        Some(Reach {
            dir,
            base: -dot(dir, c.centroid),
            t_tip: dot(dir, turned.0),
            t_far: dot(dir, turned.1),
            length: norm(sub(turned.1, turned.0)),
            bin,
            profile,
            supported: [first + 0.5 * bin, last + 0.5 * bin],
        })
    }

    /// The scales at which a pose whose apex is `a0 + scale * a1` can give this
    /// member support in [`member_cover`] (a superset: the untrimmed segment within
    /// [`REACH_SLACK_BINS`] bins of the supported bins). Both ends of the segment move
    /// linearly with the scale, so the range is an interval.
    fn scales(&self, a0: [f64; 2], a1: [f64; 2]) -> [f64; 2] {
        let at0 = dot(self.dir, a0) + self.base;
        let rate = dot(self.dir, a1);
        let (u, v) = (rate + self.t_tip, rate + self.t_far);
        let slack = REACH_SLACK_BINS * self.bin;
        let mut range = [0.0, f64::INFINITY];
        // The near end at or before the last supported bin...
        at_most(&mut range, u.min(v), self.supported[1] + slack - at0);
        // ...and the far end at or past the first.
        at_most(&mut range, -u.max(v), at0 - (self.supported[0] - slack));
        range
    }

    /// False only if [`member_cover`] would find too little. `support` sums the bins
    /// `a..b` nearest the trimmed segment's ends: with `o(R)` the overlap of the
    /// segment with range R, its visible length is at least `o(profile) - bin` and at
    /// most `o(profile) + bin`, and its supported length at most `o(supported) + bin`.
    fn may_cover(&self, pose: &Pose) -> bool {
        let at = dot(self.dir, pose.apex) + self.base;
        let (tip, far) = (at + pose.scale * self.t_tip, at + pose.scale * self.t_far);
        let m = end_margin(pose.scale * self.length);
        let dir = (far - tip).signum();
        let (a, b) = (tip + dir * m, far - dir * m);
        let (lo, hi) = (a.min(b), a.max(b));
        let overlap = |r: [f64; 2]| hi.min(r[1]) - lo.max(r[0]);
        let visible = overlap(self.profile);
        let supported = (overlap(self.supported) + self.bin).max(0.0);
        // The slack absorbs rounding between these sums and member_cover's.
        const SLACK: f64 = 1e-6;
        visible + self.bin + SLACK >= MIN_MEMBER_PX
            && supported + SLACK >= MIN_MEMBER_FRACTION * (visible - self.bin)
    }
}

/// Slack of [`Reach::scales`] around the supported bins, in bins (their rounding in
/// [`Candidates::support`] is half a bin).
const REACH_SLACK_BINS: f64 = 3.0;

/// Narrows `range` (of scales s >= 0) to where `s * rate <= rhs`.
fn at_most(range: &mut [f64; 2], rate: f64, rhs: f64) {
    if rate > 0.0 {
        range[1] = range[1].min(rhs / rate);
    } else if rate < 0.0 {
        range[0] = range[0].max(rhs / rate);
    } else if rhs < 0.0 {
        *range = [f64::INFINITY, 0.0];
    }
}

/// Coverage of an edge's predicted segment (`turned` by the pose's rotation, see
/// [`turned_segment`]) by candidate `c`'s profile, if it is enough for `c` to be part
/// of the tip (every line of a hypothesis must be). The overshoot past the corner is
/// looked up only then: most placements the scale scan tries fail before.
fn member_cover(
    pose: &Pose,
    turned: ([f64; 2], [f64; 2]),
    cands: &Candidates,
    c: &Candidate,
) -> Option<Coverage> {
    let (tip, far) = placed(pose, turned);
    let length = norm(sub(far, tip));
    let t_tip = Candidates::t_of(c, tip);
    let t_far = Candidates::t_of(c, far);
    let dir = (t_far - t_tip).signum();
    let m = end_margin(length);
    let (supported, visible) = cands.support(c, t_tip + dir * m, t_far - dir * m);
    let mut cov = Coverage {
        supported,
        visible,
        overshoot: 0.0,
    };
    if cov.visible < MIN_MEMBER_PX || cov.fraction() < MIN_MEMBER_FRACTION {
        return None;
    }
    let zone = 0.3 * length + 2.0;
    (cov.overshoot, _) = cands.support(c, t_tip - dir * (m + zone), t_tip - dir * m);
    Some(cov)
}

/// Coverage of edge `e`'s predicted segment measured directly on the edge map: used for
/// the edge a pair hypothesis leaves out.
fn walk(t: &Template, pose: &Pose, e: usize, edges: &EdgeMap) -> Coverage {
    let line = t.line(pose, e);
    // The gradient points to the brighter side: into the probe or out of it.
    let polarity = t.edges[e].polarity;
    let normal_angle = (polarity * line.normal[1]).atan2(polarity * line.normal[0]);
    let (tip, far) = segment(t, pose, e);
    let length = norm(sub(far, tip));
    if length < 1.0 {
        return Coverage::default();
    }
    let dir = [(far[0] - tip[0]) / length, (far[1] - tip[1]) / length];
    let hi = [edges.width as f64 - 1.0, edges.height as f64 - 1.0];
    let Some((a, b)) = clip_to_rect(tip, dir, [0.0, 0.0], hi) else {
        return Coverage::default();
    };
    let m = end_margin(length);
    let (a, b) = (a.max(m), b.min(length - m));
    let mut cov = Coverage::default();
    let mut s = a;
    while s < b {
        let p = [tip[0] + s * dir[0], tip[1] + s * dir[1]];
        cov.visible += 1.0;
        if edges.supports(p, line.normal, normal_angle, WALK_ANGLE_RAD) {
            cov.supported += 1.0;
        }
        s += 1.0;
    }
    cov
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::vision::candidates::line_candidates;
    use crate::vision::hough::Peak;

    /// A candidate on a 3-deg line with support on two pieces (t 0-25 and 45-70 px).
    fn gapped_candidate() -> Candidates {
        let a = 3f64.to_radians();
        let peak = Peak {
            edge: 0,
            psi: a,
            rho: 80.0 * a.cos() - 120.0 * a.sin(),
            votes: 50,
        };
        line_candidates(
            [120.0, 80.0],
            a,
            (0..70).filter(|i| !(25..45).contains(i)),
            peak,
        )
    }

    /// Uniform draws in `[lo, hi)` from a linear congruential sequence.
    fn uniform_from(mut state: u64) -> impl FnMut(f64, f64) -> f64 {
        move |lo, hi| {
            state = state
                .wrapping_mul(6_364_136_223_846_793_005)
                .wrapping_add(1_442_695_040_888_963_407);
            lo + (hi - lo) * ((state >> 11) as f64 / (1u64 << 53) as f64)
        }
    }

    /// A segment near [`gapped_candidate`]'s line, of any length and direction along it.
    fn segment_near_line(uniform: &mut impl FnMut(f64, f64) -> f64) -> ([f64; 2], [f64; 2]) {
        let tip = [uniform(-30.0, 30.0), uniform(-2.0, 2.0)];
        let far = [tip[0] + uniform(-60.0, 60.0), tip[1] + uniform(-4.0, 4.0)];
        (tip, far)
    }

    #[test]
    fn reach_rejects_only_placements_member_cover_rejects() {
        let cands = gapped_candidate();
        let c = cands.list[0];
        let mut uniform = uniform_from(0x2545_f491_4f6c_dd1d);
        let (mut rejected, mut accepted) = (0, 0);
        for _ in 0..20_000 {
            let (tip, far) = segment_near_line(&mut uniform);
            let pose = Pose {
                psi: 0.0,
                scale: uniform(0.1, 3.0),
                apex: [uniform(80.0, 220.0), uniform(70.0, 95.0)],
            };
            let reach = Reach::new(&cands, &c, (tip, far)).unwrap();
            let cover = member_cover(&pose, (tip, far), &cands, &c);
            if reach.may_cover(&pose) {
                accepted += cover.is_some() as usize;
            } else {
                assert!(cover.is_none(), "{pose:?} {tip:?} {far:?} {cover:?}");
                rejected += 1;
            }
        }
        // Both outcomes occur, so the test says something.
        assert!(
            rejected > 2_000 && accepted > 2_000,
            "{rejected} {accepted}"
        );
    }

    #[test]
    fn scale_range_holds_every_scale_member_cover_accepts() {
        let cands = gapped_candidate();
        let c = cands.list[0];
        let mut uniform = uniform_from(0x9e37_79b9_7f4a_7c15);
        let (mut outside, mut accepted) = (0, 0);
        for _ in 0..2_000 {
            let (tip, far) = segment_near_line(&mut uniform);
            // A pair's line of apexes `a0 + scale * a1`.
            let a0 = [uniform(0.0, 300.0), uniform(70.0, 95.0)];
            let a1 = [uniform(-80.0, 80.0), uniform(-5.0, 5.0)];
            let reach = Reach::new(&cands, &c, (tip, far)).unwrap();
            let [lo, hi] = reach.scales(a0, a1);
            for &scale in scale_grid() {
                let apex = [a0[0] + scale * a1[0], a0[1] + scale * a1[1]];
                let pose = Pose {
                    psi: 0.0,
                    scale,
                    apex,
                };
                let inside = (lo..=hi).contains(&scale);
                let cover = member_cover(&pose, (tip, far), &cands, &c);
                assert!(inside || cover.is_none(), "{scale} {lo} {hi} {cover:?}");
                outside += !inside as usize;
                accepted += cover.is_some() as usize;
            }
        }
        // Both the range's inside and outside occur, and placements are accepted.
        assert!(
            outside > 100_000 && accepted > 1_000,
            "{outside} {accepted}"
        );
    }
}
