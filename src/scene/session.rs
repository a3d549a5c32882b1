//! Recorded sessions on disk, in the layout of docs/conventions.md: `probe.toml`
//! (cantilever, tracker settings, calibration clicks), `reference.png` (the undeformed
//! probe, angle zero), `frames/frame_00000.png ...` and `truth.csv`. A [`Session`] is a
//! list of [`FrameSpec`]s sharing one probe, entry side and base orientation; it is built
//! either as a random-order mixed set ([`Session::mixed`]) or as a time sequence of an
//! operator pressing and releasing, with magnification jumps ([`Session::sequence`]).

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use image::{GrayImage, ImageBuffer, Luma};

use super::geometry::{Entry, ProbeGeometry};
use super::render::{truth_of, Renderer, Truth};
use super::rng::{sub_seed, Rng};
use super::spec::{FrameSpec, Style};
use super::tool::tool_clicks;
use crate::vision::{
    CalibrationConfig, ScaleRange, Threshold, Tracker, TrackerConfig, VisionError, SINGLE_NAME,
};

/// Magnifications an operator picks from (those of the public samples).
pub const MAGNIFICATIONS: [f64; 6] = [1000.0, 1500.0, 2000.0, 3500.0, 5000.0, 8000.0];
/// The SEM's frame rate, for `t_s`.
pub const FRAME_RATE_HZ: f64 = 60.0;

/// Writing a session failed.
#[derive(Debug, thiserror::Error)]
pub enum SessionError {
    #[error("{path}: {source}")]
    Io {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error("{path}: cannot encode frame: {source}")]
    Encode {
        path: PathBuf,
        source: image::ImageError,
    },
}

/// How frames are stored.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum FrameFormat {
    Png,
    /// Binary PGM (P5).
    Pgm,
    /// 16-bit grey TIFF, as some SEMs write (8-bit levels times 257).
    Tiff16,
}

impl FrameFormat {
    pub fn extension(self) -> &'static str {
        match self {
            FrameFormat::Png => "png",
            FrameFormat::Pgm => "pgm",
            FrameFormat::Tiff16 => "tif",
        }
    }
}

/// Pixels a person clicked on each tracked edge of the reference image.
#[derive(Debug, Clone, PartialEq)]
pub struct Clicks {
    pub red: Vec<[f64; 2]>,
    pub blue: Vec<[f64; 2]>,
    pub green: Vec<[f64; 2]>,
}

/// One probe seen in a series of frames, with its calibration frame.
#[derive(Debug, Clone, PartialEq)]
pub struct Session {
    /// The calibration frame: undeformed probe (angle 0).
    pub reference: FrameSpec,
    pub frames: Vec<FrameSpec>,
    /// Time stamp of each frame, seconds.
    pub times_s: Vec<f64>,
    pub threshold: Threshold,
    pub window_deg: f64,
    /// Seed of the calibration clicks' errors.
    pub click_seed: u64,
}

impl Session {
    /// The probe shared by all frames.
    pub fn probe(&self) -> &ProbeGeometry {
        &self.reference.probe
    }

    /// Where a person would click on the red, blue and green edges of the reference
    /// image: three points each, off by up to about a pixel, to 0.1 px.
    pub fn clicks(&self) -> Clicks {
        self.clicks_of(0)
    }

    /// The names of the session's probes, in order: `probe` for a session of one probe
    /// (its probe.toml gives it at the top level), else `probe1`, `probe2`, ... (its
    /// `[[probe]]` entries, and the names of its `truth.<name>.csv` files).
    pub fn probe_names(&self) -> Vec<String> {
        match self.reference.probe_count() {
            1 => vec![SINGLE_NAME.to_string()],
            n => (1..=n).map(|k| format!("probe{k}")).collect(),
        }
    }

    /// The `[tracker]` settings of probe `k` (as [`Session::probe_toml`] writes them),
    /// its calibration clicks from [`Session::clicks_of`] (a tool's from
    /// [`tool_clicks`], searched over [`Session::scales`]).
    pub fn tracker_config_of(&self, k: usize) -> TrackerConfig {
        self.tracker_config_with(k, self.calibration_of(k))
    }

    /// Probe `k`'s `[tracker]` settings with the calibration `clicks`.
    fn tracker_config_with(&self, k: usize, clicks: CalibrationConfig) -> TrackerConfig {
        TrackerConfig {
            threshold: self.threshold,
            window_deg: self.window_deg,
            scale_range: self.scale_range_of(k),
            calibration: Some(clicks),
            ..TrackerConfig::default()
        }
    }

