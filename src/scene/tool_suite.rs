//! The tool suite: seeded sessions of a rigid tool (a needle, a tipless cantilever, a
//! gripper jaw; [`super::tool`]) for a generic tracker's tests. Each session has a
//! reference frame (the tool at angle 0, little noise), the clicks a person makes on its
//! edges there, and frames of the tool turned and zoomed under one or two of the SEM's
//! conditions, as [`super::suite`] and [`super::real_suite`] span them.

use super::generate::{needle_beside, random_frame, real_scene, RealScene};
use super::geometry::{rotate, Entry, Segment};
use super::rng::{sub_seed, Rng};
use super::session::Setup;
use super::spec::{FrameSpec, Look, Style};
use super::tool::{clip_to_frame, tool_truth, ToolTruth};
use super::tool_shape::{ToolGeometry, ToolKind};

/// One tool seen in a series of frames, with its calibration frame and clicks.
#[derive(Debug, Clone, PartialEq)]
pub struct ToolSession {
    pub kind: ToolKind,
    /// The tool at angle 0 with little noise and no particles.
    pub reference: FrameSpec,
    /// The edges whose lines meet at the apex ([`ToolKind::apex_edges`]).
    pub apex: [&'static str; 2],
    /// Pixels a person clicked on each edge of the reference, in
    /// [`ToolKind::edge_names`] order: [`CLICKS_PER_EDGE`] each, within 10-90 % of the
    /// edge's visible part, each coordinate off by a normal 0.3 px clamped to 0.4 px.
    pub clicks: Vec<(&'static str, Vec<[f64; 2]>)>,
    /// The frames; [`super::BLANK_FRACTION`] of them (`blank`) show no tool.
    pub frames: Vec<FrameSpec>,
}

/// Clicks per edge on the reference.
pub const CLICKS_PER_EDGE: usize = 3;
/// Where along an edge's visible part the clicks fall (fractions from its apex end).
const CLICK_RANGE: [f64; 2] = [0.1, 0.9];
/// Click error per coordinate: a normal deviate of this sigma, clamped to the bound.
const CLICK_SIGMA_PX: f64 = 0.3;
const CLICK_BOUND_PX: f64 = 0.4;
/// Largest rotation of a frame from the reference, degrees.
const MAX_ANGLE_DEG: f64 = 15.0;
/// Range of a frame's magnification over the reference's.
pub const MAG_RATIO: [f64; 2] = [0.8, 1.25];
/// Range of the reference's magnification.
const REFERENCE_MAG: [f64; 2] = [1500.0, 4000.0];
/// Share of each edge's visible length in the reference, from its apex end, that every
/// frame keeps in view.
pub const TIP_REGION: f64 = 0.6;
/// Least distance of that tip region from the frame's border, pixels.
pub const TIP_MARGIN_PX: f64 = 20.0;
/// Noise sigma of the reference.
const REFERENCE_NOISE: f64 = 3.0;
/// Largest noise sigma of a frame.
const MAX_NOISE: f64 = 30.0;
/// Least contrast between the tool and its background, grey levels.
const MIN_CONTRAST: f64 = 25.0;
/// Amplitude of the charging drift over a session (a fraction of the brightness).
const CHARGING_AMPLITUDE: f64 = 0.3;
/// First of the random streams of the kinds' suites.
const KIND_STREAM: u64 = 900;
/// Chord length standing in for an endless flank while its visible part is measured, um.
const ENDLESS_UM: f64 = 1.0e5;

/// One condition of a session.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Setting {
    /// A style's noise, blur, clutter and levels, varied per frame (Clean otherwise).
    Styled(Style),
    /// The tool 60-100 levels darker than its background.
    Dark,
    /// The tool 25-35 levels from a flat, quiet background (noise 2-6).
    LowContrast,
    /// Beam blur sigma 1.6-2.4 px.
    Blur,
    /// 5-15 % of the rows shifted by a pixel.
    Jitter,
    /// The brightness drifting by +-30 % over the session.
    Charging,
    /// A crop of a real SEM frame as the background (the synthetic one without crops).
    Real,
    /// A tapered needle in view beside the tool.
    Decoy,
}

/// The sessions' conditions, in order (repeating), one or two each.
const SETTINGS: [&[Setting]; 16] = {
    use Setting::*;
    [
        &[Styled(Style::Clean)],
        &[Styled(Style::Noisy)],
        &[Real],
        &[Dark],
        &[Styled(Style::Clutter)],
        &[LowContrast],
        &[Styled(Style::Harsh)],
        &[Real, Dark],
        &[Blur],
        &[Jitter, Styled(Style::Noisy)],
        &[Charging],
        &[Decoy],
        &[Real, Decoy],
        &[Dark, Styled(Style::Noisy)],
        &[LowContrast, Blur],
        &[Real, Charging],
    ]
};

/// A session's look, before the per-frame draws.
#[derive(Debug, Clone, Copy)]
struct ToolScene {
    style: Style,
    real: Option<RealScene>,
    /// Background and tool levels of a dark or low-contrast synthetic session.
    levels: Option<[f64; 2]>,
    quiet: bool,
    blur_px: Option<f64>,
    jitter: Option<f64>,
    charging: bool,
    /// The decoy needle's tilt (deg), width (px) and level offset from the tool's.
    decoy: Option<[f64; 3]>,
}

impl ToolScene {
    fn new(settings: &[Setting], crops: usize, rng: &mut Rng) -> ToolScene {
        use Setting::*;
        let has = |s| settings.contains(&s);
        let style = settings
            .iter()
            .find_map(|s| match s {
                Styled(style) => Some(*style),
                _ => None,
            })
            .unwrap_or(Style::Clean);
        let dark = has(Dark);
        let mut real = (has(Real) && crops > 0).then(|| real_scene(&[], dark, crops, rng));
        if let Some(scene) = real.as_mut().filter(|_| has(Charging)) {
            // At the session's dimmest the contrast is still the least allowed.
            let look = &mut scene.look;
            let floor = MIN_CONTRAST / (1.0 - CHARGING_AMPLITUDE);
            let contrast = look.probe - look.background;
            look.probe = look.background + contrast.signum() * contrast.abs().max(floor);
        }
        let levels = (real.is_none() && (dark || has(LowContrast))).then(|| {
            let contrast = if has(LowContrast) {
                rng.uniform(MIN_CONTRAST, 35.0)
            } else {
                rng.uniform(60.0, 100.0)
            };
            let background = if dark {
                rng.uniform(150.0, 185.0)
            } else {
                rng.uniform(70.0, 110.0)
            };
            let sign = if dark { -1.0 } else { 1.0 };
            [background, background + sign * contrast]
        });
        ToolScene {
            style,
            real,
            levels,
            quiet: has(LowContrast),
            blur_px: has(Blur).then(|| rng.uniform(1.6, 2.4)),
            jitter: has(Jitter).then(|| rng.uniform(0.05, 0.15)),
            charging: has(Charging),
            decoy: has(Decoy).then(|| {
                [
                    rng.uniform(20.0, 70.0),
                    rng.uniform(10.0, 25.0),
                    rng.uniform(-10.0, 10.0),
                ]
            }),
        }
    }

