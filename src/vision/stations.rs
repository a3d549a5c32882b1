//! The per-edge checks of verification: at stations along each edge the pose puts in
//! view, does the frame step across it as this probe's calibrated edge does?
//!
//! A station averages the grey levels in two short runs parallel to the predicted
//! edge, one on the probe's side and one outside, clear of the blurred step. Its step
//! (inside minus outside) over the calibrated signed step is its ratio: about 1 on the
//! probe's edge, 0 where nothing steps (a hidden or absent edge), negative where the
//! grey levels step the other way (another body's edge, a mirror image's).
//!
//! An edge is refused as missing (`Miss::EdgeMissing`) when more than 30 % of its
//! stations show nothing (a station whose outside is covered by something brighter
//! than the probe while its inside keeps the probe's level is not counted against it),
//! or when the two stations nearest its corner (the apex, the beam's free end) do not
//! both show it: a tip hidden under a patch has no faces there (a face may lose its
//! corner to a particle beside it while the apex shows the surroundings beyond it),
//! or when a face's line steps on past the apex from the level of its far side: the
//! border of a patch over the tip, meeting a face where the apex should be.
//! It steps the wrong way (`Miss::WrongAppearance`) when its median ratio is negative.
//! The pyramid is not this probe's size at the placed scale (`Miss::ScaleMismatch`)
//! when a face's last three stations toward its base show nothing (the face is
//! shorter; unless the beam edge in the fit measures the scale and those stations keep
//! the probe's level on its side: something at that level beside the base), when both
//! faces end off their predicted bases on one side (a face lost over its whole end
//! ends before it), or, with no beam edge found to fix the scale, one face ends by its
//! base while the other runs on past its own. The probe's side of every edge is one
//! body, of one level. The beam edge is checked with its free end in view, along its
//! rigid block. When the fit left it out (a tip placed from its faces, the scale known
//! to a few per cent) it is looked for parallel to where the pose puts it, within that
//! slack, and must be found along its length as a face is (not necessarily at its
//! corner, where a faint beam fades first), unless the slack reaches out of the frame:
//! a mirrored probe's faces make a wedge, but its beam runs the other way.

use image::GrayImage;

use super::geometry::{add, clip_to_rect, dot, norm, scale, strip_mean, sub, Line};
use super::template::{Pose, Template, BLUE, GREEN, RED};
use super::{Edge, Miss};

/// Stations sampled along each edge.
pub const STATIONS: usize = 10;
/// A station shows the edge when its step is at least this share of the calibrated
/// step, with its sign. A hidden or absent edge steps by nothing (or the other way); a
/// true face whose apex dips into a bright substrate keeps 0.15-0.35 of its
/// clean-reference step there.
const HOLD_RATIO: f64 = 0.1;
/// Share of an edge's stations that must show it.
const HELD_SHARE: f64 = 0.7;
/// Stations at each end of an edge: at the corner end all but one must show it (a tip
/// under a patch fails there), at a face's far end at least one must show it or be
/// covered (a face running short of the calibrated geometry at this scale fails there).
const END_STATIONS: usize = 3;
/// A face whose last this many stations toward its base show nothing is longer than
/// the probe's at this scale (or runs on where the probe's does not).
const FAR_MISSING: usize = 3;
/// The probe's side of every edge in view is one body: their levels agree within this
/// share of the calibrated beam step.
const INSIDE_SPREAD: f64 = 0.5;
/// A station whose outside is brighter than its inside (a particle, a substrate) still
/// shows the probe when its inside lies within this share of the calibrated step of
/// the probe's level along the edge.
const COVERED_LEVEL: f64 = 0.25;
/// A beam edge the fit left out is looked for parallel to its predicted line, up to
/// this share of the apex's distance from it either way: a tip placed from its two
/// faces alone has its scale, hence that distance, known to a few per cent.
const RED_SLACK: f64 = 0.1;
/// Along-edge half length of a station's sample run, pixels (at most).
const STATION_HALF_PX: f64 = 3.0;
/// Shortest visible stretch of an edge that is checked, frame pixels.
const MIN_CHECKED_PX: f64 = 12.0;

/// Where a station samples across an edge: from `margin_px` (clear of the blurred
/// step) on, `inside_px` deep on the probe's side and `outside_px` on the other.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Sampling {
    pub margin_px: f64,
    pub inside_px: f64,
    pub outside_px: f64,
}

impl Sampling {
    /// For a frame of blur `blur_px` and a beam `beam_px` thick.
    pub fn new(blur_px: f64, beam_px: f64) -> Sampling {
        let margin_px = 1.5 * blur_px + 1.0;
        Sampling {
            margin_px,
            inside_px: (0.8 * beam_px - margin_px).clamp(0.0, 3.0),
            outside_px: 3.0,
        }
    }

    /// For a frame of blur `blur_px` showing template `t` at `pose`: the beam taken as
    /// thick as the back face's base lies below the beam edge.
    fn at_pose(t: &Template, pose: &Pose, blur_px: f64) -> Sampling {
        let beam_px = t.line(pose, RED).depth(t.segment(pose, BLUE).1).abs();
        Sampling::new(blur_px, beam_px)
    }

    fn reach(&self) -> f64 {
        self.margin_px + self.inside_px.max(self.outside_px)
    }
}

/// The grey levels across one predicted edge, station by station.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Profile {
    /// Stations with samples on both sides.
    pub stations: usize,
    /// Per station: the step (inside minus outside) over the calibrated step.
    pub ratio: [f64; STATIONS],
    /// Per station: the mean level on the probe's side.
    pub inside: [f64; STATIONS],
    /// The calibrated signed step the ratios are relative to.
    pub step: f64,
    /// Whether the corner end is in view (not cut by the frame).
    pub corner_in_view: bool,
}

/// Median of the first `n` values (n >= 1), without allocating.
fn median<const N: usize>(v: &[f64; N], n: usize) -> f64 {
    let mut s = *v;
    s[..n].sort_unstable_by(f64::total_cmp);
    if n % 2 == 1 {
        s[n / 2]
    } else {
        0.5 * (s[n / 2 - 1] + s[n / 2])
    }
}

impl Profile {
    fn held(&self, k: usize) -> bool {
        self.ratio[k] >= HOLD_RATIO
    }

    /// Median step over the calibrated one.
    pub fn step_ratio(&self) -> f64 {
        median(&self.ratio, self.stations.max(1))
    }

    /// Median level on the probe's side.
    pub fn inside_level(&self) -> f64 {
        median(&self.inside, self.stations.max(1))
    }

    /// Whether station `k`'s outside is covered by something brighter (for a brighter
    /// probe; darker for a darker one) than the probe while its inside has the probe's
    /// level: a particle or substrate beside the edge, not a missing edge.
    fn covered(&self, k: usize, probe_level: f64) -> bool {
        self.ratio[k] <= -HOLD_RATIO && self.at_probe_level(k, probe_level)
    }

    /// Whether station `k`'s inside lies within [`COVERED_LEVEL`] of the calibrated
    /// step of `probe_level`.
    fn at_probe_level(&self, k: usize, probe_level: f64) -> bool {
        self.inside_within(k, probe_level, COVERED_LEVEL)
    }

    /// Whether station `k`'s inside lies within `share` of the calibrated step of
    /// `level`.
    fn inside_within(&self, k: usize, level: f64, share: f64) -> bool {
        (self.inside[k] - level).abs() <= share * self.step.abs()
    }

    /// Whether the [`FAR_MISSING`] stations at the far end keep, on the probe's side,
    /// the probe's level along the rest of the edge.
    fn far_end_inside_probe(&self) -> bool {
        let n = self.stations;
        self.inside_probe_over(n.saturating_sub(FAR_MISSING)..n)
    }

    /// Whether every station of `stations` keeps, on the probe's side, the probe's
    /// level along the rest of the edge ([`COVERED_LEVEL`]).
    fn inside_probe_over(&self, mut stations: std::ops::Range<usize>) -> bool {
        let probe_level = self.held_level();
        stations.all(|k| self.at_probe_level(k, probe_level))
    }

