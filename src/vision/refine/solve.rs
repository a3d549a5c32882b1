//! The small dense algebra of the fit: the normal equations of one iteration, their
//! scaled, damped Cholesky solve with held parameters, and the trust-limited step.

use super::{N_PARAMS, P_BEND, P_BLUR, P_OFFSET, P_TURN};
use crate::vision::template::{PerEdge, EDGES};

/// Accumulated normal equations `h * step = g` of one iteration.
#[derive(Debug, Clone, Copy)]
pub(super) struct Normal {
    pub h: [[f64; N_PARAMS]; N_PARAMS],
    pub g: [f64; N_PARAMS],
    pub fixed: [bool; N_PARAMS],
    pub noise: PerEdge<f64>,
}

impl Default for Normal {
    fn default() -> Self {
        Normal {
            h: [[0.0; N_PARAMS]; N_PARAMS],
            g: [0.0; N_PARAMS],
            fixed: [false; N_PARAMS],
            noise: [f64::INFINITY; EDGES],
        }
    }
}

/// Solves the damped normal equations with the fixed parameters held. The system is
/// scaled to a unit diagonal first, so "no information about a parameter" (a bend with
/// no bent pixels, a band of one flat level) is recognised relative to the others and
/// that parameter is held instead of failing the solve.
// Index loops mirror the textbook formulas of the small dense solves below.
#[allow(clippy::needless_range_loop)]
pub(super) fn solve(
    h: &[[f64; N_PARAMS]; N_PARAMS],
    g: &[f64; N_PARAMS],
    fixed: &[bool; N_PARAMS],
) -> Option<[f64; N_PARAMS]> {
    let max_diag = (0..N_PARAMS).map(|i| h[i][i]).fold(0.0, f64::max);
    if max_diag.partial_cmp(&0.0) != Some(std::cmp::Ordering::Greater) || !max_diag.is_finite() {
        return None;
    }
    let mut scale = [0.0; N_PARAMS];
    for i in 0..N_PARAMS {
        let held = fixed[i]
            || h[i][i].partial_cmp(&(1e-14 * max_diag)) != Some(std::cmp::Ordering::Greater);
        scale[i] = if held { 0.0 } else { 1.0 / h[i][i].sqrt() };
    }
    let mut a = [[0.0; N_PARAMS]; N_PARAMS];
    let mut b = [0.0; N_PARAMS];
    for i in 0..N_PARAMS {
        for k in 0..N_PARAMS {
            a[i][k] = h[i][k] * scale[i] * scale[k];
        }
        a[i][i] = if scale[i] == 0.0 { 1.0 } else { 1.0 + 1e-9 };
        b[i] = g[i] * scale[i];
    }
    cholesky_solve(&mut a, &mut b);
    for i in 0..N_PARAMS {
        b[i] *= scale[i];
        if !b[i].is_finite() {
            return None;
        }
    }
    Some(b)
}

/// Variance factor of parameter `k` ((H^-1)_kk), free parameters only.
pub(super) fn variance(
    h: &[[f64; N_PARAMS]; N_PARAMS],
    fixed: &[bool; N_PARAMS],
    k: usize,
) -> Option<f64> {
    let mut e = [0.0; N_PARAMS];
    e[k] = 1.0;
    combination_variance(h, fixed, &e)
}

/// Variance factor of the combination `w . x` of the parameters (w^T H^-1 w), free
/// parameters only.
pub(super) fn combination_variance(
    h: &[[f64; N_PARAMS]; N_PARAMS],
    fixed: &[bool; N_PARAMS],
    w: &[f64; N_PARAMS],
) -> Option<f64> {
    let x = solve(h, w, fixed)?;
    Some(w.iter().zip(&x).map(|(a, b)| a * b).sum::<f64>().max(0.0))
}

/// In-place Cholesky solve of a symmetric positive semi-definite system; a parameter
/// whose pivot vanishes (dependent on the others) is held at a zero step.
#[allow(clippy::needless_range_loop)]
fn cholesky_solve(a: &mut [[f64; N_PARAMS]; N_PARAMS], b: &mut [f64; N_PARAMS]) {
    for j in 0..N_PARAMS {
        let mut d = a[j][j];
        for k in 0..j {
            d -= a[j][k] * a[j][k];
        }
        if d <= 1e-10 {
            // No independent information left in this parameter: hold it.
            for i in j + 1..N_PARAMS {
                a[i][j] = 0.0;
            }
            a[j][j] = f64::INFINITY;
            continue;
        }
        let d = d.sqrt();
        a[j][j] = d;
        for i in j + 1..N_PARAMS {
            let mut s = a[i][j];
            for k in 0..j {
                s -= a[i][k] * a[j][k];
            }
            a[i][j] = s / d;
        }
    }
    for i in 0..N_PARAMS {
        let mut s = b[i];
        for k in 0..i {
            s -= a[i][k] * b[k];
        }
        b[i] = s / a[i][i];
    }
    for i in (0..N_PARAMS).rev() {
        let mut s = b[i];
        for k in i + 1..N_PARAMS {
            s -= a[k][i] * b[k];
        }
        b[i] = s / a[i][i];
    }
}

/// Applies a Gauss-Newton step with trust limits on the geometric parameters.
pub(super) fn apply(x: &mut [f64; N_PARAMS], step: &[f64; N_PARAMS]) {
    for (k, (xk, &dk)) in x.iter_mut().zip(step).enumerate() {
        let limited = match k {
            P_TURN..=2 => dk.clamp(-0.02, 0.02),
            P_OFFSET..=5 => dk.clamp(-1.5, 1.5),
            P_BEND => dk.clamp(-2.0, 2.0),
            P_BLUR => dk.clamp(-0.3, 0.3),
            _ => dk,
        };
        *xk += limited;
    }
    x[P_BLUR] = x[P_BLUR].clamp(0.3, 4.0);
}
