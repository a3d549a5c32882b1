//! Rigid probes without a cantilever: a tungsten needle with a blunt end, the end of a
//! tipless cantilever, a gripper jaw. Each is a rigid polygon with three named straight
//! edges, two flanks and an end face between them, reaching from beyond the frame's
//! border to its end in view. A [`FrameSpec`] with a [`ToolGeometry`] in `tool` draws it
//! instead of the cantilever, posed by the spec's entry side, base tilt, angle (a
//! rotation about the apex) and apex pixel, with the spec's look; [`tool_truth`] gives
//! its true edges and apex.
//!
//! The tool's axis points from its base (beyond the entry side) to its end; "up" is the
//! side of the beam's upper face in [`super::ProbeGeometry`]'s frames (screen up for a
//! level tool from either side). The up-side flank is edge 0 of
//! [`super::ToolKind::edge_names`], the down-side flank edge 1, the end face edge 2.
//!
//! A flank may bow (a needle's does): it is drawn as a gentle parabolic arc over its
//! `span_um` from the end face's corner and runs straight on beyond it along the arc's
//! end tangent; its true edge is the chord, the straight line through the arc's ends.

use super::geometry::{add, base_direction, ccw_normal, scale, sub, Pose, Segment};
use super::spec::FrameSpec;
use super::tool_shape::{ToolGeometry, DOWN, END, TOOL_FLANKS, UP};

