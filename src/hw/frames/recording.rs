//! Reading a recorded frames file (a session's `frames.nfrm`): frames in the pipe
//! protocol's header format (see [`super::pipe`]), one after the other. A run that was
//! killed may leave its last frame short: that frame is the end of the file, with a
//! warning. Bytes that are not a header are skipped to the next one, as the pipe does.
use std::fs::File;
use std::io::{BufReader, ErrorKind, Read, Seek, SeekFrom};
use std::os::unix::fs::FileExt;
use std::path::{Path, PathBuf};

use image::GrayImage;

use super::pipe::{FrameHeader, HEADER_LEN};

#[derive(Debug, thiserror::Error)]
pub enum FrameFileError {
    #[error("{path}: cannot read: {source}")]
    Io {
        path: PathBuf,
        source: std::io::Error,
    },
}

/// The read buffer while indexing: a few headers, so that skipping a frame's pixels
/// reads none of them.
const INDEX_BUFFER: usize = 4096;

/// A frames file opened for reading, front to back.
pub struct FrameFile {
    path: PathBuf,
    reader: BufReader<File>,
    /// Bytes skipped to find a header so far.
    pub skipped_bytes: u64,
    /// Whether the last frame was cut short (the file ended inside it).
    pub truncated: bool,
    /// Bytes read so far.
    offset: u64,
}

/// The frames of a file: each one's header and the offset of its pixels.
#[derive(Debug, Clone, PartialEq)]
pub struct FrameIndex {
    pub frames: Vec<(FrameHeader, u64)>,
    pub skipped_bytes: u64,
    pub truncated: bool,
}

impl FrameFile {
    pub fn open(path: &Path) -> Result<FrameFile, FrameFileError> {
        let file = File::open(path).map_err(|source| FrameFileError::Io {
            path: path.to_path_buf(),
            source,
        })?;
        Ok(FrameFile {
            path: path.to_path_buf(),
            reader: BufReader::with_capacity(1 << 20, file),
            skipped_bytes: 0,
            truncated: false,
            offset: 0,
        })
    }

    pub fn path(&self) -> &Path {
        &self.path
    }

    /// Reads the next frame into `frame` (reusing its buffer when the size is unchanged)
    /// and returns its header; None at the end of the file.
    pub fn next_into(
        &mut self,
        frame: &mut GrayImage,
    ) -> Result<Option<FrameHeader>, FrameFileError> {
        let Some(h) = self.next_header()? else {
            return Ok(None);
        };
        if frame.dimensions() != (h.width, h.height) {
            *frame = GrayImage::new(h.width, h.height);
        }
        let size = frame.as_raw().len();
        if self.fill(frame)? < size {
            return Ok(self.cut_short());
        }
        Ok(Some(h))
    }

    /// Every frame's header and where its pixels start, without reading the pixels.
    pub fn index(mut self) -> Result<FrameIndex, FrameFileError> {
        let mut file = self.reader.into_inner();
        let at = file.seek(SeekFrom::Start(self.offset));
        self.reader = BufReader::with_capacity(INDEX_BUFFER, file);
        at.map_err(|source| self.io_error(source))?;
        let len = self
            .reader
            .get_ref()
            .metadata()
            .map_err(|source| self.io_error(source))?
            .len();
        let mut frames = Vec::new();
        while let Some(h) = self.next_header()? {
            let size = u64::from(h.width) * u64::from(h.height);
            if self.offset + size > len {
                self.cut_short();
                break;
            }
            frames.push((h, self.offset));
            self.reader
                .seek_relative(size as i64)
                .map_err(|source| self.io_error(source))?;
            self.offset += size;
        }
        Ok(FrameIndex {
            frames,
            skipped_bytes: self.skipped_bytes,
            truncated: self.truncated,
        })
    }

    /// Reads the pixels of the frame `header` describes, at `offset` of `file` (from
    /// [`FrameFile::index`]), into `frame`.
    pub fn read_at(
        file: &File,
        header: &FrameHeader,
        offset: u64,
        frame: &mut GrayImage,
    ) -> std::io::Result<()> {
        if frame.dimensions() != (header.width, header.height) {
            *frame = GrayImage::new(header.width, header.height);
        }
        file.read_exact_at(frame, offset)
    }

