//! Real-time helpers for the haptic loop thread: SCHED_FIFO priority, locked memory, a
//! limit on CPU wake-up latency, and sleeping until an absolute CLOCK_MONOTONIC deadline.
//! Each may be refused (no CAP_SYS_NICE / RLIMIT_RTPRIO, RLIMIT_MEMLOCK, no access to
//! /dev/cpu_dma_latency): the caller logs a warning and goes on.
use std::fs::File;
use std::io::{self, Write};
use std::path::Path;

use crate::hw::clock::monotonic_ns;

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

/// Sleeps until the absolute CLOCK_MONOTONIC time `deadline_ns`, then spins the last
/// `spin_ns` for a precise wake-up (the kernel's timer slack and scheduling latency
/// are tens of microseconds on a loaded machine without SCHED_FIFO).
pub fn sleep_until(deadline_ns: u64, spin_ns: u64) {
    let sleep_to = deadline_ns.saturating_sub(spin_ns);
    if monotonic_ns() < sleep_to {
        let ts = libc::timespec {
            tv_sec: (sleep_to / 1_000_000_000) as libc::time_t,
            tv_nsec: (sleep_to % 1_000_000_000) as libc::c_long,
        };
        loop {
            // SAFETY: absolute sleep on CLOCK_MONOTONIC; `ts` outlives the call and the
            // remainder pointer may be null with TIMER_ABSTIME.
            let rc = unsafe {
                libc::clock_nanosleep(
                    libc::CLOCK_MONOTONIC,
                    libc::TIMER_ABSTIME,
                    &ts,
                    std::ptr::null_mut(),
                )
            };
            if rc != libc::EINTR {
                break;
            }
        }
    }
    while monotonic_ns() < deadline_ns {
        std::hint::spin_loop();
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn wakes_at_the_deadline_not_before() {
        for _ in 0..20 {
            let deadline = monotonic_ns() + 1_000_000;
            sleep_until(deadline, 50_000);
            let late = monotonic_ns() - deadline;
            assert!(late < 20_000_000, "woke {late} ns late");
        }
        let past = monotonic_ns() - 1_000_000;
        sleep_until(past, 0);
    }

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
