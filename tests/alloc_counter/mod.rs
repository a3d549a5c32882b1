//! The counting global allocator of the allocation-free tests. It forwards everything to
//! the system allocator and counts the allocations and reallocations made by threads
//! that called [`watch_this_thread`] or carry the name given to [`watch_threads_named`],
//! between [`start`] and [`stop`]. A test binary
//! installs it with
//!
//! ```text
//! mod alloc_counter;
//! #[global_allocator]
//! static GLOBAL: alloc_counter::Counting = alloc_counter::Counting;
//! ```
use std::alloc::{GlobalAlloc, Layout, System};
use std::cell::Cell;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::OnceLock;

thread_local! {
    static WATCHED: Cell<bool> = const { Cell::new(false) };
}
static COUNTING: AtomicBool = AtomicBool::new(false);
static ALLOCATIONS: AtomicU64 = AtomicU64::new(0);
static WATCHED_NAME: OnceLock<&'static str> = OnceLock::new();

/// Counts allocations on watched threads while counting is on.
pub struct Counting;

/// Allocations on this thread count from now on (while counting is on).
pub fn watch_this_thread() {
    WATCHED.with(|w| w.set(true));
}

/// Allocations on threads named `name` count too (threads the code under test starts
/// for itself); one name per test binary.
#[allow(dead_code)]
pub fn watch_threads_named(name: &'static str) {
    let set = WATCHED_NAME.get_or_init(|| name);
    assert_eq!(*set, name, "one watched thread name per test binary");
}

/// Whether this thread's name is the watched one, read from the kernel (no allocation,
/// so it can run inside the allocator).
fn named_watched() -> bool {
    let Some(name) = WATCHED_NAME.get() else {
        return false;
    };
    let mut buf = [0u8; 16];
    // SAFETY: PR_GET_NAME writes at most 16 bytes, NUL included, into `buf`.
    if unsafe { libc::prctl(libc::PR_GET_NAME, buf.as_mut_ptr()) } != 0 {
        return false;
    }
    let len = buf.iter().position(|&b| b == 0).unwrap_or(buf.len());
    // The kernel keeps 15 bytes of a name.
    let want = &name.as_bytes()[..name.len().min(15)];
    &buf[..len] == want
}

/// Resets the count and starts counting.
pub fn start() {
    ALLOCATIONS.store(0, Ordering::SeqCst);
    COUNTING.store(true, Ordering::SeqCst);
}

/// Stops counting; the allocations counted since [`start`].
pub fn stop() -> u64 {
    COUNTING.store(false, Ordering::SeqCst);
    ALLOCATIONS.load(Ordering::SeqCst)
}

fn count() {
    // `try_with`: a thread being torn down may still free (and allocate) memory.
    if COUNTING.load(Ordering::Relaxed)
        && (WATCHED.try_with(Cell::get).unwrap_or(false) || named_watched())
    {
        ALLOCATIONS.fetch_add(1, Ordering::Relaxed);
    }
}

// SAFETY: forwards every call to the system allocator unchanged; only counts.
unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        count();
        // SAFETY: same contract as ours.
        unsafe { System.alloc(layout) }
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        // SAFETY: same contract as ours.
        unsafe { System.dealloc(ptr, layout) }
    }
    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        count();
        // SAFETY: same contract as ours.
        unsafe { System.realloc(ptr, layout, new_size) }
    }
}
