//! Rigid probes of named straight edges: a tungsten needle, a tipless cantilever, a
//! gripper jaw, any probe whose end region is a rigid body bounded by two or more
//! straight edges. The template is calibrated from clicked pixels on each named edge
//! (`calibrate`); a frame sees it through a similarity (rotation, scale, apex).
//!
//! Tracking a frame (docs/rigid-probes.md):
//! - `search`: with no prior, a polarity-gated Hough search places the template from
//!   its two apex edges and its farthest edge;
//! - `fit`: each placement is fitted on the full-resolution grey levels, at stations
//!   along every edge in view (`station`), rotation, apex and scale at once, with
//!   robust weights; the rotation's standard error comes from the fit's residuals;
//! - `verify`: the frame shows this probe only when every edge the pose puts in view
//!   steps as calibrated (polarity, size) along its length and at the apex, the
//!   probe's sides of its edges are one body, an edge away from the apex is in view
//!   (it measures the size), no closed edge runs on past its end, and the apex,
//!   rotation and scale are in range. Each refusal names its reason.

mod autocal;
mod calibrate;
mod fit;
mod search;
mod station;
#[cfg(test)]
mod tests;

use image::GrayImage;

pub use autocal::{auto_calibrate, find_tip_points, RigidAutoClicks};
pub use calibrate::calibrate;
pub use fit::MAX_EDGES;

use super::claim::{claimed, rule_out, Claim, MAX_PROBES, NO_CLAIMS};
use super::geometry::{add, along, rotate, scale, screen_deg_from_image_rad};
use super::pyramid::Pyramid;
use super::template::Pose;
use super::{EdgeFit, EdgeName, Estimate, Miss, ScaleRange};
use fit::{Fit, Fitter};
use search::Search;

/// One named edge of a rigid probe, in the reference image, relative to the apex.
#[derive(Debug, Clone, PartialEq)]
pub struct RigidEdge {
    /// Its name, as refusals give it.
    pub name: EdgeName,
    /// Unit normal pointing into the probe.
    pub normal: [f64; 2],
    /// Signed distance of the line from the apex: `normal . (p - apex)` on it.
    pub offset: f64,
    /// Positions along `along(normal)` (from the apex's foot on the line) of the ends
    /// of the segment the reference shows, ascending.
    pub extent: [f64; 2],
    /// Whether each end of `extent` is where the reference frame ended (the edge goes
    /// on) rather than where the edge does.
    pub open: [bool; 2],
    /// The edge's bow: its depth from the line is `bow * (tau - bow_ends[0]) * (tau -
    /// bow_ends[1])` (a real needle's flank is not quite straight); nil for an edge too
    /// short to show one.
    pub bow: f64,
    pub bow_ends: [f64; 2],
    /// +1 when the probe's side is the brighter one, -1 when it is the darker.
    pub polarity: f64,
    /// The step across the edge on the reference, grey levels (inside minus outside,
    /// times the polarity); at most the median of all edges' steps, since a dark patch
    /// of background beside one edge on the reference would make its own too large a
    /// yardstick for frames where the probe has moved on.
    pub step: f64,
}

impl RigidEdge {
    /// The edge's depth at `tau` from its line (its chord), into the probe, pixels.
    pub fn bow_at(&self, tau: f64) -> f64 {
        self.bow * (tau - self.bow_ends[0]) * (tau - self.bow_ends[1])
    }

    /// The point at `tau` along the edge (on its bowed shape), relative to the apex,
    /// reference pixels.
    pub fn point(&self, tau: f64) -> [f64; 2] {
        add(
            scale(self.normal, self.offset + self.bow_at(tau)),
            scale(along(self.normal), tau),
        )
    }

    /// Length of the segment the reference shows, pixels.
    pub fn length(&self) -> f64 {
        self.extent[1] - self.extent[0]
    }
}

/// A rigid probe as its reference image shows it.
#[derive(Debug, Clone, PartialEq)]
pub struct RigidTemplate {
    pub edges: Vec<RigidEdge>,
    /// The tip point, reference pixels: where the two apex edges meet.
    pub apex: [f64; 2],
    /// Indices into `edges` of the two edges that meet at the apex.
    pub apex_edges: [usize; 2],
    /// Standard error of the reference's own edge directions, combined, radians: the
    /// floor of any frame's rotation error.
    pub angle_sigma_rad: f64,
}

