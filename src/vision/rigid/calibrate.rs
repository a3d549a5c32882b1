//! A rigid probe's template from its reference image and the pixels a person clicked
//! on each named edge.
//!
//! Each edge is found where the reference steps across the line through its clicks:
//! its probe side is the side holding the other edges' clicks, its polarity and step
//! are read there (never assumed), its line is fitted through the located steps, and
//! its visible segment is traced from the clicks both ways until the step fades (or
//! the frame ends, which leaves that end open). The apex is where the two apex edges'
//! lines meet.

use image::GrayImage;

use super::fit::{stations_along, MAX_STATIONS};
use super::station::{Stations, RUN};
use super::{RigidEdge, RigidError, RigidTemplate, MAX_EDGES};
use crate::vision::geometry::{add, along, dot, norm, principal_axis, scale, sub, unit, Line};
use crate::vision::EdgeName;

/// Spacing of the stations read between and beyond the clicks, pixels.
const SPACING_PX: f64 = 2.0;
/// How far from the clicked line the step is looked for, pixels: clicks land within
/// a pixel or two of an edge.
const CLICK_REACH_PX: f64 = 3.0;
/// While tracing beyond the clicks, a station continues the edge when it steps by at
/// least this share of the edge's step within this distance of the fitted line.
const TRACE_SHARE: f64 = 0.5;
const TRACE_REACH_PX: f64 = 1.5;
/// A traced edge's direction is taken over this many of its last found stations.
const STEER_STATIONS: usize = 10;
/// How far a traced point may depart from the line through the clicked stretch, per
/// pixel traced beyond it, on top of [`TRACE_REACH_PX`]: a real needle's flank bows by
/// a pixel or two over its length (a slope of a few hundredths at its ends), while a
/// background line the trace could steer onto departs faster.
const TRACE_DRIFT: f64 = 0.02;
/// Missed stations in a row that end a traced edge.
const TRACE_GAP: usize = 3;
/// Shortest edge whose bow is fitted, pixels.
const MIN_BOW_LENGTH_PX: f64 = 60.0;
/// Points this close to another edge's line (pixels) are left out of an edge's fit:
/// half a station's run along the edge and the blur of the other's step.
const CORNER_FIT_PX: f64 = (RUN / 2) as f64 + 2.0;
/// Fewest points an edge is fitted through once those near corners are left out.
const MIN_CLEAR_POINTS: usize = 4;
/// A traced end within this distance past another edge's line ends at that corner.
const CORNER_SLACK_PX: f64 = 4.0;
/// Smallest step an edge may have on the reference, grey levels: below it the
/// profile's own noise places the edge.
pub const MIN_STEP: f64 = 6.0;
/// Smallest angle between the two apex edges, degrees: nearly parallel lines place
/// their intersection poorly.
const MIN_APEX_ANGLE_DEG: f64 = 10.0;

/// One edge while it is being found, in reference pixels.
struct Found {
    line: Line,
    /// Located points on the edge.
    points: Vec<[f64; 2]>,
    open: [bool; 2],
    polarity: f64,
    step: f64,
    /// The edge's bow and the ends it is measured between ([`Shape`]).
    bow: f64,
    bow_ends: [f64; 2],
    /// Standard error of the fitted line's direction, radians.
    angle_sigma: f64,
}

