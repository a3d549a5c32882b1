//! Automatic calibration of a rigid probe: its straight edges found from one click on
//! or near its tip point, as clicked pixels on each that then go through the ordinary
//! calibration ([`calibrate()`]). The result is a template like any other: the same
//! block printed, the same overlay for a person to confirm.
//!
//! 1. On a ring around the click the probe is the arc that stands out (as for the AFM
//!    pyramid, `vision::autocal`): its two ends are the apex edges' directions, and
//!    which side is brighter gives the probe's polarity.
//! 2. Each edge is traced outward from the corner it starts at, with profiles across
//!    it, until its step fades (another edge takes over at a corner) or it leaves the
//!    frame; then traced again along the line through what it found, until that
//!    stops growing.
//! 3. An edge that ends inside the frame ends at a corner. On a ring around it the
//!    body is an arc again: one end runs back along the edge, the other is near the
//!    next edge's direction, which is taken where the step along a ray from the corner
//!    is strongest (a ring small enough for a 10 px blunt end has its ends blurred by
//!    the corner). So the outline is followed from the apex both ways, edge after edge,
//!    until it leaves the frame (or closes, or reaches [`MAX_EDGES`]); an edge found
//!    running on along the last one's line is that edge going on.
//! 4. The edges are named `e1`, `e2`, ... in their order around the outline; each is
//!    clicked at 10, 50 and 90 % of its traced stretch.
//! 5. The template must verify on its own reference where calibration placed it; the
//!    ring's outline is tried first, then the rays' (where the probe beside its tip
//!    point is as bright as its ground, as for the pyramid).

use image::GrayImage;

use super::{calibrate, Pose, RigidTemplate, RigidTracker, MAX_EDGES};
use crate::vision::autocal::{
    body_levels, entering_bodies, ray_steps, rays, trace, traced, wedge_on, AutoCalError, Traced,
    Wedge, FACE_START_PX, LEVEL_PX, RING_PX,
};
use crate::vision::geometry::{add, dot, norm, principal_axis, scale, sub, unit};
use crate::vision::{VisionError, DEFAULT_WINDOW_DEG};

/// Smallest ring around a corner, pixels: a short edge (a needle's blunt end) leaves
/// less room before the next corner, and the ring is kept within half of it.
const MIN_RING_PX: f64 = 4.0;
/// An edge whose traced end lies within this distance of the frame's border (pixels,
/// along its direction) leaves the frame there: the profiles across it need
/// [`LEVEL_PX`] on either side.
const BORDER_PX: f64 = LEVEL_PX.1 + 4.0;
/// The traced end of an edge lies short of its corner by the profiles that missed it
/// there; the ring is centred this far further on, pixels.
const CORNER_AHEAD_PX: f64 = 2.0;
/// Around a corner, the next edge's direction is looked for this far (degrees) either
/// side of the ring's, in steps of [`TURN_STEP_DEG`], by its mean step across a ray
/// over [`TURN_RAY_PX`] pixels from the corner (both included).
const TURN_SEARCH_DEG: f64 = 45.0;
const TURN_STEP_DEG: f64 = 0.5;
const TURN_RAY_PX: (usize, usize) = (3, 30);
/// Re-traces of an edge along the line found so far.
const RETRACES: usize = 3;
/// A next edge within this angle (degrees) of the last, starting within this distance
/// (pixels) of the last's line, is the last going on: the probe's corners turn by
/// tens of degrees.
const SAME_DIRECTION: f64 = 5.0;
const SAME_LINE_PX: f64 = 3.0;
/// Two pieces of the outline whose calibrated lines lie within this angle (degrees)
/// and distance (pixels) of each other are one edge.
const ONE_LINE_DEG: f64 = 1.0;
const ONE_LINE_PX: f64 = 2.0;
/// Bodies entering from a side, largest first, tried per polarity and level for a tip
/// point (a substrate or a bright background may be larger than the probe).
const BODIES: usize = 3;
/// A tip point is a corner of the body's end: the pixel farthest from its axis among
/// those within this distance (pixels, along the axis) of its farthest.
const END_PX: f64 = 4.0;
/// Where along each edge's traced stretch the clicks fall.
const CLICK_SHARES: [f64; 3] = [0.1, 0.5, 0.9];

