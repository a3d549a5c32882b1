use super::beam::locate_end;
use super::faces::{locate_steps, END_SPAN};
use super::sampling::END_STATIONS;
use super::*;
use crate::vision::geometry::{add, dot, norm, scale, sub};

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
    assert!(faces_run_to_border(&frame, &t, &out, 1.0, &[150.0; EDGES]));
    // Faces ending 30 px below the border, 13 px short of the stretch the stations
    // cover: the pyramid is smaller than any scale that hides the beam.
    let short = probe_frame(&t, &truth, 30.0, true);
    assert!(!faces_run_to_border(&short, &t, &out, 1.0, &[150.0; EDGES]));
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
        |f: &GrayImage| check_edges(f, &t, &pose, 1.0, &[150.0; EDGES], [false, true, true]);
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
        |f: &GrayImage| check_edges(f, &t, &pose, 1.0, &[150.0; EDGES], [false, true, true]);
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
    let check = |f: &GrayImage| check_edges(f, &t, &pose, 1.0, &[150.0; EDGES], [true; EDGES]);
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
    let check = |fitted| check_edges(&frame, &t, &pose, 1.0, &[150.0; EDGES], fitted);
    assert_eq!(check([true; EDGES]), None);
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
    let check = |f: &GrayImage| check_edges(f, &t, &pose, 1.0, &[150.0; EDGES], [true; EDGES]);
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
    let miss = check_edges(&frame, &t, &pose, 1.0, &[150.0; EDGES], [true; EDGES]);
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