/// The template of a rigid probe: `edges` are (name, clicked pixels) in the config's
/// order, `apex` the names of the two edges that meet at its tip point.
pub fn calibrate(
    reference: &GrayImage,
    edges: &[(String, Vec<[f64; 2]>)],
    apex: [&str; 2],
) -> Result<RigidTemplate, RigidError> {
    if edges.len() < 2 {
        return Err(RigidError::TooFewEdges(edges.len()));
    }
    if edges.len() > MAX_EDGES {
        return Err(RigidError::TooManyEdges(edges.len()));
    }
    if let Some((name, _)) = edges
        .iter()
        .enumerate()
        .find_map(|(k, e)| edges[..k].iter().any(|(n, _)| *n == e.0).then_some(e))
    {
        return Err(RigidError::EdgeNamedTwice(name.clone()));
    }
    let index = |name: &str| {
        edges
            .iter()
            .position(|(n, _)| n == name)
            .ok_or_else(|| RigidError::UnknownApexEdge(name.to_string()))
    };
    let apex_edges = [index(apex[0])?, index(apex[1])?];
    if apex_edges[0] == apex_edges[1] {
        return Err(RigidError::ApexEdgesSame(apex[0].to_string()));
    }
    let (w, h) = (f64::from(reference.width()), f64::from(reference.height()));
    for (name, points) in edges {
        if points.len() < 2 {
            return Err(RigidError::TooFewClicks {
                edge: name.clone(),
                clicks: points.len(),
            });
        }
        if let Some(p) = points
            .iter()
            .find(|p| !(p[0] >= 0.0 && p[1] >= 0.0 && p[0] <= w - 1.0 && p[1] <= h - 1.0))
        {
            return Err(RigidError::ClickOutside {
                edge: name.clone(),
                point: *p,
                width: reference.width(),
                height: reference.height(),
            });
        }
    }
    let mut stations = Stations::default();
    let found: Vec<Found> = edges
        .iter()
        .enumerate()
        .map(|(k, (name, points))| {
            let others: Vec<[f64; 2]> = edges
                .iter()
                .enumerate()
                .filter(|(j, _)| *j != k)
                .flat_map(|(_, (_, p))| p.iter().copied())
                .collect();
            find_edge(reference, points, &others, &mut stations).map_err(|reason| {
                RigidError::EdgeNotFound {
                    edge: name.clone(),
                    reason,
                }
            })
        })
        .collect::<Result<_, _>>()?;
    let found = clear_of_corners(found);
    let (a, b) = (&found[apex_edges[0]], &found[apex_edges[1]]);
    let sin = (a.line.normal[0] * b.line.normal[1] - a.line.normal[1] * b.line.normal[0]).abs();
    if sin < MIN_APEX_ANGLE_DEG.to_radians().sin() {
        return Err(RigidError::ApexEdgesParallel {
            edges: [apex[0].to_string(), apex[1].to_string()],
            angle_deg: sin.asin().to_degrees(),
        });
    }
    let apex_px = a
        .line
        .intersect(&b.line)
        .ok_or_else(|| RigidError::ApexEdgesParallel {
            edges: [apex[0].to_string(), apex[1].to_string()],
            angle_deg: 0.0,
        })?;
    if !(apex_px[0] >= 0.0 && apex_px[1] >= 0.0 && apex_px[0] <= w - 1.0 && apex_px[1] <= h - 1.0) {
        return Err(RigidError::ApexOutside { apex: apex_px });
    }
    let mut steps: Vec<f64> = found.iter().map(|f| f.step).collect();
    steps.sort_by(f64::total_cmp);
    let typical_step = steps[steps.len() / 2];
    let template_edges: Vec<RigidEdge> = edges
        .iter()
        .zip(&found)
        .enumerate()
        .map(|(k, ((name, _), f))| {
            let n = f.line.normal;
            let taus = f.points.iter().map(|p| dot(along(n), sub(*p, apex_px)));
            let (mut lo, mut hi) = taus.fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), t| {
                (lo.min(t), hi.max(t))
            });
            if apex_edges.contains(&k) {
                // An apex edge ends at the apex, where the blur of the corner hides the
                // last pixel or two of its step.
                lo = lo.min(0.0);
                hi = hi.max(0.0);
            }
            // The body lies on the probe's side of every other edge's line: a trace
            // that ran on past one (over background that carries its step on) ends
            // where it crosses that line, at a corner.
            let clipped = overshoot(f, &found, k, apex_px, &mut lo, &mut hi);
            // A closed end lies at a corner: where the nearest other edge's line crosses
            // this one beyond the traced end, within the edge's length (a stretch of
            // background as bright as the probe can stop a trace short of it).
            let length = hi - lo;
            let crossings = || {
                found
                    .iter()
                    .enumerate()
                    .filter(|(j, _)| *j != k)
                    .filter_map(|(_, g)| f.line.intersect(&g.line))
                    .map(|p| dot(along(n), sub(p, apex_px)))
            };
            // An apex edge's end at the apex is where it is.
            let at_apex = |t: f64| apex_edges.contains(&k) && t == 0.0;
            // An end at no corner (a trace stopped by the background, or by the frame's
            // border) says nothing of where the edge ends: it is open.
            let mut open = clipped.map(|c| !c);
            if !clipped[0] && !f.open[0] {
                if at_apex(lo) {
                    open[0] = false;
                } else if let Some(t) = crossings()
                    .filter(|t| *t < lo + CORNER_SLACK_PX && lo - t <= length)
                    .max_by(f64::total_cmp)
                {
                    lo = t;
                    open[0] = false;
                }
            }
            if !clipped[1] && !f.open[1] {
                if at_apex(hi) {
                    open[1] = false;
                } else if let Some(t) = crossings()
                    .filter(|t| *t > hi - CORNER_SLACK_PX && t - hi <= length)
                    .min_by(f64::total_cmp)
                {
                    hi = t;
                    open[1] = false;
                }
            }
            RigidEdge {
                name: EdgeName::intern(name),
                normal: n,
                offset: -f.line.depth(apex_px),
                extent: [lo, hi],
                open,
                polarity: f.polarity,
                step: f.step.min(typical_step),
                bow: f.bow,
                bow_ends: {
                    // The ends, from the chord's foot of the origin to the apex's.
                    let shift = dot(along(n), apex_px);
                    [f.bow_ends[0] - shift, f.bow_ends[1] - shift]
                },
            }
        })
        .collect();
    // A frame's fit weighs each edge by its stations' moment about their middle, not
    // by the reference's sigma: each edge's error on the reference enters the frame's
    // rotation with that weight.
    let moments: Vec<f64> = template_edges
        .iter()
        .map(|e| stations_along(e.length()).min(MAX_STATIONS) as f64 * e.length().powi(2))
        .collect();
    let total: f64 = moments.iter().sum();
    let angle_sigma_rad = found
        .iter()
        .zip(&moments)
        .map(|(f, m)| (m * f.angle_sigma).powi(2))
        .sum::<f64>()
        .sqrt()
        / total;
    Ok(RigidTemplate {
        edges: template_edges,
        apex: apex_px,
        apex_edges,
        angle_sigma_rad,
    })
}

