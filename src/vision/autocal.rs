//! Automatic calibration: the three tip edges found in the reference image from one
//! click on the apex (or, when the probe is the dominant body entering from a frame
//! side, from none), as points on each edge that then go through the ordinary
//! calibration ([`Calibration::from_reference`]). The result is a calibration like any
//! other: the same block printed, the same overlay for a person to confirm.
//!
//! From the apex:
//! 1. On a ring around it the pyramid is the one arc that stands out from the rest (of
//!    either polarity): its two ends are the two faces' directions.
//! 2. Each face is traced outward with profiles across it, the edge at the crossing of
//!    the mid level, until its step fades (where the face meets the beam); a line
//!    through the crossings.
//! 3. Along the pyramid's axis the probe ends at the beam's upper face (red). Its
//!    direction is the one along which the step is strongest; it is traced both ways.
//! 4. The front face is the steeper one: where the two faces' lines meet the beam's,
//!    its base lies nearer the apex's foot, so the other is the back face (blue,
//!    towards the clamp) and the front face green, as the calibration reads them. Only
//!    when the two bases lie about as far from the foot does the beam decide: it runs
//!    much further towards the clamp (usually out of the frame) than to the free end.
//!    A beam edge that the faces run past is not the beam's upper face, and refused.
//!
//! Where that gives no calibration (beside the apex the probe is as bright as its
//! ground, so the ring does not show the pyramid), the faces are looked for again as
//! the two rays from the apex with the strongest steps along them over 6-150 px, of
//! opposite sides and one polarity; each is traced both ways from its strongest
//! stretch and must run over a third of its length (apex to beam), the ground's level
//! for the beam's edge is taken outside the faces, and the rest is as above.
//!
//! Without a click, the apex is the point of the largest body touching a frame side
//! (grey levels above Otsu's level, or above the level splitting the bright class, the
//! probe being the brightest) farthest from its beam's axis.

use std::collections::VecDeque;

use image::GrayImage;

use super::calibration::SYMMETRIC_BASES;
use super::geometry::{add, bilinear, dot, norm, principal_axis, scale, sub, unit, Line};
use super::options::{CalibrationConfig, TrackerConfig};
use super::pyramid::otsu_from;
use super::{Calibration, VisionError};

/// Radius of the ring around the apex on which the pyramid's arc is found, pixels.
pub(super) const RING_PX: f64 = 10.0;
/// Angular samples on the ring.
const RING_SAMPLES: usize = 720;
/// Narrowest and widest pyramid arc, degrees.
const ARC_DEG: (f64, f64) = (8.0, 150.0);
/// A profile across an edge: its levels averaged between these depths (pixels) on
/// each side, the crossing searched within the outer one.
pub(super) const LEVEL_PX: (f64, f64) = (1.5, 4.0);
/// The stretch of the rays from the apex (pixels) over which their steps are averaged
/// when the ring does not show the pyramid, and how far either side of a ray its levels
/// are taken.
const RAYS_PX: (usize, usize) = (6, 150);
const RAY_SIDE_PX: f64 = 1.5;
/// The weakest mean step along a face found on the rays, grey levels.
const MIN_STEP: f64 = 4.0;
/// Share of its length (apex to the beam's upper face) over which a face found on the
/// rays must be traced.
const MIN_FACE_SHARE: f64 = 1.0 / 3.0;
/// How far outside a face the ground's level is taken, pixels.
const GROUND_PX: f64 = 4.0;
/// Where the faces' tracing starts, pixels from the apex (the wedge is narrow nearer).
pub(super) const FACE_START_PX: f64 = 6.0;
/// A profile counts while its step is at least this share of the edge's first steps;
/// the tracing stops after [`MISSES`] profiles in a row that do not.
const STEP_SHARE: f64 = 0.5;
const MISSES: usize = 3;
/// A crossing this far from the traced line is not taken, pixels.
const MAX_CROSSING_PX: f64 = 2.5;
/// Crossings this far from the line fitted to them are another edge (a face turning
/// into the beam at a corner), pixels.
const INLIER_PX: f64 = 0.75;
/// Shortest edge traced, pixels.
const MIN_EDGE_PX: f64 = 5.0;
/// Half-length (pixels) over which a direction of the red edge is scored.
const RED_SCORE_PX: f64 = 20.0;

