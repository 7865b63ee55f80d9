//! Output files written whole or not at all, never over an input, a special file or a run in
//! progress.
//!
//! - One file ([`write_atomic`]): the bytes go to a hidden temporary file in the destination's
//!   directory (so the rename cannot cross file systems), which is flushed, fsynced and renamed
//!   over the destination. On any error the temporary file is removed and the destination is
//!   untouched. Temporary files left by a killed run (`.NAME.tmp-PID-N` whose process is gone)
//!   are removed the next time NAME is written.
//! - A set of files in one directory ([`OutputSet`], for `--out DIR`): a lock file
//!   `DIR/.bonnetlab.lock` (holding the writer's process id) refuses a second writer while the
//!   first runs; every file is written whole into a staging directory inside DIR first, and only
//!   when all are written are they renamed into place, one after another, so a failure part-way
//!   (full disk, a name too long) leaves DIR exactly as it was, never new files beside old ones.
//!   A set given a kind ([`OutputSet::record_as`]) keeps a record of what it published
//!   (`DIR/.bonnetlab-KIND.outputs`: each file's name and a hash of its bytes); the next set of
//!   that kind removes the files the last one published and this one does not write (a run
//!   without the option that wrote them), but only while their bytes are still those it wrote:
//!   a file the user changed, or one no record names, is never touched.
//! - The destination, for both: an existing regular file is replaced; a symbolic link is
//!   followed (the file it points to is replaced, the link is kept; a link to nothing is
//!   refused); a FIFO, device, socket or directory is refused (write to stdout with `-` instead);
//!   with the input guard on ([`crate::input::enable_input_guard`], as the CLI does), a file this
//!   process has read as an input is refused.

use std::fs::{self, File, OpenOptions};
use std::io::{self, BufWriter, Write};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};

use crate::input::{input_named, kind_name};

static COUNTER: AtomicU64 = AtomicU64::new(0);

/// Name of the lock file an [`OutputSet`] holds in its directory.
pub const LOCK_NAME: &str = ".bonnetlab.lock";
const STAGING_PREFIX: &str = ".bonnetlab-staging-";

fn refuse(what: String) -> io::Error {
    io::Error::new(io::ErrorKind::InvalidInput, what)
}

/// Where writing `path` really goes: `path` itself, or the file a symbolic link points to.
/// Refuses special files, directories, links to nothing and inputs of this process.
pub fn resolve_destination(path: &Path) -> io::Result<PathBuf> {
    if path.file_name().is_none() {
        return Err(refuse("the output path has no file name".into()));
    }
    let meta = match fs::symlink_metadata(path) {
        Ok(m) => m,
        Err(e) if e.kind() == io::ErrorKind::NotFound => return Ok(path.to_path_buf()),
        Err(e) => return Err(e),
    };
    let dest = if meta.file_type().is_symlink() {
        match fs::canonicalize(path) {
            Ok(t) => t,
            Err(_) => {
                let to = fs::read_link(path)
                    .map(|t| t.display().to_string())
                    .unwrap_or_default();
                return Err(refuse(format!(
                    "is a symbolic link to a missing file ({to}); refusing to create its target"
                )));
            }
        }
    } else {
        path.to_path_buf()
    };
    let m = fs::metadata(&dest)?;
    if !m.is_file() {
        return Err(refuse(format!(
            "is {}, not a regular file: refusing to replace it (use - for stdout)",
            kind_name(&m.file_type())
        )));
    }
    if let Some(input) = input_named(&dest) {
        return Err(refuse(format!(
            "is an input of this command ({}): refusing to overwrite it",
            input.display()
        )));
    }
    Ok(dest)
}

/// Writes `bytes` to `path` atomically.
pub fn write_atomic(path: &Path, bytes: &[u8]) -> io::Result<()> {
    write_atomic_with(path, |w| w.write_all(bytes))
}

/// Writes whatever `fill` writes to `path` atomically (through a buffered writer).
pub fn write_atomic_with<F>(path: &Path, fill: F) -> io::Result<()>
where
    F: FnOnce(&mut dyn Write) -> io::Result<()>,
{
    stage_with(path, fill)?.commit()
}

