//! Generators of whole sessions, deterministic from a seed: random-order mixed sets like
//! the public `mixed` sample, time sequences like `sequence` (an operator pressing and
//! releasing, magnification jumps, the probe now and then out of view), and the test
//! suite that spans every condition of docs/renderer.md for the tracker's accuracy tests.

use super::geometry::{probe_outline, Entry};
use super::rng::{sub_seed, Rng};
use super::session::{Session, Setup, FRAME_RATE_HZ, MAGNIFICATIONS};
use super::spec::{FrameSpec, Look, Others, Placement, Style};
use super::tool::tool_outline;
use super::tool_shape::{ToolGeometry, ToolKind};
use crate::vision::{Threshold, DEFAULT_WINDOW_DEG};

/// Share of each style in mixed sets (as in the public `mixed` sample).
const STYLE_WEIGHTS: [(Style, f64); 4] = [
    (Style::Clean, 0.2),
    (Style::Clutter, 0.2),
    (Style::Noisy, 0.37),
    (Style::Harsh, 0.23),
];
/// Share of blank frames (no probe in view) in generated sessions.
pub const BLANK_FRACTION: f64 = 0.05;

/// A style's look with per-frame counts and levels drawn around the preset.
pub fn varied_look(style: Style, rng: &mut Rng) -> Look {
    let mut look = style.look();
    let (particles, scratches) = match style {
        Style::Clean => ((1, 4), (0, 0)),
        Style::Clutter => ((6, 14), (3, 7)),
        Style::Noisy => ((2, 7), (0, 2)),
        Style::Harsh => ((14, 24), (4, 8)),
    };
    look.particles = rng.int(particles.0, particles.1);
    look.scratches = rng.int(scratches.0, scratches.1);
    look.substrate = look.substrate.map(|level| level + rng.uniform(-12.0, 12.0));
    look.background += rng.uniform(-3.0, 3.0);
    look
}

/// A frame of `setup` with a random apex placement, substrate and look.
pub fn random_frame(
    setup: &Setup,
    style: Style,
    magnification: f64,
    angle_deg: f64,
    rng: &mut Rng,
) -> FrameSpec {
    let mut spec = setup.frame(style, angle_deg, magnification, rng.next_u64());
    spec.look = varied_look(style, rng);
    spec.apex_px = random_apex(setup, rng);
    // The public samples keep the substrate within a few dozen pixels of the apex at
    // every magnification.
    let gap_px = rng.uniform(-25.0, 57.0) * f64::from(setup.width) / 640.0;
    spec.substrate_gap_um = gap_px / spec.px_per_um();
    spec.substrate_tilt_deg = rng.uniform(-6.0, 6.0);
    spec.blank = rng.chance(BLANK_FRACTION);
    spec
}

fn random_apex(setup: &Setup, rng: &mut Rng) -> [f64; 2] {
    [
        rng.uniform(0.22, 0.78) * f64::from(setup.width),
        rng.uniform(0.23, 0.8) * f64::from(setup.height),
    ]
}

fn pick_style(rng: &mut Rng) -> Style {
    let mut u = rng.unit();
    for (style, weight) in STYLE_WEIGHTS {
        if u < weight {
            return style;
        }
        u -= weight;
    }
    Style::Harsh
}

/// Mostly uniform in +-20 deg, with the round values an experimenter sets by hand.
fn pick_angle(rng: &mut Rng) -> f64 {
    if rng.chance(0.3) {
        [0.0, 5.0, -5.0, 20.0, -20.0][rng.int(0, 4) as usize]
    } else {
        rng.uniform(-20.0, 20.0)
    }
}

impl Session {
    /// `n` frames of one random probe in random order: magnifications, angles, styles,
    /// apex placements and blank frames all mixed (like the public `mixed` sample).
    pub fn mixed(seed: u64, n: usize, width: u32, height: u32) -> Session {
        let setup = Setup::random(sub_seed(seed, 1), width, height);
        Session::mixed_for(&setup, seed, n)
    }

