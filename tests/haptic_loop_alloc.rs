//! The 1 kHz loop must not allocate in steady state. A counting global allocator counts
//! allocations made on the haptic loop's thread only (the fake haptic device marks that
//! thread on its first read); the devices here are atomics-only so they add nothing.
//! The live data stream is on, its haptic state at the loop's full rate.
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Arc;
use std::time::Duration;

use image::GrayImage;
use nalgebra::Vector3;
use nanoforce::control::{HapticSample, SafetyState, TeleopGains};
use nanoforce::daemon::stream::StreamConfig;
use nanoforce::daemon::{Daemon, Devices, Estimator, LoopOptions, RunOptions};
use nanoforce::hw::daq::{DaqError, RateOutput};
use nanoforce::hw::frames::{FrameError, FrameMeta, FrameSource, NO_TRUTH};
use nanoforce::hw::haptic::{HapticDevice, HapticError};
use nanoforce::hw::Clock;
use nanoforce::vision::Estimate;

mod alloc_counter;

#[global_allocator]
static GLOBAL: alloc_counter::Counting = alloc_counter::Counting;

struct Frames(Clock, u64);
impl FrameSource for Frames {
    fn name(&self) -> &str {
        "frames"
    }
    fn next_frame(&mut self, frame: &mut GrayImage) -> Result<FrameMeta, FrameError> {
        std::thread::sleep(Duration::from_millis(16));
        if frame.width() != 32 {
            *frame = GrayImage::new(32, 32);
        }
        self.1 += 1;
        Ok(FrameMeta {
            sequence: self.1,
            captured_s: self.0.now_s(),
            truth: NO_TRUTH,
        })
    }
}

/// Alternates the force so the ramp keeps retargeting, and every third frame jumps
/// far enough for the plausibility gate to hold it.
struct Tracker(u64);
impl Tracker {
    fn next_estimate(&mut self) -> Estimate {
        self.0 += 1;
        let force_nn = match self.0 % 6 {
            0 | 3 => 3000.0,
            1 | 5 => 1000.0,
            _ => 1010.0,
        };
        Estimate {
            detected: true,
            force_nn: Some(force_nn),
            apex_px: Some([3.0, 4.0]),
            confidence: 0.9,
            angle_sigma_deg: Some(0.05),
            ..Estimate::default()
        }
    }
}

impl Estimator for Tracker {
    fn estimate(&mut self, _frame: &GrayImage, estimates: &mut [Estimate]) {
        estimates[0] = self.next_estimate();
    }
}

struct Stage(Arc<AtomicU64>);
impl RateOutput for Stage {
    fn name(&self) -> &str {
        "stage"
    }
    fn write_velocity(&mut self, _now_s: f64, v: Vector3<f64>) -> Result<(), DaqError> {
        if v.x > 0.0 {
            self.0.fetch_max(v.x.to_bits(), Ordering::Relaxed);
        }
        Ok(())
    }
}

struct Haptic;
impl HapticDevice for Haptic {
    fn name(&self) -> &str {
        "haptic"
    }
    fn read(&mut self, now_s: f64) -> Result<HapticSample, HapticError> {
        alloc_counter::watch_this_thread();
        // Centred for the first 100 ms (to engage), then a slow lateral sweep.
        let x = if now_s < 0.1 {
            0.0
        } else {
            5.0 + (now_s * 3.0).sin()
        };
        Ok(HapticSample {
            position_mm: Vector3::new(x, 0.0, 0.0),
            velocity_mm_s: Vector3::zeros(),
            buttons: 0,
        })
    }
    fn write_force(&mut self, _force_n: Vector3<f64>) -> Result<(), HapticError> {
        Ok(())
    }
    fn set_forces_enabled(&mut self, _enabled: bool) -> Result<(), HapticError> {
        Ok(())
    }
}

#[test]
fn haptic_loop_does_not_allocate_in_steady_state() {
    let clock = Clock::start();
    let velocity = Arc::new(AtomicU64::new(0));
    let devices = Devices::one_probe(
        Box::new(Frames(clock, 0)),
        Box::new(Tracker(0)),
        Box::new(Stage(velocity.clone())),
        Box::new(Haptic),
    );
    let receiver = std::net::UdpSocket::bind("127.0.0.1:0").unwrap();
    let options = RunOptions {
        clock,
        stream: StreamConfig {
            udp: Some(receiver.local_addr().unwrap()),
            haptic_hz: 1000.0,
        },
        loop_options: LoopOptions {
            rt_priority: None,
            lock_memory: false,
            cpu_latency_us: None,
            telemetry_every: 1,
            ..LoopOptions::default()
        },
        session_dir: Some(tempfile::tempdir().unwrap().keep()),
        ..RunOptions::default()
    };
    let handle = Daemon::start(TeleopGains::default(), devices, options).unwrap();
    // Engaged once the stylus is centred, later on a loaded machine than on an idle
    // one: the steady state is what is measured, so it is waited for.
    let deadline = std::time::Instant::now() + Duration::from_secs(10);
    while handle.loop_shared.state() != SafetyState::Engaged && std::time::Instant::now() < deadline
    {
        std::thread::sleep(Duration::from_millis(10));
    }
    assert_eq!(handle.loop_shared.state(), SafetyState::Engaged);
    alloc_counter::start();
    let ticks_before = handle.loop_shared.ticks.load(Ordering::SeqCst);
    std::thread::sleep(Duration::from_millis(700));
    let loop_allocations = alloc_counter::stop();
    let ticks = handle.loop_shared.ticks.load(Ordering::SeqCst) - ticks_before;
    let held = handle.loop_shared.gate_held.load(Ordering::SeqCst);
    assert!(held > 0, "the gate's held path ran too");
    handle.stop();
    let streamed = handle.wait().unwrap().stats.stream.unwrap();
    assert!(streamed.haptic_sent > 400, "the stream ran: {streamed:?}");
    assert!(ticks > 400, "the loop ran ({ticks} ticks)");
    assert!(
        f64::from_bits(velocity.load(Ordering::SeqCst)) > 0.0,
        "and moved the stage"
    );
    assert_eq!(loop_allocations, 0, "allocations on the loop thread");
}