    /// A frame's look from `base` (its style's varied look).
    fn look(&self, base: Look, rng: &mut Rng) -> Look {
        let mut look = match &self.real {
            Some(real) => Look {
                noise_sigma: rng.uniform(real.noise.0, real.noise.1.min(MAX_NOISE)),
                ..real.look
            },
            None => base,
        };
        if let Some([background, probe]) = self.levels {
            look.background = background;
            look.probe = probe;
            look.substrate = None;
        }
        if self.quiet {
            // A flat background, so the contrast is the same all along every edge.
            look.noise_sigma = rng.uniform(2.0, 6.0);
            look.shading = 0.0;
            look.probe_ramp = 0.0;
        }
        if let Some(blur) = self.blur_px {
            look.blur_sigma_px = blur;
        }
        if let Some(jitter) = self.jitter {
            look.jitter_fraction = jitter;
        }
        look
    }

    /// The decoy needle beside the tool of `spec`, if the session has one.
    fn decoy(&self, spec: &FrameSpec, rng: &mut Rng) -> Option<super::Needle> {
        let [tilt, width, offset] = self.decoy?;
        Some(needle_beside(
            spec,
            tilt,
            width,
            spec.look.probe + offset,
            rng,
        ))
    }
}

/// The tool suite: `sessions` sessions of a random tool of `kind`, each with
/// `frames_per_session` frames, the sessions cycling through one or two conditions each
/// (styles with noise up to 30, blur, jitter, charging, a darker tool, low contrast, real
/// backgrounds from `crops` crops when there are any, a decoy needle); entry sides
/// alternate, every third session is 1280x960. Frames turn the tool within +-15 deg of
/// the reference and zoom it 0.8-1.25 times, keeping every edge's first 60 % (of its
/// length visible in the reference, from its apex end) 20 px inside the frame.
/// Deterministic from `seed`.
pub fn tool_suite(
    kind: ToolKind,
    seed: u64,
    sessions: usize,
    frames_per_session: usize,
    crops: usize,
) -> Vec<ToolSession> {
    let kind_seed = sub_seed(seed, KIND_STREAM + kind as u64);
    (0..sessions)
        .map(|i| {
            tool_session(
                kind,
                sub_seed(kind_seed, i as u64),
                i,
                frames_per_session,
                crops,
            )
        })
        .collect()
}

fn tool_session(kind: ToolKind, seed: u64, i: usize, n: usize, crops: usize) -> ToolSession {
    let (w, h) = if i % 3 == 2 { (1280, 960) } else { (640, 480) };
    let mut setup = Setup::random(seed, w, h);
    setup.entry = if i.is_multiple_of(2) {
        Entry::Left
    } else {
        Entry::Right
    };
    let mut rng = Rng::new(sub_seed(seed, 4));
    let scene = ToolScene::new(SETTINGS[i % SETTINGS.len()], crops, &mut rng);
    let reference = reference(kind, &setup, &scene, seed, &mut rng);
    let truth = tool_truth(&reference).unwrap_or_else(|| unreachable!("the reference has a tool"));
    let region = TipRegion::of(&truth, w, h);
    let phase = rng.uniform(0.0, std::f64::consts::TAU);
    let frames = (0..n)
        .map(|k| {
            let mag =
                (reference.magnification * rng.log_uniform(MAG_RATIO[0], MAG_RATIO[1])).round();
            let angle = rng.uniform(-MAX_ANGLE_DEG, MAX_ANGLE_DEG);
            let mut spec = random_frame(&setup, scene.style, mag, angle, &mut rng);
            spec.tool = reference.tool;
            spec.look = scene.look(spec.look, &mut rng);
            if scene.charging {
                let t = k as f64 / n as f64;
                spec.look.charging_gain =
                    1.0 + CHARGING_AMPLITUDE * (std::f64::consts::TAU * t + phase).sin();
            }
            let ratio = spec.px_per_um() / reference.px_per_um();
            spec.apex_px = region.place(angle, ratio, w, h, &mut rng);
            spec.look.needle = scene.decoy(&spec, &mut rng);
            spec
        })
        .collect();
    ToolSession {
        kind,
        reference,
        apex: kind.apex_edges(),
        clicks: clicks(&truth, w, h, sub_seed(seed, 3)),
        frames,
    }
}

/// The session's reference: the tool at rest, its flanks' bowed spans reaching to the
/// frame's border.
fn reference(
    kind: ToolKind,
    setup: &Setup,
    scene: &ToolScene,
    seed: u64,
    rng: &mut Rng,
) -> FrameSpec {
    let mag = rng.log_uniform(REFERENCE_MAG[0], REFERENCE_MAG[1]).round();
    let mut spec = setup.frame(Style::Clean, 0.0, mag, rng.next_u64());
    let look = scene.look(scene.style.look(), rng);
    spec.look = Look {
        noise_sigma: REFERENCE_NOISE,
        jitter_fraction: 0.0,
        particles: 0,
        substrate: None,
        ..look
    };
    let x = rng.uniform(0.36, 0.46);
    let x = if setup.entry == Entry::Left {
        x
    } else {
        1.0 - x
    };
    spec.apex_px = [
        x * f64::from(setup.width),
        rng.uniform(0.4, 0.52) * f64::from(setup.height),
    ];
    let mut tool = ToolGeometry::random(kind, sub_seed(seed, 6));
    for flank in &mut tool.flanks {
        flank.span_um = ENDLESS_UM;
    }
    spec.tool = Some(tool);
    let endless = tool_truth(&spec).unwrap_or_else(|| unreachable!("the spec has a tool"));
    for (flank, (_, edge)) in tool.flanks.iter_mut().zip(&endless.edges) {
        let visible = clip_to_frame(edge, setup.width, setup.height).map_or(0.0, |s| s.length());
        flank.span_um = visible / spec.px_per_um();
    }
    spec.tool = Some(tool);
    spec.look.needle = scene.decoy(&spec, rng);
    spec
}

/// The clicks a person makes on the reference's edges (see [`ToolSession::clicks`]).
fn clicks(
    truth: &ToolTruth,
    width: u32,
    height: u32,
    seed: u64,
) -> Vec<(&'static str, Vec<[f64; 2]>)> {
    let mut rng = Rng::new(seed);
    truth
        .edges
        .iter()
        .map(|(name, edge)| {
            let Some(seen) = clip_to_frame(edge, width, height) else {
                return (*name, Vec::new());
            };
            let points = (0..CLICKS_PER_EDGE)
                .map(|j| {
                    let u = (j as f64 + rng.unit()) / CLICKS_PER_EDGE as f64;
                    let t = CLICK_RANGE[0] + (CLICK_RANGE[1] - CLICK_RANGE[0]) * u;
                    let mut err =
                        || (CLICK_SIGMA_PX * rng.normal()).clamp(-CLICK_BOUND_PX, CLICK_BOUND_PX);
                    [
                        seen.from[0] + t * (seen.to[0] - seen.from[0]) + err(),
                        seen.from[1] + t * (seen.to[1] - seen.from[1]) + err(),
                    ]
                })
                .collect();
            (*name, points)
        })
        .collect()
}

/// The part of the tool every frame keeps in view: for each edge, from its apex end
/// over [`TIP_REGION`] of its length visible in the reference, relative to the apex.
struct TipRegion {
    points: Vec<[f64; 2]>,
}

impl TipRegion {
    fn of(reference: &ToolTruth, width: u32, height: u32) -> TipRegion {
        let apex = reference.apex_px;
        let rel = |p: [f64; 2]| [p[0] - apex[0], p[1] - apex[1]];
        let points = reference
            .edges
            .iter()
            .filter_map(|(_, edge)| clip_to_frame(edge, width, height))
            .flat_map(|Segment { from, to }| {
                let part = [
                    from[0] + TIP_REGION * (to[0] - from[0]),
                    from[1] + TIP_REGION * (to[1] - from[1]),
                ];
                [rel(from), rel(part)]
            })
            .collect();
        TipRegion { points }
    }

