//! The pyramid's faces: where each station locates its face's step (a face turned
//! from its prediction is another body's), where each face's step ends against its
//! predicted base (a pyramid of another size at the placed scale), and faces the pose
//! carries to the frame's border that must run to it.

use image::GrayImage;

use super::sampling::{
    inside_frame, median, profile, run_level, station_span, unit_step, Placement, Profile,
    Sampling, HELD_SHARE, HOLD_RATIO, INSIDE_SPREAD, MIN_CHECKED_PX, STATIONS,
};
use crate::vision::geometry::{add, dot, norm, scale, sub, Line};
use crate::vision::template::{PerEdge, Pose, Template, BLUE, GREEN};
use crate::vision::Miss;

/// How far either way of the predicted face its step is looked for, pixels.
const FACE_SEARCH_PX: i64 = 12;
/// A station locates the face's step where its ratio reaches this, and shows a face
/// over its end ([`face_end`]) from there.
const LOCATED_RATIO: f64 = 0.5;
/// Steps located along a face that run off its predicted line by at least this angle
/// belong to a face of another angle, degrees. The steps of a probe's own face, under
/// noise, a textured background or a pose a pixel off, run off by up to 5.2 deg on
/// the rendered suite and three real-background suites; a face 10 deg or more off the
/// probe's is placed with the difference split between it and its partner.
const FACE_TURN_DEG: f64 = 6.0;
/// Most median distance of the located steps from their own line, pixels.
const FACE_LINE_PX: f64 = 1.0;
/// A predicted face is looked at for a turned one only when it shows at least this
/// many stations' worth of the calibrated step less than all of it (each station's
/// ratio counted between 0 and 1): a face shown along its length is this probe's.
const TURNED_ROOM: f64 = 2.0;

/// Longest cross-section [`locate_steps`] reads, pixels.
const SECTION_MAX: usize = 64;

/// Per station of `line` from `a` to `b`: the largest step ratio within
/// [`FACE_SEARCH_PX`] of the line and its offset along the normal (pixels). Each
/// station reads one cross-section, averaged along the edge as [`profile`] does, and
/// slides the sample runs along it.
pub(super) fn locate_steps(
    frame: &GrayImage,
    line: &Line,
    (a, b): ([f64; 2], [f64; 2]),
    s: &Sampling,
    step: f64,
) -> [(f64, f64); STATIONS] {
    let mut best = [(f64::NEG_INFINITY, 0.0); STATIONS];
    let place = Placement::new((a, b));
    if place.len <= 0.0 {
        return best;
    }
    let (dir, n) = (place.dir, line.normal);
    let margin = s.margin_px.round() as i64;
    let (din, dout) = (s.inside_px.round() as i64, s.outside_px.round() as i64);
    let reach = margin + din.max(dout);
    let half = FACE_SEARCH_PX + reach;
    let width = (2 * half + 1) as usize;
    if width > SECTION_MAX {
        return best;
    }
    let cal = unit_step(step);
    for (k, station) in best.iter_mut().enumerate() {
        let centre = place.centre(line, k);
        // Mean grey level at each depth along the normal (NaN where none is in view).
        let mut section = [f64::NAN; SECTION_MAX];
        for (i, v) in section[..width].iter_mut().enumerate() {
            let depth = std::iter::once((i as i64 - half) as f64);
            if let Some(level) = run_level(frame, centre, dir, n, place.along, depth) {
                *v = level;
            }
        }
        let mean = |from: i64, to: i64| -> f64 {
            let run = &section[(from + half) as usize..=(to + half) as usize];
            run.iter().sum::<f64>() / run.len() as f64
        };
        let mut ratios = [f64::NEG_INFINITY; 2 * FACE_SEARCH_PX as usize + 1];
        for (r, shift) in ratios.iter_mut().zip(-FACE_SEARCH_PX..=FACE_SEARCH_PX) {
            let inside = mean(shift + margin, shift + margin + din);
            let outside = mean(shift - margin - dout, shift - margin);
            *r = (inside - outside) / cal;
            if *r > station.0 {
                *station = (*r, shift as f64);
            }
        }
        // The samples lie clear of the blurred step, so the ratio keeps near its most
        // over a run of shifts: the step is at the run's centre (weighted by the
        // ratio above half its most), not at its first shift.
        let top = station.0;
        if top > 0.0 {
            let at = (station.1 + FACE_SEARCH_PX as f64) as usize;
            let (mut lo, mut hi) = (at, at);
            while lo > 0 && ratios[lo - 1] > 0.5 * top {
                lo -= 1;
            }
            while hi + 1 < ratios.len() && ratios[hi + 1] > 0.5 * top {
                hi += 1;
            }
            let (mut sum, mut weight) = (0.0, 0.0);
            for (k, &r) in ratios.iter().enumerate().take(hi + 1).skip(lo) {
                let w = r - 0.5 * top;
                sum += w * (k as f64 - FACE_SEARCH_PX as f64);
                weight += w;
            }
            if weight > 0.0 {
                station.1 = sum / weight;
            }
        }
    }
    best
}

