//! The fit of a rigid probe's pose on the full-resolution grey levels.
//!
//! Stations along every edge of the template, placed by the current pose, locate the
//! edge's step within a reach that shrinks pass by pass (8, 4, 2.5, 2 px); the pose
//! (rotation, apex, scale) is then solved by Gauss-Newton on the points' distances to
//! their edges' lines, with Huber weights. The rotation's standard error is the
//! solution's covariance from the weighted residuals, times a factor measured on the
//! rendered suites, combined with the reference's own. The last pass's stations are
//! then verified ([`verify`]).

use image::GrayImage;
use nalgebra::{Matrix4, Vector4};

use super::station::{Located, Stations};
use super::{Bounds, Pose, RigidEdge, RigidTemplate};
use crate::vision::geometry::{add, dot, rotate, scale, sub};
use crate::vision::Miss;

#[cfg(test)]
mod tests;
mod verify;

/// Most edges a rigid template may have.
pub const MAX_EDGES: usize = 8;
/// Reach of the passes, frame pixels.
const REACHES: [f64; 4] = [8.0, 4.0, 2.5, 2.0];
/// Gauss-Newton steps per pass.
const STEPS_PER_PASS: usize = 2;
/// Station spacing along an edge, frame pixels, and the most stations per edge.
const SPACING_PX: f64 = 5.0;
pub(super) const MAX_STATIONS: usize = 48;

/// Stations one per [`SPACING_PX`] along `length_px` frame pixels of an edge, both
/// ends included (before the bounds a pass puts on them).
pub(super) fn stations_along(length_px: f64) -> usize {
    (length_px / SPACING_PX).floor() as usize + 1
}
/// Passes reaching farther than this (frame pixels) read at most [`COARSE_STATIONS`]
/// per edge: they only bring the pose within the fine passes' reach.
const FINE_REACH_PX: f64 = 3.0;
const COARSE_STATIONS: usize = 12;
/// Stations keep this far from an edge's closed ends, frame pixels (the blurred
/// corner belongs to both edges).
const CORNER_PX: f64 = 3.0;
/// A station enters the fit when it steps by this share of the calibrated step.
const FIT_SHARE: f64 = 0.2;
/// A station steps as its edge does, while the fit converges and at the apex's corner,
/// when it steps by this share of the calibrated step: the corner tells a tip from a
/// body that only looks like it, and asking [`HOLD_SHARE`](verify::HOLD_SHARE) there
/// let a dark lever's template through on the dark gap of a rail in a real background
/// (tool seed 7).
const STEP_SHARE: f64 = 0.2;
/// Share of an edge's stations in view that must hold it.
pub const HELD_SHARE: f64 = 0.7;
/// After the second pass, a placement whose stations hold less than this share in all
/// is abandoned.
const ABANDON_SHARE: f64 = 0.4;
/// An edge is in view when at least this many of its stations are, and this share.
const MIN_IN_VIEW: usize = 3;
const IN_VIEW_SHARE: f64 = 0.25;
/// Stations checked beyond a closed end, at these distances past it, frame pixels;
/// all of them holding means the edge runs on (a particle beside the corner makes
/// two of them step on the line's side under noise; an edge that goes on makes all).
const BEYOND_PX: [f64; 3] = [4.0, 8.0, 12.0];
/// Floor of the residuals' scale in the Huber weights, pixels.
const MIN_SCALE_PX: f64 = 0.2;

/// Huber's constant, in units of the residuals' robust scale.
const HUBER_K: f64 = 1.5;
/// Ratio of the measured rotation error to the fit's covariance: neighbouring
/// stations' runs overlap and the blur correlates them (measured on the rendered
/// suites, tests/rigid_probes.rs).
const SIGMA_FACTOR: f64 = 1.2;

/// One edge as a fit saw it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Seen {
    /// Positions along the edge (reference pixels) of its first and last station in
    /// view.
    pub span: [f64; 2],
    pub held: usize,
    /// Median step of its stations, grey levels.
    pub step: f64,
}

/// A verified fit.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Fit {
    pub pose: Pose,
    pub angle_sigma_rad: f64,
    /// The least share of held stations over the edges in view.
    pub confidence: f64,
    pub edges: [Option<Seen>; MAX_EDGES],
}

/// A station's reading.
#[derive(Debug, Clone, Copy)]
struct Point {
    edge: usize,
    tau: f64,
    /// The located step's point, frame pixels.
    at: [f64; 2],
    step: f64,
    /// Mean level on the probe's side of the located step.
    inside: f64,
    /// The step was found (inside the frame); else the station is out of view.
    in_view: bool,
}

impl Point {
    /// The reading of a station at `q` (normal `normal`) that found step `f`, over the
    /// edge's calibrated `step`.
    fn located(
        edge: usize,
        tau: f64,
        q: [f64; 2],
        normal: [f64; 2],
        f: Located,
        step: f64,
    ) -> Point {
        Point {
            edge,
            tau,
            at: add(q, scale(normal, f.t)),
            step: f.step / step,
            inside: f.inside,
            in_view: true,
        }
    }