/// Why the edges could not be found.
#[derive(Debug, thiserror::Error)]
pub enum AutoCalError {
    #[error("auto-calibration: {edges} not found near the apex ({reason})")]
    NotFound { edges: &'static str, reason: String },
    #[error("auto-calibration: no probe entering from a frame side ({0}); give --apex X,Y")]
    NoProbe(String),
    #[error("auto-calibration: {0}")]
    Calibration(#[from] VisionError),
}

/// Three points on each edge, found from the apex (frame pixels, the conventions' origin).
#[derive(Debug, Clone, PartialEq)]
pub struct AutoClicks {
    pub red: Vec<[f64; 2]>,
    pub blue: Vec<[f64; 2]>,
    pub green: Vec<[f64; 2]>,
}

impl AutoClicks {
    /// The clicks as `[tracker.calibration]` holds them.
    pub fn config(&self, reference_image: std::path::PathBuf) -> CalibrationConfig {
        CalibrationConfig::pyramid(
            reference_image,
            self.red.clone(),
            self.blue.clone(),
            self.green.clone(),
        )
    }
}

/// Finds the edges from `apex` (or, if `None`, from the probe entering from a side)
/// and calibrates on them.
pub fn auto_calibrate(
    reference: &GrayImage,
    apex: Option<[f64; 2]>,
    cfg: &TrackerConfig,
) -> Result<(AutoClicks, Calibration), AutoCalError> {
    let apex = match apex {
        Some(a) => a,
        None => find_apex(reference)?,
    };
    let calibrate = |search: Search| -> Result<(AutoClicks, Calibration), AutoCalError> {
        let clicks = clicks_by(reference, apex, search)?;
        let config = clicks.config("reference".into());
        let calibration = Calibration::from_reference(reference, &config, cfg)?;
        Ok((clicks, calibration))
    };
    // The rays only where the ring does not give a calibration; its reason is the one
    // reported when neither does.
    calibrate(Search::Ring).or_else(|ring| calibrate(Search::Rays).map_err(|_| ring))
}

/// How the pyramid's faces are looked for around the apex.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Search {
    /// The arc that stands out on a ring of [`RING_PX`] around the apex; each face
    /// traced from the apex outward.
    Ring,
    /// The two rays from the apex with the strongest steps along them, over
    /// [`RAYS_PX`] (where the probe beside the apex is as bright as its ground); each
    /// face traced both ways from its strongest stretch.
    Rays,
}

/// The normal of direction `d` turned towards `towards` (relative to `d`'s origin).
pub(super) fn normal_towards(d: [f64; 2], towards: [f64; 2]) -> [f64; 2] {
    let n = [-d[1], d[0]];
    if dot(n, towards) < 0.0 {
        scale(n, -1.0)
    } else {
        n
    }
}

/// The pyramid's arc on the ring around `apex`: the two faces' directions (image
/// angles, radians), the polarity (+1 bright probe) and the probe's and background's
/// levels.
pub(super) struct Wedge {
    pub(super) ends: [f64; 2],
    pub(super) polarity: f64,
    /// Where along each face (pixels from the apex) its step is strongest.
    strongest: [f64; 2],
}

fn wedge(img: &GrayImage, apex: [f64; 2]) -> Result<Wedge, AutoCalError> {
    wedge_on(img, apex, RING_PX)
}

/// [`wedge`] on a ring of radius `ring_px`.
pub(super) fn wedge_on(
    img: &GrayImage,
    apex: [f64; 2],
    ring_px: f64,
) -> Result<Wedge, AutoCalError> {
    let not_found = |reason: String| AutoCalError::NotFound {
        edges: "blue and green edges",
        reason,
    };
    let step = std::f64::consts::TAU / RING_SAMPLES as f64;
    let mut ring = Vec::with_capacity(RING_SAMPLES);
    for k in 0..RING_SAMPLES {
        let u = unit(k as f64 * step);
        let mut sum = 0.0;
        for dr in [-2.0, -1.0, 0.0, 1.0, 2.0] {
            let v = bilinear(img, add(apex, scale(u, ring_px + dr)));
            sum += v.ok_or_else(|| {
                not_found(format!(
                    "the apex ({:.1}, {:.1}) is within {ring_px} px of the border",
                    apex[0], apex[1]
                ))
            })?;
        }
        ring.push(sum / 5.0);
    }
    let mut sorted = ring.clone();
    sorted.sort_by(f64::total_cmp);
    let (lo, hi) = (sorted[RING_SAMPLES / 10], sorted[RING_SAMPLES * 9 / 10]);
    let mid = 0.5 * (lo + hi);
    // The pyramid opens by less than ARC_DEG.1 (150 deg): it is the minority of the
    // ring, brighter or darker than the rest. A textured ground has arcs of either
    // polarity; the background's own arc is the majority. The best arc of the
    // pyramid's polarity (largest sum of levels beyond the mid level; the ring is
    // circular, so it is scanned twice round).
    let above = ring.iter().filter(|&&v| v > mid).count();
    let pyramid = if 2 * above <= RING_SAMPLES { 1.0 } else { -1.0 };
    let mut best: Option<(f64, usize, usize, f64)> = None;
    for polarity in [pyramid] {
        let (mut sum, mut start) = (0.0, 0);
        for i in 0..2 * RING_SAMPLES {
            let v = polarity * (ring[i % RING_SAMPLES] - mid);
            if sum <= 0.0 {
                sum = 0.0;
                start = i;
            }
            sum += v;
            let len = i + 1 - start;
            let width_deg = (len as f64 * step).to_degrees();
            if len <= RING_SAMPLES
                && (ARC_DEG.0..=ARC_DEG.1).contains(&width_deg)
                && best.is_none_or(|b| sum > b.0)
            {
                best = Some((sum, start, i, polarity));
            }
        }
    }
    let Some((_, start, end, polarity)) = best else {
        return Err(not_found(format!(
            "no arc of {}-{} deg stands out on a ring of {ring_px} px around ({:.1}, {:.1}); \
             levels {lo:.0}-{hi:.0}",
            ARC_DEG.0, ARC_DEG.1, apex[0], apex[1]
        )));
    };
    if hi - lo < 8.0 {
        return Err(not_found(format!(
            "the ring around ({:.1}, {:.1}) is flat (levels {lo:.0}-{hi:.0})",
            apex[0], apex[1]
        )));
    }
    // The arc's ends at half a sample outside its first and last samples.
    let ends = [(start as f64 - 0.5) * step, (end as f64 + 0.5) * step];
    Ok(Wedge {
        ends,
        polarity,
        strongest: [FACE_START_PX; 2],
    })
}

/// The step across the ray from `apex` at `angle` (radians) at each whole pixel `along`
/// it ([`RAYS_PX`] for the pyramid's faces): the level [`RAY_SIDE_PX`]
/// counter-clockwise (in image angles) of it less the level as far clockwise; `None`
/// where outside the image.
pub(super) fn ray_steps(
    img: &GrayImage,
    apex: [f64; 2],
    angle: f64,
    along: std::ops::Range<usize>,
) -> Vec<Option<f64>> {
    let u = unit(angle);
    let n = scale([-u[1], u[0]], RAY_SIDE_PX);
    along
        .map(|r| {
            let p = add(apex, scale(u, r as f64));
            Some(bilinear(img, add(p, n))? - bilinear(img, sub(p, n))?)
        })
        .collect()
}

/// The pyramid as the two rays from `apex` with the strongest steps along them (the
/// mean over [`RAYS_PX`]), opening by [`ARC_DEG`], the probe's side of each where the
/// other ray is and of one polarity: in image angles, the probe is brighter (or
/// darker) counter-clockwise of the first and clockwise of the second.
pub(super) fn rays(img: &GrayImage, apex: [f64; 2]) -> Result<Wedge, AutoCalError> {
    let step = std::f64::consts::TAU / RING_SAMPLES as f64;
    let mean_step: Vec<f64> = (0..RING_SAMPLES)
        .map(|k| {
            let steps: Vec<f64> = ray_steps(img, apex, k as f64 * step, RAYS_PX.0..RAYS_PX.1)
                .into_iter()
                .flatten()
                .collect();
            if 2 * steps.len() < RAYS_PX.1 - RAYS_PX.0 {
                0.0
            } else {
                steps.iter().sum::<f64>() / steps.len() as f64
            }
        })
        .collect();
    let widths = (ARC_DEG.0.to_radians() / step).ceil() as usize
        ..=(ARC_DEG.1.to_radians() / step).floor() as usize;
    let mut best: Option<(f64, usize, usize, f64)> = None;
    for polarity in [1.0, -1.0] {
        for first in 0..RING_SAMPLES {
            for width in widths.clone() {
                let second = (first + width) % RING_SAMPLES;
                let score = (polarity * mean_step[first]).min(-polarity * mean_step[second]);
                if best.is_none_or(|b| score > b.0) {
                    best = Some((score, first, first + width, polarity));
                }
            }
        }
    }
    let not_found = |reason: String| AutoCalError::NotFound {
        edges: "blue and green edges",
        reason,
    };
    let Some((_, first, second, polarity)) = best.filter(|b| b.0 >= MIN_STEP) else {
        return Err(not_found(format!(
            "no two rays from ({:.1}, {:.1}) have steps of {MIN_STEP} grey levels along them",
            apex[0], apex[1]
        )));
    };
    // Where along each ray its step is strongest, summed over FACE_START_PX either side.
    let strongest = [first, second].map(|k| {
        let sign = if k == first { polarity } else { -polarity };
        let steps: Vec<f64> = ray_steps(img, apex, k as f64 * step, RAYS_PX.0..RAYS_PX.1)
            .into_iter()
            .map(|v| sign * v.unwrap_or(0.0))
            .collect();
        let half = FACE_START_PX as usize;
        let window = |i: usize| -> f64 {
            steps[i.saturating_sub(half)..(i + half + 1).min(steps.len())]
                .iter()
                .sum()
        };
        let best = (0..steps.len())
            .max_by(|&a, &b| window(a).total_cmp(&window(b)))
            .unwrap_or(0);
        (RAYS_PX.0 + best) as f64
    });
    Ok(Wedge {
        ends: [first as f64 * step, second as f64 * step],
        polarity,
        strongest,
    })
}

/// The ground's level just outside the two faces, along their traced stretches.
fn ground_level(img: &GrayImage, faces: &[Traced; 2], axis: [f64; 2]) -> f64 {
    let mut levels = Vec::new();
    for f in faces {
        let out = scale(normal_towards(f.dir, sub(f.dir, axis)), GROUND_PX);
        let (a, b) = f.span;
        let mut t = a;
        while t <= b {
            if let Some(v) = bilinear(img, add(f.at(t), out)) {
                levels.push(v);
            }
            t += 1.0;
        }
    }
    levels.sort_by(f64::total_cmp);
    levels.get(levels.len() / 2).copied().unwrap_or(0.0)
}

/// One profile across an edge at `centre`, inward normal `n`: the crossing of the mid
/// level (signed offset along `n`, nearest to the centre) and the step.
fn crossing(img: &GrayImage, centre: [f64; 2], n: [f64; 2], polarity: f64) -> Option<(f64, f64)> {
    let d = [n[1], -n[0]];
    let at = |s: f64| -> Option<f64> {
        let p = add(centre, scale(n, s));
        Some(0.5 * (bilinear(img, add(p, scale(d, 0.5)))? + bilinear(img, sub(p, scale(d, 0.5)))?))
    };
    let (a, b) = LEVEL_PX;
    let mut inside = 0.0;
    let mut outside = 0.0;
    let mut k = 0.0;
    let mut s = a;
    while s <= b {
        inside += at(s)?;
        outside += at(-s)?;
        k += 1.0;
        s += 0.5;
    }
    let step = polarity * (inside - outside) / k;
    let mid = 0.5 * (inside + outside) / k;
    let mut best: Option<f64> = None;
    let mut s = -b;
    let mut prev = polarity * (at(s)? - mid);
    while s < b {
        let next = polarity * (at(s + 0.25)? - mid);
        if prev < 0.0 && next >= 0.0 {
            let x = s + 0.25 * prev / (prev - next);
            if best.is_none_or(|c| x.abs() < c.abs()) {
                best = Some(x);
            }
        }
        prev = next;
        s += 0.25;
    }
    Some((best?, step))
}

/// Traces an edge from `origin` along `dir` (inside towards `inside`), from `start`
/// pixels on: the crossings.
pub(super) fn trace(
    img: &GrayImage,
    origin: [f64; 2],
    dir: [f64; 2],
    inside: [f64; 2],
    polarity: f64,
    start: f64,
) -> Vec<[f64; 2]> {
    let n = normal_towards(dir, inside);
    let mut points: Vec<[f64; 2]> = Vec::new();
    let (mut first_steps, mut misses, mut t) = (Vec::new(), 0, start);
    let limit = (img.width() + img.height()) as f64;
    while t < limit && misses < MISSES {
        let centre = add(origin, scale(dir, t));
        let Some((x, step)) = crossing(img, centre, n, polarity) else {
            if bilinear(img, centre).is_none() {
                break;
            }
            misses += 1;
            t += 1.0;
            continue;
        };
        let reference = if first_steps.len() < 3 {
            first_steps.push(step);
            f64::NEG_INFINITY
        } else {
            let mut s = first_steps.clone();
            s.sort_by(f64::total_cmp);
            STEP_SHARE * s[1]
        };
        if step > reference.max(4.0) && x.abs() <= MAX_CROSSING_PX {
            points.push(add(centre, scale(n, x)));
            misses = 0;
        } else {
            misses += 1;
        }
        t += 1.0;
    }
    points
}

/// Total-least-squares line through points: a point on it and its direction.
fn fit_line(pts: &[[f64; 2]]) -> Option<([f64; 2], [f64; 2])> {
    if pts.len() < 3 {
        return None;
    }
    let (c, theta, _) = principal_axis(pts);
    Some((c, unit(theta)))
}

/// A traced edge: a point, its direction (from the apex or the corner outward), and
/// the traced span along it.
#[derive(Debug, Clone, Copy)]
pub(super) struct Traced {
    pub(super) point: [f64; 2],
    pub(super) dir: [f64; 2],
    pub(super) span: (f64, f64),
}

impl Traced {
    pub(super) fn at(&self, t: f64) -> [f64; 2] {
        add(self.point, scale(self.dir, t))
    }

