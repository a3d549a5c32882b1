//! Session recording: every run writes its telemetry into a fresh folder under the
//! state directory. The real-time threads push fixed-size records into wait-free rings;
//! a background writer thread drains them into CSV files, so disk latency never reaches
//! the loops.
//!
//! A session folder holds `config.toml` (the configuration the run used),
//! `session.json` (the UTC time of t = 0, see [`UtcAnchor`]), `ticks.csv` (the haptic
//! loop, decimated), `estimates.csv` (one row per tracked frame, in the one estimate
//! schema of a replay's CSV: [`crate::session::results`]; with several probes one file
//! per probe, `estimates.<name>.csv`), `events.log` (faults and
//! state changes, written as they happen) and `frames.nfrm` (the frames the tracker
//! saw, written by [`super::frame_record`]). Both CSVs have a `utc` column: the row's
//! time (`t_s`, `frame_time_s`) in UTC.
//!
//! A write that fails (a full disk) stops the recording and says so; the loops go on.
//! `[daemon] recordings_max_mb` bounds the sessions: the oldest are deleted at start
//! and while a run grows.
use std::fs::{self, File};
use std::io::{self, BufWriter, Write};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::thread::{self, JoinHandle};
use std::time::{Duration, Instant, SystemTime, UNIX_EPOCH};

use super::frame_record::FRAMES_FILE;
use super::inject::PanicInjection;
use super::pipeline::EstimateRecord;
use super::recording::RecordingStatus;
use super::tick_record::TickRecord;
use crate::config::PixelOrigin;
use crate::session::live::{SessionInfo, SESSION_FILE};
use crate::session::metadata::SemMetadata;
use crate::session::results::{self, FrameLabel, RowExtras};
use crate::session::utc::{civil_from_days, UtcAnchor};

/// The state directory: `$STATE_DIRECTORY` (set by systemd's StateDirectory=), else
/// `$XDG_STATE_HOME/nanoforce`, else `~/.local/state/nanoforce`.
pub fn default_state_dir() -> PathBuf {
    if let Some(dir) = std::env::var_os("STATE_DIRECTORY") {
        // systemd may pass several, colon-separated: the first is ours.
        let first = dir
            .to_string_lossy()
            .split(':')
            .next()
            .unwrap_or("")
            .to_string();
        if !first.is_empty() {
            return PathBuf::from(first);
        }
    }
    if let Some(dir) = std::env::var_os("XDG_STATE_HOME") {
        return PathBuf::from(dir).join("nanoforce");
    }
    match std::env::var_os("HOME") {
        Some(home) => PathBuf::from(home).join(".local/state/nanoforce"),
        None => PathBuf::from("nanoforce-state"),
    }
}

/// Creates `state_dir/sessions/<UTC time>-<pid>/` and returns its path.
pub fn create_session_dir(state_dir: &Path) -> io::Result<PathBuf> {
    let secs = SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .map_or(0, |d| d.as_secs());
    let name = format!("{}-{}", utc_stamp(secs), std::process::id());
    let dir = state_dir.join("sessions").join(name);
    fs::create_dir_all(&dir)?;
    Ok(dir)
}

/// `YYYYmmddTHHMMSSZ` from Unix seconds.
fn utc_stamp(secs: u64) -> String {
    let (year, month, day) = civil_from_days((secs / 86_400) as i64);
    let rem = secs % 86_400;
    format!(
        "{year:04}{month:02}{day:02}T{:02}{:02}{:02}Z",
        rem / 3600,
        rem / 60 % 60,
        rem % 60
    )
}

/// The recordings' size limit (`[daemon] recordings_max_mb`).
#[derive(Debug, Clone, PartialEq)]
pub struct Budget {
    /// `state_dir/sessions`.
    pub sessions_dir: PathBuf,
    pub max_bytes: u64,
}

/// How often the writer flushes its files: a crash loses at most this much telemetry.
/// The estimates of a lone probe; with several, each probe's is named after it.
pub const ESTIMATES_FILE: &str = "estimates.csv";

