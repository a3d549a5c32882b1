//! Log lines on standard error, for a person at a terminal or for the systemd journal.
//!
//! - Under systemd (`JOURNAL_STREAM` names the stream standard error is), each line
//!   starts with its syslog priority in the sd-daemon form (`<3>` error, `<4>` warning,
//!   `<6>` info, `<7>` debug and trace) and carries no timestamp: the journal adds its
//!   own, and `journalctl -p warning` finds the warnings.
//! - Elsewhere each line starts with the UTC time and the level; colour only when
//!   standard error is a terminal, so a file or a pipe gets no escape codes.
//! - Repeats are rate-limited: each place in the code that logs writes at most
//!   [`LINES_PER_INTERVAL`] lines a second (a few distinct lines at once, such as one
//!   per device or per frame of a short replay, all pass), and the next line it writes
//!   after a pause says how many were left out.

use std::collections::HashMap;
use std::fmt;
use std::io::IsTerminal;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use tracing::{Event, Level, Subscriber};
use tracing_subscriber::fmt::format::Writer;
use tracing_subscriber::fmt::time::{FormatTime, SystemTime};
use tracing_subscriber::fmt::{FmtContext, FormatEvent, FormatFields, MakeWriter};
use tracing_subscriber::layer::{Context, Filter, SubscriberExt};
use tracing_subscriber::registry::LookupSpan;
use tracing_subscriber::util::SubscriberInitExt;
use tracing_subscriber::{EnvFilter, Layer};

/// The window over which one place in the code may write [`LINES_PER_INTERVAL`] lines.
const REPEAT_INTERVAL: Duration = Duration::from_secs(1);
/// Lines one place in the code may write per `REPEAT_INTERVAL`.
pub const LINES_PER_INTERVAL: u32 = 10;

/// Where the lines go and how they look.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Style {
    /// systemd's journal: `<priority>` first, no timestamp, no colour.
    Journal,
    /// A terminal or a file: timestamp and level, colour if `colour`.
    Plain { colour: bool },
}

impl Style {
    /// The style for this process's standard error.
    pub fn for_stderr() -> Style {
        if stderr_is_journal(std::env::var("JOURNAL_STREAM").ok().as_deref()) {
            Style::Journal
        } else {
            Style::Plain {
                colour: std::io::stderr().is_terminal(),
            }
        }
    }
}

/// Whether `journal_stream` ("DEVICE:INODE", set by systemd) names standard error: a
/// child whose standard error was redirected elsewhere inherits the variable but must
/// not write priorities into a file.
fn stderr_is_journal(journal_stream: Option<&str>) -> bool {
    let Some((dev, ino)) = journal_stream.and_then(|s| s.split_once(':')) else {
        return false;
    };
    let (Ok(dev), Ok(ino)) = (dev.trim().parse::<u64>(), ino.trim().parse::<u64>()) else {
        return false;
    };
    let mut st = std::mem::MaybeUninit::<libc::stat>::uninit();
    // SAFETY: fstat writes a `stat` into the buffer on success; it is read only then.
    let ok = unsafe { libc::fstat(libc::STDERR_FILENO, st.as_mut_ptr()) } == 0;
    if !ok {
        return false;
    }
    // SAFETY: fstat succeeded, so the buffer is initialised.
    let st = unsafe { st.assume_init() };
    st.st_dev == dev && st.st_ino == ino
}

/// What a line written to standard error outside `tracing` (the binary's final error)
/// starts with: the error priority under systemd, nothing elsewhere.
pub fn error_prefix() -> &'static str {
    match Style::for_stderr() {
        Style::Journal => "<3>",
        Style::Plain { .. } => "",
    }
}

/// Human-readable logs on standard error, filtered by RUST_LOG (default: info). A second
/// initialisation (tests calling `run` twice) is harmless.
pub fn init() {
    let filter = EnvFilter::try_from_default_env().unwrap_or_else(|_| EnvFilter::new("info"));
    let _ = tracing_subscriber::registry()
        .with(filter)
        .with(layer(Style::for_stderr(), std::io::stderr))
        .try_init();
}