    pub(super) fn length(&self) -> f64 {
        self.span.1 - self.span.0
    }

    /// The traced line.
    pub(super) fn line(&self) -> Line {
        Line::through(self.point, [-self.dir[1], self.dir[0]])
    }

    /// Points at the given shares of the traced span.
    pub(super) fn clicks(&self, shares: &[f64]) -> Vec<[f64; 2]> {
        let (a, b) = self.span;
        shares.iter().map(|f| self.at(a + f * (b - a))).collect()
    }
}

/// The line through traced points, directed like `dir`, with the points' span along it.
pub(super) fn traced(points: &[[f64; 2]], dir: [f64; 2]) -> Option<Traced> {
    let mut points = points.to_vec();
    let (mut c, mut d) = fit_line(&points)?;
    for _ in 0..3 {
        let normal = [-d[1], d[0]];
        points.retain(|p| dot(sub(*p, c), normal).abs() <= INLIER_PX);
        (c, d) = fit_line(&points)?;
    }
    let d = if dot(d, dir) < 0.0 { scale(d, -1.0) } else { d };
    let ts = points.iter().map(|p| dot(sub(*p, c), d));
    let span = ts.fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), t| {
        (a.min(t), b.max(t))
    });
    (span.1 - span.0 >= MIN_EDGE_PX).then_some(Traced {
        point: c,
        dir: d,
        span,
    })
}

