//! The cantilever physics: the exact large-deflection elastica of a cantilever under a
//! tip load of fixed direction (the paper's Eqs. 1-10, corrected in docs/model.md), the
//! precomputed lookup table the tracker uses, and the beam's stiffness.
//!
//! - [`exact`], [`centreline`], [`slope_rad`]: the closed form in Carlson's elliptic
//!   integrals, accurate to ~1e-15 relative (docs/model.md).
//! - [`phi0_from_alpha`], [`phi0_from_deflection`]: exact inverses by root-finding.
//! - [`ModelTable`]: the start-up table, angle <-> load in tens of nanoseconds;
//!   [`ModelTable::global`] is the one the tracker, CLI and daemon share.
//! - [`Cantilever`]: length and rigidity; force in nN from a tip angle and back.
mod cantilever;
mod carlson;
mod chebyshev;
mod elastica;
mod inverse;
mod jacobi;
mod table;

#[cfg(test)]
mod accuracy;
#[cfg(test)]
mod reference;

pub use cantilever::Cantilever;
pub use elastica::{
    centreline, exact, slope_rad, Centreline, Elastica, ModelError, MAX_PHI0_DEG, MAX_PHI0_RAD,
};
pub use inverse::{max_alpha, max_delta_over_l, phi0_from_alpha, phi0_from_deflection};
pub use table::{Lookup, ModelTable};
