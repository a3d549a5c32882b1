//! What to render: the frame ([`FrameSpec`]), its look ([`Look`], the individual
//! knobs) and the four presets of the public samples ([`Style`]: clean, clutter, noisy,
//! harsh). The preset values were measured on the public sessions (docs/renderer.md).

use super::background::{Needle, RealLook};
use super::geometry::{px_per_um, Entry, Pose, ProbeGeometry};
use super::tool_shape::ToolGeometry;
use crate::vision::MAX_PROBES;

/// The looks of the public samples, from an easy frame to a hard one.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Style {
    /// Low noise, a few particles, no substrate.
    Clean,
    /// Moderate noise, many particles and scratches, substrate.
    Clutter,
    /// Strong noise, some particles, substrate.
    Noisy,
    /// Strongest noise and blur, low contrast, much clutter, substrate.
    Harsh,
}

impl Style {
    pub const ALL: [Style; 4] = [Style::Clean, Style::Clutter, Style::Noisy, Style::Harsh];

    /// The name written in truth.csv.
    pub fn name(self) -> &'static str {
        match self {
            Style::Clean => "clean",
            Style::Clutter => "clutter",
            Style::Noisy => "noisy",
            Style::Harsh => "harsh",
        }
    }

    /// The preset's knobs (typical counts; generators vary them per frame).
    pub fn look(self) -> Look {
        let base = Look {
            style_name: self.name(),
            noise_sigma: 6.0,
            blur_sigma_px: 0.73,
            jitter_fraction: 0.0,
            background: 70.0,
            shading: 18.0,
            probe: 214.2,
            probe_ramp: 12.0,
            outline: 3.0,
            outline_width_px: 2.5,
            edge_bias_px: 0.0,
            particles: 3,
            scratches: 0,
            substrate: None,
            real: None,
            needle: None,
            charging_gain: 1.0,
        };
        match self {
            Style::Clean => base,
            Style::Clutter => Look {
                noise_sigma: 14.0,
                blur_sigma_px: 0.93,
                jitter_fraction: 0.08,
                background: 80.0,
                probe: 209.0,
                particles: 10,
                scratches: 5,
                substrate: Some(118.0),
                ..base
            },
            Style::Noisy => Look {
                noise_sigma: 22.0,
                blur_sigma_px: 1.14,
                jitter_fraction: 0.045,
                background: 75.0,
                probe: 204.6,
                particles: 5,
                scratches: 1,
                substrate: Some(110.0),
                ..base
            },
            Style::Harsh => Look {
                noise_sigma: 30.0,
                blur_sigma_px: 1.57,
                jitter_fraction: 0.08,
                background: 96.0,
                probe: 190.5,
                particles: 19,
                scratches: 6,
                substrate: Some(128.0),
                ..base
            },
        }
    }
}

/// The individual knobs of a frame's appearance. Grey levels are on the 8-bit scale.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Look {
    /// Written in truth.csv's `style` column.
    pub style_name: &'static str,
    /// Standard deviation of the white Gaussian noise (SEM frames: up to 30).
    pub noise_sigma: f64,
    /// Gaussian blur of the beam spot, pixels (SEM frames: 0.8 to 1.6; the area
    /// integration of the pixel adds its own 0.29 px).
    pub blur_sigma_px: f64,
    /// Fraction of rows shifted sideways by one pixel (scan-line jitter).
    pub jitter_fraction: f64,
    /// Mean background level.
    pub background: f64,
    /// Amplitude of the slow background shading (+- grey levels).
    pub shading: f64,
    /// Probe level at the frame's centre.
    pub probe: f64,
    /// Rise of the probe level from the left edge to the right edge of the frame.
    pub probe_ramp: f64,
    /// Extra brightness of a band along the inside of the probe's outline (edge effect).
    pub outline: f64,
    /// Width of that band, pixels.
    pub outline_width_px: f64,
    /// How far outside the probe's true outline it is imaged (an SEM's edge effect as a
    /// shift), pixels; the truth keeps the true outline. 0 (every preset) draws it where
    /// it is, as docs/conventions.md does; the public samples' truth reads as about 0.3 px
    /// (docs/tracker.md, "Apex convention").
    pub edge_bias_px: f64,
    /// Number of bright particles.
    pub particles: u32,
    /// Number of straight scratches.
    pub scratches: u32,
    /// Level of the substrate surface below the apex, or none.
    pub substrate: Option<f64>,
    /// A crop of a real SEM frame as the background instead of the synthetic shading
    /// (the caller passes the crops to `Renderer::render_over`); none in every preset.
    /// `probe` may then lie below the background (a darker probe) as well as above it.
    pub real: Option<RealLook>,
    /// A second probe-like object (a tapered needle) in view; none in every preset.
    pub needle: Option<Needle>,
    /// Charging: the whole ideal image multiplied by this before blur and noise (a
    /// session drifts it by +-30 %); 1 in every preset.
    pub charging_gain: f64,
}