impl Pose {
    /// A rigid probe's edge `edge` at `tau` (reference pixels along it) in the frame.
    pub fn place(&self, edge: &RigidEdge, tau: f64) -> [f64; 2] {
        add(
            self.apex,
            scale(rotate(edge.point(tau), self.psi), self.scale),
        )
    }
}

/// Bad calibration input for a rigid probe.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum RigidError {
    #[error("calibration: a rigid probe needs at least 2 named edges, {0} given")]
    TooFewEdges(usize),
    #[error("calibration: a rigid probe has at most {MAX_EDGES} named edges, {0} given")]
    TooManyEdges(usize),
    #[error("calibration: edge \"{0}\" is given twice")]
    EdgeNamedTwice(String),
    #[error("calibration: apex edge \"{0}\" is not one of the named edges")]
    UnknownApexEdge(String),
    #[error("calibration: the apex needs two different edges; \"{0}\" is given twice")]
    ApexEdgesSame(String),
    #[error("calibration: edge \"{edge}\" has {clicks} clicked pixel(s); at least 2 are needed")]
    TooFewClicks { edge: String, clicks: usize },
    #[error(
        "calibration: edge \"{edge}\" click {point:?} is outside the {width}x{height} reference image"
    )]
    ClickOutside {
        edge: String,
        point: [f64; 2],
        width: u32,
        height: u32,
    },
    #[error("calibration: edge \"{edge}\" not found near its clicks: {reason}")]
    EdgeNotFound { edge: String, reason: String },
    #[error(
        "calibration: apex edges \"{}\" and \"{}\" meet at {angle_deg:.1} deg; at least 10 deg is needed",
        edges[0], edges[1]
    )]
    ApexEdgesParallel { edges: [String; 2], angle_deg: f64 },
    #[error("calibration: the apex edges meet at {apex:?}, outside the reference image")]
    ApexOutside { apex: [f64; 2] },
    #[error(
        "tracker.scale_range = {0} must run upward inside {RIGID_SCALES}, the scales a \
         rigid probe is searched over"
    )]
    ScaleRange(ScaleRange),
}

/// The widest range of scales a rigid probe is searched over, frame pixels per
/// reference pixel; `tracker.scale_range` may narrow it.
pub const RIGID_SCALES: ScaleRange = ScaleRange::new(0.5, 2.0);

/// The poses a frame may show: the rotation's half-window and the scales.
#[derive(Debug, Clone, Copy)]
pub struct Bounds {
    pub window_rad: f64,
    pub scales: ScaleRange,
}

/// Tracks one rigid probe frame by frame. Buffers are kept between frames.
#[derive(Debug)]
pub struct RigidTracker {
    template: RigidTemplate,
    bounds: Bounds,
    pyramid: Pyramid,
    search: Search,
    fitter: Fitter,
    placements: Vec<Pose>,
    /// The placements fitted before those with apexes inside runs.
    tried: Vec<Pose>,
    last: Option<Pose>,
    /// The last pose before the frame last tracked, for tracking it again.
    last_before: Option<Pose>,
    coherence: bool,
    /// Other probes' bodies ruled out in this frame ([`crate::vision::ProbeSet`]).
    excluded: [Option<Claim>; MAX_PROBES - 1],
    /// Whether the frame last tracked was searched (its placements' scores are in
    /// `search`).
    searched: bool,
}

impl RigidTracker {
    /// A tracker of `template` whose rotation is searched within +-`window_deg`, and
    /// its scale over [`RIGID_SCALES`].
    pub fn new(template: RigidTemplate, window_deg: f64) -> RigidTracker {
        RigidTracker {
            template,
            bounds: Bounds {
                window_rad: window_deg.to_radians(),
                scales: RIGID_SCALES,
            },
            pyramid: Pyramid::default(),
            search: Search::default(),
            fitter: Fitter::default(),
            placements: Vec::with_capacity(search::MAX_PLACEMENTS + 1),
            tried: Vec::with_capacity(search::MAX_PLACEMENTS + 1),
            last: None,
            last_before: None,
            coherence: false,
            excluded: NO_CLAIMS,
            searched: false,
        }
    }

    /// The same tracker demanding both apex edges show the corner, as a reference
    /// does (nothing touches its tip): a tip point placed off the corner does not
    /// verify with one apex edge's corner unseen.
    pub(super) fn whole_corner(mut self) -> RigidTracker {
        self.fitter.whole_corner = true;
        self
    }