    /// Like [`Session::mixed`] for a given setup.
    pub fn mixed_for(setup: &Setup, seed: u64, n: usize) -> Session {
        let mut rng = Rng::new(sub_seed(seed, 2));
        let frames = (0..n)
            .map(|_| {
                let style = pick_style(&mut rng);
                let mag = MAGNIFICATIONS[rng.int(0, 5) as usize];
                let angle = pick_angle(&mut rng);
                random_frame(setup, style, mag, angle, &mut rng)
            })
            .collect();
        Session {
            reference: setup.reference(seed),
            frames,
            times_s: (0..n).map(|k| k as f64 / FRAME_RATE_HZ).collect(),
            threshold: Threshold::Otsu,
            window_deg: DEFAULT_WINDOW_DEG,
            click_seed: sub_seed(seed, 3),
        }
    }

    /// `n` frames at 60 Hz of an operator pressing and releasing (the angle follows a
    /// sine of amplitude 12-20 deg), the probe drifting slowly, jumping when the
    /// magnification changes, and now and then out of view (like `sequence`).
    pub fn sequence(seed: u64, n: usize, width: u32, height: u32) -> Session {
        let setup = Setup::random(sub_seed(seed, 1), width, height);
        let mut rng = Rng::new(sub_seed(seed, 2));
        let style = pick_style(&mut rng);
        let amplitude = rng.uniform(12.0, 20.0);
        let period = rng.uniform(36.0, 60.0);
        let mut mag = MAGNIFICATIONS[rng.int(1, 3) as usize];
        let mut apex = random_apex(&setup, &mut rng);
        let mut blank_left = 0u32;
        let mut frames = Vec::with_capacity(n);
        for k in 0..n {
            let angle = amplitude * (std::f64::consts::TAU * k as f64 / period).sin();
            if k > 0 && rng.chance(0.06) {
                mag = MAGNIFICATIONS[rng.int(0, 5) as usize];
                apex = random_apex(&setup, &mut rng);
            } else {
                apex = drift(&setup, apex, &mut rng);
            }
            if blank_left == 0 && rng.chance(0.015) {
                blank_left = rng.int(1, 4);
            }
            let mut spec = random_frame(&setup, style, mag, angle, &mut rng);
            spec.apex_px = apex;
            spec.blank = blank_left > 0;
            blank_left = blank_left.saturating_sub(1);
            frames.push(spec);
        }
        let look = style.look();
        Session {
            reference: setup.reference(seed),
            frames,
            times_s: (0..n).map(|k| k as f64 / FRAME_RATE_HZ).collect(),
            threshold: Threshold::Level((0.5 * (look.background + look.probe)).round() as u8),
            window_deg: DEFAULT_WINDOW_DEG,
            click_seed: sub_seed(seed, 3),
        }
    }
}

/// Where each probe of a view of several sits: its entry side and the ranges of its
/// apex (fractions of width and height). Two probes face each other across the frame
/// (two cantilevers squeezing an object); three or four add a row: each probe's body
/// stays within its own quarter (the pyramid hangs above its apex's row), so no probe
/// covers another.
const SLOTS: [(Entry, [f64; 2], [f64; 2]); 4] = [
    (Entry::Left, [0.25, 0.32], [0.35, 0.42]),
    (Entry::Right, [0.68, 0.75], [0.35, 0.42]),
    (Entry::Left, [0.25, 0.32], [0.78, 0.85]),
    (Entry::Right, [0.68, 0.75], [0.78, 0.85]),
];
/// The vertical range of two probes' apexes (one row, mid-frame).
const PAIR_ROW: [f64; 2] = [0.4, 0.6];
/// Magnifications of a view of several probes: low enough that each body stays in
/// its quarter.
const SEVERAL_MAGNIFICATIONS: [f64; 3] = [1000.0, 1500.0, 2000.0];
/// Base tilts and tip angles of a view of several probes, degrees: each beam stays in
/// its row.
const SEVERAL_BASE_DEG: f64 = 10.0;
const SEVERAL_ANGLE_DEG: f64 = 15.0;

