//! What an SEM wrote about a frame: pixel size, magnification and horizontal field width
//! (HFW), read from the private tags of its TIFF files.
//!
//! - FEI / Thermo Fisher: INI text in tag 34682 (or 34680 on older instruments), values
//!   in SI units: `[Scan] PixelWidth` (m), `[EBeam] HFW` or `[Scan] HorFieldsize` (m),
//!   `[Image] MagCanvasRealWidth` (m, the display width magnification refers to).
//! - Zeiss: tag 34118 (`CZ_SEM`), name/value line pairs such as `AP_PIXEL_SIZE` /
//!   `Pixel Size = 12.3 nm`, `AP_MAG` / `Mag = 2.00 K X`, `AP_WIDTH` / `Width = 114.3 µm`.
//!
//! What is missing is derived when possible (pixel size from HFW and the image width and
//! back; magnification from the 127 mm display width of docs/conventions.md). Metadata
//! that cannot be read is never an error: [`SemMetadata::warnings`] says what was wrong
//! and the affected values stay empty.
use std::fs::File;
use std::io::BufReader;
use std::path::Path;

use tiff::decoder::Decoder;
use tiff::tags::{Tag, Type};

/// FEI / Thermo INI metadata (Helios and later).
pub const TAG_FEI: u16 = 34682;
/// FEI INI metadata on older instruments.
pub const TAG_FEI_OLD: u16 = 34680;
/// Zeiss `CZ_SEM` metadata.
pub const TAG_ZEISS: u16 = 34118;
/// The display width magnification is quoted for when the SEM does not say
/// (docs/conventions.md:
/// HFW = 127 mm / magnification).
pub const DISPLAY_WIDTH_UM: f64 = 127_000.0;
/// Longest metadata text read; longer tags are truncated (with a warning).
const MAX_TAG_BYTES: u64 = 1 << 20;
/// Pixel size and HFW / width disagreeing by more than this is reported.
const CONSISTENCY: f64 = 0.05;

/// Which instrument wrote the metadata.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SemVendor {
    Fei,
    Zeiss,
}

/// Scale information of one frame; every value may be missing.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct SemMetadata {
    pub vendor: Option<SemVendor>,
    pub pixel_size_um: Option<f64>,
    pub magnification: Option<f64>,
    pub hfw_um: Option<f64>,
    /// What could not be read, for the user; never fatal.
    pub warnings: Vec<String>,
}

impl SemMetadata {
    /// Frame pixels per micrometre.
    pub fn px_per_um(&self) -> Option<f64> {
        self.pixel_size_um.map(|s| 1.0 / s)
    }
}

/// Reads the SEM metadata of a TIFF file; other files (and TIFFs without SEM tags) give
/// empty metadata without warnings.
pub fn read_sem_metadata(path: &Path) -> SemMetadata {
    let is_tiff = path
        .extension()
        .and_then(|e| e.to_str())
        .is_some_and(|e| e.eq_ignore_ascii_case("tif") || e.eq_ignore_ascii_case("tiff"));
    if !is_tiff {
        return SemMetadata::default();
    }
    match read_tiff_tags(path) {
        Ok(meta) => meta,
        Err(reason) => SemMetadata {
            warnings: vec![format!("SEM metadata not read: {reason}")],
            ..SemMetadata::default()
        },
    }
}

fn read_tiff_tags(path: &Path) -> Result<SemMetadata, String> {
    let file = File::open(path).map_err(|e| e.to_string())?;
    let mut decoder = Decoder::new(BufReader::new(file)).map_err(|e| e.to_string())?;
    let (width_px, _) = decoder.dimensions().map_err(|e| e.to_string())?;
    let mut warnings = Vec::new();
    for (tag, vendor) in [
        (TAG_FEI, SemVendor::Fei),
        (TAG_FEI_OLD, SemVendor::Fei),
        (TAG_ZEISS, SemVendor::Zeiss),
    ] {
        match tag_text(&mut decoder, tag) {
            Ok(None) => continue,
            Ok(Some(text)) => {
                let mut meta = match vendor {
                    SemVendor::Fei => parse_fei(&text, width_px),
                    SemVendor::Zeiss => parse_zeiss(&text, width_px),
                };
                warnings.append(&mut meta.warnings);
                meta.warnings = warnings;
                return Ok(meta);
            }
            Err(reason) => warnings.push(format!("tag {tag}: {reason}")),
        }
    }
    Ok(SemMetadata {
        warnings,
        ..SemMetadata::default()
    })
}