/// One output file written whole beside its destination and not yet published: a command
/// with several outputs stages every one of them before it publishes any, so a destination
/// that cannot be written leaves all of them as they were. Dropped uncommitted, it leaves
/// nothing behind.
#[derive(Debug)]
pub struct Staged {
    tmp: PathBuf,
    dest: PathBuf,
    committed: bool,
}

/// Stages whatever `fill` writes (through a buffered writer) as the next content of `path`;
/// the destination is checked as [`write_atomic`] checks it, and nothing changes there yet.
pub fn stage_with<F>(path: &Path, fill: F) -> io::Result<Staged>
where
    F: FnOnce(&mut dyn Write) -> io::Result<()>,
{
    let dest = resolve_destination(path)?;
    let name = dest
        .file_name()
        .ok_or_else(|| refuse("the output path has no file name".into()))?
        .to_string_lossy()
        .into_owned();
    let dir = parent_dir(&dest);
    remove_stale_temps(&dir, Some(&name));
    let (tmp, file) = create_temp(&dir, &name)?;
    let staged = Staged {
        tmp,
        dest,
        committed: false,
    };
    let mut w = BufWriter::new(file);
    fill(&mut w)?;
    let file = w.into_inner().map_err(|e| e.into_error())?;
    file.sync_all()?;
    Ok(staged)
}

/// Stages `bytes` as the next content of `path` (see [`stage_with`]).
pub fn stage(path: &Path, bytes: &[u8]) -> io::Result<Staged> {
    stage_with(path, |w| w.write_all(bytes))
}

impl Staged {
    /// Where the content will be published.
    pub fn destination(&self) -> &Path {
        &self.dest
    }

    /// Publishes the staged content over the destination (one rename).
    pub fn commit(mut self) -> io::Result<()> {
        fs::rename(&self.tmp, &self.dest)?;
        self.committed = true;
        sync_dir(&parent_dir(&self.dest));
        Ok(())
    }
}

impl Drop for Staged {
    fn drop(&mut self) {
        if !self.committed {
            let _ = fs::remove_file(&self.tmp);
        }
    }
}

fn parent_dir(p: &Path) -> PathBuf {
    match p.parent() {
        Some(d) if !d.as_os_str().is_empty() => d.to_path_buf(),
        _ => PathBuf::from("."),
    }
}

/// Persists a rename; not every platform can open a directory, so best effort.
fn sync_dir(dir: &Path) {
    if let Ok(d) = File::open(dir) {
        let _ = d.sync_all();
    }
}

/// Creates a fresh hidden temporary file next to the destination (never reusing a name).
fn create_temp(dir: &Path, name: &str) -> io::Result<(PathBuf, File)> {
    let pid = std::process::id();
    loop {
        let n = COUNTER.fetch_add(1, Ordering::Relaxed);
        let tmp = dir.join(format!(".{name}.tmp-{pid}-{n}"));
        match OpenOptions::new().write(true).create_new(true).open(&tmp) {
            Ok(f) => return Ok((tmp, f)),
            Err(e) if e.kind() == io::ErrorKind::AlreadyExists && n < u64::MAX => continue,
            Err(e) => return Err(e),
        }
    }
}

/// Whether process `pid` is running, where the platform says (Linux `/proc`); `None` elsewhere.
fn pid_alive(pid: u32) -> Option<bool> {
    if Path::new("/proc/self").exists() {
        Some(Path::new(&format!("/proc/{pid}")).exists())
    } else {
        None
    }
}

/// The writer pid in a temporary or staging name `...-PID-N`.
fn pid_of(name: &str) -> Option<u32> {
    let mut it = name.rsplitn(3, '-');
    let _n: u64 = it.next()?.parse().ok()?;
    it.next()?.parse().ok()
}

