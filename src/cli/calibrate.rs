//! `nanoforce calibrate`: refines a person's clicks on the calibration frame and prints
//! the `[tracker.calibration]` block, with an overlay PNG to check it by eye.
use std::path::PathBuf;
use std::process::ExitCode;

use anyhow::Context;
use clap::Args;

use crate::config::{CalibrationConfig, PixelOrigin, Threshold, TrackerConfig, DEFAULT_WINDOW_DEG};
use crate::session::frames::load_gray;
use crate::vision::{auto_calibrate, draw_calibration, Calibration, Edge};

/// Refine clicked tip edges on a reference frame; print the calibration block.
#[derive(Debug, Args)]
#[command(
    long_about = "Calibrates the tracker on a reference frame: the undeformed probe, \
which defines angle zero.\n\n\
Click two or more pixels on each of the three tip edges (x right, y down, origin at the \
top-left pixel's centre) in any image viewer:\n  \
red   = the beam's upper face near the free end\n  \
blue  = the pyramid's back face, from its base to the apex\n  \
green = the pyramid's front face, from the apex back to the beam\n\n\
Clicks are off by up to a pixel, which would put each edge's orientation off by tenths of \
a degree; calibrate refines every edge on the image's grey levels. It prints the \
[tracker.calibration] block for probe.toml (the clicks, with the refined orientations \
as comments) and writes an overlay PNG with the refined edges in red, blue and green and \
the apex marked: look at it before a session.\n\n\
With --auto, calibrate finds the three edges itself, from one pixel on or near the apex \
(--apex X,Y), or, when the probe is the dominant body entering from a frame side, from \
none; the block it prints holds the points it found on each edge as clicks. Check the \
overlay all the more.",
    after_help = "Example:\n  nanoforce calibrate --image reference.png \\\n      \
--red 156.8,33.4 228.3,57.3 --blue 230.7,114.2 260.6,192.0 --green 282.5,199.8 314.8,142.9 \\\n      \
--overlay calibration.png >> probe.toml\n  \
nanoforce calibrate --image reference.png --auto --apex 270,214 >> probe.toml"
)]
pub struct CalibrateArgs {
    /// The reference frame (PNG, TIFF or PGM).
    #[arg(long, value_name = "FILE")]
    pub image: PathBuf,
    /// Pixels on the red edge, as X,Y (two or more).
    #[arg(long, value_name = "X,Y", num_args = 2.., required_unless_present = "auto", value_parser = parse_point)]
    pub red: Vec<[f64; 2]>,
    /// Pixels on the blue edge, as X,Y (two or more).
    #[arg(long, value_name = "X,Y", num_args = 2.., required_unless_present = "auto", value_parser = parse_point)]
    pub blue: Vec<[f64; 2]>,
    /// Pixels on the green edge, as X,Y (two or more).
    #[arg(long, value_name = "X,Y", num_args = 2.., required_unless_present = "auto", value_parser = parse_point)]
    pub green: Vec<[f64; 2]>,
    /// Find the three edges automatically: from the pixel given by --apex, or without
    /// it when the probe is the dominant body entering from a frame side.
    #[arg(long, conflicts_with_all = ["red", "blue", "green"])]
    pub auto: bool,
    /// A pixel on or near the apex (blue meets green), as X,Y, for --auto.
    #[arg(long, value_name = "X,Y", requires = "auto", value_parser = parse_point)]
    pub apex: Option<[f64; 2]>,
    /// Where to write the overlay (default: calibration-overlay.png beside the image).
    #[arg(long, value_name = "FILE")]
    pub overlay: Option<PathBuf>,
    /// Binarisation level 0..=255 or "otsu", as [tracker] threshold.
    #[arg(long, default_value = "otsu", value_parser = parse_threshold)]
    pub threshold: Threshold,
    /// Search half-window, degrees, as [tracker] window_deg.
    #[arg(long, default_value_t = DEFAULT_WINDOW_DEG)]
    pub window_deg: f64,
    /// Where the clicks (and the printed apex) count pixels from: "centre" (the default:
    /// the top-left pixel's centre is 0,0) or "corner" (its corner is; ImageJ), as
    /// [tracker] pixel_origin.
    #[arg(long, default_value = "centre", value_name = "ORIGIN", value_parser = parse_origin)]
    pub pixel_origin: PixelOrigin,
}

fn parse_origin(s: &str) -> Result<PixelOrigin, String> {
    PixelOrigin::parse(s).ok_or_else(|| format!("{s:?} is neither \"centre\" nor \"corner\""))
}

fn parse_point(s: &str) -> Result<[f64; 2], String> {
    let (x, y) = s
        .split_once(',')
        .ok_or_else(|| format!("{s:?} is not X,Y"))?;
    let parse = |v: &str| {
        v.trim()
            .parse::<f64>()
            .ok()
            .filter(|v| v.is_finite())
            .ok_or_else(|| format!("{s:?}: {v:?} is not a finite number"))
    };
    Ok([parse(x)?, parse(y)?])
}

