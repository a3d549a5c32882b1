//! Vision: finds the AFM probe's rigid pyramid tip (or any rigid probe of named edges)
//! in an SEM frame and measures its rotation from the reference image, the quantity
//! the elastica turns into a force.
//!
//! The pipeline starts from the paper's (threshold, Canny, one Hough line search per tip
//! edge within +-window of its calibrated orientation) and goes beyond it:
//! - `pyramid`: the frame binned to ~320 px wide for detection (cost and noise down);
//! - `edges`: Canny on that image, masked by the grey-level threshold (fixed or Otsu);
//! - `hough`: per-edge (psi, rho) accumulators, where a pixel votes only for rotations
//!   its gradient direction allows (the probe is bright: edges have a polarity);
//! - `candidates`: the best peaks polished into lines with support profiles;
//! - `hypothesis`: the rigid-tip search: pairs and triples of lines that agree on one
//!   rotation and form the reference triangle at some scale, scored by how well they
//!   cover the predicted segments (a clutter line cannot win an edge on its own);
//! - `bands`: which stretch of each edge the grey-level fit uses (shared with calibration);
//! - `refine`: sub-pixel, sub-0.1 degree fit of one shared rotation on the full-resolution
//!   grey levels, with a bend term for the curved beam edge;
//! - `verify`: is it the tip (contrast of every edge in view, a bright pyramid, a
//!   precise rotation), and the confidence;
//! - `stations`: is it this probe: every edge in view steps as calibrated at stations
//!   along its predicted length (docs/tracker.md, "What the tracker refuses, and why");
//! - `sigma`: the reported standard error of the rotation, calibrated on rendered suites;
//! - `tracker`: the per-frame driver and coherence;
//! - `calibration`: the template learned from the reference image and clicked pixels;
//! - `autocal`: the three edges found from one click on the apex (or none), for
//!   calibration;
//! - `overlay`: the paper's Figure 8 picture for a frame or a calibration;
//! - `probes`: several probes in one view, each with its own tracker; `claim`: the
//!   body a detection claims of its frame;
//! - `rigid`: any other rigid probe (a needle, a tipless cantilever, a gripper jaw),
//!   calibrated from its named edges and tracked by its own search, fit and checks;
//!   [`Tracker`] is either engine (docs/rigid-probes.md).
//!
//! Conventions (docs/conventions.md): pixels x right, y down, origin at the top-left pixel's
//! centre; output angles in degrees, counter-clockwise on screen.

mod autocal;
mod bands;
mod calibration;
mod candidates;
mod claim;
mod edges;
mod geometry;
mod hough;
mod hypothesis;
mod options;
mod overlay;
mod probes;
mod pyramid;
mod refine;
mod rigid;
mod second_thread;
mod sigma;
mod simd;
mod stations;
mod template;
mod tracker;
mod verify;

use std::fmt;

use crate::model::Cantilever;
use template::PerEdge;

pub use autocal::{auto_calibrate, clicks_from_apex, find_apex, AutoCalError, AutoClicks};
pub use calibration::{CalibratedEdge, Calibration};
pub use geometry::Line;
pub use options::{
    CalibrationConfig, PixelOrigin, ScaleRange, Threshold, TrackerConfig, DEFAULT_WINDOW_DEG,
    MAX_EDGE_BIAS_PX, PYRAMID_EDGES,
};
pub use overlay::{
    draw_calibration, draw_overlay, draw_overlays, draw_rigid_calibration, NAMED_EDGE_COLOURS,
};
pub use probes::{
    refuse_scale_outliers, refuse_shared_tips, Claim, ProbeSet, MAX_PROBES, SECOND_TRACKING_THREAD,
    SINGLE_NAME,
};
pub use rigid::{
    auto_calibrate as auto_calibrate_rigid, calibrate as calibrate_rigid,
    find_tip_points as rigid_tip_points, RigidAutoClicks, RigidEdge, RigidError, RigidTemplate,
    RigidTracker, MAX_EDGES, RIGID_SCALES,
};
pub use simd::set_avx2;
pub use template::Pose;
pub use tracker::Tracker;

/// The three tracked edges of the tip (the paper's red, blue and green lines).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Edge {
    /// The beam's upper face near the free end.
    Red,
    /// The pyramid's back face, from its base to the apex.
    Blue,
    /// The pyramid's front face, from the apex back to the beam.
    Green,
}

impl Edge {
    pub const ALL: PerEdge<Edge> = [Edge::Red, Edge::Blue, Edge::Green];

    /// Position in per-edge arrays such as [`Estimate::edges`].
    pub fn index(self) -> usize {
        match self {
            Edge::Red => template::RED,
            Edge::Blue => template::BLUE,
            Edge::Green => template::GREEN,
        }
    }

    pub const fn name(self) -> &'static str {
        match self {
            Edge::Red => "red",
            Edge::Blue => "blue",
            Edge::Green => "green",
        }
    }
}