/// Removes temporary files (`.NAME.tmp-PID-N`, for one NAME or any) and staging directories
/// left in `dir` by runs whose process is gone. Best effort: errors are ignored, and nothing is
/// removed where process liveness cannot be told.
pub fn remove_stale_temps(dir: &Path, name: Option<&str>) {
    let me = std::process::id();
    let Ok(rd) = fs::read_dir(dir) else { return };
    for e in rd.flatten() {
        let f = e.file_name();
        let f = f.to_string_lossy();
        let ours = match name {
            Some(n) => f.starts_with(&format!(".{n}.tmp-")),
            None => (f.starts_with('.') && f.contains(".tmp-")) || f.starts_with(STAGING_PREFIX),
        };
        if !ours {
            continue;
        }
        let Some(pid) = pid_of(&f) else { continue };
        if pid == me || pid_alive(pid) != Some(false) {
            continue;
        }
        let p = e.path();
        if f.starts_with(STAGING_PREFIX) {
            let _ = fs::remove_dir_all(&p);
        } else {
            let _ = fs::remove_file(&p);
        }
    }
}

/// The lock on an output directory: `DIR/.bonnetlab.lock`, removed on drop.
#[derive(Debug)]
struct DirLock {
    path: PathBuf,
}

impl DirLock {
    fn acquire(dir: &Path) -> io::Result<DirLock> {
        let path = dir.join(LOCK_NAME);
        for _ in 0..3 {
            match OpenOptions::new().write(true).create_new(true).open(&path) {
                Ok(mut f) => {
                    writeln!(f, "{}", std::process::id())?;
                    return Ok(DirLock { path });
                }
                Err(e) if e.kind() == io::ErrorKind::AlreadyExists => {
                    let holder = fs::read_to_string(&path).unwrap_or_default();
                    let pid: Option<u32> = holder.trim().parse().ok();
                    let stale = match pid {
                        Some(p) if p == std::process::id() => false,
                        Some(p) => pid_alive(p) == Some(false),
                        // Empty or garbled: a writer killed between create and write, or a
                        // foreign file; stale once it is a minute old.
                        None => fs::metadata(&path)
                            .and_then(|m| m.modified())
                            .ok()
                            .and_then(|t| t.elapsed().ok())
                            .is_some_and(|age| age.as_secs() > 60),
                    };
                    if stale {
                        let _ = fs::remove_file(&path);
                        continue;
                    }
                    let who = pid.map(|p| format!(" (pid {p})")).unwrap_or_default();
                    return Err(io::Error::new(
                        io::ErrorKind::WouldBlock,
                        format!(
                            "another bonnetlab run{who} is writing to this directory (lock file {}); \
                             wait for it or remove the lock file if no run is going on",
                            path.display()
                        ),
                    ));
                }
                Err(e) => return Err(e),
            }
        }
        Err(io::Error::other(format!(
            "cannot take the lock file {}",
            path.display()
        )))
    }
}

impl Drop for DirLock {
    fn drop(&mut self) {
        let _ = fs::remove_file(&self.path);
    }
}

/// A set of output files published together into one directory (see the module doc).
///
/// ```no_run
/// # fn main() -> std::io::Result<()> {
/// let mut set = bonnetlab_io::atomic::OutputSet::begin(std::path::Path::new("out"))?;
/// set.write("report.json", b"{}")?;
/// set.write("report.html", b"<html></html>")?;
/// set.commit()?; // both appear, or (on any error before) neither changes
/// # Ok(()) }
/// ```
#[derive(Debug)]
pub struct OutputSet {
    dir: PathBuf,
    staging: PathBuf,
    /// (name relative to dir, final destination) in write order.
    files: Vec<(PathBuf, PathBuf)>,
    committed: bool,
    /// The outermost directory `begin` created, if it created any (an uncommitted set removes
    /// what it created again).
    created: Option<PathBuf>,
    lock: Option<DirLock>,
    /// The kind of set, when it keeps a record of what it published ([`Self::record_as`]).
    kind: Option<String>,
    /// (name, hash of its bytes) of each staged file, for the record.
    hashes: Vec<(PathBuf, u64)>,
}

/// 64-bit FNV-1a, the record's hash of a file's bytes (not cryptographic: it tells a file
/// a set wrote from one the user has changed since).
#[derive(Debug, Clone, Copy)]
struct Fnv(u64);