const FLUSH_EVERY: Duration = Duration::from_millis(500);
/// How often a running session checks the recordings against the budget.
const BUDGET_EVERY: Duration = Duration::from_secs(10);

/// The writer thread's inputs.
pub struct Recorder {
    pub dir: PathBuf,
    /// The UTC time of the clock's t = 0.
    pub anchor: UtcAnchor,
    /// Whether `frames.nfrm` is recorded (named in `session.json`).
    pub records_frames: bool,
    /// The configuration file the run loaded (None: built in), for `session.json`.
    pub config_file: Option<PathBuf>,
    /// `tracker.pixel_origin`: where the apex columns count from.
    pub pixel_origin: PixelOrigin,
    /// The probes' names, in order (each has its estimates file).
    pub probe_names: Vec<String>,
    pub ticks: rtrb::Consumer<TickRecord>,
    pub estimates: rtrb::Consumer<EstimateRecord>,
    pub events: std::sync::mpsc::Receiver<String>,
    pub status: Arc<RecordingStatus>,
    pub budget: Option<Budget>,
    /// A panic to inject into this thread (tests only).
    pub inject: Option<PanicInjection>,
}

/// The session's open files.
struct Files {
    ticks: BufWriter<File>,
    /// Each probe's, in order.
    estimates: Vec<BufWriter<File>>,
    events: BufWriter<File>,
}

impl Files {
    fn create(dir: &Path, info: &SessionInfo, probe_names: &[String]) -> io::Result<Files> {
        let named = |path: &Path, e: io::Error| {
            io::Error::new(e.kind(), format!("{}: {e}", path.display()))
        };
        let open = |name: &str| {
            let path = dir.join(name);
            File::create(&path)
                .map(BufWriter::new)
                .map_err(|e| named(&path, e))
        };
        let session_json = dir.join(SESSION_FILE);
        serde_json::to_string_pretty(info)
            .map_err(io::Error::other)
            .and_then(|json| fs::write(&session_json, json + "\n"))
            .map_err(|e| named(&session_json, e))?;
        let names: Vec<&str> = probe_names.iter().map(String::as_str).collect();
        let mut files = Files {
            ticks: open("ticks.csv")?,
            estimates: results::per_probe(Path::new(ESTIMATES_FILE), &names)
                .iter()
                .map(|(_, path)| open(&path.to_string_lossy()))
                .collect::<io::Result<_>>()?,
            events: open("events.log")?,
        };
        writeln!(
            files.ticks,
            "t_s,period_us,pos_x_mm,pos_y_mm,pos_z_mm,force_x_n,force_y_n,force_z_n,\
             vel_x_um_s,vel_y_um_s,vel_z_um_s,rendered_force_nN,state,press_blocked,gate_held,\
             gate_attenuated,utc,felt_probe"
        )?;
        for estimates in &mut files.estimates {
            writeln!(estimates, "{}", results::header())?;
        }
        writeln!(
            files.events,
            "session start: t = 0 s is {} UTC (CLOCK_MONOTONIC {:.9} s)",
            info.t0_utc,
            info.anchor.t0_monotonic_ns as f64 * 1e-9
        )?;
        files.flush()?;
        Ok(files)
    }

    fn flush(&mut self) -> io::Result<()> {
        self.ticks.flush()?;
        for estimates in &mut self.estimates {
            estimates.flush()?;
        }
        self.events.flush()
    }
}

/// Starts the `telemetry` thread; it drains until `stop` is set, then flushes and ends.
/// Events reach `events.log` as they happen; the CSV files are flushed every
/// `FLUSH_EVERY`. A write that fails (a full disk) stops the recording, reported
/// through `recorder.status`; the thread keeps draining the rings so the loops never
/// notice.
pub fn spawn_recorder(
    recorder: Recorder,
    stop: Arc<AtomicBool>,
) -> io::Result<JoinHandle<io::Result<()>>> {
    thread::Builder::new()
        .name("telemetry".into())
        .spawn(move || record(recorder, &stop))
}