impl fmt::Display for Edge {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

/// An edge's name as refusals give it (`Miss::EdgeMissing`, `Miss::WrongAppearance`): a
/// pyramid edge's (`red`, `blue`, `green`) or a rigid probe's named edge, with the
/// `miss` column's spellings of both refusals.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct EdgeName {
    name: &'static str,
    missing: &'static str,
    appearance: &'static str,
}

/// Names given to [`EdgeName::intern`] so far: each distinct name is stored once, for
/// the life of the process (a lab's configs name a handful).
static NAMES: std::sync::Mutex<Vec<EdgeName>> = std::sync::Mutex::new(Vec::new());

impl EdgeName {
    /// The name of a rigid probe's edge.
    pub fn intern(name: &str) -> EdgeName {
        let mut names = NAMES.lock().unwrap_or_else(|e| e.into_inner());
        if let Some(found) = names.iter().find(|n| n.name == name) {
            return *found;
        }
        let leak = |s: String| -> &'static str { Box::leak(s.into_boxed_str()) };
        let interned = EdgeName {
            name: leak(name.to_string()),
            missing: leak(format!("edge-missing-{name}")),
            appearance: leak(format!("wrong-appearance-{name}")),
        };
        names.push(interned);
        interned
    }

    pub fn as_str(self) -> &'static str {
        self.name
    }
}

impl From<Edge> for EdgeName {
    fn from(edge: Edge) -> EdgeName {
        match edge {
            Edge::Red => EdgeName {
                name: "red",
                missing: "edge-missing-red",
                appearance: "wrong-appearance-red",
            },
            Edge::Blue => EdgeName {
                name: "blue",
                missing: "edge-missing-blue",
                appearance: "wrong-appearance-blue",
            },
            Edge::Green => EdgeName {
                name: "green",
                missing: "edge-missing-green",
                appearance: "wrong-appearance-green",
            },
        }
    }
}

impl fmt::Display for EdgeName {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name)
    }
}

/// One tip edge as found in a frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct EdgeFit {
    /// Visible part of the edge segment, frame pixels: corner end (apex or free end)
    /// first when it is in view.
    pub start_px: [f64; 2],
    pub end_px: [f64; 2],
    /// Edge pixels (detection image) supporting it.
    pub support: u32,
    /// Grey-level step across the edge.
    pub contrast: f64,
}

/// Why a frame gave no estimate (docs/tracker.md, "What the tracker refuses, and why").
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Miss {
    /// Too few edge candidates of the tip's polarity and orientation.
    NoCandidates,
    /// Candidates exist, but none combine into a rigid tip.
    Inconsistent,
    /// The placed tip's apex lies outside the frame: the tip is out of view.
    ApexOutside,
    /// The rotation lies outside the search window (`window_deg`) by more than its
    /// standard error allows.
    RotationOutside,
    /// An edge the pose puts in view is not there along its predicted length (or not
    /// at its corner: the tip hidden).
    EdgeMissing(EdgeName),
    /// An edge in view steps the wrong way (the probe's calibrated polarity), with a
    /// contrast unlike the calibrated one, or bounds a body unlike the probe's.
    WrongAppearance(EdgeName),
    /// The edges do not end where the calibrated geometry at this scale puts them: a
    /// face running short or on, or the beam's lower face not at its calibrated
    /// thickness.
    ScaleMismatch,
    /// A rigid probe of named edges shows only the two edges meeting at its tip point,
    /// which any corner of their angle matches: no edge away from the apex is in view
    /// to measure its size.
    ScaleUnseen,
    /// A tip-like hypothesis passed every check above but its combined confidence is
    /// too low.
    LowConfidence,
    /// Another probe's tracker placed its tip on the same body, more confidently
    /// (several probes in one view: [`ProbeSet`]).
    OtherProbe,
    /// Its scale is unlike that of the other probes calibrated on the same reference
    /// image, which one frame shows at one magnification ([`ProbeSet`]).
    ScaleUnlikeOthers,
}

impl Miss {
    /// The name written in result files (`miss` column).
    pub fn name(self) -> &'static str {
        match self {
            Miss::NoCandidates => "no-candidates",
            Miss::Inconsistent => "inconsistent",
            Miss::ApexOutside => "apex-outside",
            Miss::RotationOutside => "rotation-outside-window",
            Miss::EdgeMissing(edge) => edge.missing,
            Miss::WrongAppearance(edge) => edge.appearance,
            Miss::ScaleMismatch => "scale-mismatch",
            Miss::ScaleUnseen => "scale-unseen",
            Miss::LowConfidence => "low-confidence",
            Miss::OtherProbe => "other-probe",
            Miss::ScaleUnlikeOthers => "scale-unlike-other-probes",
        }
    }
}

