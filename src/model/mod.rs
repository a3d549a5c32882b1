//! The cantilever physics: the exact large-deflection elastica of a cantilever under a
//! tip load of fixed direction (the paper's Eqs. 1-10, corrected as in scene.md), the
//! precomputed lookup table the tracker uses, and the beam's stiffness.
mod cantilever;

pub use cantilever::Cantilever;
