//! The verification of a fit: what the last pass's stations must show for the frame
//! to show this probe. Every edge in view holds its calibrated step at
//! [`HELD_SHARE`] of its stations (all but one of three) and at the apex, its median
//! station holds it, the probe's sides of the edges are one body
//! ([`ONE_BODY_SHARE`]), no edge runs on past an end where the reference shows it
//! ending, the body is neither hollow nor a rim around a line of the background, and
//! the apex, rotation and scale lie in range.

use image::GrayImage;

use super::{
    Fit, Fitter, Point, Seen, BEYOND_PX, HELD_SHARE, IN_VIEW_SHARE, MAX_EDGES, MAX_STATIONS,
    MIN_IN_VIEW, REACHES, STEP_SHARE,
};
use crate::vision::geometry::{add, along, bilinear, dot, rotate, scale, strip_mean};
use crate::vision::rigid::{Pose, RigidEdge, RigidTemplate};
use crate::vision::stations::{COVERED_APEX_SHARE, PAST_APEX_HALF_PX};
use crate::vision::Miss;

/// A station holds the edge when it steps by this share of the calibrated step within
/// [`HELD_PX`] of the fitted line, as an AFM pyramid's station shows its edge: a
/// hidden or absent edge steps by nothing, and an end face over a band of a real
/// background nearly as bright as the probe by 0.15-0.25.
pub(super) const HOLD_SHARE: f64 = 0.1;

const HELD_PX: f64 = 1.5;

/// A station stepping by less than this share of the calibrated step, off its line at
/// the apex's corner, is read again centred on the line ([`Fitter::shown_off`]). A
/// stronger step lies where the frame puts it: a gripper jaw's end laid along a
/// needle's steps by 0.9-1.2 of it 1.5-1.9 px off, and centred on the line (whose
/// window then holds the step at its border) it read 1.0-1.1 px off (tool seed 7).
const WEAK_STEP_SHARE: f64 = 0.5;
/// The levels on the probe's side of its edges in view lie within this share of the
/// smallest calibrated step: one body.
const ONE_BODY_SHARE: f64 = 0.5;
/// A station past a closed end shows the edge running on when it steps by this share
/// of the calibrated step within [`HELD_PX`] of the line.
const RUN_ON_SHARE: f64 = 0.7;
/// At the apex, the other apex edge closes the body when its median step is at least
/// this share of the edge's own next to the apex ([`Fitter::run_on_share`]).
const CLOSING_SHARE: f64 = 0.5;
/// The least yardstick (share of the calibrated step) of [`RUN_ON_SHARE`] at an apex
/// the other apex edge does not close: an edge stepping by less next to the apex is
/// held by noise-sized steps, which the stations past it would match by chance.
const MIN_RUN_ON_YARDSTICK: f64 = 0.5;

/// An edge whose located steps run along this many frame pixels or more ...
const MIN_TURN_SPAN_PX: f64 = 100.0;
/// ... and lie on a line turned from the fitted edge by more than this, degrees, bounds
/// a body of another shape (`wrong-appearance-<name>`): over the seven tool-suite
/// seeds' verified fits (13,720 such edges) none turns by more than 0.51 deg; a
/// needle whose flanks stand 2.5 deg wider apart than a jaw's, taken for that jaw at
/// 0.74 of its scale, turns them by -1.56 and +0.88 deg (tool seed 10).
const MAX_TURN_DEG: f64 = 1.0;

/// A fit whose rotation's standard error exceeds this, degrees, is refused
/// (`low-confidence`): its edges do not agree on the rotation to the accuracy
/// detections are held to (docs/tracker.md, "Accuracy": at most 0.3 deg off).
pub(super) const MAX_SIGMA_DEG: f64 = 0.3;

