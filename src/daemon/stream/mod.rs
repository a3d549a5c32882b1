//! The live data stream (`[stream]`): one UDP datagram of JSON per published estimate,
//! and, when asked, the haptic loop's state at a fixed rate, for programs that want the
//! force while the run goes on (LabVIEW, MATLAB, Python, a second PC; docs/stream.md).
//!
//! The loops never wait for it: the tracker and the haptic loop push fixed-size records
//! into wait-free rings ([`EstimateTap`], [`HapticTap`]); the `stream` thread drains
//! them, formats each datagram into a reused buffer and sends it on a non-blocking
//! socket. A full ring drops the record and counts it; a send that fails (nobody
//! listening on loopback: connection refused) is counted and logged at most every
//! [`ERROR_LOG_EVERY`], and the run goes on.
pub mod datagram;

use std::io;
use std::net::{Ipv4Addr, Ipv6Addr, SocketAddr, UdpSocket};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::Arc;
use std::thread::{self, JoinHandle, Thread};
use std::time::{Duration, Instant};

use serde::Serialize;

use self::datagram::Format;
use super::tick_record::TickRecord;
use crate::config::PixelOrigin;
pub use crate::config::StreamConfig;
use crate::control::Published;
use crate::session::utc::UtcAnchor;

/// Records the rings hold: about 4 s of estimates at 60 frames/s, 1 s of haptic
/// datagrams at 1 kHz; the thread drains them every [`DRAIN_EVERY`].
const ESTIMATE_RING: usize = 256;
const HAPTIC_RING: usize = 1024;
/// The longest the thread sleeps between drains (the tracker wakes it sooner).
const DRAIN_EVERY: Duration = Duration::from_millis(5);
/// Send errors are logged at most this often, with a count.
pub const ERROR_LOG_EVERY: Duration = Duration::from_secs(10);

/// The stream's counters, read by the supervisor (stats) and the monitor page.
#[derive(Debug, Default)]
pub struct StreamShared {
    pub estimates_sent: AtomicU64,
    /// Estimates the ring had no room for (the stream thread fell behind).
    pub estimates_dropped: AtomicU64,
    pub haptic_sent: AtomicU64,
    pub haptic_dropped: AtomicU64,
    /// Datagrams the socket refused (nobody listening, network down).
    pub send_errors: AtomicU64,
}

/// The `stream` block of the `--stats-json` report (null when the stream is off).
#[derive(Debug, Clone, Copy, Serialize, PartialEq, Default)]
pub struct StreamStats {
    pub estimates_sent: u64,
    pub estimates_dropped: u64,
    pub haptic_sent: u64,
    pub haptic_dropped: u64,
    pub send_errors: u64,
}

impl StreamShared {
    pub fn stats(&self) -> StreamStats {
        let load = |c: &AtomicU64| c.load(Ordering::Relaxed);
        StreamStats {
            estimates_sent: load(&self.estimates_sent),
            estimates_dropped: load(&self.estimates_dropped),
            haptic_sent: load(&self.haptic_sent),
            haptic_dropped: load(&self.haptic_dropped),
            send_errors: load(&self.send_errors),
        }
    }
}

/// The tracker's end: one record per published estimate.
pub struct EstimateTap {
    ring: rtrb::Producer<Published>,
    shared: Arc<StreamShared>,
    stream: Thread,
}

impl EstimateTap {
    /// Hands the estimate over without waiting; wakes the stream thread.
    pub fn offer(&mut self, estimate: &Published) {
        if self.ring.push(*estimate).is_err() {
            self.shared
                .estimates_dropped
                .fetch_add(1, Ordering::Relaxed);
        }
        self.stream.unpark();
    }
}

/// The haptic loop's end: decimates its ticks to `haptic_hz` by their time.
pub struct HapticTap {
    ring: rtrb::Producer<TickRecord>,
    shared: Arc<StreamShared>,
    period_s: f64,
    next_s: f64,
}

