//! Calibration: from a reference image and a few clicked pixels per edge to the rigid-tip
//! template the tracker searches for.
//!
//! Clicks are off by up to a pixel, so an orientation taken from them is off by tenths
//! of a degree. Each edge is therefore (1) located among the reference's edge pixels near
//! the clicked line, with its polarity (which side is the bright probe), (2) followed
//! along the edge map to find its extent, and (3) refined on the grey levels with the
//! same blurred-step model the tracker uses, each edge on its own. The refined lines
//! give the orientations (so the reference itself reads 0.00 deg), the apex (blue meets
//! green), and the template: offsets and extents relative to the apex, which do not
//! depend on magnification or position.

use image::GrayImage;

use super::bands::{bands, BendPrior};
use super::candidates::angle_gap;
use super::edges::EdgeMap;
use super::geometry::{
    add, along, dot, norm, principal_axis, scale, screen_deg_from_image_rad, sub, Line,
};
use super::options::{CalibrationConfig, TrackerConfig};
use super::pyramid::Pyramid;
use super::refine::{Band, Refiner, Turns};
use super::stations;
use super::template::{PerEdge, Template, TemplateEdge, BLUE, EDGES, GREEN, RED};
use super::{Edge, VisionError};

/// Largest distance (detection pixels) of the edge pixels used from the clicked line.
const CLICK_BAND_PX: f64 = 3.0;
/// Largest gap (detection pixels) bridged when following an edge.
const MAX_GAP_PX: f64 = 3.0;
/// Gradient tolerance when following an edge, radians.
const FOLLOW_ANGLE_RAD: f64 = 0.3;
/// The reference beam is straight: the tracker's bend prior at rest.
const REST_BEND_SIGMA_PX: f64 = 0.03;
/// Faces whose bases lie this close (as a share of the farther one's distance) to
/// equally far from the apex's foot along the beam do not tell which way its free end
/// is (see `free_end`).
pub(super) const SYMMETRIC_BASES: f64 = 0.2;
/// Smallest mean grey-level difference between the two sides of the clicked pixels (3 to
/// 6 px from them) from which an edge's polarity is taken: a face 5 levels above or
/// below its background on a reference with noise 3 measures 4-6, blank ground 0-1.
const MIN_SIDE_CONTRAST: f64 = 2.5;
/// The tracker masks edge pixels with its grey-level threshold only if the probe's
/// side of every calibrated edge clears that threshold on the reference by this share
/// of the edge's contrast (and the probe is brighter across every edge).
const MASK_MARGIN: f64 = 0.25;
/// Initial blur guess for the grey-level fit, pixels.
pub const BLUR0_PX: f64 = 1.2;

/// One calibrated edge.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CalibratedEdge {
    /// Orientation of the refined edge line, degrees CCW on screen, in (-90, 90].
    pub orientation_deg: f64,
    /// The same from the clicks alone (for comparison).
    pub clicked_orientation_deg: f64,
    /// Refined line; its normal points into the probe (whichever side is brighter).
    pub line: Line,
    /// +1 when the probe's side of the edge is the brighter one on the reference, -1
    /// when it is the darker one. Learned from the grey levels beside the clicks; the
    /// tracker looks for this edge's gradient only in this direction.
    pub polarity: f64,
    /// Segment endpoints in the reference: the corner end (apex, or the beam's free end)
    /// first.
    pub segment_px: [[f64; 2]; 2],
    /// Grey-level step across the edge from outside to inside the probe: positive for a
    /// brighter probe, negative for a darker one.
    pub contrast: f64,
    /// Standard error of `orientation_deg`: how well the reference fixes this edge's
    /// direction, its background's structure beside the edge included (the larger of
    /// the fit's formula and the spread of its stretches' scores,
    /// `refine::EdgeResult::turn_sigma_robust`). Every estimate's reported sigma
    /// carries it.
    pub orientation_sigma_deg: f64,
    /// The part of it from the reference's pixel noise alone (the fit's normal
    /// equations): the tracker weighs a frame's edges by it as well as by the frame's
    /// own noise (`refine::Turns::Tied`). Weights from the larger one, estimated from a
    /// few dozen stretches, scatter with it: they put the angle's p95 on
    /// real-background seed 13 at 0.160 deg against 0.135.
    pub orientation_noise_sigma_deg: f64,
}

/// The calibration of one probe: the refined edges and the template built from them.
#[derive(Debug, Clone, PartialEq)]
pub struct Calibration {
    edges: PerEdge<CalibratedEdge>,
    template: Template,
    image_size: [u32; 2],
    blur_px: f64,
    grey_mask: bool,
}