/// Apex stations: of the stations nearest the apex on each apex edge, all but one must
/// show it (a tip hidden under a particle at the probe's level shows none; noise can
/// drop one; a tip touching a brighter particle shows its outline stepping the other
/// way), and the nearest must show it within [`NEAREST_PX`] of it: its run reaches
/// into the corner's blur, which moves the located step by up to 2 px on a faint
/// edge, while a body that only looks like the probe (a dark segment of a rail for a
/// dark lever's end) shows no step there.
const APEX_STATIONS: usize = 3;
const NEAREST_PX: f64 = 3.0;
/// A corner station's inside within this share of the calibrated step of the probe's
/// level carries the probe on; a level beyond it by more is no background
/// ([`Fitter::covered`]).
const COVERED_LEVEL: f64 = 0.25;
/// Where the levels inside a corner and past the apex are read from, pixels: clear of
/// the blur.
const LEVEL_NEAR: f64 = 2.5;
/// A body at least this wide between two facing edges (frame pixels) has its middle
/// read ([`Fitter::hollow`]): twice the depth the stations read each edge's levels to
/// (4.5 px), and the blur's margin.
const MIDDLE_MIN_WIDTH_PX: f64 = 16.0;
/// Half the side of the square whose mean is a middle's or a rim's level, pixels.
const MIDDLE_HALF_PX: i32 = 2;
/// An edge's outside is read again this far out from its located steps, pixels
/// (past the 4.5 px the stations read), at its holding stations ([`Fitter::rim`]).
const RIM_PX: f64 = 8.0;
/// An edge with at least this many holding stations is a rim when more than half of
/// them have the outside read [`RIM_PX`] out back more than halfway to the probe's
/// level: a line of the background (a scratch three pixels wide) steps as the probe's
/// edge does, and a body beside it is no probe. A blunt end's few stations read what
/// lies beyond a short face: the needle's own surroundings, a particle.
const MIN_RIM_STATIONS: usize = 6;
/// Facing edges: their inward normals at least this far from parallel (cosine).
const FACING_COS: f64 = -0.5;
/// A body is hollow when more than this share of its middles lie past the
/// surroundings' level ([`Fitter::hollow`]): a dark lever's template along a rail
/// whose dark gap it takes for its end holds half its middles in the gap (tool seed
/// 7), and the probe's body holds them all.
const HOLLOW_SHARE: f64 = 1.0 / 3.0;

/// The mean levels on the probe's side of its holding stations and outside them.
#[derive(Debug, Clone, Copy)]
struct Levels {
    probe: f64,
    around: f64,
}

impl Levels {
    /// Level `v` as a share of the way from the surroundings' level to the probe's.
    fn share(&self, v: f64) -> f64 {
        (v - self.around) / (self.probe - self.around)
    }
}

/// The mean level of `frame` over the square of side `2 MIDDLE_HALF_PX + 1` pixels
/// centred on `centre`, its rows along the unit vector `dir`; `None` outside.
fn square_mean(frame: &GrayImage, centre: [f64; 2], dir: [f64; 2]) -> Option<f64> {
    let start = add(centre, scale(dir, -f64::from(MIDDLE_HALF_PX)));
    let rows = 2 * MIDDLE_HALF_PX as usize + 1;
    strip_mean(start, dir, rows, MIDDLE_HALF_PX, |q| bilinear(frame, q))
}

/// The distance (reference pixels) from `from`, on edge `e`, along its inward normal
/// to the nearest other edge facing it whose segment (or its open continuation) the
/// normal crosses; `None` when none does.
fn facing_width(t: &RigidTemplate, e: usize, from: [f64; 2]) -> Option<f64> {
    let normal = t.edges[e].normal;
    let mut nearest: Option<f64> = None;
    for (f, other) in t.edges.iter().enumerate() {
        let cos = dot(other.normal, normal);
        if f == e || cos > FACING_COS {
            continue;
        }
        let width = (other.offset - dot(other.normal, from)) / cos;
        let tau = dot(along(other.normal), add(from, scale(normal, width)));
        let within =
            (other.open[0] || tau >= other.extent[0]) && (other.open[1] || tau <= other.extent[1]);
        if width > 0.0 && within && nearest.is_none_or(|d| width < d) {
            nearest = Some(width);
        }
    }
    nearest
}

