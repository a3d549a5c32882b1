//! `nanoforce calibrate`: refines a person's clicks on the calibration frame and prints
//! the `[tracker.calibration]` block, with an overlay PNG to check it by eye: the AFM
//! pyramid's three edges, or a rigid probe's named edges.
use std::path::PathBuf;
use std::process::ExitCode;

use anyhow::Context;
use clap::Args;

use crate::config::{CalibrationConfig, PixelOrigin, Threshold, TrackerConfig, DEFAULT_WINDOW_DEG};
use crate::session::frames::load_gray;
use crate::vision::{
    auto_calibrate, auto_calibrate_rigid, calibrate_rigid, draw_calibration,
    draw_rigid_calibration, Calibration, Edge, RigidTemplate, NAMED_EDGE_COLOURS,
};

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
overlay all the more.\n\n\
Any other rigid probe (a tungsten needle, a tipless cantilever, a gripper jaw) is \
calibrated from two or more named straight edges, each given as --edge NAME=\"X,Y X,Y \
...\", and --apex-edges naming the two that meet at its tip point. The block then holds \
apex and [tracker.calibration.edges]; the overlay draws each edge in the colour the \
block names. With --auto --rigid --apex X,Y (a pixel on or near its tip point), \
calibrate follows the probe's outline from there, edge after edge, until it leaves the \
frame; the edges are named e1, e2, ... in their order around the outline (rename them \
in the block). Without --apex, the tip point is a corner of the end that a body \
entering from a frame side (either polarity) reaches into the frame with, along its \
axis; give --apex for another corner. It refuses an outline without an edge away from \
the tip point, or whose edges do not verify as one probe on the reference.",
    after_help = "Example:\n  nanoforce calibrate --image reference.png \\\n      \
--red 156.8,33.4 228.3,57.3 --blue 230.7,114.2 260.6,192.0 --green 282.5,199.8 314.8,142.9 \\\n      \
--overlay calibration.png >> probe.toml\n  \
nanoforce calibrate --image reference.png --auto --apex 270,214 >> probe.toml\n  \
nanoforce calibrate --image needle.png --edge \"upper=120,210.5 260,236 400,261.5\" \\\n      \
--edge \"lower=120,420 260,389.5 400,359\" --edge \"end=505,280 507.5,310 510,340\" \\\n      \
--apex-edges upper,end >> needle.toml\n  \
nanoforce calibrate --image needle.png --auto --rigid --apex 505,280 >> needle.toml"
)]
pub struct CalibrateArgs {
    /// The reference frame (PNG, TIFF or PGM).
    #[arg(long, value_name = "FILE")]
    pub image: PathBuf,
    /// Pixels on the red edge, as X,Y (two or more).
    #[arg(long, value_name = "X,Y", num_args = 2.., required_unless_present_any = ["auto", "edges"], value_parser = parse_point)]
    pub red: Vec<[f64; 2]>,
    /// Pixels on the blue edge, as X,Y (two or more).
    #[arg(long, value_name = "X,Y", num_args = 2.., required_unless_present_any = ["auto", "edges"], value_parser = parse_point)]
    pub blue: Vec<[f64; 2]>,
    /// Pixels on the green edge, as X,Y (two or more).
    #[arg(long, value_name = "X,Y", num_args = 2.., required_unless_present_any = ["auto", "edges"], value_parser = parse_point)]
    pub green: Vec<[f64; 2]>,
    /// Find the three edges automatically: from the pixel given by --apex, or without
    /// it when the probe is the dominant body entering from a frame side.
    #[arg(long, conflicts_with_all = ["red", "blue", "green", "edges"])]
    pub auto: bool,
    /// A pixel on or near the apex (blue meets green; a rigid probe's tip point), as
    /// X,Y, for --auto.
    #[arg(long, value_name = "X,Y", requires = "auto", value_parser = parse_point)]
    pub apex: Option<[f64; 2]>,
    /// With --auto: a rigid probe of straight edges, found around its outline from
    /// --apex, or from a corner of the end of the body entering the frame.
    #[arg(long, requires = "auto")]
    pub rigid: bool,
    /// A rigid probe's named edge and two or more pixels on it, as "NAME=X,Y X,Y ..."
    /// (repeat for each edge, two or more; with --apex-edges).
    #[arg(long = "edge", value_name = "NAME=X,Y X,Y...", requires = "apex_edges",
          conflicts_with_all = ["red", "blue", "green"], value_parser = parse_named_edge)]
    pub edges: Vec<(String, Vec<[f64; 2]>)>,
    /// The two named edges that meet at the rigid probe's tip point, as A,B.
    #[arg(long, value_name = "A,B", requires = "edges", value_parser = parse_apex_edges)]
    pub apex_edges: Option<[String; 2]>,
    /// Where to write the overlay (default: calibration-overlay.png beside the image).
    #[arg(long, value_name = "FILE")]
    pub overlay: Option<PathBuf>,
    /// Binarisation level 0..=255 or "otsu", as [tracker] threshold (the pyramid's
    /// calibration only).
    #[arg(long, default_value = "otsu", value_parser = parse_threshold, conflicts_with = "edges")]
    pub threshold: Threshold,
    /// Search half-window, degrees, as [tracker] window_deg.
    #[arg(long, default_value_t = DEFAULT_WINDOW_DEG, conflicts_with = "edges")]
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

