//! Captured pixels to the 8-bit grey frame the tracker reads, into a reused buffer:
//! GREY rows copied without their padding, the luma bytes of YUYV, and MJPEG decoded
//! straight to luma (zune-jpeg, cargo feature `v4l2`). Also [`SequenceCounter`], which
//! turns a driver's 32-bit frame counter into the daemon's 64-bit sequence, keeping
//! its gaps (dropped frames) and bridging a reopened device by time.
use image::GrayImage;

/// Makes `frame` `width` x `height`, reusing its buffer when the size matches.
fn sized(frame: &mut GrayImage, width: u32, height: u32) {
    if frame.dimensions() != (width, height) {
        *frame = GrayImage::new(width, height);
    }
}

fn check_len(src: &[u8], height: u32, bytesperline: usize, row_bytes: usize) -> Result<(), String> {
    let need = bytesperline * (height as usize).saturating_sub(1) + row_bytes;
    if bytesperline < row_bytes || src.len() < need {
        Err(format!(
            "short frame: {} bytes for {height} rows of {row_bytes} (stride {bytesperline})",
            src.len()
        ))
    } else {
        Ok(())
    }
}

/// 8-bit grey rows of `bytesperline` bytes (>= width) into `frame`.
pub fn grey_into(
    src: &[u8],
    width: u32,
    height: u32,
    bytesperline: usize,
    frame: &mut GrayImage,
) -> Result<(), String> {
    let w = width as usize;
    check_len(src, height, bytesperline, w)?;
    sized(frame, width, height);
    for (dst, row) in frame.chunks_exact_mut(w).zip(src.chunks(bytesperline)) {
        dst.copy_from_slice(&row[..w]);
    }
    Ok(())
}

/// YUYV (Y0 U Y1 V per pixel pair) rows into `frame`: the Y bytes are the grey levels.
pub fn yuyv_into(
    src: &[u8],
    width: u32,
    height: u32,
    bytesperline: usize,
    frame: &mut GrayImage,
) -> Result<(), String> {
    let w = width as usize;
    check_len(src, height, bytesperline, 2 * w)?;
    sized(frame, width, height);
    for (dst, row) in frame.chunks_exact_mut(w).zip(src.chunks(bytesperline)) {
        for (d, pair) in dst.iter_mut().zip(row.chunks_exact(2)) {
            *d = pair[0];
        }
    }
    Ok(())
}

/// One MJPEG frame decoded to luma into `frame` (sized from the JPEG itself).
#[cfg(feature = "v4l2")]
pub fn mjpeg_into(src: &[u8], frame: &mut GrayImage) -> Result<(), String> {
    use zune_core::colorspace::ColorSpace;
    use zune_core::options::DecoderOptions;
    let options = DecoderOptions::default().jpeg_set_out_colorspace(ColorSpace::Luma);
    let mut decoder = zune_jpeg::JpegDecoder::new_with_options(std::io::Cursor::new(src), options);
    decoder
        .decode_headers()
        .map_err(|e| format!("MJPEG: {e:?}"))?;
    let (w, h) = decoder.dimensions().ok_or("MJPEG: no dimensions")?;
    sized(frame, w as u32, h as u32);
    decoder
        .decode_into(frame)
        .map_err(|e| format!("MJPEG: {e:?}"))
}

/// A driver's wrapping 32-bit frame counter as a 64-bit sequence with its gaps.
#[derive(Debug, Clone, Default)]
pub struct SequenceCounter {
    /// (driver counter, our sequence, capture time) of the last frame.
    last: Option<(u32, u64, f64)>,
    /// The device was reopened: its counter starts again.
    restarted: bool,
}

impl SequenceCounter {
    /// The sequence of a frame with driver counter `raw` captured at `time_s`.
    /// `period_s` (the nominal frame period) estimates what was lost across a reopen.
    pub fn next(&mut self, raw: u32, time_s: f64, period_s: f64) -> u64 {
        let sequence = match self.last {
            None => u64::from(raw) + 1,
            Some((_, last_seq, last_s)) if self.restarted => {
                let missed = ((time_s - last_s) / period_s).round() - 1.0;
                last_seq
                    + 1
                    + if missed.is_finite() && missed > 0.0 {
                        missed as u64
                    } else {
                        0
                    }
            }
            Some((last_raw, last_seq, _)) => {
                last_seq + u64::from(raw.wrapping_sub(last_raw).max(1))
            }
        };
        self.restarted = false;
        self.last = Some((raw, sequence, time_s));
        sequence
    }