impl Fnv {
    fn new() -> Fnv {
        Fnv(0xcbf2_9ce4_8422_2325)
    }
    fn update(&mut self, bytes: &[u8]) {
        for &b in bytes {
            self.0 ^= u64::from(b);
            self.0 = self.0.wrapping_mul(0x0000_0100_0000_01b3);
        }
    }
}

/// A writer that hashes what passes through it.
struct Hashing<W: Write> {
    inner: W,
    hash: Fnv,
}

impl<W: Write> Write for Hashing<W> {
    fn write(&mut self, buf: &[u8]) -> io::Result<usize> {
        let n = self.inner.write(buf)?;
        self.hash.update(&buf[..n]);
        Ok(n)
    }
    fn flush(&mut self) -> io::Result<()> {
        self.inner.flush()
    }
}

/// The hash of a file's bytes, or None when it cannot be read as a regular file (a link is
/// not followed).
fn file_hash(path: &Path) -> Option<u64> {
    use std::io::Read;
    let m = fs::symlink_metadata(path).ok()?;
    if !m.file_type().is_file() {
        return None;
    }
    let mut f = File::open(path).ok()?;
    let mut h = Fnv::new();
    let mut buf = vec![0u8; 1 << 16];
    loop {
        match f.read(&mut buf) {
            Ok(0) => return Some(h.0),
            Ok(n) => h.update(&buf[..n]),
            Err(e) if e.kind() == io::ErrorKind::Interrupted => {}
            Err(_) => return None,
        }
    }
}

/// The name of the record a set of `kind` keeps in its directory.
fn record_name(kind: &str) -> String {
    format!(".bonnetlab-{kind}.outputs")
}

/// The entries of a record (`HASH NAME` lines, the hash in hex); lines that do not read so are
/// passed over.
fn read_record(path: &Path) -> Vec<(PathBuf, u64)> {
    let Ok(text) = fs::read_to_string(path) else {
        return Vec::new();
    };
    text.lines()
        .filter_map(|l| {
            let (h, name) = l.split_once(' ')?;
            Some((PathBuf::from(name), u64::from_str_radix(h, 16).ok()?))
        })
        .collect()
}

impl OutputSet {
    /// Creates `dir` if needed, takes its lock and opens a staging directory inside it.
    pub fn begin(dir: &Path) -> io::Result<OutputSet> {
        if let Ok(m) = fs::metadata(dir) {
            if !m.is_dir() {
                return Err(refuse(format!(
                    "is {}, not a directory",
                    kind_name(&m.file_type())
                )));
            }
        }
        let created = dir
            .ancestors()
            .take_while(|a| !a.as_os_str().is_empty() && !a.exists())
            .last()
            .map(Path::to_path_buf);
        fs::create_dir_all(dir)?;
        let lock = match DirLock::acquire(dir) {
            Ok(l) => l,
            Err(e) => {
                remove_created(dir, created.as_deref());
                return Err(e);
            }
        };
        remove_stale_temps(dir, None);
        let pid = std::process::id();
        let staging = loop {
            let n = COUNTER.fetch_add(1, Ordering::Relaxed);
            let s = dir.join(format!("{STAGING_PREFIX}{pid}-{n}"));
            match fs::create_dir(&s) {
                Ok(()) => break s,
                Err(e) if e.kind() == io::ErrorKind::AlreadyExists => continue,
                Err(e) => {
                    drop(lock);
                    remove_created(dir, created.as_deref());
                    return Err(e);
                }
            }
        };
        Ok(OutputSet {
            dir: dir.to_path_buf(),
            staging,
            files: Vec::new(),
            committed: false,
            created,
            lock: Some(lock),
            kind: None,
            hashes: Vec::new(),
        })
    }

    /// Keeps a record of this set's files as a set of `kind` (letters, digits, `-` and `_`):
    /// on commit, files the last set of that kind published here and this one does not write
    /// are removed while their bytes are still what that set wrote (see the module doc).
    pub fn record_as(&mut self, kind: &str) -> io::Result<()> {
        if kind.is_empty()
            || !kind
                .chars()
                .all(|c| c.is_ascii_alphanumeric() || c == '-' || c == '_')
        {
            return Err(refuse(format!(
                "{kind:?}: a set's kind is letters, digits, - and _"
            )));
        }
        self.kind = Some(kind.to_string());
        Ok(())
    }