impl Calibration {
    /// Refines the clicked edges on the reference image and learns the tip template.
    pub fn from_reference(
        reference: &GrayImage,
        clicks: &CalibrationConfig,
        cfg: &TrackerConfig,
    ) -> Result<Calibration, VisionError> {
        let (w, h) = reference.dimensions();
        if w < 64 || h < 48 {
            return Err(VisionError::ImageTooSmall {
                width: w,
                height: h,
            });
        }
        let Some(points) = clicks.pyramid_points() else {
            return Err(VisionError::Degenerate(
                "the clicks name edges other than the pyramid's red, blue and green".into(),
            ));
        };
        for (edge, pts) in Edge::ALL.iter().zip(points) {
            check_clicks(*edge, pts, w, h)?;
        }
        let clicked = click_lines(points)?;
        let polarity: PerEdge<f64> = [
            side_polarity(Edge::Red, &clicked[RED], points[RED], reference)?,
            side_polarity(Edge::Blue, &clicked[BLUE], points[BLUE], reference)?,
            side_polarity(Edge::Green, &clicked[GREEN], points[GREEN], reference)?,
        ];
        let mut pyr = Pyramid::default();
        pyr.build(reference);
        let mut map = EdgeMap::default();
        let threshold = pyr.threshold(cfg.threshold);
        let locate_all = |map: &EdgeMap| -> Result<PerEdge<Located>, VisionError> {
            let mut out = [None; EDGES];
            for e in 0..EDGES {
                out[e] = Some(locate(
                    Edge::ALL[e],
                    points[e],
                    clicked[e],
                    polarity[e],
                    &pyr,
                    map,
                )?);
            }
            Ok(out.map(|l| l.expect("every edge located")))
        };
        // A probe brighter than its background across every edge is looked for with the
        // grey-level mask, as the tracker does; if that loses an edge (a bright
        // background above the threshold), or the probe is darker across any edge, the
        // edges are found without it.
        let bright = polarity.iter().all(|&p| p > 0.0);
        let mut masked = bright;
        let coarse = if bright {
            map.detect(&pyr, threshold);
            match locate_all(&map) {
                Ok(c) => c,
                Err(first) => {
                    masked = false;
                    map.detect(&pyr, f32::NEG_INFINITY);
                    locate_all(&map).map_err(|_| first)?
                }
            }
        } else {
            map.detect(&pyr, f32::NEG_INFINITY);
            locate_all(&map)?
        };
        let apex0 = coarse[BLUE]
            .line
            .intersect(&coarse[GREEN].line)
            .ok_or_else(|| VisionError::Degenerate("blue and green are parallel".into()))?;
        // First pass: each edge over its followed extent, to learn the template.
        let followed = std::array::from_fn(|e| Some(band_for(e, &coarse[e], apex0)));
        let first = fit_edges(reference, &followed, BLUR0_PX)?;
        let blur = first.blur;
        let template = build_template(&first.lines, &coarse)?;
        // Second pass on exactly the stretches the tracker fits (the template at rest),
        // so that the reference itself reads zero.
        let at_rest = template.at_rest();
        let size = [w as f64, h as f64];
        let straight = BendPrior {
            mean: 0.0,
            sigma: REST_BEND_SIGMA_PX,
        };
        let second = bands(&template, &at_rest, size, blur, straight);
        let EdgeFits {
            lines,
            contrast,
            level,
            turn_sigma,
            turn_sigma_robust,
            blur,
        } = fit_edges(reference, &second, blur)?;
        for e in 0..EDGES {
            if contrast[e] * polarity[e] <= 0.0 {
                return Err(VisionError::EdgeNotFound {
                    edge: Edge::ALL[e],
                    reason: format!(
                        "the grey-level fit finds the probe's side {} ({:+.1} grey levels), \
                         the clicks' surroundings say {}",
                        side_word(contrast[e]),
                        contrast[e],
                        side_word(polarity[e])
                    ),
                });
            }
        }
        let mut template = build_template(&lines, &coarse)?;
        for e in [BLUE, GREEN] {
            extend_face(reference, &mut template, e, contrast[e], blur);
        }
        template.beam_px = beam_thickness(reference, &template, contrast[RED], blur);
        let grey_mask = masked
            && (0..EDGES).all(|e| {
                level[e] + contrast[e] - f64::from(threshold) >= MASK_MARGIN * contrast[e]
            });
        let edges = std::array::from_fn(|e| {
            let edge = &template.edges[e];
            let place = |tau| {
                let q = edge.point(tau);
                [template.apex[0] + q[0], template.apex[1] + q[1]]
            };
            CalibratedEdge {
                orientation_deg: orientation_deg(&lines[e]),
                clicked_orientation_deg: orientation_deg(&coarse[e].clicked),
                line: lines[e],
                polarity: polarity[e],
                segment_px: [place(edge.tip_tau), place(edge.far_tau)],
                contrast: contrast[e],
                orientation_sigma_deg: turn_sigma_robust[e].to_degrees(),
                orientation_noise_sigma_deg: turn_sigma[e].to_degrees(),
            }
        });
        Ok(Calibration {
            edges,
            template,
            image_size: [w, h],
            blur_px: blur,
            grey_mask,
        })
    }

