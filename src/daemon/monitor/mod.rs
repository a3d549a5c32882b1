//! The live monitor: a small web page served by the daemon's `monitor` thread (latest frame with the
//! overlay, the sensed force as a scrolling plot, loop rates, the safety state), and the
//! overlay thumbnails a recording keeps for `nanoforce report`.
//!
//! Everything here runs on one thread, `monitor`, with its own small tokio runtime, and
//! only *reads*: estimates and frame snapshots the tracker handed over without waiting
//! ([`crate::daemon::snapshot`]) and the loops' atomic counters. Drawing overlays,
//! encoding PNGs, writing thumbnails and serving pages never touch the haptic loop or
//! the tracker; a slow page loses updates, it cannot hold anything up.
//!
//! - `[monitor]` is read by [`crate::config::monitor`] (off by default; loopback unless
//!   `allow_remote`);
//! - `server`: the HTTP/1.1 + Server-Sent Events server and its client caps;
//! - `state`: what each update says, built from the snapshots and counters.
mod server;
mod state;

use std::net::SocketAddr;
use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::thread::JoinHandle;
use std::time::Duration;

use self::server::Hub;
use self::state::Producer;
use crate::daemon::haptic_loop::LoopShared;
use crate::daemon::inject::PanicInjection;
use crate::daemon::pipeline::PipelineShared;
use crate::daemon::recording::RecordingStatus;
use crate::daemon::snapshot::SnapshotReader;
use crate::daemon::stream::StreamShared;

pub use crate::config::MonitorConfig;

/// How often the page is updated.
pub const UPDATE_PERIOD: Duration = Duration::from_millis(100);

/// The loops' shared counters the page shows.
#[derive(Clone)]
pub struct DaemonView {
    pub loop_shared: Arc<LoopShared>,
    pub pipeline_shared: Arc<PipelineShared>,
    /// Whether the session is being recorded (shown on the page).
    pub recording: Arc<RecordingStatus>,
    /// The live data stream's counters, when `[stream]` is on.
    pub stream: Option<Arc<StreamShared>>,
    /// A panic to inject into the monitor thread (tests only).
    pub inject: Option<PanicInjection>,
    /// The probes' names, in order (the frame panel names each).
    pub probe_names: Vec<String>,
}

/// A running monitor thread.
pub struct MonitorHandle {
    thread: Option<JoinHandle<()>>,
    stop: Arc<AtomicBool>,
    /// Where the page is served (the real port when the config said 0).
    pub local_addr: Option<SocketAddr>,
}

impl MonitorHandle {
    /// The thread ended on its own (only a panic ends it before [`MonitorHandle::stop`]).
    pub fn is_finished(&self) -> bool {
        self.thread.as_ref().is_some_and(JoinHandle::is_finished)
    }

    /// Stops the thread and waits for it (it checks every [`UPDATE_PERIOD`]).
    pub fn stop(mut self) {
        self.stop.store(true, Ordering::Relaxed);
        if let Some(thread) = self.thread.take() {
            if thread.join().is_err() {
                tracing::error!("the monitor thread panicked");
            }
        }
    }
}

/// Nice 10 for this thread (Linux: per thread), so the tracker and the frame source win
/// the CPU over drawing and serving pictures.
fn lower_priority() {
    // SAFETY: plain syscalls on the calling thread; no memory is passed.
    let result = unsafe {
        let tid = libc::syscall(libc::SYS_gettid) as libc::id_t;
        libc::setpriority(libc::PRIO_PROCESS, tid, 10)
    };
    if result != 0 {
        tracing::debug!("monitor: could not lower its priority");
    }
}

/// Starts the `monitor` thread. Binding the listen address happens here, so a port in
/// use is an error of the daemon's start, not a silent missing page.
pub fn start(
    config: &MonitorConfig,
    reader: SnapshotReader,
    view: DaemonView,
    recording: Option<PathBuf>,
) -> std::io::Result<MonitorHandle> {
    let listener = match config.listen {
        Some(addr) => {
            let listener = std::net::TcpListener::bind(addr).map_err(|e| {
                std::io::Error::new(e.kind(), format!("monitor: cannot listen on {addr}: {e}"))
            })?;
            listener.set_nonblocking(true)?;
            Some(listener)
        }
        None => None,
    };
    let local_addr = listener.as_ref().and_then(|l| l.local_addr().ok());
    let loopback_only = local_addr.is_some_and(|a| a.ip().is_loopback());
    let hub = Arc::new(Hub::new(config.max_clients, loopback_only));
    let thumbnails = recording
        .filter(|_| config.thumbnail_every_s > 0.0)
        .map(|dir| (dir.join("thumbnails"), config.thumbnail_every_s));
    let producer = Producer::new(reader, view, hub.clone(), thumbnails, listener.is_some());
    let stop = Arc::new(AtomicBool::new(false));
    let thread = {
        let stop = stop.clone();
        std::thread::Builder::new()
            .name("monitor".into())
            .spawn(move || run(listener, hub, producer, &stop))?
    };
    match local_addr {
        Some(addr) if loopback_only => tracing::info!("monitor page: http://{addr}/"),
        Some(addr) => tracing::warn!(
            "monitor page on the network (monitor.allow_remote), with no authentication: \
             http://{addr}/"
        ),
        None => {}
    }
    Ok(MonitorHandle {
        thread: Some(thread),
        stop,
        local_addr,
    })
}

fn run(
    listener: Option<std::net::TcpListener>,
    hub: Arc<Hub>,
    mut producer: Producer,
    stop: &AtomicBool,
) {
    lower_priority();
    let runtime = match tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
    {
        Ok(runtime) => runtime,
        Err(e) => {
            tracing::error!("monitor: cannot start its runtime: {e}; no page, no thumbnails");
            return;
        }
    };
    runtime.block_on(async {
        if let Some(listener) = listener {
            match tokio::net::TcpListener::from_std(listener) {
                Ok(listener) => {
                    tokio::spawn(server::accept_loop(listener, hub));
                }
                Err(e) => tracing::error!("monitor: {e}; no page"),
            }
        }
        let mut interval = tokio::time::interval(UPDATE_PERIOD);
        interval.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Skip);
        while !stop.load(Ordering::Relaxed) {
            interval.tick().await;
            producer.step();
        }
    });
    // Dropping the runtime closes the listener and every open page.
}