/// Clips edge `k`'s traced extent `lo..hi` (positions along it from the apex's foot)
/// at another edge's line that a traced end lies more than [`CORNER_SLACK_PX`] beyond,
/// on the side away from the probe; which ends were clipped.
fn overshoot(
    f: &Found,
    found: &[Found],
    k: usize,
    apex_px: [f64; 2],
    lo: &mut f64,
    hi: &mut f64,
) -> [bool; 2] {
    let tangent = along(f.line.normal);
    let foot = f.line.foot(apex_px);
    let at = |t: f64| add(foot, scale(tangent, t));
    let mut clipped = [false; 2];
    for (_, g) in found.iter().enumerate().filter(|(j, _)| *j != k) {
        let Some(p) = f.line.intersect(&g.line) else {
            continue;
        };
        let t = dot(tangent, sub(p, apex_px));
        if !(*lo < t && t < *hi) {
            continue;
        }
        if g.line.depth(at(*lo)) < -CORNER_SLACK_PX {
            *lo = t;
            clipped[0] = true;
        } else if g.line.depth(at(*hi)) < -CORNER_SLACK_PX {
            *hi = t;
            clipped[1] = true;
        }
    }
    clipped
}

/// Finds one edge near `clicks`, its probe side toward `others`.
fn find_edge(
    reference: &GrayImage,
    clicks: &[[f64; 2]],
    others: &[[f64; 2]],
    stations: &mut Stations,
) -> Result<Found, String> {
    let (centre, angle, spread) = principal_axis(clicks);
    if spread.sqrt() < 2.0 {
        return Err("its clicks are less than 2 pixels apart".into());
    }
    let direction = unit(angle);
    let mut normal = [-direction[1], direction[0]];
    let (oc, _, _) = principal_axis(others);
    if dot(normal, sub(oc, centre)) < 0.0 {
        normal = scale(normal, -1.0);
    }
    let tangent = along(normal);
    let taus = clicks.iter().map(|p| dot(tangent, sub(*p, centre)));
    let (lo, hi) = taus.fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), t| {
        (lo.min(t), hi.max(t))
    });
    let stations_between = ((hi - lo) / SPACING_PX).ceil().max(1.0) as usize;
    let at = |tau: f64| add(centre, scale(tangent, tau));
    // The polarity whose steps are the larger along the clicked stretch.
    let mut read = |polarity: f64| -> Vec<(f64, [f64; 2], f64)> {
        (0..=stations_between)
            .filter_map(|i| {
                let tau = lo + (hi - lo) * i as f64 / stations_between as f64;
                let q = at(tau);
                let found = stations.locate(reference, q, normal, polarity, CLICK_REACH_PX)?;
                Some((tau, add(q, scale(normal, found.t)), found.step))
            })
            .collect()
    };
    let bright = read(1.0);
    let dark = read(-1.0);
    let median_step = |v: &[(f64, [f64; 2], f64)]| median(v.iter().map(|s| s.2).collect());
    let (polarity, located) = if median_step(&bright) >= median_step(&dark) {
        (1.0, bright)
    } else {
        (-1.0, dark)
    };
    let step = median_step(&located);
    if located.is_empty() || step.is_nan() || step < MIN_STEP {
        return Err(format!(
            "no step across its clicked pixels (the probe's side steps by {:.1} grey levels; \
             at least {MIN_STEP} are needed)",
            step.max(0.0)
        ));
    }
    let mut points: Vec<[f64; 2]> = located
        .iter()
        .filter(|s| s.2 >= TRACE_SHARE * step)
        .map(|s| s.1)
        .collect();
    if points.len() < 2 {
        return Err("its step is not found along the clicked stretch".into());
    }
    let line = fit_line(&points, normal);
    let mut open = [false; 2];
    for (end, sign) in [(0, -1.0), (1, 1.0)] {
        let start = if sign < 0.0 { lo } else { hi };
        // Steered: each station continues from the last found point along the
        // direction of the points found over the last stretch, so a gently curved edge
        // (a real needle's flank) is followed to its end.
        let first = line.foot(at(start));
        let mut last = first;
        let mut direction = scale(along(line.normal), sign);
        let mut found: Vec<[f64; 2]> = vec![last];
        let mut gap = 0;
        loop {
            let q = add(last, scale(direction, SPACING_PX * (gap + 1) as f64));
            let n = [-direction[1] * sign, direction[0] * sign];
            match stations.locate(reference, q, n, polarity, TRACE_REACH_PX) {
                None => {
                    open[end] = true;
                    break;
                }
                Some(s)
                    if s.step >= TRACE_SHARE * step
                        && s.t.abs() <= TRACE_REACH_PX
                        && line.depth(add(q, scale(n, s.t))).abs()
                            <= TRACE_REACH_PX + TRACE_DRIFT * norm(sub(q, first)) =>
                {
                    last = add(q, scale(n, s.t));
                    found.push(last);
                    points.push(last);
                    gap = 0;
                    let back = found[found.len().saturating_sub(STEER_STATIONS)];
                    let d = sub(last, back);
                    if norm(d) > SPACING_PX {
                        direction = scale(d, 1.0 / norm(d));
                    }
                }
                Some(_) => {
                    gap += 1;
                    if gap >= TRACE_GAP {
                        break;
                    }
                }
            }
        }
    }
    let (line, bow, bow_ends, angle_sigma) = fitted(&points, line.normal);
    Ok(Found {
        line,
        points,
        open,
        polarity,
        step,
        bow,
        bow_ends,
        angle_sigma,
    })
}