impl Session {
    /// `n` frames of `count` probes (2 to 4, each its own random geometry) in one view,
    /// in random order: each probe at its own angle, placement and out of view at
    /// random ([`BLANK_FRACTION`]), every style mixed. Probe 1 is the frame's own, the
    /// others its [`FrameSpec::others`]; the files are named as
    /// [`Session::probe_names`].
    pub fn several(seed: u64, count: usize, n: usize, width: u32, height: u32) -> Session {
        Session::several_of(seed, &vec![None; count], n, width, height)
    }

    /// As [`Session::several`], probe `k` drawn as `tools[k]` where that is a tool
    /// (kept clear of the others by its own outline) and as a cantilever where not.
    pub fn several_of(
        seed: u64,
        tools: &[Option<ToolGeometry>],
        n: usize,
        width: u32,
        height: u32,
    ) -> Session {
        let count = tools.len();
        assert!((2..=SLOTS.len()).contains(&count), "2 to 4 probes");
        let mut rng = Rng::new(sub_seed(seed, 5));
        let setups: Vec<(Setup, [f64; 2], [f64; 2])> = SLOTS[..count]
            .iter()
            .enumerate()
            .map(|(k, &(entry, xs, ys))| {
                let mut setup = Setup::random(sub_seed(seed, 20 + k as u64), width, height);
                setup.entry = entry;
                setup.base_deg = rng.uniform(-SEVERAL_BASE_DEG, SEVERAL_BASE_DEG);
                (setup, xs, if count == 2 { PAIR_ROW } else { ys })
            })
            .collect();
        let place = |k: usize, angle: f64, rng: &mut Rng| {
            let (setup, xs, ys) = &setups[k];
            Placement {
                probe: setup.probe,
                entry: setup.entry,
                base_deg: setup.base_deg,
                angle_deg: angle,
                apex_px: [
                    rng.uniform(xs[0], xs[1]) * f64::from(width),
                    rng.uniform(ys[0], ys[1]) * f64::from(height),
                ],
                blank: rng.chance(BLANK_FRACTION),
                tool: tools[k],
            }
        };
        let with = |spec: FrameSpec, places: &[Placement]| FrameSpec {
            others: Others::of(&places[1..]),
            ..spec.placing(places[0])
        };
        let mut outline = Vec::new();
        let frames = (0..n)
            .map(|_| {
                let style = pick_style(&mut rng);
                let mag = SEVERAL_MAGNIFICATIONS[rng.int(0, 2) as usize];
                // The frame's size and magnification, to measure each placed body.
                let view = FrameSpec {
                    width,
                    height,
                    magnification: mag,
                    ..FrameSpec::new(style, 0.0, 0)
                };
                let mut places: Vec<Placement> = Vec::with_capacity(count);
                for k in 0..count {
                    // Drawn again until its body keeps clear of the others' (a few
                    // tries; the last is out of view).
                    let mut tries = 0;
                    let placed = loop {
                        let angle = rng.uniform(-SEVERAL_ANGLE_DEG, SEVERAL_ANGLE_DEG);
                        let p = place(k, angle, &mut rng);
                        let b = bounds(&view.placing(p), &mut outline);
                        let clear = places.iter().all(|&q| {
                            !bounds(&view.placing(q), &mut outline).meets(&b, SEVERAL_GAP_PX)
                        });
                        tries += 1;
                        if clear || tries == SEVERAL_TRIES {
                            break Placement {
                                blank: p.blank || !clear,
                                ..p
                            };
                        }
                    };
                    places.push(placed);
                }
                let mut spec =
                    random_frame(&setups[0].0, style, mag, places[0].angle_deg, &mut rng);
                if count > 2 {
                    // The sample's edge lies below the first row: the second row's
                    // probes would sit on it.
                    spec.look.substrate = None;
                }
                with(spec, &places)
            })
            .collect();
        let places: Vec<Placement> = (0..count)
            .map(|k| Placement {
                blank: false,
                ..place(k, 0.0, &mut rng)
            })
            .collect();
        let mut reference = with(setups[0].0.reference(seed), &places);
        reference.magnification = SEVERAL_MAGNIFICATIONS[1];
        // A person calibrates on a frame where no particle sits on any tip.
        reference.look.particles = 0;
        Session {
            reference,
            frames,
            times_s: (0..n).map(|k| k as f64 / FRAME_RATE_HZ).collect(),
            threshold: Threshold::Otsu,
            window_deg: DEFAULT_WINDOW_DEG,
            click_seed: sub_seed(seed, 3),
        }
    }
}

