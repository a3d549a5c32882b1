//! The probe's shape: an AFM cantilever seen edge-on (a beam of thickness T bent along
//! the exact elastica of [`crate::model`]) carrying a rigid block at its free end, the
//! pyramid tip plus the short overhang of the beam beyond it, which rotates by exactly
//! the tip slope phi0. This module turns a [`ProbeGeometry`] (micrometres) and a
//! [`Pose`] (where and how it sits in the frame) into a polygon in pixels and the true
//! tracked edges (`red`, `blue`, `green` of docs/conventions.md).
//!
//! Conventions (docs/conventions.md): pixels x right, y down, origin at the top-left
//! pixel's centre; angles in degrees, positive counter-clockwise as seen on screen.
//!
//! The elastica runs from the clamp (s = 0) to the back of the pyramid's base (s = L),
//! where the load from the apex enters the beam; the block beyond is rigid, so the
//! beam's upper face is straight along the block and curves (slope falling toward the
//! base orientation) further back.

use crate::model::{Cantilever, Centreline};

use super::rng::Rng;

/// Horizontal field width of the SEM at 1x, micrometres (127 mm / magnification).
pub const FIELD_WIDTH_AT_1X_UM: f64 = 127_000.0;

/// Pixels per micrometre for a frame `width_px` wide at `magnification`.
pub fn px_per_um(width_px: u32, magnification: f64) -> f64 {
    f64::from(width_px) * magnification / FIELD_WIDTH_AT_1X_UM
}

/// Dimensions of a probe, micrometres and degrees.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ProbeGeometry {
    /// Beam thickness T (1.5 to 4 um, docs/conventions.md).
    pub thickness_um: f64,
    /// Pyramid height from the beam's lower face to the apex (9 to 16 um).
    pub pyramid_height_um: f64,
    /// Angle between the beam's lower face and the pyramid's back (blue) face.
    pub back_face_deg: f64,
    /// Angle between the beam's lower face and the pyramid's front (green) face.
    pub front_face_deg: f64,
    /// Length of beam beyond the front face's base: the step at the free end.
    pub overhang_um: f64,
    /// Cantilever length L, clamp to the pyramid.
    pub length_um: f64,
    /// Spring constant k; EI = k L^3 / 3.
    pub spring_constant_n_per_m: f64,
}

impl ProbeGeometry {
    /// A typical contact-mode probe (close to the public sample `mixed`).
    pub fn typical() -> Self {
        ProbeGeometry {
            thickness_um: 3.2,
            pyramid_height_um: 10.7,
            back_face_deg: 50.5,
            front_face_deg: 78.0,
            overhang_um: 1.2,
            length_um: 434.675,
            spring_constant_n_per_m: 0.06,
        }
    }

    /// A random probe within the ranges of docs/conventions.md, deterministic from `seed`.
    pub fn random(seed: u64) -> Self {
        let mut rng = Rng::new(seed);
        ProbeGeometry {
            thickness_um: rng.uniform(1.5, 4.0),
            pyramid_height_um: rng.uniform(9.0, 16.0),
            back_face_deg: rng.uniform(42.0, 56.0),
            front_face_deg: rng.uniform(74.0, 88.0),
            overhang_um: rng.uniform(0.8, 2.2),
            length_um: rng.uniform(100.0, 500.0),
            spring_constant_n_per_m: rng.log_uniform(0.03, 50.0),
        }
    }

    /// Length and rigidity for the force model.
    pub fn cantilever(&self) -> Cantilever {
        let ei =
            Cantilever::rigidity_from_spring_constant(self.spring_constant_n_per_m, self.length_um);
        Cantilever::new(self.length_um, ei)
    }

    /// Along-beam runs of the back and front faces, micrometres.
    fn face_runs_um(&self) -> (f64, f64) {
        let h = self.pyramid_height_um;
        (
            h / self.back_face_deg.to_radians().tan(),
            h / self.front_face_deg.to_radians().tan(),
        )
    }
}

/// The side of the frame the beam comes from (its clamp is beyond that side).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Entry {
    Left,
    Right,
}

