//! SEM metadata end to end: TIFF frames carrying FEI/Thermo (tags 34682, 34680) or Zeiss
//! (tag 34118) scale metadata, written here with the `tiff` crate, are replayed; the CSV's
//! `px_per_um`, `magnification` and apex in micrometres must match the session's truth.
//! Malformed metadata is a warning and empty columns, never a failed replay.
use std::fs::File;
use std::io::BufWriter;
use std::path::Path;
use std::process::Command;

use nanoforce::scene::{FrameFormat, Session};
use nanoforce::session::metadata::{read_sem_metadata, SemVendor};
use nanoforce::session::results::{read_results, ResultRow};
use tiff::encoder::{colortype, TiffEncoder};
use tiff::tags::Tag;

const BIN: &str = env!("CARGO_BIN_EXE_nanoforce");

/// What a test frame's private tag holds.
enum Meta {
    Fei { tag: u16, text: String },
    Zeiss(Vec<u8>),
    Numbers,
}

/// Writes `png` as a 16-bit grey TIFF at `tif` with the metadata tag.
fn write_tiff(png: &Path, tif: &Path, meta: &Meta) {
    let grey = image::open(png).unwrap().into_luma8();
    let (w, h) = grey.dimensions();
    let wide: Vec<u16> = grey.as_raw().iter().map(|&v| u16::from(v) * 257).collect();
    let mut encoder = TiffEncoder::new(BufWriter::new(File::create(tif).unwrap())).unwrap();
    let mut image = encoder.new_image::<colortype::Gray16>(w, h).unwrap();
    match meta {
        Meta::Fei { tag, text } => image
            .encoder()
            .write_tag(Tag::Unknown(*tag), text.as_str())
            .unwrap(),
        Meta::Zeiss(bytes) => image
            .encoder()
            .write_tag(Tag::Unknown(34118), bytes.as_slice())
            .unwrap(),
        Meta::Numbers => image
            .encoder()
            .write_tag(Tag::Unknown(34682), &[1u32, 2, 3][..])
            .unwrap(),
    }
    image.write_data(&wide).unwrap();
}

/// FEI INI text (SI units) for a pixel size and magnification.
fn fei_text(px_per_um: f64, magnification: f64, width: u32) -> String {
    let pixel_m = 1e-6 / px_per_um;
    format!(
        "[User]\r\nDate=03/04/2025\r\n[EBeam]\r\nHV=5000\r\nHFW={:e}\r\n[Scan]\r\n\
         PixelWidth={pixel_m:e}\r\nPixelHeight={pixel_m:e}\r\n[Image]\r\n\
         MagCanvasRealWidth={:e}\r\n",
        pixel_m * f64::from(width),
        magnification * pixel_m * f64::from(width),
    )
}

/// Zeiss text, Latin-1 encoded (as Zeiss writes "µm").
fn zeiss_bytes(px_per_um: f64, magnification: f64, width: u32) -> Vec<u8> {
    let text = format!(
        "0\r\nAP_PIXEL_SIZE\r\nPixel Size = {:.6} nm\r\nAP_MAG\r\nMag = {:.4} K X\r\n\
         AP_WIDTH\r\nWidth = {:.6} \u{b5}m\r\n",
        1e3 / px_per_um,
        magnification / 1e3,
        f64::from(width) / px_per_um,
    );
    text.chars().map(|c| c as u32 as u8).collect()
}

struct TruthRow {
    frame: String,
    detected: bool,
    tip: [f64; 2],
    magnification: f64,
    px_per_um: f64,
}

fn read_truth(path: &Path) -> Vec<TruthRow> {
    let text = std::fs::read_to_string(path).unwrap();
    text.lines()
        .skip(1)
        .map(|l| {
            let c: Vec<&str> = l.split(',').collect();
            TruthRow {
                frame: c[0].to_string(),
                detected: c[1] == "1",
                tip: [c[4].parse().unwrap(), c[5].parse().unwrap()],
                magnification: c[6].parse().unwrap(),
                px_per_um: c[7].parse().unwrap(),
            }
        })
        .collect()
}

fn replay(dir: &Path, frames: &Path) -> (Vec<ResultRow>, String) {
    let csv = dir.join("replay.csv");
    let out = Command::new(BIN)
        .arg("replay")
        .arg(frames)
        .arg("--config")
        .arg(dir.join("probe.toml"))
        .arg("--csv")
        .arg(&csv)
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr).to_string();
    assert!(out.status.success(), "{stderr}");
    (read_results(&csv).unwrap(), stderr)
}