    /// The level outside the located step of a station of `edge`: its inside less
    /// its step, grey levels.
    fn outside(&self, edge: &RigidEdge) -> f64 {
        self.inside - edge.polarity * self.step * edge.step
    }
}

/// A station's point against its edge at a pose: the residual (signed distance from
/// the bowed edge), and what its derivatives need: the edge's normal in the frame, the
/// point from the apex, the edge's depth there in reference pixels.
struct Against {
    residual: f64,
    normal: [f64; 2],
    from_apex: [f64; 2],
    depth: f64,
}

impl Against {
    fn new(t: &RigidTemplate, pose: &Pose, p: &Point) -> Against {
        let edge = &t.edges[p.edge % MAX_EDGES];
        let normal = rotate(edge.normal, pose.psi);
        let from_apex = sub(p.at, pose.apex);
        let depth = edge.offset + edge.bow_at(p.tau);
        Against {
            residual: dot(normal, from_apex) - pose.scale * depth,
            normal,
            from_apex,
            depth,
        }
    }
}

/// Fits poses; keeps its buffers between calls.
#[derive(Debug, Default)]
pub struct Fitter {
    stations: Stations,
    points: Vec<Point>,
    residuals: Vec<f64>,
    /// Whether both apex edges must show the corner: on a reference, where nothing
    /// touches the tip and a misplaced tip point must not verify.
    pub(super) whole_corner: bool,
}

impl Fitter {
    /// The verified fit of `template` from `start`, or the refusal and how much of the
    /// probe the frame showed.
    pub fn fit(
        &mut self,
        frame: &GrayImage,
        template: &RigidTemplate,
        start: Pose,
        bounds: &Bounds,
    ) -> Result<Fit, (Miss, f64)> {
        let mut pose = start;
        let mut covariance = Matrix4::zeros();
        for (pass, &reach) in REACHES.iter().enumerate() {
            let stations = if reach > FINE_REACH_PX {
                COARSE_STATIONS
            } else {
                MAX_STATIONS
            };
            self.read(frame, template, &pose, reach, stations, false);
            if pass == 1 {
                let (held, total) = self.held();
                if total == 0 || (held as f64) < ABANDON_SHARE * total as f64 {
                    return Err((Miss::Inconsistent, held as f64 / total.max(1) as f64));
                }
            }
            for _ in 0..STEPS_PER_PASS {
                let Some((next, cov)) = self.solve(template, &pose) else {
                    return Err((Miss::Inconsistent, 0.0));
                };
                pose = next;
                covariance = cov;
            }
            if !bounds.scales.contains(pose.scale) {
                return Err((Miss::ScaleMismatch, 0.0));
            }
        }
        self.read(
            frame,
            template,
            &pose,
            REACHES[REACHES.len() - 1],
            MAX_STATIONS,
            true,
        );
        self.read_short_edges_at_line(frame, template, &pose);
        let sigma =
            (covariance[(0, 0)].max(0.0).sqrt() * SIGMA_FACTOR).hypot(template.angle_sigma_rad);
        self.verify(frame, template, pose, sigma, bounds.window_rad)
    }

    /// Reads every edge's stations at `pose`; with `beyond`, also the stations past
    /// each closed end (edge index offset by [`MAX_EDGES`]).
    fn read(
        &mut self,
        frame: &GrayImage,
        t: &RigidTemplate,
        pose: &Pose,
        reach: f64,
        most: usize,
        beyond: bool,
    ) {
        self.points.clear();
        for (e, edge) in t.edges.iter().enumerate() {
            let normal = rotate(edge.normal, pose.psi);
            let margin = CORNER_PX / pose.scale;
            let lo = edge.extent[0] + if edge.open[0] { 0.0 } else { margin };
            let hi = edge.extent[1] - if edge.open[1] { 0.0 } else { margin };
            if hi <= lo {
                continue;
            }
            let count = stations_along((hi - lo) * pose.scale).clamp(MIN_IN_VIEW, most);
            for k in 0..count {
                let tau = lo + (hi - lo) * k as f64 / (count - 1) as f64;
                let q = pose.place(edge, tau);
                let found = self.stations.locate(frame, q, normal, edge.polarity, reach);
                self.points.push(match found {
                    Some(f) => Point::located(e, tau, q, normal, f, edge.step),
                    None => Point {
                        edge: e,
                        tau,
                        at: q,
                        step: 0.0,
                        inside: f64::NAN,
                        in_view: false,
                    },
                });
            }
            if !beyond {
                continue;
            }
            for (end, sign) in [(0, -1.0), (1, 1.0)] {
                if edge.open[end] {
                    continue;
                }
                for d in BEYOND_PX {
                    let tau = edge.extent[end] + sign * d / pose.scale;
                    let q = pose.place(edge, tau);
                    if let Some(f) = self.stations.locate(frame, q, normal, edge.polarity, reach) {
                        self.points.push(Point::located(
                            MAX_EDGES + e,
                            tau,
                            q,
                            normal,
                            f,
                            edge.step,
                        ));
                    }
                }
            }
        }
    }

