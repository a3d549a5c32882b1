//! The beam: the scale at which the frame shows the beam edge when the fit placed the
//! tip from its faces alone, the scale that puts it out of view, and, with the beam
//! edge found, the beam's lower face behind the pyramid and its free end, which tell
//! a beam of another thickness from this probe's.

use image::GrayImage;

use super::sampling::{
    clip_inside, grey, profile, station_span, unit_step, Profile, Sampling, HELD_SHARE,
    MIN_CHECKED_PX, RED_SLACK, STATIONS,
};
use crate::vision::geometry::{add, dot, norm, scale, sub, Line};
use crate::vision::template::{Pose, Template, BLUE, GREEN, RED};
use crate::vision::{Edge, Miss};

/// A beam edge looked for over every scale ([`beam_edge_scale`]) is taken where its
/// median step is at least this share of the calibrated one.
const FOUND_RATIO: f64 = 0.5;
/// That search first tries every this many pixels of the beam edge's distance from
/// the apex, and every pixel around those whose median step reaches [`SCAN_RATIO`].
const SCAN_STEP_PX: i64 = 5;
const SCAN_RATIO: f64 = 0.3;

/// The beam edge's distance from the apex per unit of scale, reference pixels; `None`
/// for a template whose beam edge passes through the apex (no scale moves it).
fn beam_distance_per_scale(t: &Template) -> Option<f64> {
    let per_scale = t.edges[RED].offset.abs();
    (per_scale >= 1e-9).then_some(per_scale)
}

/// The scale at which the frame shows the beam edge, for a tip the fit placed from
/// its two faces alone and refused there: the faces fix the apex and the rotation,
/// and the scale only moves the beam edge parallel to itself, away from the apex.
/// When the faces fade into a bright background before their bases, their visible
/// length says little of the scale, and the beam edge may lie anywhere its line
/// crosses the frame. Every pixel of that distance is tried, with the free end in
/// view: the line is taken where it passes the beam edge's own checks
/// ([`Profile::refusal`]) with the largest median step, at least [`FOUND_RATIO`] of
/// the calibrated one. The caller fits and verifies the tip again at that scale;
/// nothing is accepted here.
pub fn beam_edge_scale(
    frame: &GrayImage,
    t: &Template,
    pose: &Pose,
    blur_px: f64,
    red_step: f64,
) -> Option<f64> {
    let size = [frame.width() as f64, frame.height() as f64];
    let per_scale = beam_distance_per_scale(t)?;
    let unit = Pose {
        scale: 1.0,
        ..*pose
    };
    let away = t.line(&unit, RED);
    // The farthest the line can lie from the apex and still cross the frame.
    let corners = [
        [0.0, 0.0],
        [size[0] - 1.0, 0.0],
        [0.0, size[1] - 1.0],
        [size[0] - 1.0, size[1] - 1.0],
    ];
    let sign = away.depth(pose.apex).signum();
    let farthest = corners
        .iter()
        .map(|&c| -sign * (away.depth(c) - away.depth(pose.apex)))
        .fold(0.0, f64::max);
    // The line's profile at `d` pixels from the apex, with the free end in view.
    let at_depth = |d: i64| -> Option<(f64, Profile)> {
        let at = Pose {
            scale: d as f64 / per_scale,
            ..*pose
        };
        let s = Sampling::at_pose(t, &at, blur_px);
        let red = t.line(&at, RED);
        let Some((a, b, true)) = station_span(t, &at, RED, size, &s) else {
            return None;
        };
        let mut p = profile(frame, &red, (a, b), None, &s, red_step);
        p.corner_in_view = true;
        Some((at.scale, p))
    };
    // Every SCAN_STEP_PX pixels first (the samples lie clear of the blurred step, so
    // a line a pixel off the edge shows most of its step), then every pixel around
    // the lines that show part of it.
    // The largest median step, and the run of distances that show it (a sharp edge
    // shows its whole step over a few pixels: the middle of the run is taken).
    let mut best: Option<(f64, i64, i64)> = None;
    for coarse in (SCAN_STEP_PX..=farthest.floor() as i64).step_by(SCAN_STEP_PX as usize) {
        if at_depth(coarse).is_none_or(|(_, p)| p.step_ratio() < SCAN_RATIO) {
            continue;
        }
        for d in coarse - SCAN_STEP_PX / 2..=coarse + SCAN_STEP_PX / 2 {
            let Some((_, p)) = at_depth(d) else {
                continue;
            };
            let ratio = p.step_ratio();
            if ratio < FOUND_RATIO || p.refusal(Edge::Red).is_some() {
                continue;
            }
            best = match best {
                Some((r, first, last)) if ratio == r && d == last + 1 => Some((r, first, d)),
                Some((r, ..)) if ratio <= r => best,
                _ => Some((ratio, d, d)),
            };
        }
    }
    best.map(|(_, first, last)| 0.5 * (first + last) as f64 / per_scale)
}

