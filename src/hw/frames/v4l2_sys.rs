//! The Video4Linux2 kernel interface, in plain Rust: the few structs and ioctls of mmap
//! streaming capture, laid out as `<linux/videodev2.h>` lays them out on 64-bit Linux
//! (checked by size assertions here, and by the tests' fake device, which is compiled
//! against the real header). No bindgen, so no libclang at build time.
//!
//! [`Device`] owns the descriptor; [`Device::ioctl`] is the one place a failed call
//! becomes an error (EINTR retried). [`Mapping`] is one mmap'd buffer, unmapped on drop.
use std::ffi::CString;
use std::os::fd::{AsRawFd, FromRawFd, OwnedFd};
use std::path::Path;

pub const BUF_TYPE_VIDEO_CAPTURE: u32 = 1;
pub const MEMORY_MMAP: u32 = 1;
pub const FIELD_ANY: u32 = 0;
pub const CAP_VIDEO_CAPTURE: u32 = 0x0000_0001;
pub const CAP_STREAMING: u32 = 0x0400_0000;
pub const CAP_DEVICE_CAPS: u32 = 0x8000_0000;
pub const BUF_FLAG_ERROR: u32 = 0x0040;
pub const BUF_FLAG_TIMESTAMP_MASK: u32 = 0xe000;
pub const BUF_FLAG_TIMESTAMP_MONOTONIC: u32 = 0x2000;

#[repr(C)]
#[derive(Clone, Copy)]
pub struct Capability {
    pub driver: [u8; 16],
    pub card: [u8; 32],
    pub bus_info: [u8; 32],
    pub version: u32,
    pub capabilities: u32,
    pub device_caps: u32,
    pub reserved: [u32; 3],
}

#[repr(C)]
#[derive(Clone, Copy, Debug, Default)]
pub struct PixFormat {
    pub width: u32,
    pub height: u32,
    pub pixelformat: u32,
    pub field: u32,
    pub bytesperline: u32,
    pub sizeimage: u32,
    pub colorspace: u32,
    pub private: u32,
    pub flags: u32,
    pub ycbcr_enc: u32,
    pub quantization: u32,
    pub xfer_func: u32,
}

#[repr(C)]
#[derive(Clone, Copy)]
pub union FormatUnion {
    pub pix: PixFormat,
    pub raw: [u8; 200],
    /// The kernel's union holds pointers (v4l2_window): 8-byte aligned.
    _align: [u64; 25],
}

#[repr(C)]
#[derive(Clone, Copy)]
pub struct Format {
    pub kind: u32,
    pub fmt: FormatUnion,
}

#[repr(C)]
#[derive(Clone, Copy, Debug, Default)]
pub struct CaptureParm {
    pub capability: u32,
    pub capturemode: u32,
    /// Seconds per frame as numerator / denominator.
    pub timeperframe: [u32; 2],
    pub extendedmode: u32,
    pub readbuffers: u32,
    pub reserved: [u32; 4],
}

#[repr(C)]
#[derive(Clone, Copy)]
pub union ParmUnion {
    pub capture: CaptureParm,
    pub raw: [u8; 200],
}

#[repr(C)]
#[derive(Clone, Copy)]
pub struct StreamParm {
    pub kind: u32,
    pub parm: ParmUnion,
}

#[repr(C)]
#[derive(Clone, Copy, Debug, Default)]
pub struct RequestBuffers {
    pub count: u32,
    pub kind: u32,
    pub memory: u32,
    pub capabilities: u32,
    pub flags: u8,
    pub reserved: [u8; 3],
}

#[repr(C)]
#[derive(Clone, Copy, Debug, Default)]
pub struct Timecode {
    pub kind: u32,
    pub flags: u32,
    pub frames: u8,
    pub seconds: u8,
    pub minutes: u8,
    pub hours: u8,
    pub userbits: [u8; 4],
}

#[repr(C)]
#[derive(Clone, Copy, Debug, Default)]
pub struct Buffer {
    pub index: u32,
    pub kind: u32,
    pub bytesused: u32,
    pub flags: u32,
    pub field: u32,
    pub timestamp: libc::timeval,
    pub timecode: Timecode,
    pub sequence: u32,
    pub memory: u32,
    /// `m.offset` for MMAP buffers; the union is 8 bytes wide.
    pub offset: u32,
    pub m_high: u32,
    pub length: u32,
    pub reserved2: u32,
    pub request_fd: i32,
}

const fn ioc(dir: u64, nr: u64, size: usize) -> u64 {
    (dir << 30) | ((size as u64) << 16) | ((b'V' as u64) << 8) | nr
}
const R: u64 = 2;
const W: u64 = 1;
pub const VIDIOC_QUERYCAP: u64 = ioc(R, 0, size_of::<Capability>());
pub const VIDIOC_S_FMT: u64 = ioc(R | W, 5, size_of::<Format>());
pub const VIDIOC_REQBUFS: u64 = ioc(R | W, 8, size_of::<RequestBuffers>());
pub const VIDIOC_QUERYBUF: u64 = ioc(R | W, 9, size_of::<Buffer>());
pub const VIDIOC_QBUF: u64 = ioc(R | W, 15, size_of::<Buffer>());
pub const VIDIOC_DQBUF: u64 = ioc(R | W, 17, size_of::<Buffer>());
pub const VIDIOC_STREAMON: u64 = ioc(W, 18, size_of::<i32>());
pub const VIDIOC_STREAMOFF: u64 = ioc(W, 19, size_of::<i32>());
pub const VIDIOC_S_PARM: u64 = ioc(R | W, 22, size_of::<StreamParm>());

