//! The AFM pyramid's engine: detection on the binned frame, the rigid-tip search,
//! sub-pixel refinement on the full frame, verification, and the estimate.
//!
//! Coherence (the paper's "mesh shifted" variant) is a shortcut, never a dependency: when
//! the last estimate was confident the search first looks only near its rotation, and
//! the result is kept only if it verifies on its own; otherwise, and always after a
//! miss, the whole window is searched. A magnification jump or frames in random order
//! are therefore tracked from scratch.
//!
//! The search ranks hypotheses on the binned edge map, where a clutter line a couple of
//! pixels beside a face looks like that face. When the best one does not verify
//! convincingly, a few runners-up placed elsewhere are refined and verified as well,
//! and one clearly more confident, explaining as many edges, takes its place.

use image::GrayImage;

use crate::model::Cantilever;
use crate::vision::bands::{bands, bend_prior, refined_pose, visible_segment};
use crate::vision::calibration::{CalibratedEdge, Calibration};
use crate::vision::candidates::{Candidates, CANDIDATES_PER_EDGE, WIDE_CANDIDATES_PER_EDGE};
use crate::vision::claim::{claimed, rule_out, Claim, MAX_PROBES, NO_CLAIMS};
use crate::vision::edges::EdgeMap;
use crate::vision::geometry::{norm, screen_deg_from_image_rad, sub, wrap_pi};
use crate::vision::hough::{Hough, PEAKS_PER_EDGE, WIDE_PEAKS_PER_EDGE};
use crate::vision::hypothesis::{Hypothesis, Prior, Search};
use crate::vision::options::{PixelOrigin, ScaleRange, Threshold, TrackerConfig};
use crate::vision::pyramid::Pyramid;
use crate::vision::refine::{half_width, Band, FitResult, Refiner, Tie, Turns};
use crate::vision::stations;
use crate::vision::template::{PerEdge, Pose, Template, BLUE, EDGES, GREEN, RED};
use crate::vision::verify::{self, Evidence, MIN_CONFIDENCE};
use crate::vision::{Edge, EdgeFit, Estimate, Miss, MAX_EDGES};

/// How far the coherent search looks around the last rotation, radians.
const COHERENT_TOL_RAD: f64 = 0.07;
/// An edge fitted at less than this share of its calibrated contrast is left out of the
/// final fit when two others hold (a particle or scratch sitting on it).
const DROP_CONTRAST_RATIO: f64 = 0.4;

/// A rotation is outside the window when it lies beyond it by more than this many of
/// its standard errors plus [`WINDOW_SLACK_RAD`]: a tip turned exactly to the window's
/// edge is measured either side of it.
const WINDOW_SIGMAS: f64 = 3.0;
const WINDOW_SLACK_RAD: f64 = 0.05 * std::f64::consts::PI / 180.0;

/// A frame missed on the detection image is searched again binned more coarsely, at
/// these multiples (numerator, denominator) of the detection image's binning in turn,
/// until one detects (see [`PyramidTracker::track`]); a multiple that bins no coarser
/// than the detection image (1.5 of a binning of 1) is skipped. Each binning averages
/// the noise and breaks a face into pieces differently: over the nine real-background
/// seeds (5,112 probe frames) the three find 5 of the 44 frames that twice as coarse
/// alone misses, all under noise 30-46 over a bright textured ground; over the noisy
/// sessions of ten seeds more (101-110, 1,431 probe frames under noise 30-48), 10 of
/// 51; and no decoy of the seven adversarial seeds.
const COARSE_RETRIES: [(u32, u32); 3] = [(2, 1), (3, 2), (3, 1)];
/// ... when the faintest calibrated edge's contrast is below this many gradient noises
/// of the frame's detection image. Over real backgrounds the frames with noise 30-48
/// lie at 10-16, the adversarial suite's frames (the rendered looks) at 22 or more
/// (where a second search found nothing but more decoys: docs/tracker.md).
const RETRY_CONTRAST_NOISES: f64 = 16.0;

/// The binnings of [`COARSE_RETRIES`] over a detection image binned `base x base`,
/// in turn, each coarser than it.
fn coarser(base: u32) -> impl Iterator<Item = u32> {
    COARSE_RETRIES
        .into_iter()
        .map(move |(num, den)| num * base / den)
        .filter(move |&factor| factor > base)
}

/// The edges a grey-level fit placed: given a band and found by the fit.
fn fitted_edges(bands: &PerEdge<Option<Band>>, fit: &FitResult) -> PerEdge<bool> {
    std::array::from_fn(|e| bands[e].is_some() && fit.edges[e].is_some())
}

