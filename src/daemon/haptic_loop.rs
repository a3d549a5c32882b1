//! The 1 kHz haptic loop: a dedicated, named thread on an absolute CLOCK_MONOTONIC
//! schedule (SCHED_FIFO and locked memory when permitted). Each tick reads the stylus,
//! runs the teleoperation law on the newest published estimate of the probe it feels
//! (never waiting for vision), writes the stylus force and sends the S100 rate command
//! to that probe's positioner; every other positioner is commanded to stand still.
//!
//! With several felt probes the stylus's [`SWITCH_BUTTON`] moves it to the next one
//! ([`crate::control::Controller::switch_probe`]: the force fades, motion waits for the
//! re-centred stylus).
//!
//! Nothing here allocates once the loop runs: the estimate arrives through a triple
//! buffer, new gains and telemetry through wait-free rings, statistics go into
//! preallocated histograms. Outputs are zeroed and forces switched off when the loop
//! ends for any reason, panics included ([`Outputs`]'s `Drop`).
use std::path::Path;
use std::sync::atomic::{AtomicBool, AtomicU64, AtomicU8, AtomicUsize, Ordering};
use std::sync::{Arc, Mutex};

use nalgebra::Vector3;

use super::rt;
use super::stats::Histogram;
use super::stream::HapticTap;
use super::tick_record::TickRecord;
pub use crate::config::LoopOptions;
use crate::control::Published;
use crate::control::{
    Controller, GateCounters, PressBlock, SafetyCounters, SafetyState, TeleopGains, TickInput,
};
use crate::hw::clock::monotonic_ns;
use crate::hw::daq::RateOutput;
use crate::hw::haptic::{HapticDevice, SWITCH_BUTTON};
use crate::hw::Clock;
use crate::model::Cantilever;

/// What the loop shares with the supervisor: counters to read, a flag to stop it.
#[derive(Debug, Default)]
pub struct LoopShared {
    pub stop: AtomicBool,
    pub ticks: AtomicU64,
    pub overruns: AtomicU64,
    pub stale_events: AtomicU64,
    pub faults: AtomicU64,
    pub telemetry_dropped: AtomicU64,
    /// The plausibility gate's counts (see [`GateCounters`]).
    pub gate_held: AtomicU64,
    pub gate_attenuated: AtomicU64,
    pub gate_confirmed: AtomicU64,
    /// The frame period and capture-to-arrival delay the loop measures, microseconds
    /// (0: not measured yet).
    pub frame_period_us: AtomicU64,
    pub frame_delay_us: AtomicU64,
    /// Frames come too slowly for force feedback (a slow scan).
    pub slow_frames: AtomicBool,
    /// The probe the stylus feels, by its place among the probes.
    active_probe: AtomicUsize,
    /// Times the stylus was switched to another probe.
    pub switches: AtomicU64,
    state: AtomicU8,
    /// Set on a fault transition (rare: it may allocate), taken by the supervisor to log.
    pub last_fault: Mutex<Option<String>>,
}

impl LoopShared {
    /// The probe the stylus feels and drives, by its place among the probes.
    pub fn active_probe(&self) -> usize {
        self.active_probe.load(Ordering::Relaxed)
    }

    pub fn state(&self) -> SafetyState {
        match self.state.load(Ordering::Relaxed) {
            1 => SafetyState::Engaged,
            2 => SafetyState::HapticFault,
            3 => SafetyState::DaqFault,
            _ => SafetyState::WaitingForCentre,
        }
    }

    fn set_state(&self, state: SafetyState) {
        let code = match state {
            SafetyState::WaitingForCentre => 0,
            SafetyState::Engaged => 1,
            SafetyState::HapticFault => 2,
            SafetyState::DaqFault => 3,
        };
        self.state.store(code, Ordering::Relaxed);
    }

    fn note_fault(&self, message: impl FnOnce() -> String) {
        if let Ok(mut slot) = self.last_fault.try_lock() {
            if slot.is_none() {
                *slot = Some(message());
            }
        }
    }
}