/// The edges from a click near the apex.
pub fn clicks_from_apex(img: &GrayImage, apex: [f64; 2]) -> Result<AutoClicks, AutoCalError> {
    clicks_by(img, apex, Search::Ring)
}

/// The edges from a click near the apex, the faces looked for by `search`.
fn clicks_by(img: &GrayImage, apex: [f64; 2], search: Search) -> Result<AutoClicks, AutoCalError> {
    let w = match search {
        Search::Ring => wedge(img, apex)?,
        Search::Rays => rays(img, apex)?,
    };
    let dirs = w.ends.map(unit);
    let axis = {
        let s = add(dirs[0], dirs[1]);
        scale(s, 1.0 / norm(s).max(1e-9))
    };
    // The two faces, each traced with the wedge's inside towards the axis, twice: the
    // second time along the line the first found, from the apex it implies.
    let mut faces = [None; 2];
    for k in 0..2 {
        let inside = sub(axis, dirs[k]);
        let pts = match search {
            Search::Ring => trace(img, apex, dirs[k], inside, w.polarity, FACE_START_PX),
            Search::Rays => {
                let from = add(apex, scale(dirs[k], w.strongest[k]));
                let mut pts = trace(img, from, dirs[k], inside, w.polarity, 0.0);
                let back = trace(img, from, scale(dirs[k], -1.0), inside, w.polarity, 1.0);
                pts.extend(back);
                pts
            }
        };
        faces[k] = traced(&pts, dirs[k]);
    }
    let (Some(f0), Some(f1)) = (faces[0], faces[1]) else {
        return Err(AutoCalError::NotFound {
            edges: "a face of the pyramid",
            reason: format!(
                "the step along {} face fades within {MIN_EDGE_PX} px of the apex",
                if faces[0].is_none() {
                    "one"
                } else {
                    "the other"
                }
            ),
        });
    };
    let apex = f0.line().intersect(&f1.line()).unwrap_or(apex);
    let faces = match search {
        Search::Ring => [f0, f1].map(|f| {
            let inside = sub(axis, f.dir);
            let pts = trace(img, apex, f.dir, inside, w.polarity, FACE_START_PX);
            traced(&pts, f.dir).unwrap_or(f)
        }),
        // Their steps fade towards the apex: the lines stand as traced, each from near
        // the apex they imply to its far end.
        Search::Rays => [f0, f1].map(|f| Traced {
            span: (dot(sub(apex, f.point), f.dir) + FACE_START_PX, f.span.1),
            ..f
        }),
    };
    // The ground's level: beyond the apex, or (where the probe beside the apex is as
    // bright as its ground) outside the faces.
    let ground = match search {
        Search::Ring => None,
        Search::Rays => Some(ground_level(img, &faces, axis)),
    };
    let (red, exit) = red_edge(img, apex, axis, &faces, w.polarity, ground)?;
    if search == Search::Rays {
        // Faces found away from the apex must be traced over a good share of their
        // length, or the calibration would rest on a short stretch of them.
        let beam = red.line();
        for f in [f0, f1] {
            let length = beam
                .intersect(&f.line())
                .map_or(0.0, |base| norm(sub(base, apex)));
            if f.length() < MIN_FACE_SHARE * length {
                return Err(AutoCalError::NotFound {
                    edges: "a face of the pyramid",
                    reason: format!(
                        "on the rays from the apex a face's step runs over {:.0} px of its \
                         {length:.0}",
                        f.length()
                    ),
                });
            }
        }
    }
    let clamp_along_red = match back_face_side(&red, apex, &faces) {
        Some(side) => side > 0.0,
        // Faces as steep as each other: the beam runs further from the pyramid towards
        // the clamp than to the free end.
        None => {
            let t_exit = dot(sub(exit, red.point), red.dir);
            red.span.1 - t_exit >= t_exit - red.span.0
        }
    };
    let (clamp, free_t, clamp_t) = if clamp_along_red {
        (red.dir, red.span.0, red.span.1)
    } else {
        (scale(red.dir, -1.0), -red.span.1, -red.span.0)
    };
    let (blue, green) = if dot(faces[0].dir, clamp) >= dot(faces[1].dir, clamp) {
        (faces[0], faces[1])
    } else {
        (faces[1], faces[0])
    };
    // Red near the free end: from it towards the clamp, over twice the back face.
    let reach = (2.0 * (blue.span.1 - blue.span.0)).max(20.0);
    let beam = Traced {
        point: red.point,
        dir: clamp,
        span: (free_t, clamp_t.min(free_t + reach)),
    };
    // Faces found on the rays are clicked nearly end to end, so that the calibration
    // follows them over the stretch beside the apex where their steps fade.
    let shares = match search {
        Search::Ring => [0.2, 0.5, 0.8],
        Search::Rays => [0.05, 0.5, 0.95],
    };
    Ok(AutoClicks {
        red: beam.clicks(&[0.15, 0.5, 0.85]),
        blue: blue.clicks(&shares),
        green: green.clicks(&shares),
    })
}