    /// Whether the tracker applies its grey-level threshold as a mask on edge pixels
    /// (their bright side must reach it): only for a probe brighter than its
    /// background across every edge whose levels cleared the threshold on the
    /// reference. A darker or low-contrast probe is found by its edges alone.
    pub fn grey_mask(&self) -> bool {
        self.grey_mask
    }

    /// +1 when the pyramid is brighter than its surroundings (its faces' contrasts,
    /// summed), -1 when darker.
    pub fn pyramid_polarity(&self) -> f64 {
        (self.edges[BLUE].contrast + self.edges[GREEN].contrast).signum()
    }

    /// The beam's thickness measured on the reference (the depth of its lower face
    /// below the red line, behind the pyramid or at the free end), pixels; `None`
    /// where it was not measured.
    pub fn beam_px(&self) -> Option<f64> {
        self.template.beam_px
    }

    /// The calibrated edge.
    pub fn edge(&self, edge: Edge) -> &CalibratedEdge {
        &self.edges[edge.index()]
    }

    /// The apex (blue meets green) in the reference image, pixels.
    pub fn apex_px(&self) -> [f64; 2] {
        self.template.apex
    }

    /// Size of the reference image.
    pub fn image_size(&self) -> [u32; 2] {
        self.image_size
    }

    /// Blur (Gaussian sigma, pixels) measured on the reference.
    pub fn blur_px(&self) -> f64 {
        self.blur_px
    }

    pub(crate) fn template(&self) -> &Template {
        &self.template
    }
}

/// Profiles across the beam measured for its thickness.
const BEAM_PROFILES: usize = 16;
/// The lower face must step by at least this share of the red edge's contrast.
const BEAM_STEP_SHARE: f64 = 0.4;
/// Share of the profiles in view that must agree on the lower face, within
/// [`BEAM_AGREE_PX`] of their median.
const BEAM_AGREE_SHARE: f64 = 0.6;
/// Fewest profiles in view for a measurement: a quarter of them.
const BEAM_MIN_PROFILES: usize = BEAM_PROFILES / 4;
const BEAM_AGREE_PX: f64 = 1.5;

/// A face whose step runs on past its followed base by this share of its length or
/// more has its base moved to where it ends ([`stations::face_runs_past_base`]):
/// verification's slack for where a face ends (`stations::END_SLACK`).
const BASE_MOVE: f64 = 0.1;

/// Moves face `e`'s base to where the reference's grey levels show its step ending,
/// when that lies well beyond the extent followed on the edge map, which loses a
/// face where a line of the background crosses it. The base stays on the probe's
/// side of the beam edge.
fn extend_face(reference: &GrayImage, template: &mut Template, e: usize, step: f64, blur: f64) {
    let share = stations::face_runs_past_base(reference, template, e, blur, step);
    if share < 1.0 + BASE_MOVE {
        return;
    }
    let mut moved = template.edges[e];
    moved.far_tau *= share;
    let base = add(template.apex, moved.point(moved.far_tau));
    if template.line(&template.at_rest(), RED).depth(base) > 0.0 {
        template.edges[e] = moved;
    }
}

/// The depth of the beam's lower face below the red line, reference pixels: behind
/// the pyramid, on profiles across the beam from the back face's base towards the
/// clamp (one tip height of it); where the beam leaves the reference there, on the
/// overhang in front of the pyramid, between the front face's base and the free end
/// (the rigid block's lower face, where the tracker's free-end check reads it). On
/// each profile it is the first depth where the grey level steps from the probe's to
/// the surroundings' by a good share of red's contrast. A profile that leaves the
/// reference before finding that step is out of view and not counted (a beam running
/// out of a frame's side). `None` when on both stretches fewer than a quarter of the
/// profiles are in view or those in view do not agree.
fn beam_thickness(
    reference: &GrayImage,
    t: &Template,
    red_contrast: f64,
    blur: f64,
) -> Option<f64> {
    let red = &t.edges[RED];
    let toward_clamp = (red.far_tau - red.tip_tau).signum();
    let k = (1.5 * blur).ceil().max(1.0);
    // Where a point's foot on the red line lies, as `tau`.
    let tau_of = |p: [f64; 2]| dot(along(red.normal), sub(p, t.apex));
    let back_base = add(t.apex, t.edges[BLUE].point(t.edges[BLUE].far_tau));
    let behind = tau_of(back_base) + toward_clamp * (2.0 * k + 2.0);
    let measured = lower_face_depth(
        reference,
        t,
        red_contrast,
        k,
        (behind, behind + toward_clamp * t.height),
    );
    if measured.is_some() {
        return measured;
    }
    // The overhang, clear of the free end and of the front face's base by the
    // blurred step's half width and a pixel.
    let front_base = add(t.apex, t.edges[GREEN].point(t.edges[GREEN].far_tau));
    let (from, to) = (
        red.tip_tau + toward_clamp * (k + 1.0),
        tau_of(front_base) - toward_clamp * (k + 1.0),
    );
    if (to - from) * toward_clamp < MIN_OVERHANG_PX {
        return None;
    }
    lower_face_depth(reference, t, red_contrast, k, (from, to))
}

