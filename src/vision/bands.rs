//! Where the grey-level fit looks: for a placed template, the stretch of each edge in
//! view, trimmed away from the corners (where a neighbouring edge enters the band),
//! the beam edge limited to a few tip heights behind its rigid block and following the
//! bend the elastica predicts. Shared by calibration (on the reference, at rest) and
//! tracking, so that both fit exactly the same stretches and the reference reads zero.

use super::geometry::{add, along, clip_to_rect, dot, norm, scale, sub, Line};
use super::refine::{half_width, Band, FitResult, Partner, BEND_UNIT_PX};
use super::template::{PerEdge, Pose, Template, BLUE, GREEN, RED};
use crate::model::{Cantilever, ModelTable};

/// How much of the beam edge (in tip heights from the free end) is fitted: all of it
/// that is in view, in practice; the bend term takes care of its curvature.
pub const RED_SPAN_HEIGHTS: f64 = 4.0;
/// Typical distance from the apex to the beam's upper face, micrometres (conventions.md:
/// pyramid 9-16 um plus beam 1.5-4 um).
const TIP_HEIGHT_UM: f64 = 14.5;

/// The beam edge's expected bend (offset at [`BEND_UNIT_PX`] beyond the rigid block,
/// pixels) from the exact elastica at the current angle, and its uncertainty (mostly
/// the unknown pixel size of the reference).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BendPrior {
    pub mean: f64,
    pub sigma: f64,
}

/// Pixels within this many blurs of a neighbouring face's inside (see
/// [`crate::vision::refine::Band`]'s partner) are left out of a pyramid face's band.
const CORNER_BLURS: f64 = 3.0;
/// With that mask, a face's band stops this share of the old corner trim (several
/// blurs) short of its corners: the mask does the rest, and the ends of a face, which
/// pin its rotation down, are fitted.
const CORNER_TRIM: f64 = 0.3;
/// The beam's lower face is placed through a face's far end as calibrated (to a pixel
/// or two): its mask reaches this much further.
const BASE_SLACK_PX: f64 = 2.0;

/// Shortest band worth fitting, frame pixels.
const MIN_BAND_PX: f64 = 10.0;

impl BendPrior {
    /// No prior: the band follows `fitted`, the fit is free.
    pub fn none(fitted: f64) -> BendPrior {
        BendPrior {
            mean: fitted,
            sigma: f64::INFINITY,
        }
    }
}

/// What the elastica says the beam's bend should be (see [`BendPrior`]); without a
/// cantilever, no prior (the band then follows `fitted`).
pub fn bend_prior(
    t: &Template,
    pose: &Pose,
    cantilever: Option<Cantilever>,
    fitted: f64,
) -> BendPrior {
    let Some(cantilever) = cantilever else {
        return BendPrior::none(fitted);
    };
    // Pixels per micrometre from the tip's size: apex to beam face is the pyramid
    // (9-16 um) plus the beam (1.5-4 um), 14.5 um give or take a factor 1.38.
    let px_per_um = t.height * pose.scale / TIP_HEIGHT_UM;
    let length_px = cantilever.length_um * px_per_um;
    let angle = pose.psi.abs();
    let alpha = ModelTable::global().alpha_rad(angle).value;
    let red = &t.edges[RED];
    let towards_clamp = scale(along(red.normal), (red.far_tau - red.tip_tau).signum());
    let handed = dot([-towards_clamp[1], towards_clamp[0]], red.normal);
    let unit3 = BEND_UNIT_PX.powi(3);
    let mean =
        -pose.psi.signum() * alpha * angle.cos() * unit3 / (6.0 * length_px * length_px) * handed;
    BendPrior {
        mean,
        sigma: 0.7 * mean.abs() + 0.03,
    }
}

/// The neighbouring faces of a pyramid face (none for the beam edge): its partner at
/// the apex and, when its far end was seen in the reference, the beam's lower face
/// there (see the fields of [`Band`]).
fn corners(
    t: &Template,
    pose: &Pose,
    e: usize,
    far: [f64; 2],
    blur: f64,
) -> (Option<Partner>, Option<Partner>) {
    let other = match e {
        BLUE => GREEN,
        GREEN => BLUE,
        _ => return (None, None),
    };
    let partner = Partner {
        line: t.line(pose, other),
        margin_px: CORNER_BLURS * blur,
    };
    let base = (!t.edges[e].far_open).then(|| Partner {
        line: lower_face(t, pose, far),
        margin_px: CORNER_BLURS * blur + BASE_SLACK_PX,
    });
    (Some(partner), base)
}