/// Which way along `red.dir` the back face's base lies (+1 or -1), from where the two
/// faces' lines meet the beam's: the front face is the steeper one, so its base lies
/// nearer the apex's foot, on the free end's side (the calibration's rule, which does
/// not depend on how far the faces were traced). `None` when the two bases lie about
/// as far from the foot (within [`SYMMETRIC_BASES`]) or a face does not meet the beam.
fn back_face_side(red: &Traced, apex: [f64; 2], faces: &[Traced; 2]) -> Option<f64> {
    let beam = red.line();
    let foot = dot(sub(apex, red.point), red.dir);
    let base = |f: &Traced| Some(dot(sub(beam.intersect(&f.line())?, red.point), red.dir) - foot);
    let bases = [base(&faces[0])?, base(&faces[1])?];
    let (near, far) = if bases[0].abs() <= bases[1].abs() {
        (bases[0], bases[1])
    } else {
        (bases[1], bases[0])
    };
    (far.abs() - near.abs() >= SYMMETRIC_BASES * far.abs()).then_some(far.signum())
}

/// The beam's upper face: where the probe ends along the pyramid's axis, its direction
/// the strongest step's, traced both ways (span: negative one way, positive the other).
fn red_edge(
    img: &GrayImage,
    apex: [f64; 2],
    axis: [f64; 2],
    faces: &[Traced; 2],
    polarity: f64,
    ground: Option<f64>,
) -> Result<(Traced, [f64; 2]), AutoCalError> {
    let not_found = |reason: String| AutoCalError::NotFound {
        edges: "red edge",
        reason,
    };
    let side = [-axis[1], axis[0]];
    let level = |t: f64| -> Option<f64> {
        let c = add(apex, scale(axis, t));
        let mut sum = 0.0;
        for s in [-1.0, 0.0, 1.0] {
            sum += bilinear(img, add(c, scale(side, s)))?;
        }
        Some(sum / 3.0)
    };
    // The probe's level inside the pyramid, the background's beyond the apex.
    let start = FACE_START_PX.max(0.5 * faces[0].span.1.min(faces[1].span.1));
    let inside =
        level(start).ok_or_else(|| not_found("the pyramid runs out of the frame".into()))?;
    let outside = ground
        .or_else(|| level(-RING_PX))
        .unwrap_or(inside - polarity * 60.0);
    let mid = 0.5 * (inside + outside);
    let mut t = start;
    let exit = loop {
        let (Some(a), Some(b)) = (level(t), level(t + 0.25)) else {
            return Err(not_found(
                "the probe runs out of the frame along the pyramid's axis".into(),
            ));
        };
        // Out of the probe for good: three pixels beyond are background as well.
        if polarity * (a - mid) >= 0.0 && polarity * (b - mid) < 0.0 {
            let beyond = (1..=3)
                .all(|k| level(t + 0.25 + k as f64).is_some_and(|v| polarity * (v - mid) < 0.0));
            if beyond {
                break t + 0.25 * polarity * (a - mid) / (polarity * (a - b));
            }
        }
        t += 0.25;
    };
    let p = add(apex, scale(axis, exit));
    // The direction along which the step into the probe (towards the apex) is strongest.
    let mut best = (f64::NEG_INFINITY, [1.0, 0.0]);
    for k in 0..180 {
        let d = unit((k as f64).to_radians());
        let n = normal_towards(d, sub(apex, p));
        let mut score = 0.0;
        let mut s = -RED_SCORE_PX;
        while s <= RED_SCORE_PX {
            let c = add(p, scale(d, s));
            if let (Some(a), Some(b)) = (
                bilinear(img, add(c, scale(n, 2.5))),
                bilinear(img, sub(c, scale(n, 2.5))),
            ) {
                score += (polarity * (a - b)).max(0.0);
            }
            s += 1.0;
        }
        if score > best.0 {
            best = (score, d);
        }
    }
    let d = best.1;
    let inside = sub(apex, p);
    let mut pts = trace(img, p, d, inside, polarity, 0.0);
    let back = trace(img, p, scale(d, -1.0), inside, polarity, 1.0);
    pts.extend(back);
    let red = traced(&pts, d).ok_or_else(|| {
        not_found(format!(
            "no step along the beam's upper face at ({:.1}, {:.1})",
            p[0], p[1]
        ))
    })?;
    // The pyramid hangs below the beam's upper face: neither face runs past it.
    let beam = Line::through(red.point, normal_towards(red.dir, sub(apex, red.point)));
    if let Some(cut) = faces
        .iter()
        .map(|f| f.at(f.span.1))
        .find(|&end| beam.depth(end) < -MAX_CROSSING_PX)
    {
        return Err(not_found(format!(
            "the line traced through ({:.1}, {:.1}) cuts a face of the pyramid at \
             ({:.1}, {:.1}): it is not the beam's upper face",
            p[0], p[1], cut[0], cut[1]
        )));
    }
    Ok((red, p))
}