/// Shortest overhang, reference pixels, on which [`beam_thickness`] measures.
const MIN_OVERHANG_PX: f64 = 4.0;

/// [`beam_thickness`] on [`BEAM_PROFILES`] profiles down from the red line at `tau`
/// from `span.0` to `span.1`, the step read between samples `k` either side (each the
/// mean over `k` pixels either side along the beam).
fn lower_face_depth(
    reference: &GrayImage,
    t: &Template,
    red_contrast: f64,
    k: f64,
    span: (f64, f64),
) -> Option<f64> {
    let red = &t.edges[RED];
    let n = red.normal;
    let (w, h) = (reference.width() as f64, reference.height() as f64);
    let pixel = |p: [f64; 2]| -> Option<f64> {
        let (x, y) = (p[0].round(), p[1].round());
        (x >= 0.0 && y >= 0.0 && x <= w - 1.0 && y <= h - 1.0)
            .then(|| f64::from(reference.get_pixel(x as u32, y as u32)[0]))
    };
    // The mean over `k` pixels either side along the beam: a low-contrast beam's
    // lower face is not lost in single pixels' noise.
    let dir = along(n);
    let value = |p: [f64; 2]| -> Option<f64> {
        let mut sum = 0.0;
        let steps = k as i64;
        for j in -steps..=steps {
            sum += pixel(add(p, scale(dir, j as f64)))?;
        }
        Some(sum / (2 * steps + 1) as f64)
    };
    let max_depth = 0.9 * t.height;
    let mut found = [0.0; BEAM_PROFILES];
    let (mut m, mut in_view) = (0, 0);
    for j in 0..BEAM_PROFILES {
        let tau = span.0 + (span.1 - span.0) * j as f64 / BEAM_PROFILES as f64;
        // A point on the red line level with this stretch of beam.
        let top = add(t.apex, red.point(tau));
        let at = |d: f64| add(top, scale(n, d));
        let mut d = k + 1.0;
        // Whether the whole search stays in the reference.
        let mut seen = true;
        while d + k <= max_depth {
            let (Some(a), Some(b)) = (value(at(d - k)), value(at(d + k))) else {
                seen = false;
                break;
            };
            // Probe side (towards red) minus far side, with red's sign.
            let step = (a - b) * red_contrast.signum();
            if step >= BEAM_STEP_SHARE * red_contrast.abs() {
                // Refine to the steepest point of this step.
                let mut best = (step, d);
                let mut e = d + 0.5;
                while e <= d + 2.0 * k {
                    if let (Some(a), Some(b)) = (value(at(e - k)), value(at(e + k))) {
                        let st = (a - b) * red_contrast.signum();
                        if st > best.0 {
                            best = (st, e);
                        }
                    }
                    e += 0.5;
                }
                found[m] = best.1;
                m += 1;
                break;
            }
            d += 0.5;
        }
        in_view += usize::from(seen);
    }
    let needed = BEAM_AGREE_SHARE * in_view as f64;
    if in_view < BEAM_MIN_PROFILES || (m as f64) < needed {
        return None;
    }
    let mut sorted = found;
    sorted[..m].sort_unstable_by(f64::total_cmp);
    let median = sorted[m / 2];
    let agree = found[..m]
        .iter()
        .filter(|&&d| (d - median).abs() <= BEAM_AGREE_PX)
        .count();
    ((agree as f64) >= needed).then_some(median)
}

/// What each edge's own grey-level fit found on the reference.
struct EdgeFits {
    lines: PerEdge<Line>,
    contrast: PerEdge<f64>,
    /// Grey level just outside each edge.
    level: PerEdge<f64>,
    /// Standard errors of the lines' rotations, radians: from the pixel noise, and
    /// with the background's structure (`EdgeResult::turn_sigma_robust`).
    turn_sigma: PerEdge<f64>,
    turn_sigma_robust: PerEdge<f64>,
    blur: f64,
}