    /// Reads again, centred on its line at `pose`, each station in view that does not
    /// hold an edge of so few stations that two of them decide it (a blunt end), and
    /// keeps the new reading where it holds. A station finds its step at the largest
    /// one-pixel rise within its reach, which noise as large as the step moves by
    /// pixels; centred on the line, the step is placed by its area between the levels
    /// either side alone. A long edge's share holds through such stations; a short
    /// one's does not.
    fn read_short_edges_at_line(&mut self, frame: &GrayImage, t: &RigidTemplate, pose: &Pose) {
        for e in 0..t.edges.len() {
            let n = self
                .points
                .iter()
                .filter(|p| p.edge == e && p.in_view)
                .count();
            if n == 0 || (n - n.min(2)) as f64 >= HELD_SHARE * n as f64 {
                continue;
            }
            for i in 0..self.points.len() {
                let p = self.points[i];
                if p.edge != e || !p.in_view || Self::holds_final(t, pose, &p) {
                    continue;
                }
                let again = self.read_again(frame, t, pose, &p, 1.0, 0.0);
                if let Some(again) = again.filter(|q| Self::holds_final(t, pose, q)) {
                    self.points[i] = again;
                }
            }
        }
    }

    /// Station `p` of an edge read again from its place on the edge at `pose`: the
    /// step of `polarity` times the edge's within `reach` pixels of the line (with
    /// `reach` 0, centred on it).
    fn read_again(
        &mut self,
        frame: &GrayImage,
        t: &RigidTemplate,
        pose: &Pose,
        p: &Point,
        polarity: f64,
        reach: f64,
    ) -> Option<Point> {
        let edge = &t.edges[p.edge];
        let normal = rotate(edge.normal, pose.psi);
        let q = pose.place(edge, p.tau);
        self.stations
            .locate(frame, q, normal, polarity * edge.polarity, reach)
            .map(|f| Point::located(p.edge, p.tau, q, normal, f, edge.step))
    }

    /// Signed distance of a station's point from its edge's line at `pose`.
    fn residual(t: &RigidTemplate, pose: &Pose, p: &Point) -> f64 {
        Against::new(t, pose, p).residual
    }

    /// Stations stepping as their edge does (before the fit has converged: wherever
    /// within the reach), and stations in view.
    fn held(&self) -> (usize, usize) {
        let in_view = self.points.iter().filter(|p| p.in_view);
        let held = in_view.clone().filter(|p| p.step >= STEP_SHARE).count();
        (held, in_view.count())
    }

    /// One Gauss-Newton step with Huber weights; the new pose and the covariance of the
    /// parameters (psi, apex x, apex y, scale).
    fn solve(&mut self, t: &RigidTemplate, pose: &Pose) -> Option<(Pose, Matrix4<f64>)> {
        self.residuals.clear();
        for p in &self.points {
            if p.in_view && p.step >= FIT_SHARE {
                self.residuals.push(Self::residual(t, pose, p).abs());
            }
        }
        let n = self.residuals.len();
        if n < 6 {
            return None;
        }
        self.residuals.sort_by(f64::total_cmp);
        let scale_px = (1.4826 * self.residuals[n / 2]).max(MIN_SCALE_PX);
        let k = HUBER_K * scale_px;
        let mut normal_matrix = Matrix4::<f64>::zeros();
        let mut rhs = Vector4::<f64>::zeros();
        let mut weighted_sq = 0.0;
        let mut weight_sum = 0.0;
        for p in &self.points {
            if !(p.in_view && p.step >= FIT_SHARE) {
                continue;
            }
            let Against {
                residual: r,
                normal,
                from_apex: d,
                depth,
            } = Against::new(t, pose, p);
            let w = if r.abs() <= k { 1.0 } else { k / r.abs() };
            let j = Vector4::new(
                -normal[1] * d[0] + normal[0] * d[1],
                -normal[0],
                -normal[1],
                -depth,
            );
            normal_matrix += w * j * j.transpose();
            rhs += w * r * j;
            weighted_sq += w * r * r;
            weight_sum += w;
        }
        if normal_matrix[(3, 3)] < 1e-6 {
            // No edge off the apex: the scale is not observed; hold it.
            normal_matrix[(3, 3)] = 1.0;
        }
        let inverse = normal_matrix.try_inverse()?;
        let delta = -inverse * rhs;
        let dof = (weight_sum - 4.0).max(1.0);
        let variance = weighted_sq / dof;
        let next = Pose {
            psi: pose.psi + delta[0],
            apex: [pose.apex[0] + delta[1], pose.apex[1] + delta[2]],
            scale: pose.scale + delta[3],
        };
        if !(next.psi.is_finite() && next.scale.is_finite() && next.scale > 0.0) {
            return None;
        }
        Some((next, inverse * variance))
    }
}