/// The beam's lower face where a pyramid face ends at `far`: through that corner, along
/// the beam (straight there: the bend starts behind the pyramid), inward normal
/// pointing into the beam.
fn lower_face(t: &Template, pose: &Pose, far: [f64; 2]) -> Line {
    let n = t.line(pose, RED).normal;
    Line::through(far, [-n[0], -n[1]])
}

/// The part of edge `e`'s predicted segment inside the frame: (corner side, far side).
pub fn visible_segment(
    t: &Template,
    pose: &Pose,
    e: usize,
    size: [f64; 2],
) -> Option<([f64; 2], [f64; 2])> {
    let (tip, far) = t.segment(pose, e);
    let len = sub(far, tip)[0].hypot(sub(far, tip)[1]);
    if len < 1e-9 {
        return None;
    }
    let dir = [(far[0] - tip[0]) / len, (far[1] - tip[1]) / len];
    let (a, b) = clip_to_rect(tip, dir, [0.0, 0.0], [size[0] - 1.0, size[1] - 1.0])?;
    let (a, b) = (a.max(0.0), b.min(len));
    (b > a).then(|| {
        (
            [tip[0] + a * dir[0], tip[1] + a * dir[1]],
            [tip[0] + b * dir[0], tip[1] + b * dir[1]],
        )
    })
}

/// Bands for the grey-level fit from a pose: each edge's predicted segment, trimmed
/// at the corners, limited (beam edge) to a few tip heights, clipped to the frame.
pub fn bands(
    t: &Template,
    pose: &Pose,
    size: [f64; 2],
    blur: f64,
    bend: BendPrior,
) -> PerEdge<Option<Band>> {
    let (nb, ng) = (t.edges[BLUE].normal, t.edges[GREEN].normal);
    let sin_apex = (nb[0] * ng[1] - nb[1] * ng[0]).abs().max(0.2);
    let reach = half_width(blur) + 2.5 * blur;
    let margin = 3.0;
    let (lo_rect, hi_rect) = (
        [margin, margin],
        [size[0] - 1.0 - margin, size[1] - 1.0 - margin],
    );
    std::array::from_fn(|e| {
        let line = t.line(pose, e);
        let (tip, far) = t.segment(pose, e);
        let full = norm(sub(far, tip));
        if full < 1.0 {
            return None;
        }
        let dir = scale(sub(far, tip), 1.0 / full);
        let red = &t.edges[RED];
        let len = if e == RED {
            ((t.bend_tau - red.tip_tau).abs() + RED_SPAN_HEIGHTS * t.height) * pose.scale
        } else {
            full
        };
        let trim_corner = if e == RED {
            reach
        } else {
            CORNER_TRIM * reach / sin_apex
        };
        let (a, b) = clip_to_rect(tip, dir, lo_rect, hi_rect)?;
        let (partner, base) = corners(t, pose, e, far, blur);
        let far_trim = if base.is_some() { CORNER_TRIM } else { 1.0 } * 1.5 * reach;
        let (a, b) = (a.max(trim_corner), b.min(len - far_trim));
        if b - a < MIN_BAND_PX {
            return None;
        }
        let at = |s: f64| line.foot(add(tip, scale(dir, s)));
        Some(Band {
            start: at(a),
            end: at(b),
            line,
            bend_from: (e == RED).then(|| line.foot(t.place(pose, red.point(t.bend_tau)))),
            bend0: bend.mean,
            bend_sigma: bend.sigma,
            partner,
            base,
        })
    })
}

/// The pose implied by the fitted lines: the fitted rotation, the apex where blue meets
/// green (else kept consistent with the lines that were fitted), the scale from red.
pub fn refined_pose(t: &Template, pose: &Pose, fit: &FitResult) -> Pose {
    let psi = pose.psi + fit.turn;
    let line = |e: usize| fit.edges[e].map(|r| r.line);
    let mut out = Pose { psi, ..*pose };
    match (line(BLUE), line(GREEN), line(RED)) {
        (Some(b), Some(g), red) => {
            if let Some(apex) = b.intersect(&g) {
                out.apex = apex;
                if let Some(r) = red {
                    let s = (r.rho - dot(r.normal, apex)) / t.edges[RED].offset;
                    if s > 0.0 {
                        out.scale = s;
                    }
                }
            }
        }
        (b, g, Some(r)) => {
            // One pyramid face and the beam: keep the scale, move the apex onto both lines.
            let face = b.map(|l| (l, BLUE)).or(g.map(|l| (l, GREEN)));
            if let Some((l, _)) = face {
                let shifted = Line {
                    normal: r.normal,
                    rho: r.rho - out.scale * t.edges[RED].offset,
                };
                if let Some(apex) = l.intersect(&shifted) {
                    out.apex = apex;
                }
            }
        }
        _ => {}
    }
    out
}
