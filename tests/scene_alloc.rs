//! The simulated lab renders one frame per 60 Hz tick: once a frame of a size has been
//! drawn, `Renderer::render_into` must not allocate. A counting global allocator counts
//! allocations on this test's thread while it renders.
use image::GrayImage;
use nanoforce::scene::{FrameSpec, Renderer, Style};

mod alloc_counter;

#[global_allocator]
static GLOBAL: alloc_counter::Counting = alloc_counter::Counting;

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
    alloc_counter::watch_this_thread();
    alloc_counter::start();
    for k in 0..24 {
        renderer.render_into(&spec(k), &mut frame);
    }
    assert_eq!(alloc_counter::stop(), 0);
}