/// The edges found: (name, clicked pixels) around the outline, and the two that meet
/// at the tip point.
#[derive(Debug, Clone, PartialEq)]
pub struct RigidAutoClicks {
    pub edges: Vec<(String, Vec<[f64; 2]>)>,
    pub apex: [String; 2],
}

/// Finds a rigid probe's edges from `apex` (a pixel on or near its tip point) and
/// calibrates on them; they are named `e1`, `e2`, ... in their order around the
/// outline.
///
/// The ring's outline is taken first, the rays' where the ring's does not make a
/// template: one with an edge away from the apex, whose own reference verifies as
/// this probe where calibration placed it (one body, every edge stepping as found).
///
/// Without a pixel, the tip point is looked for where the probe is a body entering
/// from a frame side (of either polarity): a corner of the end it reaches into the
/// view with, along its axis ([`find_tip_points`]). The first whose outline makes a
/// template is taken.
pub fn auto_calibrate(
    reference: &GrayImage,
    apex: Option<[f64; 2]>,
) -> Result<(RigidAutoClicks, RigidTemplate), AutoCalError> {
    let Some(apex) = apex else {
        let mut first = None;
        for tip in find_tip_points(reference)? {
            match from_pixel(reference, tip) {
                Ok(found) => return Ok(found),
                Err(e) => {
                    first.get_or_insert(e);
                }
            }
        }
        return Err(first.unwrap_or_else(|| AutoCalError::NoProbe("no body enters".into())));
    };
    from_pixel(reference, apex)
}

/// The candidate tip points of a probe entering the frame from a side: for each
/// polarity (the brighter body first), each level of `body_levels` (Otsu's over all
/// grey levels first: the bright class's shrinks a faint body's corners by pixels) and
/// each of the `BODIES` largest bodies touching a side, a corner of its end (the
/// `END_PX` rule) along its long axis, where that is clear of the border.
pub fn find_tip_points(reference: &GrayImage) -> Result<Vec<[f64; 2]>, AutoCalError> {
    let mut dark = reference.clone();
    image::imageops::invert(&mut dark);
    let mut tips = Vec::new();
    let mut why = String::new();
    for (img, bright) in [(reference, true), (&dark, false)] {
        for level in body_levels(img).into_iter().rev() {
            // The level in the reference's grey levels (the dark pass reads the
            // inverted frame).
            let (side, grey) = if bright {
                ("above", level)
            } else {
                ("below", 255 - level)
            };
            let bodies = match entering_bodies(img, level, BODIES) {
                Ok(bodies) => bodies,
                Err(_) if !bright => {
                    why = format!(
                        "no dark body of a probe's size below grey level {grey} touches a side"
                    );
                    continue;
                }
                Err(e) => {
                    why = e;
                    continue;
                }
            };
            for body in bodies {
                // The whole body's long axis, into the frame (near the side it enters
                // from, a needle or a jaw is as wide as it is deep).
                let (centre, theta, _) = principal_axis(&body.pixels);
                let mut axis = unit(theta);
                if dot(axis, body.axis) < 0.0 {
                    axis = scale(axis, -1.0);
                }
                let along = |p: &[f64; 2]| dot(axis, sub(*p, centre));
                let across = |p: &[f64; 2]| dot([-axis[1], axis[0]], sub(*p, centre)).abs();
                let far = body
                    .pixels
                    .iter()
                    .map(along)
                    .fold(f64::NEG_INFINITY, f64::max);
                // A corner of the end, not a pixel of noise on an end face across the
                // axis: of the pixels within END_PX of the farthest, the one farthest
                // from the axis.
                let tip = body
                    .pixels
                    .iter()
                    .copied()
                    .filter(|p| along(p) >= far - END_PX)
                    .max_by(|a, b| across(a).total_cmp(&across(b)));
                match tip {
                    // A body that reaches the border along its axis shows no tip.
                    Some(t) if near_border(reference, add(t, axis)) => {
                        why = format!(
                            "the bodies entering from a side {side} grey level {grey} run \
                             on to the border (at ({:.0}, {:.0}))",
                            t[0], t[1]
                        );
                    }
                    Some(t) if !tips.contains(&t) => tips.push(t),
                    _ => {}
                }
            }
        }
    }
    if tips.is_empty() {
        return Err(AutoCalError::NoProbe(why));
    }
    Ok(tips)
}

