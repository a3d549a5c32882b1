//! The signals the supervisor waits on: SIGHUP reloads the gains, the stop signals
//! ([`STOP_SIGNALS`]) end the run; without signal handling (tests) it waits forever.

use anyhow::Context;

use super::STOP_SIGNALS;

/// The signals the daemon reacts to.
pub(super) enum SignalEvent {
    Stop(&'static str),
    Reload,
}

pub(super) struct Signals {
    /// SIGHUP, then each of [`STOP_SIGNALS`].
    streams: Vec<tokio::signal::unix::Signal>,
}

impl Signals {
    /// tokio's handlers only note the signal and wake the supervisor (async-signal-safe);
    /// everything else happens here, on the supervisor's thread.
    pub(super) fn new(enabled: bool) -> anyhow::Result<Self> {
        use tokio::signal::unix::{signal, SignalKind};
        if !enabled {
            return Ok(Signals {
                streams: Vec::new(),
            });
        }
        let mut streams =
            vec![signal(SignalKind::hangup()).context("installing the SIGHUP handler")?];
        for (number, name) in STOP_SIGNALS {
            streams.push(
                signal(SignalKind::from_raw(number))
                    .with_context(|| format!("installing the {name} handler"))?,
            );
        }
        Ok(Signals { streams })
    }

    pub(super) async fn next(&mut self) -> SignalEvent {
        if self.streams.is_empty() {
            return std::future::pending().await;
        }
        let streams = &mut self.streams;
        let index = std::future::poll_fn(|cx| {
            for (i, stream) in streams.iter_mut().enumerate() {
                if stream.poll_recv(cx).is_ready() {
                    return std::task::Poll::Ready(i);
                }
            }
            std::task::Poll::Pending
        })
        .await;
        match index {
            0 => SignalEvent::Reload,
            i => SignalEvent::Stop(STOP_SIGNALS[i - 1].1),
        }
    }
}