/// The text of a private tag (ASCII, BYTE or UNDEFINED), Latin-1 when not UTF-8.
fn tag_text<R: std::io::Read + std::io::Seek>(
    decoder: &mut Decoder<R>,
    tag: u16,
) -> Result<Option<String>, String> {
    let mut ifd = decoder.image_ifd();
    let Some(entry) = ifd.find_entry(Tag::Unknown(tag)) else {
        return Ok(None);
    };
    if !matches!(
        entry.field_type(),
        Type::ASCII | Type::BYTE | Type::UNDEFINED
    ) {
        return Err(format!("holds {:?} values, not text", entry.field_type()));
    }
    let len = entry.count().min(MAX_TAG_BYTES);
    let mut bytes = vec![0u8; len as usize];
    ifd.find_tag_bytes(Tag::Unknown(tag), &mut bytes, 0)
        .map_err(|e| e.to_string())?;
    let text = match String::from_utf8(bytes) {
        Ok(s) => s,
        Err(e) => e.into_bytes().iter().map(|&b| char::from(b)).collect(),
    };
    let text = text.trim_matches(char::from(0)).to_string();
    if text.trim().is_empty() {
        return Err("is empty".into());
    }
    Ok(Some(text))
}

/// FEI / Thermo INI text. Values are in metres.
pub fn parse_fei(text: &str, width_px: u32) -> SemMetadata {
    let mut found = Found::default();
    let mut section = String::new();
    for line in text.lines() {
        let line = line.trim();
        if let Some(name) = line.strip_prefix('[').and_then(|l| l.strip_suffix(']')) {
            section = name.trim().to_string();
            continue;
        }
        let Some((key, value)) = line.split_once('=') else {
            continue;
        };
        let slot = match (section.as_str(), key.trim()) {
            ("Scan", "PixelWidth") | ("EScan", "PixelWidth") => &mut found.pixel_size,
            ("EBeam", "HFW") | ("Scan", "HorFieldsize") | ("EScan", "HorFieldsize") => {
                &mut found.hfw
            }
            ("Image", "MagCanvasRealWidth") => &mut found.display_width,
            _ => continue,
        };
        if slot.is_none() {
            *slot = Some((
                format!("[{section}] {}", key.trim()),
                value.trim().to_string(),
            ));
        }
    }
    let mut meta = SemMetadata {
        vendor: Some(SemVendor::Fei),
        ..SemMetadata::default()
    };
    let metres = |v: &str| v.parse::<f64>().ok().map(|m| m * 1e6);
    let pixel = found
        .pixel_size
        .and_then(|kv| meta.value(kv, metres, PIXEL_UM));
    let hfw = found.hfw.and_then(|kv| meta.value(kv, metres, HFW_UM));
    let display = found
        .display_width
        .and_then(|kv| meta.value(kv, metres, DISPLAY_UM));
    let magnification = match (display, hfw.or(pixel.map(|p| p * f64::from(width_px)))) {
        (Some(d), Some(h)) => Some(d / h),
        _ => None,
    };
    meta.complete(pixel, hfw, magnification, width_px);
    meta
}

/// Zeiss `CZ_SEM` text: lines `Name = value unit` (the `AP_...` lines name them).
pub fn parse_zeiss(text: &str, width_px: u32) -> SemMetadata {
    let mut found = Found::default();
    for line in text.lines() {
        let Some((key, value)) = line.split_once('=') else {
            continue;
        };
        let slot = match key.trim() {
            "Pixel Size" => &mut found.pixel_size,
            "Mag" => &mut found.magnification,
            "Width" => &mut found.hfw,
            _ => continue,
        };
        if slot.is_none() {
            *slot = Some((key.trim().to_string(), value.trim().to_string()));
        }
    }
    let mut meta = SemMetadata {
        vendor: Some(SemVendor::Zeiss),
        ..SemMetadata::default()
    };
    let pixel = found
        .pixel_size
        .and_then(|kv| meta.value(kv, parse_length_um, PIXEL_UM));
    let hfw = found
        .hfw
        .and_then(|kv| meta.value(kv, parse_length_um, HFW_UM));
    let magnification = found
        .magnification
        .and_then(|kv| meta.value(kv, parse_magnification, MAGNIFICATION));
    meta.complete(pixel, hfw, magnification, width_px);
    meta
}

/// Plausible ranges: pixel size 1 pm..1 mm, field width 10 nm..10 cm, magnification 1..1e8.
const PIXEL_UM: (f64, f64) = (1e-6, 1e3);
const HFW_UM: (f64, f64) = (1e-2, 1e5);
const MAGNIFICATION: (f64, f64) = (1.0, 1e8);
/// The display width magnification refers to: 1 mm..10 m.
const DISPLAY_UM: (f64, f64) = (1e3, 1e7);