/// Blur (pixels) the coarse fit's bands are sized for, at least: SEM frames range from
/// 0.8 to 1.6 (docs/renderer.md).
const START_BLUR_PX: f64 = 1.4;

/// An edge a hypothesis left out is fitted only if the edge map covers this share of it.
const CONFIRMED_FRACTION: f64 = 0.5;
/// Below this confidence the search's runners-up are refined and verified as well: a
/// clutter line running beside a face, on past the apex, can win the search with a
/// tip placed at its crossing with the other face (docs/tracker.md, "Runners-up").
const SURE_CONFIDENCE: f64 = 0.8;
/// Most runners-up refined per attempt.
const RUNNERS_UP: usize = 3;
/// How much more confident than the search's choice a runner-up must be to replace it.
/// Confidence is a verdict on one hypothesis, not a ranking: near-copies of the choice
/// (the same tip, its bands placed a little differently) verify within a few
/// hundredths of it, either way.
const RIVAL_MARGIN: f64 = 0.1;
/// Runners-up placed this close to one already tried (apex, detection pixels; rotation,
/// radians) are the same tip and are not refined again.
const SAME_APEX_PX: f64 = 2.0;
const SAME_PSI_RAD: f64 = 0.5 * std::f64::consts::PI / 180.0;

/// Whether a hypothesis found at least two edges and scores above the background.
fn complete(hyp: &Hypothesis) -> bool {
    let found = hyp
        .coverage
        .iter()
        .filter(|c| c.visible >= 4.0 && c.fraction() >= 0.5)
        .count();
    found >= 2 && hyp.score > 0.0
}

/// Share of a hypothesis' predicted edge segments covered by edge pixels (the
/// evidence's `coverage`).
fn coverage(hyp: &Hypothesis) -> f64 {
    let (sup, vis) = hyp
        .coverage
        .iter()
        .fold((0.0, 0.0), |(s, v), c| (s + c.supported, v + c.visible));
    if vis > 0.0 {
        sup / vis
    } else {
        0.0
    }
}

/// Whether two placements are the same tip.
fn same_place(a: &Pose, b: &Pose) -> bool {
    norm(sub(a.apex, b.apex)) <= SAME_APEX_PX && wrap_pi(a.psi - b.psi).abs() <= SAME_PSI_RAD
}

/// Whether a runner-up's estimate `alt` replaces `best` (so far), when the search's
/// choice had confidence `first`: clearly more confident, and explaining at least as
/// many edges. A wrong placement that leaves a faint face out can verify 0.15 higher
/// than the right tip with both faces: the confidence takes the faintest edge in view.
fn outranks(alt: &Estimate, best: &Estimate, first: f64) -> bool {
    let edges = |e: &Estimate| e.edges.iter().flatten().count();
    alt.confidence > best.confidence.max(first + RIVAL_MARGIN) && edges(alt) >= edges(best)
}

/// The detection image of a frame and its edge map: the stages of [`PyramidTracker::track`]
/// that depend only on the frame, the binning and the edge threshold, which the
/// trackers of several probes in one view share ([`crate::vision::ProbeSet`]).
#[derive(Debug, Default)]
pub struct Detection {
    pyr: Pyramid,
    edges: EdgeMap,
    /// What `pyr` and `edges` hold of the frame being tracked: the binning factor and
    /// the edge threshold's bits (None: `pyr` only); None: nothing of it.
    built: Option<(u32, Option<u32>)>,
}

impl Detection {
    /// Forgets the frame: the next tracker builds its own stages.
    pub fn clear(&mut self) {
        self.built = None;
    }
}

/// The last confident estimate, for coherence.
#[derive(Debug, Clone, Copy)]
struct Last {
    psi: f64,
}

/// Tracks the AFM pyramid's tip of one calibrated probe, frame after frame.
#[derive(Debug)]
pub struct PyramidTracker {
    threshold: Threshold,
    window_rad: f64,
    calibration: Calibration,
    /// The final fits' tie between the edges: each by its calibration error.
    tied: Turns,
    cantilever: Option<Cantilever>,
    /// `tracker.edge_bias_px`: the reported apex is where the true faces meet.
    edge_bias_px: f64,
    /// `tracker.scale_range`: a pose at another scale is not this probe.
    scale_range: Option<ScaleRange>,
    /// `tracker.pixel_origin`, for whoever writes the estimates out.
    pixel_origin: PixelOrigin,
    coherence: bool,
    last: Option<Last>,
    /// `last` before the frame being tracked, for a second search of it.
    last_before: Option<Last>,
    /// Pyramids other probes' trackers claimed in the frame being tracked: a
    /// hypothesis with its apex on one is not this probe (several probes in one view).
    excluded: [Option<Claim>; MAX_PROBES - 1],
    /// This tracker's own detection stages, where it cannot share another's.
    det: Detection,
    /// The binning factor of the stages searched last.
    factor: u32,
    hough: Hough,
    cands: Candidates,
    search: Search,
    refiner: Refiner,
}

