//! The simulated lab renders one frame per 60 Hz tick: once a frame of a size has been
//! drawn, `Renderer::render_into` must not allocate. A counting global allocator counts
//! allocations on this test's thread while it renders.
use std::alloc::{GlobalAlloc, Layout, System};
use std::cell::Cell;
use std::sync::atomic::{AtomicU64, Ordering};

use image::GrayImage;
use nanoforce::scene::{FrameSpec, Renderer, Style};

thread_local! {
    static COUNTING: Cell<bool> = const { Cell::new(false) };
}
static ALLOCATIONS: AtomicU64 = AtomicU64::new(0);

struct Counting;

// SAFETY: forwards to the system allocator; only counts.
unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        if COUNTING.with(Cell::get) {
            ALLOCATIONS.fetch_add(1, Ordering::Relaxed);
        }
        // SAFETY: same contract as ours.
        unsafe { System.alloc(layout) }
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        // SAFETY: same contract as ours.
        unsafe { System.dealloc(ptr, layout) }
    }
}

#[global_allocator]
static GLOBAL: Counting = Counting;

#[test]
fn rendering_into_a_reused_frame_allocates_nothing_after_warm_up() {
    let mut renderer = Renderer::new();
    let mut frame = GrayImage::new(640, 480);
    let spec = |k: usize| {
        let mut spec = FrameSpec::new(Style::ALL[k % 4], -20.0 + 3.3 * (k % 13) as f64, k as u64);
        spec.magnification = [1000.0, 2000.0, 5000.0, 8000.0][k % 4];
        spec.look.particles = 10 + (k % 3) as u32 * 12;
        spec
    };
    // Warm up: the first frame sizes the buffers.
    renderer.render_into(&spec(1000), &mut frame);
    COUNTING.with(|c| c.set(true));
    for k in 0..24 {
        renderer.render_into(&spec(k), &mut frame);
    }
    COUNTING.with(|c| c.set(false));
    assert_eq!(ALLOCATIONS.load(Ordering::Relaxed), 0);
}
