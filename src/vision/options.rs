//! The tracker's options: how a frame is binarised ([`Threshold`]), where pixel
//! coordinates count from ([`PixelOrigin`]), the `[tracker]` settings
//! ([`TrackerConfig`]) and the clicked calibration ([`CalibrationConfig`]). `config`
//! reads and validates them from TOML; vision owns them.
use super::template::{PerEdge, EDGES};
use super::Edge;
use std::fmt;
use std::path::PathBuf;

/// Default half-width of the Hough search window around each calibrated edge, degrees.
pub const DEFAULT_WINDOW_DEG: f64 = 20.0;

/// How the frame is binarised before edge detection.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Threshold {
    /// A fixed grey level (8-bit scale).
    Level(u8),
    /// Otsu's method on each frame's histogram.
    Otsu,
}

impl fmt::Display for Threshold {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Threshold::Level(level) => write!(f, "{level}"),
            Threshold::Otsu => f.write_str("\"otsu\""),
        }
    }
}

/// Where pixel coordinates count from, in the config's clicks and in every output
/// (`tracker.pixel_origin`). Inside nanoforce pixels always follow docs/conventions.md
/// (`Centre`); the conversion happens where numbers enter or leave.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum PixelOrigin {
    /// docs/conventions.md: the top-left pixel's centre is (0, 0).
    #[default]
    Centre,
    /// The top-left pixel's top-left corner is (0, 0), so its centre is (0.5, 0.5)
    /// (ImageJ's sub-pixel coordinates, and the public samples' truth).
    Corner,
}

impl PixelOrigin {
    /// What to add to a centre-counted coordinate to express it from this origin.
    pub fn offset_px(self) -> f64 {
        match self {
            PixelOrigin::Centre => 0.0,
            PixelOrigin::Corner => 0.5,
        }
    }

    /// A centre-counted point expressed from this origin.
    pub fn output(self, p: [f64; 2]) -> [f64; 2] {
        p.map(|v| v + self.offset_px())
    }

    /// A point given from this origin, counted from the pixel centre.
    pub fn input(self, p: [f64; 2]) -> [f64; 2] {
        p.map(|v| v - self.offset_px())
    }

    /// Parses the config's spelling (`"centre"`, `"center"` or `"corner"`).
    pub fn parse(text: &str) -> Option<PixelOrigin> {
        match text.to_ascii_lowercase().as_str() {
            "centre" | "center" => Some(PixelOrigin::Centre),
            "corner" => Some(PixelOrigin::Corner),
            _ => None,
        }
    }
}

impl fmt::Display for PixelOrigin {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            PixelOrigin::Centre => "centre",
            PixelOrigin::Corner => "corner",
        })
    }
}

/// Largest `tracker.edge_bias_px` accepted, pixels: the edge effect moves an imaged
/// outline by a fraction of the blur, never by pixels.
pub const MAX_EDGE_BIAS_PX: f64 = 2.0;

/// Validated `[tracker]` section.
#[derive(Debug, Clone, PartialEq)]
pub struct TrackerConfig {
    pub threshold: Threshold,
    /// Half-width of the search window around each calibrated edge orientation, degrees.
    pub window_deg: f64,
    /// Where the clicks below and every reported pixel count from.
    pub pixel_origin: PixelOrigin,
    /// How far outside the probe's true outline the SEM images it (the edge effect),
    /// frame pixels; the apex is reported where the true faces meet. 0 reports where
    /// the imaged faces meet.
    pub edge_bias_px: f64,
    /// The frames' magnification over the reference frame's, when the lab bounds it
    /// (`tracker.scale_range`); none leaves the engine's own search range.
    pub scale_range: Option<ScaleRange>,
    pub calibration: Option<CalibrationConfig>,
}

impl Default for TrackerConfig {
    fn default() -> Self {
        TrackerConfig {
            threshold: Threshold::Otsu,
            window_deg: DEFAULT_WINDOW_DEG,
            pixel_origin: PixelOrigin::Centre,
            edge_bias_px: 0.0,
            scale_range: None,
            calibration: None,
        }
    }
}