/// The smallest scale above `pose`'s at which the beam edge lies out of view, for a tip
/// the fit placed from its two faces alone and refused for its beam edge: the faces fix
/// the apex and the rotation, and when they run out of the frame nothing in view fixes
/// the scale. A scale that puts the beam edge inside the frame where the frame does not
/// show it is contradicted; one that puts it beyond the border, within its slack, is
/// not. The caller verifies the tip again at that scale (where a face ending in view
/// still pins the scale, [`face_ends`](super::faces::face_ends)); nothing is accepted
/// here. `None` when the beam edge's line crosses the frame at every scale.
pub fn beam_out_of_view_scale(
    frame: &GrayImage,
    t: &Template,
    pose: &Pose,
    blur_px: f64,
) -> Option<f64> {
    let size = [frame.width() as f64, frame.height() as f64];
    let per_scale = beam_distance_per_scale(t)?;
    // The nearest the beam edge may lie to its predicted line is the slack's share
    // closer to the apex: its whole stretch, so placed, must be out of view.
    let nearer = 1.0 - RED_SLACK;
    let (free_tau, bend_tau) = t.red_near_tip(0.0);
    let out_of_view = |d: f64| {
        let at = Pose {
            scale: nearer * d / per_scale,
            ..*pose
        };
        let pad = Sampling::at_pose(t, &at, blur_px).reach() + 1.0;
        // The stretch the beam edge's stations cover (as `station_span`), before trims.
        let red = &t.edges[RED];
        let (a, b) = (
            t.place(&at, red.point(free_tau)),
            t.place(&at, red.point(bend_tau)),
        );
        let len = norm(sub(b, a));
        len < 1e-9
            || clip_inside(a, scale(sub(b, a), 1.0 / len), size, pad)
                .is_none_or(|(lo, hi)| hi < 0.0 || lo > len)
    };
    let from = (pose.scale * per_scale).ceil() as i64 + 1;
    let to = (from as f64 + size[0].hypot(size[1]) / nearer).ceil() as i64;
    (from..=to)
        .map(|d| d as f64)
        .find(|&d| out_of_view(d))
        .map(|d| d / per_scale)
}

/// How far behind the back face's base the lower face is checked, in tip heights:
/// beyond, the bending beam leaves the straight line by pixels at high magnification.
const LOWER_FACE_HEIGHTS: f64 = 0.3;

/// The beam's lower face behind the pyramid, where calibration measured the beam's
/// thickness: parallel to the beam edge, that thickness below it, from the back face's
/// base towards the clamp for [`LOWER_FACE_HEIGHTS`] tip heights. A beam of another
/// thickness has the surroundings (thinner) or the beam (thicker) on both sides of it
/// there: refused as `Miss::ScaleMismatch` when more than 3 of its stations show
/// nothing. Measured from `red`, the beam edge where the frame shows it: fitted, or
/// found within the slack with all of that slack in view when the fit left it out
/// (placed from the faces alone, its distance is known to a few per cent, pixels at
/// high magnification, and one found where the slack leaves the frame may be another
/// line); not checked where the beam is too thin at this scale for both sample runs, or
/// too little of that stretch is in view.
pub(super) fn lower_face(
    frame: &GrayImage,
    t: &Template,
    pose: &Pose,
    red: &Line,
    s: &Sampling,
    red_step: f64,
) -> Option<Miss> {
    let beam_px = t.beam_px? * pose.scale;
    if beam_px < 2.0 * s.margin_px + 2.0 {
        return None;
    }
    let (tip, far) = t.segment(pose, RED);
    let len = norm(sub(far, tip));
    if len < 1e-9 {
        return None;
    }
    let dir = [(far[0] - tip[0]) / len, (far[1] - tip[1]) / len];
    let (line, sampling) = lower_face_line(red, beam_px, s);
    // The back face's base's foot on the lower face.
    let foot = line.foot(t.segment(pose, BLUE).1);
    let pad = sampling.reach() + 1.0;
    let size = [frame.width() as f64, frame.height() as f64];
    let (a, b) = clip_inside(foot, dir, size, pad)?;
    let (a0, b0) = (
        a.max(pad),
        b.min(LOWER_FACE_HEIGHTS * pose.scale * t.height),
    );
    if b0 - a0 < MIN_CHECKED_PX {
        return None;
    }
    let at = |d: f64| [foot[0] + d * dir[0], foot[1] + d * dir[1]];
    let p = profile(frame, &line, (at(a0), at(b0)), None, &sampling, red_step);
    let missing = (0..p.stations).filter(|&k| !p.held(k)).count();
    if p.stations < STATIONS || (missing as f64) > (1.0 - HELD_SHARE) * STATIONS as f64 {
        return Some(Miss::ScaleMismatch);
    }
    None
}

