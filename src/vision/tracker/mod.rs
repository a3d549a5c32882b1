//! The per-frame driver of one probe: the AFM pyramid's engine (`afm`) or a rigid
//! probe's (`super::rigid`), behind one [`Tracker`] that gives the one [`Estimate`].

mod afm;

pub(super) use afm::Detection;
use afm::PyramidTracker;

use image::GrayImage;

use super::calibration::Calibration;
use super::claim::Claim;
use super::options::{CalibrationConfig, PixelOrigin, TrackerConfig};
use super::rigid::{calibrate as calibrate_rigid, RigidError, RigidTemplate, RigidTracker};
use super::template::Pose;
use super::{Estimate, Miss, VisionError};
use crate::model::Cantilever;

/// Tracks one calibrated probe frame after frame: the AFM pyramid (red, blue, green)
/// or a rigid probe of named edges (`super::rigid`). Either gives the one
/// [`Estimate`]; a probe with a cantilever gives its force.
#[derive(Debug)]
pub struct Tracker {
    engine: Engine,
}

#[derive(Debug)]
enum Engine {
    Pyramid(Box<PyramidTracker>),
    Rigid {
        tracker: Box<RigidTracker>,
        cantilever: Option<Cantilever>,
        pixel_origin: PixelOrigin,
    },
}

impl Tracker {
    /// The AFM pyramid's tracker for the probe `calibration` describes; `cantilever`
    /// enables forces.
    pub fn new(
        cfg: &TrackerConfig,
        calibration: Calibration,
        cantilever: Option<Cantilever>,
    ) -> Tracker {
        Tracker {
            engine: Engine::Pyramid(Box::new(PyramidTracker::new(cfg, calibration, cantilever))),
        }
    }

    /// A rigid probe's tracker; `cantilever` (a tipless cantilever's) turns its
    /// rotation into a force. Refused when `tracker.scale_range` reaches beyond the
    /// scales a rigid probe is searched over.
    pub fn rigid(
        cfg: &TrackerConfig,
        template: RigidTemplate,
        cantilever: Option<Cantilever>,
    ) -> Result<Tracker, RigidError> {
        let mut tracker = RigidTracker::new(template, cfg.window_deg);
        if let Some(scales) = cfg.scale_range {
            tracker = tracker.with_scales(scales)?;
        }
        tracker.set_coherence(true);
        Ok(Tracker {
            engine: Engine::Rigid {
                tracker: Box::new(tracker),
                cantilever,
                pixel_origin: cfg.pixel_origin,
            },
        })
    }

    /// The tracker `clicks` calibrate on `reference`: the pyramid's for red, blue and
    /// green, a rigid probe's for named edges.
    pub fn from_reference(
        reference: &GrayImage,
        clicks: &CalibrationConfig,
        cfg: &TrackerConfig,
        cantilever: Option<Cantilever>,
    ) -> Result<Tracker, VisionError> {
        match (&clicks.apex, clicks.pyramid_points()) {
            (None, Some(_)) => {
                let calibration = Calibration::from_reference(reference, clicks, cfg)?;
                Ok(Tracker::new(cfg, calibration, cantilever))
            }
            (apex, _) => {
                let apex = apex.as_ref().ok_or_else(|| {
                    VisionError::Degenerate("a probe of named edges needs its apex edges".into())
                })?;
                let template = calibrate_rigid(
                    reference,
                    &clicks.edges,
                    [apex[0].as_str(), apex[1].as_str()],
                )?;
                Ok(Tracker::rigid(cfg, template, cantilever)?)
            }
        }
    }

    /// Turns coherence (searching near the last estimate first) on or off.
    pub fn set_coherence(&mut self, on: bool) {
        match &mut self.engine {
            Engine::Pyramid(t) => t.set_coherence(on),
            Engine::Rigid { tracker, .. } => tracker.set_coherence(on),
        }
    }

