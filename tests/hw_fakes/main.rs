//! Every real backend's code path, exercised against a fake of its vendor library or
//! device (C sources in `tests/fakes/`, built here with the system C compiler):
//!
//! - `comedi`: a fake `libcomedi.so.0` in place of comedilib (LD_LIBRARY_PATH, child);
//! - `openhaptics`: a fake `libHD.so` loaded at run time, with its own servo thread;
//! - `v4l2`: an LD_PRELOAD shim that fakes a `/dev/video` device (child);
//! - `hid`: a fake `libhidapi-hidraw.so.0` replaying recorded reports (child).
//!
//! Needs `--features hardware` (each module needs its own feature).
#![cfg(any(
    feature = "comedi",
    feature = "openhaptics",
    feature = "v4l2",
    feature = "hidapi"
))]
#[cfg(feature = "comedi")]
mod comedi;
#[cfg(feature = "hidapi")]
mod hid;
#[cfg(feature = "openhaptics")]
mod openhaptics;
mod support;
#[cfg(feature = "v4l2")]
mod v4l2;