    /// Whether the stations at the corner end show the edge, with the probe on its
    /// side of it (its inside within [`INSIDE_SPREAD`] of the calibrated step of the
    /// probe's level along the rest of the edge): all but one of [`END_STATIONS`]. A
    /// patch darker than the surroundings over the tip steps the same way, from its
    /// own level.
    pub fn corner_held(&self) -> bool {
        let probe_level = self.held_level();
        let shown = (0..END_STATIONS)
            .filter(|&k| self.held(k) && self.inside_within(k, probe_level, INSIDE_SPREAD))
            .count();
        shown + 1 >= END_STATIONS
    }

    /// Whether the probe is there at the corner end even where the edge does not
    /// show: every corner station's inside keeps the level of the probe's side along
    /// the rest of the edge (a bright substrate or particle outside it, not a patch
    /// over the tip).
    pub fn corner_inside_probe(&self) -> bool {
        self.inside_probe_over(0..END_STATIONS)
    }

    /// Median level on the far side of the edge over the stations that show it (at
    /// least one must).
    fn outside_level(&self) -> f64 {
        self.held_median(|k| self.inside[k] - self.ratio[k] * self.step)
    }

    /// Median level on the probe's side over the stations that show the edge.
    fn held_level(&self) -> f64 {
        self.held_median(|k| self.inside[k])
    }

    /// Median of `value` over the stations that show the edge (0 when none does).
    fn held_median(&self, value: impl Fn(usize) -> f64) -> f64 {
        let mut held = [0.0; STATIONS];
        let mut m = 0;
        for k in (0..self.stations).filter(|&k| self.held(k)) {
            held[m] = value(k);
            m += 1;
        }
        median(&held, m.max(1))
    }

    /// Why this profile is not edge `edge` of the probe, if it is not (a face's
    /// corner is judged with its partner's: [`check_edges`]).
    pub fn refusal(&self, edge: Edge) -> Option<Miss> {
        let n = self.stations;
        if n < STATIONS {
            return Some(Miss::EdgeMissing(edge.into()));
        }
        let ratio = self.step_ratio();
        if ratio <= -HOLD_RATIO {
            return Some(Miss::WrongAppearance(edge.into()));
        }
        let probe_level = self.held_level();
        let missing = |range: std::ops::Range<usize>| {
            range
                .filter(|&k| !self.held(k) && !self.covered(k, probe_level))
                .count()
        };
        if (missing(0..n) as f64) > (1.0 - HELD_SHARE) * n as f64
            || (edge == Edge::Red
                && self.corner_in_view
                && !self.corner_held()
                && !self.corner_inside_probe())
        {
            return Some(Miss::EdgeMissing(edge.into()));
        }
        if edge != Edge::Red && missing(n - FAR_MISSING..n) == FAR_MISSING {
            return Some(Miss::ScaleMismatch);
        }
        None
    }
}

/// Whether `p` lies in a frame of `size` at least `pad` pixels from its border pixels.
fn inside_frame(p: [f64; 2], size: [f64; 2], pad: f64) -> bool {
    p[0] >= pad && p[1] >= pad && p[0] <= size[0] - 1.0 - pad && p[1] <= size[1] - 1.0 - pad
}

/// Where the line from `origin` along `dir` runs at least `pad` pixels inside a frame
/// of `size`: its interval of distances along `dir`.
fn clip_inside(origin: [f64; 2], dir: [f64; 2], size: [f64; 2], pad: f64) -> Option<(f64, f64)> {
    clip_to_rect(
        origin,
        dir,
        [pad, pad],
        [size[0] - 1.0 - pad, size[1] - 1.0 - pad],
    )
}

/// The stretch of edge `e` the stations cover, with whether its corner end is in view.
fn station_span(
    t: &Template,
    pose: &Pose,
    e: usize,
    size: [f64; 2],
    s: &Sampling,
) -> Option<([f64; 2], [f64; 2], bool)> {
    let (tip, mut far) = t.segment(pose, e);
    if e == RED {
        far = t.place(pose, t.edges[RED].point(t.red_near_tip(0.0).1));
    }
    let len = norm(sub(far, tip));
    if len < MIN_CHECKED_PX {
        return None;
    }
    let dir = [(far[0] - tip[0]) / len, (far[1] - tip[1]) / len];
    let reach = s.reach();
    let trims = if e == RED {
        (reach + 1.0, 1.0)
    } else {
        (corner_trim(t, s), 1.5 * reach + 2.0)
    };
    stretch(tip, dir, len, trims, size, s)
}

/// The part of the line from `corner` along the unit `dir`, `len` pixels long, that
/// stations check: `trims` (at the corner, at the far end) cut off and the rest clipped
/// to where their samples stay in a frame of `size`; with whether the corner end is
/// in view.
fn stretch(
    corner: [f64; 2],
    dir: [f64; 2],
    len: f64,
    (trim_corner, trim_far): (f64, f64),
    size: [f64; 2],
    s: &Sampling,
) -> Option<([f64; 2], [f64; 2], bool)> {
    let (a, b) = clip_inside(corner, dir, size, s.reach() + 1.0)?;
    let (a0, b0) = (a.max(trim_corner), b.min(len - trim_far));
    if b0 - a0 < MIN_CHECKED_PX {
        return None;
    }
    let at = |d: f64| add(corner, scale(dir, d));
    Some((at(a0), at(b0), a <= trim_corner))
}

/// How far from the apex a station on a face's line (either way) samples clear of
/// the partner face, pixels.
fn corner_trim(t: &Template, s: &Sampling) -> f64 {
    let (nb, ng) = (t.edges[BLUE].normal, t.edges[GREEN].normal);
    let sin_apex = (nb[0] * ng[1] - nb[1] * ng[0]).abs().max(0.2);
    s.reach() / sin_apex + 1.0
}

/// A stretch of an edge checked by stations: its two ends, frame pixels.
type Span = ([f64; 2], [f64; 2]);

/// Where the [`STATIONS`] stations of a span lie: evenly along it, each averaging
/// `along` pixels either side of its centre.
struct Placement {
    a: [f64; 2],
    dir: [f64; 2],
    len: f64,
    along: i64,
}

impl Placement {
    fn new((a, b): Span) -> Self {
        let len = norm(sub(b, a));
        let dir = if len > 0.0 {
            [(b[0] - a[0]) / len, (b[1] - a[1]) / len]
        } else {
            [0.0, 0.0]
        };
        let along = (0.5 * len / STATIONS as f64).min(STATION_HALF_PX).floor() as i64;
        Placement { a, dir, len, along }
    }

    /// Station `k`'s centre, on `line`.
    fn centre(&self, line: &Line, k: usize) -> [f64; 2] {
        let c = (k as f64 + 0.5) / STATIONS as f64 * self.len;
        line.foot([self.a[0] + c * self.dir[0], self.a[1] + c * self.dir[1]])
    }
}

/// The grey level of the pixel nearest `p`, if it is in the frame.
fn grey(frame: &GrayImage, p: [f64; 2]) -> Option<f64> {
    let (x, y) = (p[0].round() as i64, p[1].round() as i64);
    (x >= 0 && y >= 0 && x < i64::from(frame.width()) && y < i64::from(frame.height()))
        .then(|| f64::from(frame.get_pixel(x as u32, y as u32)[0]))
}

/// The mean grey level of a station's run (`along` pixels either side of `centre`
/// on the unit `dir`) at each of `depths` pixels along the normal `n`; `None` when
/// none of it is in the frame.
fn run_level(
    frame: &GrayImage,
    centre: [f64; 2],
    dir: [f64; 2],
    n: [f64; 2],
    along: i64,
    depths: impl Iterator<Item = f64> + Clone,
) -> Option<f64> {
    let (mut sum, mut count) = (0.0, 0usize);
    for j in -along..=along {
        for depth in depths.clone() {
            let p = [
                centre[0] + j as f64 * dir[0] + depth * n[0],
                centre[1] + j as f64 * dir[1] + depth * n[1],
            ];
            if let Some(v) = grey(frame, p) {
                sum += v;
                count += 1;
            }
        }
    }
    (count > 0).then(|| sum / count as f64)
}

