//! Several probes in one view: one calibrated [`Tracker`] per probe, every probe tracked
//! in every frame. Probes are told apart by their calibration: a tracker finds only a
//! body of its own template, turned within its window (a probe entering from the other
//! side is another probe's mirror image, which no tracker takes for its own). When two
//! trackers still place their tips on one body, the more confident keeps it and the
//! other searches again without it; a tip still claimed twice is refused as
//! [`Miss::OtherProbe`] for the less confident, so no operator feels a force that
//! belongs to another probe. And one frame has one magnification: probes calibrated on
//! one reference image must be seen at one scale, and a detection at a scale unlike the
//! others' (another probe's body taken for this one's) is refused as
//! [`Miss::ScaleUnlikeOthers`].

use image::GrayImage;

pub use super::claim::{Claim, MAX_PROBES};
use super::second_thread::SecondThread;
use super::tracker::Detection;
use super::{Estimate, Miss, Tracker};

/// The name a probe goes by when it is the only one (a lab file's top-level
/// `[cantilever]` and `[tracker]`, a rendered session of one probe).
pub const SINGLE_NAME: &str = "probe";

/// The name of the thread a [`ProbeSet`] on two threads tracks half its probes on.
pub const SECOND_TRACKING_THREAD: &str = "tracker-2";

/// How far one probe's scale may stray from the others' (calibrated on the same
/// reference) as a ratio: one frame has one magnification, so every probe calibrated
/// on one reference image is seen at one scale. A tracker that took another probe's
/// body reads it at that body's size over its own (pyramids of 9-16 um: ratios of
/// 0.56-1.8); true detections of several probes in one frame agree within 0.1 %
/// (median) and 22 % (the worst, a probe with a face out of view) on the rendered
/// several-probe sessions.
const SCALE_RATIO: f64 = 1.3;

/// The trackers of the probes in one view, in configuration order.
#[derive(Debug)]
pub struct ProbeSet {
    trackers: Vec<Tracker>,
    /// Per probe, the first probe calibrated on the same reference image: probes of
    /// one group are seen at one scale.
    groups: Vec<usize>,
    /// The frame's detection image and edges, built for the first probe's tracker and
    /// reused by the others with the same binning and threshold.
    shared: Detection,
    /// Where half the probes are tracked, if the set runs on two threads.
    second: Option<SecondThread>,
}

impl ProbeSet {
    /// The set of `trackers`, 1 to [`MAX_PROBES`]; `references[i]` names probe i's
    /// reference image (probes calibrated on one image are seen at one scale).
    pub fn new<R: PartialEq>(trackers: Vec<Tracker>, references: &[R]) -> ProbeSet {
        assert!(
            (1..=MAX_PROBES).contains(&trackers.len()),
            "a probe set holds 1 to {MAX_PROBES} probes"
        );
        assert_eq!(references.len(), trackers.len(), "one reference per probe");
        let groups = references
            .iter()
            .map(|r| references.iter().position(|q| q == r).unwrap_or(0))
            .collect();
        ProbeSet {
            trackers,
            groups,
            shared: Detection::default(),
            second: None,
        }
    }

    /// The set tracking half its probes on a second thread (with two or more probes):
    /// a frame then takes its shared stages and the slower half's tracking, with the
    /// same estimates as on one thread.
    pub fn on_two_threads(mut self) -> std::io::Result<ProbeSet> {
        if self.trackers.len() > 1 && self.second.is_none() {
            self.second = Some(SecondThread::spawn(SECOND_TRACKING_THREAD)?);
        }
        Ok(self)
    }

    pub fn len(&self) -> usize {
        self.trackers.len()
    }

    pub fn is_empty(&self) -> bool {
        self.trackers.is_empty()
    }

    pub fn trackers(&self) -> &[Tracker] {
        &self.trackers
    }

    /// Turns coherence on or off for every probe.
    pub fn set_coherence(&mut self, on: bool) {
        self.trackers.iter_mut().for_each(|t| t.set_coherence(on));
    }

    /// Forgets every probe's last estimate.
    pub fn reset(&mut self) {
        self.trackers.iter_mut().for_each(Tracker::reset);
    }