#[test]
fn replay_reports_scale_from_fei_and_zeiss_tiffs() {
    let dir = tempfile::tempdir().unwrap();
    let session = Session::sequence(31, 9, 640, 480);
    session.write(dir.path(), FrameFormat::Png).unwrap();
    let truth = read_truth(&dir.path().join("truth.csv"));
    let tiffs = dir.path().join("tiffs");
    std::fs::create_dir(&tiffs).unwrap();
    for (k, t) in truth.iter().enumerate() {
        let meta = match k % 3 {
            0 => Meta::Fei {
                tag: 34682,
                text: fei_text(t.px_per_um, t.magnification, 640),
            },
            1 => Meta::Zeiss(zeiss_bytes(t.px_per_um, t.magnification, 640)),
            _ => Meta::Fei {
                tag: 34680,
                text: fei_text(t.px_per_um, t.magnification, 640),
            },
        };
        let tif = tiffs.join(t.frame.replace(".png", ".tif"));
        write_tiff(&dir.path().join("frames").join(&t.frame), &tif, &meta);
        let read = read_sem_metadata(&tif);
        let vendor = if k % 3 == 1 {
            SemVendor::Zeiss
        } else {
            SemVendor::Fei
        };
        assert_eq!(read.vendor, Some(vendor));
        assert!(read.warnings.is_empty(), "{:?}", read.warnings);
    }
    let (rows, stderr) = replay(dir.path(), &tiffs);
    assert!(stderr.contains("9 with an SEM pixel size"), "{stderr}");
    assert!(!stderr.contains("warning"), "{stderr}");
    let mut apexes = 0;
    for (row, t) in rows.iter().zip(&truth) {
        let ppu = row.px_per_um.unwrap();
        assert!(
            (ppu / t.px_per_um - 1.0).abs() < 1e-5,
            "{ppu} vs {}",
            t.px_per_um
        );
        let mag = row.magnification.unwrap();
        assert!((mag / t.magnification - 1.0).abs() < 1e-4, "{mag}");
        if let (true, true, Some(tip)) = (row.detected, t.detected, row.tip_px) {
            // The apex in um (the CSV's columns are checked in `apex_columns_are_written`)
            // is within the tracker's pixel error of the true apex, converted the same way.
            let um = [tip[0] / ppu, tip[1] / ppu];
            let err_um = (um[0] - t.tip[0] / t.px_per_um).hypot(um[1] - t.tip[1] / t.px_per_um);
            assert!(err_um < 2.0 / t.px_per_um, "apex off by {err_um} um");
            apexes += 1;
        }
    }
    assert!(apexes >= 5, "only {apexes} frames to check the apex on");
}

#[test]
fn apex_columns_are_written() {
    let dir = tempfile::tempdir().unwrap();
    let session = Session::mixed(8, 2, 640, 480);
    session.write(dir.path(), FrameFormat::Png).unwrap();
    let truth = read_truth(&dir.path().join("truth.csv"));
    let tiffs = dir.path().join("tiffs");
    std::fs::create_dir(&tiffs).unwrap();
    for t in &truth {
        let tif = tiffs.join(t.frame.replace(".png", ".tif"));
        let text = fei_text(t.px_per_um, t.magnification, 640);
        write_tiff(
            &dir.path().join("frames").join(&t.frame),
            &tif,
            &Meta::Fei { tag: 34682, text },
        );
    }
    replay(dir.path(), &tiffs);
    let text = std::fs::read_to_string(dir.path().join("replay.csv")).unwrap();
    let header: Vec<&str> = text.lines().next().unwrap().split(',').collect();
    let col = |n: &str| header.iter().position(|h| *h == n).unwrap();
    let mut checked = 0;
    for line in text.lines().skip(1) {
        let c: Vec<&str> = line.split(',').collect();
        if c[col("detected")] != "1" {
            continue;
        }
        let v = |n: &str| c[col(n)].parse::<f64>().unwrap();
        let ppu = v("px_per_um");
        assert!((v("tip_x_um") - v("tip_x") / ppu).abs() < 1e-3, "{line}");
        assert!((v("tip_y_um") - v("tip_y") / ppu).abs() < 1e-3, "{line}");
        checked += 1;
    }
    assert!(checked >= 1);
}

#[test]
fn malformed_metadata_warns_and_leaves_columns_empty() {
    let dir = tempfile::tempdir().unwrap();
    let session = Session::mixed(12, 3, 640, 480);
    session.write(dir.path(), FrameFormat::Png).unwrap();
    let truth = read_truth(&dir.path().join("truth.csv"));
    let tiffs = dir.path().join("tiffs");
    std::fs::create_dir(&tiffs).unwrap();
    let metas = [
        Meta::Fei {
            tag: 34682,
            text: "[Scan]\nPixelWidth=not-a-number\n[EBeam]\nHFW=\n".into(),
        },
        Meta::Zeiss(b"AP_PIXEL_SIZE\r\nPixel Size = 12 furlongs\r\nMag = ?? X\r\n".to_vec()),
        Meta::Numbers,
    ];
    for (t, meta) in truth.iter().zip(&metas) {
        let tif = tiffs.join(t.frame.replace(".png", ".tif"));
        write_tiff(&dir.path().join("frames").join(&t.frame), &tif, meta);
        let read = read_sem_metadata(&tif);
        assert!(!read.warnings.is_empty() && read.pixel_size_um.is_none());
    }
    let (rows, stderr) = replay(dir.path(), &tiffs);
    assert!(stderr.contains("SEM metadata"), "{stderr}");
    assert!(stderr.contains("PixelWidth = \"not-a-number\""), "{stderr}");
    assert!(stderr.contains("12 furlongs"), "{stderr}");
    assert!(stderr.contains("tag 34682"), "{stderr}");
    assert!(stderr.contains("(3 with metadata warnings)"), "{stderr}");
    assert_eq!(rows.len(), 3);
    for (row, t) in rows.iter().zip(&truth) {
        assert_eq!((row.px_per_um, row.magnification), (None, None));
        if t.detected {
            assert!(row.detected, "the frame itself is still tracked: {row:?}");
        }
    }
}