/// Each edge's own grey-level fit over `bands`.
fn fit_edges(
    reference: &GrayImage,
    bands: &PerEdge<Option<Band>>,
    blur: f64,
) -> Result<EdgeFits, VisionError> {
    let fit = Refiner::default()
        .fit(reference, bands, Turns::Free, blur, None, false)
        .ok_or_else(|| VisionError::Degenerate("the grey-level fit of the edges failed".into()))?;
    let mut lines = [Line {
        normal: [1.0, 0.0],
        rho: 0.0,
    }; EDGES];
    let mut contrast = [0.0; EDGES];
    let mut level = [0.0; EDGES];
    let mut turn_sigma = [0.0; EDGES];
    let mut turn_sigma_robust = [0.0; EDGES];
    for e in 0..EDGES {
        let r = fit.edges[e].ok_or(VisionError::EdgeNotFound {
            edge: Edge::ALL[e],
            reason: "too few pixels along the edge".into(),
        })?;
        lines[e] = r.line;
        contrast[e] = r.contrast;
        level[e] = r.level;
        turn_sigma[e] = r.turn_sigma;
        turn_sigma_robust[e] = r.turn_sigma_robust;
    }
    Ok(EdgeFits {
        lines,
        contrast,
        level,
        turn_sigma,
        turn_sigma_robust,
        blur: fit.blur,
    })
}

/// Which of the beam edge's two ends (positions `taus` along it, from the apex's foot)
/// is the free end, given where the two faces' bases lie along it (`bases`). The front
/// face is the steeper, shorter one, so its base lies nearer the apex's foot and on the
/// free end's side: the free end is the end furthest from the far base towards the near
/// one. That needs no labels, so a swapped blue and green is still caught afterwards.
/// Only when the two bases are about as far from the foot (within
/// [`SYMMETRIC_BASES`]) does the end nearer the apex's foot decide; that alone fails
/// when a large pyramid hangs from a beam that leaves the frame close behind the apex,
/// so that the border cuts the beam nearer the foot than its free end is.
fn free_end(taus: [f64; 2], bases: [f64; 2]) -> usize {
    let (near, far) = if bases[0].abs() <= bases[1].abs() {
        (bases[0], bases[1])
    } else {
        (bases[1], bases[0])
    };
    if far.abs() - near.abs() < SYMMETRIC_BASES * far.abs() {
        return usize::from(taus[1].abs() < taus[0].abs());
    }
    let towards_free = (near - far).signum();
    usize::from(towards_free * taus[1] > towards_free * taus[0])
}

/// Orientation of a line's direction, degrees CCW on screen, in (-90, 90].
fn orientation_deg(line: &Line) -> f64 {
    let d = along(line.normal);
    let mut a = screen_deg_from_image_rad(d[1].atan2(d[0]));
    while a > 90.0 {
        a -= 180.0;
    }
    while a <= -90.0 {
        a += 180.0;
    }
    a
}

fn check_clicks(edge: Edge, pts: &[[f64; 2]], w: u32, h: u32) -> Result<(), VisionError> {
    if pts.len() < 2 {
        return Err(VisionError::EdgeNotFound {
            edge,
            reason: format!("needs at least two clicked pixels, got {}", pts.len()),
        });
    }
    for &p in pts {
        let inside = p[0].is_finite()
            && p[1].is_finite()
            && p[0] >= 0.0
            && p[1] >= 0.0
            && p[0] <= (w - 1) as f64
            && p[1] <= (h - 1) as f64;
        if !inside {
            return Err(VisionError::ClickOutside {
                edge,
                point: p,
                width: w,
                height: h,
            });
        }
    }
    Ok(())
}

/// An edge located on the edge map: its coarse line (frame pixels) and extent.
#[derive(Debug, Clone, Copy)]
struct Located {
    clicked: Line,
    line: Line,
    /// Ends of the followed segment, frame pixels.
    ends: [[f64; 2]; 2],
    /// +1: the probe's side is the brighter one; -1: the darker one.
    polarity: f64,
}