    /// Tracks every probe in `frame`, writing probe i's estimate to `out[i]` (`out`
    /// holds one per probe); allocation-free once the trackers are warm.
    ///
    /// Each tracker searches the whole frame. When two place their tips on one body
    /// (an apex on the other's pyramid), the more confident keeps it and the other
    /// searches the frame again with that pyramid ruled out: a probe whose tracker
    /// took its neighbour (another pyramid of similar angles) is still found where it
    /// is. A probe refused while another is found searches again with the found
    /// bodies ruled out. What still overlaps after that is refused
    /// ([`refuse_shared_tips`]).
    pub fn track(&mut self, frame: &GrayImage, out: &mut [Estimate]) {
        assert_eq!(out.len(), self.trackers.len(), "one estimate per probe");
        self.shared.clear();
        if let Some(first) = self.trackers.iter().find(|t| t.calibration().is_some()) {
            first.build_shared(frame, &mut self.shared);
        }
        let shared = &self.shared;
        let track = |trackers: &mut [Tracker], out: &mut [Estimate]| {
            for (tracker, estimate) in trackers.iter_mut().zip(out.iter_mut()) {
                *estimate = tracker.track_sharing(frame, shared);
            }
        };
        match &self.second {
            Some(second) => {
                // The first half here, with the first probe (the one in front); the
                // rest on the second thread.
                let half = self.trackers.len().div_ceil(2);
                let (mine, theirs) = self.trackers.split_at_mut(half);
                let (my_out, their_out) = out.split_at_mut(half);
                second.join(|| track(theirs, their_out), || track(mine, my_out));
            }
            None => track(&mut self.trackers, out),
        }
        // Each round settles one conflict; a probe searched again is searched with
        // every claim against it so far ruled out.
        for _ in 0..MAX_PROBES * MAX_PROBES {
            let Some((winner, loser)) = conflict(out) else {
                break;
            };
            let Some(claim) = Claim::of(&out[winner]) else {
                break;
            };
            let tracker = &mut self.trackers[loser];
            if !tracker.exclude_more(claim) {
                break;
            }
            out[loser] = tracker.retrack_sharing(frame, &self.shared);
        }
        // A probe refused while another is found searches again with the found bodies
        // ruled out: a stronger body of another probe (a cantilever's beam beside a
        // faint lever) can take every placement its search shortlists.
        for i in 0..out.len() {
            for j in 0..out.len() {
                if out[i].detected {
                    break;
                }
                let Some(claim) = Claim::of(&out[j]).filter(|_| j != i) else {
                    continue;
                };
                if self.trackers[i].exclude_more(claim) {
                    out[i] = self.trackers[i].retrack_sharing(frame, &self.shared);
                }
            }
        }
        refuse_shared_tips(out);
        refuse_scale_outliers(out, &self.groups);
    }
}

/// Refuses, as [`Miss::ScaleUnlikeOthers`], each detection whose scale strays from the
/// median of the other detections of its group by more than `SCALE_RATIO` (with two
/// in a group that disagree, both: the frame cannot say which is wrong).
pub fn refuse_scale_outliers(estimates: &mut [Estimate], groups: &[usize]) {
    let mut refused = [false; MAX_PROBES];
    for (i, e) in estimates.iter().enumerate() {
        let Some(own) = e.scale.filter(|_| e.detected) else {
            continue;
        };
        let mut others = [0.0; MAX_PROBES];
        let mut n = 0;
        for (j, o) in estimates.iter().enumerate() {
            if let Some(s) = o
                .scale
                .filter(|_| o.detected && j != i && groups[j] == groups[i])
            {
                others[n] = s;
                n += 1;
            }
        }
        if n == 0 {
            continue;
        }
        let others = &mut others[..n];
        others.sort_by(f64::total_cmp);
        let median = if n % 2 == 1 {
            others[n / 2]
        } else {
            0.5 * (others[n / 2 - 1] + others[n / 2])
        };
        let ratio = (own / median).max(median / own);
        // A NaN scale agrees with nothing.
        refused[i] = ratio.is_nan() || ratio > SCALE_RATIO;
    }
    for (e, refused) in estimates.iter_mut().zip(refused) {
        if refused {
            *e = Estimate::missed(Miss::ScaleUnlikeOthers, e.confidence);
        }
    }
}

/// The first pair of detections on one body: (the more confident, the other; the
/// earlier probe on a tie).
fn conflict(estimates: &[Estimate]) -> Option<(usize, usize)> {
    for i in 0..estimates.len() {
        for j in i + 1..estimates.len() {
            let (Some(a), Some(b)) = (Claim::of(&estimates[i]), Claim::of(&estimates[j])) else {
                continue;
            };
            if a.overlaps(&b) {
                return Some(if estimates[j].confidence > estimates[i].confidence {
                    (j, i)
                } else {
                    (i, j)
                });
            }
        }
    }
    None
}

