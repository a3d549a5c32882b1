use super::verify::MAX_SIGMA_DEG;
use super::*;

/// Stations along every edge, each holding its step where the pose puts it, the
/// lower flank's in view or not.
fn fitter(t: &RigidTemplate, pose: &Pose, lower_in_view: bool) -> Fitter {
    let mut f = Fitter::default();
    for (e, edge) in t.edges.iter().enumerate() {
        for k in 0..=8 {
            let tau = edge.extent[0] + edge.length() * f64::from(k) / 8.0;
            let in_view = e != 2 || lower_in_view;
            f.points.push(Point {
                edge: e,
                tau,
                at: pose.place(edge, tau),
                step: if in_view { 1.0 } else { 0.0 },
                inside: 180.0,
                in_view,
            });
        }
    }
    f
}

/// The needle template at rest in a blank frame (the stations carry the readings).
fn needle_at_rest() -> (RigidTemplate, Pose, GrayImage) {
    let pose = Pose {
        psi: 0.0,
        scale: 1.0,
        apex: [250.0, 100.0],
    };
    (
        crate::vision::rigid::needle_template(),
        pose,
        GrayImage::new(320, 240),
    )
}

/// What `f`'s stations are refused for at `pose`, if anything.
fn refusal(f: &mut Fitter, t: &RigidTemplate, pose: Pose, frame: &GrayImage) -> Option<Miss> {
    f.verify(frame, t, pose, 1e-4, 0.3).err().map(|r| r.0)
}

/// The two edges meeting at the apex, holding everywhere, are any corner of their
/// angle: without an edge away from the apex in view the pose is refused as
/// `scale-unseen`; with the lower flank in view it is verified.
#[test]
fn a_corner_alone_does_not_show_the_probe() {
    let (t, pose, frame) = needle_at_rest();
    assert_eq!(
        refusal(&mut fitter(&t, &pose, true), &t, pose, &frame),
        None
    );
    assert_eq!(
        refusal(&mut fitter(&t, &pose, false), &t, pose, &frame),
        Some(Miss::ScaleUnseen)
    );
}

/// Every edge holding, but the fit's rotation known to no better than the
/// accuracy detections are held to: refused as `low-confidence`.
#[test]
fn a_fit_whose_rotation_is_not_pinned_down_is_refused() {
    let (t, pose, frame) = needle_at_rest();
    let at_sigma = |deg: f64| {
        let f = &mut fitter(&t, &pose, true);
        f.verify(&frame, &t, pose, f64::to_radians(deg), 0.3)
            .err()
            .map(|r| r.0)
    };
    assert_eq!(at_sigma(0.9 * MAX_SIGMA_DEG), None);
    assert_eq!(at_sigma(1.1 * MAX_SIGMA_DEG), Some(Miss::LowConfidence));
}

/// A particle brighter than the probe touching its tip, beside the end face's
/// corner: past the apex the frame lies beyond the probe's level, and the
/// particle's blur lifts the corner above it, so the end face's corner is hidden
/// by a particle, not missing. The same disc at the probe's level is not such a
/// particle: past the apex it reads as the probe carrying on, as a patch over the
/// tip does.
#[test]
fn a_particle_brighter_than_the_probe_beside_the_tip_does_not_hide_it() {
    let (t, pose, _) = needle_at_rest();
    let mut f = fitter(&t, &pose, true);
    // The end face's stations from 3 px on (the nearest station's run lies
    // inside the face, as a frame's stations do).
    for (k, p) in f.points.iter_mut().filter(|p| p.edge == 1).enumerate() {
        p.tau = 3.0 + k as f64;
        p.at = pose.place(&t.edges[1], p.tau);
    }
    // Background 60, the needle (x up to the apex at 250, y 100-112) at 180, and
    // beside its corner (up and right of it) a disc of radius 7 at `disc`, whose
    // blur lifts the levels within 13 px of it by 40.
    let frame = |disc: u8| {
        let centre = [257.0, 93.0];
        GrayImage::from_fn(320, 240, |x, y| {
            let (x, y) = (f64::from(x), f64::from(y));
            let d = (x - centre[0]).hypot(y - centre[1]);
            let body = (50.0..=250.0).contains(&x) && (100.0..=112.0).contains(&y);
            let level = if d <= 7.0 {
                disc
            } else if body {
                180
            } else {
                60
            };
            let halo = if disc > 180 && d > 7.0 && d <= 20.0 {
                40
            } else {
                0
            };
            image::Luma([level.saturating_add(halo)])
        })
    };
    assert!(f.particle_beside_tip(&frame(250), &t, &pose, 1));
    assert!(!f.particle_beside_tip(&frame(180), &t, &pose, 1));
}