/// The loop's final numbers.
#[derive(Debug, Clone)]
pub struct LoopReport {
    pub ticks: u64,
    pub periods_us: Histogram,
    pub overruns: u64,
    pub counters: SafetyCounters,
    pub gate: GateCounters,
    pub realtime: bool,
}

/// The devices the loop drives; dropping it zeroes every positioner and switches
/// forces off.
pub struct Outputs {
    pub haptic: Box<dyn HapticDevice>,
    /// One positioner per probe, in the probes' order.
    pub stages: Vec<Box<dyn RateOutput>>,
    clock: Clock,
}

impl Drop for Outputs {
    fn drop(&mut self) {
        let now_s = self.clock.now_s();
        for stage in &mut self.stages {
            let _ = stage.zero(now_s);
        }
        let _ = self.haptic.write_force(Vector3::zeros());
        let _ = self.haptic.set_forces_enabled(false);
    }
}

/// A probe the stylus can feel: its place among the probes and what it changes in the
/// teleoperation gains.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FeltProbe {
    pub probe: usize,
    /// Its beam: the plausibility gate's spring constant and force sigmas; None:
    /// `[teleop]`'s (the first probe's).
    pub cantilever: Option<Cantilever>,
    /// The sign of its tracked force while it presses; None: `[teleop]`'s.
    pub pressing_force_sign: Option<f64>,
}

impl FeltProbe {
    /// The lone probe of a view, felt with `[teleop]` as it is.
    pub const SINGLE: FeltProbe = FeltProbe {
        probe: 0,
        cantilever: None,
        pressing_force_sign: None,
    };

    /// `gains` while feeling this probe.
    pub fn gains(&self, gains: TeleopGains) -> TeleopGains {
        TeleopGains {
            cantilever: self.cantilever.unwrap_or(gains.cantilever),
            pressing_force_sign: self
                .pressing_force_sign
                .unwrap_or(gains.pressing_force_sign),
            ..gains
        }
    }
}

/// Everything the loop thread owns.
pub struct HapticLoop {
    pub controller: Controller,
    pub outputs: Outputs,
    /// Each probe's newest estimate, in the probes' order.
    pub estimates: Vec<triple_buffer::Output<Published>>,
    /// The probes the stylus can feel, in the order the switch visits them (at least
    /// one); the first is felt at the start.
    felt: Vec<FeltProbe>,
    /// Which of `felt` is felt now.
    active: usize,
    /// `[teleop]` and `[safety]` as last loaded, before any probe's own values.
    teleop: TeleopGains,
    pub gains: rtrb::Consumer<TeleopGains>,
    pub telemetry: rtrb::Producer<TickRecord>,
    pub shared: Arc<LoopShared>,
    pub options: LoopOptions,
    /// The live data stream's ring for the decimated haptic state (None: not streamed).
    pub stream: Option<HapticTap>,
}

impl HapticLoop {
    /// `stages` and `estimates`: one per probe, in order; `felt`: the probes the stylus
    /// can feel (at least one; the first is felt at the start).
    #[allow(clippy::too_many_arguments)]
    pub fn new(
        gains: TeleopGains,
        felt: Vec<FeltProbe>,
        haptic: Box<dyn HapticDevice>,
        stages: Vec<Box<dyn RateOutput>>,
        clock: Clock,
        estimates: Vec<triple_buffer::Output<Published>>,
        new_gains: rtrb::Consumer<TeleopGains>,
        telemetry: rtrb::Producer<TickRecord>,
        shared: Arc<LoopShared>,
        options: LoopOptions,
    ) -> Self {
        assert!(!felt.is_empty(), "the stylus feels at least one probe");
        assert!(
            felt.iter()
                .all(|f| f.probe < stages.len() && f.probe < estimates.len()),
            "every felt probe has a positioner and an estimate"
        );
        shared.active_probe.store(felt[0].probe, Ordering::Relaxed);
        HapticLoop {
            controller: Controller::new(felt[0].gains(gains.clone())),
            outputs: Outputs {
                haptic,
                stages,
                clock,
            },
            estimates,
            felt,
            active: 0,
            teleop: gains,
            gains: new_gains,
            telemetry,
            shared,
            options,
            stream: None,
        }
    }