impl HapticTap {
    /// Whether the tick at `now_s` is one to send. A loop that stalled does not catch
    /// up with a burst: the schedule restarts from now.
    pub fn due(&mut self, now_s: f64) -> bool {
        if now_s < self.next_s {
            return false;
        }
        self.next_s += self.period_s;
        if self.next_s <= now_s {
            self.next_s = now_s + self.period_s;
        }
        true
    }

    /// Hands the tick over without waiting (allocation-free: a copy into the ring).
    pub fn offer(&mut self, record: TickRecord) {
        if self.ring.push(record).is_err() {
            self.shared.haptic_dropped.fetch_add(1, Ordering::Relaxed);
        }
    }
}

/// The running `stream` thread; dropping it stops the thread.
pub struct StreamHandle {
    thread: Option<JoinHandle<()>>,
    stop: Arc<AtomicBool>,
    pub shared: Arc<StreamShared>,
}

impl StreamHandle {
    /// Asks the thread to send what is queued and end; returns its handle to join.
    pub fn stop(mut self) -> Option<JoinHandle<()>> {
        self.stop.store(true, Ordering::Relaxed);
        let thread = self.thread.take();
        if let Some(t) = &thread {
            t.thread().unpark();
        }
        thread
    }

    /// The thread ended on its own (only a panic ends it before [`StreamHandle::stop`]).
    pub fn is_finished(&self) -> bool {
        self.thread.as_ref().is_some_and(JoinHandle::is_finished)
    }
}

impl Drop for StreamHandle {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
        if let Some(t) = &self.thread {
            t.thread().unpark();
        }
    }
}

/// What [`start`] returns: the thread and the loops' ends of its rings.
pub struct Started {
    pub handle: StreamHandle,
    pub estimates: EstimateTap,
    /// None when `haptic_hz` is 0.
    pub haptic: Option<HapticTap>,
}

/// Opens the socket and starts the `stream` thread for `config` (whose `udp` is set).
pub fn start(
    config: &StreamConfig,
    shared: Arc<StreamShared>,
    anchor: UtcAnchor,
    pixel_origin: PixelOrigin,
) -> io::Result<Started> {
    let Some(target) = config.udp else {
        return Err(io::Error::new(
            io::ErrorKind::InvalidInput,
            "[stream] has no udp address",
        ));
    };
    let socket = open_socket(target)?;
    let (est_tx, est_rx) = rtrb::RingBuffer::new(ESTIMATE_RING);
    let (haptic_tx, haptic_rx) = rtrb::RingBuffer::new(HAPTIC_RING);
    let stop = Arc::new(AtomicBool::new(false));
    let sender = Sender {
        socket,
        target,
        estimates: est_rx,
        haptic: haptic_rx,
        format: Format {
            anchor,
            pixel_origin,
        },
        shared: shared.clone(),
        stop: stop.clone(),
        errors: ErrorLog::default(),
    };
    let thread = thread::Builder::new()
        .name("stream".into())
        .spawn(move || sender.run())?;
    let haptic = (config.haptic_hz > 0.0).then(|| HapticTap {
        ring: haptic_tx,
        shared: shared.clone(),
        period_s: 1.0 / config.haptic_hz,
        next_s: f64::NEG_INFINITY,
    });
    Ok(Started {
        estimates: EstimateTap {
            ring: est_tx,
            shared: shared.clone(),
            stream: thread.thread().clone(),
        },
        haptic,
        handle: StreamHandle {
            thread: Some(thread),
            stop,
            shared,
        },
    })
}