/// A range of a frame's scale over the reference's: frame pixels per reference pixel,
/// which is the session's magnification over the reference frame's. The lab knows it
/// from the SEM's settings, and it tells apart probes that differ mostly in size (a
/// needle of a jaw's taper is that jaw at half the magnification).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ScaleRange {
    pub lo: f64,
    pub hi: f64,
}

impl ScaleRange {
    /// `lo` to `hi`, both included.
    pub const fn new(lo: f64, hi: f64) -> ScaleRange {
        ScaleRange { lo, hi }
    }

    pub fn contains(&self, scale: f64) -> bool {
        (self.lo..=self.hi).contains(&scale)
    }

    /// Whether this range lies inside `outer`.
    pub fn within(&self, outer: &ScaleRange) -> bool {
        self.lo >= outer.lo && self.hi <= outer.hi
    }
}

impl fmt::Display for ScaleRange {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "[{}, {}]", self.lo, self.hi)
    }
}

/// Validated `[tracker.calibration]`: the reference frame and the pixels a person
/// clicked on each named edge (x right, y down, origin at the top-left pixel's centre:
/// clicks given from the corner are converted on reading). The AFM pyramid's edges are
/// `red`, `blue` and `green` with no `apex` (its tip is where blue meets green); any
/// other probe names its edges and the two that meet at its tip point.
#[derive(Debug, Clone, PartialEq)]
pub struct CalibrationConfig {
    /// Resolved against the config file's directory.
    pub reference_image: PathBuf,
    /// Each edge's name and clicked pixels, in the file's order.
    pub edges: Vec<(String, Vec<[f64; 2]>)>,
    /// The two edges meeting at the tip point; none for the AFM pyramid.
    pub apex: Option<[String; 2]>,
}

/// The AFM pyramid's edge names ([`Edge::name`]), in [`Edge::ALL`] order.
pub const PYRAMID_EDGES: PerEdge<&str> = {
    let mut names = [""; EDGES];
    let mut e = 0;
    while e < EDGES {
        names[e] = Edge::ALL[e].name();
        e += 1;
    }
    names
};

impl CalibrationConfig {
    /// The AFM pyramid's clicks.
    pub fn pyramid(
        reference_image: PathBuf,
        red: Vec<[f64; 2]>,
        blue: Vec<[f64; 2]>,
        green: Vec<[f64; 2]>,
    ) -> CalibrationConfig {
        CalibrationConfig {
            reference_image,
            edges: PYRAMID_EDGES
                .iter()
                .map(|n| n.to_string())
                .zip([red, blue, green])
                .collect(),
            apex: None,
        }
    }

    /// The clicks on edge `name`.
    pub fn points(&self, name: &str) -> Option<&[[f64; 2]]> {
        self.edges
            .iter()
            .find(|(n, _)| n == name)
            .map(|(_, p)| p.as_slice())
    }

    /// The clicks on edge `name`, to change them.
    pub fn points_mut(&mut self, name: &str) -> Option<&mut Vec<[f64; 2]>> {
        self.edges
            .iter_mut()
            .find(|(n, _)| n == name)
            .map(|(_, p)| p)
    }

    /// The red, blue and green clicks when these are the AFM pyramid's.
    pub fn pyramid_points(&self) -> Option<PerEdge<&[[f64; 2]]>> {
        if self.apex.is_some() || self.edges.len() != PYRAMID_EDGES.len() {
            return None;
        }
        let [r, b, g] = PYRAMID_EDGES.map(|n| self.points(n));
        Some([r?, b?, g?])
    }

    /// Clicks given from `origin`, brought to count from the pixel centre.
    pub fn counted_from(mut self, origin: PixelOrigin) -> CalibrationConfig {
        for (_, points) in self.edges.iter_mut() {
            for p in points.iter_mut() {
                *p = origin.input(*p);
            }
        }
        self
    }

    /// Clicked pixels as a lab file writes them: `[[x, y], ...]` to 0.1 px.
    pub fn toml_points(points: &[[f64; 2]]) -> String {
        let items: Vec<String> = points
            .iter()
            .map(|p| format!("[{:.1}, {:.1}]", p[0], p[1]))
            .collect();
        format!("[{}]", items.join(", "))
    }
}