/// The beam's lower face, `beam_px` below the beam edge `red` and parallel to it (its
/// inward normal up into the beam), and the sampling whose inside runs stay within
/// the beam.
fn lower_face_line(red: &Line, beam_px: f64, s: &Sampling) -> (Line, Sampling) {
    let normal = [-red.normal[0], -red.normal[1]];
    let line = Line {
        normal,
        rho: -(red.rho + beam_px),
    };
    let sampling = Sampling {
        inside_px: (beam_px - 2.0 * s.margin_px).clamp(1.0, 3.0),
        ..*s
    };
    (line, sampling)
}

/// How far inside the true free end calibration places it, as a share of the tip
/// height: it follows the beam edge until its step fades into the corner (measured on
/// rendered references: up to 3.2 %).
const FREE_END_SHORT: f64 = 0.05;
/// The free end, and a station of the overhang, show the probe's step from this share
/// of the beam edge's calibrated step (genuine overhangs step by about 0.4 of it, the
/// overhang of a beam of another thickness by 0.15 at most).
const END_RATIO: f64 = 0.2;
/// Fewer stations than this (of [`STATIONS`]) showing the overhang's step leave it to
/// the end face below it to tell a beam of another thickness.
const OVERHANG_SHOWN: usize = 3;
/// Shortest stretch of the overhang that is checked, pixels.
const MIN_OVERHANG_PX: f64 = 4.0;
/// Behind an overhang too short to check, the end face below the corner is judged on
/// the stations whose samples on the beam's side lie clear of the front face, when at
/// least this many (half of [`STATIONS`]) do.
const SHORT_OVERHANG_STATIONS: usize = STATIONS / 2;
/// Half width of the runs either side of a candidate end face, pixels.
const END_RUN_PX: usize = 3;
/// Rows of the beam's band averaged at each position of the end face's search.
const END_ROWS: usize = 6;
/// How deep below the beam edge, in beam thicknesses, the end face's line is followed
/// past the block's corner, each depth judged alone. A beam thicker by a factor f
/// moves the apex as well, and with it the scale: its end face reaches
/// f (T + H) / (f T + H) beam thicknesses at that scale (T the beam's thickness, H the
/// tip's height), 1.5-1.75 for a beam twice as thick under a tip 2-6 times taller than
/// it, which shows along the first half of the full second thickness but not along
/// 70 % of it.
const END_FACE_DEPTHS: [f64; 2] = [2.0, 1.5];
/// Longest search for the end face, pixels either way (the samples live on the stack).
const END_SEARCH_MAX: usize = 120;

