//! The rigid-tip template learned from the reference image, in a form that does not
//! depend on where the tip is or how large it appears.
//!
//! Everything is measured from the apex (blue meets green) in reference pixels: each
//! edge's inward normal, the offset of its line from the apex, and the extent of its
//! segment along it. A frame sees the template through a similarity: rotation `psi`
//! (the tip angle), scale `s` (the magnification ratio) and the apex position. The
//! three lines of fixed directions always form a triangle similar to the reference
//! one, so the offsets fix `s` and the apex; the segment extents say where each edge
//! must be supported (and where it must end) for a hypothesis to be the tip.

use super::geometry::{add, along, dot, rotate, scale, Line};

/// Indices of the tracked edges, in the order used by every per-edge array.
pub const RED: usize = 0;
pub const BLUE: usize = 1;
pub const GREEN: usize = 2;
/// How many edges the pyramid's template has: the beam edge and the two faces.
pub const EDGES: usize = 3;
/// One value per edge of the pyramid's template, indexed by [`RED`], [`BLUE`] and
/// [`GREEN`] (as [`Edge::index`](super::Edge::index) gives them).
pub type PerEdge<T> = [T; EDGES];

/// One edge of the template.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TemplateEdge {
    /// Inward (towards the probe) unit normal in the reference, image coordinates.
    pub normal: [f64; 2],
    /// Signed offset of the line from the apex: `normal . (p - apex)` on the line.
    pub offset: f64,
    /// Position along `along(normal)` (from the apex's foot on the line) of the segment
    /// end at the corner: the apex for blue and green, the beam's free end for red.
    pub tip_tau: f64,
    /// Position of the other end: the pyramid's base, or for red where the beam left the
    /// reference frame.
    pub far_tau: f64,
    /// Whether the far end is open (the edge went on out of the reference frame).
    pub far_open: bool,
    /// +1 when the probe's side of the edge is the brighter one (its gradient points
    /// along `normal`), -1 when the darker one (against it). Learned at calibration.
    pub polarity: f64,
}

impl TemplateEdge {
    /// Length of the segment in the reference, pixels.
    pub fn length(&self) -> f64 {
        (self.far_tau - self.tip_tau).abs()
    }

    /// The point at `tau` along the edge, relative to the apex (reference pixels).
    pub fn point(&self, tau: f64) -> [f64; 2] {
        add(
            scale(self.normal, self.offset),
            scale(along(self.normal), tau),
        )
    }
}

/// The tip as the reference image shows it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Template {
    pub edges: PerEdge<TemplateEdge>,
    /// Apex in the reference image, pixels.
    pub apex: [f64; 2],
    /// Distance from the apex to the red line: the pyramid's height plus the beam's
    /// thickness, the natural unit of the tip's size.
    pub height: f64,
    /// Position along red (as `tau`) of the back of the pyramid's base: the beam is
    /// rigid (straight) from there to the free end, and bends beyond.
    pub bend_tau: f64,
    /// The beam's thickness: the depth of its lower face below the
    /// red line, reference pixels, where calibration measured it.
    pub beam_px: Option<f64>,
}

/// Where a probe's template sits in a frame: an AFM tip's (`Template`) or a rigid
/// probe's (`RigidTemplate`, which places its edges with `Pose::place`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Pose {
    /// Rotation from the reference, image radians.
    pub psi: f64,
    /// Frame pixels per reference pixel.
    pub scale: f64,
    /// Apex, frame pixels.
    pub apex: [f64; 2],
}

impl Template {
    /// The pose that lays the template on its own reference image.
    pub fn at_rest(&self) -> Pose {
        Pose {
            psi: 0.0,
            scale: 1.0,
            apex: self.apex,
        }
    }

    /// Frame position of template point `q` (relative to the apex, reference pixels).
    pub fn place(&self, pose: &Pose, q: [f64; 2]) -> [f64; 2] {
        add(pose.apex, scale(rotate(q, pose.psi), pose.scale))
    }

    /// Edge `e`'s line in a frame.
    pub fn line(&self, pose: &Pose, e: usize) -> Line {
        let edge = &self.edges[e];
        let normal = rotate(edge.normal, pose.psi);
        Line {
            normal,
            rho: dot(normal, pose.apex) + pose.scale * edge.offset,
        }
    }

    /// Edge `e`'s segment in a frame: (tip end, far end).
    pub fn segment(&self, pose: &Pose, e: usize) -> ([f64; 2], [f64; 2]) {
        let edge = &self.edges[e];
        (
            self.place(pose, edge.point(edge.tip_tau)),
            self.place(pose, edge.point(edge.far_tau)),
        )
    }