/// How much of the calibrated step a profile shows, in stations: each station's ratio
/// clamped to 0..1, summed.
fn shown(p: &Profile) -> f64 {
    p.ratio[..p.stations]
        .iter()
        .map(|r| r.clamp(0.0, 1.0))
        .sum()
}

/// Whether the face predicted on `line` (stations from `a` to `b`) is in the frame a
/// straight step turned from it by [`FACE_TURN_DEG`] or more: a pyramid of other face
/// angles, placed where its other edges fit. Such a face crosses the predicted line,
/// so its stations fade toward both ends, which the per-station threshold alone lets
/// pass. Each station locates the step within [`FACE_SEARCH_PX`] of the prediction,
/// where it reaches [`LOCATED_RATIO`] of the step its partner face shows along its
/// length (`shown_by_partner`, taken between [`END_SHOWN_MIN`] and 1: a probe drawn
/// fainter than calibrated, under harsh noise at low magnification, shows about half
/// its step, and its turned face no more); the located steps are that face when at
/// least [`HELD_SHARE`] of the stations
/// locate one, they lie on one line within [`FACE_LINE_PX`], that line is turned, and
/// it shows more of the step than the predicted one. Looked at for every face whose
/// corner is in view, fitted or not: the fit turns the faces together, so a face of
/// another angle is placed where it crosses its partner's prediction. Only when the
/// predicted face leaves [`TURNED_ROOM`] for more, which a face shown along its length
/// does not.
pub(super) fn turned_face(
    frame: &GrayImage,
    line: &Line,
    (a, b): ([f64; 2], [f64; 2]),
    partner: Option<&Line>,
    s: &Sampling,
    predicted: &Profile,
    shown_by_partner: f64,
) -> bool {
    let before = shown(predicted);
    if before + TURNED_ROOM > STATIONS as f64 {
        return false;
    }
    let len = norm(sub(b, a));
    let best = locate_steps(frame, line, (a, b), s, predicted.step);
    let shows_from = located_ratio(shown_by_partner);
    // (position along the face, offset of the located step), pixels.
    let mut located = [[0.0; 2]; STATIONS];
    let mut n = 0;
    for (i, &(r, k)) in best.iter().enumerate() {
        if r >= shows_from {
            located[n] = [(i as f64 + 0.5) / STATIONS as f64 * len, k];
            n += 1;
        }
    }
    if (n as f64) < HELD_SHARE * STATIONS as f64 {
        return false;
    }
    // Theil-Sen: the median of the pairwise slopes, then the median intercept.
    let mut slopes = [0.0; STATIONS * (STATIONS - 1) / 2];
    let mut m = 0;
    for i in 0..n {
        for j in i + 1..n {
            let dx = located[j][0] - located[i][0];
            if dx > 0.0 {
                slopes[m] = (located[j][1] - located[i][1]) / dx;
                m += 1;
            }
        }
    }
    if m == 0 {
        return false;
    }
    let slope = median(&slopes, m);
    let mut intercepts = [0.0; STATIONS];
    for (c, p) in intercepts.iter_mut().zip(&located[..n]) {
        *c = p[1] - slope * p[0];
    }
    let intercept = median(&intercepts, n);
    let mut misfit = [0.0; STATIONS];
    for (d, p) in misfit.iter_mut().zip(&located[..n]) {
        *d = (p[1] - intercept - slope * p[0]).abs();
    }
    if slope.atan().abs() < FACE_TURN_DEG.to_radians() || median(&misfit, n) > FACE_LINE_PX {
        return false;
    }
    // That line must show the face: more of the step than the predicted one.
    let n0 = line.normal;
    let (fa, fb) = (line.foot(a), line.foot(b));
    let a1 = add(fa, scale(n0, intercept));
    let b1 = add(fb, scale(n0, intercept + slope * len));
    let d = sub(b1, a1);
    let dl = norm(d);
    if dl < 1e-9 {
        return false;
    }
    let mut normal = [-d[1] / dl, d[0] / dl];
    if dot(normal, n0) < 0.0 {
        normal = [-normal[0], -normal[1]];
    }
    let turned = Line::through(a1, normal);
    let q = profile(frame, &turned, (a1, b1), partner, s, predicted.step);
    q.stations == STATIONS && shown(&q) > before
}

