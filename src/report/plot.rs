//! Small plots drawn in pure Rust on an `image` canvas: stacked time-series panels that
//! share one x axis, and histograms. Text uses an embedded font (DejaVu Sans, see
//! `font/LICENSE`), so nothing depends on the system's fonts or libraries.
use std::sync::OnceLock;

use ab_glyph::{FontRef, PxScale};
use image::{Rgb, RgbImage};
use imageproc::drawing::{
    draw_antialiased_line_segment_mut, draw_filled_rect_mut, draw_line_segment_mut, draw_text_mut,
    text_size,
};
use imageproc::pixelops::interpolate;
use imageproc::rect::Rect;

use crate::session::score::percentile;

pub const BLUE: Rgb<u8> = Rgb([31, 119, 180]);
pub const ORANGE: Rgb<u8> = Rgb([255, 127, 14]);
pub const GREEN: Rgb<u8> = Rgb([44, 160, 44]);
pub const RED: Rgb<u8> = Rgb([214, 39, 40]);
pub const GREY: Rgb<u8> = Rgb([120, 120, 120]);
const WHITE: Rgb<u8> = Rgb([255, 255, 255]);
const INK: Rgb<u8> = Rgb([30, 30, 30]);
const GRID: Rgb<u8> = Rgb([228, 228, 228]);
const LEFT: i32 = 78;
const RIGHT: i32 = 18;
const TOP: i32 = 30;
const BOTTOM: i32 = 44;
const TEXT_PX: f32 = 15.0;

fn font() -> Option<&'static FontRef<'static>> {
    static FONT: OnceLock<Option<FontRef<'static>>> = OnceLock::new();
    FONT.get_or_init(|| FontRef::try_from_slice(include_bytes!("font/DejaVuSans.ttf")).ok())
        .as_ref()
}

/// How a series is drawn.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Style {
    /// Joined points; a non-finite value breaks the line.
    Line,
    /// A small square per point.
    Dots,
    /// Both: a lone point between gaps still shows.
    LineDots,
}

#[derive(Debug, Clone)]
pub struct Series {
    pub label: String,
    pub points: Vec<[f64; 2]>,
    pub colour: Rgb<u8>,
    pub style: Style,
}

/// One panel: a y axis and its series.
#[derive(Debug, Clone, Default)]
pub struct Panel {
    pub title: String,
    pub y_label: String,
    pub series: Vec<Series>,
    /// Fixed y range; default: the data's, with a margin.
    pub y_range: Option<[f64; 2]>,
}

/// Panels stacked vertically over one shared x axis labelled `x_label`.
pub fn panels(panels: &[Panel], x_label: &str, width: u32, panel_height: u32) -> RgbImage {
    let height = panel_height * panels.len().max(1) as u32;
    let mut img = RgbImage::from_pixel(width, height, WHITE);
    let xs = panels
        .iter()
        .flat_map(|p| &p.series)
        .flat_map(|s| s.points.iter().map(|p| p[0]));
    let x_range = padded_range(xs, 0.0);
    for (k, panel) in panels.iter().enumerate() {
        let top = k as i32 * panel_height as i32;
        let ys = panel
            .series
            .iter()
            .flat_map(|s| s.points.iter().map(|p| p[1]));
        let y_range = panel.y_range.unwrap_or_else(|| padded_range(ys, 0.06));
        let area = Area {
            x0: LEFT,
            y0: top + TOP,
            x1: width as i32 - RIGHT,
            y1: top + panel_height as i32 - BOTTOM,
            x_range,
            y_range,
        };
        area.axes(&mut img, &panel.title, x_label, &panel.y_label);
        for s in &panel.series {
            area.series(&mut img, s);
        }
        area.legend(&mut img, &panel.series);
    }
    img
}

/// A histogram of `values` in `bins` bins over [min, p99.5] (larger values counted in
/// the last bin), with the median and 99th percentile marked.
pub fn histogram(
    values: &[f64],
    bins: usize,
    title: &str,
    x_label: &str,
    width: u32,
    height: u32,
) -> RgbImage {
    let mut img = RgbImage::from_pixel(width, height, WHITE);
    let mut v: Vec<f64> = values.iter().copied().filter(|v| v.is_finite()).collect();
    v.sort_by(f64::total_cmp);
    // numpy's linear percentile, as the summary table quotes them.
    let quantile = |q: f64| (!v.is_empty()).then(|| percentile(&v, 100.0 * q));
    let (Some(lo), Some(hi)) = (v.first().copied(), quantile(0.995)) else {
        text(&mut img, LEFT, TOP, &format!("{title}: no data"), INK);
        return img;
    };
    let hi = if hi > lo { hi } else { lo + 1.0 };
    let bins = bins.max(1);
    let step = (hi - lo) / bins as f64;
    let mut counts = vec![0usize; bins];
    for &x in &v {
        counts[(((x - lo) / step) as usize).min(bins - 1)] += 1;
    }
    let top = counts.iter().copied().max().unwrap_or(1) as f64;
    let area = Area {
        x0: LEFT,
        y0: TOP,
        x1: width as i32 - RIGHT,
        y1: height as i32 - BOTTOM,
        x_range: [lo, hi],
        y_range: [0.0, top * 1.08],
    };
    area.axes(&mut img, title, x_label, "frames");
    for (k, &c) in counts.iter().enumerate() {
        let (a, b) = (
            area.px(lo + k as f64 * step),
            area.px(lo + (k + 1) as f64 * step),
        );
        let y = area.py(c as f64);
        if c > 0 && b > a {
            let h = (area.y1 - y).max(1) as u32;
            draw_filled_rect_mut(&mut img, Rect::at(a, y).of_size((b - a) as u32, h), BLUE);
        }
    }
    for (q, name, colour) in [(0.5, "median", GREEN), (0.99, "p99", RED)] {
        if let Some(x) = quantile(q) {
            let px = area.px(x.min(hi));
            vline(&mut img, px, area.y0, area.y1, colour);
            let label = format!("{name} {}", tick_label(x, step / 10.0));
            let (w, _) = measure(&label);
            // Right of the line, or left of it near the right edge.
            let lx = if px + 4 + w as i32 > area.x1 {
                px - 4 - w as i32
            } else {
                px + 4
            };
            text(
                &mut img,
                lx,
                area.y0 + 2 + i32::from(q > 0.6) * 18,
                &label,
                colour,
            );
        }
    }
    img
}