/// A calibrated step to divide by: a step under one grey level counts as one of its sign.
fn unit_step(step: f64) -> f64 {
    if step.abs() < 1.0 {
        step.signum()
    } else {
        step
    }
}

/// Samples the step across `line` at [`STATIONS`] stations from `a` to `b`.
pub fn profile(
    frame: &GrayImage,
    line: &Line,
    (a, b): ([f64; 2], [f64; 2]),
    partner: Option<&Line>,
    s: &Sampling,
    calibrated: f64,
) -> Profile {
    let place = Placement::new((a, b));
    let (dir, n) = (place.dir, line.normal);
    let cal = unit_step(calibrated);
    let pixel = |p: [f64; 2]| grey(frame, p);
    let mut out = Profile {
        stations: 0,
        ratio: [0.0; STATIONS],
        inside: [0.0; STATIONS],
        step: cal,
        corner_in_view: false,
    };
    let depths_in = s.inside_px.round() as i64;
    let depths_out = s.outside_px.round() as i64;
    for k in 0..STATIONS {
        let centre = place.centre(line, k);
        let (mut sum_in, mut n_in, mut sum_out, mut n_out) = (0.0, 0usize, 0.0, 0usize);
        for j in -place.along..=place.along {
            let q = [centre[0] + j as f64 * dir[0], centre[1] + j as f64 * dir[1]];
            for d in 0..=depths_in {
                let depth = s.margin_px + d as f64;
                let p = [q[0] + depth * n[0], q[1] + depth * n[1]];
                if partner.is_some_and(|l| l.depth(p) < s.margin_px) {
                    continue;
                }
                if let Some(v) = pixel(p) {
                    sum_in += v;
                    n_in += 1;
                }
            }
            for d in 0..=depths_out {
                let depth = s.margin_px + d as f64;
                if let Some(v) = pixel([q[0] - depth * n[0], q[1] - depth * n[1]]) {
                    sum_out += v;
                    n_out += 1;
                }
            }
        }
        if n_in == 0 || n_out == 0 {
            continue;
        }
        let (inside, outside) = (sum_in / n_in as f64, sum_out / n_out as f64);
        out.ratio[out.stations] = (inside - outside) / cal;
        out.inside[out.stations] = inside;
        out.stations += 1;
    }
    out
}

/// The stations' verdict on a placed tip: each edge the pose puts in view, then one
/// level on the probe's side of them all. `calibrated` are the edges' signed steps,
/// `fitted` which edges the grey-level fit placed.
pub fn check_edges(
    frame: &GrayImage,
    t: &Template,
    pose: &Pose,
    blur_px: f64,
    calibrated: &[f64; 3],
    fitted: [bool; 3],
) -> Option<Miss> {
    let size = [frame.width() as f64, frame.height() as f64];
    let red = t.line(pose, RED);
    let s = Sampling::at_pose(t, pose, blur_px);
    let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
    // Faces whose corner (the apex) is in view, and of those the ones not shown there.
    let (mut corners, mut hidden) = (0, 0);
    // The beam edge where the frame shows it: the fitted line, or the one found
    // within the slack when the fit left it out.
    let mut beam_edge = fitted[RED].then_some(red);
    // The faces whose corner is in view, for the turned-face check.
    let mut faces: [Option<(Span, Profile, Option<Line>)>; 3] = [None; 3];
    let mut shown_step = [1.0; 3];
    // The far end of each edge's station span.
    let mut far_end = [None; 3];
    // An unfitted beam edge whose slack reaches out of the frame, not found on the
    // shifts in view: refused if a face's base pins the scale (below).
    let mut red_unseen = None;
    for e in [RED, BLUE, GREEN] {
        let Some((a, b, corner)) = station_span(t, pose, e, size, &s) else {
            continue;
        };
        far_end[e] = Some(b);
        if e == RED && !corner {
            continue;
        }
        let partner = match e {
            BLUE => Some(t.line(pose, GREEN)),
            GREEN => Some(t.line(pose, BLUE)),
            _ => None,
        };
        let line = t.line(pose, e);
        let mut p = profile(frame, &line, (a, b), partner.as_ref(), &s, calibrated[e]);
        if e == RED && !fitted[RED] {
            // Left out of the fit: where is it, within the scale's slack? It must be
            // found there, as the faces are, unless that slack reaches out of the
            // frame (a beam along the border may lie just beyond it).
            let slack = (RED_SLACK * line.depth(pose.apex).abs()).ceil() as i64;
            let pad = s.reach() + 1.0;
            let inside = |p: [f64; 2]| inside_frame(p, size, pad);
            let shifted =
                |p: [f64; 2], k: f64| [p[0] + k * line.normal[0], p[1] + k * line.normal[1]];
            let sure = [-1.0, 1.0].iter().all(|&sign| {
                let k = sign * slack as f64;
                inside(shifted(a, k)) && inside(shifted(b, k))
            });
            let mut found = line;
            let mut best_in_view: Option<Profile> = None;
            for k in -slack..=slack {
                let moved = Line {
                    rho: line.rho + k as f64,
                    ..line
                };
                let q = profile(frame, &moved, (a, b), None, &s, calibrated[e]);
                if q.stations < STATIONS {
                    continue;
                }
                if best_in_view.is_none_or(|best| q.step_ratio() > best.step_ratio()) {
                    best_in_view = Some(q);
                }
                if q.step_ratio() > p.step_ratio() {
                    p = q;
                    found = moved;
                }
            }
            if p.step_ratio() <= -HOLD_RATIO {
                return Some(Miss::WrongAppearance(Edge::Red.into()));
            }
            // Found along its length, not necessarily at its corner: a beam edge the
            // fit could not use is faint, and its corner the first to fade.
            p.corner_in_view = false;
            match (sure, p.refusal(Edge::Red)) {
                (true, Some(miss)) => return Some(miss),
                // Found with the whole slack in view: the beam edge is there.
                (true, None) => beam_edge = Some(found),
                (false, _) => {
                    red_unseen = best_in_view.and_then(|mut q| {
                        q.corner_in_view = false;
                        q.refusal(Edge::Red)
                    });
                }
            }
            continue;
        }
        p.corner_in_view = corner;
        if let Some(miss) = p.refusal(Edge::ALL[e]) {
            // With the beam edge in the fit the scale is measured: a face whose last
            // stations lose their step to something at the probe's level beside its
            // base, its inside keeping that level, is judged with its partner's end
            // (`face_ends`), the beam's lower face and its free end, not alone.
            let beside_base = miss == Miss::ScaleMismatch && p.far_end_inside_probe();
            if !(beside_base && fitted[RED]) {
                return Some(miss);
            }
        }
        shown_step[e] = p.step_ratio();
        if e != RED && corner {
            faces[e] = Some(((a, b), p, partner));
            let held = p.corner_held();
            corners += 1;
            hidden += usize::from(!held);
            if !held && !p.corner_inside_probe() {
                return Some(Miss::EdgeMissing(Edge::ALL[e].into()));
            }
        }
        let level = p.inside_level();
        (lo, hi) = (lo.min(level), hi.max(level));
    }
    // A tip too small at its scale for either face to be checked (each under about
    // 30 px: MIN_CHECKED_PX beyond the corner's and the base's trims) shows nothing
    // that makes it this probe; a free-end corner of another body passes for one.
    if corners == 0 {
        return Some(Miss::ScaleMismatch);
    }
    // The tip is hidden when no face shows it at the apex; one face may lose its
    // corner to a particle or a bright substrate beside it while the other holds.
    if corners > 0 && hidden == corners {
        return Some(Miss::EdgeMissing(Edge::Blue.into()));
    }
    // One face losing its corner to a body at the probe's level beside it is a
    // particle touching the tip only while the apex itself shows.
    if hidden > 0 && apex_covered(frame, t, pose, &s, &faces) {
        return Some(Miss::EdgeMissing(Edge::Blue.into()));
    }
    // A face that is a border running on past the apex: the tip under a patch.
    for (e, face) in faces.iter().enumerate() {
        if let Some((_, p, _)) = face {
            if runs_on_past_apex(frame, t, pose, e, size, &s, p) {
                return Some(Miss::EdgeMissing(Edge::ALL[e].into()));
            }
        }
    }
    if hi - lo > INSIDE_SPREAD * calibrated[RED].abs() {
        return Some(Miss::WrongAppearance(Edge::Red.into()));
    }
    // Where each face's step ends (back face first), measured over its whole end in
    // view.
    let end_profiles = [BLUE, GREEN].map(|e| end_profile(frame, t, pose, e, &s, calibrated[e]));
    let shown_faces = [shown_step[BLUE], shown_step[GREEN]];
    let ends = [0, 1].map(|i| face_end(&end_profiles[i], shown_faces[i]));
    // A face lost over its whole end (one whose lost base is judged with its
    // partner, above) is judged by where it ends at the latest.
    let latest = [0, 1].map(|i| ends[i].or_else(|| lost_end(&end_profiles[i], shown_faces[i])));
    if let Some(miss) = face_ends(latest) {
        return Some(miss);
    }
    // Without the beam edge to fix the scale, a face ending by its base beside one
    // whose step runs on well past its own base is not this pyramid at any scale.
    if beam_edge.is_none() {
        for (ended, other) in [(0, 1), (1, 0)] {
            if ends[ended].is_some_and(|f| f <= 1.0 + END_SLACK)
                && runs_throughout(&end_profiles[other], shown_faces[other])
            {
                return Some(Miss::ScaleMismatch);
            }
        }
    }
    // A face ending at its base pins the scale and with it the beam edge's depth: the
    // beam edge must then show on the part of its slack in view.
    if let Some(miss) = red_unseen {
        if ends.iter().flatten().any(|f| (f - 1.0).abs() <= END_SLACK) {
            return Some(miss);
        }
    }
    // A face the pose places to leave the frame must run to the border.
    for e in [BLUE, GREEN] {
        let Some(b) = far_end[e] else {
            continue;
        };
        if runs_out(frame, t, pose, e, b, size, &s, calibrated[e], shown_step[e]) {
            return Some(Miss::EdgeMissing(Edge::ALL[e].into()));
        }
    }
    if let Some(miss) =
        beam_edge.and_then(|red| lower_face(frame, t, pose, &red, &s, calibrated[RED]))
    {
        return Some(miss);
    }
    if let Some(miss) =
        beam_edge.and_then(|red| free_end(frame, t, pose, &red, &s, calibrated[RED]))
    {
        return Some(miss);
    }
    // Last, as the dearest: a face the frame shows turned from its prediction.
    for (e, face) in faces.iter().enumerate() {
        if let Some((span, p, partner)) = face {
            let other = if e == BLUE { GREEN } else { BLUE };
            if turned_face(
                frame,
                &t.line(pose, e),
                *span,
                partner.as_ref(),
                &s,
                p,
                shown_step[other],
            ) {
                return Some(Miss::EdgeMissing(Edge::ALL[e].into()));
            }
        }
    }
    None
}