/// A lower flank whose located steps lie on a line turned about its middle: at
/// 1.1 deg its 31 stations still hold it at 74 % (within 1.5 px out to 78 px
/// either side), but its direction is another body's; at 0.5 deg it verifies.
#[test]
fn an_edge_turned_from_the_probe_s_is_another_body() {
    let (t, pose, frame) = needle_at_rest();
    let lower = &t.edges[2];
    let turned = |deg: f64| {
        let mut f = fitter(&t, &pose, true);
        f.points.retain(|p| p.edge != 2);
        let normal = rotate(lower.normal, pose.psi);
        for k in 0..=30 {
            let tau = lower.extent[0] + lower.length() * f64::from(k) / 30.0;
            let off = (tau + 100.0) * deg.to_radians().tan();
            f.points.push(Point {
                edge: 2,
                tau,
                at: add(pose.place(lower, tau), scale(normal, off)),
                step: 1.0,
                inside: 180.0,
                in_view: true,
            });
        }
        f
    };
    assert_eq!(refusal(&mut turned(0.5), &t, pose, &frame), None);
    assert_eq!(
        refusal(&mut turned(1.1), &t, pose, &frame),
        Some(Miss::WrongAppearance(lower.name))
    );
}

/// The needle template with its flanks 40 px apart along the body, at rest, and a
/// frame of its body at 180 on 80 (x 50-250, y 100-140) whose core 16 px wide
/// reads `core` from `from_x` on.
fn with_core(core: u8, from_x: f64) -> (RigidTemplate, Pose, GrayImage) {
    let (mut t, pose, _) = needle_at_rest();
    t.edges[1].extent = [0.0, 40.0];
    t.edges[2].offset = -40.0;
    // The lower flank runs along -x as its extent grows.
    t.edges[2].extent = [0.0, 200.0];
    let frame = GrayImage::from_fn(320, 240, |x, y| {
        let (x, y) = (f64::from(x), f64::from(y));
        let level = if !(50.0..=250.0).contains(&x) || !(100.0..=140.0).contains(&y) {
            80
        } else if x >= from_x && (112.0..=128.0).contains(&y) {
            core
        } else {
            180
        };
        image::Luma([level])
    });
    (t, pose, frame)
}

/// The body of [`with_core`] with the frame above its upper flank back at the
/// probe's level from `band` px out: a band of 3 px (a scratch along the flank) is
/// a rim, refused; one of 12 px is surroundings.
#[test]
fn an_edge_whose_outside_is_a_thin_band_is_a_line_of_the_background() {
    let refused = |band: u32| {
        let (t, pose, body) = with_core(180, 50.0);
        let frame = GrayImage::from_fn(body.width(), body.height(), |x, y| {
            if y + band < 100 {
                image::Luma([180])
            } else {
                *body.get_pixel(x, y)
            }
        });
        refusal(&mut fitter(&t, &pose, true), &t, pose, &frame)
    };
    let upper = crate::vision::rigid::needle_template().edges[0].name;
    assert_eq!(refused(12), None);
    assert_eq!(refused(3), Some(Miss::WrongAppearance(upper)));
}

