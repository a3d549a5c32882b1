//! One daemon per set of devices: before anything is opened, `nanoforce run` takes an
//! exclusive `flock` on its state directory (`nanoforce.lock`, holding its pid) and on
//! every real device it will drive (the device node or pipe itself; a lock file for a
//! device known only by name). A second run on the same state directory or any of the
//! same devices is refused with the running one's pid. The kernel drops a `flock` when
//! its holder dies however it dies, so a crash leaves nothing stale.
use std::fs::{File, OpenOptions};
use std::io::{self, Write};
use std::os::fd::AsRawFd;
use std::os::unix::fs::{MetadataExt, OpenOptionsExt};
use std::path::{Path, PathBuf};

use crate::hw::config::{DaqBackend, DevicesConfig, FramesBackend, HapticBackend};
use crate::hw::frames::config::PipePath;

/// The name of the state directory's lock file.
pub const STATE_LOCK: &str = "nanoforce.lock";

/// Where lock files for devices without a node go, when writable.
const RUN_LOCK_DIR: &str = "/run/lock";

/// What one lock guards, for messages.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct LockTarget {
    /// "state directory /var/lib/nanoforce", "DAQ /dev/comedi0", ...
    pub what: String,
    /// The file the lock is taken on.
    pub path: PathBuf,
    /// A plain lock file we may create and write our pid into (not a device node).
    pub lock_file: bool,
}

/// The locks of a running daemon; dropping it releases them.
#[derive(Debug)]
pub struct InstanceLock {
    _files: Vec<File>,
}

impl InstanceLock {
    /// Takes every lock of `targets`, or fails naming the first one held elsewhere and
    /// the pid holding it.
    pub fn acquire(targets: &[LockTarget]) -> anyhow::Result<InstanceLock> {
        let mut files = Vec::with_capacity(targets.len());
        for target in targets {
            files.extend(lock_one(target)?);
        }
        Ok(InstanceLock { _files: files })
    }
}

/// The locks a run needs: its state directory (when it records) and each real device.
pub fn targets(state_dir: Option<&Path>, devices: &DevicesConfig) -> Vec<LockTarget> {
    let mut targets = Vec::new();
    if let Some(dir) = state_dir {
        targets.push(LockTarget {
            what: format!("state directory {}", dir.display()),
            path: dir.join(STATE_LOCK),
            lock_file: true,
        });
    }
    let node = |what: String, path: &Path| LockTarget {
        what,
        path: path.to_path_buf(),
        lock_file: false,
    };
    match &devices.frames {
        FramesBackend::Sim => {}
        FramesBackend::V4l2(v) => targets.push(node(
            format!("frame source {}", v.device.display()),
            &v.device,
        )),
        FramesBackend::Pipe(p) => match &p.path {
            PipePath::File(path) => {
                targets.push(node(format!("frame pipe {}", path.display()), path))
            }
            PipePath::Stdin => {}
        },
    }
    let mut seen: Vec<&PathBuf> = Vec::new();
    for positioner in &devices.positioners {
        if let DaqBackend::Comedi(c) = &positioner.daq {
            for path in std::iter::once(&c.device).chain(c.axis_devices.iter()) {
                if !seen.contains(&path) {
                    seen.push(path);
                    targets.push(node(format!("DAQ {}", path.display()), path));
                }
            }
        }
    }
    let named = |what: String, key: String| {
        let dir = if is_writable_dir(Path::new(RUN_LOCK_DIR)) {
            PathBuf::from(RUN_LOCK_DIR)
        } else {
            state_dir.map_or_else(std::env::temp_dir, Path::to_path_buf)
        };
        LockTarget {
            what,
            path: dir.join(format!("nanoforce-{}.lock", sanitise(&key))),
            lock_file: true,
        }
    };
    match &devices.haptic {
        HapticBackend::Sim => {}
        HapticBackend::OpenHaptics(o) => {
            let name = o.device_name.clone().unwrap_or_else(|| "default".into());
            targets.push(named(
                format!("haptic device {name} (OpenHaptics)"),
                format!("haptic-openhaptics-{name}"),
            ));
        }
        HapticBackend::Hid(h) => targets.push(named(
            format!(
                "haptic device {:04x}:{:04x} (HID)",
                h.vendor_id, h.product_id
            ),
            format!("haptic-hid-{:04x}-{:04x}", h.vendor_id, h.product_id),
        )),
    }
    targets
}

fn sanitise(key: &str) -> String {
    key.chars()
        .map(|c| {
            if c.is_ascii_alphanumeric() || c == '-' {
                c
            } else {
                '_'
            }
        })
        .collect()
}

fn is_writable_dir(dir: &Path) -> bool {
    let Ok(c) = std::ffi::CString::new(dir.as_os_str().as_encoded_bytes()) else {
        return false;
    };
    // SAFETY: access() reads the NUL-terminated path and nothing else.
    dir.is_dir() && unsafe { libc::access(c.as_ptr(), libc::W_OK) } == 0
}