fn record(mut recorder: Recorder, stop: &AtomicBool) -> io::Result<()> {
    let status = recorder.status.clone();
    let dir = recorder.dir.clone();
    let fail = |e: io::Error| status.stop(format!("{}: {e}", dir.display()));
    let frames_file = recorder.records_frames.then_some(FRAMES_FILE);
    let info = SessionInfo::new(
        recorder.anchor,
        frames_file,
        recorder.config_file.as_deref(),
    );
    let mut files = match Files::create(&recorder.dir, &info, &recorder.probe_names) {
        Ok(files) => Some(files),
        Err(e) => {
            fail(e);
            None
        }
    };
    let mut last_flush = Instant::now();
    let mut last_budget = Instant::now();
    loop {
        PanicInjection::check(recorder.inject.as_ref(), "telemetry");
        let stopping = stop.load(Ordering::Relaxed);
        if let Some(f) = files.as_mut() {
            if let Err(e) = drain(&mut recorder, f) {
                fail(e);
                files = None;
            }
        } else {
            discard(&mut recorder);
        }
        if let Some(f) = files.as_mut() {
            if last_flush.elapsed() >= FLUSH_EVERY || stopping {
                last_flush = Instant::now();
                if let Err(e) = f.flush() {
                    fail(e);
                    files = None;
                }
            }
        }
        if files.is_some() && last_budget.elapsed() >= BUDGET_EVERY {
            last_budget = Instant::now();
            if let Some(budget) = &recorder.budget {
                let own = dir_size(&recorder.dir);
                if own > budget.max_bytes {
                    status.stop(format!(
                        "this session reached daemon.recordings_max_mb ({} MB)",
                        budget.max_bytes / MB
                    ));
                    files = None;
                } else {
                    prune_sessions(budget, Some(&recorder.dir));
                }
            }
        }
        if stopping {
            return Ok(());
        }
        thread::sleep(Duration::from_millis(50));
    }
}

fn drain(recorder: &mut Recorder, files: &mut Files) -> io::Result<()> {
    while let Ok(r) = recorder.ticks.pop() {
        write_tick(
            &mut files.ticks,
            &r,
            &recorder.anchor,
            &recorder.probe_names,
        )?;
    }
    while let Ok(r) = recorder.estimates.pop() {
        let Some(out) = files.estimates.get_mut(r.estimate.probe) else {
            continue;
        };
        write_estimate(out, &r, recorder.pixel_origin, &recorder.anchor)?;
    }
    let mut wrote_event = false;
    while let Ok(line) = recorder.events.try_recv() {
        writeln!(files.events, "{line}")?;
        wrote_event = true;
    }
    if wrote_event {
        files.events.flush()?;
    }
    Ok(())
}

fn discard(recorder: &mut Recorder) {
    while recorder.ticks.pop().is_ok() {}
    while recorder.estimates.pop().is_ok() {}
    while recorder.events.try_recv().is_ok() {}
}

const MB: u64 = 1024 * 1024;

/// Bytes in the files under `dir` (not following links).
pub fn dir_size(dir: &Path) -> u64 {
    let Ok(entries) = fs::read_dir(dir) else {
        return 0;
    };
    entries
        .flatten()
        .map(|e| match e.file_type() {
            Ok(t) if t.is_dir() => dir_size(&e.path()),
            Ok(t) if t.is_file() => e.metadata().map_or(0, |m| m.len()),
            _ => 0,
        })
        .sum()
}

/// Whether `name` is a session folder's name, `YYYYmmddTHHMMSSZ-<pid>`.
fn is_session_name(name: &str) -> bool {
    let b = name.as_bytes();
    b.len() > 17
        && b[..8].iter().all(u8::is_ascii_digit)
        && b[8] == b'T'
        && b[9..15].iter().all(u8::is_ascii_digit)
        && b[15] == b'Z'
        && b[16] == b'-'
        && b[17..].iter().all(u8::is_ascii_digit)
}

