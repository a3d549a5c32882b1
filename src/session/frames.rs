//! The frames of a recorded session: every PNG, TIFF (8- or 16-bit) and PGM/PNM file of a
//! folder, in file-name order, decoded to 8-bit grey. A file that does not decode is an
//! error for that frame only; the caller reports it and goes on.
use std::path::{Path, PathBuf};

use image::{DynamicImage, GrayImage, ImageReader};

/// File extensions read as frames (case-insensitive).
pub const FRAME_EXTENSIONS: [&str; 6] = ["png", "tif", "tiff", "pgm", "pnm", "pbm"];

#[derive(Debug, thiserror::Error)]
pub enum FramesError {
    #[error("{dir}: cannot list frames: {source}")]
    List {
        dir: PathBuf,
        source: std::io::Error,
    },
    #[error("{dir}: no frames (PNG, TIFF or PGM files) in this folder")]
    Empty { dir: PathBuf },
    #[error("{path}: cannot decode: {reason}")]
    Decode { path: PathBuf, reason: String },
}

/// The frame files of `dir`, sorted by file name.
pub fn list_frames(dir: &Path) -> Result<Vec<PathBuf>, FramesError> {
    let entries = std::fs::read_dir(dir).map_err(|source| FramesError::List {
        dir: dir.to_path_buf(),
        source,
    })?;
    let mut frames: Vec<PathBuf> = entries
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.is_file() && is_frame(p))
        .collect();
    if frames.is_empty() {
        return Err(FramesError::Empty {
            dir: dir.to_path_buf(),
        });
    }
    frames.sort_by(|a, b| a.file_name().cmp(&b.file_name()));
    Ok(frames)
}

fn is_frame(path: &Path) -> bool {
    path.extension()
        .and_then(|e| e.to_str())
        .is_some_and(|e| FRAME_EXTENSIONS.iter().any(|x| x.eq_ignore_ascii_case(e)))
}

/// Decodes one frame to 8-bit grey: colour is converted to luma, 16-bit samples are
/// scaled from the full 16-bit range.
pub fn load_gray(path: &Path) -> Result<GrayImage, FramesError> {
    let decode_error = |reason: String| FramesError::Decode {
        path: path.to_path_buf(),
        reason,
    };
    let image = ImageReader::open(path)
        .map_err(|e| decode_error(e.to_string()))?
        .with_guessed_format()
        .map_err(|e| decode_error(e.to_string()))?
        .decode()
        .map_err(|e| decode_error(e.to_string()))?;
    Ok(to_gray8(image))
}

/// 8-bit grey from any decoded image.
pub fn to_gray8(image: DynamicImage) -> GrayImage {
    match image {
        DynamicImage::ImageLuma8(gray) => gray,
        DynamicImage::ImageLuma16(gray16) => {
            let (w, h) = gray16.dimensions();
            let data = gray16
                .into_raw()
                .into_iter()
                .map(|v| ((u32::from(v) * 255 + 32767) / 65535) as u8)
                .collect();
            GrayImage::from_raw(w, h, data).unwrap_or_else(|| GrayImage::new(w, h))
        }
        other => other.into_luma8(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use image::{ImageBuffer, Luma};

    #[test]
    fn sixteen_bit_scales_from_full_range() {
        let img: ImageBuffer<Luma<u16>, Vec<u16>> =
            ImageBuffer::from_raw(3, 1, vec![0, 32896, 65535]).unwrap();
        let gray = to_gray8(DynamicImage::ImageLuma16(img));
        assert_eq!(gray.into_raw(), vec![0, 128, 255]);
    }

    #[test]
    fn lists_frames_in_name_order_and_skips_other_files() {
        let dir = tempfile::tempdir().unwrap();
        for name in ["b.png", "a.tif", "c.PGM", "notes.txt", "d.jpg"] {
            std::fs::write(dir.path().join(name), b"x").unwrap();
        }
        let names: Vec<_> = list_frames(dir.path())
            .unwrap()
            .iter()
            .map(|p| p.file_name().unwrap().to_string_lossy().to_string())
            .collect();
        assert_eq!(names, ["a.tif", "b.png", "c.PGM"]);
    }

    #[test]
    fn empty_folder_and_corrupt_file_are_clear_errors() {
        let dir = tempfile::tempdir().unwrap();
        let err = list_frames(dir.path()).unwrap_err().to_string();
        assert!(err.contains("no frames"), "{err}");
        let bad = dir.path().join("bad.png");
        std::fs::write(&bad, b"\x89PNG\r\n\x1a\nnot really").unwrap();
        let err = load_gray(&bad).unwrap_err().to_string();
        assert!(
            err.starts_with(&format!("{}: cannot decode", bad.display())),
            "{err}"
        );
    }
}