/// The apex of the largest body touching a frame side: its point farthest from the
/// beam's axis.
pub fn find_apex(img: &GrayImage) -> Result<[f64; 2], AutoCalError> {
    let mut why = String::new();
    for level in body_levels(img) {
        match entering_body(img, level) {
            Ok(body) => {
                let n = [-body.axis[1], body.axis[0]];
                let off = |p: &[f64; 2]| dot(n, sub(*p, body.centre)).abs();
                let apex = body
                    .pixels
                    .iter()
                    .copied()
                    .max_by(|a, b| off(a).total_cmp(&off(b)));
                return Ok(apex.unwrap_or(body.centre));
            }
            Err(e) => why = e,
        }
    }
    Err(AutoCalError::NoProbe(why))
}

/// The levels a body is looked for above: the one splitting the bright class, then
/// Otsu's level over all grey levels (the probe being the brightest).
pub fn body_levels(img: &GrayImage) -> [usize; 2] {
    let hist = histogram(img);
    let all = otsu_from(&hist, 0);
    [otsu_from(&hist, all + 1), all]
}

/// The grey levels' histogram.
fn histogram(img: &GrayImage) -> [u32; 256] {
    let mut hist = [0u32; 256];
    for p in img.pixels() {
        hist[p[0] as usize] += 1;
    }
    hist
}