/// Share of the frames of [`Session::tool_beside_a_cantilever`] without the tool.
const TOOL_OUT_OF_VIEW: f64 = 0.25;
/// A needle's blunt end there, over a random needle's: the frames' 1000x-2000x show
/// it at 10-30 px.
const NEEDLE_END_ZOOM: f64 = 2.0;
/// Its flanks' bowed span there, micrometres: past the border of every frame.
const LONG_FLANK_UM: f64 = 1000.0;

/// A random tool of `kind` as the views of several probes show it: a needle's end
/// zoomed, its flanks running out of the frame.
fn framed_tool(kind: ToolKind, seed: u64) -> ToolGeometry {
    let mut tool = ToolGeometry::random(kind, seed);
    if kind == ToolKind::Needle {
        tool.end_um *= NEEDLE_END_ZOOM;
    }
    for flank in &mut tool.flanks {
        flank.span_um = LONG_FLANK_UM;
    }
    tool
}

impl Session {
    /// `n` of [`Session::several`]'s two-probe 640x480 frames whose first probe is a
    /// rigid tool of `kind` (its flanks running out of the frame), out of view in
    /// `TOOL_OUT_OF_VIEW` of the frames, beside the second, an AFM cantilever.
    pub fn tool_beside_a_cantilever(kind: ToolKind, seed: u64, n: usize) -> Session {
        let mut session = Session::several(seed, 2, n, 640, 480);
        let tool = framed_tool(kind, sub_seed(seed, 60));
        session.reference.tool = Some(tool);
        let mut rng = Rng::new(sub_seed(seed, 61));
        for frame in &mut session.frames {
            frame.tool = Some(tool);
            frame.blank |= rng.chance(TOOL_OUT_OF_VIEW);
        }
        session
    }

    /// `n` of [`Session::several`]'s two-probe 640x480 frames whose probes are rigid
    /// tools of `kinds` (kept clear of each other by their own outlines), each out of
    /// view in `TOOL_OUT_OF_VIEW` of the frames.
    pub fn two_tools(kinds: [ToolKind; 2], seed: u64, n: usize) -> Session {
        let tools: Vec<Option<ToolGeometry>> = (0..2)
            .map(|k| Some(framed_tool(kinds[k], sub_seed(seed, 60 + k as u64))))
            .collect();
        let mut session = Session::several_of(seed, &tools, n, 640, 480);
        let mut rng = Rng::new(sub_seed(seed, 61));
        for frame in &mut session.frames {
            frame.blank |= rng.chance(TOOL_OUT_OF_VIEW);
            for other in frame.others.iter_mut() {
                other.blank |= rng.chance(TOOL_OUT_OF_VIEW);
            }
        }
        session
    }
}

/// The least gap between two probes' bodies in one view, pixels.
const SEVERAL_GAP_PX: f64 = 12.0;
/// Placements drawn for one probe before it is left out of view.
const SEVERAL_TRIES: usize = 20;