/// Finds edge `edge` near its clicks (`clicked`: the line through them, its normal
/// into the probe; `polarity`: which side is brighter): the edge pixels along the
/// clicked line whose gradient points to the brighter side, then the extent of the run
/// of edge pixels that covers the clicks.
fn locate(
    edge: Edge,
    clicks: &[[f64; 2]],
    clicked: Line,
    polarity: f64,
    pyr: &Pyramid,
    map: &EdgeMap,
) -> Result<Located, VisionError> {
    let not_found = |reason: &str| VisionError::EdgeNotFound {
        edge,
        reason: reason.into(),
    };
    let gradient = scale(clicked.normal, polarity);
    // Clicks in detection coordinates, and the span they cover along the edge.
    let d = along(clicked.normal);
    let det: Vec<[f64; 2]> = clicks.iter().map(|&p| pyr.frame_to_detection(p)).collect();
    let det_line = Line::through(
        pyr.frame_to_detection(clicked.foot(clicks[0])),
        clicked.normal,
    );
    let ts: Vec<f64> = det.iter().map(|&p| dot(d, p)).collect();
    let (t_lo, t_hi) = ts
        .iter()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), &t| {
            (a.min(t), b.max(t))
        });
    let pad = 0.2 * (t_hi - t_lo) + 2.0;
    let near: Vec<[f64; 2]> = map
        .points
        .iter()
        .map(|p| ([p.x as f64, p.y as f64], p.angle as f64))
        .filter(|&(q, a)| {
            det_line.depth(q).abs() <= CLICK_BAND_PX
                && angle_gap(a, gradient) < 0.35
                && (t_lo - pad..=t_hi + pad).contains(&dot(d, q))
        })
        .map(|(q, _)| q)
        .collect();
    if near.len() < 4 {
        return Err(not_found(&format!(
            "no edge pixels with the probe {} within 3 detection pixels of the clicks",
            side_word(polarity)
        )));
    }
    let fitted = fit_points(&near, clicked.normal)
        .ok_or_else(|| not_found("edge pixels do not form a line"))?;
    // Follow the edge both ways from the clicks.
    let towards_bright = scale(fitted.normal, polarity);
    let angle = towards_bright[1].atan2(towards_bright[0]);
    let start = fitted.foot([
        0.5 * (det[0][0] + det[det.len() - 1][0]),
        0.5 * (det[0][1] + det[det.len() - 1][1]),
    ]);
    let fd = along(fitted.normal);
    let mut ends = [[0.0; 2]; 2];
    for (k, sign) in [-1.0, 1.0].into_iter().enumerate() {
        let (mut s, mut last, mut gap) = (0.0, 0.0, 0.0);
        loop {
            let p = [start[0] + sign * s * fd[0], start[1] + sign * s * fd[1]];
            if p[0] < 0.0
                || p[1] < 0.0
                || p[0] > (map.width - 1) as f64
                || p[1] > (map.height - 1) as f64
            {
                break;
            }
            if map.supports(p, fitted.normal, angle, FOLLOW_ANGLE_RAD) {
                last = s;
                gap = 0.0;
            } else {
                gap += 0.5;
                if gap > MAX_GAP_PX && s > 0.5 * (t_hi - t_lo) {
                    break;
                }
            }
            s += 0.5;
        }
        ends[k] = pyr.to_frame([
            start[0] + sign * last * fd[0],
            start[1] + sign * last * fd[1],
        ]);
    }
    if norm(sub(ends[1], ends[0])) < 6.0 {
        return Err(not_found("the edge is shorter than 6 pixels"));
    }
    let frame_line = Line::through(pyr.to_frame(fitted.foot(start)), fitted.normal);
    Ok(Located {
        clicked,
        line: frame_line,
        ends,
        polarity,
    })
}

/// The lines through each edge's clicks, their normals turned into the probe by the
/// geometry alone (the probe may be brighter or darker than its surroundings): blue's
/// towards the green clicks and green's towards the blue ones (the pyramid lies between
/// its faces), red's towards the apex where the clicked faces meet (the pyramid hangs
/// below the beam's upper face).
fn click_lines(points: PerEdge<&[[f64; 2]]>) -> Result<PerEdge<Line>, VisionError> {
    let centroid = |pts: &[[f64; 2]]| {
        let n = pts.len() as f64;
        [
            pts.iter().map(|p| p[0]).sum::<f64>() / n,
            pts.iter().map(|p| p[1]).sum::<f64>() / n,
        ]
    };
    let mut lines = [Line {
        normal: [0.0, 1.0],
        rho: 0.0,
    }; EDGES];
    for e in 0..EDGES {
        let normal = fit_points(points[e], [0.0, 1.0])
            .ok_or_else(|| VisionError::EdgeNotFound {
                edge: Edge::ALL[e],
                reason: "the clicked pixels do not form a line".into(),
            })?
            .normal;
        lines[e] = Line::through(centroid(points[e]), normal);
    }
    let apex = lines[BLUE].intersect(&lines[GREEN]).ok_or_else(|| {
        VisionError::Degenerate("the blue and green clicks lie on parallel lines".into())
    })?;
    let inside = [apex, centroid(points[GREEN]), centroid(points[BLUE])];
    for e in 0..EDGES {
        if lines[e].depth(inside[e]) < 0.0 {
            lines[e] = Line::through(centroid(points[e]), scale(lines[e].normal, -1.0));
        }
    }
    Ok(lines)
}