/// An edge's line (its chord), bow and bow ends, and its direction's standard error,
/// fitted through `points` on the side `normal` faces.
fn fitted(points: &[[f64; 2]], normal: [f64; 2]) -> (Line, f64, [f64; 2], f64) {
    let line = fit_line(points, normal);
    let shape = Shape::fit(points, &line);
    let sigma = shape.sigma.max(0.05);
    // Points SPACING_PX apart each average a run of RUN pixels along the edge, so
    // neighbours share their noise: about RUN / SPACING_PX of them count as one.
    let angle_sigma = sigma / shape.spread.max(1.0) * (RUN as f64 / SPACING_PX).max(1.0).sqrt();
    (shape.chord, shape.bow, shape.ends, angle_sigma)
}

/// Each edge fitted again without its points within [`CORNER_FIT_PX`] of another
/// edge's line: there a station's run reaches into the corner, where the other edge's
/// blurred step moves the located one. Their extents keep every point.
fn clear_of_corners(found: Vec<Found>) -> Vec<Found> {
    let lines: Vec<Line> = found.iter().map(|f| f.line).collect();
    found
        .into_iter()
        .enumerate()
        .map(|(k, mut f)| {
            let clear: Vec<[f64; 2]> = f
                .points
                .iter()
                .copied()
                .filter(|p| {
                    lines
                        .iter()
                        .enumerate()
                        .all(|(j, l)| j == k || l.depth(*p).abs() > CORNER_FIT_PX)
                })
                .collect();
            if clear.len() >= MIN_CLEAR_POINTS && clear.len() < f.points.len() {
                (f.line, f.bow, f.bow_ends, f.angle_sigma) = fitted(&clear, f.line.normal);
            }
            f
        })
        .collect()
}