impl PyramidTracker {
    /// A tracker for the probe `calibration` describes; `cantilever` enables forces.
    pub fn new(
        cfg: &TrackerConfig,
        calibration: Calibration,
        cantilever: Option<Cantilever>,
    ) -> PyramidTracker {
        let sigma =
            |f: fn(&CalibratedEdge) -> f64| Edge::ALL.map(|e| f(calibration.edge(e)).to_radians());
        let tied = Turns::Tied(Tie {
            weigh: sigma(|e| e.orientation_noise_sigma_deg),
            error: sigma(|e| e.orientation_sigma_deg),
        });
        PyramidTracker {
            threshold: cfg.threshold,
            window_rad: cfg.window_deg.to_radians(),
            calibration,
            tied,
            cantilever,
            edge_bias_px: cfg.edge_bias_px,
            scale_range: cfg.scale_range,
            pixel_origin: cfg.pixel_origin,
            coherence: true,
            last: None,
            last_before: None,
            excluded: NO_CLAIMS,
            det: Detection::default(),
            factor: 1,
            hough: Hough::default(),
            cands: Candidates::default(),
            search: Search::default(),
            refiner: Refiner::default(),
        }
    }

    /// Turns coherence (searching near the last estimate first) on or off.
    pub fn set_coherence(&mut self, on: bool) {
        self.coherence = on;
        self.last = None;
    }

    /// Forgets the last estimate.
    pub fn reset(&mut self) {
        self.last = None;
    }

    pub fn calibration(&self) -> &Calibration {
        &self.calibration
    }

    /// Where the configuration counts pixels from: estimates are in the conventions' frame,
    /// and what writes them out converts with [`Estimate::with_pixel_origin`].
    pub fn pixel_origin(&self) -> PixelOrigin {
        self.pixel_origin
    }

    /// Tracks the tip in one 8-bit frame.
    pub fn track(&mut self, frame: &GrayImage) -> Estimate {
        self.det.clear();
        self.excluded = NO_CLAIMS;
        self.track_frame(frame, None)
    }

    /// Builds into `shared` the detection stages this tracker first searches `frame`
    /// on, for the other probes' trackers to share ([`PyramidTracker::track_sharing`]).
    pub(super) fn build_shared(&self, frame: &GrayImage, shared: &mut Detection) {
        self.build(
            frame,
            shared,
            crate::vision::pyramid::binning_factor(frame.width()),
        );
    }

    /// As [`PyramidTracker::track`], searching on the stages `shared` holds for this
    /// frame (from another probe's tracker) where they are this tracker's (the same
    /// binning, the same edge threshold), and on its own otherwise.
    pub(super) fn track_sharing(&mut self, frame: &GrayImage, shared: &Detection) -> Estimate {
        self.det.clear();
        self.excluded = NO_CLAIMS;
        self.track_frame(frame, Some(shared))
    }

    /// Rules out one more pyramid; false when it already was, or no room is left.
    pub(super) fn exclude_more(&mut self, claim: Claim) -> bool {
        rule_out(&mut self.excluded, claim)
    }

    /// Tracks the frame just tracked again, from the state before it (with what is
    /// now ruled out), sharing detection stages as [`PyramidTracker::track_sharing`].
    pub(super) fn retrack_sharing(&mut self, frame: &GrayImage, shared: &Detection) -> Estimate {
        self.last = self.last_before;
        self.track_frame(frame, Some(shared))
    }

    /// Tracks `frame` on the stages of `shared` where they are this tracker's, on its
    /// own stages otherwise.
    fn track_frame(&mut self, frame: &GrayImage, shared: Option<&Detection>) -> Estimate {
        let mut own = std::mem::take(&mut self.det);
        let estimate = self.track_on(frame, shared, &mut own);
        self.det = own;
        estimate
    }