/// Which side of `line` (the clicks' line, normal into the probe) is brighter on the
/// reference: +1 the probe's, -1 the outside. Sampled 3 to 6 px either side of every
/// pixel along the clicked span; an error if the two sides differ by less than
/// [`MIN_SIDE_CONTRAST`] grey levels on average.
fn side_polarity(
    edge: Edge,
    line: &Line,
    clicks: &[[f64; 2]],
    img: &GrayImage,
) -> Result<f64, VisionError> {
    let sample = |p: [f64; 2]| -> f64 {
        let x = p[0].round().clamp(0.0, (img.width() - 1) as f64) as u32;
        let y = p[1].round().clamp(0.0, (img.height() - 1) as f64) as u32;
        img.get_pixel(x, y)[0] as f64
    };
    let d = along(line.normal);
    let n = line.normal;
    let ts = clicks.iter().map(|&p| dot(d, p));
    let t0 = ts.clone().fold(f64::INFINITY, f64::min);
    let t1 = ts.fold(f64::NEG_INFINITY, f64::max);
    let foot = line.foot(clicks[0]);
    let t_foot = dot(d, foot);
    let (mut diff, mut count) = (0.0f64, 0.0f64);
    let mut t = t0;
    while t <= t1 + 1e-9 {
        let p = add(foot, scale(d, t - t_foot));
        for k in 3..=6 {
            let k = k as f64;
            diff += sample(add(p, scale(n, k))) - sample(add(p, scale(n, -k)));
            count += 1.0;
        }
        t += 1.0;
    }
    let diff = diff / count.max(1.0);
    if diff.abs() < MIN_SIDE_CONTRAST {
        return Err(VisionError::EdgeNotFound {
            edge,
            reason: format!(
                "no contrast across the clicked pixels: the two sides differ by {diff:.1} \
                 grey levels on average, at least {MIN_SIDE_CONTRAST} needed"
            ),
        });
    }
    Ok(diff.signum())
}

/// "brighter" or "darker" for a sign.
fn side_word(sign: f64) -> &'static str {
    if sign > 0.0 {
        "brighter"
    } else {
        "darker"
    }
}

/// Total-least-squares line through points, normal oriented like `hint`.
fn fit_points(pts: &[[f64; 2]], hint: [f64; 2]) -> Option<Line> {
    if pts.len() < 2 {
        return None;
    }
    // Direction = principal axis; normal perpendicular to it.
    let (c, theta, spread) = principal_axis(pts);
    let mut normal = [-theta.sin(), theta.cos()];
    if spread < 1e-9 {
        return None;
    }
    if dot(normal, hint) < 0.0 {
        normal = [-normal[0], -normal[1]];
    }
    Some(Line::through(c, normal))
}

/// The stretch of a located edge handed to the grey-level fit: its followed extent,
/// trimmed away from corners where a neighbouring edge enters the band.
fn band_for(e: usize, loc: &Located, apex: [f64; 2]) -> Band {
    let d = along(loc.line.normal);
    let (t0, t1) = (dot(d, loc.ends[0]), dot(d, loc.ends[1]));
    let ta = dot(d, apex);
    // The corner end is the one nearer the apex (along the edge).
    let (tc, tf) = if (t0 - ta).abs() < (t1 - ta).abs() {
        (t0, t1)
    } else {
        (t1, t0)
    };
    let dir = (tf - tc).signum();
    let trim_corner = if e == RED { 6.0 } else { 12.0 };
    let (tc, tf) = (tc + dir * trim_corner, tf - dir * 5.0);
    let foot = loc.line.foot(apex);
    let at = |t: f64| [foot[0] + (t - ta) * d[0], foot[1] + (t - ta) * d[1]];
    Band {
        start: at(tc),
        end: at(tf),
        line: loc.line,
        bend_from: None,
        bend0: 0.0,
        bend_sigma: f64::INFINITY,
        partner: None,
        base: None,
    }
}

