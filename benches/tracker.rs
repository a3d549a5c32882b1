//! Tracking alone (decoded 8-bit frame in, estimate out), single thread.
//!
//! - `track/<size>/<frame>`: rendered frames of the typical probe at both frame sizes
//!   (a busy low-magnification frame, a mid one, a high-magnification one, a blank one)
//!   and a public sample frame;
//! - `window/<deg>`: the same 640x480 frame for a Hough window of 10, 20 and 40 deg;
//! - `clutter/<scratches>`: the same frame with more and more clutter;
//! - `probes/<size>/<n>-of-<count>`: two probes at 640x480 and four at 1024x768 in
//!   one view, and the first of them alone on the same frames;
//! - `rigid/<kind>`: a rigid probe of named edges (needle, tipless cantilever, gripper
//!   jaw), each frame searched whole, over eight frames of its tool suite, and
//!   `rigid/<kind>-absent` over eight frames of another kind's (every placement
//!   refused);
//! - `probes/tool-beside-cantilever/<kind>`: a rigid tool beside an AFM cantilever,
//!   both tracked, `<kind>-out-of-view` with the tool out of view, and each on two
//!   threads (`-two-threads`);
//! - `realbg/faded-faces`: the 50 frames of a real-background session whose faces
//!   fade into a bright textured ground under noise 30-48
//!   (`scene::real_suite(13, 12, 50, crops)[10]`), per frame: the frames where the
//!   scale is found from the beam edge itself.
//!
//! `cargo bench --bench tracker`; docs/tracker.md records the numbers.
use std::path::Path;

use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion, Throughput};
use image::GrayImage;
use nanoforce::config::{Config, TrackerConfig};
use nanoforce::scene::{
    self, render_tool_into, tool_suite, Entry, FrameSpec, ProbeGeometry, Session, Setup, Style,
    ToolKind, ToolSession,
};
use nanoforce::vision::{calibrate_rigid, Calibration, Estimate, ProbeSet, RigidTracker, Tracker};

/// A session of the typical probe at `width`, calibrated, with the given frames.
fn tracker_for(width: u32, window_deg: f64) -> (Setup, Tracker) {
    let setup = Setup {
        probe: ProbeGeometry::typical(),
        width,
        height: width * 3 / 4,
        entry: Entry::Left,
        base_deg: -18.0,
    };
    let session = Session::mixed_for(&setup, 11, 1);
    let cfg = TrackerConfig {
        window_deg,
        ..session.tracker_config_of(0)
    };
    let (reference, _) = scene::render(&session.reference);
    let cal =
        Calibration::from_reference(&reference, cfg.calibration.as_ref().expect("clicks"), &cfg)
            .expect("the rendered reference calibrates");
    let mut tracker = Tracker::new(&cfg, cal, Some(setup.probe.cantilever()));
    tracker.set_coherence(false);
    (setup, tracker)
}

fn frame(setup: &Setup, style: Style, mag: f64, angle: f64, blank: bool) -> GrayImage {
    let mut spec: FrameSpec = setup.frame(style, angle, mag, 77);
    spec.apex_px = [0.5 * setup.width as f64, 0.55 * setup.height as f64];
    spec.blank = blank;
    scene::render(&spec).0
}

fn bench_sizes(c: &mut Criterion) {
    let mut group = c.benchmark_group("track");
    for width in [640u32, 1280] {
        let (setup, mut tracker) = tracker_for(width, 20.0);
        let size = format!("{}x{}", width, width * 3 / 4);
        for (name, style, mag, blank) in [
            ("clutter-1000x", Style::Clutter, 1000.0, false),
            ("noisy-2000x", Style::Noisy, 2000.0, false),
            ("harsh-3500x", Style::Harsh, 3500.0, false),
            ("clean-8000x", Style::Clean, 8000.0, false),
            ("blank", Style::Clutter, 2000.0, true),
        ] {
            let img = frame(&setup, style, mag, 12.0, blank);
            assert_eq!(tracker.track(&img).detected, !blank, "{size} {name}");
            group.bench_with_input(BenchmarkId::new(&size, name), &img, |b, img| {
                b.iter(|| tracker.track(img))
            });
        }
    }
    // A public sample frame as recorded.
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/samples/mixed");
    let config = Config::load(&dir.join("probe.toml")).expect("sample config");
    let clicks = config.probes[0]
        .tracker
        .calibration
        .clone()
        .expect("calibration");
    let reference = image::open(&clicks.reference_image)
        .expect("reference")
        .to_luma8();
    let cal = Calibration::from_reference(&reference, &clicks, &config.probes[0].tracker)
        .expect("calibrates");
    let mut tracker = Tracker::new(&config.probes[0].tracker, cal, config.probes[0].cantilever);
    tracker.set_coherence(false);
    let img = image::open(dir.join("frames/frame_00001.png"))
        .expect("frame")
        .to_luma8();
    assert!(tracker.track(&img).detected);
    group.bench_with_input(
        BenchmarkId::new("640x480", "sample-mixed-1"),
        &img,
        |b, img| b.iter(|| tracker.track(img)),
    );
    group.finish();
}