/// Where and how the probe sits in a frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Pose {
    pub entry: Entry,
    /// Tilt of the undeformed beam from horizontal, degrees; negative means the beam
    /// descends toward its free end (both public samples, about -18 and -16). The
    /// pyramid hangs on the lower side.
    pub base_deg: f64,
    /// Tip slope phi0 = rotation of the pyramid from the reference, degrees CCW on screen.
    pub angle_deg: f64,
    /// The apex's pixel position.
    pub apex_px: [f64; 2],
    pub px_per_um: f64,
}

/// A straight segment in pixels.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Segment {
    pub from: [f64; 2],
    pub to: [f64; 2],
}

impl Segment {
    /// Direction angle from `from` to `to`, degrees CCW on screen.
    pub fn angle_deg(&self) -> f64 {
        (-(self.to[1] - self.from[1]))
            .atan2(self.to[0] - self.from[0])
            .to_degrees()
    }

    pub fn length(&self) -> f64 {
        (self.to[0] - self.from[0]).hypot(self.to[1] - self.from[1])
    }

    /// Signed distance of `p` from the segment's line, positive to the left of the
    /// direction as seen on screen.
    pub fn signed_distance(&self, p: [f64; 2]) -> f64 {
        let d = sub(self.to, self.from);
        let r = sub(p, self.from);
        (d[0] * r[1] - d[1] * r[0]) / -self.length()
    }
}

/// The three tracked edges (docs/conventions.md), in pixels.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Edges {
    /// The beam's upper face along the rigid end block, toward the free end.
    pub red: Segment,
    /// The pyramid's back face, base -> apex.
    pub blue: Segment,
    /// The pyramid's front face, apex -> beam.
    pub green: Segment,
}

/// Arc step along the beam when sampling the elastica, pixels.
const BEAM_STEP_PX: f64 = 6.0;

/// Writes the probe's outline (pixels, one closed polygon) into `outline` for a frame
/// of `width` x `height`, and returns the true edges. The beam is continued straight
/// past the clamp if the clamp itself would be in view.
pub fn probe_outline(
    geometry: &ProbeGeometry,
    pose: &Pose,
    width: u32,
    height: u32,
    outline: &mut Vec<[f64; 2]>,
) -> Edges {
    let phi0 = pose.angle_deg.to_radians();
    let (d, side) = base_direction(pose);
    let block = Block::new(geometry, pose.px_per_um, rotate(d, phi0), side);
    // Place the beam so that the apex lands on the requested pixel.
    let end = sub(pose.apex_px, block.apex);
    let beam = Beam::new(geometry, pose.px_per_um, phi0, d, side, end);
    let far = [[0.0, 0.0], [1.0, 0.0], [0.0, 1.0], [1.0, 1.0]]
        .iter()
        .map(|c| dist([c[0] * f64::from(width), c[1] * f64::from(height)], end))
        .fold(0.0, f64::max);
    // Arc needed to leave the frame from the end, with margin; s for step i of n.
    let arc_px = 1.2 * far + 2.0 * beam.half_thickness_px + 20.0;
    let steps = (arc_px / BEAM_STEP_PX).ceil().max(2.0) as usize;
    let s_at = |i: usize| 1.0 - arc_px / beam.length_px * (1.0 - i as f64 / steps as f64);
    outline.clear();
    // Upper face from far back to the end of the elastica, around the block, and the
    // lower face back from the pyramid's base.
    outline.extend((0..=steps).map(|i| beam.face(s_at(i), 1.0)));
    for corner in [
        block.end_upper,
        block.end_lower,
        block.front_base,
        block.apex,
        block.back_base,
    ] {
        outline.push(add(end, corner));
    }
    outline.extend((0..steps).rev().map(|i| beam.face(s_at(i), -1.0)));
    let at = |p: [f64; 2]| add(end, p);
    Edges {
        red: Segment {
            from: at(block.upper_start),
            to: at(block.end_upper),
        },
        blue: Segment {
            from: at(block.back_base),
            to: at(block.apex),
        },
        green: Segment {
            from: at(block.apex),
            to: at(block.front_base),
        },
    }
}