    /// The device is being reopened: its next counter value starts a new run.
    pub fn restart(&mut self) {
        self.restarted = true;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn grey_drops_row_padding() {
        // 3x2 image in rows of 5 bytes.
        let src = [1, 2, 3, 99, 99, 4, 5, 6, 99, 99];
        let mut frame = GrayImage::new(0, 0);
        grey_into(&src, 3, 2, 5, &mut frame).unwrap();
        assert_eq!(frame.as_raw(), &[1, 2, 3, 4, 5, 6]);
        // The last row needs no padding; less than that is an error.
        grey_into(&src[..8], 3, 2, 5, &mut frame).unwrap();
        assert!(grey_into(&src[..7], 3, 2, 5, &mut frame)
            .unwrap_err()
            .contains("short frame"));
        assert!(
            grey_into(&src, 6, 1, 5, &mut frame).is_err(),
            "stride below width"
        );
    }

    #[test]
    fn yuyv_keeps_luma() {
        // 2x2: Y0 U Y1 V per pair, rows of 4 pixels' worth of padding room (6 bytes).
        let src = [10, 128, 20, 129, 0, 0, 30, 127, 40, 126, 0, 0];
        let mut frame = GrayImage::new(2, 2);
        let ptr = frame.as_ptr();
        yuyv_into(&src, 2, 2, 6, &mut frame).unwrap();
        assert_eq!(frame.as_raw(), &[10, 20, 30, 40]);
        assert_eq!(frame.as_ptr(), ptr, "buffer reused");
    }

    #[cfg(feature = "v4l2")]
    #[test]
    fn mjpeg_decodes_to_luma() {
        use image::codecs::jpeg::JpegEncoder;
        let w = 32;
        let src = GrayImage::from_fn(w, 16, |x, _| image::Luma([(x * 8) as u8]));
        let mut jpeg = Vec::new();
        JpegEncoder::new_with_quality(&mut jpeg, 95)
            .encode_image(&src)
            .unwrap();
        let mut frame = GrayImage::new(0, 0);
        mjpeg_into(&jpeg, &mut frame).unwrap();
        assert_eq!(frame.dimensions(), (w, 16));
        let worst = src
            .iter()
            .zip(frame.iter())
            .map(|(a, b)| a.abs_diff(*b))
            .max()
            .unwrap();
        assert!(worst <= 4, "lossy but close: {worst}");
        assert!(mjpeg_into(&jpeg[..20], &mut frame).is_err());
    }

    #[test]
    fn sequence_keeps_gaps_and_wraps() {
        let mut s = SequenceCounter::default();
        let p = 0.01;
        assert_eq!(s.next(0, 0.00, p), 1);
        assert_eq!(s.next(1, 0.01, p), 2);
        assert_eq!(s.next(4, 0.04, p), 5, "two frames dropped by the driver");
        let mut w = SequenceCounter::default();
        assert_eq!(w.next(u32::MAX - 1, 0.0, p), u64::from(u32::MAX));
        assert_eq!(w.next(u32::MAX, 0.01, p), u64::from(u32::MAX) + 1);
        assert_eq!(
            w.next(1, 0.03, p),
            u64::from(u32::MAX) + 3,
            "wrapped past 0"
        );
    }

    #[test]
    fn sequence_bridges_a_reopen_by_time() {
        let mut s = SequenceCounter::default();
        let p = 0.02;
        assert_eq!(s.next(10, 1.00, p), 11);
        s.restart();
        // Reopened 0.5 s later: the driver counts from 0 again; 24 frames were lost.
        assert_eq!(s.next(0, 1.50, p), 11 + 25);
        assert_eq!(s.next(1, 1.52, p), 37);
    }
}