/// A non-blocking UDP socket connected to `target` (so that a refusal is reported back),
/// bound to loopback when the target is on it.
fn open_socket(target: SocketAddr) -> io::Result<UdpSocket> {
    let local: SocketAddr = match (target.is_ipv4(), target.ip().is_loopback()) {
        (true, true) => (Ipv4Addr::LOCALHOST, 0).into(),
        (true, false) => (Ipv4Addr::UNSPECIFIED, 0).into(),
        (false, true) => (Ipv6Addr::LOCALHOST, 0).into(),
        (false, false) => (Ipv6Addr::UNSPECIFIED, 0).into(),
    };
    let socket = UdpSocket::bind(local)?;
    socket.connect(target)?;
    socket.set_nonblocking(true)?;
    Ok(socket)
}

/// The `stream` thread's state.
struct Sender {
    socket: UdpSocket,
    target: SocketAddr,
    estimates: rtrb::Consumer<Published>,
    haptic: rtrb::Consumer<TickRecord>,
    format: Format,
    shared: Arc<StreamShared>,
    stop: Arc<AtomicBool>,
    errors: ErrorLog,
}

impl Sender {
    fn run(mut self) {
        let mut buffer = Vec::with_capacity(512);
        let mut haptic_seq = 0u64;
        loop {
            // Read before draining, so that what was queued before the stop is sent.
            let stopping = self.stop.load(Ordering::Relaxed);
            while let Ok(e) = self.estimates.pop() {
                self.format.estimate(&mut buffer, &e);
                let sent = self.send(&buffer);
                count(sent, &self.shared.estimates_sent);
            }
            while let Ok(record) = self.haptic.pop() {
                haptic_seq += 1;
                self.format.haptic(&mut buffer, haptic_seq, &record);
                let sent = self.send(&buffer);
                count(sent, &self.shared.haptic_sent);
            }
            if stopping {
                break;
            }
            thread::park_timeout(DRAIN_EVERY);
        }
        if let Some(line) = self.errors.finish(self.target) {
            tracing::warn!("{line}");
        }
    }

    fn send(&mut self, datagram: &[u8]) -> bool {
        match self.socket.send(datagram) {
            Ok(_) => {
                if let Some(line) = self.errors.sent(self.target, Instant::now()) {
                    tracing::info!("{line}");
                }
                true
            }
            Err(e) => {
                self.shared.send_errors.fetch_add(1, Ordering::Relaxed);
                if let Some(line) = self.errors.failed(self.target, &e, Instant::now()) {
                    tracing::warn!("{line}");
                }
                false
            }
        }
    }
}

fn count(sent: bool, counter: &AtomicU64) {
    if sent {
        counter.fetch_add(1, Ordering::Relaxed);
    }
}

/// What to log about sends: the first failure at once, then at most one line per
/// [`ERROR_LOG_EVERY`] with the count since the last line, and one line once sends have
/// gone through for that long again. (A success alone says little: on loopback the
/// kernel reports a missing receiver on the send after the refused one, so sends
/// alternate while nobody listens.)
#[derive(Debug, Default)]
struct ErrorLog {
    last_line: Option<Instant>,
    /// The newest failure while failing; None once sends go through again.
    last_error: Option<Instant>,
    unlogged: u64,
}

impl ErrorLog {
    fn failed(&mut self, target: SocketAddr, error: &io::Error, now: Instant) -> Option<String> {
        self.unlogged += 1;
        let starting = self.last_error.is_none();
        self.last_error = Some(now);
        if self
            .last_line
            .is_some_and(|t| now.duration_since(t) < ERROR_LOG_EVERY)
        {
            return None;
        }
        let line = if starting && self.unlogged == 1 {
            format!(
                "stream: sending to {target} failed: {error}; datagrams are lost until a \
                 receiver listens there (the run goes on)"
            )
        } else {
            format!(
                "stream: {} datagrams to {target} failed since the last report (last: {error})",
                self.unlogged
            )
        };
        self.unlogged = 0;
        self.last_line = Some(now);
        Some(line)
    }