    /// Probe `k`'s `tracker.scale_range`: for a tool, [`Session::scales`] as the file
    /// writes it, to 1e-4 outward; none for the AFM probe.
    fn scale_range_of(&self, k: usize) -> Option<ScaleRange> {
        self.nth(k).tool.map(|_| {
            let range = self.scales();
            ScaleRange::new(
                (range.lo * 1e4).floor() / 1e4,
                (range.hi * 1e4).ceil() / 1e4,
            )
        })
    }

    /// Probe `k` of the reference alone (0: its own, then the others).
    fn nth(&self, k: usize) -> FrameSpec {
        self.reference.nth_probe(k).unwrap_or(self.reference)
    }

    /// The `[tracker.calibration]` of probe `k`: the reference and its clicks, to 0.1 px
    /// as the file writes them; a tool's named edges with the two meeting at its tip.
    fn calibration_of(&self, k: usize) -> CalibrationConfig {
        let reference_image = PathBuf::from("reference.png");
        let own = self.nth(k);
        if let Some(tool) = own.tool {
            let tenth = |p: [f64; 2]| p.map(|v| (10.0 * v).round() / 10.0);
            return CalibrationConfig {
                reference_image,
                edges: tool_clicks(&own)
                    .into_iter()
                    .map(|(name, points)| (name, points.into_iter().map(tenth).collect()))
                    .collect(),
                apex: Some(tool.kind.apex_edges().map(String::from)),
            };
        }
        let clicks = self.clicks_of(k);
        CalibrationConfig::pyramid(reference_image, clicks.red, clicks.blue, clicks.green)
    }

    /// A tracker for each probe of the reference, in order, calibrated on the rendered
    /// reference with [`Session::tracker_config_of`] and forces from its geometry: the
    /// trackers `replay` builds from the session's probe.toml. A tool has no
    /// cantilever.
    pub fn trackers(&self) -> Result<Vec<Tracker>, VisionError> {
        let mut reference = GrayImage::new(1, 1);
        Renderer::new().render_into(&self.reference, &mut reference);
        (0..self.reference.probe_count())
            .map(|k| {
                let clicks = self.calibration_of(k);
                let cfg = self.tracker_config_with(k, clicks.clone());
                let own = self.nth(k);
                let cantilever = own.tool.is_none().then(|| own.probe.cantilever());
                Tracker::from_reference(&reference, &clicks, &cfg, cantilever)
            })
            .collect()
    }

    /// The scales the session's frames show, over the reference's, with 10 % to spare:
    /// the `tracker.scale_range` a lab would state for them.
    pub fn scales(&self) -> ScaleRange {
        let (lo, hi) = self
            .frames
            .iter()
            .map(|f| f.magnification / self.reference.magnification)
            .fold((f64::INFINITY, 0.0f64), |(lo, hi), r| {
                (lo.min(r), hi.max(r))
            });
        ScaleRange::new(lo / 1.1, hi * 1.1)
    }

    /// As [`Session::clicks`] for probe `k` of the reference (0: its own, then the
    /// others); none for a probe out of view.
    pub fn clicks_of(&self, k: usize) -> Clicks {
        let reference = self.reference.nth_probe(k).unwrap_or(self.reference);
        let truth = truth_of(&reference);
        let mut rng = Rng::new(match k {
            0 => self.click_seed,
            k => sub_seed(self.click_seed, k as u64),
        });
        let mut click = |p: [f64; 2]| {
            let jitter =
                |v: f64, rng: &mut Rng| (10.0 * (v + rng.uniform(-0.7, 0.7))).round() / 10.0;
            let x = jitter(p[0], &mut rng);
            [x, jitter(p[1], &mut rng)]
        };
        let Some(edges) = truth.edges else {
            return Clicks {
                red: vec![],
                blue: vec![],
                green: vec![],
            };
        };
        let along = |s: &super::geometry::Segment, t: f64| {
            [
                s.from[0] + t * (s.to[0] - s.from[0]),
                s.from[1] + t * (s.to[1] - s.from[1]),
            ]
        };
        // The reference beam is straight, so red clicks may reach beyond the end block,
        // as far as the frame allows.
        let h_px = reference.probe.pyramid_height_um * reference.px_per_um();
        let red_len = edges.red.length();
        let (w, h) = (
            f64::from(self.reference.width),
            f64::from(self.reference.height),
        );
        let inside = |p: [f64; 2]| p[0] >= 3.0 && p[1] >= 3.0 && p[0] <= w - 4.0 && p[1] <= h - 4.0;
        let mut reach = 1.75 * h_px;
        while reach > 0.3 * red_len && !inside(along(&edges.red, 1.0 - reach / red_len)) {
            reach *= 0.95;
        }
        let red = [1.0, 0.57, 0.14].map(|k| along(&edges.red, 1.0 - k * reach / red_len));
        Clicks {
            red: red.into_iter().map(&mut click).collect(),
            blue: [0.15, 0.5, 0.85]
                .map(|t| along(&edges.blue, t))
                .into_iter()
                .map(&mut click)
                .collect(),
            green: [0.85, 0.5, 0.15]
                .map(|t| along(&edges.green, t))
                .into_iter()
                .map(&mut click)
                .collect(),
        }
    }

