//! Session recording: every run writes its telemetry into a fresh folder under the
//! state directory. The real-time threads push fixed-size records into wait-free rings;
//! a background writer thread drains them into CSV files, so disk latency never reaches
//! the loops.
//!
//! A session folder holds `config.toml` (the configuration the run used), `ticks.csv`
//! (the haptic loop, decimated), `estimates.csv` (one row per tracked frame) and
//! `events.log` (faults and state changes).
use std::fs::{self, File};
use std::io::{self, BufWriter, Write};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::thread::{self, JoinHandle};
use std::time::{Duration, SystemTime, UNIX_EPOCH};

use super::haptic_loop::TickRecord;
use super::pipeline::EstimateRecord;
use crate::config::PixelOrigin;

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

/// `YYYYmmddTHHMMSSZ` from Unix seconds (civil-from-days, proleptic Gregorian).
fn utc_stamp(secs: u64) -> String {
    let days = (secs / 86_400) as i64;
    let rem = secs % 86_400;
    let z = days + 719_468;
    let era = z.div_euclid(146_097);
    let doe = z - era * 146_097;
    let yoe = (doe - doe / 1460 + doe / 36_524 - doe / 146_096) / 365;
    let doy = doe - (365 * yoe + yoe / 4 - yoe / 100);
    let mp = (5 * doy + 2) / 153;
    let day = doy - (153 * mp + 2) / 5 + 1;
    let month = if mp < 10 { mp + 3 } else { mp - 9 };
    let year = yoe + era * 400 + i64::from(month <= 2);
    format!(
        "{year:04}{month:02}{day:02}T{:02}{:02}{:02}Z",
        rem / 3600,
        rem / 60 % 60,
        rem % 60
    )
}

/// The writer thread's inputs.
pub struct Recorder {
    pub dir: PathBuf,
    /// `tracker.pixel_origin`: where the apex columns count from.
    pub pixel_origin: PixelOrigin,
    pub ticks: rtrb::Consumer<TickRecord>,
    pub estimates: rtrb::Consumer<EstimateRecord>,
    pub events: std::sync::mpsc::Receiver<String>,
}

/// Starts the `telemetry` thread; it drains until `stop` is set, then flushes and ends.
pub fn spawn_recorder(
    mut recorder: Recorder,
    stop: Arc<AtomicBool>,
) -> io::Result<JoinHandle<io::Result<()>>> {
    let mut ticks = BufWriter::new(File::create(recorder.dir.join("ticks.csv"))?);
    let mut estimates = BufWriter::new(File::create(recorder.dir.join("estimates.csv"))?);
    let mut events = BufWriter::new(File::create(recorder.dir.join("events.log"))?);
    writeln!(
        ticks,
        "t_s,period_us,pos_x_mm,pos_y_mm,pos_z_mm,force_x_n,force_y_n,force_z_n,\
         vel_x_um_s,vel_y_um_s,vel_z_um_s,rendered_force_nN,state,press_blocked,gate_held,\
         gate_attenuated"
    )?;
    writeln!(
        estimates,
        "seq,frame_seq,frame_time_s,published_s,detected,angle_deg,force_nN,tip_x,tip_y,\
         confidence,processing_ms,true_force_nN"
    )?;
    thread::Builder::new()
        .name("telemetry".into())
        .spawn(move || {
            loop {
                let stopping = stop.load(Ordering::Relaxed);
                while let Ok(r) = recorder.ticks.pop() {
                    write_tick(&mut ticks, &r)?;
                }
                while let Ok(r) = recorder.estimates.pop() {
                    write_estimate(&mut estimates, &r, recorder.pixel_origin)?;
                }
                while let Ok(line) = recorder.events.try_recv() {
                    writeln!(events, "{line}")?;
                }
                if stopping {
                    break;
                }
                thread::sleep(Duration::from_millis(50));
            }
            ticks.flush()?;
            estimates.flush()?;
            events.flush()
        })
}

fn write_tick(out: &mut impl Write, r: &TickRecord) -> io::Result<()> {
    let [px, py, pz] = r.position_mm;
    let [fx, fy, fz] = r.force_n;
    let [vx, vy, vz] = r.velocity_um_s;
    writeln!(
        out,
        "{:.6},{:.1},{px:.4},{py:.4},{pz:.4},{fx:.5},{fy:.5},{fz:.5},{vx:.4},{vy:.4},{vz:.4},{:.3},{},{},{},{}",
        r.t_s,
        r.period_us,
        r.rendered_force_nn,
        r.state.as_str(),
        u8::from(r.press_blocked),
        r.gate_held,
        r.gate_attenuated
    )
}

fn write_estimate(out: &mut impl Write, r: &EstimateRecord, origin: PixelOrigin) -> io::Result<()> {
    let e = &r.estimate;
    let apex = origin.output(e.apex_px);
    let opt = |v: f64| {
        if v.is_finite() {
            format!("{v}")
        } else {
            String::new()
        }
    };
    writeln!(
        out,
        "{},{},{:.6},{:.6},{},{},{},{},{},{:.4},{:.3},{}",
        e.seq,
        e.frame_sequence,
        e.frame_time_s,
        e.published_s,
        u8::from(e.detected),
        opt(e.angle_deg),
        opt(e.force_nn),
        opt(apex[0]),
        opt(apex[1]),
        e.confidence,
        r.processing_ms,
        r.true_force_nn.map_or(String::new(), |f| format!("{f}"))
    )
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
    fn apex_columns_follow_the_pixel_origin() {
        let record = |detected: bool| EstimateRecord {
            estimate: super::super::PublishedEstimate {
                seq: 7,
                frame_sequence: 9,
                frame_time_s: 1.0,
                published_s: 1.02,
                detected,
                angle_deg: if detected { -1.5 } else { f64::NAN },
                force_nn: if detected { -420.0 } else { f64::NAN },
                apex_px: if detected {
                    [300.25, 200.0]
                } else {
                    [f64::NAN; 2]
                },
                confidence: 0.9,
                angle_sigma_deg: if detected { 0.02 } else { f64::NAN },
            },
            processing_ms: 0.8,
            true_force_nn: None,
        };
        let line = |r: &EstimateRecord, origin| {
            let mut out = Vec::new();
            write_estimate(&mut out, r, origin).unwrap();
            String::from_utf8(out).unwrap()
        };
        let centre = line(&record(true), PixelOrigin::Centre);
        let corner = line(&record(true), PixelOrigin::Corner);
        assert!(centre.contains(",-420,300.25,200,0.9000,"), "{centre}");
        assert!(corner.contains(",-420,300.75,200.5,0.9000,"), "{corner}");
        // No apex stays empty whichever the origin.
        let missed = line(&record(false), PixelOrigin::Corner);
        assert!(missed.contains(",0,,,,,0.9000,"), "{missed}");
    }
}