/// Deletes the oldest session folders until the recordings fit `budget` (`keep`, the
/// running session, is counted but never deleted); each deletion is logged. Returns the
/// deleted folders.
pub fn prune_sessions(budget: &Budget, keep: Option<&Path>) -> Vec<PathBuf> {
    let Ok(entries) = fs::read_dir(&budget.sessions_dir) else {
        return Vec::new();
    };
    let mut sessions: Vec<(String, PathBuf)> = entries
        .flatten()
        .filter(|e| e.file_type().is_ok_and(|t| t.is_dir()))
        .filter_map(|e| {
            let name = e.file_name().to_str()?.to_string();
            is_session_name(&name).then(|| (name, e.path()))
        })
        .collect();
    // The names start with the UTC time: sorted by name is oldest first.
    sessions.sort();
    let sizes: Vec<u64> = sessions.iter().map(|(_, p)| dir_size(p)).collect();
    let mut total: u64 = sizes.iter().sum::<u64>()
        + keep
            .filter(|k| !sessions.iter().any(|(_, p)| p == k))
            .map_or(0, dir_size);
    let mut pruned = Vec::new();
    for ((_, path), size) in sessions.iter().zip(sizes) {
        if total <= budget.max_bytes {
            break;
        }
        if keep == Some(path.as_path()) {
            continue;
        }
        match fs::remove_dir_all(path) {
            Ok(()) => {
                tracing::info!(
                    "recordings over daemon.recordings_max_mb ({} MB): deleted the oldest \
                     session {} ({:.1} MB)",
                    budget.max_bytes / MB,
                    path.display(),
                    size as f64 / MB as f64
                );
                total -= size;
                pruned.push(path.clone());
            }
            Err(e) => tracing::warn!("recordings budget: cannot delete {}: {e}", path.display()),
        }
    }
    pruned
}

/// One row of `ticks.csv`; `names`: the probes', in order (the felt one is named).
fn write_tick(
    out: &mut impl Write,
    r: &TickRecord,
    anchor: &UtcAnchor,
    names: &[String],
) -> io::Result<()> {
    let [px, py, pz] = r.position_mm;
    let [fx, fy, fz] = r.force_n;
    let [vx, vy, vz] = r.velocity_um_s;
    writeln!(
        out,
        "{:.6},{:.1},{px:.4},{py:.4},{pz:.4},{fx:.5},{fy:.5},{fz:.5},{vx:.4},{vy:.4},{vz:.4},{:.3},{},{},{},{},{},{}",
        r.t_s,
        r.period_us,
        r.rendered_force_nn,
        r.state.as_str(),
        u8::from(r.press_blocked),
        r.gate_held,
        r.gate_attenuated,
        anchor.utc(r.t_s),
        names.get(r.felt_probe).map_or("", String::as_str)
    )
}