/// Stations over a face's end, as a share of its predicted length either side of
/// its base.
pub(super) const END_SPAN: f64 = 0.3;
/// Stations over a face's end that may go against the measured end.
const END_AGAINST: usize = 1;
/// How far, as a share of its length, a face may end from its predicted base: the
/// stations over its end are that far apart, and a face's end is blurred.
pub(super) const END_SLACK: f64 = 0.1;
/// A face's end is where its step fades below half the step the face shows along its
/// length (its median ratio, taken between this and 1): a face drawn fainter than
/// calibrated, by charging or on another body, ends where it fades to half of its
/// own step, not of the calibrated one.
const END_SHOWN_MIN: f64 = 0.3;

/// Where a face's step ends along its predicted line, as a share of its predicted
/// length (1 at the predicted base), from its stations over its end (`end`,
/// [`end_profile`]), the face showing `shown` of its calibrated step along its length
/// ([`END_SHOWN_MIN`]); `None` when its stations are not all in view.
pub(super) fn face_end(end: &Profile, shown: f64) -> Option<f64> {
    let j = located_end(end, shown)?;
    Some(1.0 - END_SPAN + 2.0 * END_SPAN * j)
}

/// The stations of face `e` over its end, [`END_SPAN`] of its predicted length either
/// side of its predicted base.
pub(super) fn end_profile(
    frame: &GrayImage,
    t: &Template,
    pose: &Pose,
    e: usize,
    s: &Sampling,
    step: f64,
) -> Profile {
    let (tip, base) = t.segment(pose, e);
    let d = sub(base, tip);
    let at = |f: f64| add(tip, scale(d, f));
    let span = (at(1.0 - END_SPAN), at(1.0 + END_SPAN));
    profile(frame, &t.line(pose, e), span, None, s, step)
}

/// How far past its base, as a share of its length, a face's step is followed on the
/// reference ([`face_runs_past_base`]).
const FOLLOW_SPAN: f64 = 0.3;
/// Positions along a face's line (1 px apart) without its step that end the follow:
/// a line of the background crossing the face near its base is narrower.
const FOLLOW_GAP_PX: usize = 8;

/// How far face `e` of template `t`, at rest on its reference `frame` (blur
/// `blur_px`, the face's calibrated step `step`), runs on in the grey levels beyond
/// its base, as a share of its length (1 at the base). From the base on, 1 px at a
/// time, stations over 7 px of the face's line show the face while they step by
/// [`END_SHOWN_MIN`] of the step on average, the probe's level on the probe's side
/// (within [`INSIDE_SPREAD`] of the step of the face's level from 0.3 to 0.9 of its
/// length); [`FOLLOW_GAP_PX`] positions without the face end the follow. Past the
/// face's true base the beam lies on both sides within a few pixels; a line of the
/// background crossing the face takes part of its step, not all of it.
pub fn face_runs_past_base(
    frame: &GrayImage,
    t: &Template,
    e: usize,
    blur_px: f64,
    step: f64,
) -> f64 {
    let pose = t.at_rest();
    let (tip, base) = t.segment(&pose, e);
    let len = norm(sub(base, tip));
    if len < MIN_CHECKED_PX {
        return 1.0;
    }
    let dir = scale(sub(base, tip), 1.0 / len);
    let line = t.line(&pose, e);
    let s = Sampling::at_pose(t, &pose, blur_px);
    let at = |d: f64| add(tip, scale(dir, d));
    let body = profile(frame, &line, (at(0.3 * len), at(0.9 * len)), None, &s, step);
    if body.stations < STATIONS || body.step_ratio() < HOLD_RATIO {
        return 1.0;
    }
    let level = body.held_level();
    let mean = |v: &[f64; STATIONS]| v.iter().sum::<f64>() / STATIONS as f64;
    let (mut last, mut gap) = (len, 0);
    let mut d = len + 1.0;
    while d <= (1.0 + FOLLOW_SPAN) * len && gap <= FOLLOW_GAP_PX {
        let p = profile(frame, &line, (at(d - 3.0), at(d + 4.0)), None, &s, step);
        if p.stations < STATIONS {
            break;
        }
        if mean(&p.ratio) >= END_SHOWN_MIN
            && (mean(&p.inside) - level).abs() <= INSIDE_SPREAD * step.abs()
        {
            (last, gap) = (d, 0);
        } else {
            gap += 1;
        }
        d += 1.0;
    }
    last / len
}

