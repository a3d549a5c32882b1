//! What a converged fit reports ([`FitResult`]): each edge's line, contrast and blur,
//! and the standard errors of the rotations, from this frame's noise (the normal
//! equations), from the spread of an edge's stretches in calibration mode (cluster
//! robust), and from the calibration's own precision when the edges are tied.

use super::kernel::StretchShare;
use super::solve::{combination_variance, solve, variance, Normal};
use super::{
    EdgeFrame, EdgeResult, FitResult, Refiner, Turns, CHUNKS_PER_EDGE, MIN_TIE_SIGMA_RAD, N_PARAMS,
    P_BEND, P_BLUR, P_OFFSET, P_TURN,
};
use crate::vision::geometry::{dot, rotate, Line};
use crate::vision::template::{PerEdge, EDGES};

impl Refiner {
    /// The fit's result at the parameters `x` of the last normal equations `ne`, the
    /// tip's rotation made from the edges' with `weights`.
    pub(super) fn result(
        &self,
        frames: &PerEdge<Option<EdgeFrame>>,
        x: &[f64; N_PARAMS],
        ne: &Normal,
        turns: Turns,
        weights: &[f64; N_PARAMS],
    ) -> FitResult {
        let shared = turns == Turns::Shared;
        // The tip's rotation's uncertainty from this frame's noise (one solve).
        let tip_sigma = turn_sigma(ne, weights);
        let robust = if turns == Turns::Free {
            self.clustered_turn_sigma(frames, x, ne)
        } else {
            [0.0; EDGES]
        };
        let mut edges = [None; EDGES];
        for (e, f) in frames.iter().enumerate() {
            let Some(f) = f else { continue };
            let turn = if shared { x[P_TURN] } else { x[P_TURN + e] };
            let turn_sigma = if shared {
                tip_sigma
            } else {
                ne.noise[e]
                    * variance(&ne.h, &ne.fixed, P_TURN + e)
                        .unwrap_or(f64::INFINITY)
                        .sqrt()
            };
            let normal = rotate(f.normal0, turn);
            let line = Line {
                normal,
                rho: dot(normal, f.origin) + x[P_OFFSET + e],
            };
            let (contrast, level) = self.step_height(e, f, x, normal);
            edges[e] = Some(EdgeResult {
                line,
                contrast,
                level,
                noise: ne.noise[e],
                samples: self.ranges[e].len(),
                turn,
                turn_sigma,
                turn_sigma_robust: turn_sigma.max(robust[e]),
            });
        }
        let turn = (0..EDGES).map(|e| weights[e] * x[P_TURN + e]).sum();
        // The calibration's share: the edges' calibration errors, averaged with the
        // weights that make the tip's rotation.
        let (turn_sigma, turn_error_sigma) = match turns {
            Turns::Tied(t) => (
                tip_sigma.hypot(tie_precision(frames, &t.weigh).recip().sqrt()),
                tip_sigma.hypot(tie_error(frames, weights, &t.error)),
            ),
            _ => (tip_sigma, tip_sigma),
        };
        FitResult {
            edges,
            turn,
            turn_sigma,
            turn_error_sigma,
            blur: x[P_BLUR],
            bend: x[P_BEND],
        }
    }