    /// An apex for a frame turned by `angle_deg` and zoomed by `ratio` from the
    /// reference, uniform over the places that keep the region [`TIP_MARGIN_PX`] inside
    /// the frame (the middle of them if there are none).
    fn place(
        &self,
        angle_deg: f64,
        ratio: f64,
        width: u32,
        height: u32,
        rng: &mut Rng,
    ) -> [f64; 2] {
        let (mut lo, mut hi) = ([f64::INFINITY; 2], [f64::NEG_INFINITY; 2]);
        for &p in &self.points {
            let q = rotate(p, angle_deg.to_radians());
            for (axis, v) in q.iter().enumerate() {
                lo[axis] = lo[axis].min(ratio * v);
                hi[axis] = hi[axis].max(ratio * v);
            }
        }
        let size = [f64::from(width), f64::from(height)];
        std::array::from_fn(|axis| {
            let min = TIP_MARGIN_PX - lo[axis];
            let max = size[axis] - 1.0 - TIP_MARGIN_PX - hi[axis];
            if min <= max {
                rng.uniform(min, max)
            } else {
                0.5 * (min + max)
            }
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const SESSIONS: usize = 4;
    const FRAMES: usize = 12;

    #[test]
    fn the_suite_is_a_pure_function_of_its_seed() {
        for kind in ToolKind::ALL {
            let a = tool_suite(kind, 3, 2, 5, 2);
            assert_eq!(a, tool_suite(kind, 3, 2, 5, 2));
            assert_ne!(a, tool_suite(kind, 4, 2, 5, 2));
        }
    }

    #[test]
    fn the_clicks_lie_on_their_true_edges() {
        for kind in ToolKind::ALL {
            for session in tool_suite(kind, 8, SESSIONS, 1, 0) {
                let truth = tool_truth(&session.reference).unwrap();
                assert_eq!(session.apex, kind.apex_edges());
                assert_eq!(session.clicks.len(), kind.edge_names().len());
                for (name, points) in &session.clicks {
                    let edge = truth.edge(name).unwrap();
                    assert_eq!(points.len(), CLICKS_PER_EDGE);
                    for &p in points {
                        let off = edge.signed_distance(p).abs();
                        assert!(off < 0.6, "{kind:?} {name}: {off}");
                    }
                }
            }
        }
    }

    #[test]
    fn frames_keep_the_tip_in_view_within_the_ranges() {
        for kind in ToolKind::ALL {
            for session in tool_suite(kind, 21, SESSIONS, FRAMES, 0) {
                let reference = &session.reference;
                let truth = tool_truth(reference).unwrap();
                let (w, h) = (reference.width, reference.height);
                let seen: Vec<f64> = truth
                    .edges
                    .iter()
                    .map(|(_, e)| clip_to_frame(e, w, h).unwrap().length())
                    .collect();
                for frame in &session.frames {
                    let t = tool_truth(frame).unwrap();
                    if frame.blank {
                        assert!(!t.in_view);
                        continue;
                    }
                    assert!(frame.angle_deg.abs() <= MAX_ANGLE_DEG);
                    let ratio = frame.magnification / reference.magnification;
                    assert!((0.79..=1.26).contains(&ratio), "{ratio}");
                    let inside = |v: f64, size: u32| {
                        let far = f64::from(size) - 1.0 - TIP_MARGIN_PX;
                        (TIP_MARGIN_PX - 1e-6..=far + 1e-6).contains(&v)
                    };
                    let zoom = t.px_per_um / truth.px_per_um;
                    for ((name, e), len) in t.edges.iter().zip(&seen) {
                        let k = TIP_REGION * len * zoom / e.length();
                        let p = [
                            e.from[0] + k * (e.to[0] - e.from[0]),
                            e.from[1] + k * (e.to[1] - e.from[1]),
                        ];
                        for q in [e.from, p] {
                            assert!(inside(q[0], w) && inside(q[1], h), "{kind:?} {name} {q:?}");
                        }
                    }
                }
            }
        }
    }

    #[test]
    fn sessions_show_bright_and_dark_tools() {
        let sessions = tool_suite(ToolKind::Needle, 2, SETTINGS.len(), 1, 0);
        let dark = |s: &ToolSession| s.reference.look.probe < s.reference.look.background;
        assert!(sessions.iter().any(dark));
        assert!(!sessions.iter().all(dark));
        for s in &sessions {
            let contrast = (s.reference.look.probe - s.reference.look.background).abs();
            assert!(contrast >= MIN_CONTRAST, "{contrast}");
        }
    }
}
