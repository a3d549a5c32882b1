//! Whether the session is being recorded: the state the telemetry writer and the frame
//! recorder set and the supervisor, the status line and the monitor page read. A leaf
//! of the daemon, so that both writers can share it without importing each other.
use std::sync::atomic::{AtomicBool, AtomicU64, AtomicU8, Ordering};
use std::sync::Mutex;

/// Whether the session is being recorded, shared by the writer thread (which sets it),
/// the supervisor (status line, stats) and the monitor page.
#[derive(Debug, Default)]
pub struct RecordingStatus {
    state: AtomicU8,
    error: Mutex<Option<String>>,
    /// The recorded frames (`frames.nfrm`).
    pub frames: FrameRecordShared,
}

/// What [`RecordingStatus`] says.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum RecordingState {
    /// This run records nothing (`--no-record`).
    Off,
    Recording,
    /// Recording stopped during the run (a full disk, a write error, the budget); the
    /// loops go on.
    Stopped,
}

impl RecordingState {
    pub fn as_str(self) -> &'static str {
        match self {
            RecordingState::Off => "off",
            RecordingState::Recording => "recording",
            RecordingState::Stopped => "stopped",
        }
    }
}

impl RecordingStatus {
    pub fn recording() -> Self {
        let status = RecordingStatus::default();
        status.state.store(1, Ordering::Relaxed);
        status
    }

    pub fn state(&self) -> RecordingState {
        match self.state.load(Ordering::Relaxed) {
            1 => RecordingState::Recording,
            2 => RecordingState::Stopped,
            _ => RecordingState::Off,
        }
    }

    /// Why recording stopped, if it did.
    pub fn error(&self) -> Option<String> {
        self.error.lock().ok().and_then(|e| e.clone())
    }

    /// Recording stops for `reason` (the first reason is kept); logged once, as a warning.
    pub fn stop(&self, reason: String) {
        if self.state.swap(2, Ordering::Relaxed) == 2 {
            return;
        }
        tracing::warn!("recording stopped: {reason}; control goes on");
        if let Ok(mut e) = self.error.lock() {
            *e = Some(reason);
        }
    }

    /// One phrase for status lines: "recording", "recording off", "recording stopped: ...".
    pub fn describe(&self) -> String {
        match self.state() {
            RecordingState::Off => "recording off".into(),
            RecordingState::Recording => "recording".into(),
            RecordingState::Stopped => format!(
                "recording stopped: {}",
                self.error().unwrap_or_else(|| "unknown error".into())
            ),
        }
    }
}

/// Counters shared by the tap, the writer, the supervisor and the monitor (they live in
/// the session's [`RecordingStatus`]).
#[derive(Debug, Default)]
pub struct FrameRecordShared {
    /// Frames written to `frames.nfrm`.
    pub recorded: AtomicU64,
    /// Frames the tracker offered that were not recorded (the writer was behind, or the
    /// frames had stopped).
    pub dropped: AtomicU64,
    pub bytes: AtomicU64,
    /// The frames reached their share of the budget (or failed to write) and stopped.
    pub stopped: AtomicBool,
}