/// [`auto_calibrate`] from a pixel on or near the tip point.
fn from_pixel(
    reference: &GrayImage,
    apex: [f64; 2],
) -> Result<(RigidAutoClicks, RigidTemplate), AutoCalError> {
    let ring = wedge_on(reference, apex, RING_PX)
        .map_err(|e| not_found("the apex edges", e))
        .and_then(|w| calibrated(reference, apex, &w));
    ring.or_else(|first| {
        rays(reference, apex)
            .and_then(|w| calibrated(reference, apex, &w))
            .map_err(|_| first)
    })
}

/// The template of the outline that the apex edges `w` start, verified on its
/// reference.
fn calibrated(
    reference: &GrayImage,
    apex: [f64; 2],
    w: &Wedge,
) -> Result<(RigidAutoClicks, RigidTemplate), AutoCalError> {
    let (mut edges, mut apex_at) = outline(reference, apex, w)?;
    let (clicks, template) = loop {
        if edges.len() < 3 {
            return Err(AutoCalError::NotFound {
                edges: "an edge away from the tip point",
                reason: "the outline from the apex edges leaves the frame or fades before \
                         another edge; without one the template is any corner of the apex \
                         edges' angle"
                    .into(),
            });
        }
        let names: Vec<String> = (1..=edges.len()).map(|k| format!("e{k}")).collect();
        let clicks = RigidAutoClicks {
            edges: names
                .iter()
                .zip(&edges)
                .map(|(n, t)| (n.clone(), t.clicks(&CLICK_SHARES)))
                .collect(),
            apex: apex_at.map(|k| names[k].clone()),
        };
        let template = calibrate(
            reference,
            &clicks.edges,
            [clicks.apex[0].as_str(), clicks.apex[1].as_str()],
        )
        .map_err(VisionError::from)?;
        // Two pieces of the outline that calibrate to one line are one edge, its trace
        // stopped short (by a particle on it): joined, and calibrated again.
        let Some(k) = (0..edges.len() - 1).find(|&k| {
            let (a, b) = (&template.edges[k], &template.edges[k + 1]);
            dot(a.normal, b.normal) >= ONE_LINE_DEG.to_radians().cos()
                && (a.offset - b.offset).abs() <= ONE_LINE_PX
                && !(apex_at.contains(&k) && apex_at.contains(&(k + 1)))
        }) else {
            break (clicks, template);
        };
        let (a, b) = (edges[k], edges.remove(k + 1));
        let along = |p: [f64; 2]| dot(sub(p, a.point), a.dir);
        let ends = [
            a.span.0,
            a.span.1,
            along(b.at(b.span.0)),
            along(b.at(b.span.1)),
        ];
        edges[k].span = (
            ends.iter().copied().fold(f64::INFINITY, f64::min),
            ends.iter().copied().fold(f64::NEG_INFINITY, f64::max),
        );
        for i in apex_at.iter_mut() {
            if *i > k {
                *i -= 1;
            }
        }
    };
    let at_home = Pose {
        psi: 0.0,
        scale: 1.0,
        apex: template.apex,
    };
    let check = RigidTracker::new(template.clone(), DEFAULT_WINDOW_DEG)
        .whole_corner()
        .track_from(reference, at_home);
    if let Some(miss) = check.miss {
        return Err(AutoCalError::NotFound {
            edges: "a probe",
            reason: format!(
                "the {} edges found around the outline do not verify as one probe on the \
                 reference ({miss})",
                edges.len()
            ),
        });
    }
    Ok((clicks, template))
}

