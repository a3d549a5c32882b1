//! What a detection claims of its frame when several probes are in view: its body, so
//! that no other probe's tracker places a tip on it ([`super::ProbeSet`]).

use super::geometry::{norm, sub};
use super::Estimate;

/// Most probes in one view: an S100 carries up to four positioners.
pub const MAX_PROBES: usize = 4;

/// A tip found by fewer than two edges claims this disc around its apex, frame pixels:
/// a tip any tracker can place is tens of pixels tall.
const CLAIM_RADIUS_PX: f64 = 8.0;
/// How far outside a claimed body another tracker's apex is still on it: this share
/// of the body's size (apex to its farthest found point), at least
/// [`CLAIM_MARGIN_PX`]. A placement on another probe's body can stray from it by the
/// coarse search's few detection pixels, or sit on its beam's end block (beyond the
/// edges' ends); two tips side by side (squeezing an object) stay apart by more.
const CLAIM_MARGIN_SHARE: f64 = 0.05;
const CLAIM_MARGIN_PX: f64 = 3.0;

/// The body a detection claims in its frame: the convex hull of its apex and the ends
/// of its found edges (the pyramid and the beam's end above it), or a disc around
/// the apex when fewer than two edges were found.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Claim {
    apex: [f64; 2],
    /// The apex and the found edges' ends; `corners` of them in use.
    points: [[f64; 2]; 7],
    corners: usize,
    /// How far beyond the hull a point is still on the body, pixels.
    margin: f64,
}

impl Claim {
    /// The body `estimate` claims, if it is a detection.
    pub fn of(estimate: &Estimate) -> Option<Claim> {
        let apex = estimate.apex_px.filter(|_| estimate.detected)?;
        let mut points = [apex; 7];
        let mut corners = 1;
        for fit in estimate.edges.iter().flatten() {
            points[corners] = fit.start_px;
            points[corners + 1] = fit.end_px;
            corners += 2;
        }
        let size = points[..corners]
            .iter()
            .map(|&p| norm(sub(p, apex)))
            .fold(0.0, f64::max);
        Some(Claim {
            apex,
            points,
            corners,
            margin: (CLAIM_MARGIN_SHARE * size).max(CLAIM_MARGIN_PX),
        })
    }

    /// Whether point `p` lies on this body (within its margin of its hull, or
    /// `CLAIM_RADIUS_PX` of its apex).
    pub fn contains(&self, p: [f64; 2]) -> bool {
        if norm(sub(p, self.apex)) <= CLAIM_RADIUS_PX {
            return true;
        }
        // p is inside the hull when no line through two of its points has every point
        // on one side and p beyond it by more than the margin.
        let pts = &self.points[..self.corners];
        if pts.len() < 3 {
            return false;
        }
        for (i, &a) in pts.iter().enumerate() {
            for &b in &pts[i + 1..] {
                let d = sub(b, a);
                let len = norm(d);
                if len < 1e-9 {
                    continue;
                }
                let side = |q: [f64; 2]| cross(d, sub(q, a)) / len;
                let (lo, hi) = pts
                    .iter()
                    .map(|&q| side(q))
                    .fold((0.0f64, 0.0f64), |(lo, hi), s| (lo.min(s), hi.max(s)));
                let sp = side(p);
                // A hull edge: every point on one side of it.
                if lo >= -1e-9 && sp < -self.margin {
                    return false;
                }
                if hi <= 1e-9 && sp > self.margin {
                    return false;
                }
            }
        }
        true
    }

    /// Whether two claims are one body: either apex on the other's body.
    pub fn overlaps(&self, other: &Claim) -> bool {
        self.contains(other.apex) || other.contains(self.apex)
    }
}

/// No body claimed: what a tracker rules out when it tracks on its own.
pub const NO_CLAIMS: [Option<Claim>; MAX_PROBES - 1] = [None; MAX_PROBES - 1];

/// Adds `claim` to the bodies `claims` rules out; false when it already was, or no
/// room is left.
pub fn rule_out(claims: &mut [Option<Claim>], claim: Claim) -> bool {
    if claims.contains(&Some(claim)) {
        return false;
    }
    match claims.iter_mut().find(|c| c.is_none()) {
        Some(slot) => {
            *slot = Some(claim);
            true
        }
        None => false,
    }
}

/// Whether point `p` lies on any of the bodies `claims`.
pub fn claimed(claims: &[Option<Claim>], p: [f64; 2]) -> bool {
    claims.iter().flatten().any(|c| c.contains(p))
}

fn cross(a: [f64; 2], b: [f64; 2]) -> f64 {
    a[0] * b[1] - a[1] * b[0]
}