fn parse_threshold(s: &str) -> Result<Threshold, String> {
    if s.eq_ignore_ascii_case("otsu") {
        return Ok(Threshold::Otsu);
    }
    s.parse::<u8>()
        .map(Threshold::Level)
        .map_err(|_| format!("{s:?} is neither a grey level 0..=255 nor \"otsu\""))
}

pub fn run(args: CalibrateArgs) -> anyhow::Result<ExitCode> {
    let overlay_path = args
        .overlay
        .clone()
        .unwrap_or_else(|| args.image.with_file_name("calibration-overlay.png"));
    if super::replay::resolved(&overlay_path) == super::replay::resolved(&args.image) {
        anyhow::bail!(
            "the overlay {} is the --image itself: refusing to overwrite the reference \
             frame; give another --overlay",
            overlay_path.display()
        );
    }
    let reference = load_gray(&args.image)?;
    let window = crate::config::WINDOW_DEG;
    if !window.contains(args.window_deg) {
        anyhow::bail!(
            "--window-deg must be {window}, as [tracker] window_deg; got {}",
            args.window_deg
        );
    }
    let tracker = TrackerConfig {
        threshold: args.threshold,
        window_deg: args.window_deg,
        ..TrackerConfig::default()
    };
    let origin = args.pixel_origin;
    let (clicks, calibration) = if args.auto {
        let apex = args.apex.map(|p| origin.input(p));
        let (found, calibration) = auto_calibrate(&reference, apex, &tracker)
            .with_context(|| format!("calibrating on {}", args.image.display()))?;
        let mut clicks = found.config(args.image.clone());
        for (_, points) in clicks.edges.iter_mut() {
            for p in points.iter_mut() {
                *p = origin.output(*p);
            }
        }
        (clicks, calibration)
    } else {
        let clicks =
            CalibrationConfig::pyramid(args.image.clone(), args.red, args.blue, args.green);
        let clicked = clicks.clone().counted_from(origin);
        let calibration = Calibration::from_reference(&reference, &clicked, &tracker)
            .with_context(|| format!("calibrating on {}", args.image.display()))?;
        (clicks, calibration)
    };
    print!("{}", calibration_block(&clicks, &calibration, origin));
    draw_calibration(&reference, &calibration)
        .save(&overlay_path)
        .with_context(|| format!("writing {}", overlay_path.display()))?;
    eprintln!(
        "overlay written to {}: check the three edges and the apex",
        overlay_path.display()
    );
    Ok(ExitCode::SUCCESS)
}

/// The `[tracker.calibration]` block: clicks (as given, counted from `origin`) as keys,
/// refined orientations as comments.
pub fn calibration_block(
    clicks: &CalibrationConfig,
    calibration: &Calibration,
    origin: PixelOrigin,
) -> String {
    let points = CalibrationConfig::toml_points;
    let name = clicks.reference_image.file_name().map_or_else(
        || clicks.reference_image.display().to_string(),
        |n| n.to_string_lossy().to_string(),
    );
    let mut out =
        format!("[tracker.calibration]\nreference_image = {name:?}  # relative to probe.toml\n");
    for (edge, clicked) in &clicks.edges {
        out.push_str(&format!("{edge} = {}\n", points(clicked)));
    }
    out.push_str(
        "# Refined on the reference image (degrees, CCW on screen, +- the standard error\n\
         # from the reference's noise); from the clicks alone:\n",
    );
    for edge in [Edge::Red, Edge::Blue, Edge::Green] {
        let e = calibration.edge(edge);
        out.push_str(&format!(
            "#   {:<5} {:>9.3} +- {:.3}   (clicks {:>9.3}, {:+.3})\n",
            edge.name(),
            e.orientation_deg,
            e.orientation_sigma_deg,
            e.clicked_orientation_deg,
            e.clicked_orientation_deg - e.orientation_deg
        ));
    }
    let side = |edge: Edge| {
        let e = calibration.edge(edge);
        let word = if e.polarity > 0.0 {
            "brighter"
        } else {
            "darker"
        };
        format!("{} {word} ({:+.0})", edge.name(), e.contrast)
    };
    out.push_str(&format!(
        "# The probe's side of each edge, grey levels: {}, {}, {}\n",
        side(Edge::Red),
        side(Edge::Blue),
        side(Edge::Green)
    ));
    let apex = origin.output(calibration.apex_px());
    out.push_str(&format!(
        "# Apex (blue meets green): ({:.2}, {:.2}) px\n",
        apex[0], apex[1]
    ));
    out.push_str(&match calibration.beam_px() {
        Some(px) => {
            format!("# Beam thickness: {px:.1} px (checked on every frame)\n")
        }
        None => "# Beam thickness: not measured, the reference shows the beam's lower face\n\
                 # neither behind the pyramid nor at the free end; a probe of another beam\n\
                 # thickness is not told apart. Take a reference that shows it for that check.\n"
            .to_string(),
    });
    if origin != PixelOrigin::Centre {
        out.push_str(&format!(
            "# Pixels counted from the top-left pixel's {origin}: \
             [tracker] needs pixel_origin = \"{origin}\"\n"
        ));
    }
    out
}