    fn track_on(
        &mut self,
        frame: &GrayImage,
        shared: Option<&Detection>,
        own: &mut Detection,
    ) -> Estimate {
        self.last_before = self.last;
        let template = *self.calibration.template();
        let base = crate::vision::pyramid::binning_factor(frame.width());
        let det = self.stages(frame, shared, own, base);
        self.search_stages(det, &template, false);
        let prior = match (self.coherence, self.last) {
            (true, Some(last)) => Some(Prior {
                psi: last.psi,
                psi_tol: COHERENT_TOL_RAD,
            }),
            _ => None,
        };
        let mut estimate = None;
        if prior.is_some() {
            estimate = self
                .attempt(frame, det, &template, prior)
                .filter(|e| e.detected);
        }
        let mut estimate = estimate.unwrap_or_else(|| {
            self.attempt(frame, det, &template, None)
                .unwrap_or_else(|| Estimate::missed(Miss::NoCandidates, 0.0))
        });
        // Faces that the detection image breaks up under strong noise: when the
        // faintest calibrated edge steps by fewer than RETRY_CONTRAST_NOISES of this
        // frame's gradient noise, its Canny seeds (5 noises) are chance, and a frame
        // missed for any reason (no tip found, or the tips found refused: a face's
        // pieces can make a wrong placement that the verification refuses) is
        // searched again binned more coarsely (less noise per detection pixel, the
        // same step; see COARSE_RETRIES), as long as the tip stays large enough there
        // to be placed.
        if !estimate.detected && self.faint_under_noise(det) {
            for factor in coarser(base) {
                let det = self.stages(frame, None, own, factor);
                if let Some(e) = self.search_again(frame, det, &template, false) {
                    estimate = e;
                    break;
                }
            }
        }
        // A short face beside many long lines of the background (grain boundaries,
        // a sample's rails) can be crowded out of the Hough peaks and candidates
        // kept per edge, so that no placement near the tip is ever made: a frame
        // still missed is searched once more on its detection image with more of
        // them kept (WIDE_PEAKS_PER_EDGE, WIDE_CANDIDATES_PER_EDGE).
        if !estimate.detected {
            let det = self.stages(frame, shared, own, base);
            if let Some(e) = self.search_again(frame, det, &template, true) {
                estimate = e;
            }
        }
        self.last = match (estimate.detected, estimate.angle_deg) {
            (true, Some(a)) => Some(Last {
                psi: -a.to_radians(),
            }),
            _ => None,
        };
        estimate
    }

    /// The estimate of `frame` fitted and verified from `pose` (frame pixels, the
    /// apex where the imaged edges meet) alone, with no search and nothing carried to
    /// the next frame: whether a pose known from elsewhere (a rendered frame's truth)
    /// passes, which tells a frame the search missed from one the verification
    /// refuses. The pose is placed as the search places a pair's left-out edge (each
    /// edge's support walked on the edge map where the pose puts it), on the detection
    /// image the frame is searched on first and, where a missed frame is searched
    /// again more coarsely, on those binnings in turn until one detects.
    pub fn track_from(&mut self, frame: &GrayImage, pose: Pose) -> Estimate {
        let template = *self.calibration.template();
        let base = crate::vision::pyramid::binning_factor(frame.width());
        let mut own = std::mem::take(&mut self.det);
        own.clear();
        self.build(frame, &mut own, base);
        let mut estimate = self.evaluate_at(frame, &template, &own, pose);
        if !estimate.detected && self.faint_under_noise(&own) {
            for factor in coarser(base) {
                self.build(frame, &mut own, factor);
                estimate = self.evaluate_at(frame, &template, &own, pose);
                if estimate.detected {
                    break;
                }
            }
        }
        self.det = own;
        estimate
    }

    /// [`Self::evaluate`] of `pose` (frame pixels) placed on `det`.
    fn evaluate_at(
        &mut self,
        frame: &GrayImage,
        t: &Template,
        det: &Detection,
        pose: Pose,
    ) -> Estimate {
        self.factor = det.pyr.factor;
        let hyp = crate::vision::hypothesis::at_pose(t, &det.pyr, &det.edges, pose);
        self.evaluate(frame, t, &hyp)
    }

    /// Whether the faintest calibrated edge steps by fewer than
    /// [`RETRY_CONTRAST_NOISES`] of the gradient noise of `det`'s detection image: a
    /// missed frame is searched again more coarsely ([`coarser`]).
    fn faint_under_noise(&self, det: &Detection) -> bool {
        let faintest = Edge::ALL
            .map(|e| self.calibration.edge(e).contrast.abs())
            .into_iter()
            .fold(f64::INFINITY, f64::min);
        faintest < RETRY_CONTRAST_NOISES * f64::from(det.edges.noise)
    }