/// A face's line steps on past the apex when its step keeps, at every station there,
/// the level of the face's far side within this share of the calibrated step.
const RUN_ON_OUTSIDE: f64 = 0.25;

/// Whether face `e` (its stations `face`) is a border running on past the apex: along
/// its line beyond the apex, from where the partner face is clear (the corner's trim)
/// for as far as the face is long, every station steps the face's way
/// ([`HOLD_RATIO`]) from the level of the face's far side ([`RUN_ON_OUTSIDE`]).
/// Beyond a probe's apex both sides of a face's line are the surroundings; the border
/// of a patch over the tip, meeting a face where the apex should be, goes on between
/// the patch and the surroundings.
fn runs_on_past_apex(
    frame: &GrayImage,
    t: &Template,
    pose: &Pose,
    e: usize,
    size: [f64; 2],
    s: &Sampling,
    face: &Profile,
) -> bool {
    let (tip, far) = t.segment(pose, e);
    let len = norm(sub(far, tip));
    if len < MIN_CHECKED_PX {
        return false;
    }
    let dir = scale(sub(tip, far), 1.0 / len);
    let Some((a, b, true)) = stretch(tip, dir, len, (corner_trim(t, s), 0.0), size, s) else {
        return false;
    };
    let line = t.line(pose, e);
    let past = profile(frame, &line, (a, b), None, s, face.step);
    past.stations == STATIONS
        && (0..STATIONS).all(|k| past.held(k))
        && (past.outside_level() - face.outside_level()).abs() <= RUN_ON_OUTSIDE * face.step.abs()
        && wide_past_line(frame, &line, (a, b), s, &past)
}

/// Past the line's inside samples, this many pixels on, and this many rows deep, the
/// level that tells a body's border from a line along it.
const DEEP_GAP_PX: f64 = 1.0;
const DEEP_ROWS: i64 = 3;
/// A body past a line holds this share of its step at that depth.
const DEEP_SHARE: f64 = 0.5;

/// Whether what steps along `line` over `(a, b)` (its stations `past`) is a border
/// between two wide regions: deeper on its inside than its inside samples, past a
/// gap, the median station keeps at least [`DEEP_SHARE`] of its step. Both sides of
/// a patch's border are wide; a thin line read as the inside (a scratch running on
/// from a face through the apex) is back to its far side's level there.
fn wide_past_line(
    frame: &GrayImage,
    line: &Line,
    span: Span,
    s: &Sampling,
    past: &Profile,
) -> bool {
    let place = Placement::new(span);
    let (dir, n) = (place.dir, line.normal);
    let first = s.margin_px + s.inside_px.round() + DEEP_GAP_PX;
    let mut shares = [0.0; STATIONS];
    for (k, share) in shares.iter_mut().enumerate().take(past.stations) {
        let centre = place.centre(line, k);
        let depths = (0..DEEP_ROWS).map(|d| first + d as f64);
        let step = past.ratio[k] * past.step;
        let outside = past.inside[k] - step;
        *share = run_level(frame, centre, dir, n, place.along, depths)
            .map_or(0.0, |level| (level - outside) / step);
    }
    median(&shares, past.stations.max(1)) >= DEEP_SHARE
}

/// Past the apex, a level this share of the way from the surroundings' to the
/// probe's is a body over the tip. A face whose corner a particle beside it hides
/// (rendered suites 1-15 and 31, real-background seeds 5, 7, 9, 13, 21-24 and 71)
/// leaves at most 0.57 there; the tips under a patch at the probe's level that
/// passed without this check (adversarial seeds 4242, 7, 99, 11 and 12) 0.8-1.3.
/// The rigid engine reads its tips past the apex with the same rule.
pub(super) const COVERED_APEX_SHARE: f64 = 0.5;
/// Half the width of the strip read past the apex, pixels (five pixels wide).
pub(super) const PAST_APEX_HALF_PX: i32 = 2;