/// Refuses, of two detections placed on one body, the less confident (the later one
/// on a tie), as [`Miss::OtherProbe`].
pub fn refuse_shared_tips(estimates: &mut [Estimate]) {
    while let Some((_, loser)) = conflict(estimates) {
        let confidence = estimates[loser].confidence;
        estimates[loser] = Estimate::missed(Miss::OtherProbe, confidence);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::vision::EdgeFit;

    fn at(apex: [f64; 2], confidence: f64) -> Estimate {
        Estimate {
            detected: true,
            angle_deg: Some(0.5),
            apex_px: Some(apex),
            confidence,
            ..Estimate::default()
        }
    }

    #[test]
    fn two_probes_on_one_tip_leave_it_to_the_more_confident() {
        let mut set = [at([100.0, 100.0], 0.7), at([103.0, 104.0], 0.9)];
        // Without faces a tip claims a disc around its apex.
        refuse_shared_tips(&mut set);
        assert_eq!(set[0].miss, Some(Miss::OtherProbe));
        assert!(!set[0].detected && set[0].angle_deg.is_none());
        assert!(set[1].detected);
        // A tie refuses the later probe.
        let mut set = [at([100.0, 100.0], 0.8), at([100.0, 100.0], 0.8)];
        refuse_shared_tips(&mut set);
        assert!(set[0].detected && !set[1].detected);
    }

    fn with_faces(apex: [f64; 2], confidence: f64, scale: f64) -> Estimate {
        // A pyramid 100 px tall hanging from a beam face 100 px long.
        let fit = |a: [f64; 2], b: [f64; 2]| EdgeFit {
            start_px: a,
            end_px: b,
            support: 50,
            contrast: 100.0,
        };
        let [x, y] = apex;
        Estimate {
            edges: std::array::from_fn(|k| match k {
                0 => Some(fit([x - 80.0, y - 100.0], [x + 20.0, y - 100.0])),
                1 => Some(fit([x - 40.0, y - 100.0], apex)),
                2 => Some(fit(apex, [x + 10.0, y - 100.0])),
                _ => None,
            }),
            scale: Some(scale),
            ..at(apex, confidence)
        }
    }

    #[test]
    fn a_claim_is_the_body_its_edges_span() {
        let claim = Claim::of(&with_faces([100.0, 200.0], 0.9, 1.0)).expect("detected");
        // On the pyramid, on the beam above it, and just beyond its faces (the margin
        // is 5 % of its 128 px size).
        for p in [[100.0, 150.0], [60.0, 110.0], [100.0, 206.0], [60.0, 145.0]] {
            assert!(claim.contains(p), "{p:?}");
        }
        // Beside it: a tip 20 px away across the gap.
        for p in [[100.0, 220.0], [130.0, 180.0], [40.0, 200.0]] {
            assert!(!claim.contains(p), "{p:?}");
        }
        assert!(Claim::of(&Estimate::missed(Miss::LowConfidence, 0.5)).is_none());
    }

    #[test]
    fn one_frame_shows_probes_of_one_reference_at_one_scale() {
        let three = |s: f64| {
            [
                with_faces([100.0, 200.0], 0.9, 1.0),
                with_faces([400.0, 200.0], 0.9, 1.02),
                with_faces([100.0, 500.0], 0.9, s),
            ]
        };
        // Within the tolerance: kept.
        let mut set = three(1.25);
        refuse_scale_outliers(&mut set, &[0, 0, 0]);
        assert!(set.iter().all(|e| e.detected));
        // Another body read at its size over this probe's: refused, the others kept.
        let mut set = three(0.6);
        refuse_scale_outliers(&mut set, &[0, 0, 0]);
        assert_eq!(set[2].miss, Some(Miss::ScaleUnlikeOthers));
        assert!(set[0].detected && set[1].detected);
        // Calibrated on another reference: another scale is no contradiction.
        let mut set = three(0.6);
        refuse_scale_outliers(&mut set, &[0, 0, 2]);
        assert!(set.iter().all(|e| e.detected));
        // Two that disagree: the frame cannot say which, so neither is kept.
        let mut pair = [
            with_faces([100.0, 200.0], 0.9, 1.0),
            with_faces([400.0, 200.0], 0.95, 1.6),
        ];
        refuse_scale_outliers(&mut pair, &[0, 0]);
        assert!(pair.iter().all(|e| e.miss == Some(Miss::ScaleUnlikeOthers)));
    }

    #[test]
    fn tips_apart_or_missed_are_left_alone() {
        let mut set = [
            at([100.0, 100.0], 0.7),
            at([109.0, 100.0], 0.9),
            Estimate::missed(Miss::NoCandidates, 0.0),
        ];
        let before = set;
        refuse_shared_tips(&mut set);
        assert_eq!(set, before);
    }
}