    /// Reads the next valid header (skipping bytes that are not one); None at the end.
    fn next_header(&mut self) -> Result<Option<FrameHeader>, FrameFileError> {
        let mut header = [0u8; HEADER_LEN];
        match self.fill(&mut header)? {
            0 => return Ok(None),
            HEADER_LEN => {}
            _ => return Ok(self.cut_short()),
        }
        let (h, len) = loop {
            match FrameHeader::decode(&header) {
                Ok(found) => break found,
                Err(_) => {
                    header.copy_within(1.., 0);
                    if self.fill(&mut header[HEADER_LEN - 1..])? == 0 {
                        return Ok(self.cut_short());
                    }
                    self.skipped_bytes += 1;
                }
            }
        };
        if len > HEADER_LEN {
            let mut rest = vec![0u8; len - HEADER_LEN];
            if self.fill(&mut rest)? < rest.len() {
                return Ok(self.cut_short());
            }
        }
        Ok(Some(h))
    }

    fn io_error(&self, source: std::io::Error) -> FrameFileError {
        FrameFileError::Io {
            path: self.path.clone(),
            source,
        }
    }

    /// The file ended inside a frame.
    fn cut_short(&mut self) -> Option<FrameHeader> {
        self.truncated = true;
        tracing::warn!(
            "{}: the last frame is cut short (the run ended while writing it); ignored",
            self.path.display()
        );
        None
    }

    /// Reads into `buf` until it is full or the file ends; returns the bytes read.
    fn fill(&mut self, buf: &mut [u8]) -> Result<usize, FrameFileError> {
        let mut done = 0;
        while done < buf.len() {
            match self.reader.read(&mut buf[done..]) {
                Ok(0) => break,
                Ok(n) => {
                    done += n;
                    self.offset += n as u64;
                }
                Err(e) if e.kind() == ErrorKind::Interrupted => {}
                Err(source) => {
                    return Err(FrameFileError::Io {
                        path: self.path.clone(),
                        source,
                    })
                }
            }
        }
        Ok(done)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::io::Write;

    fn frame(w: u32, h: u32, seq: u64) -> (FrameHeader, Vec<u8>) {
        let header = FrameHeader {
            width: w,
            height: h,
            sequence: seq,
            capture_ns: 1_000_000 * seq,
        };
        let pixels = (0..w * h).map(|i| (i as u64 + seq) as u8).collect();
        (header, pixels)
    }

    #[test]
    fn reads_frames_back_skips_junk_and_stops_at_a_short_frame() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("frames.nfrm");
        let mut out = std::fs::File::create(&path).unwrap();
        let frames = [frame(4, 3, 1), frame(4, 3, 2), frame(5, 2, 4)];
        for (i, (h, p)) in frames.iter().enumerate() {
            if i == 1 {
                out.write_all(b"junk").unwrap();
            }
            out.write_all(&h.encode()).unwrap();
            out.write_all(p).unwrap();
        }
        // A frame cut short by a crash.
        let (h, p) = frame(4, 3, 5);
        out.write_all(&h.encode()).unwrap();
        out.write_all(&p[..5]).unwrap();
        drop(out);
        let mut file = FrameFile::open(&path).unwrap();
        let mut image = GrayImage::new(0, 0);
        for (h, p) in &frames {
            assert_eq!(file.next_into(&mut image).unwrap(), Some(*h));
            assert_eq!(image.as_raw(), p);
        }
        assert_eq!(file.next_into(&mut image).unwrap(), None);
        assert_eq!(file.skipped_bytes, 4);
        assert!(file.truncated);
        // The index finds the same frames; their pixels read back from the offsets.
        let index = FrameFile::open(&path).unwrap().index().unwrap();
        assert_eq!(index.frames.len(), 3);
        assert_eq!((index.skipped_bytes, index.truncated), (4, true));
        let raw = std::fs::File::open(&path).unwrap();
        for ((h, p), (indexed, offset)) in frames.iter().zip(&index.frames) {
            assert_eq!(h, indexed);
            FrameFile::read_at(&raw, indexed, *offset, &mut image).unwrap();
            assert_eq!(image.as_raw(), p);
        }
        let missing = FrameFile::open(&dir.path().join("none.nfrm"))
            .err()
            .unwrap()
            .to_string();
        assert!(missing.contains("none.nfrm: cannot read"), "{missing}");
    }

    #[test]
    fn a_whole_file_is_not_truncated() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("frames.nfrm");
        let (h, p) = frame(3, 3, 9);
        std::fs::write(&path, [h.encode().as_slice(), &p].concat()).unwrap();
        let mut file = FrameFile::open(&path).unwrap();
        let mut image = GrayImage::new(0, 0);
        assert!(file.next_into(&mut image).unwrap().is_some());
        assert!(file.next_into(&mut image).unwrap().is_none());
        assert!(!file.truncated);
    }
}