/// The truth of a tool frame.
#[derive(Debug, Clone, PartialEq)]
pub struct ToolTruth {
    /// The tool is drawn (false for a blank frame).
    pub in_view: bool,
    /// Rotation from the reference pose, degrees CCW on screen (NaN when blank).
    pub angle_deg: f64,
    /// The tip point: where the two edges of [`super::ToolKind::apex_edges`] meet (NaN
    /// when blank).
    pub apex_px: [f64; 2],
    pub px_per_um: f64,
    /// The true edges in [`super::ToolKind::edge_names`] order (none when blank): each flank
    /// its chord from the end face's corner back over its span, the end face from the
    /// apex to the other corner.
    pub edges: Vec<(&'static str, Segment)>,
}

impl ToolTruth {
    /// The true edge called `name`.
    pub fn edge(&self, name: &str) -> Option<Segment> {
        self.edges.iter().find(|(n, _)| *n == name).map(|&(_, s)| s)
    }
}

/// The truth of `spec`'s tool without drawing it (none if the spec has no tool).
pub fn tool_truth(spec: &FrameSpec) -> Option<ToolTruth> {
    let tool = spec.tool?;
    let ppu = spec.px_per_um();
    if spec.blank {
        return Some(ToolTruth {
            in_view: false,
            angle_deg: f64::NAN,
            apex_px: [f64::NAN; 2],
            px_per_um: ppu,
            edges: Vec::new(),
        });
    }
    let placed = Placed::new(&tool, &spec.pose());
    let names = tool.kind.edge_names();
    let mut edges: Vec<(&'static str, Segment)> = (0..TOOL_FLANKS)
        .map(|k| {
            let to = add(placed.corner[k], scale(placed.back[k], placed.span_px[k]));
            (
                names[k],
                Segment {
                    from: placed.corner[k],
                    to,
                },
            )
        })
        .collect();
    let apex = tool.kind.apex_flank();
    edges.push((
        names[END],
        Segment {
            from: placed.corner[apex],
            to: placed.corner[1 - apex],
        },
    ));
    Some(ToolTruth {
        in_view: true,
        angle_deg: spec.angle_deg,
        apex_px: spec.apex_px,
        px_per_um: ppu,
        edges,
    })
}

/// The pixels a person clicks on each edge of the tool in `spec` (its reference), in
/// [`super::ToolKind::edge_names`] order: at 10, 50 and 90 % of the edge's part in
/// view; none for a spec without a tool in view.
pub fn tool_clicks(spec: &FrameSpec) -> Vec<(String, Vec<[f64; 2]>)> {
    let Some(truth) = tool_truth(spec) else {
        return Vec::new();
    };
    truth
        .edges
        .iter()
        .filter_map(|(name, edge)| {
            let s = clip_to_frame(edge, spec.width, spec.height)?;
            let at = |f: f64| [0, 1].map(|i| s.from[i] + f * (s.to[i] - s.from[i]));
            Some((name.to_string(), vec![at(0.1), at(0.5), at(0.9)]))
        })
        .collect()
}

/// The part of `segment` inside a `width` x `height` frame's pixel area (pixel centres
/// at integers, so x from -0.5 to width - 0.5), from the end nearer `segment.from`.
pub fn clip_to_frame(segment: &Segment, width: u32, height: u32) -> Option<Segment> {
    let d = sub(segment.to, segment.from);
    let (mut t0, mut t1) = (0.0f64, 1.0f64);
    let bounds = [
        (0, -0.5, f64::from(width) - 0.5),
        (1, -0.5, f64::from(height) - 0.5),
    ];
    for (axis, lo, hi) in bounds {
        let p = segment.from[axis];
        if d[axis].abs() < 1e-12 {
            if p < lo || p > hi {
                return None;
            }
            continue;
        }
        let (a, b) = ((lo - p) / d[axis], (hi - p) / d[axis]);
        t0 = t0.max(a.min(b));
        t1 = t1.min(a.max(b));
    }
    (t0 < t1).then(|| Segment {
        from: add(segment.from, scale(d, t0)),
        to: add(segment.from, scale(d, t1)),
    })
}

/// Segments of each flank's drawn arc.
const ARC_SEGMENTS: usize = 64;

/// Writes the outline of `tool` posed by `pose` (pixels, one closed polygon reaching
/// well beyond a `width` x `height` frame) into `outline`.
pub(super) fn tool_outline(
    tool: &ToolGeometry,
    pose: &Pose,
    width: u32,
    height: u32,
    outline: &mut Vec<[f64; 2]>,
) {
    let placed = Placed::new(tool, pose);
    // Far enough from any flank point in view to leave the frame from it.
    let reach = 2.5 * f64::from(width).hypot(f64::from(height)) + 20.0;
    outline.clear();
    outline.push(placed.far(UP, reach));
    outline.extend((0..=ARC_SEGMENTS).rev().map(|i| placed.point(UP, i)));
    outline.extend((0..=ARC_SEGMENTS).map(|i| placed.point(DOWN, i)));
    outline.push(placed.far(DOWN, reach));
}

/// A tool placed in a frame: its corners and flanks in pixels.
struct Placed {
    /// The end face's corners on the up and down sides.
    corner: [[f64; 2]; TOOL_FLANKS],
    /// Each flank's chord direction, away from the end (unit).
    back: [[f64; 2]; TOOL_FLANKS],
    /// Each flank's outward normal (unit).
    out: [[f64; 2]; TOOL_FLANKS],
    span_px: [f64; TOOL_FLANKS],
    sagitta_px: [f64; TOOL_FLANKS],
}

impl Placed {
    fn new(tool: &ToolGeometry, pose: &Pose) -> Placed {
        let (base, side) = base_direction(pose);
        let axis = super::geometry::rotate(base, pose.angle_deg.to_radians());
        let up = scale(ccw_normal(axis), side);
        let ppu = pose.px_per_um;
        let tilt = tool.end_tilt_deg.to_radians();
        // Down-side corner -> up-side corner, half its length.
        let half = scale(
            add(scale(up, tilt.cos()), scale(axis, tilt.sin())),
            0.5 * tool.end_um * ppu,
        );
        // The apex exactly on its pixel, the other corner the whole face away.
        let apex = tool.kind.apex_flank();
        let mut corner = [pose.apex_px; TOOL_FLANKS];
        let toward = if apex == UP { -1.0 } else { 1.0 };
        corner[1 - apex] = add(pose.apex_px, scale(half, 2.0 * toward));
        let flank = |k: usize| {
            let a = tool.flanks[k].angle_deg.to_radians();
            let sign = if k == UP { 1.0 } else { -1.0 };
            (
                add(scale(axis, -a.cos()), scale(up, sign * a.sin())),
                add(scale(up, sign * a.cos()), scale(axis, a.sin())),
            )
        };
        let span_px = tool.flanks.map(|f| f.span_um * ppu);
        Placed {
            corner,
            back: [flank(UP).0, flank(DOWN).0],
            out: [flank(UP).1, flank(DOWN).1],
            span_px,
            sagitta_px: [
                tool.flanks[UP].bow * span_px[UP],
                tool.flanks[DOWN].bow * span_px[DOWN],
            ],
        }
    }

    /// Point `i` of [`ARC_SEGMENTS`] along flank `k`'s arc, from the corner.
    fn point(&self, k: usize, i: usize) -> [f64; 2] {
        let t = i as f64 / ARC_SEGMENTS as f64;
        let along = scale(self.back[k], t * self.span_px[k]);
        let off = scale(self.out[k], 4.0 * self.sagitta_px[k] * t * (1.0 - t));
        add(add(self.corner[k], along), off)
    }

    /// A point `reach` beyond the end of flank `k`'s arc, along its end tangent.
    fn far(&self, k: usize, reach: f64) -> [f64; 2] {
        let tangent = sub(
            scale(self.back[k], self.span_px[k]),
            scale(self.out[k], 4.0 * self.sagitta_px[k]),
        );
        let len = tangent[0].hypot(tangent[1]).max(1e-12);
        add(self.point(k, ARC_SEGMENTS), scale(tangent, reach / len))
    }
}

#[cfg(test)]
mod tests {
    use super::super::geometry::{rotate, Entry};
    use super::super::spec::Style;
    use super::super::tool_shape::ToolKind;
    use super::*;

    /// A frame of `tool` at `angle_deg` with no noise, shading, clutter or rim.
    fn plain(tool: ToolGeometry, entry: Entry, angle_deg: f64, apex_px: [f64; 2]) -> FrameSpec {
        let mut spec = FrameSpec::new(Style::Clean, angle_deg, 5);
        spec.tool = Some(tool);
        spec.entry = entry;
        spec.base_deg = -12.0;
        spec.apex_px = apex_px;
        spec.look.noise_sigma = 0.0;
        spec.look.shading = 0.0;
        spec.look.probe_ramp = 0.0;
        spec.look.outline = 0.0;
        spec.look.particles = 0;
        spec.look.substrate = None;
        spec
    }

    fn tools() -> impl Iterator<Item = ToolGeometry> {
        ToolKind::ALL.into_iter().flat_map(|kind| {
            std::iter::once(ToolGeometry::typical(kind))
                .chain((0..4).map(move |seed| ToolGeometry::random(kind, seed)))
        })
    }

    /// Where the lines through two segments cross.
    fn crossing(a: &Segment, b: &Segment) -> [f64; 2] {
        let (d, e) = (sub(a.to, a.from), sub(b.to, b.from));
        let r = sub(b.from, a.from);
        let t = (r[0] * e[1] - r[1] * e[0]) / (d[0] * e[1] - d[1] * e[0]);
        add(a.from, scale(d, t))
    }

    #[test]
    fn the_apex_is_where_the_apex_edges_meet() {
        for tool in tools() {
            for entry in [Entry::Left, Entry::Right] {
                for angle in [-15.0, 0.0, 9.0] {
                    let spec = plain(tool, entry, angle, [300.0, 250.0]);
                    let truth = tool_truth(&spec).unwrap();
                    let names: Vec<_> = truth.edges.iter().map(|(n, _)| *n).collect();
                    assert_eq!(names, tool.kind.edge_names());
                    let [a, b] = tool.kind.apex_edges().map(|n| truth.edge(n).unwrap());
                    let p = crossing(&a, &b);
                    let miss = (p[0] - 300.0).hypot(p[1] - 250.0);
                    assert!(miss < 1e-6, "{tool:?} {entry:?} {angle}: {p:?}");
                    assert_eq!(a.from, truth.apex_px);
                    assert_eq!(b.from, truth.apex_px);
                    let end = truth.edge("end").unwrap();
                    assert!((end.length() - tool.end_um * spec.px_per_um()).abs() < 1e-9);
                }
            }
        }
    }

    #[test]
    fn the_truth_turns_rigidly_about_the_apex() {
        for tool in tools() {
            for entry in [Entry::Left, Entry::Right] {
                let a0 = [320.0, 240.0];
                let r = tool_truth(&plain(tool, entry, 0.0, a0)).unwrap();
                for angle in [-15.0, -4.5, 12.0] {
                    let a1 = [280.0, 300.0];
                    let f = tool_truth(&plain(tool, entry, angle, a1)).unwrap();
                    let moved = |p: [f64; 2]| add(a1, rotate(sub(p, a0), f64::to_radians(angle)));
                    for ((name, s0), (_, s1)) in r.edges.iter().zip(&f.edges) {
                        for (p0, p1) in [(s0.from, s1.from), (s0.to, s1.to)] {
                            let q = moved(p0);
                            let miss = (q[0] - p1[0]).hypot(q[1] - p1[1]);
                            assert!(miss < 1e-9, "{tool:?} {entry:?} {angle} {name}");
                        }
                    }
                }
            }
        }
    }

    #[test]
    fn a_person_clicks_each_edge_in_view_within_it() {
        let spec = plain(
            ToolGeometry::typical(ToolKind::Gripper),
            Entry::Left,
            4.0,
            [330.0, 250.0],
        );
        let truth = tool_truth(&spec).unwrap();
        let clicks = tool_clicks(&spec);
        assert_eq!(clicks.len(), truth.edges.len());
        for ((name, points), (edge_name, edge)) in clicks.iter().zip(&truth.edges) {
            assert_eq!(name, edge_name);
            let d = sub(edge.to, edge.from);
            let length = d[0].hypot(d[1]);
            for p in points {
                let q = sub(*p, edge.from);
                let across = (d[0] * q[1] - d[1] * q[0]) / length;
                let along = (d[0] * q[0] + d[1] * q[1]) / length;
                assert!(
                    across.abs() < 1e-9 && (0.0..=length).contains(&along),
                    "{name}"
                );
                assert!((0.0..640.0).contains(&p[0]) && (0.0..480.0).contains(&p[1]));
            }
        }
        let mut blank = spec;
        blank.blank = true;
        assert!(tool_clicks(&blank).is_empty());
    }

    #[test]
    fn a_blank_frame_has_no_truth_in_view() {
        let mut spec = plain(
            ToolGeometry::typical(ToolKind::Needle),
            Entry::Left,
            3.0,
            [1.0; 2],
        );
        spec.blank = true;
        let truth = tool_truth(&spec).unwrap();
        assert!(!truth.in_view && truth.edges.is_empty());
        assert!(truth.angle_deg.is_nan() && truth.apex_px[0].is_nan());
        spec.tool = None;
        assert!(tool_truth(&spec).is_none());
    }

    #[test]
    fn clipping_keeps_the_part_in_the_frame() {
        let s = Segment {
            from: [10.0, 10.0],
            to: [-90.0, 110.0],
        };
        let c = clip_to_frame(&s, 640, 480).unwrap();
        assert_eq!(c.from, [10.0, 10.0]);
        assert!((c.to[0] + 0.5).abs() < 1e-12 && (c.to[1] - 20.5).abs() < 1e-12);
        let out = Segment {
            from: [-5.0, 10.0],
            to: [-5.0, 50.0],
        };
        assert!(clip_to_frame(&out, 640, 480).is_none());
    }

    /// The frame's level at the pixel nearest `p`.
    fn level(frame: &image::GrayImage, p: [f64; 2]) -> f64 {
        f64::from(frame.get_pixel(p[0].round() as u32, p[1].round() as u32)[0])
    }

    #[test]
    fn the_tool_is_drawn_inside_its_true_edges_and_deterministically() {
        // Inside and outside each edge, a few pixels off the middle of its visible part.
        const OFF_PX: f64 = 4.0;
        for tool in tools() {
            for (entry, dark) in [(Entry::Left, false), (Entry::Right, true)] {
                let mut spec = plain(tool, entry, 7.0, [330.0, 250.0]);
                if dark {
                    spec.look.background = 170.0;
                    spec.look.probe = 90.0;
                }
                let mut frame = image::GrayImage::new(1, 1);
                let truth = super::super::render_tool_into(&spec, &[], &mut frame);
                let mut again = image::GrayImage::new(1, 1);
                super::super::render_tool_into(&spec, &[], &mut again);
                assert_eq!(frame, again);
                // A point inside: the middle of the flanks' chords' four ends.
                let ends: Vec<[f64; 2]> = truth.edges[..TOOL_FLANKS]
                    .iter()
                    .flat_map(|(_, s)| [s.from, s.to])
                    .collect();
                let inner = scale(ends.iter().fold([0.0; 2], |a, &p| add(a, p)), 0.25);
                for (name, edge) in &truth.edges {
                    let seen = clip_to_frame(edge, spec.width, spec.height).unwrap();
                    let mid = scale(add(seen.from, seen.to), 0.5);
                    let d = scale(sub(seen.to, seen.from), 1.0 / seen.length());
                    let mut n = [-d[1], d[0]];
                    if (inner[0] - mid[0]) * n[0] + (inner[1] - mid[1]) * n[1] < 0.0 {
                        n = scale(n, -1.0);
                    }
                    let inside = level(&frame, add(mid, scale(n, OFF_PX)));
                    let outside = level(&frame, add(mid, scale(n, -OFF_PX)));
                    let contrast = if dark {
                        outside - inside
                    } else {
                        inside - outside
                    };
                    assert!(contrast > 60.0, "{tool:?} {name}: {inside} vs {outside}");
                }
            }
        }
    }
}
