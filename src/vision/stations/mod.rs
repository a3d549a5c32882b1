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

use super::geometry::Line;
use super::template::{PerEdge, Pose, Template, BLUE, EDGES, GREEN, RED};
use super::{Edge, Miss};
use beam::{free_end, lower_face};
use faces::{
    end_profile, face_end, face_ends, lost_end, runs_out, runs_throughout, turned_face, END_SLACK,
};
use sampling::{
    inside_frame, profile, station_span, Profile, Sampling, Span, HOLD_RATIO, INSIDE_SPREAD,
    RED_SLACK, STATIONS,
};
use tip::{apex_covered, runs_on_past_apex};

mod beam;
mod faces;
mod sampling;
#[cfg(test)]
mod tests;
mod tip;

pub use beam::{beam_edge_scale, beam_out_of_view_scale};
pub use faces::{face_runs_past_base, faces_run_to_border};

pub(super) use tip::{COVERED_APEX_SHARE, PAST_APEX_HALF_PX};

/// The stations' verdict on a placed tip: each edge the pose puts in view, then one
/// level on the probe's side of them all. `calibrated` are the edges' signed steps,
/// `fitted` which edges the grey-level fit placed.
pub fn check_edges(
    frame: &GrayImage,
    t: &Template,
    pose: &Pose,
    blur_px: f64,
    calibrated: &PerEdge<f64>,
    fitted: PerEdge<bool>,
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
    let mut faces: PerEdge<Option<(Span, Profile, Option<Line>)>> = [None; EDGES];
    let mut shown_step = [1.0; EDGES];
    // The far end of each edge's station span.
    let mut far_end = [None; EDGES];
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
