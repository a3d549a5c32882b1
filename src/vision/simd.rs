//! Vector instructions chosen at run time for the tracker's hot loops.
//!
//! The build targets plain x86-64 (SSE2), so the binary runs on any lab PC; a CPU with
//! AVX2 runs a second copy of each hot loop compiled for it. Both copies are compiled
//! from the same source (the loop body is `#[inline(always)]`, the copy only changes
//! which instructions carry it), and neither lets the compiler fuse a multiply and an
//! add (no FMA), so they compute the same results to the bit: an estimate does not
//! depend on the CPU it ran on. The CPU is asked once; [`set_avx2`] turns the AVX2 copies
//! off (to compare both, or to rule them out on a suspect machine).

use std::sync::atomic::{AtomicU8, Ordering};

/// Not asked yet, then whether the AVX2 copies run.
const UNKNOWN: u8 = 0;
const PORTABLE: u8 = 1;
const AVX2: u8 = 2;
static CHOICE: AtomicU8 = AtomicU8::new(UNKNOWN);

/// Whether this CPU runs AVX2.
fn cpu_has_avx2() -> bool {
    #[cfg(target_arch = "x86_64")]
    {
        std::is_x86_feature_detected!("avx2")
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        false
    }
}

/// Whether the hot loops run their AVX2 copies (the CPU has it, and it is not off).
#[inline]
#[cfg_attr(not(target_arch = "x86_64"), allow(dead_code))]
pub fn avx2() -> bool {
    match CHOICE.load(Ordering::Relaxed) {
        UNKNOWN => {
            let on = cpu_has_avx2();
            CHOICE.store(if on { AVX2 } else { PORTABLE }, Ordering::Relaxed);
            on
        }
        choice => choice == AVX2,
    }
}

/// Lets the hot loops use AVX2 when the CPU has it (`true`, the default) or keeps them
/// on the portable copies (`false`); returns whether the AVX2 copies now run. The
/// results are the same either way, only the time differs.
pub fn set_avx2(on: bool) -> bool {
    let on = on && cpu_has_avx2();
    CHOICE.store(if on { AVX2 } else { PORTABLE }, Ordering::Relaxed);
    on
}

/// Defines `fn $name(args) -> ret` that runs `$body(args)` (an `#[inline(always)]`
/// function) compiled for AVX2 when [`avx2`] says so, and as built otherwise.
macro_rules! dispatch {
    ($(#[$meta:meta])* $vis:vis fn $name:ident($($arg:ident: $ty:ty),* $(,)?) $(-> $ret:ty)?
        => $body:path) => {
        $(#[$meta])*
        $vis fn $name($($arg: $ty),*) $(-> $ret)? {
            #[cfg(target_arch = "x86_64")]
            {
                #[target_feature(enable = "avx2")]
                fn with_avx2($($arg: $ty),*) $(-> $ret)? {
                    $body($($arg),*)
                }
                if $crate::vision::simd::avx2() {
                    // SAFETY: the CPU runs AVX2 (asked at run time).
                    return unsafe { with_avx2($($arg),*) };
                }
            }
            $body($($arg),*)
        }
    };
}
pub(crate) use dispatch;