/// An edge's shape: the chord between the ends of its found points, and its bow, the
/// depth of a parabola through both ends (`bow * (tau - ends[0]) * (tau - ends[1])`
/// from the chord, positive into the probe). A straight edge's bow is nil; a real
/// needle's flank bows by up to a pixel or two, and a frame that shows another stretch
/// of it than the reference did would turn a straight fit.
struct Shape {
    chord: Line,
    bow: f64,
    /// Positions of the ends along the chord, from the chord's foot of the origin.
    ends: [f64; 2],
    /// Residual standard deviation about the bowed edge, pixels.
    sigma: f64,
    /// Root of the points' summed squared distances along the edge from their mean.
    spread: f64,
}

impl Shape {
    fn fit(points: &[[f64; 2]], line: &Line) -> Shape {
        let n = line.normal;
        let t = along(n);
        let taus: Vec<f64> = points.iter().map(|p| dot(t, *p)).collect();
        let depths: Vec<f64> = points.iter().map(|p| line.depth(*p)).collect();
        let (lo, hi) = taus
            .iter()
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), &v| {
                (lo.min(v), hi.max(v))
            });
        let mean = taus.iter().sum::<f64>() / taus.len() as f64;
        let spread = taus.iter().map(|v| (v - mean).powi(2)).sum::<f64>().sqrt();
        // depth = c0 + c1 (tau - mean) + bow (tau - lo)(tau - hi), least squares; an
        // edge too short to show a bow is fitted straight.
        let with_bow = hi - lo >= MIN_BOW_LENGTH_PX && points.len() >= 8;
        let basis = |tau: f64| {
            [
                1.0,
                tau - mean,
                if with_bow {
                    (tau - lo) * (tau - hi)
                } else {
                    0.0
                },
            ]
        };
        let mut a = nalgebra::Matrix3::<f64>::zeros();
        let mut b = nalgebra::Vector3::<f64>::zeros();
        for (&tau, &d) in taus.iter().zip(&depths) {
            let f = nalgebra::Vector3::from(basis(tau));
            a += f * f.transpose();
            b += f * d;
        }
        if !with_bow {
            a[(2, 2)] = 1.0;
        }
        let c = a
            .try_inverse()
            .map_or(nalgebra::Vector3::zeros(), |inv| inv * b);
        let residual = taus
            .iter()
            .zip(&depths)
            .map(|(&tau, &d)| {
                let f = basis(tau);
                d - (c[0] * f[0] + c[1] * f[1] + c[2] * f[2])
            })
            .map(|r| r * r)
            .sum::<f64>();
        let sigma = (residual / (points.len().saturating_sub(3).max(1)) as f64).sqrt();
        // The chord: through the fitted line's points at the two ends.
        let on = |tau: f64| {
            let depth = c[0] + c[1] * (tau - mean);
            add(line.foot(scale(t, tau)), scale(n, depth))
        };
        let (p0, p1) = (on(lo), on(hi));
        let d = sub(p1, p0);
        let chord_normal = {
            let u = scale(d, 1.0 / norm(d).max(1e-9));
            let m = [-u[1], u[0]];
            if dot(m, n) < 0.0 {
                scale(m, -1.0)
            } else {
                m
            }
        };
        let chord = Line::through(p0, chord_normal);
        let ends = [dot(along(chord_normal), p0), dot(along(chord_normal), p1)];
        let ends = [ends[0].min(ends[1]), ends[0].max(ends[1])];
        Shape {
            chord,
            bow: c[2],
            ends,
            sigma,
            spread,
        }
    }
}

/// The total-least-squares line through `points`, its normal on `normal`'s side.
pub fn fit_line(points: &[[f64; 2]], normal: [f64; 2]) -> Line {
    let (c, angle, _) = principal_axis(points);
    let d = unit(angle);
    let mut n = [-d[1], d[0]];
    if dot(n, normal) < 0.0 {
        n = scale(n, -1.0);
    }
    let n = scale(n, 1.0 / norm(n));
    Line::through(c, n)
}

fn median(mut v: Vec<f64>) -> f64 {
    if v.is_empty() {
        return f64::NAN;
    }
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}