/// The template from the refined lines and the followed extents; checks the geometry.
fn build_template(lines: &PerEdge<Line>, loc: &PerEdge<Located>) -> Result<Template, VisionError> {
    let degenerate = |m: &str| VisionError::Degenerate(m.into());
    let (nb, ng) = (lines[BLUE].normal, lines[GREEN].normal);
    if (nb[0] * ng[1] - nb[1] * ng[0]).abs() < 0.17 {
        return Err(degenerate(
            "blue and green are within 10 degrees of parallel: no apex",
        ));
    }
    let apex = lines[BLUE]
        .intersect(&lines[GREEN])
        .ok_or_else(|| degenerate("blue and green do not meet"))?;
    if lines[RED].depth(apex) <= 0.0 {
        return Err(degenerate(
            "the apex is not on the probe side of the red edge",
        ));
    }
    let mut edges = [TemplateEdge {
        normal: [0.0; 2],
        offset: 0.0,
        tip_tau: 0.0,
        far_tau: 0.0,
        far_open: false,
        polarity: 1.0,
    }; EDGES];
    // The faces first: where they meet the beam tells which end of it is free.
    for e in [BLUE, GREEN, RED] {
        let n = lines[e].normal;
        let d = along(n);
        let taus = loc[e].ends.map(|p| dot(d, sub(p, apex)));
        let corner = if e == RED {
            let base = |f: usize| dot(d, edges[f].point(edges[f].far_tau));
            free_end(taus, [base(BLUE), base(GREEN)])
        } else if taus[0].abs() < taus[1].abs() {
            0
        } else {
            1
        };
        let (tip_tau, far_tau) = (taus[corner], taus[1 - corner]);
        if e != RED {
            let length = (far_tau - tip_tau).abs();
            if tip_tau.abs() > 0.25 * length + 6.0 {
                return Err(degenerate(&format!(
                    "the {} edge does not reach the apex (it stops {:.0} px short)",
                    Edge::ALL[e],
                    tip_tau.abs()
                )));
            }
        }
        edges[e] = TemplateEdge {
            normal: n,
            offset: lines[e].rho - dot(n, apex),
            tip_tau: if e == RED { tip_tau } else { 0.0 },
            far_tau,
            // The beam goes on to its clamp, whatever the reference showed of it.
            far_open: e == RED,
            polarity: loc[e].polarity,
        };
    }
    // Each side of the pyramid must have the other on its probe side.
    let far_point = |e: usize| {
        let q = edges[e].point(edges[e].far_tau);
        [apex[0] + q[0], apex[1] + q[1]]
    };
    if lines[BLUE].depth(far_point(GREEN)) <= 0.0 || lines[GREEN].depth(far_point(BLUE)) <= 0.0 {
        return Err(degenerate(
            "blue and green do not enclose a pyramid (check which edge is which)",
        ));
    }
    // Blue is the back face (towards the clamp), green the front face (towards the free
    // end): their bases come in that order along the beam.
    let red = &edges[RED];
    let towards_clamp = scale(along(red.normal), (red.far_tau - red.tip_tau).signum());
    let (tb, tg) = (
        dot(towards_clamp, sub(far_point(BLUE), apex)),
        dot(towards_clamp, sub(far_point(GREEN), apex)),
    );
    if tb <= tg {
        return Err(degenerate(
            "blue must be the pyramid's back face (towards the clamp) and green its front \
             face (towards the free end); check which edge is which",
        ));
    }
    let height = -edges[RED].offset;
    let bend_tau = dot(along(edges[RED].normal), sub(far_point(BLUE), apex));
    Ok(Template {
        edges,
        apex,
        height,
        bend_tau,
        beam_px: None,
    })
}

#[cfg(test)]
mod tests {
    use super::free_end;

    // Positions along the beam edge (from the apex's foot) of its two followed ends and
    // of the back and front faces' bases, as measured on rendered references.

    #[test]
    fn free_end_is_beyond_the_front_face_even_when_the_border_cuts_the_beam_nearer() {
        // A large pyramid under a beam that leaves the frame 44 px behind the apex's
        // foot: the free end (52.6) is further from the foot than the cut (-44.4).
        assert_eq!(free_end([-44.4, 52.6], [-130.0, 41.3]), 1);
        assert_eq!(free_end([52.6, -44.4], [41.3, -130.0]), 0);
    }

    #[test]
    fn free_end_when_the_border_cuts_the_beam_at_the_back_face() {
        assert_eq!(free_end([-42.0, 130.0], [126.8, -34.5]), 0);
    }

    #[test]
    fn free_end_out_of_view_or_not_reached() {
        // Only a stretch of beam behind the back face is in view: its end towards the
        // pyramid is where the tip lies.
        assert_eq!(free_end([-260.9, -190.9], [-162.0, 9.8]), 1);
        // The followed extent stops short of the front face's base.
        assert_eq!(free_end([-0.2, 165.8], [102.7, -10.3]), 0);
    }

    #[test]
    fn symmetric_faces_fall_back_to_the_end_nearer_the_apex() {
        assert_eq!(free_end([-10.0, 200.0], [-50.0, 48.0]), 0);
        assert_eq!(free_end([200.0, -10.0], [48.0, -50.0]), 1);
    }
}