/// The part of the frame a placed probe's body covers (its outline's bounding box
/// within the frame; empty for a probe out of view).
#[derive(Debug, Clone, Copy)]
struct Bounds {
    lo: [f64; 2],
    hi: [f64; 2],
}

impl Bounds {
    /// Whether two bodies come closer than `gap`.
    fn meets(&self, other: &Bounds, gap: f64) -> bool {
        (0..2).all(|i| self.lo[i] - gap <= other.hi[i] && other.lo[i] - gap <= self.hi[i])
    }
}

/// The bounds of `spec`'s own probe.
fn bounds(spec: &FrameSpec, outline: &mut Vec<[f64; 2]>) -> Bounds {
    let empty = Bounds {
        lo: [f64::INFINITY; 2],
        hi: [f64::NEG_INFINITY; 2],
    };
    if spec.blank {
        return empty;
    }
    match &spec.tool {
        Some(tool) => tool_outline(tool, &spec.pose(), spec.width, spec.height, outline),
        None => {
            probe_outline(&spec.probe, &spec.pose(), spec.width, spec.height, outline);
        }
    }
    let (w, h) = (f64::from(spec.width), f64::from(spec.height));
    outline
        .iter()
        .filter(|v| (0.0..=w).contains(&v[0]) && (0.0..=h).contains(&v[1]))
        .fold(empty, |b, v| Bounds {
            lo: [b.lo[0].min(v[0]), b.lo[1].min(v[1])],
            hi: [b.hi[0].max(v[0]), b.hi[1].max(v[1])],
        })
}

/// A few pixels of random drift, kept inside the apex placement range.
fn drift(setup: &Setup, apex: [f64; 2], rng: &mut Rng) -> [f64; 2] {
    let (w, h) = (f64::from(setup.width), f64::from(setup.height));
    [
        (apex[0] + 3.0 * rng.normal()).clamp(0.22 * w, 0.78 * w),
        (apex[1] + 3.0 * rng.normal()).clamp(0.23 * h, 0.8 * h),
    ]
}

/// The tracker's accuracy suite: `sessions` sessions of `frames_per_session` frames
/// each, together spanning every condition of docs/renderer.md: magnification 1000x-8000x
/// (log-uniform), both entry sides (alternating), base orientation within +-35 deg,
/// deflections within +-20 deg, every style in equal shares, blank frames, 640x480 and
/// (every third session) 1280x960, all in random order. Deterministic from `seed`.
pub fn suite(seed: u64, sessions: usize, frames_per_session: usize) -> Vec<Session> {
    (0..sessions)
        .map(|i| {
            let session_seed = sub_seed(seed, 100 + i as u64);
            let (w, h) = if i % 3 == 2 { (1280, 960) } else { (640, 480) };
            let mut setup = Setup::random(session_seed, w, h);
            setup.entry = if i % 2 == 0 {
                Entry::Left
            } else {
                Entry::Right
            };
            let mut session = Session::mixed_for(&setup, session_seed, frames_per_session);
            let mut rng = Rng::new(sub_seed(session_seed, 4));
            for (k, frame) in session.frames.iter_mut().enumerate() {
                let style = Style::ALL[(k + i) % 4];
                let mag = rng.log_uniform(1000.0, 8000.0).round();
                let angle = rng.uniform(-20.0, 20.0);
                *frame = random_frame(&setup, style, mag, angle, &mut rng);
            }
            session
        })
        .collect()
}

/// One condition of the real-background suite, beyond the real background itself.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) enum Condition {
    /// The probe 10-20 grey levels from a quiet background (noise at most 5).
    LowContrast,
    /// A bright background (mean 150-185), its texture 0.3-0.45 of the probe's contrast
    /// (45-70 levels).
    BrightTexture,
    /// The brightness drifting by up to +-30 % over the session.
    Charging,
    /// 5-15 % of the rows shifted by a pixel.
    Jitter,
    /// Noise sigma 30-48 (with a contrast of 60-90 levels).
    HighNoise,
    /// A tapered needle in view.
    Needle,
}