/// The lock on one target; `None` for a device node that does not exist (opening the
/// devices then fails with the message that names the missing device).
fn lock_one(target: &LockTarget) -> anyhow::Result<Option<File>> {
    let file = if target.lock_file {
        if let Some(parent) = target.path.parent() {
            std::fs::create_dir_all(parent)
                .map_err(|e| anyhow::anyhow!("creating {}: {e}", parent.display()))?;
        }
        OpenOptions::new()
            .read(true)
            .write(true)
            .create(true)
            .truncate(false)
            .mode(0o644)
            .custom_flags(libc::O_CLOEXEC)
            .open(&target.path)
    } else {
        // A device node or pipe: opened only to hold the lock (non-blocking, so a FIFO
        // without a writer does not wait here).
        OpenOptions::new()
            .read(true)
            .custom_flags(libc::O_NONBLOCK | libc::O_CLOEXEC | libc::O_NOCTTY)
            .open(&target.path)
    };
    let file = match file {
        Err(e) if !target.lock_file && e.kind() == io::ErrorKind::NotFound => return Ok(None),
        other => other,
    }
    .map_err(|e| {
        anyhow::anyhow!(
            "{}: cannot open {} to lock it: {e}",
            target.what,
            target.path.display()
        )
    })?;
    // SAFETY: flock on a descriptor we own.
    if unsafe { libc::flock(file.as_raw_fd(), libc::LOCK_EX | libc::LOCK_NB) } != 0 {
        let err = io::Error::last_os_error();
        if err.raw_os_error() == Some(libc::EWOULDBLOCK) {
            let holder = holder_pid(&file, target)
                .map_or_else(|| "another process".to_string(), |pid| format!("pid {pid}"));
            anyhow::bail!(
                "{} is in use by another nanoforce run ({holder}, lock {}); stop it first",
                target.what,
                target.path.display()
            );
        }
        anyhow::bail!(
            "{}: cannot lock {}: {err}",
            target.what,
            target.path.display()
        );
    }
    if target.lock_file {
        let mut f = &file;
        let _ = f.set_len(0);
        let _ = writeln!(f, "{}", std::process::id());
    }
    Ok(Some(file))
}

/// The pid holding a flock on `file`: from /proc/locks (any file), else the pid the
/// holder wrote into its lock file.
fn holder_pid(file: &File, target: &LockTarget) -> Option<u32> {
    let meta = file.metadata().ok()?;
    if let Ok(locks) = std::fs::read_to_string("/proc/locks") {
        if let Some(pid) = pid_in_proc_locks(&locks, meta.dev(), meta.ino()) {
            return Some(pid);
        }
    }
    if target.lock_file {
        return std::fs::read_to_string(&target.path)
            .ok()?
            .trim()
            .parse()
            .ok();
    }
    None
}

/// `1: FLOCK  ADVISORY  WRITE 1234 08:01:5678 0 EOF`: the pid of the FLOCK on
/// device `dev` (major:minor in hex), inode `ino`.
fn pid_in_proc_locks(locks: &str, dev: u64, ino: u64) -> Option<u32> {
    let major = libc::major(dev);
    let minor = libc::minor(dev);
    locks.lines().find_map(|line| {
        let fields: Vec<&str> = line.split_whitespace().collect();
        // Waiters are listed as "1: -> FLOCK ...": skip them.
        if fields.get(1) != Some(&"FLOCK") {
            return None;
        }
        let pid: u32 = fields.get(4)?.parse().ok()?;
        let mut id = fields.get(5)?.split(':');
        let maj = u32::from_str_radix(id.next()?, 16).ok()?;
        let min = u32::from_str_radix(id.next()?, 16).ok()?;
        let inode: u64 = id.next()?.parse().ok()?;
        (maj == major && min == minor && inode == ino).then_some(pid)
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_second_lock_names_the_holder_and_a_released_one_is_free() {
        let dir = tempfile::tempdir().unwrap();
        let targets = targets(Some(dir.path()), &DevicesConfig::default());
        assert_eq!(targets.len(), 1);
        let first = InstanceLock::acquire(&targets).unwrap();
        // flock locks belong to the open file description: a second open conflicts even
        // in the same process.
        let err = InstanceLock::acquire(&targets).unwrap_err().to_string();
        let pid = format!("pid {}", std::process::id());
        assert!(
            err.contains("state directory") && err.contains(&pid),
            "{err}"
        );
        drop(first);
        InstanceLock::acquire(&targets).unwrap();
    }

    #[test]
    fn a_frame_pipe_in_use_is_refused_whatever_the_state_directory() {
        use crate::hw::frames::config::{PipeConfig, PipeFormat};
        let dir = tempfile::tempdir().unwrap();
        let fifo = dir.path().join("frames.fifo");
        let c = std::ffi::CString::new(fifo.to_str().unwrap()).unwrap();
        // SAFETY: mkfifo with a NUL-terminated path.
        assert_eq!(unsafe { libc::mkfifo(c.as_ptr(), 0o600) }, 0);
        let devices = DevicesConfig {
            frames: FramesBackend::Pipe(PipeConfig {
                path: PipePath::File(fifo.clone()),
                format: PipeFormat::Header,
                timeout_ms: 1000,
            }),
            ..DevicesConfig::default()
        };
        let (a, b) = (dir.path().join("a"), dir.path().join("b"));
        let _first = InstanceLock::acquire(&targets(Some(&a), &devices)).unwrap();
        let err = InstanceLock::acquire(&targets(Some(&b), &devices))
            .unwrap_err()
            .to_string();
        assert!(
            err.contains(&format!("frame pipe {}", fifo.display()))
                && err.contains(&format!("pid {}", std::process::id())),
            "{err}"
        );
    }

    #[test]
    fn proc_locks_lines() {
        let locks = "1: POSIX  ADVISORY  WRITE 99 08:01:77 0 EOF\n\
                     2: FLOCK  ADVISORY  WRITE 4242 00:1a:77 0 EOF\n\
                     2: -> FLOCK  ADVISORY  WRITE 5555 00:1a:77 0 EOF\n";
        assert_eq!(
            pid_in_proc_locks(locks, libc::makedev(0, 0x1a), 77),
            Some(4242)
        );
        assert_eq!(pid_in_proc_locks(locks, libc::makedev(8, 1), 77), None);
    }

    #[test]
    fn device_keys_are_file_names() {
        assert_eq!(
            sanitise("haptic-openhaptics-Default PHANToM"),
            "haptic-openhaptics-Default_PHANToM"
        );
    }
}