/// The block's free end, where a beam of another thickness shows even with the back
/// face's base out of view. The rigid block ends a short overhang beyond the front
/// face's base. With the beam edge found (the scale, hence the lower face's depth,
/// known to a pixel) and the free end located in the frame near where the pose puts
/// it ([`locate_end`]), a thicker beam shows twice: the overhang's lower face, from
/// where the front face's line meets it to the free end, steps on fewer than
/// [`OVERHANG_SHOWN`] stations (the beam lies on both sides of it), and the end face's
/// step carries on below the corner, over the next beam thickness or its first half
/// ([`END_FACE_DEPTHS`]), on [`HELD_SHARE`] of its stations (those a particle brighter
/// than the beam covers beside it not counted; at least [`SHORT_OVERHANG_STATIONS`]
/// counted). Refused as `Miss::ScaleMismatch` when both hold: a particle at the
/// probe's level at the free end hides the overhang and steps beside the end face's
/// line, but not along that much of it. An overhang too short to check leaves the end
/// face alone to tell, on the stations whose samples on the beam's side lie clear of
/// the front face (at least [`SHORT_OVERHANG_STATIONS`]). The free end itself is not
/// refused when its step is missing: a bright textured background beyond it takes
/// the step away as often as a beam running on.
pub(super) fn free_end(
    frame: &GrayImage,
    t: &Template,
    pose: &Pose,
    red: &Line,
    s: &Sampling,
    red_step: f64,
) -> Option<Miss> {
    let (tip, far) = t.segment(pose, RED);
    let len = norm(sub(tip, far));
    if len < 1e-9 {
        return None;
    }
    // Along the beam, out of its free end.
    let out = [(tip[0] - far[0]) / len, (tip[1] - far[1]) / len];
    let free = red.foot(tip);
    let beam_px = t.beam_px? * pose.scale;
    let depths = (s.margin_px, beam_px - s.margin_px);
    if depths.1 - depths.0 < 1.0 {
        return None;
    }
    let reach = FREE_END_SHORT * t.height * pose.scale + 2.0;
    let (at, step) = locate_end(frame, red, free, out, depths, reach, red_step)?;
    if step < END_RATIO {
        return None;
    }
    let (lower, lower_sampling) = lower_face_line(red, beam_px, s);
    let base = lower.intersect(&t.line(pose, GREEN))?;
    let end = add(free, scale(out, at));
    let overhang = dot(sub(end, base), out);
    let sampling = Sampling {
        inside_px: 3.0,
        ..*s
    };
    // The overhang's lower face, from where the front face's line meets it to the end,
    // where it is long enough to keep the pyramid clear of the samples behind the end
    // face's line.
    let (a0, b0) = (2.0, overhang - 2.0);
    let short = overhang < sampling.reach() + 2.0 || b0 - a0 < MIN_OVERHANG_PX;
    let shown = |p: &Profile| (0..p.stations).filter(|&k| p.ratio[k] >= END_RATIO).count();
    if !short {
        let p = profile(
            frame,
            &lower,
            (add(base, scale(out, a0)), add(base, scale(out, b0))),
            None,
            &lower_sampling,
            red_step,
        );
        if p.stations < STATIONS || shown(&p) >= OVERHANG_SHOWN {
            return None;
        }
    }
    // Below the block's corner, along the end face's line: the surroundings on both
    // sides for this probe, the rest of the end face for a thicker beam. Behind a
    // short overhang the front face runs along that line: the samples on the beam's
    // side are taken only clear of the front face's predicted line.
    let face = Line::through(end, [-out[0], -out[1]]);
    let size = [frame.width() as f64, frame.height() as f64];
    let (c0, c1) = clip_inside(end, red.normal, size, sampling.reach() + 1.0)?;
    let front = t.line(pose, GREEN);
    let clear_of_front = Line {
        normal: scale(front.normal, -1.0),
        rho: -front.rho,
    };
    let judged = if short {
        SHORT_OVERHANG_STATIONS
    } else {
        STATIONS
    };
    let runs_on = |depth: f64| {
        let (a0, b0) = (
            (beam_px + s.margin_px + 2.0).max(c0),
            (depth * beam_px).min(c1),
        );
        if b0 - a0 < MIN_CHECKED_PX {
            return false;
        }
        let q = profile(
            frame,
            &face,
            (
                add(end, scale(red.normal, a0)),
                add(end, scale(red.normal, b0)),
            ),
            short.then_some(&clear_of_front),
            &sampling,
            red_step,
        );
        // A station whose far side a particle brighter than the beam covers, while
        // its beam side keeps the beam's level, says nothing either way.
        let level = q.held_level();
        let counted = (0..q.stations).filter(|&k| !q.covered(k, level)).count();
        q.stations >= judged
            && counted >= SHORT_OVERHANG_STATIONS
            && shown(&q) as f64 >= HELD_SHARE * counted as f64
    };
    END_FACE_DEPTHS
        .into_iter()
        .any(runs_on)
        .then_some(Miss::ScaleMismatch)
}

/// Where the beam's band (`depths` below `red`) steps from the probe to the
/// surroundings along `out`, within `reach` of `free`: the position (pixels along `out`
/// from `free`) of the largest step between runs of [`END_RUN_PX`] either side, and
/// that step over the calibrated one. `None` when the band leaves the frame there.
pub(super) fn locate_end(
    frame: &GrayImage,
    red: &Line,
    free: [f64; 2],
    out: [f64; 2],
    depths: (f64, f64),
    reach: f64,
    red_step: f64,
) -> Option<(f64, f64)> {
    let half = (reach.ceil() as usize).min(END_SEARCH_MAX);
    let n = 2 * (half + END_RUN_PX) + 1;
    let mut level = [0.0; 2 * (END_SEARCH_MAX + END_RUN_PX) + 1];
    // At most END_ROWS rows, evenly over the band.
    let rows = (0..END_ROWS)
        .map(|r| depths.0 + (depths.1 - depths.0) * (r as f64 + 0.5) / END_ROWS as f64);
    let count = END_ROWS as f64;
    for (i, v) in level[..n].iter_mut().enumerate() {
        let x = i as f64 - (half + END_RUN_PX) as f64;
        let mut sum = 0.0;
        for d in rows.clone() {
            let p = add(free, add(scale(out, x), scale(red.normal, d)));
            sum += grey(frame, p)?;
        }
        *v = sum / count;
    }
    let cal = unit_step(red_step);
    let run = END_RUN_PX as f64;
    let mut best = (0.0, f64::NEG_INFINITY);
    for i in END_RUN_PX..n - END_RUN_PX {
        let before: f64 = level[i - END_RUN_PX..i].iter().sum::<f64>() / run;
        let after: f64 = level[i + 1..=i + END_RUN_PX].iter().sum::<f64>() / run;
        let ratio = (before - after) / cal;
        if ratio > best.1 {
            best = (i as f64 - (half + END_RUN_PX) as f64, ratio);
        }
    }
    Some(best)
}
