//! Real-time helpers for the haptic loop thread: SCHED_FIFO priority, locked memory, a
//! limit on CPU wake-up latency, and sleeping until an absolute CLOCK_MONOTONIC deadline
//! ([`sleep_until`], kept with the clock in `hw`, where the simulated SEM sleeps too).
//! Each may be refused (no CAP_SYS_NICE / RLIMIT_RTPRIO, RLIMIT_MEMLOCK, no access to
//! /dev/cpu_dma_latency): the caller logs a warning and goes on.
use std::fs::File;
use std::io::{self, Write};
use std::path::Path;

pub use crate::hw::clock::sleep_until;

/// Puts the calling thread under SCHED_FIFO at `priority` (1..=99).
pub fn set_realtime_priority(priority: i32) -> io::Result<()> {
    let param = libc::sched_param {
        sched_priority: priority,
    };
    // SAFETY: pid 0 = the calling thread; param is a valid sched_param.
    let rc = unsafe { libc::sched_setscheduler(0, libc::SCHED_FIFO, &param) };
    if rc == 0 {
        Ok(())
    } else {
        Err(io::Error::last_os_error())
    }
}

/// Locks all current and future pages in RAM so the loop never page-faults.
pub fn lock_memory() -> io::Result<()> {
    // SAFETY: mlockall takes flags only.
    let rc = unsafe { libc::mlockall(libc::MCL_CURRENT | libc::MCL_FUTURE) };
    if rc == 0 {
        Ok(())
    } else {
        Err(io::Error::last_os_error())
    }
}

/// The kernel's PM QoS interface for CPU wake-up latency.
pub const CPU_LATENCY_DEVICE: &str = "/dev/cpu_dma_latency";

/// A held PM QoS request: while it lives, idle CPUs stay in states they can leave within
/// the requested time (0: they poll instead of sleeping; under a hypervisor, they are not
/// handed back to the host). Dropping it closes the file, which withdraws the request.
#[derive(Debug)]
pub struct CpuLatencyRequest {
    _file: File,
}

/// Asks the kernel (through `device`, normally [`CPU_LATENCY_DEVICE`]) to keep CPU
/// wake-up latency at most `max_us` microseconds for as long as the result is held.
pub fn request_cpu_latency(device: &Path, max_us: u32) -> io::Result<CpuLatencyRequest> {
    let mut file = File::options().write(true).open(device)?;
    let value = i32::try_from(max_us).map_err(|_| io::Error::from(io::ErrorKind::InvalidInput))?;
    file.write_all(&value.to_ne_bytes())?;
    Ok(CpuLatencyRequest { _file: file })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_latency_request_writes_the_kernel_s_binary_value_and_holds_the_file() {
        let dir = tempfile::tempdir().unwrap();
        let device = dir.path().join("cpu_dma_latency");
        std::fs::write(&device, b"").unwrap();
        let request = request_cpu_latency(&device, 20).unwrap();
        assert_eq!(std::fs::read(&device).unwrap(), 20i32.to_ne_bytes());
        drop(request);
        let missing = request_cpu_latency(&dir.path().join("absent"), 0).unwrap_err();
        assert_eq!(missing.kind(), io::ErrorKind::NotFound);
    }
}