/// The largest body touching a frame side, and the axis it enters along.
pub struct EnteringBody {
    /// Its pixels' centres.
    pub pixels: Vec<[f64; 2]>,
    /// A point on its axis, and the axis's direction into the frame from the side it
    /// enters from (a unit vector).
    pub centre: [f64; 2],
    pub axis: [f64; 2],
}

/// The largest body above `level` touching a frame side: its pixels and the axis
/// through those within a fifth of its depth from the side it touches most.
pub fn entering_body(img: &GrayImage, level: usize) -> Result<EnteringBody, String> {
    entering_bodies(img, level, 1).map(|mut bodies| bodies.swap_remove(0))
}

/// The `most` largest bodies above `level` touching a frame side, largest first (as
/// [`entering_body`]); an error when none is of a probe's size.
pub fn entering_bodies(
    img: &GrayImage,
    level: usize,
    most: usize,
) -> Result<Vec<EnteringBody>, String> {
    let (w, h) = (img.width() as usize, img.height() as usize);
    let raw = img.as_raw();
    let on = |i: usize| raw[i] as usize > level;
    let mut label = vec![0u32; w * h];
    let mut found: Vec<Vec<usize>> = Vec::new();
    let mut queue = VecDeque::new();
    let mut next = 0;
    for seed in 0..w * h {
        if label[seed] != 0 || !on(seed) {
            continue;
        }
        next += 1;
        let mut body = Vec::new();
        label[seed] = next;
        queue.push_back(seed);
        while let Some(i) = queue.pop_front() {
            body.push(i);
            let (x, y) = (i % w, i / w);
            let mut visit = |j: usize| {
                if label[j] == 0 && on(j) {
                    label[j] = next;
                    queue.push_back(j);
                }
            };
            if x > 0 {
                visit(i - 1);
            }
            if x + 1 < w {
                visit(i + 1);
            }
            if y > 0 {
                visit(i - w);
            }
            if y + 1 < h {
                visit(i + w);
            }
        }
        let touches = body.iter().any(|&i| {
            let (x, y) = (i % w, i / w);
            x == 0 || y == 0 || x == w - 1 || y == h - 1
        });
        if touches {
            found.push(body);
        }
    }
    found.sort_by_key(|b| std::cmp::Reverse(b.len()));
    let Some(largest) = found.first() else {
        return Err(format!("nothing above grey level {level} touches a side"));
    };
    if largest.len() < (w * h) / 500 {
        return Err(format!(
            "the largest body above grey level {level} touching a side has {} pixels",
            largest.len()
        ));
    }
    Ok(found
        .iter()
        .take(most)
        .take_while(|b| b.len() >= (w * h) / 500)
        .map(|b| with_axis(b, w, h))
        .collect())
}