/// Whether the apex lies under a body at the probe's level: beyond it, along the
/// outward bisector of the faces (from the blurred corner on, the inside sample's
/// depth, five pixels wide), the frame is nearer the level of the probe's side than
/// that of the surroundings, both taken from the `faces`' stations that show them.
/// A particle touching the tip beside one face leaves the surroundings past the
/// apex; a patch over the tip does not.
fn apex_covered(
    frame: &GrayImage,
    t: &Template,
    pose: &Pose,
    s: &Sampling,
    faces: &[Option<(Span, Profile, Option<Line>)>; 3],
) -> bool {
    let inward = add(t.line(pose, BLUE).normal, t.line(pose, GREEN).normal);
    let len = norm(inward);
    if len < 1e-9 {
        return false;
    }
    let out = scale(inward, -1.0 / len);
    let (mut probe, mut around, mut n) = (0.0, 0.0, 0usize);
    for (_, p, _) in faces.iter().flatten() {
        for k in (0..p.stations).filter(|&k| p.held(k)) {
            probe += p.inside[k];
            around += p.inside[k] - p.ratio[k] * p.step;
            n += 1;
        }
    }
    if n == 0 {
        return false;
    }
    let rows = s.inside_px.max(3.0).round() as usize + 1;
    let from = add(pose.apex, scale(out, s.margin_px + 1.0));
    let Some(beyond) = strip_mean(from, out, rows, PAST_APEX_HALF_PX, |q| grey(frame, q)) else {
        return false;
    };
    let (probe, around) = (probe / n as f64, around / n as f64);
    (beyond - around) / (probe - around) > COVERED_APEX_SHARE
}

/// A beam edge looked for over every scale ([`beam_edge_scale`]) is taken where its
/// median step is at least this share of the calibrated one.
const FOUND_RATIO: f64 = 0.5;
/// That search first tries every this many pixels of the beam edge's distance from
/// the apex, and every pixel around those whose median step reaches [`SCAN_RATIO`].
const SCAN_STEP_PX: i64 = 5;
const SCAN_RATIO: f64 = 0.3;

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
    // The beam edge's distance from the apex per unit of scale.
    let per_scale = t.edges[RED].offset.abs();
    if per_scale < 1e-9 {
        return None;
    }
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