impl fmt::Display for Miss {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

/// What the tracker reports for one frame: the one estimate type, carried whole from
/// the tracker to the haptic loop, the live stream, the monitor and the CSVs. The
/// default is a frame with nothing found and no reason given (nothing tracked yet).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Estimate {
    pub detected: bool,
    /// Tip rotation from the reference, degrees CCW on screen.
    pub angle_deg: Option<f64>,
    /// Tip force through the cantilever model, nN (sign of the angle).
    pub force_nn: Option<f64>,
    /// The angle is beyond the model's table: the force is clamped.
    pub force_saturated: bool,
    /// Apex (blue meets green), frame pixels; predicted from the rigid tip when one of
    /// the two is out of view.
    pub apex_px: Option<[f64; 2]>,
    /// Every edge of the probe in view, in its calibration's order: the AFM pyramid's
    /// indexed by [`Edge::index`], a rigid probe's as its `[tracker.calibration.edges]`
    /// names them.
    pub edges: [Option<EdgeFit>; MAX_EDGES],
    /// Standard error of `angle_deg` from the frame's noise and the calibration's (each
    /// edge's orientation on the reference), degrees.
    pub angle_sigma_deg: Option<f64>,
    /// Frame pixels per reference pixel.
    pub scale: Option<f64>,
    /// In [0, 1]; `detected` requires it to pass the tracker's threshold.
    pub confidence: f64,
    /// Set when `detected` is false.
    pub miss: Option<Miss>,
}

impl Estimate {
    /// The force this frame may put in the operator's hand: a detection whose force was
    /// measured, finite and not clamped at the model's limit (a clamped force is not a
    /// measurement). The one rule: the haptic loop feels only this, and every output
    /// (the estimate CSV, the stream, the monitor) shows it as `felt` beside `detected`.
    pub fn felt_force_nn(&self) -> Option<f64> {
        self.force_nn
            .filter(|f| self.detected && !self.force_saturated && f.is_finite())
    }

    /// A detection with the force its angle bends `cantilever` by (through
    /// `Cantilever::force_nn`, clamped at the model's limit and saying so); without a
    /// cantilever, or for a miss, the estimate as it is.
    pub fn with_force(mut self, cantilever: Option<Cantilever>) -> Estimate {
        if let (true, Some(angle), Some(c)) = (self.detected, self.angle_deg, cantilever) {
            let force = c.force_nn(angle);
            self.force_nn = Some(force.value);
            self.force_saturated = force.saturated;
        }
        self
    }

    /// One of this estimate's values as every output shows it (the estimate CSV, the
    /// stream, the monitor): only for a detection, and only when finite.
    pub fn shown(&self, value: Option<f64>) -> Option<f64> {
        value.filter(|v| self.detected && v.is_finite())
    }

    /// The estimate with its pixels (apex, edge ends) counted from `origin`, for the
    /// numbers nanoforce writes out; drawing and tracking keep the pixel centre's.
    pub fn with_pixel_origin(mut self, origin: PixelOrigin) -> Estimate {
        self.apex_px = self.apex_px.map(|a| origin.output(a));
        for fit in self.edges.iter_mut().flatten() {
            fit.start_px = origin.output(fit.start_px);
            fit.end_px = origin.output(fit.end_px);
        }
        self
    }

    /// A frame without a usable tip.
    pub fn missed(miss: Miss, confidence: f64) -> Estimate {
        Estimate {
            detected: false,
            angle_deg: None,
            force_nn: None,
            force_saturated: false,
            apex_px: None,
            edges: [None; MAX_EDGES],
            angle_sigma_deg: None,
            scale: None,
            confidence,
            miss: Some(miss),
        }
    }
}

/// Bad calibration input (reading the image is the caller's job).
#[derive(Debug, thiserror::Error)]
pub enum VisionError {
    #[error("calibration: the reference image is {width}x{height}; at least 64x48 is needed")]
    ImageTooSmall { width: u32, height: u32 },
    #[error("calibration: {edge} click {point:?} is outside the {width}x{height} reference image")]
    ClickOutside {
        edge: Edge,
        point: [f64; 2],
        width: u32,
        height: u32,
    },
    #[error("calibration: {edge} edge not found near its clicks: {reason}")]
    EdgeNotFound { edge: Edge, reason: String },
    #[error("calibration: degenerate tip geometry: {0}")]
    Degenerate(String),
    #[error(transparent)]
    Rigid(#[from] RigidError),
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn only_a_measured_force_of_a_detection_is_felt() {
        let found = Estimate {
            detected: true,
            angle_deg: Some(0.4),
            force_nn: Some(120.0),
            apex_px: Some([10.0, 20.0]),
            confidence: 0.9,
            ..Estimate::default()
        };
        assert_eq!(found.felt_force_nn(), Some(120.0));
        for (why, e) in [
            (
                "not detected",
                Estimate {
                    detected: false,
                    ..found
                },
            ),
            (
                "no force",
                Estimate {
                    force_nn: None,
                    ..found
                },
            ),
            (
                "not finite",
                Estimate {
                    force_nn: Some(f64::NAN),
                    ..found
                },
            ),
            (
                "clamped",
                Estimate {
                    force_saturated: true,
                    ..found
                },
            ),
        ] {
            assert_eq!(e.felt_force_nn(), None, "{why}");
        }
    }
}
