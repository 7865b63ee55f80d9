//! Reading input files safely: only regular files are read (a FIFO would block forever, a
//! device such as `/dev/zero` never ends), every read is bounded by a size limit checked against
//! the file's length before anything is allocated, and every file read is remembered so that
//! [`crate::atomic`] can refuse to write an output over an input of the same command.
//!
//! Limits (documented in `reports/reliability.md`):
//! - [`MAP_LIMIT`]: 1 GiB for a surface map (the largest real Zygo export in the project's data is
//!   under 20 MB; a 4096 x 4096 CSV grid is about 170 MB);
//! - [`LOG_LIMIT`]: 256 MiB for a tool-path log (about 8 million rows);
//! - [`TEXT_LIMIT`]: 16 MiB for recipes, dwell cases, manifests and lists.

use std::fs::File;
use std::io::{self, Read};
use std::path::{Path, PathBuf};
use std::sync::Mutex;

/// Largest surface map file read (bytes).
pub const MAP_LIMIT: u64 = 1 << 30;
/// Largest tool-path log read (bytes).
pub const LOG_LIMIT: u64 = 256 << 20;
/// Largest recipe / case / manifest / list file read (bytes).
pub const TEXT_LIMIT: u64 = 16 << 20;

/// The identity of a file: device and inode on Unix, the canonical path elsewhere.
#[derive(Debug, Clone, PartialEq, Eq)]
enum FileId {
    #[cfg(unix)]
    Inode(u64, u64),
    #[allow(dead_code)]
    Path(PathBuf),
}

static INPUTS: Mutex<Vec<(FileId, PathBuf)>> = Mutex::new(Vec::new());
static GUARD: std::sync::atomic::AtomicBool = std::sync::atomic::AtomicBool::new(false);

/// Turns on the input guard for this process: from now on every file read through this module
/// is remembered, and [`crate::atomic`] refuses to write over one. A command-line program calls
/// this once at start ("no output of a command replaces one of its inputs"); a library user that
/// reads and rewrites its own files leaves it off.
pub fn enable_input_guard() {
    GUARD.store(true, std::sync::atomic::Ordering::Relaxed);
}

fn guard_on() -> bool {
    GUARD.load(std::sync::atomic::Ordering::Relaxed)
}

fn file_id(path: &Path, meta: &std::fs::Metadata) -> FileId {
    #[cfg(unix)]
    {
        use std::os::unix::fs::MetadataExt;
        let _ = path;
        FileId::Inode(meta.dev(), meta.ino())
    }
    #[cfg(not(unix))]
    {
        let _ = meta;
        FileId::Path(std::fs::canonicalize(path).unwrap_or_else(|_| path.to_path_buf()))
    }
}

/// Remembers `path` as an input of this process (outputs may not replace it), when the guard
/// is on ([`enable_input_guard`]).
pub fn register_input(path: &Path) {
    if !guard_on() {
        return;
    }
    if let Ok(meta) = std::fs::metadata(path) {
        let id = file_id(path, &meta);
        let mut g = INPUTS.lock().unwrap_or_else(|e| e.into_inner());
        if !g.iter().any(|(i, p)| *i == id && p == path) {
            g.push((id, path.to_path_buf()));
        }
    }
}

/// If the existing file at `path` (symbolic links followed) is an input read by this process,
/// the path under which it was read.
pub fn input_named(path: &Path) -> Option<PathBuf> {
    if !guard_on() {
        return None;
    }
    let meta = std::fs::metadata(path).ok()?;
    let id = file_id(path, &meta);
    let g = INPUTS.lock().unwrap_or_else(|e| e.into_inner());
    // The registered path must still name that file: a deleted input's inode may be reused.
    g.iter()
        .find(|(i, p)| *i == id && std::fs::metadata(p).is_ok_and(|m| file_id(p, &m) == id))
        .map(|(_, p)| p.clone())
}

/// Forgets every registered input (for long-running callers and tests).
pub fn clear_inputs() {
    INPUTS.lock().unwrap_or_else(|e| e.into_inner()).clear();
}

/// What kind of file a metadata describes, for messages.
pub fn kind_name(ft: &std::fs::FileType) -> &'static str {
    #[cfg(unix)]
    {
        use std::os::unix::fs::FileTypeExt;
        if ft.is_fifo() {
            return "a FIFO (named pipe)";
        }
        if ft.is_char_device() {
            return "a character device";
        }
        if ft.is_block_device() {
            return "a block device";
        }
        if ft.is_socket() {
            return "a socket";
        }
    }
    if ft.is_dir() {
        "a directory"
    } else if ft.is_symlink() {
        "a symbolic link"
    } else if ft.is_file() {
        "a regular file"
    } else {
        "not a regular file"
    }
}