/// A body's pixels (indices into a `w` x `h` frame) and the axis through those within
/// a fifth of its depth from the side it touches most.
fn with_axis(body: &[usize], w: usize, h: usize) -> EnteringBody {
    let pixels: Vec<[f64; 2]> = body
        .iter()
        .map(|&i| [(i % w) as f64, (i / w) as f64])
        .collect();
    let sides = [[1.0, 0.0], [-1.0, 0.0], [0.0, 1.0], [0.0, -1.0]];
    let depth = |s: usize, p: [f64; 2]| match s {
        0 => p[0],
        1 => (w - 1) as f64 - p[0],
        2 => p[1],
        _ => (h - 1) as f64 - p[1],
    };
    let side = (0..4)
        .max_by_key(|&s| pixels.iter().filter(|&&p| depth(s, p) < 0.5).count())
        .unwrap_or(0);
    let reach = pixels.iter().map(|&p| depth(side, p)).fold(0.0, f64::max);
    let near: Vec<[f64; 2]> = pixels
        .iter()
        .copied()
        .filter(|&p| depth(side, p) <= 0.2 * reach)
        .collect();
    let (centre, d) = fit_line(&near).unwrap_or((pixels[0], [-sides[side][1], sides[side][0]]));
    let axis = if dot(d, sides[side]) < 0.0 {
        scale(d, -1.0)
    } else {
        d
    };
    EnteringBody {
        pixels,
        centre,
        axis,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_flat_image_has_no_pyramid() {
        let img = GrayImage::from_pixel(100, 80, image::Luma([90]));
        let err = clicks_from_apex(&img, [50.0, 40.0]).unwrap_err();
        assert!(err.to_string().contains("not found near the apex"), "{err}");
    }
}
