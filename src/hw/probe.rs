//! What `nanoforce probe-devices` checks: each configured device opened the way the
//! daemon opens it (and asked for one frame or one stylus sample), then closed again
//! (a DAQ is left at zero); and, to help with a new setup, what this machine offers:
//! video and comedi device nodes, HID devices, whether libHD.so loads, which hardware
//! features this build has.
use std::time::Instant;

use image::GrayImage;

use super::config::{DevicesConfig, FramesBackend, HapticBackend, Positioner};
use super::open::{self, compiled_features};
use super::Clock;

/// One line of the report: a device, whether it works, and what was seen or why not.
#[derive(Debug, Clone, PartialEq)]
pub struct Finding {
    pub kind: &'static str,
    pub ok: bool,
    pub detail: String,
}

/// Opens and exercises every configured device; a `"sim"` one is reported as such.
pub fn configured(devices: &DevicesConfig, clock: Clock) -> Vec<Finding> {
    let found = |kind, result: Result<String, String>| match result {
        Ok(detail) => Finding {
            kind,
            ok: true,
            detail,
        },
        Err(detail) => Finding {
            kind,
            ok: false,
            detail,
        },
    };
    let several = devices.positioners.len() > 1;
    let positioners = devices.positioners.iter().map(|p| {
        let result = probe_daq(p);
        match several {
            // Each positioner named by its section.
            true => found(
                "daq",
                result
                    .map(|d| format!("[{}] {d}", p.section))
                    .map_err(|e| format!("[{}] {e}", p.section)),
            ),
            false => found("daq", result),
        }
    });
    std::iter::once(found("frames", probe_frames(&devices.frames, clock)))
        .chain(positioners)
        .chain([found("haptic", probe_haptic(&devices.haptic, clock))])
        .collect()
}

fn probe_frames(backend: &FramesBackend, clock: Clock) -> Result<String, String> {
    let Some(mut source) = open::frames(backend, clock).map_err(|e| e.to_string())? else {
        return Ok("sim: the simulated SEM".into());
    };
    let mut frame = GrayImage::new(0, 0);
    let started = Instant::now();
    match source.next_frame(&mut frame) {
        Ok(meta) => Ok(format!(
            "{}: first frame {}x{} (sequence {}) after {} ms",
            source.name(),
            frame.width(),
            frame.height(),
            meta.sequence,
            started.elapsed().as_millis()
        )),
        Err(e) => Err(format!("opened, but no frame: {e}")),
    }
}

fn probe_daq(positioner: &Positioner) -> Result<String, String> {
    match open::daq(positioner).map_err(|e| e.to_string())? {
        None => Ok("sim: the simulated S100".into()),
        Some(daq) => Ok(format!("{}: opened, every output set to zero", daq.name())),
    }
}

fn probe_haptic(backend: &HapticBackend, clock: Clock) -> Result<String, String> {
    let Some(mut haptic) = open::haptic(backend).map_err(|e| e.to_string())? else {
        return Ok("sim: the scripted virtual operator".into());
    };
    let sample = haptic
        .read(clock.now_s())
        .map_err(|e| format!("opened, but: {e}"))?;
    let p = sample.position_mm;
    let force = if haptic.has_force_feedback() {
        "force feedback"
    } else {
        "NO force feedback (position only)"
    };
    Ok(format!(
        "{}: stylus at ({:.1}, {:.1}, {:.1}) mm, {force}",
        haptic.name(),
        p.x,
        p.y,
        p.z
    ))
}

/// Device nodes matching `prefix` in /dev, sorted.
fn nodes(prefix: &str) -> Vec<String> {
    let mut found: Vec<String> = std::fs::read_dir("/dev")
        .map(|d| {
            d.filter_map(|e| e.ok())
                .map(|e| e.file_name().to_string_lossy().into_owned())
                .filter(|n| {
                    n.starts_with(prefix) && n[prefix.len()..].chars().all(|c| c.is_ascii_digit())
                })
                .map(|n| format!("/dev/{n}"))
                .collect()
        })
        .unwrap_or_default();
    found.sort();
    found
}

/// Whether the current user may open `path` read-write.
fn access(path: &str) -> &'static str {
    let Ok(c) = std::ffi::CString::new(path) else {
        return "?";
    };
    // SAFETY: a valid C string.
    if unsafe { libc::access(c.as_ptr(), libc::R_OK | libc::W_OK) } == 0 {
        "read-write"
    } else {
        "NO PERMISSION (see udev/99-nanoforce.rules and the groups in docs/hardware.md)"
    }
}

/// What this machine offers, one line each.
pub fn discover() -> Vec<String> {
    let mut lines = Vec::new();
    let features = compiled_features();
    lines.push(format!(
        "hardware features in this build: {}",
        if features.is_empty() {
            "none (build with --features hardware)".into()
        } else {
            features.join(" ")
        }
    ));
    for (prefix, what) in [("video", "V4L2 video"), ("comedi", "comedi")] {
        let found = nodes(prefix);
        if found.is_empty() {
            lines.push(format!("no {what} device nodes (/dev/{prefix}N)"));
        }
        for node in found {
            lines.push(format!("{node}: {what} node, {}", access(&node)));
        }
    }
    lines.extend(hid_lines());
    lines.push(libhd_line());
    lines
}

#[cfg(feature = "hidapi")]
fn hid_lines() -> Vec<String> {
    match super::haptic::hidapi_sys::enumerate() {
        Ok(found) if found.is_empty() => vec!["no HID devices visible to hidapi".into()],
        Ok(found) => found
            .iter()
            .map(|d| {
                format!(
                    "{}: HID {:04x}:{:04x} {}, {}",
                    d.path,
                    d.vendor_id,
                    d.product_id,
                    d.product,
                    access(&d.path)
                )
            })
            .collect(),
        Err(e) => vec![format!("hidapi: {e}")],
    }
}

#[cfg(not(feature = "hidapi"))]
fn hid_lines() -> Vec<String> {
    let found = nodes("hidraw");
    if found.is_empty() {
        return vec!["no hidraw device nodes".into()];
    }
    found
        .iter()
        .map(|n| format!("{n}: hidraw node, {}", access(n)))
        .collect()
}

#[cfg(feature = "openhaptics")]
fn libhd_line() -> String {
    match super::haptic::hd_sys::Api::load("libHD.so") {
        Ok(_) => "libHD.so (OpenHaptics): loads".into(),
        Err(e) => format!("libHD.so (OpenHaptics): cannot load: {e}"),
    }
}

#[cfg(not(feature = "openhaptics"))]
fn libhd_line() -> String {
    let present = [
        "/usr/lib/libHD.so",
        "/usr/lib64/libHD.so",
        "/usr/lib/x86_64-linux-gnu/libHD.so",
    ]
    .iter()
    .find(|p| std::path::Path::new(p).exists());
    match present {
        Some(p) => format!("{p} present (this build cannot use it: --features openhaptics)"),
        None => "libHD.so (OpenHaptics) not found in the usual places".into(),
    }
}