/// (where it was found, the raw value) per quantity.
#[derive(Default)]
struct Found {
    pixel_size: Option<(String, String)>,
    hfw: Option<(String, String)>,
    magnification: Option<(String, String)>,
    display_width: Option<(String, String)>,
}

impl SemMetadata {
    /// Parses one value; a value that does not parse or is implausible is a warning.
    fn value(
        &mut self,
        (key, raw): (String, String),
        parse: impl Fn(&str) -> Option<f64>,
        (low, high): (f64, f64),
    ) -> Option<f64> {
        match parse(&raw) {
            Some(v) if v.is_finite() && v >= low && v <= high => Some(v),
            Some(_) => {
                self.warnings
                    .push(format!("{key} = {raw:?} is out of the plausible range"));
                None
            }
            None => {
                self.warnings
                    .push(format!("{key} = {raw:?} is not a number with a known unit"));
                None
            }
        }
    }

    /// Fills in what can be derived and checks the values against each other.
    fn complete(
        &mut self,
        pixel: Option<f64>,
        hfw: Option<f64>,
        magnification: Option<f64>,
        width_px: u32,
    ) {
        let width = f64::from(width_px.max(1));
        if let (Some(p), Some(h)) = (pixel, hfw) {
            if ((p * width) / h - 1.0).abs() > CONSISTENCY {
                self.warnings.push(format!(
                    "pixel size {p:.6} um x {width_px} px = {:.3} um disagrees with the field \
                     width {h:.3} um; using the pixel size",
                    p * width
                ));
            }
        }
        self.pixel_size_um = pixel.or(hfw.map(|h| h / width));
        self.hfw_um = hfw.or(pixel.map(|p| p * width));
        self.magnification = magnification.or(self.hfw_um.map(|h| DISPLAY_WIDTH_UM / h));
        if self.pixel_size_um.is_none() {
            self.warnings
                .push("no usable pixel size or field width".to_string());
        }
    }
}

/// A length with its unit (`12.3 nm`, `1.5 µm`, `1.5 um`, `0.2 mm`, `3e-9 m`, `500 pm`)
/// in micrometres.
pub fn parse_length_um(text: &str) -> Option<f64> {
    let (number, unit) = split_number(text)?;
    let scale = match unit {
        "pm" => 1e-6,
        "nm" => 1e-3,
        "um" | "µm" | "μm" => 1.0,
        "mm" => 1e3,
        "m" => 1e6,
        _ => return None,
    };
    Some(number * scale)
}

/// A magnification as Zeiss writes it: `2.00 K X`, `500 X`, `1.5 KX`, `12 k x`.
pub fn parse_magnification(text: &str) -> Option<f64> {
    let (number, unit) = split_number(text)?;
    let unit: String = unit
        .chars()
        .filter(|c| !c.is_whitespace())
        .collect::<String>()
        .to_ascii_lowercase();
    let scale = match unit.as_str() {
        "x" | "" => 1.0,
        "kx" => 1e3,
        "mx" => 1e6,
        _ => return None,
    };
    Some(number * scale)
}

/// The leading number and the rest, trimmed.
fn split_number(text: &str) -> Option<(f64, &str)> {
    let text = text.trim();
    let end = text
        .char_indices()
        .find(|&(i, c)| {
            !(c.is_ascii_digit()
                || c == '.'
                || c == '+'
                || c == '-'
                || ((c == 'e' || c == 'E') && exponent_follows(&text[i + 1..])))
        })
        .map_or(text.len(), |(i, _)| i);
    let number = text[..end].parse::<f64>().ok()?;
    Some((number, text[end..].trim()))
}