/// The edge whose probe side is not the body the others' are, if one is: the levels
/// on the probe's side of the edges in view (`inside`, NaN for an edge not in view)
/// spread by more than [`ONE_BODY_SHARE`] of the smallest calibrated step. Named: the
/// edge farthest from their median.
fn not_one_body(t: &RigidTemplate, inside: &[f64; MAX_EDGES]) -> Option<usize> {
    let mut seen = [0.0; MAX_EDGES];
    let mut n = 0;
    let mut yardstick = f64::INFINITY;
    for (e, &level) in inside.iter().enumerate().take(t.edges.len()) {
        if level.is_finite() {
            seen[n] = level;
            n += 1;
            yardstick = yardstick.min(t.edges[e].step);
        }
    }
    if n < 2 {
        return None;
    }
    let seen = &mut seen[..n];
    seen.sort_by(f64::total_cmp);
    if seen[n - 1] - seen[0] <= ONE_BODY_SHARE * yardstick {
        return None;
    }
    let median = seen[n / 2];
    (0..t.edges.len())
        .filter(|&e| inside[e].is_finite())
        .max_by(|&a, &b| {
            (inside[a] - median)
                .abs()
                .total_cmp(&(inside[b] - median).abs())
        })
}

/// Which end of an apex edge lies at the apex: the one nearer `tau = 0`.
fn apex_end(edge: &RigidEdge) -> usize {
    usize::from(edge.extent[0].abs() > edge.extent[1].abs())
}

/// The median step (share of the calibrated step) of the stations in view among
/// `points`, at most [`MAX_STATIONS`] of them; 0 when none is.
fn median_step<'a>(points: impl Iterator<Item = &'a Point>) -> f64 {
    let mut steps = [0.0; MAX_STATIONS];
    let mut n = 0;
    for p in points.filter(|p| p.in_view).take(MAX_STATIONS) {
        steps[n] = p.step;
        n += 1;
    }
    if n == 0 {
        return 0.0;
    }
    let steps = &mut steps[..n];
    steps.sort_by(f64::total_cmp);
    steps[n / 2]
}