    fn sent(&mut self, target: SocketAddr, now: Instant) -> Option<String> {
        let since = now.duration_since(self.last_error?);
        if since < ERROR_LOG_EVERY {
            return None;
        }
        self.last_error = None;
        let unlogged = std::mem::take(&mut self.unlogged);
        let earlier = if unlogged > 0 {
            format!(" ({unlogged} more datagrams had failed before)")
        } else {
            String::new()
        };
        Some(format!(
            "stream: no send errors to {target} for {} s: a receiver listens there{earlier}",
            ERROR_LOG_EVERY.as_secs()
        ))
    }

    fn finish(&self, target: SocketAddr) -> Option<String> {
        (self.unlogged > 0).then(|| {
            format!(
                "stream: {} datagrams to {target} failed since the last report",
                self.unlogged
            )
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::hw::Clock;

    #[test]
    fn haptic_tap_keeps_its_rate_and_never_bursts() {
        let (ring, _rx) = rtrb::RingBuffer::new(4);
        let mut tap = HapticTap {
            ring,
            shared: Arc::default(),
            period_s: 0.004,
            next_s: f64::NEG_INFINITY,
        };
        // A 1 kHz loop for 1 s: every fourth tick.
        let due = (0..1000).filter(|&k| tap.due(k as f64 * 1e-3)).count();
        assert!((249..=251).contains(&due), "{due}");
        // After a 100 ms stall, one datagram, then the rate again.
        assert!(tap.due(1.1));
        assert!(!tap.due(1.101));
        assert!(tap.due(1.104));
    }

    #[test]
    fn send_errors_are_logged_at_a_limited_rate() {
        let target: SocketAddr = "127.0.0.1:9870".parse().unwrap();
        let refused = io::Error::from(io::ErrorKind::ConnectionRefused);
        let t0 = Instant::now();
        let at = |ms: u64| t0 + Duration::from_millis(ms);
        let mut log = ErrorLog::default();
        // Nobody listening for 25 s at 100 datagrams/s: sends alternate.
        let mut lines = Vec::new();
        for k in 0..2500u64 {
            let line = if k % 2 == 0 {
                log.sent(target, at(10 * k))
            } else {
                log.failed(target, &refused, at(10 * k))
            };
            lines.extend(line);
        }
        assert_eq!(lines.len(), 3, "{lines:?}");
        assert!(lines[0].contains("failed: ") && lines[0].contains("the run goes on"));
        assert!(lines[1].starts_with("stream: 500 datagrams to 127.0.0.1:9870 failed"));
        // A receiver appears: one line once 10 s passed without an error.
        assert_eq!(log.sent(target, at(25_000)), None);
        let back = log.sent(target, at(35_000)).unwrap();
        assert!(
            back.ends_with("a receiver listens there (249 more datagrams had failed before)"),
            "{back}"
        );
        assert_eq!(log.sent(target, at(36_000)), None);
        assert_eq!(log.finish(target), None);
    }

    #[test]
    fn a_missing_receiver_is_counted_not_fatal() {
        // A port nobody listens on: bind one, note it, close it.
        let free = UdpSocket::bind("127.0.0.1:0")
            .unwrap()
            .local_addr()
            .unwrap();
        let config = StreamConfig {
            udp: Some(free),
            haptic_hz: 0.0,
        };
        let shared = Arc::new(StreamShared::default());
        let clock = Clock::start();
        let anchor = UtcAnchor::measure(&clock);
        let mut started = start(&config, shared.clone(), anchor, PixelOrigin::Centre).unwrap();
        for seq in 1..=20 {
            let estimate = Published {
                seq,
                frame_time_s: clock.now_s(),
                ..Published::default()
            };
            started.estimates.offer(&estimate);
            thread::sleep(Duration::from_millis(2));
        }
        let handle = started.handle.stop().unwrap();
        handle.join().unwrap();
        let stats = shared.stats();
        assert_eq!(stats.estimates_dropped, 0);
        // Loopback reports the refusal of one datagram on the next send.
        assert!(stats.send_errors >= 5, "{stats:?}");
        assert_eq!(stats.estimates_sent + stats.send_errors, 20, "{stats:?}");
    }
}