/// A name is what TOML takes as a bare key: letters, digits, `_` and `-`.
fn parse_name(name: &str) -> Result<String, String> {
    let name = name.trim();
    if name.is_empty()
        || !name
            .chars()
            .all(|c| c.is_ascii_alphanumeric() || c == '_' || c == '-')
    {
        return Err(format!(
            "{name:?} is not an edge name (letters, digits, _ and -)"
        ));
    }
    Ok(name.to_string())
}

fn parse_named_edge(s: &str) -> Result<(String, Vec<[f64; 2]>), String> {
    let (name, points) = s
        .split_once('=')
        .ok_or_else(|| format!("{s:?} is not NAME=X,Y X,Y ..."))?;
    let points = points
        .split_whitespace()
        .map(parse_point)
        .collect::<Result<Vec<_>, _>>()?;
    if points.len() < 2 {
        return Err(format!("{s:?}: an edge needs two or more pixels"));
    }
    Ok((parse_name(name)?, points))
}

fn parse_apex_edges(s: &str) -> Result<[String; 2], String> {
    let (a, b) = s
        .split_once(',')
        .ok_or_else(|| format!("{s:?} is not A,B (two edge names)"))?;
    Ok([parse_name(a)?, parse_name(b)?])
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
    if let Some(apex) = &args.apex_edges {
        return calibrate_named(&args, &reference, apex, &overlay_path);
    }
    if args.rigid {
        return auto_calibrate_named(&args, &reference, &overlay_path);
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

/// A rigid probe's calibration from its named edges: the block printed, the overlay
/// written.
fn calibrate_named(
    args: &CalibrateArgs,
    reference: &image::GrayImage,
    apex: &[String; 2],
    overlay_path: &std::path::Path,
) -> anyhow::Result<ExitCode> {
    let clicks = CalibrationConfig {
        reference_image: args.image.clone(),
        edges: args.edges.clone(),
        apex: Some(apex.clone()),
    };
    let clicked = clicks.clone().counted_from(args.pixel_origin);
    let template = calibrate_rigid(
        reference,
        &clicked.edges,
        [apex[0].as_str(), apex[1].as_str()],
    )
    .with_context(|| format!("calibrating on {}", args.image.display()))?;
    print!("{}", named_block(&clicks, &template, args.pixel_origin));
    draw_rigid_calibration(reference, &template)
        .save(overlay_path)
        .with_context(|| format!("writing {}", overlay_path.display()))?;
    eprintln!(
        "overlay written to {}: check each named edge (in the colour the block names) and \
         the apex",
        overlay_path.display()
    );
    Ok(ExitCode::SUCCESS)
}

/// A rigid probe's calibration from one pixel near its tip point, or from none
/// (`--auto --rigid`): the block printed with the edges found as clicks, the overlay written.
fn auto_calibrate_named(
    args: &CalibrateArgs,
    reference: &image::GrayImage,
    overlay_path: &std::path::Path,
) -> anyhow::Result<ExitCode> {
    let origin = args.pixel_origin;
    let apex = args.apex.map(|p| origin.input(p));
    let (found, template) = auto_calibrate_rigid(reference, apex)
        .with_context(|| format!("calibrating on {}", args.image.display()))?;
    let clicks = CalibrationConfig {
        reference_image: args.image.clone(),
        edges: found
            .edges
            .into_iter()
            .map(|(name, points)| (name, points.into_iter().map(|p| origin.output(p)).collect()))
            .collect(),
        apex: Some(found.apex),
    };
    print!("{}", named_block(&clicks, &template, origin));
    draw_rigid_calibration(reference, &template)
        .save(overlay_path)
        .with_context(|| format!("writing {}", overlay_path.display()))?;
    eprintln!(
        "overlay written to {}: check that each edge found (in the colour the block names) \
         lies on the probe and the apex on its tip point",
        overlay_path.display()
    );
    Ok(ExitCode::SUCCESS)
}

/// A line's direction, degrees CCW on screen, in (-90, 90].
fn line_deg(d: [f64; 2]) -> f64 {
    half_turn((-d[1]).atan2(d[0]).to_degrees())
}

/// An angle between lines, degrees, brought into (-90, 90].
fn half_turn(deg: f64) -> f64 {
    if deg > 90.0 {
        deg - 180.0
    } else if deg <= -90.0 {
        deg + 180.0
    } else {
        deg
    }
}

/// The block's first lines: the section and the reference image, by its file name.
fn block_head(clicks: &CalibrationConfig) -> String {
    let name = clicks.reference_image.file_name().map_or_else(
        || clicks.reference_image.display().to_string(),
        |n| n.to_string_lossy().to_string(),
    );
    format!("[tracker.calibration]\nreference_image = {name:?}  # relative to probe.toml\n")
}

/// A rigid probe's `[tracker.calibration]` block: the apex edges and each edge's
/// clicks (as given, counted from `origin`) as keys; what the reference shows of each
/// edge as comments.
pub fn named_block(
    clicks: &CalibrationConfig,
    template: &RigidTemplate,
    origin: PixelOrigin,
) -> String {
    let points = CalibrationConfig::toml_points;
    let mut out = block_head(clicks);
    let [a, b] = template.apex_edges.map(|k| clicks.edges[k].0.as_str());
    out.push_str(&format!(
        "apex = [{a:?}, {b:?}]          # the tip point: where these two edges meet\n\
         [tracker.calibration.edges]\n"
    ));
    for (edge, clicked) in &clicks.edges {
        out.push_str(&format!("{edge} = {}\n", points(clicked)));
    }
    out.push_str(
        "# Refined on the reference image: each edge's direction (degrees, CCW on screen),\n\
         # the clicks' own direction, the probe's side and its step (grey levels), the\n\
         # length the reference shows, and the colour the overlay draws it in:\n",
    );
    for ((edge, clicked), (fitted, (colour, _))) in clicks
        .edges
        .iter()
        .zip(template.edges.iter().zip(NAMED_EDGE_COLOURS))
    {
        // Along the edge: its normal turned a quarter.
        let refined = line_deg([fitted.normal[1], -fitted.normal[0]]);
        let (p, q) = (clicked[0], clicked[clicked.len() - 1]);
        let by_clicks = line_deg([q[0] - p[0], q[1] - p[1]]);
        let off = half_turn(by_clicks - refined);
        let side = if fitted.polarity > 0.0 {
            "brighter"
        } else {
            "darker"
        };
        let open = match fitted.open {
            [false, false] => "",
            _ => ", runs on out of the frame",
        };
        out.push_str(&format!(
            "#   {edge:<8} {refined:>8.3}   (clicks {by_clicks:>8.3}, {off:+.3})   {side} \
             ({:+.0})   {:.0} px{open}   {colour}\n",
            fitted.polarity * fitted.step,
            fitted.length()
        ));
    }
    let apex = origin.output(template.apex);
    out.push_str(&format!(
        "# Apex ({a} meets {b}): ({:.2}, {:.2}) px\n\
         # The reference's own edges leave each frame's rotation +- {:.4} deg\n",
        apex[0],
        apex[1],
        template.angle_sigma_rad.to_degrees()
    ));
    if origin != PixelOrigin::Centre {
        out.push_str(&format!(
            "# Pixels counted from the top-left pixel's {origin}: \
             [tracker] needs pixel_origin = \"{origin}\"\n"
        ));
    }
    out
}

/// The `[tracker.calibration]` block: clicks (as given, counted from `origin`) as keys,
/// refined orientations as comments.
pub fn calibration_block(
    clicks: &CalibrationConfig,
    calibration: &Calibration,
    origin: PixelOrigin,
) -> String {
    let points = CalibrationConfig::toml_points;
    let mut out = block_head(clicks);
    for (edge, clicked) in &clicks.edges {
        out.push_str(&format!("{edge} = {}\n", points(clicked)));
    }
    out.push_str(
        "# Refined on the reference image (degrees, CCW on screen, +- the standard error\n\
         # of the reading, the background beside the edge included, and the pixel noise's\n\
         # share alone: where the two differ, the ground beside the edge limits the reading);\n\
         # from the clicks alone:\n",
    );
    for edge in [Edge::Red, Edge::Blue, Edge::Green] {
        let e = calibration.edge(edge);
        out.push_str(&format!(
            "#   {:<5} {:>9.3} +- {:.3} (noise {:.3})   (clicks {:>9.3}, {:+.3})\n",
            edge.name(),
            e.orientation_deg,
            e.orientation_sigma_deg,
            e.orientation_noise_sigma_deg,
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