    /// Searches and accepts only scales in `scales`, which must lie inside
    /// [`RIGID_SCALES`].
    pub fn with_scales(mut self, scales: ScaleRange) -> Result<RigidTracker, RigidError> {
        if !(scales.lo < scales.hi && scales.within(&RIGID_SCALES)) {
            return Err(RigidError::ScaleRange(scales));
        }
        self.bounds.scales = scales;
        Ok(self)
    }

    pub fn template(&self) -> &RigidTemplate {
        &self.template
    }

    /// With coherence on, a frame is first fitted from the last detection's pose, and
    /// searched whole only when that fails (a time sequence); off, every frame is
    /// searched whole (frames in any order).
    pub fn set_coherence(&mut self, on: bool) {
        self.coherence = on;
        self.last = None;
    }

    /// Forgets the last pose.
    pub fn reset(&mut self) {
        self.last = None;
    }

    /// The estimate of one frame. Its force is the caller's (a rigid probe without a
    /// cantilever has none).
    pub fn track(&mut self, frame: &GrayImage) -> Estimate {
        self.excluded = NO_CLAIMS;
        self.track_frame(frame)
    }

    /// Rules out one more body of another probe; false when it already was, or no room
    /// is left.
    pub(crate) fn exclude_more(&mut self, claim: Claim) -> bool {
        rule_out(&mut self.excluded, claim)
    }

    /// Tracks the frame just tracked again, from the state before it, with what is
    /// now ruled out: on the last search's scores when it was searched (the same
    /// estimate as searching it again, without the votes), else as a new frame.
    pub(crate) fn retrack(&mut self, frame: &GrayImage) -> Estimate {
        self.last = self.last_before;
        if !self.searched {
            return self.track_frame(frame);
        }
        self.search
            .select(&self.pyramid, &self.excluded, &mut self.placements);
        self.fit_placements(frame)
    }

    fn track_frame(&mut self, frame: &GrayImage) -> Estimate {
        self.last_before = self.last;
        self.searched = false;
        let t = &self.template;
        if frame.width() < MIN_FRAME_PX || frame.height() < MIN_FRAME_PX {
            self.last = None;
            return Estimate::missed(Miss::NoCandidates, 0.0);
        }
        if let Some(prior) = self.last.filter(|_| self.coherence) {
            if let Ok(fit) = self.fitter.fit(frame, t, prior, &self.bounds) {
                if !claimed(&self.excluded, fit.pose.apex) {
                    let estimate = estimate(t, &fit);
                    self.last = Some(fit.pose);
                    return estimate;
                }
            }
        }
        self.pyramid
            .build_binned(frame, search_binning(t, frame.width()));
        self.search.placements(
            &self.pyramid,
            t,
            &self.bounds,
            &self.excluded,
            &mut self.placements,
        );
        self.searched = true;
        self.fit_placements(frame)
    }

    /// The estimate from the placements found: the most confident verified fit
    /// (the first sure one), or the most telling refusal. When none verifies in a
    /// searched frame, the best placements with apexes inside the first apex edge's
    /// runs competing too are fitted, those not fitted yet.
    fn fit_placements(&mut self, frame: &GrayImage) -> Estimate {
        let mut refusal: Option<(Miss, f64)> = None;
        let mut placed = !self.placements.is_empty();
        let mut best = self.fit_each(frame, &mut refusal);
        if best.is_none() && self.searched {
            std::mem::swap(&mut self.placements, &mut self.tried);
            self.search.placements_within_runs(
                &self.pyramid,
                &self.template,
                &self.bounds,
                &self.excluded,
                &self.tried,
                &mut self.placements,
            );
            placed |= !self.placements.is_empty();
            best = self.fit_each(frame, &mut refusal);
        }
        match best {
            Some(fit) => {
                self.last = Some(fit.pose);
                estimate(&self.template, &fit)
            }
            None => {
                self.last = None;
                let (miss, confidence) = match refusal {
                    Some(refusal) => refusal,
                    None if placed => (Miss::Inconsistent, 0.0),
                    None => (Miss::NoCandidates, 0.0),
                };
                Estimate::missed(miss, confidence)
            }
        }
    }