/// The plotting rectangle and its data ranges.
struct Area {
    x0: i32,
    y0: i32,
    x1: i32,
    y1: i32,
    x_range: [f64; 2],
    y_range: [f64; 2],
}

impl Area {
    fn px(&self, x: f64) -> i32 {
        let [a, b] = self.x_range;
        self.x0 + ((x - a) / (b - a) * f64::from(self.x1 - self.x0)).round() as i32
    }

    fn py(&self, y: f64) -> i32 {
        let [a, b] = self.y_range;
        self.y1 - ((y - a) / (b - a) * f64::from(self.y1 - self.y0)).round() as i32
    }

    fn axes(&self, img: &mut RgbImage, title: &str, x_label: &str, y_label: &str) {
        let (x_ticks, x_step) = nice_ticks(self.x_range);
        let (y_ticks, y_step) = nice_ticks(self.y_range);
        for &x in &x_ticks {
            let px = self.px(x);
            vline(img, px, self.y0, self.y1, GRID);
            let label = tick_label(x, x_step);
            let (w, _) = measure(&label);
            text(img, px - w as i32 / 2, self.y1 + 6, &label, INK);
        }
        for &y in &y_ticks {
            let py = self.py(y);
            hline(img, self.x0, self.x1, py, GRID);
            let label = tick_label(y, y_step);
            let (w, _) = measure(&label);
            text(img, self.x0 - 6 - w as i32, py - 8, &label, INK);
        }
        hline(img, self.x0, self.x1, self.y1, INK);
        vline(img, self.x0, self.y0, self.y1, INK);
        text(img, self.x0, self.y0 - 24, title, INK);
        let (w, _) = measure(x_label);
        text(
            img,
            (self.x0 + self.x1) / 2 - w as i32 / 2,
            self.y1 + 24,
            x_label,
            GREY,
        );
        let (w, _) = measure(title);
        text(
            img,
            self.x0 + w as i32 + 12,
            self.y0 - 24,
            &format!("({y_label})"),
            GREY,
        );
    }

    fn series(&self, img: &mut RgbImage, s: &Series) {
        let inside = |p: &[f64; 2]| p[0].is_finite() && p[1].is_finite();
        if matches!(s.style, Style::Dots | Style::LineDots) {
            for p in s.points.iter().filter(|p| inside(p)) {
                let (x, y) = (self.px(p[0]), self.py(p[1]));
                draw_filled_rect_mut(img, Rect::at(x - 1, y - 1).of_size(3, 3), s.colour);
            }
        }
        match s.style {
            Style::Dots => {}
            Style::Line | Style::LineDots => {
                for pair in s.points.windows(2) {
                    if !(inside(&pair[0]) && inside(&pair[1])) {
                        continue;
                    }
                    let a = (self.px(pair[0][0]), self.py(pair[0][1]));
                    let b = (self.px(pair[1][0]), self.py(pair[1][1]));
                    for d in [0, 1] {
                        draw_antialiased_line_segment_mut(
                            img,
                            (a.0, a.1 + d),
                            (b.0, b.1 + d),
                            s.colour,
                            interpolate,
                        );
                    }
                }
            }
        }
    }

    fn legend(&self, img: &mut RgbImage, series: &[Series]) {
        let mut x = self.x1;
        for s in series.iter().rev() {
            let (w, _) = measure(&s.label);
            x -= w as i32 + 30;
            draw_filled_rect_mut(img, Rect::at(x, self.y0 - 17).of_size(14, 4), s.colour);
            text(img, x + 18, self.y0 - 24, &s.label, INK);
        }
    }
}

fn hline(img: &mut RgbImage, x0: i32, x1: i32, y: i32, c: Rgb<u8>) {
    draw_line_segment_mut(img, (x0 as f32, y as f32), (x1 as f32, y as f32), c);
}