/// Where profile `p`'s step stops showing, as a share of its span: the split of its
/// stations that best explains them, showing the step before (from
/// [`located_ratio`] of `shown`) and not after, with at most [`END_AGAINST`] station
/// against it. `None` when not all stations are in view, or the step shows on all of
/// them or on none.
fn located_end(p: &Profile, shown: f64) -> Option<f64> {
    if p.stations < STATIONS {
        return None;
    }
    let located = located_ratio(shown);
    split(|k| p.ratio[k] >= located)
}

/// Whether profile `p`'s step runs on over its whole span (its stations all in view,
/// at most [`END_AGAINST`] of them without the step, from [`located_ratio`] of
/// `shown`): where it does over a face's end ([`end_profile`]), the face runs on past
/// its predicted base.
pub(super) fn runs_throughout(p: &Profile, shown: f64) -> bool {
    p.stations == STATIONS && stepping(p, located_ratio(shown)) + END_AGAINST >= STATIONS
}

/// Where a face ends at the latest when its step is absent over its whole end
/// ([`absent_throughout`] on its stations over it, `end`): before the first of them.
/// `None` when it is not.
pub(super) fn lost_end(end: &Profile, shown: f64) -> Option<f64> {
    absent_throughout(end, shown).then_some(1.0 - END_SPAN)
}

/// Whether profile `p`'s step is absent over its whole span: its stations all in
/// view, at most [`END_AGAINST`] of them stepping by half of [`located_ratio`] of
/// `shown` or more. A station shows the face from that ratio and lacks it below half
/// of it, so a faint face's stations about the ratio are neither.
fn absent_throughout(p: &Profile, shown: f64) -> bool {
    p.stations == STATIONS && stepping(p, 0.5 * located_ratio(shown)) <= END_AGAINST
}

/// How many of profile `p`'s stations step by `ratio` or more.
fn stepping(p: &Profile, ratio: f64) -> usize {
    (0..p.stations).filter(|&k| p.ratio[k] >= ratio).count()
}

/// The ratio from which a station shows a face that shows `shown` of its calibrated
/// step along its length: [`LOCATED_RATIO`] of it, taken between [`END_SHOWN_MIN`]
/// and 1.
fn located_ratio(shown: f64) -> f64 {
    LOCATED_RATIO * shown.clamp(END_SHOWN_MIN, 1.0)
}

/// The split of the stations that best explains which `shows`: all before it, none
/// after, at most [`END_AGAINST`] against it; as a share of the stations. `None`
/// when they all show or none does.
fn split(shows: impl Fn(usize) -> bool) -> Option<f64> {
    let score = |j: usize| {
        (0..j).filter(|&k| shows(k)).count() + (j..STATIONS).filter(|&k| !shows(k)).count()
    };
    let best = (0..=STATIONS).map(score).max()?;
    let first = (0..=STATIONS).find(|&j| score(j) == best)?;
    let last = (0..=STATIONS).rev().find(|&j| score(j) == best)?;
    if best + END_AGAINST < STATIONS || first == 0 || last == STATIONS {
        return None;
    }
    Some(0.5 * (first + last) as f64 / STATIONS as f64)
}

/// The stretch of a face leaving the frame whose step is followed to the border, as a
/// share of its length in view.
const RUN_SPAN: f64 = 0.5;
/// How far before the border, as a share of its length in view, a face leaving the
/// frame may end: two stations' spacing over the stretch followed, as a face's end
/// is blurred. The body's end, required as well, keeps a face whose step a bright
/// body beside it takes away near the border: no probe frame of the rendered suites
/// 1-15 and 31 or the real-background seeds 5, 7, 9, 13, 21-24 and 71 is refused
/// with this slack, and one (real-background seed 13) with none.
const RUN_SLACK: f64 = 0.1;