    /// The most confident verified fit of the placements (the first sure one); else
    /// `refusal` keeps the most telling refusal.
    fn fit_each(&mut self, frame: &GrayImage, refusal: &mut Option<(Miss, f64)>) -> Option<Fit> {
        let t = &self.template;
        let mut best: Option<Fit> = None;
        for &placement in &self.placements {
            match self.fitter.fit(frame, t, placement, &self.bounds) {
                // Not a verdict on this probe: the other placements are tried.
                Ok(fit) if claimed(&self.excluded, fit.pose.apex) => {
                    if refusal.is_none() {
                        *refusal = Some((Miss::OtherProbe, 0.0));
                    }
                }
                Ok(fit) => {
                    let sure = fit.confidence >= SURE_CONFIDENCE;
                    if best.as_ref().is_none_or(|b| fit.confidence > b.confidence) {
                        best = Some(fit);
                    }
                    if sure {
                        break;
                    }
                }
                Err((miss, confidence)) => {
                    if refusal.is_none_or(|(_, c)| confidence > c) {
                        *refusal = Some((miss, confidence));
                    }
                }
            }
        }
        best
    }

    /// The estimate of `frame` fitted and verified from `pose` alone, with no search
    /// and no change to the tracker's state: whether a pose known from elsewhere (a
    /// rendered frame's truth) passes verification, which tells a frame the search
    /// missed from one the verification refuses.
    pub fn track_from(&mut self, frame: &GrayImage, pose: Pose) -> Estimate {
        if frame.width() < MIN_FRAME_PX || frame.height() < MIN_FRAME_PX {
            return Estimate::missed(Miss::NoCandidates, 0.0);
        }
        match self.fitter.fit(frame, &self.template, pose, &self.bounds) {
            Ok(fit) => estimate(&self.template, &fit),
            Err((miss, confidence)) => Estimate::missed(miss, confidence),
        }
    }
}

/// Frames narrower or lower than this, pixels, show no probe to track.
const MIN_FRAME_PX: u32 = 16;

/// A verified placement this confident (every edge held at this share of its
/// stations) ends the search: the placements after it have fewer votes.
const SURE_CONFIDENCE: f64 = 0.9;

/// Shortest an apex edge may be in the search's detection image, pixels: shorter, its
/// few pixels' votes are lost in the background's.
const MIN_SEARCH_EDGE_PX: f64 = 8.0;

/// The binning of the search's detection image for a frame `width` pixels wide: the
/// tracker's usual binning, finer when an apex edge (a needle's blunt end) would be
/// shorter than [`MIN_SEARCH_EDGE_PX`] there.
fn search_binning(t: &RigidTemplate, width: u32) -> u32 {
    let shortest = t
        .apex_edges
        .map(|e| t.edges[e].length())
        .into_iter()
        .fold(f64::INFINITY, f64::min);
    let fine = (shortest / MIN_SEARCH_EDGE_PX).floor().max(1.0) as u32;
    super::pyramid::binning_factor(width).min(fine)
}

/// The estimate of a verified fit: its pose, standard error and every edge's visible
/// segment.
fn estimate(t: &RigidTemplate, fit: &Fit) -> Estimate {
    let mut edges = [None; MAX_EDGES];
    for (slot, (e, seen)) in edges.iter_mut().zip(t.edges.iter().zip(&fit.edges)) {
        *slot = seen.map(|s| EdgeFit {
            start_px: fit.pose.place(e, s.span[0]),
            end_px: fit.pose.place(e, s.span[1]),
            support: s.held as u32,
            contrast: s.step,
        });
    }
    Estimate {
        detected: true,
        angle_deg: Some(screen_deg_from_image_rad(fit.pose.psi)),
        force_nn: None,
        force_saturated: false,
        apex_px: Some(fit.pose.apex),
        edges,
        angle_sigma_deg: Some(fit.angle_sigma_rad.to_degrees()),
        scale: Some(fit.pose.scale),
        confidence: fit.confidence,
        miss: None,
    }
}

/// A blunt needle's template, for the unit tests: the upper flank and the end face meet
/// at the apex (the origin); the lower flank lies 12 px below, away from it.
#[cfg(test)]
fn needle_template() -> RigidTemplate {
    let edge = |name: &str, normal: [f64; 2], offset: f64, extent: [f64; 2]| RigidEdge {
        name: EdgeName::intern(name),
        normal,
        offset,
        extent,
        open: [true, false],
        bow: 0.0,
        bow_ends: extent,
        polarity: 1.0,
        step: 100.0,
    };
    RigidTemplate {
        edges: vec![
            edge("upper", [0.0, 1.0], 0.0, [-200.0, 0.0]),
            edge("end", [-1.0, 0.0], 0.0, [0.0, 12.0]),
            edge("lower", [0.0, -1.0], -12.0, [-200.0, 0.0]),
        ],
        apex: [0.0, 0.0],
        apex_edges: [0, 1],
        angle_sigma_rad: 1e-4,
    }
}