    /// The directory the set is published into.
    pub fn dir(&self) -> &Path {
        &self.dir
    }

    /// Where the staged files will be published, in the order written.
    pub fn destinations(&self) -> impl Iterator<Item = &Path> {
        self.files.iter().map(|(_, d)| d.as_path())
    }

    /// Checks `name` (a relative path without `..`) and its final destination.
    fn check(&self, name: &Path) -> io::Result<PathBuf> {
        use std::path::Component;
        if name.as_os_str().is_empty()
            || !name.components().all(|c| matches!(c, Component::Normal(_)))
        {
            return Err(refuse(format!(
                "{}: an output name must be a relative path inside the output directory",
                name.display()
            )));
        }
        resolve_destination(&self.dir.join(name))
    }

    /// Stages one file whole (created through `fill`); nothing in the directory changes yet.
    pub fn write_with<F>(&mut self, name: impl AsRef<Path>, fill: F) -> io::Result<()>
    where
        F: FnOnce(&mut dyn Write) -> io::Result<()>,
    {
        let name = name.as_ref();
        let dest = self.check(name)?;
        let staged = self.staging.join(name);
        if let Some(p) = staged.parent() {
            fs::create_dir_all(p)?;
        }
        if name.to_str().is_none_or(|n| n.contains('\n')) {
            return Err(refuse(format!(
                "{}: an output name must be UTF-8 on one line",
                name.display()
            )));
        }
        let file = File::create(&staged)?;
        let mut w = Hashing {
            inner: BufWriter::new(file),
            hash: Fnv::new(),
        };
        fill(&mut w)?;
        let hash = w.hash.0;
        let file = w.inner.into_inner().map_err(|e| e.into_error())?;
        file.sync_all()?;
        self.files.retain(|(n, _)| n != name);
        self.files.push((name.to_path_buf(), dest));
        self.hashes.retain(|(n, _)| n != name);
        self.hashes.push((name.to_path_buf(), hash));
        Ok(())
    }

    /// Stages one file whole; nothing in the directory changes yet.
    pub fn write(&mut self, name: impl AsRef<Path>, bytes: &[u8]) -> io::Result<()> {
        self.write_with(name, |w| w.write_all(bytes))
    }

    /// Publishes every staged file (in the order written), then removes the staging directory
    /// and the lock. Files whose destination is a symbolic link are written through the link.
    pub fn commit(mut self) -> io::Result<()> {
        // The record is staged and published with the files; the last record is read first.
        let last = match self.kind.clone() {
            Some(kind) => {
                let name = record_name(&kind);
                let last = read_record(&self.dir.join(&name));
                fs::write(self.staging.join(&name), self.record_text())?;
                let dest = self.check(Path::new(&name))?;
                self.files.retain(|(n, _)| n.as_os_str() != name.as_str());
                self.files.push((PathBuf::from(name), dest));
                Some(last)
            }
            None => None,
        };
        // Directories first, so a rename cannot fail half-way for a missing parent.
        for (name, dest) in &self.files {
            if let Some(p) = dest.parent() {
                if !p.as_os_str().is_empty() {
                    fs::create_dir_all(p).map_err(|e| {
                        io::Error::new(e.kind(), format!("{}: {e}", name.display()))
                    })?;
                }
            }
        }
        for (name, dest) in &self.files {
            let staged = self.staging.join(name);
            if dest == &self.dir.join(name) {
                fs::rename(&staged, dest)?;
            } else {
                // A symbolic link to elsewhere (maybe another file system).
                let bytes = fs::read(&staged)?;
                write_atomic(dest, &bytes)?;
            }
        }
        if let Some(old) = &last {
            self.retire(old);
        }
        sync_dir(&self.dir);
        self.committed = true;
        let _ = fs::remove_dir_all(&self.staging);
        Ok(())
    }