fn bench_window(c: &mut Criterion) {
    let mut group = c.benchmark_group("window");
    for window in [10.0, 20.0, 40.0] {
        let (setup, mut tracker) = tracker_for(640, window);
        let img = frame(&setup, Style::Noisy, 2000.0, 8.0, false);
        assert!(tracker.track(&img).detected);
        group.bench_with_input(BenchmarkId::from_parameter(window), &img, |b, img| {
            b.iter(|| tracker.track(img))
        });
    }
    group.finish();
}

fn bench_clutter(c: &mut Criterion) {
    let mut group = c.benchmark_group("clutter");
    let (setup, mut tracker) = tracker_for(640, 20.0);
    for scratches in [0u32, 5, 20] {
        let mut spec = setup.frame(Style::Clutter, 8.0, 2000.0, 78);
        spec.apex_px = [320.0, 264.0];
        spec.look.scratches = scratches;
        spec.look.particles = 4 * scratches;
        let img = scene::render(&spec).0;
        assert!(tracker.track(&img).detected);
        group.bench_with_input(BenchmarkId::from_parameter(scratches), &img, |b, img| {
            b.iter(|| tracker.track(img))
        });
    }
    group.finish();
}

/// `probes/<size>/<n>-of-<count>[-two-threads]`: several probes in one view
/// (`ProbeSet`): the first probe alone and all `count` (on one thread, and on two),
/// per frame over eight frames of mixed looks with every probe in view.
fn bench_probes(c: &mut Criterion) {
    let mut group = c.benchmark_group("probes");
    for (count, width, height) in [(2usize, 640u32, 480u32), (4, 1024, 768)] {
        let session = Session::several(3, count, 40, width, height);
        let frames: Vec<GrayImage> = session
            .frames
            .iter()
            .filter(|f| (0..count).all(|k| f.nth_probe(k).is_some_and(|p| !p.blank)))
            .take(8)
            .map(|f| scene::render(f).0)
            .collect();
        group.throughput(Throughput::Elements(frames.len() as u64));
        // The first probe alone on the same frames, then all of them on one thread,
        // then on two (as the daemon tracks them).
        for (n, threads) in [(1, 1), (count, 1), (count, 2)] {
            let mut trackers = session
                .trackers()
                .expect("the rendered reference calibrates");
            trackers.truncate(n);
            trackers.iter_mut().for_each(|t| t.set_coherence(false));
            let mut set = ProbeSet::new(trackers, &vec![0; n]);
            if threads == 2 {
                set = set.on_two_threads().expect("a second thread starts");
            }
            let mut out = vec![Estimate::default(); n];
            let name = match threads {
                1 => format!("{n}-of-{count}"),
                _ => format!("{n}-of-{count}-two-threads"),
            };
            let name = BenchmarkId::new(format!("{width}x{height}"), name);
            group.bench_function(name, |b| {
                b.iter(|| {
                    for f in &frames {
                        set.track(f, &mut out);
                    }
                })
            });
        }
    }
}

/// `probes/tool-beside-cantilever/<kind>[-out-of-view][-two-threads]`: a rigid tool
/// and an AFM cantilever in one view (`Session::tool_beside_a_cantilever(kind, 3,
/// 60)`), both in view, or the tool out of view (searched again without the
/// cantilever's body), on eight frames each, each frame searched whole, on one thread
/// or on two (as the daemon tracks them).
fn bench_tool_beside_cantilever(c: &mut Criterion) {
    let mut group = c.benchmark_group("probes/tool-beside-cantilever");
    for kind in ToolKind::ALL {
        let session = Session::tool_beside_a_cantilever(kind, 3, 60);
        for tool_in_view in [true, false] {
            let frames: Vec<GrayImage> = session
                .frames
                .iter()
                .filter(|f| f.blank != tool_in_view && f.others.iter().all(|o| !o.blank))
                .take(8)
                .map(|f| scene::render(f).0)
                .collect();
            group.throughput(Throughput::Elements(frames.len() as u64));
            for threads in [1, 2] {
                let mut trackers = session
                    .trackers()
                    .expect("the rendered reference calibrates");
                trackers.iter_mut().for_each(|t| t.set_coherence(false));
                let mut set = ProbeSet::new(trackers, &[0, 0]);
                if threads == 2 {
                    set = set.on_two_threads().expect("a second thread starts");
                }
                let mut out = vec![Estimate::default(); 2];
                let view = if tool_in_view { "" } else { "-out-of-view" };
                let on = if threads == 2 { "-two-threads" } else { "" };
                group.bench_function(format!("{}{view}{on}", kind.name()), |b| {
                    b.iter(|| {
                        for f in &frames {
                            set.track(f, &mut out);
                        }
                    })
                });
            }
        }
    }
}