impl Fitter {
    /// The verdict on the last read's stations at `pose`.
    pub(super) fn verify(
        &mut self,
        frame: &GrayImage,
        t: &RigidTemplate,
        pose: Pose,
        sigma: f64,
        window_rad: f64,
    ) -> Result<Fit, (Miss, f64)> {
        let (w, h) = (f64::from(frame.width()), f64::from(frame.height()));
        let apex_in = pose.apex[0] >= 0.0
            && pose.apex[1] >= 0.0
            && pose.apex[0] <= w - 1.0
            && pose.apex[1] <= h - 1.0;
        let mut edges = [None; MAX_EDGES];
        let mut confidence: f64 = 1.0;
        let mut refusal: Option<Miss> = None;
        let mut levels = [0.0; MAX_STATIONS];
        // Per edge in view, the median level on the probe's side of its holding
        // stations.
        let mut inside = [f64::NAN; MAX_EDGES];
        // The apex edge whose corner does not show, if one does not.
        let mut hidden_corner = None;
        for (e, edge) in t.edges.iter().enumerate() {
            let points = || self.points.iter().filter(move |p| p.edge == e);
            let total = points().count();
            let mut in_view = 0;
            let mut held = 0;
            let mut span = [f64::NAN; 2];
            for p in points().filter(|p| p.in_view) {
                if in_view == 0 {
                    span[0] = p.tau;
                }
                span[1] = p.tau;
                in_view += 1;
                if Self::holds_final(t, &pose, p) {
                    if held < MAX_STATIONS {
                        levels[held] = p.inside;
                    }
                    held += 1;
                }
            }
            let is_apex_edge = t.apex_edges.contains(&e);
            if in_view < MIN_IN_VIEW.min(total) || (in_view as f64) < IN_VIEW_SHARE * total as f64 {
                if is_apex_edge && refusal.is_none() {
                    refusal = Some(Miss::EdgeMissing(edge.name));
                }
                continue;
            }
            let median_ratio = median_step(points());
            let m = held.min(MAX_STATIONS);
            if m > 0 {
                levels[..m].sort_by(f64::total_cmp);
                inside[e] = levels[m / 2];
            }
            // Stations reading a particle across or beside the edge (`covered`)
            // neither hold nor miss it, once the edge shows itself on enough others;
            // the median step still counts them, so an edge more than half covered is
            // refused.
            let covered = if held >= MIN_IN_VIEW {
                points()
                    .filter(|p| {
                        p.in_view
                            && !Self::holds_final(t, &pose, p)
                            && Self::covered(edge, p, inside[e])
                    })
                    .count()
            } else {
                0
            };
            let share = held as f64 / (in_view - covered) as f64;
            confidence = confidence.min(share);
            edges[e] = Some(Seen {
                span,
                held,
                step: median_ratio * edge.step,
            });
            if refusal.is_some() {
                continue;
            }
            if median_ratio < 0.0 {
                refusal = Some(Miss::WrongAppearance(edge.name));
            } else if share < HELD_SHARE && held + 1 < in_view {
                // An edge of three stations in view (a needle's blunt end) holds at
                // two: the share would ask for all three, and one in three is the
                // noise's.
                refusal = Some(Miss::EdgeMissing(edge.name));
            } else if median_ratio < HOLD_SHARE {
                // Its median station steps too little to hold it. The yardstick is the
                // reference's step, and a face against a brighter background than on
                // the reference steps by less; a larger step is no sign of another
                // body either, as the level outside the probe changes as it moves.
                refusal = Some(Miss::WrongAppearance(edge.name));
            } else if is_apex_edge
                && !self.apex_held(frame, t, &pose, e)
                && hidden_corner.replace(e).is_some()
            {
                // Neither apex edge shows the corner: the tip is hidden.
                refusal = Some(Miss::EdgeMissing(edge.name));
            } else if self.runs_on(t, &pose, e, inside[e]) {
                refusal = Some(Miss::ScaleMismatch);
            } else if self.turned(t, &pose, e) {
                refusal = Some(Miss::WrongAppearance(edge.name));
            }
        }
        // An edge away from the apex measures the probe's size; the two apex edges
        // alone are any corner of their angle.
        let away = |e: &usize| !t.apex_edges.contains(e);
        let size_unseen = (0..t.edges.len()).any(|e| away(&e))
            && !(0..t.edges.len()).any(|e| away(&e) && edges[e].is_some());
        let refusal = refusal.or_else(|| {
            // One apex edge may lose its corner to a particle beside the tip, while
            // the other shows it and the apex itself shows the surroundings; a corner
            // lost away from the apex too is a particle over the probe's whole end.
            let hidden = hidden_corner.filter(|&e| {
                self.whole_corner
                    || !self.particle_beside_tip(frame, t, &pose, e)
                    || self.far_corner_hidden(frame, t, &pose)
            });
            if let Some(e) = hidden {
                Some(Miss::EdgeMissing(t.edges[e].name))
            } else if size_unseen {
                Some(Miss::ScaleUnseen)
            } else if let Some(e) = not_one_body(t, &inside) {
                Some(Miss::WrongAppearance(t.edges[e].name))
            } else if let Some(e) = self.hollow(frame, t, &pose) {
                Some(Miss::WrongAppearance(t.edges[e].name))
            } else if let Some(e) = self.rim(frame, t, &pose) {
                Some(Miss::WrongAppearance(t.edges[e].name))
            } else if !apex_in {
                Some(Miss::ApexOutside)
            } else if pose.psi.abs() > window_rad + 2.0 * sigma {
                Some(Miss::RotationOutside)
            } else if sigma > MAX_SIGMA_DEG.to_radians() {
                Some(Miss::LowConfidence)
            } else {
                None
            }
        });
        match refusal {
            Some(miss) => Err((miss, confidence)),
            None => Ok(Fit {
                pose,
                angle_sigma_rad: sigma,
                confidence,
                edges,
            }),
        }
    }

    /// Whether edge `e`'s located steps (its stations in view that step as it does,
    /// held or not) run along at least [`MIN_TURN_SPAN_PX`] and lie on a line turned
    /// from the edge at `pose` by more than [`MAX_TURN_DEG`]: the frame's edge has
    /// another direction than the probe's, which the stations near the fit's pivot
    /// still hold.
    fn turned(&self, t: &RigidTemplate, pose: &Pose, e: usize) -> bool {
        // Residual against distance along the edge, one pass of sums.
        let (mut n, mut lo, mut hi) = (0.0, f64::INFINITY, f64::NEG_INFINITY);
        let (mut sx, mut sy, mut sxx, mut sxy) = (0.0, 0.0, 0.0, 0.0);
        for p in self
            .points
            .iter()
            .filter(|p| p.edge == e && p.in_view && p.step >= STEP_SHARE)
        {
            let (x, y) = (p.tau * pose.scale, Self::residual(t, pose, p));
            (lo, hi) = (lo.min(x), hi.max(x));
            (sx, sy, sxx, sxy) = (sx + x, sy + y, sxx + x * x, sxy + x * y);
            n += 1.0;
        }
        if n < 3.0 || hi - lo < MIN_TURN_SPAN_PX {
            return false;
        }
        let slope = (n * sxy - sx * sy) / (n * sxx - sx * sx);
        slope.atan().abs() > MAX_TURN_DEG.to_radians()
    }

