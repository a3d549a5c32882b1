//! The shapes of the rigid tools without a cantilever (a tungsten needle with a blunt
//! end, the end of a tipless cantilever, a gripper jaw): their kinds, named edges and
//! dimensions. [`super::tool`] poses and draws them.

use super::rng::Rng;

/// What kind of rigid tool a frame shows.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum ToolKind {
    /// A tapered tungsten needle with a short, blunt end face.
    Needle,
    /// The end of a tipless cantilever seen edge-on: parallel faces, a square end.
    Tipless,
    /// A gripper jaw: a wide finger, straight on its gripping (inner) side, with a
    /// square end.
    Gripper,
}

/// Index in [`ToolKind::edge_names`] (and [`ToolGeometry::flanks`]) of the up-side flank.
pub(super) const UP: usize = 0;
/// Index of the down-side flank.
pub(super) const DOWN: usize = 1;
/// Index of the end face.
pub(super) const END: usize = 2;
/// Number of flanks of every tool.
pub const TOOL_FLANKS: usize = 2;

impl ToolKind {
    pub const ALL: [ToolKind; 3] = [ToolKind::Needle, ToolKind::Tipless, ToolKind::Gripper];

    pub fn name(self) -> &'static str {
        match self {
            ToolKind::Needle => "needle",
            ToolKind::Tipless => "tipless",
            ToolKind::Gripper => "gripper",
        }
    }

    /// The edges, in truth order: up-side flank, down-side flank, end face.
    pub fn edge_names(self) -> &'static [&'static str] {
        match self {
            ToolKind::Needle => &["upper", "lower", "end"],
            ToolKind::Tipless => &["top", "bottom", "end"],
            ToolKind::Gripper => &["outer", "inner", "end"],
        }
    }

    /// The two edges whose lines meet at the apex: a flank and the end face.
    pub fn apex_edges(self) -> [&'static str; 2] {
        let names = self.edge_names();
        [names[self.apex_flank()], names[END]]
    }

    /// The flank whose corner with the end face is the apex (a gripper's inner side).
    pub(super) fn apex_flank(self) -> usize {
        match self {
            ToolKind::Gripper => DOWN,
            ToolKind::Needle | ToolKind::Tipless => UP,
        }
    }
}

/// One flank of a tool.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Flank {
    /// Angle between the flank and the tool's axis, opening toward the base, degrees.
    pub angle_deg: f64,
    /// Sagitta of the flank's bow as a fraction of its span, positive bulging outward;
    /// 0 is straight.
    pub bow: f64,
    /// Length of the bowed part, from the end face's corner, micrometres: the true
    /// edge's chord. Beyond it the flank runs straight on.
    pub span_um: f64,
}

/// Dimensions of a tool, micrometres and degrees.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ToolGeometry {
    pub kind: ToolKind,
    /// Length of the end face (a tipless cantilever's thickness).
    pub end_um: f64,
    /// Tilt of the end face from perpendicular to the axis, degrees; positive puts the
    /// up-side corner ahead of the down-side one.
    pub end_tilt_deg: f64,
    /// The up-side and down-side flanks (needle `upper`, `lower`; tipless `top`,
    /// `bottom`; gripper `outer`, `inner`).
    pub flanks: [Flank; TOOL_FLANKS],
}

/// Span of the flanks' bowed part of [`ToolGeometry::typical`] and
/// [`ToolGeometry::random`], micrometres: about the field of a 2000x frame.
pub const DEFAULT_SPAN_UM: f64 = 60.0;
/// Largest bow of a needle's flank, as a fraction of its span.
pub const MAX_BOW: f64 = 0.003;

impl ToolGeometry {
    /// A typical tool of `kind`.
    pub fn typical(kind: ToolKind) -> Self {
        let flank = |angle_deg, bow| Flank {
            angle_deg,
            bow,
            span_um: DEFAULT_SPAN_UM,
        };
        let (end_um, end_tilt_deg, flanks) = match kind {
            ToolKind::Needle => (2.0, 0.0, [flank(8.0, 0.002), flank(8.0, -0.001)]),
            ToolKind::Tipless => (3.0, 4.0, [flank(0.0, 0.0), flank(0.0, 0.0)]),
            ToolKind::Gripper => (4.5, 2.0, [flank(9.0, 0.0), flank(1.0, 0.0)]),
        };
        ToolGeometry {
            kind,
            end_um,
            end_tilt_deg,
            flanks,
        }
    }

    /// A random tool of `kind`, deterministic from `seed`: a needle's end 1-3 um, its
    /// flanks together 12-24 deg apart, each bowed by up to [`MAX_BOW`], its end tilted
    /// up to 12 deg; a tipless cantilever 1.5-4 um thick, its end within 10 deg of
    /// square; a gripper jaw's end 3-6 um, its flanks 5-15 deg apart, the inner one
    /// within 1.5 deg of the axis, its end within 5 deg of square.
    pub fn random(kind: ToolKind, seed: u64) -> Self {
        let mut rng = Rng::new(seed);
        let flank = |angle_deg, bow| Flank {
            angle_deg,
            bow,
            span_um: DEFAULT_SPAN_UM,
        };
        let (end_um, end_tilt_deg, flanks) = match kind {
            ToolKind::Needle => {
                let end = rng.uniform(1.0, 3.0);
                let tilt = rng.uniform(-12.0, 12.0);
                let half = 0.5 * rng.uniform(12.0, 24.0);
                let skew = rng.uniform(-1.5, 1.5);
                let bows = [
                    rng.uniform(-MAX_BOW, MAX_BOW),
                    rng.uniform(-MAX_BOW, MAX_BOW),
                ];
                (
                    end,
                    tilt,
                    [flank(half + skew, bows[0]), flank(half - skew, bows[1])],
                )
            }
            ToolKind::Tipless => {
                let end = rng.uniform(1.5, 4.0);
                let tilt = rng.uniform(-10.0, 10.0);
                (end, tilt, [flank(0.0, 0.0), flank(0.0, 0.0)])
            }
            ToolKind::Gripper => {
                let end = rng.uniform(3.0, 6.0);
                let tilt = rng.uniform(-5.0, 5.0);
                let taper = rng.uniform(5.0, 15.0);
                let inner = rng.uniform(0.0, 1.5);
                (end, tilt, [flank(taper - inner, 0.0), flank(inner, 0.0)])
            }
        };
        ToolGeometry {
            kind,
            end_um,
            end_tilt_deg,
            flanks,
        }
    }
}