fn exponent_follows(rest: &str) -> bool {
    let rest = rest.strip_prefix(['+', '-']).unwrap_or(rest);
    rest.starts_with(|c: char| c.is_ascii_digit())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn close(a: Option<f64>, b: f64) -> bool {
        a.is_some_and(|a| (a / b - 1.0).abs() < 1e-9)
    }

    #[test]
    fn lengths_in_every_unit() {
        assert!(close(parse_length_um("12.3 nm"), 0.0123));
        assert!(close(parse_length_um("1.5 µm"), 1.5));
        assert!(close(parse_length_um("1.5 μm"), 1.5));
        assert!(close(parse_length_um("1.5um"), 1.5));
        assert!(close(parse_length_um("0.2 mm"), 200.0));
        assert!(close(parse_length_um("3e-9 m"), 0.003));
        assert!(close(parse_length_um("2.5E+2 pm"), 2.5e-4));
        assert_eq!(parse_length_um("12.3"), None, "a length needs its unit");
        assert_eq!(parse_length_um("12.3 furlongs"), None);
        assert_eq!(parse_length_um("nm"), None);
    }

    #[test]
    fn magnifications() {
        assert!(close(parse_magnification("2.00 K X"), 2000.0));
        assert!(close(parse_magnification("500 X"), 500.0));
        assert!(close(parse_magnification("1.5 KX"), 1500.0));
        assert!(close(parse_magnification("12 k x"), 12_000.0));
        assert!(close(parse_magnification("1.2 M X"), 1.2e6));
        assert_eq!(parse_magnification("lots"), None);
        assert_eq!(parse_magnification("2 Q X"), None);
    }

    #[test]
    fn fei_ini_in_metres() {
        let text = "[User]\nDate=01/02/2024\n[EBeam]\nHFW=6.35e-05\n[Scan]\n\
                    PixelWidth=9.921875e-08\nPixelHeight=9.921875e-08\nHorFieldsize=6.35e-05\n";
        let m = parse_fei(text, 640);
        assert_eq!(m.vendor, Some(SemVendor::Fei));
        assert!(close(m.pixel_size_um, 0.09921875));
        assert!(close(m.hfw_um, 63.5));
        assert!(close(m.magnification, 2000.0), "{:?}", m.magnification);
        assert!(m.warnings.is_empty(), "{:?}", m.warnings);
        let with_canvas = format!("{text}[Image]\nMagCanvasRealWidth=0.1\n");
        assert!(close(
            parse_fei(&with_canvas, 640).magnification,
            100_000.0 / 63.5
        ));
    }

    #[test]
    fn zeiss_pairs_with_units() {
        let text = "0\r\nAP_PIXEL_SIZE\r\nPixel Size = 99.2 nm\r\nAP_MAG\r\nMag = 2.00 K X\r\n\
                    AP_WIDTH\r\nWidth = 63.49 µm\r\n";
        let m = parse_zeiss(text, 640);
        assert_eq!(m.vendor, Some(SemVendor::Zeiss));
        assert!(close(m.pixel_size_um, 0.0992));
        assert!(close(m.px_per_um(), 1.0 / 0.0992));
        assert!(close(m.magnification, 2000.0));
        assert!(close(m.hfw_um, 63.49));
        assert!(m.warnings.is_empty(), "{:?}", m.warnings);
    }

    #[test]
    fn derived_values_when_one_is_missing() {
        let m = parse_zeiss("AP_WIDTH\nWidth = 0.127 mm\n", 1270);
        assert!(close(m.pixel_size_um, 0.1));
        assert!(close(m.magnification, 1000.0));
        let m = parse_fei("[Scan]\nPixelWidth=2e-8\n", 500);
        assert!(close(m.hfw_um, 10.0));
        assert!(close(m.magnification, 12_700.0));
    }

    #[test]
    fn malformed_values_warn_and_stay_empty() {
        let m = parse_fei("[Scan]\nPixelWidth=abc\n[EBeam]\nHFW=-1\n", 640);
        assert_eq!(m.pixel_size_um, None);
        assert_eq!(m.magnification, None);
        assert_eq!(m.warnings.len(), 3, "{:?}", m.warnings);
        assert!(m.warnings[0].contains("[Scan] PixelWidth = \"abc\""));
        assert!(m.warnings[1].contains("out of the plausible range"));
        let m = parse_zeiss("Pixel Size = 12 parsecs\nMag = many\n", 640);
        assert_eq!((m.pixel_size_um, m.magnification), (None, None));
        assert_eq!(m.warnings.len(), 3, "{:?}", m.warnings);
        let m = parse_fei("garbage without sections\x01\x02", 640);
        assert_eq!(m.pixel_size_um, None);
        assert_eq!(m.warnings, ["no usable pixel size or field width"]);
    }

    #[test]
    fn disagreeing_values_warn_and_keep_the_pixel_size() {
        let m = parse_fei("[Scan]\nPixelWidth=1e-7\n[EBeam]\nHFW=1e-4\n", 640);
        assert!(close(m.pixel_size_um, 0.1));
        assert!(close(m.hfw_um, 100.0));
        assert_eq!(m.warnings.len(), 1);
        assert!(m.warnings[0].contains("disagrees"), "{:?}", m.warnings);
    }

    #[test]
    fn non_tiff_files_have_no_metadata() {
        assert_eq!(
            read_sem_metadata(Path::new("frame.png")),
            SemMetadata::default()
        );
    }
}