    /// Each edge's rotation's cluster-robust standard error (radians; free rotations;
    /// see [`EdgeResult::turn_sigma_robust`]) at the parameters `x` of the last normal
    /// equations `ne`. Each stretch's influence on a rotation is its score through the
    /// inverse of the M-estimator's normal matrix without that stretch (the
    /// jackknife's leverage correction: a stretch near an end of a band pulls the
    /// rotation the fit also adjusts to it). A stretch's own outside level has no
    /// score at the solution (its own equation is solved), so only the shared
    /// parameters' scores count.
    fn clustered_turn_sigma(
        &self,
        frames: &PerEdge<Option<EdgeFrame>>,
        x: &[f64; N_PARAMS],
        ne: &Normal,
    ) -> PerEdge<f64> {
        let shares = self.stretch_shares(frames, x, &ne.noise);
        let add = |h: &mut [[f64; N_PARAMS]; N_PARAMS],
                   s: &StretchShare,
                   block: &[[f64; 8]; 8],
                   sign: f64| {
            let slots = self.slots[s.stretch / CHUNKS_PER_EDGE];
            for (i, row) in block.iter().enumerate() {
                for (j, v) in row.iter().enumerate() {
                    h[slots[i]][slots[j]] += sign * v;
                }
            }
        };
        // The M-estimator's normal matrix: each stretch's share with the derivative of
        // its weighted residuals in place of the fit's robust weights (which, counting
        // a clipped residual's pixel at part weight, overstate what it tells).
        let mut bread = ne.h;
        for s in &shares {
            add(&mut bread, s, &s.psi, 1.0);
            add(&mut bread, s, &s.fitted, -1.0);
        }
        let mut var = [0.0f64; EDGES];
        for s in &shares {
            let mut without = bread;
            add(&mut without, s, &s.psi, -1.0);
            let slots = self.slots[s.stretch / CHUNKS_PER_EDGE];
            for e in (0..EDGES).filter(|&e| frames[e].is_some()) {
                let mut unit = [0.0; N_PARAMS];
                unit[P_TURN + e] = 1.0;
                var[e] += match solve(&without, &unit, &ne.fixed) {
                    Some(a) => slots
                        .iter()
                        .zip(&s.score)
                        .map(|(&k, g)| a[k] * g)
                        .sum::<f64>()
                        .powi(2),
                    None => f64::INFINITY,
                };
            }
        }
        var.map(f64::sqrt)
    }
}

/// The largest noise of the edges in view: the unit of the pixel sums' normal
/// equations for the parameters all edges share.
pub(super) fn common_noise(ne: &Normal) -> f64 {
    ne.noise
        .iter()
        .copied()
        .filter(|n| n.is_finite())
        .fold(0.0, f64::max)
}

/// 1-sigma uncertainty, from the normal equations `ne`, of the tip's rotation: the
/// rotation parameters combined with `weights` (infinite when they do not determine
/// it).
pub(super) fn turn_sigma(ne: &Normal, weights: &[f64; N_PARAMS]) -> f64 {
    let var = combination_variance(&ne.h, &ne.fixed, weights).unwrap_or(f64::INFINITY);
    common_noise(ne) * var.sqrt()
}

/// Edge `e`'s calibration standard error as the tie takes it (radians).
pub(super) fn tie_sigma(sigma: &PerEdge<f64>, e: usize) -> f64 {
    if sigma[e].is_finite() {
        sigma[e].max(MIN_TIE_SIGMA_RAD)
    } else {
        MIN_TIE_SIGMA_RAD
    }
}

/// The calibration's precision of the tip's rotation with tied edges: the sum of the
/// edges in view's calibration precisions (radians^-2).
pub(super) fn tie_precision(frames: &PerEdge<Option<EdgeFrame>>, sigma: &PerEdge<f64>) -> f64 {
    (0..EDGES)
        .filter(|&e| frames[e].is_some())
        .map(|e| tie_sigma(sigma, e).powi(-2))
        .sum()
}

/// The calibration's share of the tip's rotation's standard error with tied edges
/// (radians): the edges' calibration errors `error` combined with the `weights` that
/// make the tip's rotation ([`tip_weights`](super::tip_weights)), `sqrt(sum w_e^2 error_e^2)` (with the
/// errors the weights come from, `1 / sqrt(tie_precision)`).
pub(super) fn tie_error(
    frames: &PerEdge<Option<EdgeFrame>>,
    weights: &[f64; N_PARAMS],
    error: &PerEdge<f64>,
) -> f64 {
    (0..EDGES)
        .filter(|&e| frames[e].is_some())
        .map(|e| (weights[P_TURN + e] * tie_sigma(error, e)).powi(2))
        .sum::<f64>()
        .sqrt()
}