    /// Starts the loop on its own thread named `haptic-loop`.
    pub fn spawn(self) -> std::io::Result<std::thread::JoinHandle<LoopReport>> {
        std::thread::Builder::new()
            .name("haptic-loop".into())
            .spawn(move || self.run())
    }

    /// Real-time settings for this thread; the latency request lives as long as the loop.
    fn prepare_thread(&self) -> (bool, Option<rt::CpuLatencyRequest>) {
        let mut realtime = false;
        if let Some(priority) = self.options.rt_priority {
            match rt::set_realtime_priority(priority) {
                Ok(()) => realtime = true,
                Err(e) => tracing::warn!(
                    "haptic loop: SCHED_FIFO priority {priority} refused ({e}); running at \
                     normal priority, expect more jitter (grant LimitRTPRIO / CAP_SYS_NICE)"
                ),
            }
        }
        if self.options.lock_memory {
            if let Err(e) = rt::lock_memory() {
                tracing::warn!(
                    "haptic loop: mlockall refused ({e}); pages may fault in (raise LimitMEMLOCK)"
                );
            }
        }
        let latency = self.options.cpu_latency_us.and_then(|us| {
            let device = Path::new(rt::CPU_LATENCY_DEVICE);
            rt::request_cpu_latency(device, us)
                .map_err(|e| {
                    tracing::warn!(
                        "haptic loop: CPU wake-up latency limit of {us} us refused ({}: {e}); \
                         idle CPUs may wake late (udev/99-nanoforce.rules grants access)",
                        device.display()
                    )
                })
                .ok()
        });
        (realtime, latency)
    }

    /// Runs until `shared.stop` is set; returns the loop's numbers.
    pub fn run(mut self) -> LoopReport {
        let (realtime, _latency_request) = self.prepare_thread();
        let mut periods_us = Histogram::new(1.0, 20_000.0);
        let mut period_ns = self.period_ns();
        let spin_ns = self.options.spin_us * 1000;
        let mut next_ns = monotonic_ns() + period_ns;
        let mut last_tick_ns: Option<u64> = None;
        let mut state = TickState::default();
        let mut overruns = 0u64;
        let mut ticks = 0u64;
        while !self.shared.stop.load(Ordering::Relaxed) {
            rt::sleep_until(next_ns, spin_ns);
            let now_ns = monotonic_ns();
            let period_us = last_tick_ns.map_or(0.0, |last| (now_ns - last) as f64 * 1e-3);
            if last_tick_ns.is_some() {
                periods_us.record(period_us);
            }
            last_tick_ns = Some(now_ns);
            next_ns += period_ns;
            if now_ns > next_ns {
                // Missed whole deadlines: count them and re-anchor, never burst to catch up.
                let missed = (now_ns - next_ns) / period_ns + 1;
                overruns += missed;
                next_ns += missed * period_ns;
                self.shared.overruns.store(overruns, Ordering::Relaxed);
            }
            while let Ok(gains) = self.gains.pop() {
                self.controller
                    .set_gains(self.felt[self.active].gains(gains.clone()));
                self.teleop = gains;
                period_ns = self.period_ns();
            }
            self.tick(now_ns, period_us, ticks, &mut state);
            ticks += 1;
            self.shared.ticks.store(ticks, Ordering::Relaxed);
        }
        LoopReport {
            ticks,
            periods_us,
            overruns,
            counters: self.controller.counters(),
            gate: self.controller.gate_counters(),
            realtime,
        }
    }

    fn period_ns(&self) -> u64 {
        (self.controller.gains().period_us() * 1e3).round() as u64
    }