/// The outline from the apex edges `w` gives: its edges in order, and the indices of
/// the two apex edges among them.
fn outline(
    img: &GrayImage,
    apex: [f64; 2],
    w: &Wedge,
) -> Result<(Vec<Traced>, [usize; 2]), AutoCalError> {
    let dirs = w.ends.map(unit);
    let axis = unit_of(add(dirs[0], dirs[1]));
    let mut chains: [Vec<Traced>; 2] = [Vec::new(), Vec::new()];
    for k in 0..2 {
        // The edge's direction for the message: degrees CCW on screen, in (-180, 180].
        let screen_deg = 180.0 - (180.0 + w.ends[k].to_degrees()).rem_euclid(360.0);
        let first =
            follow(img, apex, dirs[k], sub(axis, dirs[k]), w.polarity).ok_or_else(|| {
                AutoCalError::NotFound {
                    edges: "an apex edge",
                    reason: format!(
                        "the step along the edge leaving ({:.1}, {:.1}) at {screen_deg:.0} deg \
                         (CCW on screen) fades within a few pixels",
                        apex[0], apex[1]
                    ),
                }
            })?;
        chains[k].push(first);
    }
    // Each chain followed on from its far end while the outline has room left.
    let mut corners = vec![apex];
    for k in 0..2 {
        while chains[0].len() + chains[1].len() < MAX_EDGES {
            let last = *chains[k].last().expect("a chain starts with its apex edge");
            let Some(next) = next_edge(img, &last, w.polarity, &corners) else {
                break;
            };
            corners.push(last.at(last.span.1));
            match merged(&last, &next) {
                // The edge goes on past a point where its trace stopped.
                Some(longer) => *chains[k].last_mut().expect("not empty") = longer,
                None => chains[k].push(next),
            }
        }
    }
    // Around the outline: the first chain from its far end to the apex, then the second.
    let apex_at = [chains[0].len() - 1, chains[0].len()];
    let [first, second] = chains;
    Ok((first.into_iter().rev().chain(second).collect(), apex_at))
}

/// `next` as the continuation of `edge`, when it runs on along the same line: `edge`
/// extended to its end.
fn merged(edge: &Traced, next: &Traced) -> Option<Traced> {
    let normal = [-edge.dir[1], edge.dir[0]];
    let (start, end) = (next.at(next.span.0), next.at(next.span.1));
    let on_line = dot(sub(start, edge.point), normal).abs() <= SAME_LINE_PX;
    (dot(next.dir, edge.dir) >= SAME_DIRECTION.to_radians().cos() && on_line).then(|| Traced {
        span: (edge.span.0, dot(sub(end, edge.point), edge.dir)),
        ..*edge
    })
}

/// An error of the ring search, for `edges`.
fn not_found(edges: &'static str, e: AutoCalError) -> AutoCalError {
    match e {
        AutoCalError::NotFound { reason, .. } => AutoCalError::NotFound { edges, reason },
        other => other,
    }
}

fn unit_of(v: [f64; 2]) -> [f64; 2] {
    scale(v, 1.0 / norm(v).max(1e-9))
}