/// The smallest scale above `pose`'s at which the beam edge lies out of view, for a
/// tip the fit placed from its two faces alone and refused for its beam edge: the
/// faces fix the apex and the rotation, and when they run out of the frame nothing
/// in view fixes the scale. A scale that puts the beam edge inside the frame where
/// the frame does not show it is contradicted; one that puts it beyond the border,
/// within its slack, is not. The caller verifies the tip again at that scale (where
/// a face ending in view still pins the scale, [`face_ends`]); nothing is accepted
/// here. `None` when the beam edge's line crosses the frame at every scale.
pub fn beam_out_of_view_scale(
    frame: &GrayImage,
    t: &Template,
    pose: &Pose,
    blur_px: f64,
) -> Option<f64> {
    let size = [frame.width() as f64, frame.height() as f64];
    let per_scale = t.edges[RED].offset.abs();
    if per_scale < 1e-9 {
        return None;
    }
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
fn locate_steps(
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
fn turned_face(
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
const END_SPAN: f64 = 0.3;
/// Stations over a face's end that may go against the measured end.
const END_AGAINST: usize = 1;
/// How far, as a share of its length, a face may end from its predicted base: the
/// stations over its end are that far apart, and a face's end is blurred.
const END_SLACK: f64 = 0.1;
/// A face's end is where its step fades below half the step the face shows along its
/// length (its median ratio, taken between this and 1): a face drawn fainter than
/// calibrated, by charging or on another body, ends where it fades to half of its
/// own step, not of the calibrated one.
const END_SHOWN_MIN: f64 = 0.3;

/// Where a face's step ends along its predicted line, as a share of its predicted
/// length (1 at the predicted base), from its stations over its end (`end`,
/// [`end_profile`]), the face showing `shown` of its calibrated step along its length
/// ([`END_SHOWN_MIN`]); `None` when its stations are not all in view.
fn face_end(end: &Profile, shown: f64) -> Option<f64> {
    let j = located_end(end, shown)?;
    Some(1.0 - END_SPAN + 2.0 * END_SPAN * j)
}

/// The stations of face `e` over its end, [`END_SPAN`] of its predicted length either
/// side of its predicted base.
fn end_profile(
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
fn runs_throughout(p: &Profile, shown: f64) -> bool {
    p.stations == STATIONS && stepping(p, located_ratio(shown)) + END_AGAINST >= STATIONS
}

/// Where a face ends at the latest when its step is absent over its whole end
/// ([`absent_throughout`] on its stations over it, `end`): before the first of them.
/// `None` when it is not.
fn lost_end(end: &Profile, shown: f64) -> Option<f64> {
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
fn runs_out(
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

/// Whether each face shows its step to the end the pose gives it in view (its base,
/// or the border it leaves the frame by): over the far [`RUN_SPAN`] of its stretch
/// in view, the step does not end ([`located_end`], at [`LOCATED_RATIO`] of the step
/// the face shows along its length) before the last [`RUN_SLACK`] of that stretch. A
/// tip whose beam edge is placed out of view ([`beam_out_of_view_scale`], the
/// smallest such scale) has only its faces to fix the scale: a face ending before
/// that scale's end says the pyramid is smaller than any scale that hides the beam,
/// whatever lies beyond the face (the beam of a probe of another geometry at the
/// pyramid's level, a patch's border).
pub fn faces_run_to_border(
    frame: &GrayImage,
    t: &Template,
    pose: &Pose,
    blur_px: f64,
    calibrated: &[f64; 3],
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
fn face_ends([back, front]: [Option<f64>; 2]) -> Option<Miss> {
    let (b, g) = (back? - 1.0, front? - 1.0);
    (b * g > 0.0 && b.abs().min(g.abs()) > END_SLACK).then_some(Miss::ScaleMismatch)
}

/// How far behind the back face's base the lower face is checked, in tip heights:
/// beyond, the bending beam leaves the straight line by pixels at high magnification.
const LOWER_FACE_HEIGHTS: f64 = 0.3;

/// The beam's lower face behind the pyramid, where calibration measured the beam's
/// thickness: parallel to the beam edge, that thickness below it, from the back face's
/// base towards the clamp for [`LOWER_FACE_HEIGHTS`] tip heights. A beam of another thickness has the
/// surroundings (thinner) or the beam (thicker) on both sides of it there: refused as
/// `Miss::ScaleMismatch` when more than 3 of its stations show nothing. Measured from
/// `red`, the beam edge where the frame shows it: fitted, or found within the slack
/// with all of that slack in view when the fit left it out (placed from the faces
/// alone, its distance is known to a few per cent, pixels at high magnification, and
/// one found where the slack leaves the frame may be another line); not checked
/// where the beam is too thin at this scale for both sample runs, or too little of
/// that stretch is in view.
fn lower_face(
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
fn free_end(
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
fn locate_end(
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_step_is_located_at_its_centre_not_at_its_first_offset() {
        // A sharp step between x = 99 and 100 (the probe to the right), predicted
        // 3.5 px to its right: each station finds it there, though its samples lie
        // clear of it and show the whole step over several offsets.
        let frame = GrayImage::from_fn(200, 200, |x, _| {
            image::Luma([if x >= 100 { 200 } else { 60 }])
        });
        let line = Line {
            normal: [1.0, 0.0],
            rho: 103.0,
        };
        let s = Sampling::new(1.0, 20.0);
        let located = locate_steps(&frame, &line, ([103.0, 40.0], [103.0, 160.0]), &s, 140.0);
        for (ratio, offset) in located {
            assert!(ratio > 0.95, "{ratio}");
            assert!((offset + 3.5).abs() <= 0.25, "{offset}");
        }
    }

    /// The toy pyramid under a beam 10 reference pixels thick.
    fn toy_under_beam() -> Template {
        Template {
            beam_px: Some(10.0),
            ..super::super::template::toy()
        }
    }

    /// The probe of `t` at `pose` (200) on 50, its pyramid drawn only below
    /// `pyramid_from_y` (faces fading into the ground above), its beam only if `beam`.
    fn probe_frame(t: &Template, pose: &Pose, pyramid_from_y: f64, beam: bool) -> GrayImage {
        let lines = [RED, BLUE, GREEN].map(|e| t.line(pose, e));
        let (free, far) = t.segment(pose, RED);
        let len = norm(sub(far, free));
        let dir = scale(sub(far, free), 1.0 / len);
        let thick = t.beam_px.unwrap() * pose.scale;
        GrayImage::from_fn(400, 300, |x, y| {
            let p = [f64::from(x), f64::from(y)];
            let pyramid = lines.iter().all(|l| l.depth(p) >= 0.0) && p[1] >= pyramid_from_y;
            let along_beam = dot(sub(p, free), dir);
            let in_beam = beam
                && (0.0..=thick).contains(&lines[RED].depth(p))
                && (0.0..=len).contains(&along_beam);
            image::Luma([if pyramid || in_beam { 200 } else { 50 }])
        })
    }

    #[test]
    fn a_beam_out_of_view_is_placed_beyond_the_border_and_the_faces_run_to_it() {
        // The toy pyramid pointing down, its apex 60 px below the top border and its
        // beam above it: the faces run out of the frame, nothing in view gives the
        // scale. Placed at 0.8, the beam edge lies in view, where the frame does not
        // show it.
        let t = toy_under_beam();
        let truth = Pose {
            psi: 0.0,
            scale: 2.5,
            apex: [200.0, 60.0],
        };
        let placed = Pose {
            scale: 0.8,
            ..truth
        };
        let frame = probe_frame(&t, &truth, 0.0, true);
        let scale = beam_out_of_view_scale(&frame, &t, &placed, 1.0).unwrap();
        // The smallest such scale: the beam edge's stretch, its slack nearer the apex,
        // just out of the stations' reach of the frame (6.5 px here; the red line 50
        // reference px above the apex, a pixel of depth 0.02 of scale).
        let nearest_y = |scale: f64| 60.0 - (1.0 - RED_SLACK) * 50.0 * scale;
        assert!(scale > placed.scale && nearest_y(scale) < 6.5, "{scale}");
        assert!(nearest_y(scale - 0.02) >= 6.5, "{scale}");
        let out = Pose { scale, ..truth };
        assert!(faces_run_to_border(&frame, &t, &out, 1.0, &[150.0; 3]));
        // Faces ending 30 px below the border, 13 px short of the stretch the stations
        // cover: the pyramid is smaller than any scale that hides the beam.
        let short = probe_frame(&t, &truth, 30.0, true);
        assert!(!faces_run_to_border(&short, &t, &out, 1.0, &[150.0; 3]));
    }

    #[test]
    fn the_beam_edge_is_found_at_its_own_scale() {
        let t = toy_under_beam();
        let truth = Pose {
            psi: 0.02,
            scale: 2.5,
            apex: [220.0, 250.0],
        };
        // Faces seen only over their last 60 pixels to the apex: the scale the fit
        // left them at is far off.
        let frame = probe_frame(&t, &truth, 190.0, true);
        for guess in [0.8, 1.6, 3.5] {
            let placed = Pose {
                scale: guess,
                ..truth
            };
            let found = beam_edge_scale(&frame, &t, &placed, 1.0, 150.0).unwrap();
            // To the pixel of the beam edge's distance (50 reference pixels per scale).
            assert!(
                (found - truth.scale).abs() <= 1.0 / 50.0,
                "{guess}: {found}"
            );
        }
        // No beam: no line anywhere the beam edge could lie.
        let bare = probe_frame(&t, &truth, 190.0, false);
        assert_eq!(beam_edge_scale(&bare, &t, &truth, 1.0, 150.0), None);
    }

    /// The toy pyramid with its faces meeting the beam's lower face at their bases (50
    /// reference pixels from the apex, 60 deg from the beam), turned 0.45 rad at
    /// scale 2 with its apex at `apex`: in a 400 x 300 frame, the beam edge slants
    /// across the top border.
    fn toy_slanted(apex: [f64; 2]) -> (Template, Pose) {
        let t = Template {
            beam_px: Some(50.0 - 50.0 * 60f64.to_radians().sin()),
            ..super::super::template::toy()
        };
        let pose = Pose {
            psi: 0.45,
            scale: 2.0,
            apex,
        };
        (t, pose)
    }

    #[test]
    fn a_face_ending_at_its_base_demands_the_beam_edge_in_view() {
        // The slanted toy probe: the beam edge's slack reaches out of the frame; the
        // front face's base and the stretch past it are in view.
        let (t, pose) = toy_slanted([280.0, 115.0]);
        let lines = [RED, BLUE, GREEN].map(|e| t.line(&pose, e));
        let thick = t.beam_px.unwrap() * pose.scale;
        // The pyramid up to the beam's lower face, and the beam if `beam`; or a
        // pyramid running on to the beam edge's line with no beam.
        let frame = |beam: bool, running_on: bool| {
            GrayImage::from_fn(400, 300, |x, y| {
                let p = [f64::from(x), f64::from(y)];
                let depth = lines[RED].depth(p);
                let faces = lines[BLUE].depth(p) >= 0.0 && lines[GREEN].depth(p) >= 0.0;
                let pyramid = faces && depth >= if running_on { 0.0 } else { thick };
                let in_beam = beam && (0.0..=thick).contains(&depth);
                image::Luma([if pyramid || in_beam { 200 } else { 50 }])
            })
        };
        let check =
            |f: &GrayImage| check_edges(f, &t, &pose, 1.0, &[150.0; 3], [false, true, true]);
        assert_eq!(check(&frame(true, false)), None);
        assert_eq!(
            check(&frame(false, false)),
            Some(Miss::EdgeMissing(Edge::Red.into()))
        );
        // Faces running on past their bases do not pin the scale: a beam edge beyond
        // the border is allowed.
        assert_eq!(check(&frame(false, true)), None);
    }

    #[test]
    fn faces_disagreeing_on_the_scale_without_the_beam_edge_are_refused() {
        // The slanted toy probe without its beam: the pyramid drawn to 0.85 of its
        // faces' length, and a strip inside the front face running on past its base
        // to the border (a pyramid of another shape, or a mirrored one). The beam
        // edge's slack reaches out of the frame.
        let (t, pose) = toy_slanted([280.0, 130.0]);
        let lines = [RED, BLUE, GREEN].map(|e| t.line(&pose, e));
        let at_apex = lines[RED].depth(pose.apex);
        let at_base = lines[RED].depth(t.segment(&pose, BLUE).1);
        let cut = at_apex + 0.85 * (at_base - at_apex);
        let frame = |strip_px: f64, whole: bool| {
            GrayImage::from_fn(400, 300, |x, y| {
                let p = [f64::from(x), f64::from(y)];
                let (back, front) = (lines[BLUE].depth(p), lines[GREEN].depth(p));
                let faces = back >= 0.0 && front >= 0.0;
                let pyramid = faces && (whole || lines[RED].depth(p) >= cut);
                let strip = faces && front <= strip_px;
                image::Luma([if pyramid || strip { 200 } else { 50 }])
            })
        };
        let check =
            |f: &GrayImage| check_edges(f, &t, &pose, 1.0, &[150.0; 3], [false, true, true]);
        assert_eq!(check(&frame(12.0, false)), Some(Miss::ScaleMismatch));
        // Both faces ending short agree with each other (and are refused for it);
        // both running on to the border leave the scale free.
        assert_eq!(check(&frame(0.0, false)), Some(Miss::ScaleMismatch));
        assert_eq!(check(&frame(0.0, true)), None);
    }

    /// The toy pyramid pointing down (apex angle 60 deg) under its beam, at scale 2.5
    /// with its apex at (220, 250).
    fn toy_down() -> (Template, Pose) {
        let pose = Pose {
            psi: 0.0,
            scale: 2.5,
            apex: [220.0, 250.0],
        };
        (toy_under_beam(), pose)
    }

    /// Paints a disc of radius `r` at grey `level` centred on `centre` into `frame`.
    fn paint_disc(frame: &mut GrayImage, centre: [f64; 2], r: f64, level: u8) {
        for (x, y, px) in frame.enumerate_pixels_mut() {
            if norm(sub([f64::from(x), f64::from(y)], centre)) <= r {
                px.0 = [level];
            }
        }
    }

    /// [`toy_down`]'s frame with a disc of radius `r` at the probe's level, its centre
    /// `along` pixels from the apex on face `e`'s line and `off` pixels outside it.
    fn disc_beside_face(e: usize, along: f64, off: f64, r: f64) -> GrayImage {
        let (t, pose) = toy_down();
        let (tip, base) = t.segment(&pose, e);
        let up = scale(sub(base, tip), 1.0 / norm(sub(base, tip)));
        let out = scale(t.line(&pose, e).normal, -1.0);
        let centre = add(add(pose.apex, scale(up, along)), scale(out, off));
        let mut frame = probe_frame(&t, &pose, 0.0, true);
        paint_disc(&mut frame, centre, r, 200);
        frame
    }

    #[test]
    fn a_face_hidden_at_the_apex_is_a_particle_only_while_the_apex_shows() {
        // The toy pyramid pointing down, and a disc at the probe's level beside its
        // back face: touching the face near the apex (the apex clear), or over the
        // apex and the face's first stretch.
        let (t, pose) = toy_down();
        let with_disc = |along, off, r| disc_beside_face(BLUE, along, off, r);
        let s = Sampling::new(1.0, t.beam_px.unwrap() * pose.scale);
        let corner_held = |frame: &GrayImage, e: usize| {
            let partner = t.line(&pose, if e == BLUE { GREEN } else { BLUE });
            let (a, b, corner) = station_span(&t, &pose, e, [400.0, 300.0], &s).unwrap();
            assert!(corner);
            profile(frame, &t.line(&pose, e), (a, b), Some(&partner), &s, 150.0).corner_held()
        };
        let check = |f: &GrayImage| check_edges(f, &t, &pose, 1.0, &[150.0; 3], [true; 3]);
        let touching = with_disc(19.0, 14.0, 14.0);
        let over = with_disc(10.0, 6.0, 18.0);
        for frame in [&touching, &over] {
            assert!(!corner_held(frame, BLUE) && corner_held(frame, GREEN));
        }
        assert_eq!(check(&touching), None);
        assert_eq!(check(&over), Some(Miss::EdgeMissing(Edge::Blue.into())));
    }

    #[test]
    fn a_face_losing_its_base_to_a_body_at_its_level_keeps_a_measured_scale() {
        // The toy pyramid pointing down, and a disc at the probe's level over about
        // the last third of its front face, its centre outside: the face's last
        // stations show no step, their inside at the probe's level. With the beam edge
        // in the fit, its scale stands; without it, the face is shorter than the placed
        // scale's.
        let (t, pose) = toy_down();
        let (tip, base) = t.segment(&pose, GREEN);
        let len = norm(sub(base, tip));
        let frame = disc_beside_face(GREEN, 0.85 * len, 0.1 * len, 0.2 * len);
        let check = |fitted| check_edges(&frame, &t, &pose, 1.0, &[150.0; 3], fitted);
        assert_eq!(check([true; 3]), None);
        assert_eq!(check([false, true, true]), Some(Miss::ScaleMismatch));
    }

    #[test]
    fn a_border_running_on_past_the_apex_is_not_a_face() {
        // The toy pyramid pointing down under its beam, and a patch darker than the
        // ground beside its back face: up to the apex, or on past it as the border of
        // a patch over a tip would run.
        let t = toy_under_beam();
        let pose = Pose {
            psi: 0.0,
            scale: 2.5,
            apex: [220.0, 250.0],
        };
        let blue = t.line(&pose, BLUE);
        let (tip, base) = t.segment(&pose, BLUE);
        let up = sub(base, tip);
        let with_patch = |past_apex: bool| {
            let mut frame = probe_frame(&t, &pose, 0.0, true);
            for (x, y, px) in frame.enumerate_pixels_mut() {
                let p = [f64::from(x), f64::from(y)];
                // Along the face from its base, to the apex or on past it.
                let along = dot(sub(p, tip), up) / dot(up, up);
                if blue.depth(p) < 0.0 && along <= 1.0 && (past_apex || along >= 0.0) {
                    px.0 = [20];
                }
            }
            frame
        };
        let check = |f: &GrayImage| check_edges(f, &t, &pose, 1.0, &[150.0; 3], [true; 3]);
        assert_eq!(check(&probe_frame(&t, &pose, 0.0, true)), None);
        assert_eq!(check(&with_patch(false)), None);
        assert_eq!(
            check(&with_patch(true)),
            Some(Miss::EdgeMissing(Edge::Blue.into()))
        );
        // A scratch at the probe's level, 3 px wide, running on from the face along
        // its line past the apex: a line, not a border.
        let mut scratched = probe_frame(&t, &pose, 0.0, true);
        for (x, y, px) in scratched.enumerate_pixels_mut() {
            let p = [f64::from(x), f64::from(y)];
            let along = dot(sub(p, tip), up) / dot(up, up);
            if (0.0..3.0).contains(&blue.depth(p)) && (-1.0..0.0).contains(&along) {
                px.0 = [200];
            }
        }
        assert_eq!(check(&scratched), None);
    }

    #[test]
    fn a_thicker_beam_shows_below_the_corner_behind_a_short_overhang() {
        // The toy pyramid with a front face 5 deg from the vertical and its beam's free
        // end 5 reference pixels from the apex's foot: the front face meets the beam's
        // lower face 1.5 reference pixels before the free end, too short an overhang to
        // check, and runs 4-6 px from the end face's line below the corner, where the
        // end face's samples on the beam's side lie. The probe as calibrated (a beam
        // 10 reference pixels thick) and one whose beam is 2.5 times thicker: only
        // samples clear of the front face tell them apart.
        let mut t = toy_under_beam();
        let (sin, cos) = 5f64.to_radians().sin_cos();
        t.edges[GREEN].normal = [-cos, -sin];
        t.edges[RED].tip_tau = 5.0;
        let pose = Pose {
            psi: 0.1,
            scale: 2.5,
            apex: [200.0, 230.0],
        };
        let red = t.line(&pose, RED);
        let s = Sampling::new(1.0, t.beam_px.unwrap() * pose.scale);
        let thicker = Template {
            beam_px: Some(25.0),
            ..t
        };
        let free_end_of = |drawn: &Template| {
            let frame = probe_frame(drawn, &pose, 0.0, true);
            free_end(&frame, &t, &pose, &red, &s, 150.0)
        };
        assert_eq!(free_end_of(&t), None);
        assert_eq!(free_end_of(&thicker), Some(Miss::ScaleMismatch));
    }

    #[test]
    fn a_beam_thicker_by_less_than_its_thickness_shows_below_the_corner() {
        // The toy pyramid under a beam 1.6 times as thick as calibrated (the apex and
        // the scale where calibration puts them): its end face runs on below the corner
        // over 0.6 of the next thickness, short of 70 % of it but over all of its first
        // half. A disc brighter than the beam beside the end face there covers some of
        // those stations without hiding the rest.
        let t = toy_under_beam();
        let pose = Pose {
            psi: 0.1,
            scale: 4.0,
            apex: [150.0, 260.0],
        };
        let red = t.line(&pose, RED);
        let beam_px = t.beam_px.unwrap() * pose.scale;
        let s = Sampling::new(1.0, beam_px);
        let thicker = Template {
            beam_px: Some(16.0),
            ..t
        };
        let (free, far) = t.segment(&pose, RED);
        let out = scale(sub(free, far), 1.0 / norm(sub(free, far)));
        // Beside the end face's line, 5 px out, 1.45 thicknesses below the beam edge.
        let centre = add(
            add(free, scale(out, 5.0)),
            scale(red.normal, 1.45 * beam_px),
        );
        let free_end_of = |drawn: &Template, disc: bool| {
            let mut frame = probe_frame(drawn, &pose, 0.0, true);
            if disc {
                paint_disc(&mut frame, centre, 4.0, 250);
            }
            free_end(&frame, &t, &pose, &red, &s, 150.0)
        };
        assert_eq!(free_end_of(&t, false), None);
        assert_eq!(free_end_of(&t, true), None);
        assert_eq!(free_end_of(&thicker, false), Some(Miss::ScaleMismatch));
        assert_eq!(free_end_of(&thicker, true), Some(Miss::ScaleMismatch));
    }

    #[test]
    fn a_tip_too_small_to_check_its_faces_is_refused() {
        let t = toy_under_beam();
        // Faces of 50 reference pixels at a scale of 0.4: 20 px each.
        let pose = Pose {
            psi: 0.0,
            scale: 0.4,
            apex: [220.0, 250.0],
        };
        let frame = probe_frame(&t, &pose, 0.0, true);
        let miss = check_edges(&frame, &t, &pose, 1.0, &[150.0; 3], [true; 3]);
        assert_eq!(miss, Some(Miss::ScaleMismatch));
    }

    #[test]
    fn a_face_leaving_the_frame_must_run_to_the_border() {
        // At a scale that puts its faces' bases 100 px above the frame.
        let t = toy_under_beam();
        let pose = Pose {
            psi: 0.0,
            scale: 8.0,
            apex: [220.0, 250.0],
        };
        let s = Sampling::new(1.0, 80.0);
        let runs_out_from = |pyramid_from_y: f64| {
            let frame = probe_frame(&t, &pose, pyramid_from_y, false);
            let size = [400.0, 300.0];
            [BLUE, GREEN].map(|e| {
                let (_, b, _) = station_span(&t, &pose, e, size, &s).unwrap();
                runs_out(&frame, &t, &pose, e, b, size, &s, 150.0, 1.0)
            })
        };
        // To the border, and ending a twentieth of their 250 px in view short of it.
        assert_eq!(runs_out_from(0.0), [false, false]);
        assert_eq!(runs_out_from(12.5), [false, false]);
        // Ending a fifth and four tenths short.
        assert_eq!(runs_out_from(50.0), [true, true]);
        assert_eq!(runs_out_from(100.0), [true, true]);
    }

    #[test]
    fn the_free_end_is_located_where_the_beam_stops() {
        // A beam (200) from the left edge to x = 100 between y = 50 and 70, on 50.
        let frame = GrayImage::from_fn(200, 120, |x, y| {
            image::Luma([if x <= 100 && (50..=70).contains(&y) {
                200
            } else {
                50
            }])
        });
        let red = Line::through([0.0, 50.0], [0.0, 1.0]);
        let (at, ratio) = locate_end(
            &frame,
            &red,
            [94.0, 50.0],
            [1.0, 0.0],
            (2.0, 18.0),
            10.0,
            150.0,
        )
        .unwrap();
        // The beam's last pixel (x = 100); the first dark one ties with it.
        assert_eq!(at, 6.0);
        assert!((ratio - 1.0).abs() < 1e-9, "{ratio}");
        // Half of the band beyond the frame: not judged.
        assert!(locate_end(
            &frame,
            &red,
            [194.0, 50.0],
            [1.0, 0.0],
            (2.0, 18.0),
            10.0,
            150.0
        )
        .is_none());
    }

    /// A frame bright (200) right of the vertical line x = 100, dark (50) left of it.
    fn half_plane() -> GrayImage {
        GrayImage::from_fn(200, 200, |x, _| {
            image::Luma([if x > 100 { 200 } else { 50 }])
        })
    }

    /// The line through (100, 100) whose inward normal points `deg` from +x, and its
    /// stretch 40 px either side of that point.
    fn predicted(deg: f64) -> (Line, ([f64; 2], [f64; 2])) {
        let (s, c) = deg.to_radians().sin_cos();
        let centre = [100.0, 100.0];
        let dir = [-s, c];
        let a = [centre[0] - 40.0 * dir[0], centre[1] - 40.0 * dir[1]];
        let b = [centre[0] + 40.0 * dir[0], centre[1] + 40.0 * dir[1]];
        (Line::through(centre, [c, s]), (a, b))
    }

    /// A face's profile: every station shows the step from the probe's level, except
    /// the corner stations, which step from `corner_inside` with `corner_ratio`.
    fn face_profile(corner_inside: f64, corner_ratio: f64) -> Profile {
        let mut p = Profile {
            stations: STATIONS,
            ratio: [1.0; STATIONS],
            inside: [210.0; STATIONS],
            step: 130.0,
            corner_in_view: true,
        };
        for k in 0..END_STATIONS - 1 {
            p.inside[k] = corner_inside;
            p.ratio[k] = corner_ratio;
        }
        p
    }

    #[test]
    fn a_face_lost_over_its_whole_end_ends_before_it() {
        // Stations over a face's end (`end_profile`): the step to the base, absent
        // past it; absent throughout; and a faint face (showing 0.6 of its
        // calibrated step) whose stations hover about the ratio that locates it.
        let end = |ratio: [f64; STATIONS]| Profile {
            ratio,
            ..face_profile(210.0, 1.0)
        };
        let at_base = end([1.0, 1.0, 0.9, 1.0, 1.0, 0.1, 0.0, -0.1, 0.0, 0.1]);
        let absent = end([0.1, 0.0, -0.1, 0.1, 0.0, 0.1, 0.0, 0.0, -0.5, -1.0]);
        let faint = end([0.03, 0.28, 0.32, 0.17, 0.2, 0.04, -0.04, 0.06, -0.1, -0.3]);
        assert_eq!(lost_end(&at_base, 1.0), None);
        assert_eq!(lost_end(&absent, 1.0), Some(1.0 - END_SPAN));
        assert_eq!(lost_end(&faint, 0.6), None);
        // Its partner ending short as well: both faces short, another scale.
        let short = Some(0.82);
        assert_eq!(
            face_ends([short, lost_end(&absent, 1.0)]),
            Some(Miss::ScaleMismatch)
        );
        assert_eq!(
            face_ends([face_end(&at_base, 1.0), lost_end(&absent, 1.0)]),
            None
        );
    }

    #[test]
    fn a_corner_shows_its_face_only_from_the_probes_level() {
        // The probe's own corner, its step fading into the blur at the apex.
        assert!(face_profile(195.0, 0.3).corner_held());
        // A patch darker than the surroundings over the tip: its border steps the
        // face's way, from the patch's level.
        assert!(!face_profile(77.0, 0.3).corner_held());
        assert!(!face_profile(77.0, 0.3).corner_inside_probe());
    }

    #[test]
    fn a_face_turned_from_the_prediction_is_told_apart() {
        let frame = half_plane();
        let s = Sampling::new(1.0, 20.0);
        for (deg, turned) in [(0.0, false), (12.0, true), (-12.0, true), (3.0, false)] {
            let (line, span) = predicted(deg);
            let p = profile(&frame, &line, span, None, &s, 150.0);
            assert_eq!(
                turned_face(&frame, &line, span, None, &s, &p, 1.0),
                turned,
                "predicted {deg} deg off"
            );
        }
    }

    #[test]
    fn a_faint_face_is_told_turned_at_the_step_its_partner_shows() {
        // The probe drawn at 0.4 of its calibrated step: a face 12 deg off locates
        // its step at half of what the partner face shows, not at half the
        // calibrated step, which no station reaches.
        let frame = GrayImage::from_fn(200, 200, |x, _| {
            image::Luma([if x > 100 { 110 } else { 50 }])
        });
        let s = Sampling::new(1.0, 20.0);
        for (deg, partner, turned) in [
            (12.0, 0.4, true),
            (-12.0, 0.4, true),
            (12.0, 1.0, false),
            (0.0, 0.4, false),
            (3.0, 0.4, false),
        ] {
            let (line, span) = predicted(deg);
            let p = profile(&frame, &line, span, None, &s, 150.0);
            assert_eq!(
                turned_face(&frame, &line, span, None, &s, &p, partner),
                turned,
                "predicted {deg} deg off, partner showing {partner}"
            );
        }
    }
}