    /// Removes the files of the last record that this set did not write, while their bytes
    /// are still what that set wrote.
    fn retire(&self, last: &[(PathBuf, u64)]) {
        for (name, hash) in last {
            if self.hashes.iter().any(|(n, _)| n == name) || self.check(name).is_err() {
                continue;
            }
            let p = self.dir.join(name);
            if file_hash(&p) == Some(*hash) && fs::remove_file(&p).is_ok() {
                // Its directories inside `dir` go too once empty (`remove_dir` keeps any
                // that holds something).
                for d in p.ancestors().skip(1) {
                    if d == self.dir || fs::remove_dir(d).is_err() {
                        break;
                    }
                }
            }
        }
    }

    /// This set's record: a `HASH NAME` line a file, sorted by name.
    fn record_text(&self) -> String {
        let mut entries: Vec<&(PathBuf, u64)> = self.hashes.iter().collect();
        entries.sort_by(|a, b| a.0.cmp(&b.0));
        entries
            .iter()
            .map(|(name, hash)| format!("{hash:016x} {}\n", name.display()))
            .collect()
    }
}

impl Drop for OutputSet {
    fn drop(&mut self) {
        if !self.committed {
            let _ = fs::remove_dir_all(&self.staging);
            // The lock goes first; a directory this set created is then empty and goes too
            // (`remove_dir` never removes one that holds anything).
            self.lock.take();
            remove_created(&self.dir, self.created.as_deref());
        }
    }
}