/// Everything that determines one frame; rendering it is a pure function of this.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FrameSpec {
    pub width: u32,
    pub height: u32,
    pub magnification: f64,
    pub probe: ProbeGeometry,
    pub entry: Entry,
    /// Tilt of the undeformed beam, degrees (see [`Pose::base_deg`]).
    pub base_deg: f64,
    /// Tip angle phi0, degrees CCW on screen, 0 in the reference.
    pub angle_deg: f64,
    /// Where the apex lands, pixels.
    pub apex_px: [f64; 2],
    /// Perpendicular distance of the substrate's edge below the apex, micrometres
    /// (negative: the apex overlaps the substrate as seen from the SEM).
    pub substrate_gap_um: f64,
    /// Tilt of the substrate's edge, degrees CCW on screen.
    pub substrate_tilt_deg: f64,
    pub look: Look,
    /// No probe in view (the tracker must report nothing).
    pub blank: bool,
    /// Seed of everything random in the frame (clutter, shading, noise, jitter).
    pub seed: u64,
    /// More probes in the same view, drawn after the first with the frame's look; none
    /// in every preset.
    pub others: Others,
    /// A rigid tool drawn instead of the cantilever as the frame's own (first) probe,
    /// posed by `entry`, `base_deg`, `angle_deg` and `apex_px`; its truth is
    /// [`crate::scene::tool_truth`]. None in every preset.
    pub tool: Option<ToolGeometry>,
}

/// Most probes a frame shows besides its first.
pub const MAX_OTHER_PROBES: usize = MAX_PROBES - 1;

/// The other probes of a frame, up to [`MAX_OTHER_PROBES`], in order.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Others([Option<Placement>; MAX_OTHER_PROBES]);

impl Others {
    /// None.
    pub const NONE: Others = Others([None; MAX_OTHER_PROBES]);

    /// These probes, in order; more than [`MAX_OTHER_PROBES`] is a caller's error.
    pub fn of(probes: &[Placement]) -> Others {
        assert!(
            probes.len() <= MAX_OTHER_PROBES,
            "at most {MAX_OTHER_PROBES} other probes"
        );
        Others(std::array::from_fn(|k| probes.get(k).copied()))
    }

    pub fn iter(&self) -> impl Iterator<Item = &Placement> {
        self.0.iter().flatten()
    }

    pub fn iter_mut(&mut self) -> impl Iterator<Item = &mut Placement> {
        self.0.iter_mut().flatten()
    }
}

/// Another probe in a frame: its geometry and pose.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Placement {
    pub probe: ProbeGeometry,
    pub entry: Entry,
    pub base_deg: f64,
    pub angle_deg: f64,
    pub apex_px: [f64; 2],
    /// Out of view in this frame.
    pub blank: bool,
    /// A rigid tool drawn instead of the cantilever ([`FrameSpec::tool`]).
    pub tool: Option<ToolGeometry>,
}

impl FrameSpec {
    /// A 640x480 frame of the typical probe entering from the left at `angle_deg`,
    /// 2000x, apex near the centre; adjust fields from here.
    pub fn new(style: Style, angle_deg: f64, seed: u64) -> Self {
        FrameSpec {
            width: 640,
            height: 480,
            magnification: 2000.0,
            probe: ProbeGeometry::typical(),
            entry: Entry::Left,
            base_deg: -18.0,
            angle_deg,
            apex_px: [330.0, 260.0],
            substrate_gap_um: 1.5,
            substrate_tilt_deg: 0.0,
            look: style.look(),
            blank: false,
            seed,
            others: Others::NONE,
            tool: None,
        }
    }

    /// The placement of this spec's own (first) probe.
    pub fn placement(&self) -> Placement {
        Placement {
            probe: self.probe,
            entry: self.entry,
            base_deg: self.base_deg,
            angle_deg: self.angle_deg,
            apex_px: self.apex_px,
            blank: self.blank,
            tool: self.tool,
        }
    }

    /// How many probes the frame places (in view or not): its own and the others.
    pub fn probe_count(&self) -> usize {
        1 + self.others.iter().count()
    }

    /// Probe `k` of the frame (0: its own, then the others in order) as a frame of that
    /// probe alone, with this frame's size, magnification, look and seed; its truth is
    /// [`crate::scene::truth_of`] of it ([`crate::scene::tool_truth`] for a tool).
    pub fn nth_probe(&self, k: usize) -> Option<FrameSpec> {
        let place = match k {
            0 => self.placement(),
            k => *self.others.iter().nth(k - 1)?,
        };
        Some(FrameSpec {
            others: Others::NONE,
            ..self.placing(place)
        })
    }

    /// This frame with its own (first) probe placed as `place` (a tool if `place`
    /// is one); the others stay.
    pub fn placing(&self, place: Placement) -> FrameSpec {
        FrameSpec {
            probe: place.probe,
            entry: place.entry,
            base_deg: place.base_deg,
            angle_deg: place.angle_deg,
            apex_px: place.apex_px,
            blank: place.blank,
            tool: place.tool,
            ..*self
        }
    }

    pub fn px_per_um(&self) -> f64 {
        px_per_um(self.width, self.magnification)
    }

    /// The probe's placement in this frame.
    pub fn pose(&self) -> Pose {
        Pose {
            entry: self.entry,
            base_deg: self.base_deg,
            angle_deg: self.angle_deg,
            apex_px: self.apex_px,
            px_per_um: self.px_per_um(),
        }
    }
}