    /// The `probe.toml` text (a configuration file: it parses with `Config::load`): one
    /// probe at the top level, several as `[[probe]]` entries named as
    /// [`Session::probe_names`].
    pub fn probe_toml(&self) -> String {
        let names = self.probe_names();
        let mut text = String::from("# Probe and tracker settings for one recorded session.\n");
        match names.len() {
            1 => text.push_str(&self.probe_settings(0, "")),
            _ => {
                for (k, name) in names.iter().enumerate() {
                    text.push_str(&self.probe_entry(k, name));
                }
            }
        }
        text
    }

    /// Probe `k`'s `[[probe]]` entry of [`Session::probe_toml`], named `name`.
    pub fn probe_entry(&self, k: usize, name: &str) -> String {
        format!(
            "\n[[probe]]\nname = \"{name}\"\n{}",
            self.probe_settings(k, "probe.")
        )
    }

    /// Probe `k`'s cantilever (none for a tool), tracker and calibration tables, their
    /// names prefixed with `prefix`.
    fn probe_settings(&self, k: usize, prefix: &str) -> String {
        let own = self.nth(k);
        let clicks = self.calibration_of(k);
        let points = CalibrationConfig::toml_points;
        let mut text = String::new();
        if own.tool.is_none() {
            let _ = write!(
                text,
                "[{prefix}cantilever]\nlength_um = {:.3}\nspring_constant_n_per_m = {:.4}\n\n",
                own.probe.length_um, own.probe.spring_constant_n_per_m,
            );
        }
        let _ = write!(
            text,
            "[{prefix}tracker]\nthreshold = {}\nwindow_deg = {:.1}\n",
            self.threshold, self.window_deg,
        );
        if let Some(range) = self.scale_range_of(k) {
            let _ = writeln!(text, "scale_range = [{:.4}, {:.4}]", range.lo, range.hi);
        }
        let _ = write!(
            text,
            "\n[{prefix}tracker.calibration]\n\
             reference_image = \"reference.png\"  # relative to this file\n\
             # pixels marked on each edge in the reference image; x right, y down\n",
        );
        // The AFM pyramid's red, blue and green stand in the calibration table; a
        // tool's named edges in their own, after its apex edges.
        if let Some([a, b]) = &clicks.apex {
            let _ = writeln!(text, "apex = [\"{a}\", \"{b}\"]");
            let _ = writeln!(text, "[{prefix}tracker.calibration.edges]");
        }
        for (name, clicked) in &clicks.edges {
            let _ = writeln!(text, "{name} = {}", points(clicked));
        }
        text
    }

    /// Writes the session into `dir` (created if needed) and returns every frame's truth
    /// (of its first probe; with several probes, each probe's truth is in
    /// `truth.<name>.csv`).
    pub fn write(&self, dir: &Path, format: FrameFormat) -> Result<Vec<Truth>, SessionError> {
        let frames_dir = dir.join("frames");
        std::fs::create_dir_all(&frames_dir).map_err(|source| SessionError::Io {
            path: frames_dir.clone(),
            source,
        })?;
        write_text(&dir.join("probe.toml"), &self.probe_toml())?;
        let mut renderer = Renderer::new();
        let mut frame = GrayImage::new(1, 1);
        renderer.render_into(&self.reference, &mut frame);
        save(&frame, &dir.join("reference.png"), FrameFormat::Png)?;
        let names = self.probe_names();
        let mut csvs = vec![
            String::from(
                "frame,detected,angle_deg,force_nN,tip_x,tip_y,magnification,px_per_um,style,t_s\n",
            );
            names.len()
        ];
        let mut truths = Vec::with_capacity(self.frames.len());
        for (k, spec) in self.frames.iter().enumerate() {
            let truth = renderer.render_into(spec, &mut frame);
            let name = format!("frame_{k:05}.{}", format.extension());
            save(&frame, &frames_dir.join(&name), format)?;
            let t_s = self
                .times_s
                .get(k)
                .copied()
                .unwrap_or(k as f64 / FRAME_RATE_HZ);
            for (p, csv) in csvs.iter_mut().enumerate() {
                let truth = match (p, spec.nth_probe(p)) {
                    (0, _) => truth,
                    (_, Some(other)) => truth_of(&other),
                    (_, None) => truth_of(&FrameSpec {
                        blank: true,
                        ..*spec
                    }),
                };
                csv_row(csv, &name, &truth, spec.look.style_name, t_s);
            }
            truths.push(truth);
        }
        for (csv, name) in csvs.iter().zip(&names) {
            let file = match names.len() {
                1 => "truth.csv".to_string(),
                _ => format!("truth.{name}.csv"),
            };
            write_text(&dir.join(file), csv)?;
        }
        Ok(truths)
    }
}