/// Removes `dir` and its parents up to `outermost` (the directories a set created), as long as
/// each is empty; nothing when it created none.
fn remove_created(dir: &Path, outermost: Option<&Path>) {
    let Some(top) = outermost else { return };
    for d in dir.ancestors() {
        if fs::remove_dir(d).is_err() || d == top {
            break;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn leftovers(dir: &Path) -> Vec<String> {
        fs::read_dir(dir)
            .unwrap()
            .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
            .filter(|n| n.contains(".tmp-"))
            .collect()
    }

    #[test]
    fn writes_whole_file_and_replaces_old_content() {
        let d = tempfile::tempdir().unwrap();
        let p = d.path().join("out.txt");
        fs::write(&p, b"old content that is longer").unwrap();
        write_atomic(&p, b"new").unwrap();
        assert_eq!(fs::read(&p).unwrap(), b"new");
        assert!(leftovers(d.path()).is_empty());
    }

    #[test]
    fn failure_leaves_destination_untouched_and_no_temp_file() {
        let d = tempfile::tempdir().unwrap();
        let p = d.path().join("out.txt");
        fs::write(&p, b"precious").unwrap();
        let err = write_atomic_with(&p, |w| {
            w.write_all(b"partial")?;
            Err(io::Error::other("generator failed half way"))
        })
        .unwrap_err();
        assert!(err.to_string().contains("half way"));
        assert_eq!(fs::read(&p).unwrap(), b"precious");
        assert!(leftovers(d.path()).is_empty());
    }

    #[test]
    fn missing_directory_is_an_error_not_a_panic() {
        let d = tempfile::tempdir().unwrap();
        let p = d.path().join("no/such/dir/out.txt");
        assert!(write_atomic(&p, b"x").is_err());
        assert!(!p.exists());
    }

    #[cfg(unix)]
    #[test]
    fn fifo_and_device_destinations_are_refused_not_replaced() {
        use std::os::unix::fs::FileTypeExt;
        let d = tempfile::tempdir().unwrap();
        let fifo = d.path().join("pipe");
        let st = std::process::Command::new("mkfifo")
            .arg(&fifo)
            .status()
            .unwrap();
        assert!(st.success());
        let e = write_atomic(&fifo, b"x").unwrap_err().to_string();
        assert!(e.contains("FIFO"), "{e}");
        assert!(fs::symlink_metadata(&fifo).unwrap().file_type().is_fifo());
        let e = write_atomic(Path::new("/dev/null"), b"x")
            .unwrap_err()
            .to_string();
        assert!(e.contains("character device"), "{e}");
        assert!(leftovers(d.path()).is_empty());
    }

    #[cfg(unix)]
    #[test]
    fn symlink_is_followed_and_kept_dangling_link_refused() {
        let d = tempfile::tempdir().unwrap();
        let target = d.path().join("real.txt");
        fs::write(&target, b"old").unwrap();
        let link = d.path().join("link.txt");
        std::os::unix::fs::symlink(&target, &link).unwrap();
        write_atomic(&link, b"new").unwrap();
        assert!(fs::symlink_metadata(&link)
            .unwrap()
            .file_type()
            .is_symlink());
        assert_eq!(fs::read(&target).unwrap(), b"new");
        let dangling = d.path().join("dangling.txt");
        std::os::unix::fs::symlink(d.path().join("nothing"), &dangling).unwrap();
        let e = write_atomic(&dangling, b"x").unwrap_err().to_string();
        assert!(e.contains("missing file"), "{e}");
        assert!(!d.path().join("nothing").exists());
    }

    #[test]
    fn an_input_is_never_overwritten() {
        crate::input::enable_input_guard();
        let d = tempfile::tempdir().unwrap();
        let p = d.path().join("in.csv");
        fs::write(&p, b"1,2\n").unwrap();
        crate::input::read_bounded(&p, 100).unwrap();
        let e = write_atomic(&p, b"x").unwrap_err().to_string();
        assert!(e.contains("input of this command"), "{e}");
        assert_eq!(fs::read(&p).unwrap(), b"1,2\n");
    }

    #[test]
    fn stale_temp_of_a_dead_process_is_removed() {
        if pid_alive(1).is_none() {
            return; // liveness cannot be told on this platform: nothing is removed by design
        }
        let d = tempfile::tempdir().unwrap();
        // pid 4194305 is above Linux's largest pid (2^22), so it is never alive.
        let stale = d.path().join(".out.txt.tmp-4194305-7");
        fs::write(&stale, b"half").unwrap();
        let other = d.path().join(".other.txt.tmp-4194305-8");
        fs::write(&other, b"half").unwrap();
        write_atomic(&d.path().join("out.txt"), b"x").unwrap();
        assert!(!stale.exists());
        assert!(
            other.exists(),
            "only the written name is cleaned by write_atomic"
        );
        let set = OutputSet::begin(d.path()).unwrap();
        assert!(!other.exists(), "OutputSet::begin cleans every stale temp");
        drop(set);
    }

    /// A set dropped uncommitted removes the directories it created (and only those); a
    /// staged file dropped uncommitted leaves nothing, committed it replaces the destination.
    #[test]
    fn uncommitted_outputs_leave_nothing_behind() {
        let d = tempfile::tempdir().unwrap();
        let out = d.path().join("a").join("b").join("out");
        let mut set = OutputSet::begin(&out).unwrap();
        set.write("x.json", b"{}").unwrap();
        drop(set);
        assert!(!d.path().join("a").exists());
        std::fs::create_dir(d.path().join("kept")).unwrap();
        let set = OutputSet::begin(&d.path().join("kept").join("new")).unwrap();
        drop(set);
        assert!(d.path().join("kept").is_dir() && !d.path().join("kept/new").exists());

        let p = d.path().join("f.txt");
        std::fs::write(&p, b"old").unwrap();
        drop(stage(&p, b"new").unwrap());
        assert_eq!(fs::read(&p).unwrap(), b"old");
        assert!(leftovers(d.path()).is_empty());
        stage(&p, b"new").unwrap().commit().unwrap();
        assert_eq!(fs::read(&p).unwrap(), b"new");
        assert!(leftovers(d.path()).is_empty());
    }

    #[test]
    fn output_set_is_all_or_nothing_and_locked() {
        let d = tempfile::tempdir().unwrap();
        let dir = d.path().join("out");
        let mut set = OutputSet::begin(&dir).unwrap();
        set.write("report.json", b"old json").unwrap();
        set.write("report.html", b"old html").unwrap();
        set.commit().unwrap();
        // A second writer while one holds the lock is refused.
        let first = OutputSet::begin(&dir).unwrap();
        fs::write(dir.join(LOCK_NAME), "1\n").unwrap(); // pid 1 is alive
        drop(first); // removes the lock it thinks it owns; recreate a foreign one
        fs::write(dir.join(LOCK_NAME), "1\n").unwrap();
        if pid_alive(1) == Some(true) {
            let e = OutputSet::begin(&dir).unwrap_err().to_string();
            assert!(e.contains("another bonnetlab run (pid 1)"), "{e}");
        }
        fs::remove_file(dir.join(LOCK_NAME)).unwrap();
        // A failure part-way leaves the directory exactly as it was.
        let mut set = OutputSet::begin(&dir).unwrap();
        set.write("report.json", b"new json").unwrap();
        let long = "x".repeat(300);
        assert!(set.write(format!("{long}.csv"), b"1").is_err());
        drop(set);
        assert_eq!(fs::read(dir.join("report.json")).unwrap(), b"old json");
        assert_eq!(fs::read(dir.join("report.html")).unwrap(), b"old html");
        let names: Vec<String> = fs::read_dir(&dir)
            .unwrap()
            .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
            .collect();
        assert_eq!(names.len(), 2, "{names:?}");
        // Names escaping the directory are refused.
        let mut set = OutputSet::begin(&dir).unwrap();
        assert!(set.write("../x", b"1").is_err());
        assert!(set.write("/tmp/x", b"1").is_err());
    }

    fn publish(dir: &Path, kind: &str, files: &[(&str, &[u8])]) {
        let mut set = OutputSet::begin(dir).unwrap();
        set.record_as(kind).unwrap();
        for (n, b) in files {
            set.write(n, b).unwrap();
        }
        set.commit().unwrap();
    }

    #[test]
    fn a_set_removes_what_its_last_run_wrote_and_it_does_not() {
        let d = tempfile::tempdir().unwrap();
        let dir = d.path().join("out");
        fs::create_dir(&dir).unwrap();
        fs::write(dir.join("mine.txt"), b"the user's").unwrap();
        publish(
            &dir,
            "sim",
            &[
                ("a.json", b"1"),
                ("sweep.csv", b"2"),
                ("sub/c.csv", b"3"),
                ("edited.txt", b"4"),
            ],
        );
        publish(&dir, "other", &[("z.txt", b"z")]);
        fs::write(dir.join("edited.txt"), b"changed by the user").unwrap();
        publish(&dir, "sim", &[("a.json", b"5")]);
        assert_eq!(fs::read(dir.join("a.json")).unwrap(), b"5");
        assert!(!dir.join("sweep.csv").exists());
        assert!(!dir.join("sub").exists(), "its emptied directory too");
        // Changed since, never recorded, or another kind's: kept.
        assert_eq!(
            fs::read(dir.join("edited.txt")).unwrap(),
            b"changed by the user"
        );
        assert_eq!(fs::read(dir.join("mine.txt")).unwrap(), b"the user's");
        assert_eq!(fs::read(dir.join("z.txt")).unwrap(), b"z");
        let rec = fs::read_to_string(dir.join(".bonnetlab-sim.outputs")).unwrap();
        assert_eq!(rec.lines().count(), 1, "{rec}");
        assert!(rec.ends_with(" a.json\n"), "{rec}");
    }

    #[test]
    fn an_unpublished_set_or_a_foreign_record_removes_nothing() {
        let d = tempfile::tempdir().unwrap();
        let dir = d.path().join("out");
        publish(&dir, "sim", &[("a.json", b"1"), ("b.csv", b"2")]);
        {
            let mut set = OutputSet::begin(&dir).unwrap();
            set.record_as("sim").unwrap();
            set.write("a.json", b"3").unwrap();
        } // dropped without commit
        assert_eq!(fs::read(dir.join("b.csv")).unwrap(), b"2");
        // A record naming a file outside the directory is passed over.
        fs::write(d.path().join("outside.txt"), b"x").unwrap();
        let h = file_hash(&d.path().join("outside.txt")).unwrap();
        fs::write(
            dir.join(".bonnetlab-sim.outputs"),
            format!("{h:016x} ../outside.txt\n"),
        )
        .unwrap();
        publish(&dir, "sim", &[("a.json", b"4")]);
        assert!(d.path().join("outside.txt").exists());
        assert!(OutputSet::begin(&dir).unwrap().record_as("a/b").is_err());
    }
}