fn vline(img: &mut RgbImage, x: i32, y0: i32, y1: i32, c: Rgb<u8>) {
    draw_line_segment_mut(img, (x as f32, y0 as f32), (x as f32, y1 as f32), c);
}

fn text(img: &mut RgbImage, x: i32, y: i32, s: &str, c: Rgb<u8>) {
    if let Some(font) = font() {
        draw_text_mut(img, c, x, y, PxScale::from(TEXT_PX), font, s);
    }
}

/// Caption text (13 px, dark grey), for pictures built around the plots.
pub fn small_text(img: &mut RgbImage, x: i32, y: i32, s: &str) {
    if let Some(font) = font() {
        draw_text_mut(img, INK, x, y, PxScale::from(13.0), font, s);
    }
}

fn measure(s: &str) -> (u32, u32) {
    font().map_or((0, 0), |f| text_size(PxScale::from(TEXT_PX), f, s))
}

/// The finite data's range, widened by `margin` of its span (a flat series gets +-1).
fn padded_range(values: impl Iterator<Item = f64>, margin: f64) -> [f64; 2] {
    let (lo, hi) = values
        .filter(|v| v.is_finite())
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), v| {
            (a.min(v), b.max(v))
        });
    if !lo.is_finite() {
        return [0.0, 1.0];
    }
    if hi - lo < 1e-12 {
        return [lo - 1.0, hi + 1.0];
    }
    let pad = (hi - lo) * margin;
    [lo - pad, hi + pad]
}

/// Round tick positions (steps of 1, 2 or 5 times a power of ten) inside `range`.
pub fn nice_ticks([lo, hi]: [f64; 2]) -> (Vec<f64>, f64) {
    let span = (hi - lo).abs().max(1e-12);
    let raw = span / 6.0;
    let power = 10f64.powf(raw.log10().floor());
    let step = [1.0, 2.0, 5.0, 10.0]
        .iter()
        .map(|m| m * power)
        .find(|s| *s >= raw)
        .unwrap_or(10.0 * power);
    let first = (lo / step).ceil() as i64;
    let last = (hi / step).floor() as i64;
    let ticks = (first..=last).map(|k| k as f64 * step).collect();
    (ticks, step)
}

/// A tick label with as many decimals as the step needs.
fn tick_label(v: f64, step: f64) -> String {
    let decimals = (-step.log10().floor()).clamp(0.0, 6.0) as usize;
    let v = if v.abs() < step * 1e-6 { 0.0 } else { v };
    format!("{v:.decimals$}")
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ticks_are_round_and_inside() {
        let (ticks, step) = nice_ticks([-3.2, 27.5]);
        assert_eq!(step, 10.0);
        assert_eq!(ticks, [0.0, 10.0, 20.0]);
        let (ticks, step) = nice_ticks([0.0, 1.0]);
        assert_eq!(step, 0.2);
        assert_eq!(ticks.len(), 6);
        assert_eq!(tick_label(0.4, 0.2), "0.4");
        assert_eq!(tick_label(1500.0, 500.0), "1500");
        assert_eq!(tick_label(-1e-17, 0.2), "0.0");
    }

    #[test]
    fn lines_land_where_the_data_is() {
        let series = Series {
            label: "force".into(),
            points: vec![[0.0, 0.0], [1.0, 10.0], [2.0, f64::NAN], [3.0, 0.0]],
            colour: RED,
            style: Style::Line,
        };
        let panel = Panel {
            title: "t".into(),
            y_label: "nN".into(),
            series: vec![series],
            y_range: Some([0.0, 10.0]),
        };
        let img = panels(&[panel], "s", 400, 200);
        assert_eq!(img.dimensions(), (400, 200));
        // (1, 10) is the top of the plotting area at a third of its width.
        let x = LEFT + (400 - LEFT - RIGHT) / 3;
        let red = |x: i32, y: i32| {
            let p = img.get_pixel(x as u32, y as u32);
            p[0] > 150 && p[1] < 120
        };
        assert!((TOP - 1..=TOP + 2).any(|y| red(x, y)));
        // The NaN breaks the line: nothing red between x = 2 and 3 above the baseline.
        let x_gap = LEFT + (400 - LEFT - RIGHT) * 5 / 6;
        assert!(!(TOP..200 - BOTTOM - 3).any(|y| red(x_gap, y)));
    }

    #[test]
    fn histogram_bars_count_values() {
        let values: Vec<f64> = (0..100).map(|k| if k < 90 { 1.0 } else { 5.0 }).collect();
        let img = histogram(&values, 4, "latency", "ms", 400, 200);
        let blue = |x: i32| {
            (TOP..200 - BOTTOM)
                .filter(|&y| *img.get_pixel(x as u32, y as u32) == BLUE)
                .count()
        };
        let w = (400 - LEFT - RIGHT) / 4;
        let (first, last) = (blue(LEFT + w / 2), blue(LEFT + 7 * w / 2));
        assert!(first > 5 * last && last > 0, "{first} vs {last}");
        assert!(histogram(&[], 4, "latency", "ms", 200, 100).width() == 200);
    }
}