/// The edge leaving `origin` along `dir` with the probe towards `inside`, traced, then
/// traced again along the line found so far (from the origin's foot on it) while that
/// finds more of it.
fn follow(
    img: &GrayImage,
    origin: [f64; 2],
    dir: [f64; 2],
    inside: [f64; 2],
    polarity: f64,
) -> Option<Traced> {
    let mut found = traced(
        &trace(img, origin, dir, inside, polarity, FACE_START_PX),
        dir,
    )?;
    for _ in 0..RETRACES {
        let foot = found.at(dot(sub(origin, found.point), found.dir));
        let pts = trace(img, foot, found.dir, inside, polarity, FACE_START_PX);
        match traced(&pts, found.dir) {
            Some(next) if next.length() > found.length() + 0.5 => found = next,
            _ => break,
        }
    }
    Some(found)
}

/// Whether `p` lies within [`BORDER_PX`] of the frame's border.
fn near_border(img: &GrayImage, p: [f64; 2]) -> bool {
    let (w, h) = (f64::from(img.width()) - 1.0, f64::from(img.height()) - 1.0);
    p[0] < BORDER_PX || p[1] < BORDER_PX || p[0] > w - BORDER_PX || p[1] > h - BORDER_PX
}

/// The edge after `edge` around the outline, from the corner where it ends: none when
/// it leaves the frame, when the corner is one already passed (the outline closes),
/// or when no edge of the probe's polarity leaves it.
fn next_edge(
    img: &GrayImage,
    edge: &Traced,
    polarity: f64,
    corners: &[[f64; 2]],
) -> Option<Traced> {
    let end = edge.at(edge.span.1);
    if near_border(img, add(end, scale(edge.dir, BORDER_PX))) {
        return None;
    }
    let corner = add(end, scale(edge.dir, CORNER_AHEAD_PX));
    let ring = (0.5 * edge.length()).clamp(MIN_RING_PX, RING_PX);
    if corners.iter().any(|c| norm(sub(*c, corner)) < 2.0 * ring) {
        return None;
    }
    let w = wedge_on(img, corner, ring).ok()?;
    if w.polarity != polarity {
        return None;
    }
    // One end of the arc runs back along the edge; the other is near the next edge's.
    // A small ring's ends are blurred by the corner: the direction is taken where the
    // step along a ray from the corner is strongest, within [`TURN_SEARCH_DEG`] of it.
    let back = scale(edge.dir, -1.0);
    let ends = w.ends.map(unit);
    let near = if dot(ends[0], back) >= dot(ends[1], back) {
        w.ends[1]
    } else {
        w.ends[0]
    };
    let next = strongest_ray(img, corner, near, back, polarity)?;
    follow(img, corner, next, back, polarity)
}