/// `rigid/<kind>`: a rigid probe searched whole in each of eight frames of the first
/// sessions of its tool suite (synthetic backgrounds), per frame;
/// `rigid/<kind>-absent`: the same tracker on eight frames of the next kind's suite,
/// none of which shows its probe (every placement fitted and refused).
fn bench_rigid(c: &mut Criterion) {
    let mut group = c.benchmark_group("rigid");
    let render = |session: &ToolSession| -> Vec<GrayImage> {
        session
            .frames
            .iter()
            .filter(|f| !f.blank)
            .map(|f| {
                let mut g = GrayImage::new(1, 1);
                render_tool_into(f, &[], &mut g);
                g
            })
            .collect()
    };
    for (k, kind) in ToolKind::ALL.into_iter().enumerate() {
        let sessions = tool_suite(kind, 41, 2, 8, 0);
        let session = &sessions[0];
        let mut frame = GrayImage::new(1, 1);
        render_tool_into(&session.reference, &[], &mut frame);
        let clicks: Vec<(String, Vec<[f64; 2]>)> = session
            .clicks
            .iter()
            .map(|(n, p)| (n.to_string(), p.clone()))
            .collect();
        let template = calibrate_rigid(&frame, &clicks, session.apex).expect("calibrates");
        let mut tracker = RigidTracker::new(template, 20.0);
        let frames = render(session);
        group.throughput(Throughput::Elements(frames.len() as u64));
        group.bench_function(kind.name(), |b| {
            b.iter(|| {
                for f in &frames {
                    tracker.track(f);
                }
            })
        });
        let next = ToolKind::ALL[(k + 1) % ToolKind::ALL.len()];
        let absent = render(&tool_suite(next, 41, 2, 8, 0)[0]);
        group.throughput(Throughput::Elements(absent.len() as u64));
        group.bench_function(format!("{}-absent", kind.name()), |b| {
            b.iter(|| {
                for f in &absent {
                    tracker.track(f);
                }
            })
        });
    }
}

/// The real SEM crops of `tests/data/real-sem`, in name order.
fn real_crops() -> Vec<GrayImage> {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/real-sem");
    let mut paths: Vec<_> = std::fs::read_dir(&dir)
        .expect("tests/data/real-sem")
        .map(|e| e.expect("a directory entry").path())
        .filter(|p| p.extension().is_some_and(|x| x == "png"))
        .collect();
    paths.sort();
    paths
        .iter()
        .map(|p| image::open(p).expect("a crop").to_luma8())
        .collect()
}

/// `realbg/faded-faces`: a whole real-background session, per frame.
fn bench_realbg(c: &mut Criterion) {
    let mut group = c.benchmark_group("realbg");
    let crops = real_crops();
    let session = &scene::real_suite(13, 12, 50, crops.len())[10];
    let cfg = session.tracker_config_of(0);
    let mut reference = GrayImage::new(1, 1);
    scene::render_over_into(&session.reference, &crops, &mut reference);
    let cal =
        Calibration::from_reference(&reference, cfg.calibration.as_ref().expect("clicks"), &cfg)
            .expect("the reference calibrates");
    let mut tracker = Tracker::new(&cfg, cal, Some(session.probe().cantilever()));
    tracker.set_coherence(false);
    let frames: Vec<GrayImage> = session
        .frames
        .iter()
        .map(|spec| {
            let mut frame = GrayImage::new(1, 1);
            scene::render_over_into(spec, &crops, &mut frame);
            frame
        })
        .collect();
    group.throughput(Throughput::Elements(frames.len() as u64));
    group.bench_function("faded-faces", |b| {
        b.iter(|| {
            for f in &frames {
                tracker.track(f);
            }
        })
    });
    group.finish();
}

criterion_group!(
    benches,
    bench_sizes,
    bench_window,
    bench_clutter,
    bench_probes,
    bench_rigid,
    bench_tool_beside_cantilever,
    bench_realbg
);
criterion_main!(benches);