/// The rigid end block (pyramid plus overhang), corners relative to the end of the
/// elastica's centreline, in pixels.
struct Block {
    /// Upper face at the end of the elastica, where the straight block face starts.
    upper_start: [f64; 2],
    back_base: [f64; 2],
    apex: [f64; 2],
    front_base: [f64; 2],
    end_lower: [f64; 2],
    end_upper: [f64; 2],
}

impl Block {
    /// `tangent`: the beam's direction at its end; `side` turns the CCW normal "up".
    fn new(geometry: &ProbeGeometry, ppu: f64, tangent: [f64; 2], side: f64) -> Block {
        let up = scale(ccw_normal(tangent), side);
        let t_px = geometry.thickness_um * ppu;
        let (back_um, front_um) = geometry.face_runs_um();
        let back_base = scale(up, -0.5 * t_px);
        let apex = add(
            add(back_base, scale(tangent, back_um * ppu)),
            scale(up, -geometry.pyramid_height_um * ppu),
        );
        let front_base = add(back_base, scale(tangent, (back_um + front_um) * ppu));
        let end_lower = add(front_base, scale(tangent, geometry.overhang_um * ppu));
        Block {
            upper_start: scale(up, 0.5 * t_px),
            back_base,
            apex,
            front_base,
            end_lower,
            end_upper: add(end_lower, scale(up, t_px)),
        }
    }
}

/// The bent beam placed on screen: the elastica from the clamp, scaled to pixels.
struct Beam {
    centreline: Centreline,
    clamp: [f64; 2],
    direction: [f64; 2],
    side: f64,
    length_px: f64,
    half_thickness_px: f64,
}

impl Beam {
    /// The beam whose centreline ends at `end` (pixels), undeformed `direction`.
    fn new(
        geometry: &ProbeGeometry,
        ppu: f64,
        phi0: f64,
        direction: [f64; 2],
        side: f64,
        end: [f64; 2],
    ) -> Beam {
        let centreline = Centreline::new(phi0);
        let length_px = geometry.length_um * ppu;
        let c1 = centreline.point(1.0);
        let reach = add(scale(direction, c1[0]), scale(ccw_normal(direction), c1[1]));
        Beam {
            centreline,
            clamp: sub(end, scale(reach, length_px)),
            direction,
            side,
            length_px,
            half_thickness_px: 0.5 * geometry.thickness_um * ppu,
        }
    }

    /// The upper (`face` = 1) or lower (-1) face at arclength fraction `s` (straight
    /// beyond the clamp for s < 0).
    fn face(&self, s: f64, face: f64) -> [f64; 2] {
        let d = self.direction;
        let (p, slope) = if s >= 0.0 {
            let c = self.centreline.point(s);
            let local = add(scale(d, c[0]), scale(ccw_normal(d), c[1]));
            (
                add(self.clamp, scale(local, self.length_px)),
                self.centreline.slope_rad(s),
            )
        } else {
            (add(self.clamp, scale(d, s * self.length_px)), 0.0)
        };
        let up = scale(ccw_normal(rotate(d, slope)), self.side);
        add(p, scale(up, face * self.half_thickness_px))
    }
}

/// Undeformed beam direction (clamp -> free end) on screen and the side sign that turns
/// the CCW normal into the "up" normal (away from the pyramid).
pub(super) fn base_direction(pose: &Pose) -> ([f64; 2], f64) {
    let b = pose.base_deg.to_radians();
    match pose.entry {
        Entry::Left => ([b.cos(), -b.sin()], 1.0),
        Entry::Right => ([-b.cos(), -b.sin()], -1.0),
    }
}

/// Rotates a screen vector counter-clockwise as seen on screen (y down).
pub(crate) fn rotate(v: [f64; 2], angle_rad: f64) -> [f64; 2] {
    let (s, c) = angle_rad.sin_cos();
    [v[0] * c + v[1] * s, -v[0] * s + v[1] * c]
}

/// The screen vector 90 degrees counter-clockwise from `v`.
pub(super) fn ccw_normal(v: [f64; 2]) -> [f64; 2] {
    [v[1], -v[0]]
}