    /// Whether apex edge `hidden`, whose corner does not show, is hidden by a particle
    /// beside the tip rather than missing: the probe's level carries on along the
    /// inside of its corner stations (within [`COVERED_LEVEL`] of the calibrated step
    /// of the level at the apex edges' holding stations), and past the apex, along the
    /// outward bisector of the apex edges (from [`LEVEL_NEAR`] on, five pixels wide
    /// and deep), the frame lies less than [`COVERED_APEX_SHARE`] of the way from the
    /// surroundings' level to the probe's. A patch over the tip leaves the probe's
    /// level past the apex; a body that only looks like the probe has no inside there.
    ///
    /// A particle beyond the probe's level (brighter than a bright probe, darker than
    /// a dark one) touching the tip is the other case: past the apex the frame lies
    /// beyond the probe's level by more than [`COVERED_LEVEL`] of the step, and its
    /// blur reaches into the corner, so there the corner stations' inside may lie at
    /// the probe's level or beyond it. A patch at the probe's level over the tip
    /// still reads as the probe past the apex, and a patch beyond it over the tip
    /// hides both apex edges' corners, which is refused before this is asked.
    pub(super) fn particle_beside_tip(
        &self,
        frame: &GrayImage,
        t: &RigidTemplate,
        pose: &Pose,
        hidden: usize,
    ) -> bool {
        let normal = |e: usize| rotate(t.edges[e].normal, pose.psi);
        let [a, b] = t.apex_edges;
        let inward = add(normal(a), normal(b));
        let len = dot(inward, inward).sqrt();
        if len < 1e-9 {
            return false;
        }
        let out = scale(inward, -1.0 / len);
        let Some(levels) = self.levels(t, pose, |e| e == a || e == b) else {
            return false;
        };
        // The mean level over a square of five pixels a side whose near side's centre
        // lies at `from`, reaching along `dir`.
        let level = |from: [f64; 2], dir: [f64; 2]| {
            strip_mean(from, dir, 5, PAST_APEX_HALF_PX, |q| bilinear(frame, q))
        };
        let edge = &t.edges[hidden];
        let inside = normal(hidden);
        let past = level(add(pose.apex, scale(out, LEVEL_NEAR)), out).map(|v| levels.share(v));
        let beyond = past.is_some_and(|r| r > 1.0 + COVERED_LEVEL);
        let carries_on = self
            .corner_stations(hidden, apex_end(edge))
            .into_iter()
            .flatten()
            .all(|p| {
                let at = add(pose.place(edge, p.tau), scale(inside, LEVEL_NEAR));
                level(at, inside)
                    .map(|v| levels.share(v))
                    .is_some_and(|r| (r - 1.0).abs() <= COVERED_LEVEL || (beyond && r >= 1.0))
            });
        carries_on && past.is_some_and(|r| r < COVERED_APEX_SHARE || beyond)
    }