/// One truth.csv row in the samples' number formats; blank frames get `nan`.
fn csv_row(csv: &mut String, name: &str, t: &Truth, style: &str, t_s: f64) {
    let _ = writeln!(
        csv,
        "{name},{},{:.6},{:.4},{:.3},{:.3},{:.0},{:.5},{style},{t_s:.6}",
        u8::from(t.probe_in_view),
        t.angle_deg,
        t.force_nn,
        t.tip_x,
        t.tip_y,
        t.magnification,
        t.px_per_um,
    );
}

fn write_text(path: &Path, text: &str) -> Result<(), SessionError> {
    std::fs::write(path, text).map_err(|source| SessionError::Io {
        path: path.to_path_buf(),
        source,
    })
}

fn save(frame: &GrayImage, path: &Path, format: FrameFormat) -> Result<(), SessionError> {
    let result = match format {
        FrameFormat::Png => frame.save_with_format(path, image::ImageFormat::Png),
        FrameFormat::Pgm => frame.save_with_format(path, image::ImageFormat::Pnm),
        FrameFormat::Tiff16 => {
            let wide: ImageBuffer<Luma<u16>, Vec<u16>> =
                ImageBuffer::from_fn(frame.width(), frame.height(), |x, y| {
                    Luma([u16::from(frame.get_pixel(x, y)[0]) * 257])
                });
            wide.save_with_format(path, image::ImageFormat::Tiff)
        }
    };
    result.map_err(|source| SessionError::Encode {
        path: path.to_path_buf(),
        source,
    })
}

/// The fixed part of a session: probe, frame size, entry side, base orientation.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Setup {
    pub probe: ProbeGeometry,
    pub width: u32,
    pub height: u32,
    pub entry: Entry,
    pub base_deg: f64,
}

impl Setup {
    /// A random setup (probe within docs/conventions.md's ranges, base within +-35 deg).
    pub fn random(seed: u64, width: u32, height: u32) -> Self {
        let mut rng = Rng::new(seed);
        let mut probe = ProbeGeometry::random(rng.next_u64());
        // As written in probe.toml, so the config reproduces the true forces exactly.
        probe.length_um = (probe.length_um * 1e3).round() / 1e3;
        probe.spring_constant_n_per_m = (probe.spring_constant_n_per_m * 1e4).round() / 1e4;
        Setup {
            probe,
            width,
            height,
            entry: if rng.chance(0.5) {
                Entry::Left
            } else {
                Entry::Right
            },
            base_deg: rng.uniform(-35.0, 35.0),
        }
    }

    /// A frame of this setup with everything else at neutral values.
    pub fn frame(&self, style: Style, angle_deg: f64, magnification: f64, seed: u64) -> FrameSpec {
        FrameSpec {
            width: self.width,
            height: self.height,
            magnification,
            probe: self.probe,
            entry: self.entry,
            base_deg: self.base_deg,
            ..FrameSpec::new(style, angle_deg, seed)
        }
    }

    /// The calibration frame: clean, angle 0, at 2000x on 640 px (same field on any size).
    pub fn reference(&self, seed: u64) -> FrameSpec {
        let mut rng = Rng::new(sub_seed(seed, 11));
        let mut spec = self.frame(Style::Clean, 0.0, 2000.0, rng.next_u64());
        let x = rng.uniform(0.36, 0.46);
        let x = if self.entry == Entry::Left {
            x
        } else {
            1.0 - x
        };
        spec.apex_px = [
            x * f64::from(self.width),
            rng.uniform(0.4, 0.52) * f64::from(self.height),
        ];
        spec.look.substrate = None;
        spec
    }
}