/// The formatting layer for `style`, writing to `writer`, with repeats rate-limited.
pub fn layer<S, W>(style: Style, writer: W) -> impl Layer<S>
where
    S: Subscriber + for<'a> LookupSpan<'a>,
    W: for<'w> MakeWriter<'w> + Send + Sync + 'static,
{
    let limiter = RateLimit::default();
    tracing_subscriber::fmt::layer()
        .with_writer(writer)
        .with_ansi(matches!(style, Style::Plain { colour: true }))
        .event_format(Line {
            style,
            limiter: limiter.clone(),
        })
        .with_filter(limiter)
}

/// One line per event.
struct Line {
    style: Style,
    limiter: RateLimit,
}

impl<S, N> FormatEvent<S, N> for Line
where
    S: Subscriber + for<'a> LookupSpan<'a>,
    N: for<'a> FormatFields<'a> + 'static,
{
    fn format_event(
        &self,
        ctx: &FmtContext<'_, S, N>,
        mut writer: Writer<'_>,
        event: &Event<'_>,
    ) -> fmt::Result {
        let meta = event.metadata();
        match self.style {
            Style::Journal => write!(writer, "<{}>", priority(*meta.level()))?,
            Style::Plain { colour } => {
                SystemTime.format_time(&mut writer)?;
                let (on, off) = if colour {
                    (level_colour(*meta.level()), "\x1b[0m")
                } else {
                    ("", "")
                };
                write!(writer, " {on}{:>5}{off} ", meta.level())?;
            }
        }
        write!(writer, "{}: ", meta.target())?;
        ctx.field_format().format_fields(writer.by_ref(), event)?;
        let left_out = self.limiter.take_left_out(meta.callsite());
        if left_out > 0 {
            let s = if left_out == 1 { "" } else { "s" };
            write!(writer, " ({left_out} similar line{s} left out)")?;
        }
        writeln!(writer)
    }
}

/// The sd-daemon priority of a level.
fn priority(level: Level) -> u8 {
    match level {
        Level::ERROR => 3,
        Level::WARN => 4,
        Level::INFO => 6,
        _ => 7,
    }
}

fn level_colour(level: Level) -> &'static str {
    match level {
        Level::ERROR => "\x1b[31m",
        Level::WARN => "\x1b[33m",
        Level::INFO => "\x1b[32m",
        Level::DEBUG => "\x1b[34m",
        _ => "\x1b[35m",
    }
}

/// Per place in the code: when it last wrote, and how many lines were left out since.
#[derive(Clone, Default)]
struct RateLimit {
    seen: Arc<Mutex<HashMap<tracing::callsite::Identifier, Repeats>>>,
}

#[derive(Debug, Clone, Copy)]
struct Repeats {
    window_start: Instant,
    written: u32,
    left_out: u64,
    /// Left out before the line now being written (read by its formatter).
    pending: u64,
}

impl RateLimit {
    /// Whether a line from `callsite` may be written now.
    fn admit(&self, callsite: tracing::callsite::Identifier) -> bool {
        let Ok(mut seen) = self.seen.lock() else {
            return true;
        };
        let now = Instant::now();
        let r = seen.entry(callsite).or_insert(Repeats {
            window_start: now,
            written: 0,
            left_out: 0,
            pending: 0,
        });
        if now.duration_since(r.window_start) >= REPEAT_INTERVAL {
            r.window_start = now;
            r.written = 0;
        }
        if r.written >= LINES_PER_INTERVAL {
            r.left_out += 1;
            return false;
        }
        r.written += 1;
        r.pending = std::mem::take(&mut r.left_out);
        true
    }

    /// How many lines from `callsite` were left out before the one being written.
    fn take_left_out(&self, callsite: tracing::callsite::Identifier) -> u64 {
        self.seen
            .lock()
            .ok()
            .and_then(|mut seen| {
                seen.get_mut(&callsite)
                    .map(|r| std::mem::take(&mut r.pending))
            })
            .unwrap_or(0)
    }
}