    fn tick(&mut self, now_ns: u64, period_us: f64, tick: u64, state: &mut TickState) {
        let now_s = self.outputs.clock.seconds_at(now_ns);
        let shared = &self.shared;
        let haptic = match self.outputs.haptic.read(now_s) {
            Ok(sample) => Some(sample),
            Err(e) => {
                shared.note_fault(|| format!("haptic device: {e}"));
                None
            }
        };
        let pressed = haptic.map_or(0, |h| h.buttons & SWITCH_BUTTON);
        if pressed != 0 && state.switch_held == 0 && self.felt.len() > 1 {
            self.active = (self.active + 1) % self.felt.len();
            let felt = self.felt[self.active];
            self.controller
                .switch_probe(felt.gains(self.teleop.clone()));
            shared.active_probe.store(felt.probe, Ordering::Relaxed);
            shared.switches.fetch_add(1, Ordering::Relaxed);
        }
        state.switch_held = pressed;
        let probe = self.felt[self.active].probe;
        let estimate = *self.estimates[probe].read();
        let out = self.controller.tick(&TickInput {
            now_s,
            haptic,
            estimate: Some(estimate),
            daq_ok: state.daq_ok,
        });
        let haptic_dev = &mut self.outputs.haptic;
        if out.forces_enabled != state.forces_on {
            let _ = haptic_dev.set_forces_enabled(out.forces_enabled);
            state.forces_on = out.forces_enabled;
        }
        if out.forces_enabled {
            if let Err(e) = haptic_dev.write_force(out.force_n) {
                shared.note_fault(|| format!("haptic device: {e}"));
            }
        }
        // The felt probe's positioner follows the stylus; the others stand still.
        let mut daq_ok = true;
        for (k, stage) in self.outputs.stages.iter_mut().enumerate() {
            let velocity = if k == probe {
                out.stage_velocity_um_s
            } else {
                Vector3::zeros()
            };
            if let Err(e) = stage.write_velocity(now_s, velocity) {
                let _ = stage.zero(now_s);
                if state.daq_ok && daq_ok {
                    shared.note_fault(|| format!("stage output: {e}; outputs set to zero"));
                }
                daq_ok = false;
            }
        }
        if !daq_ok {
            // Every positioner stops with the one that failed.
            for stage in &mut self.outputs.stages {
                let _ = stage.zero(now_s);
            }
        }
        state.daq_ok = daq_ok;
        shared.set_state(out.state);
        let counters = self.controller.counters();
        shared
            .stale_events
            .store(counters.stale_events, Ordering::Relaxed);
        shared.faults.store(counters.faults, Ordering::Relaxed);
        let gate = self.controller.gate_counters();
        shared.gate_held.store(gate.held, Ordering::Relaxed);
        shared
            .gate_attenuated
            .store(gate.attenuated, Ordering::Relaxed);
        shared
            .gate_confirmed
            .store(gate.confirmed, Ordering::Relaxed);
        let timing = self.controller.frame_timing();
        let micros = |s: Option<f64>| s.map_or(0, |s| (s * 1e6) as u64);
        shared
            .frame_period_us
            .store(micros(timing.period_s()), Ordering::Relaxed);
        shared
            .frame_delay_us
            .store(micros(timing.delay_s()), Ordering::Relaxed);
        shared.slow_frames.store(
            out.press_block == Some(PressBlock::SlowFrames),
            Ordering::Relaxed,
        );
        let telemetry_due = tick.is_multiple_of(u64::from(self.options.telemetry_every.max(1)));
        let stream_due = self.stream.as_mut().is_some_and(|s| s.due(now_s));
        if telemetry_due || stream_due {
            let record = TickRecord {
                t_s: now_s,
                period_us,
                position_mm: haptic.map_or([f64::NAN; 3], |h| h.position_mm.into()),
                force_n: out.force_n.into(),
                velocity_um_s: out.stage_velocity_um_s.into(),
                rendered_force_nn: out.rendered_force_nn,
                state: out.state,
                press_blocked: out.press_block.is_some(),
                gate_held: gate.held,
                gate_attenuated: gate.attenuated,
                felt_probe: probe,
            };
            if telemetry_due && self.telemetry.push(record).is_err() {
                shared.telemetry_dropped.fetch_add(1, Ordering::Relaxed);
            }
            if let Some(stream) = self.stream.as_mut().filter(|_| stream_due) {
                stream.offer(record);
            }
        }
    }
}