pub(super) fn add(a: [f64; 2], b: [f64; 2]) -> [f64; 2] {
    [a[0] + b[0], a[1] + b[1]]
}

pub(super) fn sub(a: [f64; 2], b: [f64; 2]) -> [f64; 2] {
    [a[0] - b[0], a[1] - b[1]]
}

pub(super) fn scale(a: [f64; 2], k: f64) -> [f64; 2] {
    [a[0] * k, a[1] * k]
}

fn dist(a: [f64; 2], b: [f64; 2]) -> f64 {
    (a[0] - b[0]).hypot(a[1] - b[1])
}

#[cfg(test)]
mod tests {
    use super::*;

    fn pose(entry: Entry, angle_deg: f64) -> Pose {
        Pose {
            entry,
            base_deg: -18.0,
            angle_deg,
            apex_px: [300.0, 250.0],
            px_per_um: 10.0,
        }
    }

    #[test]
    fn px_per_um_follows_the_field_width() {
        // Public samples: 640 px at 1000x -> 5.03937, at 8000x -> 40.31496.
        assert!((px_per_um(640, 1000.0) - 5.039_370).abs() < 1e-6);
        assert!((px_per_um(640, 8000.0) - 40.314_961).abs() < 1e-6);
    }

    #[test]
    fn edges_rotate_rigidly_by_the_tip_angle() {
        let g = ProbeGeometry::typical();
        let mut outline = Vec::new();
        for entry in [Entry::Left, Entry::Right] {
            let e0 = probe_outline(&g, &pose(entry, 0.0), 640, 480, &mut outline);
            for angle in [-20.0, -3.3, 7.0, 20.0] {
                let e = probe_outline(&g, &pose(entry, angle), 640, 480, &mut outline);
                for (s, s0) in [(e.red, e0.red), (e.blue, e0.blue), (e.green, e0.green)] {
                    let turn = (s.angle_deg() - s0.angle_deg() + 540.0) % 360.0 - 180.0;
                    assert!((turn - angle).abs() < 1e-9, "{entry:?} {angle}: {turn}");
                    assert!((s.length() - s0.length()).abs() < 1e-9);
                }
                assert_eq!(e.blue.to, [300.0, 250.0]);
                assert_eq!(e.green.from, [300.0, 250.0]);
            }
        }
    }

    #[test]
    fn reference_orientation_and_pyramid_side() {
        let g = ProbeGeometry::typical();
        let mut outline = Vec::new();
        let left = probe_outline(&g, &pose(Entry::Left, 0.0), 640, 480, &mut outline);
        // Beam at -18 deg heading right and down; the apex below the beam.
        assert!((left.red.angle_deg() + 18.0).abs() < 1e-9);
        assert!(left.red.signed_distance(left.blue.to) < 0.0);
        // Height of the apex below the upper face: T + H.
        let depth = -left.red.signed_distance(left.blue.to);
        assert!((depth - 10.0 * (g.thickness_um + g.pyramid_height_um)).abs() < 1e-9);
        let right = probe_outline(&g, &pose(Entry::Right, 0.0), 640, 480, &mut outline);
        // Mirror image: heading left and down (-162 deg), apex below.
        assert!((right.red.angle_deg() + 162.0).abs() < 1e-9);
        assert!(right.red.signed_distance(right.blue.to) > 0.0);
    }

    #[test]
    fn outline_leaves_the_frame_and_bends_along_the_elastica() {
        let g = ProbeGeometry::typical();
        let mut outline = Vec::new();
        let e = probe_outline(&g, &pose(Entry::Left, 15.0), 640, 480, &mut outline);
        let first = outline[0];
        assert!(first[0] < -100.0, "beam starts off-screen: {first:?}");
        // Far from the end the upper face is less steep than the end block (slope falls
        // toward the clamp's orientation), by the elastica's slope there.
        let n = outline.len();
        let (p, q) = (outline[0], outline[1]);
        let far_deg = (-(q[1] - p[1])).atan2(q[0] - p[0]).to_degrees();
        assert!(
            far_deg < e.red.angle_deg() - 0.1,
            "{far_deg} vs {}",
            e.red.angle_deg()
        );
        assert!(n > 100);
    }
}