    /// The stations on the edges (not past their ends) that hold them at `pose`.
    fn holding<'a>(
        &'a self,
        t: &'a RigidTemplate,
        pose: &'a Pose,
    ) -> impl Iterator<Item = &'a Point> + 'a {
        self.points
            .iter()
            .filter(move |p| p.edge < MAX_EDGES && p.in_view && Self::holds_final(t, pose, p))
    }

    /// The mean levels on the probe's side and outside over the holding stations of
    /// the edges `of` accepts; `None` when none holds.
    fn levels(&self, t: &RigidTemplate, pose: &Pose, of: impl Fn(usize) -> bool) -> Option<Levels> {
        let (mut probe, mut around, mut n) = (0.0, 0.0, 0usize);
        for p in self.holding(t, pose).filter(|p| of(p.edge)) {
            let edge = &t.edges[p.edge];
            probe += p.inside;
            around += p.outside(edge);
            n += 1;
        }
        (n > 0).then(|| Levels {
            probe: probe / n as f64,
            around: around / n as f64,
        })
    }

    /// The edge whose outline encloses no body of the probe's, if the fit's edges are
    /// such outlines: beside each holding station, the body's middle between it and
    /// the edge facing it (where they stand [`MIDDLE_MIN_WIDTH_PX`] apart or more) is
    /// read, and more than [`HOLLOW_SHARE`] of the middles lie past the surroundings'
    /// level (darker than the surroundings where the probe is the brighter). The
    /// stations read each edge's levels a few pixels deep only, and two rims of another
    /// body (a rail's dark outlines around its brighter core, for a dark lever's top and
    /// bottom) step as the probe's edges do. Named: the edge of the middle at that
    /// share.
    fn hollow(&self, frame: &GrayImage, t: &RigidTemplate, pose: &Pose) -> Option<usize> {
        let levels = self.levels(t, pose, |_| true)?;
        let mut middles = [(0.0, 0usize); MAX_EDGES * MAX_STATIONS];
        let mut n = 0;
        for p in self.holding(t, pose) {
            let edge = &t.edges[p.edge];
            let from = edge.point(p.tau);
            let Some(width) = facing_width(t, p.edge, from) else {
                continue;
            };
            if width * pose.scale < MIDDLE_MIN_WIDTH_PX || n == middles.len() {
                continue;
            }
            let middle = add(from, scale(edge.normal, 0.5 * width));
            let dir = rotate(edge.normal, pose.psi);
            let centre = add(pose.apex, scale(rotate(middle, pose.psi), pose.scale));
            if let Some(level) = square_mean(frame, centre, dir) {
                middles[n] = (levels.share(level), p.edge);
                n += 1;
            }
        }
        if n == 0 {
            return None;
        }
        let middles = &mut middles[..n];
        middles.sort_by(|a, b| a.0.total_cmp(&b.0));
        let (share, e) = middles[(n as f64 * HOLLOW_SHARE) as usize];
        (share < 0.0).then_some(e)
    }

    /// The edge that is a rim, if one is: of its holding stations (at least
    /// [`MIN_RIM_STATIONS`]), more than half have the outside [`RIM_PX`] out from the
    /// located step back more than halfway from the level outside the step to the
    /// level inside it. A dark needle's template took the dark wedge between a bright
    /// scratch three pixels wide and a sample's bright edge, closed by another probe's
    /// tip, its flanks and blunt end stepping as the needle's do (tool seed 7, frames
    /// without a tool).
    fn rim(&self, frame: &GrayImage, t: &RigidTemplate, pose: &Pose) -> Option<usize> {
        (0..t.edges.len()).find(|&e| {
            let edge = &t.edges[e];
            let normal = rotate(edge.normal, pose.psi);
            let across = along(normal);
            let (mut rims, mut n) = (0, 0);
            for p in self.holding(t, pose).filter(|p| p.edge == e) {
                let centre = add(p.at, scale(normal, -RIM_PX));
                let Some(far) = square_mean(frame, centre, across) else {
                    continue;
                };
                let outside = p.outside(edge);
                n += 1;
                if (far - outside) * edge.polarity > 0.5 * (p.inside - outside) * edge.polarity {
                    rims += 1;
                }
            }
            n >= MIN_RIM_STATIONS && 2 * rims > n
        })
    }

    /// Whether station `p` of `edge` reads a body beyond the probe's level (brighter
    /// than a brighter probe, darker than a darker one): its step the wrong way, the
    /// level on its far side more than [`COVERED_LEVEL`] of the step beyond
    /// `probe_level`, the level of the edge's holding stations. The background lies on
    /// the other side of the probe's level, so such a body is no background: a particle
    /// across the edge or beside it (tool seed 15: one beyond a gripper jaw's end face
    /// turned 4 of its 13 stations).
    fn covered(edge: &RigidEdge, p: &Point, probe_level: f64) -> bool {
        p.step <= -HOLD_SHARE
            && (p.outside(edge) - probe_level) * edge.polarity > COVERED_LEVEL * edge.step
    }

    /// Whether station `p` holds its edge: a step of [`HOLD_SHARE`] of the edge's
    /// within [`HELD_PX`] of it.
    pub(super) fn holds_final(t: &RigidTemplate, pose: &Pose, p: &Point) -> bool {
        Self::off_at(t, pose, p, HOLD_SHARE) <= HELD_PX
    }

    /// How far from the edge station `p` steps by [`STEP_SHARE`] of its edge's step,
    /// pixels (infinity where it does not).
    fn step_off(t: &RigidTemplate, pose: &Pose, p: &Point) -> f64 {
        Self::off_at(t, pose, p, STEP_SHARE)
    }

    /// How far from the edge station `p` steps by `share` of its edge's step, pixels
    /// (infinity where it does not, or is out of view).
    fn off_at(t: &RigidTemplate, pose: &Pose, p: &Point, share: f64) -> f64 {
        if p.in_view && p.step >= share {
            Self::residual(t, pose, p).abs()
        } else {
            f64::INFINITY
        }
    }

    /// The [`APEX_STATIONS`] stations of edge `e` nearest its end `end` (0 or 1, as
    /// its extent), counted from that end (fewer when the edge has fewer).
    fn corner_stations(&self, e: usize, end: usize) -> [Option<Point>; APEX_STATIONS] {
        // Stations run from extent[0] to extent[1].
        let from_low = end == 0;
        let count = self.points.iter().filter(|p| p.edge == e).count();
        let nearest = APEX_STATIONS.min(count);
        let skip = if from_low { 0 } else { count - nearest };
        let mut stations = [None; APEX_STATIONS];
        for (k, p) in self
            .points
            .iter()
            .filter(|p| p.edge == e)
            .skip(skip)
            .take(nearest)
            .enumerate()
        {
            stations[if from_low { k } else { nearest - 1 - k }] = Some(*p);
        }
        stations
    }

    /// Whether apex edge `e` shows the apex ([`Fitter::corner_held`] at its apex end).
    fn apex_held(&mut self, frame: &GrayImage, t: &RigidTemplate, pose: &Pose, e: usize) -> bool {
        let stations = self.corner_stations(e, apex_end(&t.edges[e]));
        self.corner_held(frame, t, pose, &stations)
    }

    /// Whether an edge away from the apex fails to show one of its closed corners
    /// whose nearest stations lie in view ([`Fitter::corner_held`]). Asked where a
    /// particle took the apex's corner from one apex edge: a particle at the probe's
    /// level beside the tip leaves the probe's other corners as they are, while one
    /// over the whole end of the probe (wider than a tipless lever is thick) lengthens
    /// it by its size, the end face then placed on the particle's far side, and takes
    /// the corner of the flank away from the apex as well (tipless levers placed 17
    /// and 23 px past their ends, several-probe seeds 8 and 5).
    fn far_corner_hidden(&mut self, frame: &GrayImage, t: &RigidTemplate, pose: &Pose) -> bool {
        for e in (0..t.edges.len()).filter(|e| !t.apex_edges.contains(e)) {
            for end in (0..2).filter(|&end| !t.edges[e].open[end]) {
                let stations = self.corner_stations(e, end);
                let in_view = stations.iter().all(|p| p.is_some_and(|p| p.in_view));
                if in_view && !self.corner_held(frame, t, pose, &stations) {
                    return true;
                }
            }
        }
        false
    }

    /// All but one of a corner's `stations` ([`Fitter::corner_stations`], nearest
    /// first) show their edge within [`HELD_PX`], and the nearest within
    /// [`NEAREST_PX`] ([`Fitter::shown_off`]).
    fn corner_held(
        &mut self,
        frame: &GrayImage,
        t: &RigidTemplate,
        pose: &Pose,
        stations: &[Option<Point>; APEX_STATIONS],
    ) -> bool {
        let nearest = stations.iter().flatten().count();
        let mut shown = 0;
        for (slot, p) in stations.iter().enumerate() {
            let Some(p) = p else { continue };
            let off = self.shown_off(frame, t, pose, p);
            if slot == 0 && off > NEAREST_PX {
                return false;
            }
            shown += usize::from(off <= HELD_PX);
        }
        shown + 1 >= nearest
    }

    /// How far from the line station `p` shows its edge, pixels (infinity where it
    /// does not): where it steps as the edge does by [`STEP_SHARE`] of the calibrated
    /// step, or, beyond [`HELD_PX`], where it steps the other way by as much against a
    /// neighbour brighter than the probe where the probe is the brighter (darker where
    /// it is darker): the tip's outline where it touches a particle; or, for a step
    /// weaker than [`WEAK_STEP_SHARE`], where the station read centred on the line
    /// places it.
    fn shown_off(&mut self, frame: &GrayImage, t: &RigidTemplate, pose: &Pose, p: &Point) -> f64 {
        let own = Self::step_off(t, pose, p);
        if own <= HELD_PX || !p.in_view {
            return own;
        }
        let off = |read: Option<Point>| read.map_or(f64::INFINITY, |q| Self::step_off(t, pose, &q));
        let reach = REACHES[REACHES.len() - 1];
        let outline = off(self.read_again(frame, t, pose, p, -1.0, reach));
        // A weak step, off the line, read again centred on it: where the step is as
        // small as the noise, its largest rise is the noise's to place.
        let centred = if p.step < WEAK_STEP_SHARE {
            off(self.read_again(frame, t, pose, p, 1.0, 0.0))
        } else {
            f64::INFINITY
        };
        own.min(outline).min(centred)
    }

    /// Every station past a closed end of edge `e` holds it (steps by
    /// [`Fitter::run_on_share`] within [`HELD_PX`] of the line), with the probe's
    /// `level` on its side (the edge's holding stations'): the probe's body runs on. A
    /// particle beside the corner of another level (brighter than a bright probe)
    /// steps on the line's side too, but is not the probe.
    pub(super) fn runs_on(&self, t: &RigidTemplate, pose: &Pose, e: usize, level: f64) -> bool {
        let edge = &t.edges[e];
        let probe_level = |p: &Point| {
            level.is_nan() || (p.inside - level).abs() <= ONE_BODY_SHARE * edge.step.abs()
        };
        let past = |end: usize| {
            let share = self.run_on_share(t, e, end);
            self.points
                .iter()
                .filter(|p| p.edge == MAX_EDGES + e)
                .filter(|p| (p.tau > edge.extent[1]) == (end == 1))
                .filter(|p| p.step >= share && Self::residual(t, pose, p).abs() <= HELD_PX)
                .filter(|p| probe_level(p))
                .count()
        };
        (0..2).any(|end| !edge.open[end] && past(end) == BEYOND_PX.len())
    }

    /// The step, as a share of the calibrated one, that shows edge `e` running on past
    /// its closed end `end`: [`RUN_ON_SHARE`], but at the apex when the other apex
    /// edge does not close the body there (its median step under [`CLOSING_SHARE`] of
    /// this edge's next to the apex, the median of its [`APEX_STATIONS`] nearest), then
    /// [`RUN_ON_SHARE`] of this edge's own step next to the apex (within
    /// [`MIN_RUN_ON_YARDSTICK`] and 1). Past the apex a body that runs on steps as it
    /// does next to the apex, which a background brighter than on the reference
    /// weakens: a tipless lever's template laid along an AFM lever's beam over a bright
    /// sample, its end face placed where noise steps by 0.2-0.3, has the top edge step
    /// by 0.59-0.68 past the apex as next to it (tool seed 16). Where the other apex
    /// edge steps as strongly, the body ends there, and a particle at the probe's level
    /// beside the corner steps nearly as much: a needle at 0.75 of its calibrated step
    /// on both apex edges, the particle at 0.55-0.68 (several-probe seed 3).
    fn run_on_share(&self, t: &RigidTemplate, e: usize, end: usize) -> f64 {
        let other = match t.apex_edges {
            [a, b] if a == e => b,
            [a, b] if b == e => a,
            _ => return RUN_ON_SHARE,
        };
        if end != apex_end(&t.edges[e]) {
            return RUN_ON_SHARE;
        }
        let corner = self.corner_stations(e, end);
        let own = median_step(corner.iter().flatten());
        let closing = median_step(self.points.iter().filter(|p| p.edge == other));
        if closing >= CLOSING_SHARE * own {
            return RUN_ON_SHARE;
        }
        RUN_ON_SHARE * own.clamp(MIN_RUN_ON_YARDSTICK, 1.0)
    }
}