/// Whether face `e`, placed by the pose to leave the frame before its base, ends in
/// view instead: its step stops more than [`RUN_SLACK`] of its length in view short
/// of the border, and beyond that end the probe's side leaves the probe's level on
/// some station (the body ends, not only the step).
/// `b` is the far end of the face's station span ([`station_span`]).
#[allow(clippy::too_many_arguments)]
pub(super) fn runs_out(
    frame: &GrayImage,
    t: &Template,
    pose: &Pose,
    e: usize,
    b: [f64; 2],
    size: [f64; 2],
    s: &Sampling,
    step: f64,
    shown: f64,
) -> bool {
    if inside_frame(t.segment(pose, e).1, size, s.reach() + 1.0) {
        return false;
    }
    let Some((p, j)) = step_ends_short(frame, t, pose, e, b, s, step, shown) else {
        return false;
    };
    // The body must end there too: beside a face near the border, a particle at the
    // probe's level takes the step away while the probe's side keeps its level.
    let level = p.held_level();
    let first = (j * STATIONS as f64).ceil() as usize;
    (first..STATIONS).any(|k| !p.at_probe_level(k, level))
}

/// Where face `e`'s step ends short of `b`, the far end of its stretch in view: over
/// the far [`RUN_SPAN`] of that stretch, the profile and the share of it where the
/// step stops ([`located_end`]), when that is before the last [`RUN_SLACK`] of the
/// stretch.
#[allow(clippy::too_many_arguments)]
fn step_ends_short(
    frame: &GrayImage,
    t: &Template,
    pose: &Pose,
    e: usize,
    b: [f64; 2],
    s: &Sampling,
    step: f64,
    shown: f64,
) -> Option<(Profile, f64)> {
    let tip = t.segment(pose, e).0;
    if norm(sub(b, tip)) < 1e-9 {
        return None;
    }
    let from = add(tip, scale(sub(b, tip), 1.0 - RUN_SPAN));
    let p = profile(frame, &t.line(pose, e), (from, b), None, s, step);
    let j = located_end(&p, shown)?;
    (RUN_SPAN * (1.0 - j) > RUN_SLACK).then_some((p, j))
}

/// Whether each face shows its step to the end the pose gives it in view (its base, or
/// the border it leaves the frame by): over the far [`RUN_SPAN`] of its stretch in
/// view, the step does not end ([`located_end`], at [`LOCATED_RATIO`] of the step the
/// face shows along its length) before the last [`RUN_SLACK`] of that stretch. A tip
/// whose beam edge is placed out of view
/// ([`beam_out_of_view_scale`](super::beam_out_of_view_scale), the smallest such scale)
/// has only its faces to fix the scale: a face ending before that scale's end says the
/// pyramid is smaller than any scale that hides the beam, whatever lies beyond the face
/// (the beam of a probe of another geometry at the pyramid's level, a patch's border).
pub fn faces_run_to_border(
    frame: &GrayImage,
    t: &Template,
    pose: &Pose,
    blur_px: f64,
    calibrated: &PerEdge<f64>,
) -> bool {
    let size = [frame.width() as f64, frame.height() as f64];
    let s = Sampling::at_pose(t, pose, blur_px);
    [BLUE, GREEN].into_iter().all(|e| {
        let Some((a, b, _)) = station_span(t, pose, e, size, &s) else {
            return true;
        };
        let shown = profile(frame, &t.line(pose, e), (a, b), None, &s, calibrated[e]);
        step_ends_short(frame, t, pose, e, b, &s, calibrated[e], shown.step_ratio()).is_none()
    })
}

/// Both faces, where the pose places them and their ends are measured (whether or not
/// the fit kept them; `ends` as [`face_end`] gives them, back face first), ending more
/// than [`END_SLACK`] of their length before or beyond the bases the scale predicts:
/// the pyramid is not this probe's size at this scale. The scale comes from the beam
/// edge's distance to the apex, so a beam of another thickness moves it while the
/// pyramid keeps its size. One face alone can end early or late where a particle or a
/// bright substrate lies at its base; the scale moves both.
pub(super) fn face_ends([back, front]: [Option<f64>; 2]) -> Option<Miss> {
    let (b, g) = (back? - 1.0, front? - 1.0);
    (b * g > 0.0 && b.abs().min(g.abs()) > END_SLACK).then_some(Miss::ScaleMismatch)
}