    /// Red's stretch from the free end to `heights` tip heights beyond the start of the
    /// bend (but not beyond its reference extent), as a `tau` interval (tip end first).
    pub fn red_near_tip(&self, heights: f64) -> (f64, f64) {
        let red = &self.edges[RED];
        let dir = (red.far_tau - red.tip_tau).signum();
        let span = (self.bend_tau - red.tip_tau).abs() + heights * self.height;
        (red.tip_tau, red.tip_tau + dir * span.min(red.length()))
    }

    /// Where the probe's true faces meet in a frame when the SEM images its outline
    /// `bias` pixels outside them (the edge effect): the apex moved into the pyramid
    /// until it lies `bias` from both imaged faces, blue and green.
    pub fn true_apex(&self, pose: &Pose, bias: f64) -> [f64; 2] {
        let [b, g] = [BLUE, GREEN].map(|e| rotate(self.edges[e].normal, pose.psi));
        // Solve b . d = g . d = bias (Cramer); faces of a pyramid are never parallel.
        let det = b[0] * g[1] - b[1] * g[0];
        if bias == 0.0 || det.abs() < 1e-9 {
            return pose.apex;
        }
        let d = [bias * (g[1] - b[1]) / det, bias * (b[0] - g[0]) / det];
        add(pose.apex, d)
    }

    /// Image angles (radians) of the three edges' gradients in the reference: towards
    /// the brighter side, i.e. the inward normal turned by the edge's polarity.
    pub fn gradient_angles(&self) -> PerEdge<f64> {
        self.edges.map(|e| {
            let g = scale(e.normal, e.polarity);
            g[1].atan2(g[0])
        })
    }
}

/// A toy pyramid for unit tests: red horizontal 50 px above the apex (the probe,
/// brighter, below it), blue and green at +-30 deg from the vertical, 50 px long, the
/// beam's free end 40 px to the right of the apex's foot on red.
#[cfg(test)]
pub(crate) fn toy() -> Template {
    let n_red = [0.0, 1.0];
    let (s, c) = 30f64.to_radians().sin_cos();
    let n_blue = [c, -s];
    let n_green = [-c, -s];
    let edge = |normal, offset, tip_tau, far_tau| TemplateEdge {
        normal,
        offset,
        tip_tau,
        far_tau,
        far_open: false,
        polarity: 1.0,
    };
    Template {
        edges: [
            edge(n_red, -50.0, 40.0, -200.0),
            edge(n_blue, 0.0, 0.0, 50.0),
            edge(n_green, 0.0, 0.0, -50.0),
        ],
        apex: [100.0, 100.0],
        height: 50.0,
        bend_tau: 20.0,
        beam_px: None,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn identity_pose_reproduces_the_reference() {
        let t = toy();
        let pose = t.at_rest();
        let red = t.line(&pose, RED);
        assert!((red.depth([0.0, 50.0])).abs() < 1e-12);
        assert!(red.depth(t.apex) > 0.0, "apex is on the probe side of red");
        let (tip, _) = t.segment(&pose, BLUE);
        assert!((tip[0] - 100.0).abs() < 1e-12 && (tip[1] - 100.0).abs() < 1e-12);
    }

    #[test]
    fn lines_follow_rotation_and_scale() {
        let t = toy();
        let pose = Pose {
            psi: 0.3,
            scale: 2.0,
            apex: [10.0, 20.0],
        };
        for e in 0..EDGES {
            let line = t.line(&pose, e);
            let edge = &t.edges[e];
            for tau in [edge.tip_tau, edge.far_tau] {
                let p = t.place(&pose, edge.point(tau));
                assert!(line.depth(p).abs() < 1e-9);
            }
        }
        let red = t.line(&pose, RED);
        assert!((red.depth(pose.apex) - 100.0).abs() < 1e-9);
    }

    #[test]
    fn true_apex_lies_the_bias_inside_both_imaged_faces() {
        let t = toy();
        let upright = t.at_rest();
        // Faces at +-30 deg from the axis: 0.3 px across each is 0.6 px along the axis,
        // up into the pyramid.
        let a = t.true_apex(&upright, 0.3);
        assert!(
            (a[0] - 100.0).abs() < 1e-12 && (a[1] - 99.4).abs() < 1e-12,
            "{a:?}"
        );
        assert_eq!(t.true_apex(&upright, 0.0), t.apex);
        let pose = Pose {
            psi: -0.4,
            scale: 0.5,
            apex: [30.0, 40.0],
        };
        for bias in [0.3, -0.2] {
            let a = t.true_apex(&pose, bias);
            for e in [BLUE, GREEN] {
                let depth = t.line(&pose, e).depth(a);
                assert!((depth - bias).abs() < 1e-12, "edge {e}: {depth} for {bias}");
            }
        }
    }
}
