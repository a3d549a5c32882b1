//! Synthetic SEM frames with ground truth: the SEM scene of docs/renderer.md rendered
//! from a seed, for the tracker's accuracy tests, the simulated lab, benches and the
//! demo.
//!
//! A [`FrameSpec`] fixes everything about a frame: size, magnification, the probe
//! ([`ProbeGeometry`]: an elastica-bent beam with a rigid pyramid), its pose (entry side,
//! base orientation, tip angle, apex pixel), the look ([`Look`] knobs or a [`Style`]
//! preset: noise, blur, scan-line jitter, shading, particles, scratches, substrate) and a
//! seed. [`render_into`] draws it into a reused 8-bit frame and returns the [`Truth`]
//! (angle, force, apex, the true red/blue/green edges); the same spec gives the same
//! bytes on every run.
//!
//! [`Session`] writes the session layout of docs/conventions.md (probe.toml with
//! calibration clicks, reference.png, frames/, truth.csv) for random-order mixed sets and
//! time sequences; [`suite`] generates the tracker's accuracy suite spanning every
//! condition.
//!
//! A spec's own probe may instead be a rigid tool without a cantilever (a needle, the
//! end of a tipless cantilever, a gripper jaw: [`ToolGeometry`], named straight edges,
//! truth from [`tool_truth`]); [`tool_suite()`] generates seeded sessions of them.
//!
//! Shapes are drawn with exact area coverage (anti-aliased at sub-pixel level) and then
//! blurred, so the truth is exact to the rasteriser's float precision. The physics of
//! the bent beam is [`crate::model`]'s exact elastica; nothing here duplicates it.
pub mod adversarial;
mod background;
mod blur;
mod clutter;
mod generate;
mod geometry;
mod raster;
mod render;
pub mod rng;
mod session;
mod spec;
mod tool;
mod tool_shape;
mod tool_suite;

use std::cell::RefCell;

use image::GrayImage;

pub use background::{Needle, RealLook};
pub use clutter::{Particle, Scratch};
pub use generate::{random_frame, real_suite, suite, varied_look, BLANK_FRACTION};
pub use geometry::{px_per_um, Edges, Entry, Pose, ProbeGeometry, Segment, FIELD_WIDTH_AT_1X_UM};
pub use render::{force_nn, truth_of, Renderer, Truth};
pub use session::{
    Clicks, FrameFormat, Session, SessionError, Setup, FRAME_RATE_HZ, MAGNIFICATIONS,
};
pub use spec::{FrameSpec, Look, Others, Placement, Style, MAX_OTHER_PROBES};
pub use tool::{clip_to_frame, tool_clicks, tool_truth, ToolTruth};
pub use tool_shape::{Flank, ToolGeometry, ToolKind, DEFAULT_SPAN_UM, MAX_BOW, TOOL_FLANKS};
pub use tool_suite::{
    tool_suite, ToolSession, CLICKS_PER_EDGE, MAG_RATIO as TOOL_MAG_RATIO, TIP_MARGIN_PX,
    TIP_REGION,
};

thread_local! {
    static RENDERER: RefCell<Renderer> = RefCell::new(Renderer::new());
}

/// Renders `spec` into `frame` with this thread's [`Renderer`] (its buffers are reused,
/// so after the first frame of a size nothing is allocated) and returns the truth.
pub fn render_into(spec: &FrameSpec, frame: &mut GrayImage) -> Truth {
    RENDERER.with(|r| r.borrow_mut().render_into(spec, frame))
}

/// As [`render_into`], over the caller's crops of real SEM frames when `spec.look.real`
/// asks for one (see [`Renderer::render_over`]).
pub fn render_over_into(spec: &FrameSpec, crops: &[GrayImage], frame: &mut GrayImage) -> Truth {
    RENDERER.with(|r| r.borrow_mut().render_over(spec, crops, frame))
}

/// Renders `spec`, whose own probe is a tool, over the caller's crops (as
/// [`render_over_into`]) and returns the tool's truth. A spec without a tool is a
/// caller's error.
pub fn render_tool_into(spec: &FrameSpec, crops: &[GrayImage], frame: &mut GrayImage) -> ToolTruth {
    let truth = tool_truth(spec);
    render_over_into(spec, crops, frame);
    truth.expect("render_tool_into draws a spec with a tool")
}

/// Renders `spec` into a new frame.
pub fn render(spec: &FrameSpec) -> (GrayImage, Truth) {
    let mut frame = GrayImage::new(spec.width, spec.height);
    let truth = render_into(spec, &mut frame);
    (frame, truth)
}
