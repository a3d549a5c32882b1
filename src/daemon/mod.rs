//! The real-time teleoperation daemon (`nanoforce run`).
//!
//! Threads, each named, each with one job:
//! - `frames`: the [`FrameSource`](crate::hw::frames::FrameSource) fills a latest-only slot;
//! - `tracker`: the vision tracker turns the newest frame into an estimate, published
//!   whole and stamped ([`crate::control::Published`]) to every reader below;
//! - `haptic-loop`: the 1 kHz loop (stylus -> law -> force and S100 rate command);
//! - `telemetry`: drains the loops' records into the session folder;
//! - `stream` (when `[stream]` asks for it): the live UDP data stream of estimates and
//!   the haptic state, fed through wait-free rings;
//! - `frame-recorder`: writes the frames the tracker saw into the session's
//!   `frames.nfrm` ([`frame_record`]);
//! - `monitor` (when `[monitor]` asks for it): the live web page and the recorded
//!   thumbnails ([`monitor`]), drawn from [`snapshot`]s the tracker hands over without
//!   waiting;
//! - the supervisor, on a small tokio runtime: signals (SIGHUP reloads the gains;
//!   SIGINT, SIGTERM, SIGQUIT, SIGABRT, SIGUSR1/2, SIGALRM, SIGXCPU stop it), systemd
//!   notifications and watchdog, the status line. Any thread that dies (a panic, in
//!   any of them) stops the run: the haptic loop first, so the outputs are at zero and
//!   forces off before the stop is recorded.
//!
//! [`instance`] keeps one daemon per state directory and device set; [`inject`] lets
//! the tests panic any thread.
//!
//! The blocking loops are plain threads rather than async tasks: a capture call, a
//! tracker pass or a 1 kHz deadline must never wait on an executor, and async is only
//! the wiring around them.
pub mod frame_record;
pub mod haptic_loop;
pub mod inject;
pub mod instance;
pub mod lab;
pub mod monitor;
pub mod notify;
pub mod pipeline;
pub mod recording;
pub mod rt;
pub mod snapshot;
pub mod stats;
pub mod stream;
mod supervisor;
pub mod telemetry;
pub mod tick_record;

pub use haptic_loop::LoopOptions;
pub use pipeline::Estimator;
pub use supervisor::{
    Daemon, DaemonHandle, Devices, ExitReason, Outcome, Reload, RunOptions, STOP_SIGNALS,
};