/// The direction from `corner`, within [`TURN_SEARCH_DEG`] of `near` (an image angle,
/// radians), along which the frame steps most as an edge of `polarity` with the probe
/// on the side of `body`; none where no ray shows such a step.
fn strongest_ray(
    img: &GrayImage,
    corner: [f64; 2],
    near: f64,
    body: [f64; 2],
    polarity: f64,
) -> Option<[f64; 2]> {
    let steps = (TURN_SEARCH_DEG / TURN_STEP_DEG) as i32;
    let mut best: Option<(f64, [f64; 2])> = None;
    for k in -steps..=steps {
        let angle = near + f64::from(k) * TURN_STEP_DEG.to_radians();
        let u = unit(angle);
        // `ray_steps` reads counter-clockwise less clockwise; the probe lies on the
        // body's side of the ray.
        let side = if dot([-u[1], u[0]], body) < 0.0 {
            -1.0
        } else {
            1.0
        };
        let steps: Vec<f64> = ray_steps(img, corner, angle, TURN_RAY_PX.0..TURN_RAY_PX.1 + 1)
            .into_iter()
            .flatten()
            .collect();
        if 2 * steps.len() < TURN_RAY_PX.1 - TURN_RAY_PX.0 {
            continue;
        }
        let mean = steps.iter().map(|s| polarity * side * s).sum::<f64>() / steps.len() as f64;
        if mean > 0.0 && best.is_none_or(|b| mean > b.0) {
            best = Some((mean, u));
        }
    }
    best.map(|b| b.1)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A bright needle (200 on 60) whose upper flank rises to the left from the apex
    /// at (300, 200), with a blunt end face 40 px long down to the lower flank, which
    /// falls to the left: a quadrilateral widening out of the frame on the left.
    fn needle() -> GrayImage {
        let upper = |x: f64| 200.0 - 0.10 * (300.0 - x);
        let lower = |x: f64| 240.0 + 0.05 * (300.0 - x);
        GrayImage::from_fn(400, 300, |x, y| {
            let (x, y) = (f64::from(x), f64::from(y));
            let inside = x <= 300.0 && y >= upper(x) && y <= lower(x);
            image::Luma([if inside { 200 } else { 60 }])
        })
    }

    #[test]
    fn a_needle_is_followed_round_from_its_tip() {
        let img = needle();
        let (clicks, template) = auto_calibrate(&img, Some([301.0, 199.0])).unwrap();
        let names: Vec<&str> = clicks.edges.iter().map(|(n, _)| n.as_str()).collect();
        assert_eq!(names, ["e1", "e2", "e3"]);
        assert_eq!(template.edges.len(), 3);
        // The tip point is where the upper flank meets the end face.
        assert!(
            norm(sub(template.apex, [300.0, 200.0])) < 1.0,
            "{:?}",
            template.apex
        );
    }

    #[test]
    fn without_a_pixel_the_tip_point_is_a_corner_of_the_end() {
        // Bright on dark, and dark on bright: either polarity enters from the side.
        let bright = needle();
        let mut dark = bright.clone();
        image::imageops::invert(&mut dark);
        for img in [bright, dark] {
            let (clicks, template) = auto_calibrate(&img, None).unwrap();
            assert_eq!(clicks.edges.len(), 3);
            let off = |q: [f64; 2]| norm(sub(template.apex, q));
            assert!(
                off([300.0, 200.0]).min(off([300.0, 240.0])) < 1.0,
                "{:?}",
                template.apex
            );
        }
    }

    #[test]
    fn a_body_across_the_frame_has_no_tip_point() {
        let bar = GrayImage::from_fn(400, 300, |_, y| {
            image::Luma([if (140..160).contains(&y) { 200 } else { 60 }])
        });
        let err = auto_calibrate(&bar, None).unwrap_err().to_string();
        assert!(err.contains("run on to the border"), "{err}");
    }

    /// A dark particle on the upper flank stops its trace: the piece beyond is that
    /// flank going on, one edge.
    #[test]
    fn a_flank_interrupted_by_a_particle_is_one_edge() {
        let mut img = needle();
        for (x, y, p) in img.enumerate_pixels_mut() {
            let (dx, dy) = (f64::from(x) - 150.0, f64::from(y) - 185.0);
            if dx.hypot(dy) <= 8.0 {
                *p = image::Luma([60]);
            }
        }
        let (clicks, template) = auto_calibrate(&img, Some([301.0, 199.0])).unwrap();
        assert_eq!(clicks.edges.len(), 3, "{:?}", clicks.edges);
        assert_eq!(template.edges.len(), 3);
    }

    /// A wedge whose two edges both leave the frame is any corner of its angle: no
    /// template is made of it.
    #[test]
    fn a_corner_alone_is_refused() {
        let img = GrayImage::from_fn(400, 300, |x, y| {
            let (x, y) = (f64::from(x), f64::from(y));
            let inside = x <= 300.0 && (y - 150.0).abs() <= 0.3 * (300.0 - x);
            image::Luma([if inside { 200 } else { 60 }])
        });
        let err = auto_calibrate(&img, Some([300.0, 150.0]))
            .unwrap_err()
            .to_string();
        assert!(err.contains("an edge away from the tip point"), "{err}");
    }
}