/// The real-background suite's sessions: one or two conditions each (never low
/// contrast with high noise: nobody could see that probe), in this order, each with a
/// brighter and (next session) a darker probe than its background.
const REAL_CONDITIONS: [&[Condition]; 12] = {
    use Condition::*;
    [
        &[LowContrast],
        &[BrightTexture],
        &[Charging],
        &[Jitter],
        &[HighNoise],
        &[Needle],
        &[LowContrast, BrightTexture],
        &[Charging, Needle],
        &[HighNoise, Jitter],
        &[LowContrast, Needle],
        &[BrightTexture, HighNoise],
        &[Charging, Jitter],
    ]
};

/// A session's look over a real background, before the per-frame noise and charging.
#[derive(Debug, Clone, Copy)]
pub(super) struct RealScene {
    pub look: Look,
    /// Range of the frames' noise sigma.
    pub noise: (f64, f64),
    pub charging: bool,
    /// The needle's tilt (degrees) and width (pixels), if one is in view.
    pub needle: Option<(f64, f64)>,
    pub needle_level: f64,
}

pub(super) fn real_scene(
    conditions: &[Condition],
    dark: bool,
    crops: usize,
    rng: &mut Rng,
) -> RealScene {
    use Condition::*;
    let has = |c| conditions.contains(&c);
    let mut look = Style::Clean.look();
    look.style_name = if dark { "real-dark" } else { "real-bright" };
    look.particles = 0;
    look.scratches = 0;
    look.substrate = None;
    look.blur_sigma_px = rng.uniform(0.8, 1.4);
    let mut level = rng.uniform(70.0, 140.0);
    let mut contrast = rng.uniform(35.0, 70.0);
    // The background's texture as a share of the probe's contrast: a person still
    // sees every edge of the probe where the ground's own structures are fainter.
    let mut texture = rng.uniform(0.15, 0.3);
    let mut noise = (4.0, 14.0);
    if has(LowContrast) {
        contrast = rng.uniform(10.0, 20.0);
        texture = rng.uniform(0.1, 0.2);
        noise = (2.0, 5.0);
    }
    if has(BrightTexture) {
        level = rng.uniform(150.0, 185.0);
        if !has(LowContrast) {
            contrast = rng.uniform(45.0, 70.0);
            texture = rng.uniform(0.3, 0.45);
        }
    }
    if has(HighNoise) {
        contrast = rng.uniform(60.0, 90.0);
        noise = (30.0, 48.0);
    }
    if has(Jitter) {
        look.jitter_fraction = rng.uniform(0.05, 0.15);
    }
    // Keep the probe's level on the 8-bit scale.
    level = if dark {
        level.max(contrast + 25.0)
    } else {
        level.min(235.0 - contrast)
    };
    look.real = Some(super::background::RealLook {
        crop: rng.int(0, crops.max(1) as u32 - 1) as usize,
        window_seed: rng.next_u64(),
        zoom: rng.uniform(1.0, 1.6),
        level,
        texture_sigma: texture * contrast,
    });
    look.background = level;
    look.shading = 0.0;
    look.probe = if dark {
        level - contrast
    } else {
        level + contrast
    };
    look.probe_ramp = rng.uniform(-8.0, 8.0);
    let needle = has(Needle).then(|| (rng.uniform(20.0, 70.0), rng.uniform(10.0, 25.0)));
    let needle_level = look.probe + rng.uniform(-10.0, 10.0);
    RealScene {
        look,
        noise,
        charging: has(Charging),
        needle,
        needle_level,
    }
}

/// The needle of `scene` beside the probe of `spec`: its point 70-150 px away from the
/// apex, away from the beam and below it, its base beyond the frame's border.
fn place_needle(scene: &RealScene, spec: &FrameSpec, rng: &mut Rng) -> Option<super::Needle> {
    let (tilt_deg, width) = scene.needle?;
    Some(needle_beside(
        spec,
        tilt_deg,
        width,
        scene.needle_level,
        rng,
    ))
}