impl<S> Filter<S> for RateLimit {
    fn enabled(&self, _meta: &tracing::Metadata<'_>, _cx: &Context<'_, S>) -> bool {
        true
    }

    fn event_enabled(&self, event: &Event<'_>, _cx: &Context<'_, S>) -> bool {
        self.admit(event.metadata().callsite())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Lines written through a layer of `style` while `f` runs.
    fn lines(style: Style, f: impl FnOnce()) -> Vec<String> {
        let buf = Arc::new(Mutex::new(Vec::<u8>::new()));
        let sink = buf.clone();
        let make = move || Sink(sink.clone());
        let subscriber = tracing_subscriber::registry().with(layer(style, make));
        tracing::subscriber::with_default(subscriber, f);
        let bytes = buf.lock().unwrap().clone();
        String::from_utf8(bytes)
            .unwrap()
            .lines()
            .map(str::to_string)
            .collect()
    }

    struct Sink(Arc<Mutex<Vec<u8>>>);

    impl std::io::Write for Sink {
        fn write(&mut self, b: &[u8]) -> std::io::Result<usize> {
            self.0.lock().unwrap().extend_from_slice(b);
            Ok(b.len())
        }
        fn flush(&mut self) -> std::io::Result<()> {
            Ok(())
        }
    }

    #[test]
    fn journal_lines_start_with_their_priority_and_carry_no_time() {
        let out = lines(Style::Journal, || {
            tracing::error!("e");
            tracing::warn!(device = "/dev/comedi0", "w");
            tracing::info!("i");
            tracing::debug!("d");
        });
        assert_eq!(out.len(), 4, "{out:?}");
        for (line, p) in out.iter().zip(["<3>", "<4>", "<6>", "<7>"]) {
            assert!(line.starts_with(p), "{line}");
            assert!(!line.contains('\x1b'), "{line}");
            // No time of its own: the target follows the priority.
            assert!(line[3..].starts_with("nanoforce::cli::logging"), "{line}");
        }
        assert!(out[1].ends_with("w device=\"/dev/comedi0\""), "{}", out[1]);
    }

    #[test]
    fn plain_lines_have_time_and_level_and_colour_only_when_asked() {
        let plain = lines(Style::Plain { colour: false }, || tracing::warn!("w"));
        assert_eq!(plain.len(), 1);
        assert!(!plain[0].contains('\x1b'), "{}", plain[0]);
        assert!(plain[0].contains(" WARN "), "{}", plain[0]);
        assert!(
            plain[0].contains('T') && plain[0].contains('Z'),
            "{}",
            plain[0]
        );
        let coloured = lines(Style::Plain { colour: true }, || tracing::warn!("w"));
        assert!(coloured[0].contains("\x1b[33m"), "{}", coloured[0]);
    }

    #[test]
    fn repeats_are_a_few_lines_a_second_with_a_count() {
        // One place in the code, logging again and again.
        let late = |ms: u32| tracing::warn!("frame late by {ms} ms");
        let out = lines(Style::Journal, || {
            for ms in 0..100 {
                late(ms);
            }
            tracing::info!("another place is not held back");
            std::thread::sleep(REPEAT_INTERVAL + Duration::from_millis(50));
            for ms in 0..3 {
                late(ms);
            }
        });
        let late: Vec<_> = out.iter().filter(|l| l.contains("frame late")).collect();
        let burst = LINES_PER_INTERVAL as usize;
        assert_eq!(late.len(), burst + 3, "{out:?}");
        assert!(late[..burst].iter().all(|l| !l.contains("left out")));
        let left_out = 100 - burst;
        assert!(
            late[burst].ends_with(&format!("({left_out} similar lines left out)")),
            "{}",
            late[burst]
        );
        assert!(!late[burst + 1].contains("left out"));
        assert!(out.iter().any(|l| l.contains("another place")));
    }

    #[test]
    fn journal_stream_must_name_standard_error() {
        assert!(!stderr_is_journal(None));
        assert!(!stderr_is_journal(Some("garbage")));
        assert!(!stderr_is_journal(Some("1:2")));
    }
}