    /// Forgets the last estimate.
    pub fn reset(&mut self) {
        match &mut self.engine {
            Engine::Pyramid(t) => t.reset(),
            Engine::Rigid { tracker, .. } => tracker.reset(),
        }
    }

    /// The pyramid's calibration; none for a rigid probe of named edges.
    pub fn calibration(&self) -> Option<&Calibration> {
        match &self.engine {
            Engine::Pyramid(t) => Some(t.calibration()),
            Engine::Rigid { .. } => None,
        }
    }

    /// Where the configuration counts pixels from: estimates are in the conventions'
    /// frame, and what writes them out converts with [`Estimate::with_pixel_origin`].
    pub fn pixel_origin(&self) -> PixelOrigin {
        match &self.engine {
            Engine::Pyramid(t) => t.pixel_origin(),
            Engine::Rigid { pixel_origin, .. } => *pixel_origin,
        }
    }

    /// Tracks the probe in one 8-bit frame.
    pub fn track(&mut self, frame: &GrayImage) -> Estimate {
        match &mut self.engine {
            Engine::Pyramid(t) => t.track(frame),
            Engine::Rigid {
                tracker,
                cantilever,
                ..
            } => tracker.track(frame).with_force(*cantilever),
        }
    }

    /// The estimate of `frame` fitted and verified from `pose` alone, with no search
    /// (`PyramidTracker::track_from`, [`RigidTracker::track_from`]): whether a pose
    /// known from elsewhere passes the verification. A pose that is not one (a
    /// coordinate not finite, a scale not positive) is refused for what is wrong with
    /// it.
    pub fn track_from(&mut self, frame: &GrayImage, pose: Pose) -> Estimate {
        let refusal = if !pose.apex.iter().all(|c| c.is_finite()) {
            Some(Miss::ApexOutside)
        } else if !(pose.scale.is_finite() && pose.scale > 0.0) {
            Some(Miss::ScaleMismatch)
        } else if !pose.psi.is_finite() {
            Some(Miss::RotationOutside)
        } else {
            None
        };
        if let Some(miss) = refusal {
            return Estimate::missed(miss, 0.0);
        }
        match &mut self.engine {
            Engine::Pyramid(t) => t.track_from(frame, pose),
            Engine::Rigid {
                tracker,
                cantilever,
                ..
            } => tracker.track_from(frame, pose).with_force(*cantilever),
        }
    }

    /// Builds into `shared` the detection stages this probe's tracker first searches
    /// `frame` on, for the other probes' trackers ([`PyramidTracker::build_shared`]);
    /// a rigid probe's tracker shares none.
    pub(super) fn build_shared(&self, frame: &GrayImage, shared: &mut Detection) {
        if let Engine::Pyramid(t) = &self.engine {
            t.build_shared(frame, shared);
        }
    }

    /// As [`Tracker::track`], on the pyramid's detection stages `shared` holds where
    /// they are this tracker's ([`PyramidTracker::track_sharing`]).
    pub(super) fn track_sharing(&mut self, frame: &GrayImage, shared: &Detection) -> Estimate {
        match &mut self.engine {
            Engine::Pyramid(t) => t.track_sharing(frame, shared),
            Engine::Rigid { .. } => self.track(frame),
        }
    }

    /// Rules out one more body of another probe; false when it already was, or no
    /// room is left.
    pub(super) fn exclude_more(&mut self, claim: Claim) -> bool {
        match &mut self.engine {
            Engine::Pyramid(t) => t.exclude_more(claim),
            Engine::Rigid { tracker, .. } => tracker.exclude_more(claim),
        }
    }

    /// Tracks the frame just tracked again with what is now ruled out
    /// ([`PyramidTracker::retrack_sharing`]).
    pub(super) fn retrack_sharing(&mut self, frame: &GrayImage, shared: &Detection) -> Estimate {
        match &mut self.engine {
            Engine::Pyramid(t) => t.retrack_sharing(frame, shared),
            Engine::Rigid {
                tracker,
                cantilever,
                ..
            } => tracker.retrack(frame).with_force(*cantilever),
        }
    }
}
