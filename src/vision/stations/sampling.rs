//! Stations along a predicted edge: where each samples across it ([`Sampling`]), what
//! it reads there ([`Profile`]: its step over the calibrated one, the levels on either
//! side), and the verdict on one edge alone ([`Profile::refusal`]). The checks of the
//! sibling modules read their stations through [`profile`].

use image::GrayImage;

use crate::vision::geometry::{add, clip_to_rect, norm, scale, sub, Line};
use crate::vision::template::{Pose, Template, BLUE, GREEN, RED};
use crate::vision::{Edge, Miss};

/// Stations sampled along each edge.
pub const STATIONS: usize = 10;
/// A station shows the edge when its step is at least this share of the calibrated
/// step, with its sign. A hidden or absent edge steps by nothing (or the other way); a
/// true face whose apex dips into a bright substrate keeps 0.15-0.35 of its
/// clean-reference step there.
pub(super) const HOLD_RATIO: f64 = 0.1;
/// Share of an edge's stations that must show it.
pub(super) const HELD_SHARE: f64 = 0.7;
/// Stations at each end of an edge: at the corner end all but one must show it (a tip
/// under a patch fails there), at a face's far end at least one must show it or be
/// covered (a face running short of the calibrated geometry at this scale fails there).
pub(super) const END_STATIONS: usize = 3;
/// A face whose last this many stations toward its base show nothing is longer than
/// the probe's at this scale (or runs on where the probe's does not).
const FAR_MISSING: usize = 3;
/// The probe's side of every edge in view is one body: their levels agree within this
/// share of the calibrated beam step.
pub(super) const INSIDE_SPREAD: f64 = 0.5;
/// A station whose outside is brighter than its inside (a particle, a substrate) still
/// shows the probe when its inside lies within this share of the calibrated step of
/// the probe's level along the edge.
const COVERED_LEVEL: f64 = 0.25;
/// A beam edge the fit left out is looked for parallel to its predicted line, up to
/// this share of the apex's distance from it either way: a tip placed from its two
/// faces alone has its scale, hence that distance, known to a few per cent.
pub(super) const RED_SLACK: f64 = 0.1;
/// Along-edge half length of a station's sample run, pixels (at most).
const STATION_HALF_PX: f64 = 3.0;
/// Shortest visible stretch of an edge that is checked, frame pixels.
pub(super) const MIN_CHECKED_PX: f64 = 12.0;

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
    pub(super) fn at_pose(t: &Template, pose: &Pose, blur_px: f64) -> Sampling {
        let beam_px = t.line(pose, RED).depth(t.segment(pose, BLUE).1).abs();
        Sampling::new(blur_px, beam_px)
    }

    pub(super) fn reach(&self) -> f64 {
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
pub(super) fn median<const N: usize>(v: &[f64; N], n: usize) -> f64 {
    let mut s = *v;
    s[..n].sort_unstable_by(f64::total_cmp);
    if n % 2 == 1 {
        s[n / 2]
    } else {
        0.5 * (s[n / 2 - 1] + s[n / 2])
    }
}

impl Profile {
    pub(super) fn held(&self, k: usize) -> bool {
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
    pub(super) fn covered(&self, k: usize, probe_level: f64) -> bool {
        self.ratio[k] <= -HOLD_RATIO && self.at_probe_level(k, probe_level)
    }

    /// Whether station `k`'s inside lies within [`COVERED_LEVEL`] of the calibrated
    /// step of `probe_level`.
    pub(super) fn at_probe_level(&self, k: usize, probe_level: f64) -> bool {
        self.inside_within(k, probe_level, COVERED_LEVEL)
    }

    /// Whether station `k`'s inside lies within `share` of the calibrated step of
    /// `level`.
    fn inside_within(&self, k: usize, level: f64, share: f64) -> bool {
        (self.inside[k] - level).abs() <= share * self.step.abs()
    }

    /// Whether the [`FAR_MISSING`] stations at the far end keep, on the probe's side,
    /// the probe's level along the rest of the edge.
    pub(super) fn far_end_inside_probe(&self) -> bool {
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
    pub(super) fn outside_level(&self) -> f64 {
        self.held_median(|k| self.inside[k] - self.ratio[k] * self.step)
    }

    /// Median level on the probe's side over the stations that show the edge.
    pub(super) fn held_level(&self) -> f64 {
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
    /// corner is judged with its partner's: [`check_edges`](super::check_edges)).
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
pub(super) fn inside_frame(p: [f64; 2], size: [f64; 2], pad: f64) -> bool {
    p[0] >= pad && p[1] >= pad && p[0] <= size[0] - 1.0 - pad && p[1] <= size[1] - 1.0 - pad
}

/// Where the line from `origin` along `dir` runs at least `pad` pixels inside a frame
/// of `size`: its interval of distances along `dir`.
pub(super) fn clip_inside(
    origin: [f64; 2],
    dir: [f64; 2],
    size: [f64; 2],
    pad: f64,
) -> Option<(f64, f64)> {
    clip_to_rect(
        origin,
        dir,
        [pad, pad],
        [size[0] - 1.0 - pad, size[1] - 1.0 - pad],
    )
}

/// The stretch of edge `e` the stations cover, with whether its corner end is in view.
pub(super) fn station_span(
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
pub(super) fn stretch(
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
pub(super) fn corner_trim(t: &Template, s: &Sampling) -> f64 {
    let (nb, ng) = (t.edges[BLUE].normal, t.edges[GREEN].normal);
    let sin_apex = (nb[0] * ng[1] - nb[1] * ng[0]).abs().max(0.2);
    s.reach() / sin_apex + 1.0
}

/// A stretch of an edge checked by stations: its two ends, frame pixels.
pub(super) type Span = ([f64; 2], [f64; 2]);

/// Where the [`STATIONS`] stations of a span lie: evenly along it, each averaging
/// `along` pixels either side of its centre.
pub(super) struct Placement {
    a: [f64; 2],
    pub(super) dir: [f64; 2],
    pub(super) len: f64,
    pub(super) along: i64,
}

impl Placement {
    pub(super) fn new((a, b): Span) -> Self {
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
    pub(super) fn centre(&self, line: &Line, k: usize) -> [f64; 2] {
        let c = (k as f64 + 0.5) / STATIONS as f64 * self.len;
        line.foot([self.a[0] + c * self.dir[0], self.a[1] + c * self.dir[1]])
    }
}

/// The grey level of the pixel nearest `p`, if it is in the frame.
pub(super) fn grey(frame: &GrayImage, p: [f64; 2]) -> Option<f64> {
    let (x, y) = (p[0].round() as i64, p[1].round() as i64);
    (x >= 0 && y >= 0 && x < i64::from(frame.width()) && y < i64::from(frame.height()))
        .then(|| f64::from(frame.get_pixel(x as u32, y as u32)[0]))
}

/// The mean grey level of a station's run (`along` pixels either side of `centre`
/// on the unit `dir`) at each of `depths` pixels along the normal `n`; `None` when
/// none of it is in the frame.
pub(super) fn run_level(
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
pub(super) fn unit_step(step: f64) -> f64 {
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