    /// The edge threshold of this tracker on detection image `pyr` (none without the
    /// grey mask).
    fn edge_threshold(&self, pyr: &Pyramid) -> f32 {
        if self.calibration.grey_mask() {
            pyr.threshold(self.threshold)
        } else {
            f32::NEG_INFINITY
        }
    }

    /// Whether `det` holds this tracker's stages of the frame binned `factor x factor`.
    fn holds(&self, det: &Detection, factor: u32) -> bool {
        matches!(det.built, Some((f, Some(bits)))
            if f == factor && bits == self.edge_threshold(&det.pyr).to_bits())
    }

    /// Builds this tracker's binning and edges of `frame` binned `factor x factor` into
    /// `det`, keeping what it holds of them already.
    fn build(&self, frame: &GrayImage, det: &mut Detection, factor: u32) {
        if det.built.is_none_or(|(f, _)| f != factor) {
            det.pyr.build_binned(frame, factor);
            det.built = Some((factor, None));
        }
        let threshold = self.edge_threshold(&det.pyr);
        let built = Some((factor, Some(threshold.to_bits())));
        if det.built != built {
            det.edges.detect(&det.pyr, threshold);
            det.built = built;
        }
    }

    /// The stages to search `frame` binned `factor x factor` on: `shared`'s where they
    /// are this tracker's, else `own`, built.
    fn stages<'a>(
        &self,
        frame: &GrayImage,
        shared: Option<&'a Detection>,
        own: &'a mut Detection,
        factor: u32,
    ) -> &'a Detection {
        if let Some(shared) = shared.filter(|s| self.holds(s, factor)) {
            return shared;
        }
        self.build(frame, own, factor);
        own
    }

    /// The search's stages on `det`: Hough votes, peaks and line candidates (more of
    /// both per edge in a `wide` search).
    fn search_stages(&mut self, det: &Detection, template: &Template, wide: bool) {
        let (peaks, lines) = if wide {
            (WIDE_PEAKS_PER_EDGE, WIDE_CANDIDATES_PER_EDGE)
        } else {
            (PEAKS_PER_EDGE, CANDIDATES_PER_EDGE)
        };
        let (w, h) = (det.pyr.width, det.pyr.height);
        self.factor = det.pyr.factor;
        self.hough
            .configure(w, h, self.window_rad, template.gradient_angles());
        self.hough.vote(&det.edges.points, det.edges.noise);
        self.hough.find_peaks(peaks);
        self.cands.build(
            &self.hough.peaks,
            &det.edges.points,
            &self.hough.voters,
            template.gradient_angles(),
            [w, h],
            lines,
        );
    }

    /// A missed frame searched again on `det` (`wide`: see [`Self::search_stages`]):
    /// its estimate if that search detects the tip.
    fn search_again(
        &mut self,
        frame: &GrayImage,
        det: &Detection,
        template: &Template,
        wide: bool,
    ) -> Option<Estimate> {
        self.search_stages(det, template, wide);
        self.attempt(frame, det, template, None)
            .filter(|e| e.detected)
    }

    /// One search (restricted by `prior` if given) and its verification.
    fn attempt(
        &mut self,
        frame: &GrayImage,
        det: &Detection,
        t: &Template,
        prior: Option<Prior>,
    ) -> Option<Estimate> {
        if self.cands.list.len() < 2 {
            return Some(Estimate::missed(Miss::NoCandidates, 0.0));
        }
        // Placements on another probe's claimed pyramid are not this probe's.
        let (excluded, pyr) = (&self.excluded, &det.pyr);
        let ruled_out = |apex: [f64; 2]| claimed(excluded, pyr.to_frame(apex));
        if self
            .search
            .run(t, &self.cands, &det.edges, prior, &ruled_out)
            .is_none()
        {
            return Some(Estimate::missed(Miss::Inconsistent, 0.0));
        }
        // The shortlist is ranked by support, and a placement many times the tip's
        // size along a background's long straight lines can outscore the tip while
        // showing only one edge (a dark probe at 1200x beside a sample's rails: the
        // tip, complete, ranked second). The best-ranked placement that shows two
        // edges is the search's choice.
        let Some(hyp) = self.search.ranked().iter().find(|h| complete(h)).copied() else {
            return Some(Estimate::missed(Miss::Inconsistent, 0.0));
        };
        let first = self.evaluate(frame, t, &hyp);
        if first.confidence >= SURE_CONFIDENCE {
            return Some(first);
        }
        // Not convincing: the runners-up placed elsewhere are refined and verified too.
        let mut best = first;
        let mut tried = [hyp.pose; RUNNERS_UP + 1];
        let mut n = 1;
        for k in 1..self.search.ranked().len() {
            if n > RUNNERS_UP {
                break;
            }
            let h = self.search.ranked()[k];
            if !complete(&h) || tried[..n].iter().any(|p| same_place(p, &h.pose)) {
                continue;
            }
            tried[n] = h.pose;
            n += 1;
            // Its confidence is at most its coverage's score: one that cannot outrank
            // even at that is not refined.
            let bar = best.confidence.max(first.confidence + RIVAL_MARGIN);
            if verify::coverage_score(coverage(&h)) <= bar {
                continue;
            }
            let alt = self.evaluate(frame, t, &h);
            if outranks(&alt, &best, first.confidence) {
                best = alt;
            }
        }
        Some(best)
    }

    /// Each edge's calibrated signed step, in edge order.
    fn calibrated_steps(&self) -> PerEdge<f64> {
        Edge::ALL.map(|e| self.calibration.edge(e).contrast)
    }

    /// A hypothesis refined and verified.
    ///
    /// A tip placed from its two faces alone and refused for its beam edge or its
    /// scale is fitted and verified once more at the scale where the frame shows the
    /// beam edge, if it does anywhere ([`stations::beam_edge_scale`]): faces fading
    /// into a bright background place the scale far off. That second placement is
    /// taken only with the beam edge in its fit and the beam's thickness calibrated,
    /// so that the lower face and the free end check the scale found: without them,
    /// a probe of another geometry finds a scale where its own beam edge passes.
    /// Where the frame shows the beam edge nowhere, the tip is placed at the smallest
    /// scale that puts it out of view ([`stations::beam_out_of_view_scale`]) and kept
    /// only with its faces running to the ends that scale gives them
    /// ([`stations::faces_run_to_border`]).
    fn evaluate(&mut self, frame: &GrayImage, t: &Template, hyp: &Hypothesis) -> Estimate {
        let Some((pose, fit, bands)) = self.refine(frame, t, hyp, false) else {
            return Estimate::missed(Miss::LowConfidence, 0.0);
        };
        let first = self.verdict(frame, t, hyp, &pose, &fit, &bands);
        let fitted = fitted_edges(&bands, &fit);
        let refused_scale = first.miss == Some(Miss::EdgeMissing(Edge::Red.into()))
            || first.miss == Some(Miss::ScaleMismatch);
        if !(refused_scale && !fitted[RED] && fitted[BLUE] && fitted[GREEN]) {
            return first;
        }
        let k = self.factor as f64;
        let red_step = self.calibration.edge(Edge::Red).contrast;
        let shown = t
            .beam_px
            .and_then(|_| stations::beam_edge_scale(frame, t, &pose, fit.blur, red_step));
        if let Some(scale) = shown {
            let moved = crate::vision::hypothesis::rescaled(hyp, scale / k);
            if let Some((pose, fit, bands)) = self.refine(frame, t, &moved, true) {
                let second = self.verdict(frame, t, &moved, &pose, &fit, &bands);
                if second.detected && fitted_edges(&bands, &fit)[RED] {
                    return second;
                }
            }
            return first;
        }
        // The beam edge shown nowhere: out of view, if the faces leave room for it.
        let Some(scale) = stations::beam_out_of_view_scale(frame, t, &pose, fit.blur) else {
            return first;
        };
        let moved = crate::vision::hypothesis::rescaled(hyp, scale / k);
        let Some((pose, fit, bands)) = self.refine(frame, t, &moved, false) else {
            return first;
        };
        let second = self.verdict(frame, t, &moved, &pose, &fit, &bands);
        let calibrated = self.calibrated_steps();
        if second.detected
            && !fitted_edges(&bands, &fit)[RED]
            && stations::faces_run_to_border(frame, t, &pose, fit.blur, &calibrated)
        {
            second
        } else {
            first
        }
    }

    /// The grey-level fit of a hypothesis: a coarse pass on bands placed from the search,
    /// a final pass on bands placed from the coarse lines, and if an edge turns out far
    /// fainter than calibrated (something sitting on it) while two others hold, a last
    /// pass without it.
    fn refine(
        &mut self,
        frame: &GrayImage,
        t: &Template,
        hyp: &Hypothesis,
        with_beam_edge: bool,
    ) -> Option<(Pose, FitResult, PerEdge<Option<Band>>)> {
        let k = self.factor as f64;
        let pose = Pose {
            psi: hyp.pose.psi,
            scale: hyp.pose.scale * k,
            apex: crate::vision::pyramid::to_frame(self.factor, hyp.pose.apex),
        };
        let size = [frame.width() as f64, frame.height() as f64];
        // Fit the edges the search found: its lines, and a left-out edge only where the
        // edge map confirms it (a pair leaves the scale, hence that edge, uncertain).
        let mut keep: PerEdge<bool> = std::array::from_fn(|e| {
            hyp.members[e].is_some()
                || hyp.coverage[e].fraction() >= CONFIRMED_FRACTION
                || (with_beam_edge && e == RED)
        });
        let only = |b: PerEdge<Option<Band>>, keep: &PerEdge<bool>| -> PerEdge<Option<Band>> {
            std::array::from_fn(|e| b[e].filter(|_| keep[e]))
        };
        let prior = bend_prior(t, &pose, self.cantilever, 0.0);
        // Every frame starts from the same blur guess (wide enough for the blurriest
        // frames; the coarse pass measures it): nothing carries over from the frame
        // before, so the result does not depend on the order of frames.
        let blur0 = self.calibration.blur_px().max(START_BLUR_PX);
        let first = only(bands(t, &pose, size, blur0, prior), &keep);
        let fit = self
            .refiner
            .fit(frame, &first, Turns::Shared, blur0, None, true)?;
        let blur = fit.blur.clamp(0.5, 3.0);
        let pose = refined_pose(t, &pose, &fit);
        let prior = bend_prior(t, &pose, self.cantilever, fit.bend);
        let mut bands = only(bands(t, &pose, size, blur, prior), &keep);
        // The final fit starts from the coarse pass's noise, so its first iteration
        // already weights the residuals robustly (and the fit may stop an iteration
        // sooner).
        let mut fit =
            self.refiner
                .fit(frame, &bands, self.tied, fit.blur, Some(fit.noise()), false)?;
        let ratio = |fit: &FitResult, e: usize| {
            fit.edges[e].map_or(0.0, |r| {
                r.contrast / self.calibration.edge(Edge::ALL[e]).contrast
            })
        };
        let fitted = fitted_edges(&bands, &fit);
        let weak: PerEdge<bool> =
            std::array::from_fn(|e| fitted[e] && ratio(&fit, e) < DROP_CONTRAST_RATIO);
        let strong = (0..EDGES).filter(|&e| fitted[e] && !weak[e]).count();
        if weak.iter().any(|&w| w) && strong >= 2 {
            for e in 0..EDGES {
                keep[e] &= !weak[e];
            }
            bands = only(bands, &keep);
            fit = self
                .refiner
                .fit(frame, &bands, self.tied, fit.blur, Some(fit.noise()), false)?;
        }
        let pose = refined_pose(t, &pose, &fit);
        Some((pose, fit, bands))
    }

    /// Why a refined tip is not this probe's, if it is not: the apex outside the
    /// frame, the rotation outside the window (beyond its standard error), the scale
    /// (where the beam edge measures it) outside `tracker.scale_range`, or an edge
    /// in view that the frame does not show as calibrated ([`stations::check_edges`]).
    fn refusal(
        &self,
        frame: &GrayImage,
        t: &Template,
        pose: &Pose,
        fit: &FitResult,
        bands: &PerEdge<Option<Band>>,
    ) -> Option<Miss> {
        let [x, y] = pose.apex;
        let (w, h) = (frame.width() as f64, frame.height() as f64);
        if !(x >= 0.0 && y >= 0.0 && x <= w - 1.0 && y <= h - 1.0) {
            return Some(Miss::ApexOutside);
        }
        let beyond = pose.psi.abs() - self.window_rad;
        if beyond > WINDOW_SIGMAS * fit.turn_sigma + WINDOW_SLACK_RAD {
            return Some(Miss::RotationOutside);
        }
        let scale_measured = fitted_edges(bands, fit)[RED];
        if scale_measured && self.scale_range.is_some_and(|r| !r.contains(pose.scale)) {
            return Some(Miss::ScaleMismatch);
        }
        let calibrated = self.calibrated_steps();
        stations::check_edges(
            frame,
            t,
            pose,
            fit.blur,
            &calibrated,
            fitted_edges(bands, fit),
        )
    }

    #[allow(clippy::too_many_arguments)]
    fn verdict(
        &mut self,
        frame: &GrayImage,
        t: &Template,
        hyp: &Hypothesis,
        pose: &Pose,
        fit: &FitResult,
        bands: &PerEdge<Option<Band>>,
    ) -> Estimate {
        let size = [frame.width() as f64, frame.height() as f64];
        if let Some(miss) = self.refusal(frame, t, pose, fit, bands) {
            return Estimate::missed(miss, 0.0);
        }
        let in_view = bands.map(|b| b.is_some());
        let calibrated = self.calibrated_steps();
        let margin = half_width(fit.blur);
        let interior = verify::interior_median(frame, t, pose, margin).map_or(0.0, |m| {
            verify::interior_position(fit, m, self.calibration.pyramid_polarity())
        });
        let evidence = Evidence {
            coverage: coverage(hyp),
            contrast_ratio: verify::contrast_ratio(fit, &in_view, &calibrated),
            interior,
            turn_sigma_deg: fit.turn_sigma.to_degrees(),
        };
        let confidence = evidence.confidence();
        if confidence < MIN_CONFIDENCE {
            return Estimate::missed(Miss::LowConfidence, confidence);
        }
        let mut edges = [None; MAX_EDGES];
        for e in Edge::ALL.map(Edge::index) {
            let (Some(r), true) = (fit.edges[e], in_view[e]) else {
                continue;
            };
            let (a, b) = visible_segment(t, pose, e, size).unwrap_or((pose.apex, pose.apex));
            edges[e] = Some(EdgeFit {
                start_px: r.line.foot(a),
                end_px: r.line.foot(b),
                support: hyp.coverage[e].supported as u32,
                contrast: r.contrast,
            });
        }
        let apex = t.true_apex(pose, self.edge_bias_px);
        if claimed(&self.excluded, apex) {
            // Not a verdict on this probe: the runners-up are tried.
            return Estimate::missed(Miss::OtherProbe, 0.0);
        }
        Estimate {
            detected: true,
            angle_deg: Some(screen_deg_from_image_rad(pose.psi)),
            force_nn: None,
            force_saturated: false,
            apex_px: Some(apex),
            edges,
            angle_sigma_deg: Some(crate::vision::sigma::angle_sigma_deg(fit.turn_error_sigma)),
            // Measured only by the beam edge's distance from the apex; the faces alone
            // leave it free over a range.
            scale: fitted_edges(bands, fit)[RED].then_some(pose.scale),
            confidence,
            miss: None,
        }
        .with_force(self.cantilever)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn estimate(confidence: f64, edges: usize) -> Estimate {
        let fit = EdgeFit {
            start_px: [0.0, 0.0],
            end_px: [10.0, 0.0],
            support: 10,
            contrast: 100.0,
        };
        Estimate {
            detected: confidence >= MIN_CONFIDENCE,
            confidence,
            edges: std::array::from_fn(|e| (e < edges).then_some(fit)),
            ..Estimate::missed(Miss::LowConfidence, confidence)
        }
    }

    #[test]
    fn a_runner_up_must_be_clearly_more_confident_and_explain_as_much() {
        let first = estimate(0.54, 2);
        // The wrong lock of docs/tracker.md: 0.54 against 0.84, both with two faces.
        assert!(outranks(&estimate(0.84, 2), &first, first.confidence));
        // A few hundredths are noise between refinements of one frame.
        assert!(!outranks(&estimate(0.6, 3), &first, first.confidence));
        // Leaving a face out raises the confidence without explaining more.
        assert!(!outranks(&estimate(0.9, 1), &first, first.confidence));
        // Against an earlier runner-up, the margin is still over the search's choice.
        let second = estimate(0.7, 2);
        assert!(outranks(&estimate(0.72, 2), &second, first.confidence));
        assert!(!outranks(&estimate(0.69, 2), &second, first.confidence));
        // A miss is replaced by a detection that explains anything.
        let miss = Estimate::missed(Miss::LowConfidence, 0.0);
        assert!(outranks(&estimate(0.6, 2), &miss, 0.0));
    }

    #[test]
    fn placements_close_in_apex_and_rotation_are_one_tip() {
        let a = Pose {
            psi: 0.1,
            scale: 1.0,
            apex: [50.0, 40.0],
        };
        let near = Pose {
            psi: 0.1 + 0.4f64.to_radians(),
            apex: [51.5, 40.5],
            ..a
        };
        assert!(same_place(&a, &near));
        assert!(!same_place(
            &a,
            &Pose {
                apex: [50.0, 43.0],
                ..a
            }
        ));
        assert!(!same_place(
            &a,
            &Pose {
                psi: 0.1 + 0.6f64.to_radians(),
                ..a
            }
        ));
    }
}