/// A needle `width_px` wide at its base, tilted by `tilt_deg`, at `level`, beside the
/// probe of `spec` (see [`place_needle`]).
pub(super) fn needle_beside(
    spec: &FrameSpec,
    tilt_deg: f64,
    width_px: f64,
    level: f64,
    rng: &mut Rng,
) -> super::Needle {
    let away = if spec.entry == Entry::Left { 1.0 } else { -1.0 };
    let (w, h) = (f64::from(spec.width), f64::from(spec.height));
    let tip = [
        (spec.apex_px[0] + away * rng.uniform(70.0, 150.0)).clamp(10.0, w - 10.0),
        (spec.apex_px[1] + rng.uniform(30.0, 110.0)).clamp(10.0, h - 10.0),
    ];
    let a = tilt_deg.to_radians();
    let reach = w + h;
    super::Needle {
        base: [tip[0] + away * reach * a.cos(), tip[1] + reach * a.sin()],
        tip,
        base_width_px: width_px,
        level,
    }
}

/// The real-background suite: `sessions` sessions of `frames_per_session` 640x480
/// frames over crops of real SEM frames (`crops` of them, passed to the renderer by the
/// caller), each session showing one or two of the conditions of a real SEM (low
/// contrast, a bright textured background, charging, scan-line jitter, noise up to 48,
/// a second needle) with a probe brighter than its background in every other session
/// and darker in the rest. Frames mix magnifications 1000x-8000x, angles within +-20 deg,
/// apex placements and blank frames; each session's reference shows the same scene at
/// rest with little noise. Deterministic from `seed`.
pub fn real_suite(
    seed: u64,
    sessions: usize,
    frames_per_session: usize,
    crops: usize,
) -> Vec<Session> {
    (0..sessions)
        .map(|i| {
            let session_seed = sub_seed(seed, 500 + i as u64);
            let mut setup = Setup::random(session_seed, 640, 480);
            setup.entry = if (i / 2) % 2 == 0 {
                Entry::Left
            } else {
                Entry::Right
            };
            let mut rng = Rng::new(sub_seed(session_seed, 4));
            let dark = (i + i / REAL_CONDITIONS.len()) % 2 == 1;
            let conditions = REAL_CONDITIONS[i % REAL_CONDITIONS.len()];
            let scene = real_scene(conditions, dark, crops, &mut rng);
            let mut reference = setup.reference(session_seed);
            reference.look = Look {
                noise_sigma: 3.0,
                jitter_fraction: 0.0,
                ..scene.look
            };
            reference.look.needle = place_needle(&scene, &reference, &mut rng);
            let phase = rng.uniform(0.0, std::f64::consts::TAU);
            let frames = (0..frames_per_session)
                .map(|k| {
                    let mag = rng.log_uniform(1000.0, 8000.0).round();
                    let angle = rng.uniform(-20.0, 20.0);
                    let mut spec = random_frame(&setup, Style::Clean, mag, angle, &mut rng);
                    spec.look = scene.look;
                    spec.look.noise_sigma = rng.uniform(scene.noise.0, scene.noise.1);
                    if scene.charging {
                        let t = k as f64 / frames_per_session as f64;
                        spec.look.charging_gain =
                            1.0 + 0.3 * (std::f64::consts::TAU * t + phase).sin();
                    }
                    spec.look.needle = place_needle(&scene, &spec, &mut rng);
                    spec
                })
                .collect();
            Session {
                reference,
                frames,
                times_s: (0..frames_per_session)
                    .map(|k| k as f64 / FRAME_RATE_HZ)
                    .collect(),
                threshold: Threshold::Otsu,
                window_deg: DEFAULT_WINDOW_DEG,
                click_seed: sub_seed(session_seed, 3),
            }
        })
        .collect()
}