/// The fourcc of four ASCII bytes.
pub const fn fourcc(code: [u8; 4]) -> u32 {
    u32::from_le_bytes(code)
}

/// An open V4L2 device node.
pub struct Device {
    fd: OwnedFd,
}

impl Device {
    /// Opens the node read-write, non-blocking (waiting is done with poll).
    pub fn open(path: &Path) -> std::io::Result<Device> {
        let c_path = CString::new(path.as_os_str().as_encoded_bytes())
            .map_err(|_| std::io::Error::from(std::io::ErrorKind::InvalidInput))?;
        // SAFETY: a valid C string; the result is a new descriptor or -1.
        let fd = unsafe {
            libc::open(
                c_path.as_ptr(),
                libc::O_RDWR | libc::O_NONBLOCK | libc::O_CLOEXEC,
            )
        };
        if fd < 0 {
            return Err(std::io::Error::last_os_error());
        }
        // SAFETY: a fresh descriptor that nothing else owns.
        Ok(Device {
            fd: unsafe { OwnedFd::from_raw_fd(fd) },
        })
    }

    /// The one place a V4L2 call's status becomes an error (EINTR is retried).
    ///
    /// # Safety
    /// `request` must be an ioctl whose argument is a `T` (the `VIDIOC_*` above).
    pub unsafe fn ioctl<T>(&self, request: u64, arg: &mut T) -> std::io::Result<()> {
        loop {
            // SAFETY: the caller pairs `request` with its argument type.
            let r = unsafe { libc::ioctl(self.fd.as_raw_fd(), request as _, arg as *mut T) };
            if r >= 0 {
                return Ok(());
            }
            let e = std::io::Error::last_os_error();
            if e.kind() != std::io::ErrorKind::Interrupted {
                return Err(e);
            }
        }
    }

    /// Waits up to `timeout_ms` for a filled buffer; Ok(false) on timeout. POLLERR
    /// (an unplugged device) is an error.
    pub fn poll(&self, timeout_ms: i32) -> std::io::Result<bool> {
        let mut pfd = libc::pollfd {
            fd: self.fd.as_raw_fd(),
            events: libc::POLLIN,
            revents: 0,
        };
        // SAFETY: one pollfd we own.
        match unsafe { libc::poll(&mut pfd, 1, timeout_ms) } {
            0 => Ok(false),
            n if n < 0 => {
                let e = std::io::Error::last_os_error();
                if e.kind() == std::io::ErrorKind::Interrupted {
                    Ok(false)
                } else {
                    Err(e)
                }
            }
            _ if pfd.revents & (libc::POLLERR | libc::POLLHUP | libc::POLLNVAL) != 0 => {
                Err(std::io::Error::from_raw_os_error(libc::ENODEV))
            }
            _ => Ok(true),
        }
    }

    /// Maps buffer `buffer` (as QUERYBUF described it).
    pub fn map(&self, buffer: &Buffer) -> std::io::Result<Mapping> {
        let len = buffer.length as usize;
        // SAFETY: a shared mapping of the driver's buffer at the offset it gave us.
        let ptr = unsafe {
            libc::mmap(
                std::ptr::null_mut(),
                len,
                libc::PROT_READ | libc::PROT_WRITE,
                libc::MAP_SHARED,
                self.fd.as_raw_fd(),
                buffer.offset as libc::off_t,
            )
        };
        if ptr == libc::MAP_FAILED {
            return Err(std::io::Error::last_os_error());
        }
        Ok(Mapping {
            ptr: ptr.cast(),
            len,
        })
    }
}

/// One mmap'd capture buffer.
pub struct Mapping {
    ptr: *mut u8,
    len: usize,
}

// SAFETY: the mapping is plain memory owned by this value; the source that holds it is
// used from one thread at a time.
unsafe impl Send for Mapping {}

impl Mapping {
    /// The first `used` bytes (as the driver filled them).
    pub fn bytes(&self, used: usize) -> &[u8] {
        // SAFETY: the mapping is `len` bytes long and stays mapped while `self` lives;
        // the driver does not write to a dequeued buffer.
        unsafe { std::slice::from_raw_parts(self.ptr, used.min(self.len)) }
    }
}

impl Drop for Mapping {
    fn drop(&mut self) {
        // SAFETY: unmapping exactly what we mapped; a failure is not actionable.
        let _ = unsafe { libc::munmap(self.ptr.cast(), self.len) };
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn layouts_match_videodev2_on_64_bit() {
        assert_eq!(size_of::<Capability>(), 104);
        assert_eq!(size_of::<PixFormat>(), 48);
        assert_eq!(size_of::<Format>(), 208);
        assert_eq!(size_of::<StreamParm>(), 204);
        assert_eq!(size_of::<RequestBuffers>(), 20);
        assert_eq!(size_of::<Buffer>(), 88);
        assert_eq!(std::mem::offset_of!(Buffer, sequence), 56);
        assert_eq!(std::mem::offset_of!(Buffer, offset), 64);
        assert_eq!(VIDIOC_QUERYCAP, 0x8068_5600);
        assert_eq!(VIDIOC_DQBUF, 0xc058_5611);
        assert_eq!(fourcc(*b"GREY"), 0x5945_5247);
    }
}
