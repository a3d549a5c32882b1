//! The daemon's one clock: seconds on CLOCK_MONOTONIC since the daemon started. Frame
//! timestamps (V4L2 kernel timestamps are CLOCK_MONOTONIC too), estimates and haptic
//! ticks are all on it, so ages and latencies are differences of plain numbers.

/// Monotonic seconds since an epoch taken at construction. Cheap to copy and share.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Clock {
    epoch_ns: u64,
}

impl Clock {
    /// A clock whose zero is now.
    pub fn start() -> Self {
        Clock {
            epoch_ns: monotonic_ns(),
        }
    }

    /// Seconds since the epoch.
    pub fn now_s(&self) -> f64 {
        self.seconds_at(monotonic_ns())
    }

    /// Seconds since the epoch of an absolute CLOCK_MONOTONIC time in nanoseconds.
    pub fn seconds_at(&self, monotonic_ns: u64) -> f64 {
        (monotonic_ns as i128 - self.epoch_ns as i128) as f64 * 1e-9
    }

    /// The absolute CLOCK_MONOTONIC nanoseconds of a time on this clock.
    pub fn monotonic_ns_at(&self, seconds: f64) -> u64 {
        (self.epoch_ns as i128 + (seconds * 1e9).round() as i128).max(0) as u64
    }

    /// `seconds` held to the whole nanosecond a recording stores it as: what a replay
    /// of the recorded frame reads back, to the last bit.
    pub fn to_whole_ns(&self, seconds: f64) -> f64 {
        self.seconds_at(self.monotonic_ns_at(seconds))
    }
}

/// CLOCK_MONOTONIC in nanoseconds.
pub fn monotonic_ns() -> u64 {
    let mut ts = libc::timespec {
        tv_sec: 0,
        tv_nsec: 0,
    };
    // SAFETY: clock_gettime writes into the timespec we own; CLOCK_MONOTONIC always exists.
    unsafe { libc::clock_gettime(libc::CLOCK_MONOTONIC, &mut ts) };
    ts.tv_sec as u64 * 1_000_000_000 + ts.tv_nsec as u64
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
    fn monotonic_and_convertible() {
        let clock = Clock::start();
        let a = clock.now_s();
        std::thread::sleep(std::time::Duration::from_millis(2));
        let b = clock.now_s();
        assert!(a >= 0.0 && b - a >= 0.002, "{a} {b}");
        let ns = clock.monotonic_ns_at(b);
        assert!((clock.seconds_at(ns) - b).abs() < 1e-9);
    }
}