/// A core at the probe's level, at the surroundings' (a real probe's middle may
/// fade) or past them: only the last is refused, as two rims of another body
/// around its core are.
#[test]
fn two_rims_around_a_core_past_the_surroundings_are_no_probe() {
    let refused = |core: u8| {
        let (t, pose, frame) = with_core(core, 50.0);
        refusal(&mut fitter(&t, &pose, true), &t, pose, &frame)
    };
    assert_eq!(refused(180), None);
    assert_eq!(refused(80), None);
    let (t, _, _) = with_core(20, 50.0);
    let flanks = [t.edges[0].name, t.edges[2].name];
    assert!(matches!(
        refused(20),
        Some(Miss::WrongAppearance(name)) if flanks.contains(&name)
    ));
}

/// The core past the surroundings over only the body's last 90 px, four of the
/// nine stations per flank (a dark lever's template along a rail, the rail's dark
/// gap taken for its end and its bright core beyond): refused, though the median
/// middle shows the probe's level. Over the last 40 px, two of nine (a flaw, a
/// particle on the body): verified.
#[test]
fn a_body_hollow_over_part_of_its_length_is_no_probe() {
    let refused = |from_x: f64| {
        let (t, pose, frame) = with_core(20, from_x);
        refusal(&mut fitter(&t, &pose, true), &t, pose, &frame)
    };
    assert_eq!(refused(210.0), None);
    assert!(matches!(refused(160.0), Some(Miss::WrongAppearance(_))));
}

/// A particle brighter than a bright probe lying across or beside part of its
/// lower flank: the stations there step the wrong way to a level beyond the
/// probe's, and neither hold nor miss the flank, which its other stations show. A
/// level a fifth of the step beyond the probe's (a background about as bright as
/// the probe) is no such body: those stations miss it.
#[test]
fn a_particle_across_or_beside_an_edge_does_not_hide_it() {
    let (t, pose, frame) = needle_at_rest();
    let with_stations = |step: f64, inside: f64| {
        let mut f = fitter(&t, &pose, true);
        for p in f.points.iter_mut().filter(|p| p.edge == 2).skip(2).take(4) {
            p.step = step;
            p.inside = inside;
        }
        f
    };
    // Across: both sides beyond the probe's level (180).
    assert_eq!(
        refusal(&mut with_stations(-1.5, 240.0), &t, pose, &frame),
        None
    );
    // Beside: the probe's level inside, the particle outside.
    assert_eq!(
        refusal(&mut with_stations(-1.5, 180.0), &t, pose, &frame),
        None
    );
    assert_eq!(
        refusal(&mut with_stations(-0.2, 180.0), &t, pose, &frame),
        Some(Miss::EdgeMissing(t.edges[2].name))
    );
}

/// Past the apex the upper flank steps by 0.6 of the calibrated step at three
/// stations, with the probe's level on its side. Where it steps by 0.62 next to the
/// apex (a background brighter than on the reference) and the end face by 0.25,
/// nothing closes the body there and it runs on. With the end face stepping by 0.5
/// or more (the probe's end, in a frame of less contrast than its reference), or the
/// flank by 1.0 next to the apex, 0.6 is short of running on.
#[test]
fn a_body_runs_on_past_an_apex_its_closing_edge_does_not_show() {
    let (t, pose, _) = needle_at_rest();
    let upper = &t.edges[0];
    let with = |flank: f64, face: f64| {
        let mut f = fitter(&t, &pose, true);
        for p in &mut f.points {
            p.step = [flank, face, 1.0][p.edge];
        }
        for d in BEYOND_PX {
            let tau = upper.extent[1] + d / pose.scale;
            f.points.push(Point {
                edge: MAX_EDGES,
                tau,
                at: pose.place(upper, tau),
                step: 0.6,
                inside: 180.0,
                in_view: true,
            });
        }
        f
    };
    assert!(with(0.62, 0.25).runs_on(&t, &pose, 0, 180.0));
    assert!(!with(0.62, 0.5).runs_on(&t, &pose, 0, 180.0));
    assert!(!with(0.62, 1.0).runs_on(&t, &pose, 0, 180.0));
    assert!(!with(1.0, 0.25).runs_on(&t, &pose, 0, 180.0));
}