/// One row of `estimates.csv`, in the one estimate schema ([`results::COLUMNS`]).
fn write_estimate(
    out: &mut impl Write,
    r: &EstimateRecord,
    origin: PixelOrigin,
    anchor: &UtcAnchor,
) -> io::Result<()> {
    let p = &r.estimate;
    let (name, utc) = (p.frame_sequence.to_string(), anchor.utc(p.frame_time_s));
    let frame = FrameLabel {
        name: &name,
        seq: p.frame_sequence,
        utc: &utc,
        time_s: Some(p.frame_time_s),
    };
    let extras = RowExtras {
        processing_ms: Some(r.processing_ms),
        published: Some((p.seq, p.published_s)),
        true_force_nn: r.true_force_nn,
    };
    let estimate = p.estimate.with_pixel_origin(origin);
    results::write_row(out, &frame, &estimate, &SemMetadata::default(), &extras)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn utc_stamps() {
        assert_eq!(utc_stamp(0), "19700101T000000Z");
        assert_eq!(utc_stamp(951_782_400), "20000229T000000Z");
        assert_eq!(utc_stamp(1_795_000_000), "20261118T110640Z");
    }

    #[test]
    fn the_budget_deletes_the_oldest_sessions_only() {
        let state = tempfile::tempdir().unwrap();
        let sessions = state.path().join("sessions");
        let make = |name: &str, kib: usize| {
            let dir = sessions.join(name);
            fs::create_dir_all(dir.join("thumbnails")).unwrap();
            fs::write(dir.join("thumbnails/a.png"), vec![0u8; kib * 1024]).unwrap();
            dir
        };
        make("20250101T000000Z-1", 400);
        make("20250102T000000Z-2", 400);
        let newest = make("20250103T000000Z-3", 400);
        let running = make("20250104T000000Z-4", 500);
        let other = sessions.join("not-a-session");
        fs::create_dir_all(&other).unwrap();
        fs::write(other.join("big"), vec![0u8; 900 * 1024]).unwrap();
        assert!(is_session_name("20250104T000000Z-4") && !is_session_name("20250104-4"));
        let budget = Budget {
            sessions_dir: sessions.clone(),
            max_bytes: MB,
        };
        let pruned = prune_sessions(&budget, Some(&running));
        // 1.7 MiB of sessions against 1 MiB: the two oldest go; the running one and
        // anything that is not a session stay.
        assert_eq!(
            pruned,
            vec![
                sessions.join("20250101T000000Z-1"),
                sessions.join("20250102T000000Z-2")
            ]
        );
        assert!(newest.exists() && running.exists() && other.exists());
        assert_eq!(dir_size(&newest), 400 * 1024);
        // Within the budget: nothing more goes.
        assert!(prune_sessions(&budget, Some(&running)).is_empty());
    }

    #[test]
    fn apex_columns_follow_the_pixel_origin() {
        let record = |detected: bool| EstimateRecord {
            estimate: crate::control::Published {
                probe: 0,
                seq: 7,
                frame_sequence: 9,
                frame_time_s: 1.0,
                published_s: 1.02,
                estimate: crate::vision::Estimate {
                    detected,
                    angle_deg: detected.then_some(-1.5),
                    force_nn: detected.then_some(-420.0),
                    apex_px: detected.then_some([300.25, 200.0]),
                    confidence: 0.9,
                    angle_sigma_deg: detected.then_some(0.02),
                    ..Default::default()
                },
            },
            processing_ms: 0.8,
            true_force_nn: None,
        };
        let anchor = UtcAnchor {
            t0_unix_ns: 1_796_256_068_000_000_000,
            t0_monotonic_ns: 1,
        };
        let line = |r: &EstimateRecord, origin| {
            let mut out = Vec::new();
            write_estimate(&mut out, r, origin, &anchor).unwrap();
            String::from_utf8(out).unwrap()
        };
        let centre = line(&record(true), PixelOrigin::Centre);
        let corner = line(&record(true), PixelOrigin::Corner);
        assert!(
            centre.starts_with("9,1,-1.500000,-420.0000,300.250,200.000,0.9000,"),
            "{centre}"
        );
        assert!(
            corner.contains(",-420.0000,300.750,200.500,0.9000,"),
            "{corner}"
        );
        // The frame, its times, the publication and whether the force may be felt.
        assert!(
            centre.ends_with(",9,2026-12-03T00:01:09.000000Z,1.000000,0.800,7,1.020000,,1\n"),
            "{centre}"
        );
        // No apex stays empty whichever the origin.
        let missed = line(&record(false), PixelOrigin::Corner);
        assert!(missed.starts_with("9,0,,,,,0.9000,"), "{missed}");
        assert!(missed.ends_with(",0.800,7,1.020000,,0\n"), "{missed}");
        // One schema with the replay's CSV.
        let cells = missed.trim_end().split(',').count();
        assert_eq!(cells, results::COLUMNS.len());
    }
}
