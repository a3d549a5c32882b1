//! The `"sim"` frame backend: the simulated SEM renders the probe as the simulated stage
//! has bent it, at the configured rate and delay, with ground truth attached.
use image::GrayImage;

use super::daq::StageSnapshot;
use super::sem::SemScene;
use crate::hw::clock::sleep_until;
use crate::hw::frames::MAX_TRUTHS;
use crate::hw::frames::{FrameError, FrameMeta, FrameSource};
use crate::hw::Clock;
use crate::scene::Renderer;
use nalgebra::Vector3;

/// Slack between the end of a render and its frame's delivery, seconds.
const RENDER_MARGIN_S: f64 = 0.001;

pub struct SimSem {
    scene: SemScene,
    /// Each probe's simulated positioner, in the probes' order (None: a real one).
    stages: Vec<Option<triple_buffer::Output<StageSnapshot>>>,
    positions_um: [Vector3<f64>; MAX_TRUTHS],
    renderer: Renderer,
    clock: Clock,
    period_s: f64,
    next_capture_s: Option<f64>,
    sequence: u64,
    /// The slowest recent render, seconds (decays slowly), to start the next one in time.
    render_s: f64,
}

impl SimSem {
    /// `stages`: each probe's simulated positioner, in the probes' order; a probe
    /// without one (None, or past the end) hangs free.
    pub fn new(
        scene: SemScene,
        stages: Vec<Option<triple_buffer::Output<StageSnapshot>>>,
        clock: Clock,
    ) -> Self {
        let period_s = 1.0 / scene.params.rate_hz;
        SimSem {
            scene,
            stages,
            positions_um: [Vector3::zeros(); MAX_TRUTHS],
            renderer: Renderer::new(),
            clock,
            period_s,
            next_capture_s: None,
            sequence: 0,
            render_s: 0.005,
        }
    }
}

impl FrameSource for SimSem {
    fn name(&self) -> &str {
        "sim:SEM"
    }

    fn next_frame(&mut self, frame: &mut GrayImage) -> Result<FrameMeta, FrameError> {
        let delay_s = self.scene.params.delay_ms * 1e-3;
        let now_s = self.clock.now_s();
        let mut capture_s = self.next_capture_s.unwrap_or(now_s);
        // A frame whose delivery time has already passed was lost (we fell behind):
        // skip to the next scan, as a real frame grabber would.
        while capture_s + delay_s + self.period_s < now_s {
            capture_s += self.period_s;
            self.sequence += 1;
        }
        self.next_capture_s = Some(capture_s + self.period_s);
        // A real SEM does not use the control PC's CPU. The stage state at `capture_s` is
        // already known, so render late, just before delivery, in the part of the period
        // where the tracker has finished the previous frame, instead of right after that
        // frame's delivery, where the two would compete for the cores.
        let deliver_s = capture_s + delay_s;
        let start_s = deliver_s - (2.0 * self.render_s + RENDER_MARGIN_S);
        sleep_until(self.clock.monotonic_ns_at(start_s), 0);
        let render_started_s = self.clock.now_s();
        for (position, stage) in self.positions_um.iter_mut().zip(&mut self.stages) {
            *position = stage
                .as_mut()
                .map_or_else(Vector3::zeros, |s| s.read().position_at(capture_s));
        }
        let stages = &self.positions_um[..self.stages.len().min(MAX_TRUTHS)];
        let (spec, truth) = self.scene.view(capture_s, self.sequence, stages);
        self.renderer.render_into(&spec, frame);
        let took_s = self.clock.now_s() - render_started_s;
        self.render_s = took_s.max(self.render_s * 0.99);
        let deliver_ns = self.clock.monotonic_ns_at(deliver_s);
        sleep_until(deliver_ns, 0);
        self.sequence += 1;
        Ok(FrameMeta {
            sequence: self.sequence,
            captured_s: capture_s,
            truth,
        })
    }
}