fn invalid(what: String) -> io::Error {
    io::Error::new(io::ErrorKind::InvalidInput, what)
}

/// Opens a regular file for reading (symbolic links followed) and registers it as an input.
/// A FIFO, device, socket or directory is refused before it is opened, so nothing blocks.
/// Returns the file and its length; a length over `limit` is refused.
pub fn open_regular(path: &Path, limit: u64) -> io::Result<(File, u64)> {
    let meta = std::fs::metadata(path)?;
    if !meta.is_file() {
        return Err(invalid(format!(
            "is {}, not a regular file (bonnetlab reads only regular files)",
            kind_name(&meta.file_type())
        )));
    }
    let file = File::open(path)?;
    // The file may have been swapped between the check and the open: check what was opened.
    let meta = file.metadata()?;
    if !meta.is_file() {
        return Err(invalid(format!(
            "is {}, not a regular file (bonnetlab reads only regular files)",
            kind_name(&meta.file_type())
        )));
    }
    if meta.len() > limit {
        return Err(invalid(format!(
            "is {} bytes, over the {} limit for this kind of file",
            meta.len(),
            human(limit)
        )));
    }
    register_input(path);
    Ok((file, meta.len()))
}

/// Reads at most `max` bytes from the start of a regular file (for format detection).
pub fn read_head(path: &Path, limit: u64, max: usize) -> io::Result<(Vec<u8>, u64)> {
    let (file, len) = open_regular(path, limit)?;
    let want = (len as usize).min(max);
    let mut buf = Vec::with_capacity(want);
    file.take(want as u64).read_to_end(&mut buf)?;
    Ok((buf, len))
}

/// Reads a whole regular file of at most `limit` bytes. The file growing while it is read is
/// caught too (never more than `limit + 1` bytes are read).
pub fn read_bounded(path: &Path, limit: u64) -> io::Result<Vec<u8>> {
    let (file, len) = open_regular(path, limit)?;
    let mut buf = Vec::new();
    buf.try_reserve_exact(len as usize).map_err(|_| {
        io::Error::new(
            io::ErrorKind::OutOfMemory,
            "cannot allocate the file's size",
        )
    })?;
    file.take(limit + 1).read_to_end(&mut buf)?;
    if buf.len() as u64 > limit {
        return Err(invalid(format!(
            "grew over the {} limit while being read",
            human(limit)
        )));
    }
    Ok(buf)
}

/// Reads a whole regular text file of at most `limit` bytes as UTF-8. Binary content is
/// refused with the offset of the first invalid byte (`what` names the expected format).
pub fn read_text(path: &Path, limit: u64, what: &str) -> io::Result<String> {
    let bytes = read_bounded(path, limit)?;
    String::from_utf8(bytes).map_err(|e| {
        let at = e.utf8_error().valid_up_to();
        let b = e.as_bytes()[at];
        io::Error::new(
            io::ErrorKind::InvalidData,
            format!("is not a text file (byte {at} is 0x{b:02X}, not UTF-8): expected {what}"),
        )
    })
}

/// A byte count in the largest whole binary unit.
pub fn human(n: u64) -> String {
    if n >= 1 << 30 && n.is_multiple_of(1 << 30) {
        format!("{} GiB", n >> 30)
    } else if n >= 1 << 20 && n.is_multiple_of(1 << 20) {
        format!("{} MiB", n >> 20)
    } else {
        format!("{n} bytes")
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn regular_file_is_read_and_registered() {
        enable_input_guard();
        let d = tempfile::tempdir().unwrap();
        let p = d.path().join("a.txt");
        std::fs::write(&p, "hello").unwrap();
        assert_eq!(read_text(&p, 100, "text").unwrap(), "hello");
        assert_eq!(input_named(&p).as_deref(), Some(p.as_path()));
    }

    #[test]
    fn over_limit_and_binary_are_refused() {
        let d = tempfile::tempdir().unwrap();
        let p = d.path().join("a.bin");
        std::fs::write(&p, [b'a', 0x8F, 0]).unwrap();
        let e = read_bounded(&p, 2).unwrap_err().to_string();
        assert!(e.contains("over the 2 bytes limit"), "{e}");
        let e = read_text(&p, 100, "a TOML file").unwrap_err().to_string();
        assert!(e.contains("byte 1 is 0x8F") && e.contains("TOML"), "{e}");
    }

    #[test]
    fn directory_and_device_are_refused_without_blocking() {
        let d = tempfile::tempdir().unwrap();
        let e = read_bounded(d.path(), 100).unwrap_err().to_string();
        assert!(e.contains("a directory"), "{e}");
        #[cfg(unix)]
        {
            let e = read_bounded(Path::new("/dev/zero"), 100)
                .unwrap_err()
                .to_string();
            assert!(e.contains("character device"), "{e}");
        }
    }
}