/// Device-facing state carried from tick to tick.
#[derive(Debug, Clone, Copy)]
struct TickState {
    daq_ok: bool,
    forces_on: bool,
    /// The switch button as last read (a switch on each press, not while held).
    switch_held: u32,
}

impl Default for TickState {
    fn default() -> Self {
        TickState {
            daq_ok: true,
            forces_on: false,
            switch_held: 0,
        }
    }
}

/// Logs what the loop's counters say about the plausibility gate and the frame rate, at
/// most once per `every` (the loop itself never logs): held and attenuated estimates
/// since the last line, and entering or leaving the slow-scan mode at once.
#[derive(Debug)]
pub struct GateLog {
    every: std::time::Duration,
    last_line: Option<std::time::Instant>,
    logged: GateCounters,
    slow: bool,
}

impl Default for GateLog {
    fn default() -> Self {
        GateLog {
            every: std::time::Duration::from_secs(5),
            last_line: None,
            logged: GateCounters::default(),
            slow: false,
        }
    }
}

impl GateLog {
    /// Called by the supervisor every 100 ms or so.
    pub fn poll(&mut self, shared: &LoopShared, now: std::time::Instant) {
        let slow = shared.slow_frames.load(Ordering::Relaxed);
        if slow != self.slow {
            self.slow = slow;
            let period_ms = shared.frame_period_us.load(Ordering::Relaxed) as f64 * 1e-3;
            if slow {
                tracing::warn!(
                    "frames arrive every {period_ms:.0} ms, above safety.max_frame_period_ms: \
                     a slow scan gives no force feedback; sensed force off, pressing refused, \
                     positioning only (use a fast scan of 10 frames/s or more to feel forces)"
                );
            } else {
                tracing::info!("frames every {period_ms:.0} ms again: force feedback back on");
            }
        }
        if self
            .last_line
            .is_some_and(|t| now.duration_since(t) < self.every)
        {
            return;
        }
        let held = shared.gate_held.load(Ordering::Relaxed);
        let attenuated = shared.gate_attenuated.load(Ordering::Relaxed);
        let confirmed = shared.gate_confirmed.load(Ordering::Relaxed);
        if held == self.logged.held && attenuated == self.logged.attenuated {
            return;
        }
        tracing::warn!(
            "plausibility gate: {} estimates held as implausible jumps, {} rendered \
             attenuated for a large sigma, {} jumps confirmed (totals {held}, {attenuated}, \
             {confirmed})",
            held - self.logged.held,
            attenuated - self.logged.attenuated,
            confirmed - self.logged.confirmed,
        );
        self.logged = GateCounters {
            held,
            attenuated,
            confirmed,
        };
        self.last_line = Some(now);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_felt_probe_brings_its_cantilever_and_sign_into_the_gains() {
        let teleop = TeleopGains::default();
        let beam = Cantilever {
            length_um: 200.0,
            ..teleop.cantilever
        };
        let own = FeltProbe {
            probe: 1,
            cantilever: Some(beam),
            pressing_force_sign: Some(-1.0),
        };
        let gains = own.gains(teleop.clone());
        assert_eq!(gains.pressing_force_sign, -1.0);
        assert_eq!(gains.cantilever, beam);
        assert_eq!(gains.press_direction_stage, teleop.press_direction_stage);
        // A lone probe is felt with [teleop] as it is.
        assert_eq!(FeltProbe::SINGLE.gains(teleop.clone()), teleop);
    }
}
