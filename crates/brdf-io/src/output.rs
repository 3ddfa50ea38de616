//! Output files written atomically, the way `File::create` would leave them.
//!
//! [`AtomicOutput`] is the one mechanism every writer of this crate (tensor files, MERL files,
//! `.npy` arrays, dataset stores) uses, and the one the CLI should use for its own outputs
//! (CSV, PNG, JSON): [`write_file_atomic`] for "write these bytes", [`write_atomic_with`] for a
//! streaming body, [`AtomicOutput`] itself when the writer must outlive one call.
//!
//! Rules:
//! - **target missing or a regular file**: the data goes to a temporary file in the target's
//!   directory (named `.NAME.XXXXXX.tmp`), renamed into place by [`AtomicOutput::commit`];
//!   dropping the output uncommitted deletes it, so readers never see a half-written file. A
//!   new file gets mode `0666 & !umask` (as `File::create`), a replaced file keeps its mode. A
//!   symbolic link to a regular file is followed: the file it points to is replaced, the link
//!   stays. A regular file without write permission (`chmod a-w`, or none for this user) is
//!   refused with a permission error, as `File::create` refuses it, rather than renamed over.
//! - **read-only directories**: nothing is created inside a directory whose mode bits say
//!   read-only (no write bit, or none for this user): no temporary file (so no new or replaced
//!   file), no staging directory, no missing output directory. Root, whom the system lets write
//!   there, is refused as well ([`ensure_dir_writable`]), as for read-only files; the error names
//!   the directory.
//! - **target exists and is not a regular file** (`/dev/stdout`, `/dev/null`, a FIFO, a
//!   terminal, a character device; symlinks followed): the data is written straight into it,
//!   since renaming would replace the special file by a regular one. Such output is not atomic.
//!   Writers that need to seek ([`AtomicOutput::create_seekable`]) refuse targets that cannot
//!   seek (pipes, terminals, sockets) with [`Error::NotSeekable`].
//! - **`-`, standard output**: the data is written to the process's standard output as it is
//!   open (a dup of descriptor 1), at its current position: `{ echo a; specgp ... --out -; } >
//!   f` keeps `a`, `>> f` appends. Nothing is resolved or renamed (following `/dev/stdout` to a
//!   redirected file and renaming over it lost what the shell had written). Seeking writers
//!   need standard output to be a regular file at its start, not opened for appending (`> f`),
//!   and refuse anything else with [`Error::NotSeekable`].
//! - **interrupted runs**: an exit that skips destructors (a signal, `std::process::exit`) would
//!   leave the temporary files behind. Every temporary file is listed while it exists, so a
//!   signal handler can call [`remove_unfinished_outputs`] before it exits
//!   ([`remove_unfinished_outputs_on_signal`] installs one; the `specgp` and `xtask` binaries do).
//! - **runs that write several files** stage them in a [`StagingDir`] inside the output
//!   directory and publish them together.

use std::fs::File;
use std::io::{Seek, SeekFrom, Write};
use std::path::{Path, PathBuf};
use std::sync::{Mutex, MutexGuard, PoisonError};

use tempfile::NamedTempFile;

use crate::error::{Error, Result};

/// A file being written: a temporary file renamed into place on [`AtomicOutput::commit`], or the
/// target itself when it is a special file (see the [module docs](self)).
#[derive(Debug)]
pub struct AtomicOutput {
    /// The path as given (used in error messages).
    path: PathBuf,
    inner: Inner,
}

#[derive(Debug)]
enum Inner {
    /// Temporary file and the path it is renamed to (symlinks resolved). `listed` is dropped
    /// after `tmp` (field order), so the file is deleted before it leaves the list.
    Temp {
        tmp: NamedTempFile,
        target: PathBuf,
        listed: Listed,
    },
    /// The existing special file, written in place.
    Direct(File),
}

/// The output path that means standard output.
pub const STDOUT: &str = "-";

/// How error messages name standard output.
const STDOUT_NAME: &str = "<standard output>";

/// A handle on this process's standard output (a duplicate of descriptor 1), after flushing
/// what the standard library's `stdout()` buffers.
fn stdout_file() -> std::io::Result<File> {
    std::io::stdout().flush()?;
    #[cfg(unix)]
    {
        use std::os::fd::AsFd;
        Ok(File::from(std::io::stdout().as_fd().try_clone_to_owned()?))
    }
    #[cfg(windows)]
    {
        use std::os::windows::io::AsHandle;
        Ok(File::from(
            std::io::stdout().as_handle().try_clone_to_owned()?,
        ))
    }
}

/// The part of an output's file name that its temporary file's name repeats: the whole name,
/// or its first 200 bytes (at a character boundary) for a long one, so that the temporary
/// name (`.NAME.XXXXXX.tmp`, 13 bytes more) stays within the usual 255-byte limit whenever the
/// output's own name does.
fn temp_stem(name: &str) -> &str {
    let mut end = name.len().min(200);
    while !name.is_char_boundary(end) {
        end -= 1;
    }
    &name[..end]
}

/// Bytes free for this user on the file system holding `dir` (`None` where unknown).
pub fn available_space(dir: &Path) -> Option<u64> {
    #[cfg(unix)]
    {
        rustix::fs::statvfs(dir)
            .ok()
            .map(|s| s.f_bavail.saturating_mul(s.f_frsize))
    }
    #[cfg(not(unix))]
    {
        let _ = dir;
        None
    }
}

/// Refuses, before writing, an output of about `bytes` bytes that the file system holding
/// `path` has no room for. A file the output replaces does not count as free space: the new
/// one is written beside it before the rename. Standard output and unknown free space pass.
pub fn ensure_space(path: &Path, bytes: u64, what: &str) -> Result<()> {
    if path == Path::new(STDOUT) {
        return Ok(());
    }
    let dir = match path.parent() {
        Some(d) if !d.as_os_str().is_empty() => d,
        _ => Path::new("."),
    };
    match available_space(dir) {
        Some(available) if available < bytes => Err(Error::NoSpace {
            path: path.to_owned(),
            what: what.to_owned(),
            needed: bytes,
            available,
        }),
        _ => Ok(()),
    }
}

/// Checks that a file can be created in directory `dir` (its mode bits allow it,
/// [`ensure_dir_writable`], and an unnamed temporary file can be created and dropped there), so
/// that a command can refuse an unwritable output before its work.
pub fn check_writable_dir(dir: &Path) -> Result<()> {
    ensure_dir_writable(dir, None)?;
    tempfile::tempfile_in(dir)
        .map(drop)
        .map_err(|e| Error::io(dir, e))
}

/// Size in bytes of what the output `path` holds now: the file, or for [`STDOUT`] the regular
/// file standard output is redirected to. `None` when that is not a regular file (a pipe, a
/// terminal) or cannot be read.
pub fn output_len(path: &Path) -> Option<u64> {
    let meta = if path == Path::new(STDOUT) {
        stdout_file().and_then(|f| f.metadata())
    } else {
        std::fs::metadata(path)
    };
    meta.ok().filter(|m| m.is_file()).map(|m| m.len())
}

/// Whether `file` was opened for appending (Linux: `/proc/self/fdinfo`; elsewhere assumed not).
fn is_append_mode(file: &File) -> bool {
    #[cfg(target_os = "linux")]
    {
        use std::os::fd::AsRawFd;
        const O_APPEND: u32 = 0o2000;
        let info = std::fs::read_to_string(format!("/proc/self/fdinfo/{}", file.as_raw_fd()));
        info.ok()
            .and_then(|t| {
                let line = t.lines().find(|l| l.starts_with("flags:"))?;
                u32::from_str_radix(line["flags:".len()..].trim(), 8).ok()
            })
            .is_some_and(|flags| flags & O_APPEND != 0)
    }
    #[cfg(not(target_os = "linux"))]
    {
        let _ = file;
        false
    }
}

/// Whether the existing regular file or directory `path` (`meta` its metadata, symbolic links
/// followed) may be written: it has a write permission bit, and this process may write it
/// (`access(2)`: the owner's, group's or others' bit that applies; root may write anything with
/// a bit).
fn writable(path: &Path, meta: &std::fs::Metadata) -> bool {
    if meta.permissions().readonly() {
        return false;
    }
    #[cfg(unix)]
    {
        rustix::fs::access(path, rustix::fs::Access::WRITE_OK).is_ok()
    }
    #[cfg(not(unix))]
    {
        let _ = path;
        true
    }
}

/// Refuses to create anything in the existing directory `dir` (`output`, when given, is what
/// would be created) when its mode bits say read-only (`writable`): root may create files
/// there, but an output is not put where the bits say no, as a read-only file is not replaced.
/// The error ([`Error::Io`], permission denied) names the directory. A `dir` that is missing or
/// not a directory passes: creating in it fails with its own error.
pub fn ensure_dir_writable(dir: &Path, output: Option<&Path>) -> Result<()> {
    match std::fs::metadata(dir) {
        Ok(meta) if meta.is_dir() && !writable(dir, &meta) => {
            let what = output.map_or_else(
                || "no output is written there".to_owned(),
                |o| format!("{} is not written there", o.display()),
            );
            Err(Error::io(
                dir,
                std::io::Error::new(
                    std::io::ErrorKind::PermissionDenied,
                    format!(
                        "the directory is read-only (no write permission), so {what}; make it \
                         writable (chmod u+w) or choose another output"
                    ),
                ),
            ))
        }
        _ => Ok(()),
    }
}

/// `std::fs::create_dir_all(dir)`, refused ([`ensure_dir_writable`]) when the existing directory
/// that the first missing one would be created in is read-only.
fn create_dir_all_checked(dir: &Path) -> Result<()> {
    let mut base = dir;
    while std::fs::metadata(base).is_err() {
        base = match base.parent() {
            Some(p) if p.as_os_str().is_empty() => Path::new("."),
            Some(p) => p,
            None => break,
        };
    }
    if base != dir {
        ensure_dir_writable(base, Some(dir))?;
    }
    std::fs::create_dir_all(dir).map_err(|e| Error::io(dir, e))
}

impl AtomicOutput {
    /// Starts writing `path` (see the [module docs](self) for what happens with special files
    /// and with [`STDOUT`]).
    pub fn create(path: impl AsRef<Path>) -> Result<Self> {
        let path = path.as_ref().to_owned();
        if path == Path::new(STDOUT) {
            let path = PathBuf::from(STDOUT_NAME);
            let file = stdout_file().map_err(|e| Error::io(&path, e))?;
            return Ok(Self {
                path,
                inner: Inner::Direct(file),
            });
        }
        let io = |e| Error::io(&path, e);
        let (target, existing) = match std::fs::metadata(&path) {
            Ok(meta) if !meta.is_file() => {
                let file = std::fs::OpenOptions::new()
                    .write(true)
                    .open(&path)
                    .map_err(io)?;
                return Ok(Self {
                    path,
                    inner: Inner::Direct(file),
                });
            }
            Ok(meta) => {
                // A file without write permission is not replaced: the rename would succeed
                // where `File::create` (and a shell's `>`) fails, so `chmod a-w` would not
                // protect a reference file from an output aimed at it by mistake.
                if !writable(&path, &meta) {
                    return Err(io(std::io::Error::new(
                        std::io::ErrorKind::PermissionDenied,
                        "the file exists and is read-only (no write permission), so it is not \
                         replaced; make it writable (chmod u+w) or choose another output",
                    )));
                }
                let is_link = std::fs::symlink_metadata(&path)
                    .map(|m| m.file_type().is_symlink())
                    .unwrap_or(false);
                let target = if is_link {
                    std::fs::canonicalize(&path).map_err(io)?
                } else {
                    path.clone()
                };
                (target, Some(meta.permissions()))
            }
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => (path.clone(), None),
            Err(e) => return Err(io(e)),
        };
        let dir = match target.parent() {
            Some(p) if !p.as_os_str().is_empty() => p.to_owned(),
            _ => PathBuf::from("."),
        };
        let name = target
            .file_name()
            .map(|n| n.to_string_lossy().into_owned())
            .unwrap_or_default();
        let prefix = format!(".{}.", temp_stem(&name));
        let mut builder = tempfile::Builder::new();
        builder.prefix(&prefix).suffix(".tmp");
        // `open(2)` applies the umask to this mode: 0666 & !umask, as `File::create`.
        #[cfg(unix)]
        builder.permissions(
            <std::fs::Permissions as std::os::unix::fs::PermissionsExt>::from_mode(0o666),
        );
        ensure_dir_writable(&dir, Some(&path))?;
        let tmp = builder.tempfile_in(&dir).map_err(io)?;
        let listed = Listed::new(tmp.path());
        // A killed run's temporary file of this output stays until someone deletes it.
        if let Ok(leftovers) = other_runs_temporaries(&dir, &prefix, tmp.path(), false) {
            warn_of_leftovers(&dir, &leftovers, "a temporary file", "temporary files");
        }
        if let Some(perm) = existing {
            tmp.as_file().set_permissions(perm).map_err(io)?;
        }
        Ok(Self {
            path,
            inner: Inner::Temp {
                tmp,
                target,
                listed,
            },
        })
    }

    /// Like [`AtomicOutput::create`], for a writer that seeks: fails with
    /// [`Error::NotSeekable`] when `path` is a pipe, terminal or socket. `what` names the
    /// output in that message (e.g. "a dataset store").
    /// Standard output ([`STDOUT`]) must be a regular file at its start, not opened for
    /// appending (the writer seeks to absolute offsets).
    pub fn create_seekable(path: impl AsRef<Path>, what: &str) -> Result<Self> {
        let is_stdout = path.as_ref() == Path::new(STDOUT);
        let out = Self::create(path)?;
        if let Inner::Direct(file) = &out.inner {
            let position = (&*file).stream_position();
            let unusable = if is_stdout {
                position.map_or(true, |p| p != 0) || is_append_mode(file)
            } else {
                position.is_err()
            };
            if unusable {
                return Err(Error::NotSeekable {
                    path: out.path,
                    what: what.to_owned(),
                });
            }
        }
        Ok(out)
    }

    /// Sets the length of the output when it is a regular file (the temporary file, or standard
    /// output redirected to a file); special files have no length to set.
    pub fn set_len(&self, len: u64) -> Result<()> {
        let file = self.file();
        let regular = file.metadata().is_ok_and(|m| m.is_file());
        if regular {
            file.set_len(len).map_err(|e| Error::io(&self.path, e))?;
        }
        Ok(())
    }

    /// The path the output was created for.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// True when the target is a special file written in place (not atomic, nothing to rename).
    pub fn is_direct(&self) -> bool {
        matches!(self.inner, Inner::Direct(_))
    }

    /// The open file being written (the temporary file or the special file).
    pub fn file(&self) -> &File {
        match &self.inner {
            Inner::Temp { tmp, .. } => tmp.as_file(),
            Inner::Direct(f) => f,
        }
    }

    /// Finishes the output: flushes it to disk and renames the temporary file into place (for a
    /// special file, only flushes). Data in a `BufWriter` around this output must be flushed
    /// first (`BufWriter::into_inner`).
    pub fn commit(self) -> Result<()> {
        let path = self.path;
        match self.inner {
            Inner::Temp {
                tmp,
                target,
                listed,
            } => {
                tmp.as_file().sync_all().map_err(|e| Error::io(&path, e))?;
                tmp.persist(&target)
                    .map_err(|e| Error::io(&path, e.error))?;
                drop(listed);
            }
            Inner::Direct(mut f) => f.flush().map_err(|e| Error::io(&path, e))?,
        }
        Ok(())
    }
}

impl Write for AtomicOutput {
    fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
        let mut f = self.file();
        f.write(buf)
    }

    fn write_all(&mut self, buf: &[u8]) -> std::io::Result<()> {
        let mut f = self.file();
        f.write_all(buf)
    }

    fn flush(&mut self) -> std::io::Result<()> {
        let mut f = self.file();
        f.flush()
    }
}

impl Seek for AtomicOutput {
    fn seek(&mut self, pos: SeekFrom) -> std::io::Result<u64> {
        let mut f = self.file();
        f.seek(pos)
    }
}

/// Paths of the temporary files that exist now (outputs created and neither committed nor
/// dropped), for [`remove_unfinished_outputs`].
static UNFINISHED: Mutex<Vec<PathBuf>> = Mutex::new(Vec::new());

/// The list, even if a thread panicked while holding it (a `Vec` of paths stays consistent).
fn unfinished() -> MutexGuard<'static, Vec<PathBuf>> {
    UNFINISHED.lock().unwrap_or_else(PoisonError::into_inner)
}

/// A temporary file's entry in [`UNFINISHED`]: added on creation, removed on drop.
#[derive(Debug)]
struct Listed(PathBuf);

impl Listed {
    fn new(tmp: &Path) -> Self {
        unfinished().push(tmp.to_owned());
        Self(tmp.to_owned())
    }
}

impl Drop for Listed {
    fn drop(&mut self) {
        let mut list = unfinished();
        if let Some(i) = list.iter().position(|p| *p == self.0) {
            list.swap_remove(i);
        }
    }
}

/// The temporary files of this process's outputs that are still being written.
pub fn unfinished_outputs() -> Vec<PathBuf> {
    unfinished().clone()
}

/// Deletes the temporary files (and staging directories, [`StagingDir`]) of every output this
/// process is still writing and returns how many it deleted. Meant for a signal handler that
/// exits right after: such an exit skips the destructors that would delete them. Targets are
/// never touched; an output of this process committed afterwards fails, since its temporary
/// file is gone.
pub fn remove_unfinished_outputs() -> usize {
    let list = unfinished();
    list.iter()
        .filter(|p| match std::fs::symlink_metadata(p) {
            Ok(m) if m.is_dir() => std::fs::remove_dir_all(p).is_ok(),
            _ => std::fs::remove_file(p).is_ok(),
        })
        .count()
}

/// The temporary files (`dirs`: directories) named `PREFIX*.tmp` in `dir` other than `mine`:
/// another run's of the same output, running now or killed (SIGKILL, a power cut) before it
/// could delete them; sorted.
fn other_runs_temporaries(
    dir: &Path,
    prefix: &str,
    mine: &Path,
    dirs: bool,
) -> std::io::Result<Vec<PathBuf>> {
    let mut found: Vec<PathBuf> = std::fs::read_dir(dir)?
        .filter_map(|entry| {
            let entry = entry.ok()?;
            let name = entry.file_name().into_string().ok()?;
            // PREFIX, tempfile's 6 random characters, `.tmp` (not another output's whose name
            // starts like this one's).
            let ours = name.starts_with(prefix)
                && name.ends_with(".tmp")
                && name.len() == prefix.len() + 6 + ".tmp".len();
            // By name: `tempdir_in` and `tempfile_in` make a relative directory absolute.
            let is_mine = Some(entry.file_name().as_os_str()) == mine.file_name();
            let kind = entry.file_type().ok()?;
            let kind_ok = if dirs { kind.is_dir() } else { kind.is_file() };
            (ours && !is_mine && kind_ok).then(|| entry.path())
        })
        .collect();
    found.sort();
    Ok(found)
}

/// Warns that `dir` holds `leftovers` (`one` / `many`: what they are) of another run of the
/// same output. Only reported: deleting a running one would break it.
fn warn_of_leftovers(dir: &Path, leftovers: &[PathBuf], one: &str, many: &str) {
    if leftovers.is_empty() {
        return;
    }
    let (what, them) = match leftovers.len() {
        1 => (one, "it"),
        _ => (many, "them"),
    };
    tracing::warn!(
        "{} holds {what} of another run of this output (running now, or killed before it could \
         clean up): {}; delete {them} when no run is using {them}",
        dir.display(),
        leftovers
            .iter()
            .map(|p| p.display().to_string())
            .collect::<Vec<_>>()
            .join(", "),
    );
}

/// A hidden directory (`.NAME.XXXXXX.tmp`) inside an output directory where a run that writes
/// several files puts them, so that a run that fails or is interrupted leaves the output
/// directory as it was, and a run that succeeds replaces the earlier run's files as a set
/// ([`StagingDir::publish`]): never a mix of two runs' outputs. Dropped unpublished (an error),
/// it is deleted with everything in it; it is listed for [`remove_unfinished_outputs`] while it
/// exists.
#[derive(Debug)]
pub struct StagingDir {
    dir: tempfile::TempDir,
    dest: PathBuf,
    leftovers: Vec<PathBuf>,
    _listed: Listed,
}

impl StagingDir {
    /// A new staging directory inside `dest` (created if missing). Refused when `dest`, or the
    /// directory its first missing part would be created in, is read-only
    /// ([`ensure_dir_writable`]).
    pub fn create(dest: impl AsRef<Path>) -> Result<Self> {
        let dest = dest.as_ref();
        create_dir_all_checked(dest)?;
        ensure_dir_writable(dest, None)?;
        let name = dest
            .file_name()
            .map_or("out".into(), |n| n.to_string_lossy().into_owned());
        let prefix = format!(".{}.", temp_stem(&name));
        let dir = tempfile::Builder::new()
            .prefix(&prefix)
            .suffix(".tmp")
            .tempdir_in(dest)
            .map_err(|e| Error::io(dest, e))?;
        let listed = Listed::new(dir.path());
        // Staging directories of other runs: one running now, or one killed (SIGKILL, a power
        // cut) before it could delete its own. Only reported: deleting a running one would
        // break it.
        let leftovers = other_runs_temporaries(dest, &prefix, dir.path(), true)
            .map_err(|e| Error::io(dest, e))?;
        warn_of_leftovers(
            dest,
            &leftovers,
            "a staging directory",
            "staging directories",
        );
        Ok(Self {
            dir,
            dest: dest.to_owned(),
            leftovers,
            _listed: listed,
        })
    }

    /// The staging directory: write the run's files here.
    pub fn path(&self) -> &Path {
        self.dir.path()
    }

    /// Other staging directories of the same output found when this one was created (another
    /// run's, running or killed; reported with a warning, never deleted).
    pub fn leftovers(&self) -> &[PathBuf] {
        &self.leftovers
    }

    /// Moves every file of the staging directory into the output directory (a rename each,
    /// replacing files of the same name), after deleting the output directory's files for which
    /// `is_stale(name)` holds and that this run did not write (an earlier run's outputs that
    /// this run does not produce: they would describe other data). Then removes the staging
    /// directory. Returns the published paths.
    pub fn publish(self, is_stale: impl Fn(&str) -> bool) -> Result<Vec<PathBuf>> {
        let read = |dir: &Path| -> Result<Vec<String>> {
            let mut names = Vec::new();
            for entry in std::fs::read_dir(dir).map_err(|e| Error::io(dir, e))? {
                let entry = entry.map_err(|e| Error::io(dir, e))?;
                let is_file = entry.file_type().map_err(|e| Error::io(dir, e))?.is_file();
                if let (true, Some(name)) = (is_file, entry.file_name().to_str()) {
                    names.push(name.to_owned());
                }
            }
            names.sort();
            Ok(names)
        };
        let new = read(self.path())?;
        for old in read(&self.dest)? {
            if is_stale(&old) && !new.contains(&old) {
                let p = self.dest.join(&old);
                std::fs::remove_file(&p).map_err(|e| Error::io(&p, e))?;
            }
        }
        let mut published = Vec::with_capacity(new.len());
        for name in new {
            let (from, to) = (self.path().join(&name), self.dest.join(&name));
            std::fs::rename(&from, &to).map_err(|e| Error::io(&to, e))?;
            published.push(to);
        }
        Ok(published)
    }
}

/// Installs the process's handler of SIGINT, SIGTERM and SIGHUP (for binaries; a library must
/// not call it): it calls [`remove_unfinished_outputs`], says so on stderr as `program`, and
/// exits with status 128 + the signal's number (130 for SIGINT, 143 for SIGTERM, 129 for
/// SIGHUP), as a shell reports a command the signal ended. Where there are no such signals
/// (not Unix) it handles Ctrl-C and exits with 130. Fails when it was installed already; a
/// run interrupted then leaves its temporary files behind.
pub fn remove_unfinished_outputs_on_signal(program: &'static str) -> Result<()> {
    static INSTALLED: std::sync::atomic::AtomicBool = std::sync::atomic::AtomicBool::new(false);
    let failed = |reason: String| Error::InvalidArgument {
        reason: format!(
            "cannot install the signal handler that cleans up interrupted outputs: {reason}"
        ),
    };
    if INSTALLED.swap(true, std::sync::atomic::Ordering::SeqCst) {
        return Err(failed("it is installed already".into()));
    }
    #[cfg(unix)]
    {
        use signal_hook::consts::{SIGHUP, SIGINT, SIGTERM};
        let mut signals = signal_hook::iterator::Signals::new([SIGINT, SIGTERM, SIGHUP])
            .map_err(|e| failed(e.to_string()))?;
        std::thread::Builder::new()
            .name("signals".into())
            .spawn(move || {
                if let Some(signal) = signals.forever().next() {
                    exit_interrupted(program, 128 + signal);
                }
            })
            .map_err(|e| failed(e.to_string()))?;
    }
    #[cfg(not(unix))]
    ctrlc::set_handler(move || exit_interrupted(program, 130))
        .map_err(|e| failed(e.to_string()))?;
    Ok(())
}

/// What the handler of [`remove_unfinished_outputs_on_signal`] does: removes the unfinished
/// outputs, says so as `program` and exits with `code`.
fn exit_interrupted(program: &str, code: i32) -> ! {
    let removed = remove_unfinished_outputs();
    // Best effort: a closed stderr must not keep the handler from exiting (`eprintln!` would
    // panic the handler's thread).
    let _ = writeln!(
        std::io::stderr(),
        "{program}: interrupted; removed {removed} unfinished output file(s)"
    );
    std::process::exit(code);
}

/// Writes `bytes` to `path` atomically (see the [module docs](self)).
pub fn write_file_atomic(path: impl AsRef<Path>, bytes: &[u8]) -> Result<()> {
    write_atomic_with(path, |w| w.write_all(bytes))
}

/// Writes `path` atomically with `body`, which gets a buffered writer (see the
/// [module docs](self)); an error from `body` leaves the target untouched.
pub fn write_atomic_with(
    path: impl AsRef<Path>,
    body: impl FnOnce(&mut dyn Write) -> std::io::Result<()>,
) -> Result<()> {
    let path = path.as_ref();
    let out = AtomicOutput::create(path)?;
    let mut w = std::io::BufWriter::new(out);
    body(&mut w).map_err(|e| Error::io(path, e))?;
    let out = w
        .into_inner()
        .map_err(|e| Error::io(path, e.into_error()))?;
    out.commit()
}

/// Test helpers shared by the writers' tests.
#[cfg(all(test, target_os = "linux"))]
pub(crate) mod test_util {
    use std::fs::File;
    use std::path::{Path, PathBuf};

    /// The current umask, read from /proc without changing it.
    pub(crate) fn umask() -> u32 {
        let status = std::fs::read_to_string("/proc/self/status").unwrap();
        let line = status.lines().find(|l| l.starts_with("Umask:")).unwrap();
        u32::from_str_radix(line["Umask:".len()..].trim(), 8).unwrap()
    }

    /// Permission bits of `p`.
    pub(crate) fn mode(p: &Path) -> u32 {
        use std::os::unix::fs::PermissionsExt;
        std::fs::metadata(p).unwrap().permissions().mode() & 0o777
    }

    /// A FIFO `dir/name` and a read+write handle on it (so opening it for writing does not block
    /// and small writes are buffered by the kernel until read).
    pub(crate) fn fifo(dir: &Path, name: &str) -> (PathBuf, File) {
        let p = dir.join(name);
        let status = std::process::Command::new("mkfifo")
            .arg(&p)
            .status()
            .unwrap();
        assert!(status.success());
        let f = std::fs::OpenOptions::new()
            .read(true)
            .write(true)
            .open(&p)
            .unwrap();
        (p, f)
    }

    /// True when `p` is (still) a FIFO.
    pub(crate) fn is_fifo(p: &Path) -> bool {
        use std::os::unix::fs::FileTypeExt;
        std::fs::symlink_metadata(p).unwrap().file_type().is_fifo()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[cfg(target_os = "linux")]
    use super::test_util::{fifo, is_fifo, mode, umask};
    use test_warnings::warnings_of;

    /// A staged run replaces the earlier run's files as a set, deletes its stale ones, keeps
    /// other files; an unpublished stage leaves the directory as it was.
    #[test]
    fn staged_runs_publish_together_or_not_at_all() {
        let dir = tempfile::tempdir().unwrap();
        let out = dir.path().join("out");
        let stale = |n: &str| n.ends_with(".npy") || n == "report.md";
        std::fs::create_dir_all(&out).unwrap();
        for (name, text) in [
            ("report.md", "old"),
            ("p-1.npy", "old"),
            ("p-2.npy", "old"),
            ("notes.txt", "mine"),
        ] {
            std::fs::write(out.join(name), text).unwrap();
        }
        // A failed run: nothing changes, nothing stays behind.
        let stage = StagingDir::create(&out).unwrap();
        std::fs::write(stage.path().join("report.md"), "failed").unwrap();
        assert!(unfinished_outputs().contains(&stage.path().to_owned()));
        let staged = stage.path().to_owned();
        drop(stage);
        assert!(!staged.exists() && !unfinished_outputs().contains(&staged));
        assert_eq!(
            names(&out),
            ["notes.txt", "p-1.npy", "p-2.npy", "report.md"]
        );
        // A run that writes one prediction: p-2.npy is stale, notes.txt is not the run's.
        let stage = StagingDir::create(&out).unwrap();
        std::fs::write(stage.path().join("report.md"), "new").unwrap();
        std::fs::write(stage.path().join("p-1.npy"), "new").unwrap();
        let published = stage.publish(stale).unwrap();
        assert_eq!(published, [out.join("p-1.npy"), out.join("report.md")]);
        assert_eq!(names(&out), ["notes.txt", "p-1.npy", "report.md"]);
        assert_eq!(
            std::fs::read_to_string(out.join("report.md")).unwrap(),
            "new"
        );
        assert_eq!(
            std::fs::read_to_string(out.join("notes.txt")).unwrap(),
            "mine"
        );
    }

    /// Another run's staging directory (a killed run's) is reported by the next run of the
    /// same output, and left alone; other hidden directories are not reported.
    #[test]
    fn staging_reports_other_runs_directories() {
        let dir = tempfile::tempdir().unwrap();
        let out = dir.path().join("out");
        let killed = StagingDir::create(&out).unwrap();
        assert!(killed.leftovers().is_empty());
        std::fs::write(killed.path().join("report.md"), "half").unwrap();
        // What SIGKILL leaves: the directory stays (no drop).
        let killed = killed.dir.keep();
        std::fs::create_dir(out.join(".other.abc.tmp")).unwrap();
        std::fs::write(out.join(".out.file.tmp"), "a file, not a run's directory").unwrap();
        let stage = StagingDir::create(&out).unwrap();
        assert_eq!(stage.leftovers(), std::slice::from_ref(&killed));
        drop(stage);
        assert_eq!(
            std::fs::read_to_string(killed.join("report.md")).unwrap(),
            "half"
        );
    }

    /// A killed run's temporary file of the same output is found (and reported by
    /// `AtomicOutput::create`); the new run's own, other outputs' and directories are not.
    #[test]
    fn other_runs_temporary_files_are_found() {
        let dir = tempfile::tempdir().unwrap();
        let d = dir.path();
        for name in [
            ".a.csv.AbCdEf.tmp",
            ".a.csv.x.AbCdEf.tmp",
            ".a.csv.AbCdEfGh.tmp",
        ] {
            std::fs::write(d.join(name), "x").unwrap();
        }
        std::fs::create_dir(d.join(".a.csv.Zz1234.tmp")).unwrap();
        let out = AtomicOutput::create(d.join("a.csv")).unwrap();
        let Inner::Temp { tmp, .. } = &out.inner else {
            panic!("a file output is written to a temporary file")
        };
        let found = other_runs_temporaries(d, ".a.csv.", tmp.path(), false).unwrap();
        assert_eq!(found, [d.join(".a.csv.AbCdEf.tmp")]);
        let dirs = other_runs_temporaries(d, ".a.csv.", tmp.path(), true).unwrap();
        assert_eq!(dirs, [d.join(".a.csv.Zz1234.tmp")]);
    }

    /// A run given a relative output directory does not report its own staging directory
    /// (it did: `tempdir_in` makes the path absolute, and the listing's paths stay relative).
    #[test]
    fn staging_in_a_relative_directory_is_not_its_own_leftover() {
        let dir = tempfile::tempdir().unwrap();
        // The same directory, relative to the working directory (no chdir: tests share it).
        let cwd = std::env::current_dir().unwrap();
        let up = cwd.components().count() - 1;
        let mut out: PathBuf = std::iter::repeat_n("..", up).collect();
        out.push(dir.path().strip_prefix("/").unwrap());
        out.push("out");
        assert!(out.is_relative(), "{}", out.display());
        let first = StagingDir::create(&out).unwrap();
        assert!(first.leftovers().is_empty(), "{:?}", first.leftovers());
        // The check still sees another run's directory.
        let second = StagingDir::create(&out).unwrap();
        assert_eq!(second.leftovers().len(), 1);
        assert_eq!(second.leftovers()[0].file_name(), first.path().file_name());
    }

    #[test]
    fn writes_bytes_and_leaves_no_temporary_file() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("a.csv");
        write_file_atomic(&p, b"x,y\n1,2\n").unwrap();
        assert_eq!(std::fs::read(&p).unwrap(), b"x,y\n1,2\n");
        write_file_atomic(&p, b"z\n").unwrap();
        assert_eq!(std::fs::read(&p).unwrap(), b"z\n");
        let names: Vec<_> = std::fs::read_dir(dir.path()).unwrap().collect();
        assert_eq!(names.len(), 1);
    }

    /// A name near the file system's 255-byte limit is writable: its temporary file's name
    /// repeats only part of it (it used to fail with "File name too long").
    #[test]
    fn long_names_are_writable() {
        let dir = tempfile::tempdir().unwrap();
        let name = format!("{}é.png", "a".repeat(247));
        assert_eq!(name.len(), 253);
        let p = dir.path().join(&name);
        write_file_atomic(&p, b"png").unwrap();
        assert_eq!(std::fs::read(&p).unwrap(), b"png");
        assert_eq!(temp_stem(&name).len(), 200);
        assert_eq!(temp_stem("a.npy"), "a.npy");
        // Byte 200 falls inside a two-byte character: the stem stops before it.
        let accents = format!("a{}", "é".repeat(150));
        assert_eq!(temp_stem(&accents).len(), 199);
        assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 1);
    }

    #[test]
    fn temporary_files_are_listed_until_committed_or_dropped() {
        let dir = tempfile::tempdir().unwrap();
        let listed = |out: &AtomicOutput| {
            let tmp = std::fs::read_dir(dir.path())
                .unwrap()
                .map(|e| e.unwrap().path())
                .find(|p| p.extension().is_some_and(|e| e == "tmp"))
                .unwrap();
            assert!(!out.is_direct());
            unfinished_outputs().contains(&tmp).then_some(tmp)
        };
        let mut out = AtomicOutput::create(dir.path().join("a.bin")).unwrap();
        out.write_all(b"x").unwrap();
        let tmp = listed(&out).expect("a new output's temporary file is listed");
        out.commit().unwrap();
        assert!(!unfinished_outputs().contains(&tmp));
        let out = AtomicOutput::create(dir.path().join("b.bin")).unwrap();
        let tmp = listed(&out).expect("listed");
        drop(out);
        assert!(!unfinished_outputs().contains(&tmp) && !tmp.exists());
    }

    #[test]
    fn failed_body_leaves_the_target_untouched() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("a.bin");
        std::fs::write(&p, b"old").unwrap();
        let e = write_atomic_with(&p, |w| {
            w.write_all(b"new")?;
            Err(std::io::Error::other("boom"))
        })
        .unwrap_err();
        assert!(e.to_string().contains("a.bin") && e.to_string().contains("boom"));
        assert_eq!(std::fs::read(&p).unwrap(), b"old");
        assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 1);
    }

    #[cfg(target_os = "linux")]
    #[test]
    fn new_files_get_the_umask_mode_and_replaced_files_keep_theirs() {
        use std::os::unix::fs::PermissionsExt;
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("new.npy");
        write_file_atomic(&p, b"1").unwrap();
        assert_eq!(mode(&p), 0o666 & !umask());
        std::fs::set_permissions(&p, std::fs::Permissions::from_mode(0o640)).unwrap();
        write_file_atomic(&p, b"2").unwrap();
        assert_eq!(mode(&p), 0o640);
    }

    /// A read-only file (`chmod a-w`) is not replaced, even by root (a rename over it used to
    /// succeed where `File::create` fails): the error names the path and says why, the file
    /// keeps its bytes and no temporary file is left; through a symbolic link as well.
    #[cfg(target_os = "linux")]
    #[test]
    fn read_only_files_are_not_replaced() {
        use std::os::unix::fs::PermissionsExt;
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("ref.sbrdf");
        let link = dir.path().join("link.sbrdf");
        std::fs::write(&p, b"precious").unwrap();
        std::os::unix::fs::symlink(&p, &link).unwrap();
        std::fs::set_permissions(&p, std::fs::Permissions::from_mode(0o444)).unwrap();
        for target in [&p, &link] {
            let e = write_file_atomic(target, b"new").unwrap_err();
            let Error::Io { path, error } = &e else {
                panic!("{e}")
            };
            assert_eq!(path, target);
            assert_eq!(error.kind(), std::io::ErrorKind::PermissionDenied);
            assert!(e.to_string().contains("read-only"), "{e}");
            assert_eq!(std::fs::read(&p).unwrap(), b"precious");
            assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 2);
        }
        // Writable again, it is replaced as usual (and keeps its mode).
        std::fs::set_permissions(&p, std::fs::Permissions::from_mode(0o644)).unwrap();
        write_file_atomic(&p, b"new").unwrap();
        assert_eq!(std::fs::read(&p).unwrap(), b"new");
        assert_eq!(mode(&p), 0o644);
    }

    /// Nothing is created in a directory whose mode bits say read-only, even by root (root
    /// created a pipeline's output directory inside one): no new or replaced file, no staging
    /// directory, no missing output directory; the error names the directory, and the
    /// directory is left as it was.
    #[cfg(unix)]
    #[test]
    fn read_only_directories_get_no_outputs() {
        use std::os::unix::fs::PermissionsExt;
        let dir = tempfile::tempdir().unwrap();
        let ro = dir.path().join("ro");
        std::fs::create_dir(&ro).unwrap();
        std::fs::write(ro.join("old.txt"), b"old").unwrap();
        std::fs::set_permissions(&ro, std::fs::Permissions::from_mode(0o555)).unwrap();
        let refused = |e: Error| {
            let msg = e.to_string();
            let Error::Io { path, error } = e else {
                panic!("{msg}")
            };
            assert_eq!(path, ro, "{msg}");
            assert_eq!(error.kind(), std::io::ErrorKind::PermissionDenied, "{msg}");
            assert!(msg.contains("the directory is read-only"), "{msg}");
            msg
        };
        let msg = refused(write_file_atomic(ro.join("new.txt"), b"new").unwrap_err());
        assert!(msg.contains("new.txt is not written there"), "{msg}");
        refused(write_file_atomic(ro.join("old.txt"), b"new").unwrap_err());
        refused(StagingDir::create(&ro).unwrap_err());
        refused(StagingDir::create(ro.join("out/deeper")).unwrap_err());
        refused(check_writable_dir(&ro).unwrap_err());
        let names: Vec<_> = std::fs::read_dir(&ro)
            .unwrap()
            .map(|e| e.unwrap().file_name())
            .collect();
        assert_eq!(names, ["old.txt"]);
        assert_eq!(std::fs::read(ro.join("old.txt")).unwrap(), b"old");
        // Writable again, outputs are created as usual.
        std::fs::set_permissions(&ro, std::fs::Permissions::from_mode(0o755)).unwrap();
        write_file_atomic(ro.join("old.txt"), b"new").unwrap();
        check_writable_dir(&ro).unwrap();
        let stage = StagingDir::create(ro.join("out/deeper")).unwrap();
        std::fs::write(stage.path().join("a.txt"), b"a").unwrap();
        stage.publish(|_| false).unwrap();
        assert_eq!(std::fs::read(ro.join("out/deeper/a.txt")).unwrap(), b"a");
    }

    #[cfg(unix)]
    #[test]
    fn symlink_to_a_regular_file_is_followed() {
        let dir = tempfile::tempdir().unwrap();
        let real = dir.path().join("real.txt");
        let link = dir.path().join("link.txt");
        std::fs::write(&real, b"old").unwrap();
        std::os::unix::fs::symlink(&real, &link).unwrap();
        write_file_atomic(&link, b"new").unwrap();
        assert!(
            std::fs::symlink_metadata(&link)
                .unwrap()
                .file_type()
                .is_symlink()
        );
        assert_eq!(std::fs::read(&real).unwrap(), b"new");
    }

    /// A FIFO target is written in place (not replaced by a regular file), and a seeking
    /// writer refuses it with an error naming the path.
    #[cfg(target_os = "linux")]
    #[test]
    fn fifo_is_written_in_place_and_refused_for_seeking_writers() {
        use std::io::Read;
        let dir = tempfile::tempdir().unwrap();
        let (p, mut reader) = fifo(dir.path(), "pipe");
        assert!(
            !is_fifo(dir.path()),
            "the check tells a FIFO from a directory"
        );
        write_file_atomic(&p, b"through the pipe").unwrap();
        assert!(is_fifo(&p));
        let mut got = [0u8; 16];
        reader.read_exact(&mut got).unwrap();
        assert_eq!(&got, b"through the pipe");
        let e = AtomicOutput::create_seekable(&p, "a dataset store").unwrap_err();
        assert!(matches!(e, Error::NotSeekable { .. }), "{e}");
        let msg = e.to_string();
        assert!(
            msg.contains("pipe") && msg.contains("a dataset store"),
            "{msg}"
        );
        assert!(msg.starts_with(&p.display().to_string()), "{msg}");
        assert!(is_fifo(&p));
    }

    /// `/dev/null` (a character device) is written in place: it stays a character device.
    #[cfg(unix)]
    #[test]
    fn character_device_is_written_in_place() {
        use std::os::unix::fs::FileTypeExt;
        let p = Path::new("/dev/null");
        let out = AtomicOutput::create_seekable(p, "a dataset store").unwrap();
        assert!(out.is_direct());
        // (Not committed when the check above fails: as root a rename would replace /dev/null.)
        out.commit().unwrap();
        assert!(std::fs::metadata(p).unwrap().file_type().is_char_device());
    }

    /// Bytes free for this user by `stat -f` (blocks available to non-root users times the
    /// fundamental block size): another code path than `statvfs` through rustix.
    #[cfg(target_os = "linux")]
    fn stat_available(dir: &Path) -> u64 {
        let out = std::process::Command::new("stat")
            .args(["-f", "-c", "%a %S"])
            .arg(dir)
            .output()
            .unwrap();
        assert!(out.status.success());
        let text = String::from_utf8(out.stdout).unwrap();
        let (blocks, size) = text.trim().split_once(' ').unwrap();
        blocks.parse::<u64>().unwrap() * size.parse::<u64>().unwrap()
    }

    /// Free space is what `stat -f` reports for the directory (within 5 %: other processes
    /// write to the same file system between the two readings; a wrong formula is off by
    /// orders of magnitude). `/proc` has none, so an output there is refused with an error
    /// naming the output, what it is and both sizes; standard output always passes, and so
    /// does an output that fits.
    #[cfg(target_os = "linux")]
    #[test]
    fn free_space_is_the_file_systems_and_outputs_beyond_it_are_refused() {
        let dir = tempfile::tempdir().unwrap();
        let want = stat_available(dir.path());
        let got = available_space(dir.path()).unwrap();
        assert!(want > 1 << 20, "test file system nearly full: {want}");
        assert!(got.abs_diff(want) <= want / 20, "{got} vs {want}");
        assert_eq!(available_space(Path::new("/proc")), Some(0));

        let e = ensure_space(Path::new("/proc/out.npy"), 5, "the table").unwrap_err();
        let Error::NoSpace {
            path,
            what,
            needed,
            available,
        } = &e
        else {
            panic!("{e}")
        };
        assert_eq!(
            (path.as_path(), what.as_str(), *needed, *available),
            (Path::new("/proc/out.npy"), "the table", 5, 0)
        );
        let out = dir.path().join("a.npy");
        ensure_space(&out, 1, "the table").unwrap();
        assert!(matches!(
            ensure_space(&out, u64::MAX, "the table"),
            Err(Error::NoSpace { .. })
        ));
        ensure_space(Path::new(STDOUT), u64::MAX, "the table").unwrap();
    }

    /// The length of an output is its file's; directories, missing files and special files
    /// have none.
    #[cfg(unix)]
    #[test]
    fn output_len_is_a_regular_files_length() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("a.csv");
        std::fs::write(&p, b"12345").unwrap();
        assert_eq!(output_len(&p), Some(5));
        assert_eq!(output_len(dir.path()), None);
        assert_eq!(output_len(&dir.path().join("missing")), None);
        assert_eq!(output_len(Path::new("/dev/null")), None);
    }

    /// Append mode is read from the open file's flags: a file opened to append is, one opened
    /// to write (or only to read) is not.
    #[cfg(target_os = "linux")]
    #[test]
    fn append_mode_is_read_from_the_descriptor() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("log.txt");
        std::fs::write(&p, b"x").unwrap();
        let open = |append: bool| {
            std::fs::OpenOptions::new()
                .write(true)
                .append(append)
                .open(&p)
                .unwrap()
        };
        assert!(is_append_mode(&open(true)));
        assert!(!is_append_mode(&open(false)));
        assert!(!is_append_mode(&File::open(&p).unwrap()));
    }

    /// An output writes, seeks and truncates its temporary file: `write` reports the bytes
    /// taken, a seek back overwrites, `set_len` cuts the file; the committed file holds the
    /// result. `path` is the path given; a regular file is a seekable, non-direct output.
    #[test]
    fn outputs_write_seek_and_set_their_length() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("a.bin");
        let mut out = AtomicOutput::create_seekable(&p, "a dataset store").unwrap();
        assert_eq!(out.path(), p);
        assert!(!out.is_direct());
        assert_eq!(out.write(b"abcdef").unwrap(), 6);
        assert_eq!(out.seek(SeekFrom::Start(1)).unwrap(), 1);
        out.write_all(b"XY").unwrap();
        assert_eq!(out.seek(SeekFrom::End(0)).unwrap(), 6);
        out.set_len(4).unwrap();
        out.flush().unwrap();
        assert_eq!(out.file().metadata().unwrap().len(), 4);
        out.commit().unwrap();
        assert_eq!(std::fs::read(&p).unwrap(), b"aXYd");
    }

    /// Special files are written in place and have no length to set (`set_len` on
    /// `/dev/null` passes); standard output (`-`) is written directly and named as such.
    #[cfg(unix)]
    #[test]
    fn special_outputs_are_direct_and_named() {
        let null = AtomicOutput::create(Path::new("/dev/null")).unwrap();
        assert!(null.is_direct());
        null.set_len(10).unwrap();
        assert_eq!(null.path(), Path::new("/dev/null"));
        let stdout = AtomicOutput::create(STDOUT).unwrap();
        assert!(stdout.is_direct());
        assert_eq!(stdout.path(), Path::new("<standard output>"));
        // Nothing written, so nothing to flush into the test's output.
        drop(stdout);
    }

    /// A directory that does not exist cannot take an output: the check fails naming it.
    #[test]
    fn missing_directories_are_not_writable() {
        let dir = tempfile::tempdir().unwrap();
        let missing = dir.path().join("missing");
        let e = check_writable_dir(&missing).unwrap_err();
        let Error::Io { path, error } = &e else {
            panic!("{e}")
        };
        assert_eq!(path, &missing);
        assert_eq!(error.kind(), std::io::ErrorKind::NotFound);
        check_writable_dir(dir.path()).unwrap();
    }

    /// The variable that makes a test binary run a child's part of a test (in a process of
    /// its own: what it does would disturb the other tests running in this one).
    #[cfg(target_os = "linux")]
    const CHILD_DIR: &str = "SPECGP_OUTPUT_TEST_CHILD_DIR";

    /// Runs this test binary's test `name` alone, as a child given `dir` (`setup` may change
    /// its working directory or standard output); its status and stderr.
    #[cfg(target_os = "linux")]
    fn run_child_with(
        name: &str,
        dir: &Path,
        setup: impl FnOnce(&mut std::process::Command),
    ) -> (Option<i32>, String) {
        let mut command = std::process::Command::new(std::env::current_exe().unwrap());
        command
            .args([name, "--exact", "--nocapture", "--test-threads=1"])
            .env(CHILD_DIR, dir);
        setup(&mut command);
        let out = command.output().unwrap();
        (
            out.status.code(),
            String::from_utf8_lossy(&out.stderr).into_owned(),
        )
    }

    /// [`run_child_with`] without changes.
    #[cfg(target_os = "linux")]
    fn run_child(name: &str, dir: &Path) -> (Option<i32>, String) {
        run_child_with(name, dir, |_| {})
    }

    /// The names of the entries of `dir`, sorted.
    fn names(dir: &Path) -> Vec<String> {
        let mut v: Vec<String> = std::fs::read_dir(dir)
            .unwrap()
            .map(|e| e.unwrap().file_name().into_string().unwrap())
            .collect();
        v.sort();
        v
    }

    /// `remove_unfinished_outputs` deletes every temporary file and staging directory (with
    /// its files) of the process and counts them; an output committed afterwards fails, a
    /// second call finds nothing left to delete, targets are untouched.
    #[cfg(target_os = "linux")]
    #[test]
    fn unfinished_outputs_are_removed_and_counted() {
        if let Some(dir) = std::env::var_os(CHILD_DIR) {
            let dir = PathBuf::from(dir);
            std::fs::write(dir.join("a.bin"), b"old").unwrap();
            let mut out = AtomicOutput::create(dir.join("a.bin")).unwrap();
            out.write_all(b"new").unwrap();
            let stage = StagingDir::create(dir.join("out")).unwrap();
            std::fs::write(stage.path().join("r.md"), b"r").unwrap();
            assert_eq!(remove_unfinished_outputs(), 2);
            assert!(out.commit().is_err());
            assert_eq!(remove_unfinished_outputs(), 0);
            drop(stage);
            return;
        }
        let dir = tempfile::tempdir().unwrap();
        let (code, stderr) = run_child(
            "output::tests::unfinished_outputs_are_removed_and_counted",
            dir.path(),
        );
        assert_eq!(code, Some(0), "{stderr}");
        assert_eq!(names(dir.path()), ["a.bin", "out"]);
        assert_eq!(std::fs::read(dir.path().join("a.bin")).unwrap(), b"old");
        assert!(names(&dir.path().join("out")).is_empty());
    }

    /// The signal handler installs once (a second install is an error saying so); on SIGTERM
    /// it removes the unfinished outputs, says how many as the program, and exits with
    /// 128 + 15 = 143, as a shell reports a command SIGTERM ended.
    #[cfg(target_os = "linux")]
    #[test]
    fn signals_remove_unfinished_outputs_and_exit_128_plus_the_signal() {
        if let Some(dir) = std::env::var_os(CHILD_DIR) {
            let dir = PathBuf::from(dir);
            remove_unfinished_outputs_on_signal("prog").unwrap();
            let e = remove_unfinished_outputs_on_signal("prog").unwrap_err();
            eprintln!("second install: {e}");
            let mut out = AtomicOutput::create(dir.join("a.bin")).unwrap();
            out.write_all(b"half").unwrap();
            signal_hook::low_level::raise(signal_hook::consts::SIGTERM).unwrap();
            // The handler's thread exits the process.
            std::thread::sleep(std::time::Duration::from_secs(30));
            unreachable!("SIGTERM did not end the process");
        }
        let dir = tempfile::tempdir().unwrap();
        let (code, stderr) = run_child(
            "output::tests::signals_remove_unfinished_outputs_and_exit_128_plus_the_signal",
            dir.path(),
        );
        assert_eq!(code, Some(143), "{stderr}");
        assert!(
            stderr.contains(
                "second install: invalid argument: cannot install the signal handler that \
                 cleans up interrupted outputs: it is installed already"
            ),
            "{stderr}"
        );
        assert!(
            stderr.contains("prog: interrupted; removed 1 unfinished output file(s)"),
            "{stderr}"
        );
        assert!(names(dir.path()).is_empty(), "{:?}", names(dir.path()));
    }

    /// Another run's temporary files of the same output are warned of, by path, as "a
    /// temporary file" / "it" for one and "temporary files" / "them" for several (listed with
    /// ", "); another run's staging directory likewise; nothing is said when there is none.
    #[test]
    fn other_runs_leftovers_are_warned_of() {
        let dir = tempfile::tempdir().unwrap();
        let d = dir.path();
        let (out, said) = warnings_of(|| AtomicOutput::create(d.join("a.csv")).unwrap());
        assert_eq!(said, "");
        drop(out);
        let one = d.join(".a.csv.AbCdEf.tmp");
        std::fs::write(&one, "x").unwrap();
        let (out, said) = warnings_of(|| AtomicOutput::create(d.join("a.csv")).unwrap());
        drop(out);
        let want = format!(
            "{} holds a temporary file of another run of this output (running now, or killed \
             before it could clean up): {}; delete it when no run is using it",
            d.display(),
            one.display()
        );
        assert!(said.contains(&want), "{said}");
        let two = d.join(".a.csv.GhIjKl.tmp");
        std::fs::write(&two, "x").unwrap();
        let (out, said) = warnings_of(|| AtomicOutput::create(d.join("a.csv")).unwrap());
        drop(out);
        let want = format!(
            "{} holds temporary files of another run of this output (running now, or killed \
             before it could clean up): {}, {}; delete them when no run is using them",
            d.display(),
            one.display(),
            two.display()
        );
        assert!(said.contains(&want), "{said}");

        let out_dir = d.join("out");
        let (first, said) = warnings_of(|| StagingDir::create(&out_dir).unwrap());
        assert_eq!(said, "");
        let (second, said) = warnings_of(|| StagingDir::create(&out_dir).unwrap());
        assert!(
            said.contains(&format!(
                "holds a staging directory of another run of this output (running now, or \
                 killed before it could clean up): {}; delete it",
                first.path().display()
            )),
            "{said}"
        );
        drop((first, second));
    }

    /// Relative outputs are created in the working directory, so a read-only one refuses
    /// them, naming `.`, as any other read-only directory (a file, a staging directory, a
    /// missing output directory), and is left empty.
    #[cfg(target_os = "linux")]
    #[test]
    fn relative_outputs_in_a_read_only_working_directory_are_refused() {
        use std::os::unix::fs::PermissionsExt;
        if let Some(dir) = std::env::var_os(CHILD_DIR) {
            assert_eq!(std::env::current_dir().unwrap(), Path::new(&dir));
            let refused = |e: Error| {
                let Error::Io { path, error } = &e else {
                    panic!("{e}")
                };
                assert_eq!(path, Path::new("."), "{e}");
                assert_eq!(error.kind(), std::io::ErrorKind::PermissionDenied, "{e}");
            };
            refused(write_file_atomic("a.csv", b"x").unwrap_err());
            refused(StagingDir::create("out").unwrap_err());
            refused(StagingDir::create("out/deeper").unwrap_err());
            return;
        }
        let dir = tempfile::tempdir().unwrap();
        let ro = dir.path().join("ro");
        std::fs::create_dir(&ro).unwrap();
        std::fs::set_permissions(&ro, std::fs::Permissions::from_mode(0o555)).unwrap();
        let (code, stderr) = run_child_with(
            "output::tests::relative_outputs_in_a_read_only_working_directory_are_refused",
            &ro,
            |c| {
                c.current_dir(&ro);
            },
        );
        assert_eq!(code, Some(0), "{stderr}");
        assert!(names(&ro).is_empty(), "{:?}", names(&ro));
    }

    /// An output path that is a symbolic link loop is an error naming it (its metadata cannot
    /// be read), and the link is not replaced by a regular file.
    #[cfg(unix)]
    #[test]
    fn symlink_loops_are_errors_and_stay_links() {
        let dir = tempfile::tempdir().unwrap();
        let link = dir.path().join("loop.csv");
        std::os::unix::fs::symlink(&link, &link).unwrap();
        let e = write_file_atomic(&link, b"x").unwrap_err();
        let Error::Io { path, .. } = &e else {
            panic!("{e}")
        };
        assert_eq!(path, &link);
        let meta = std::fs::symlink_metadata(&link).unwrap();
        assert!(meta.file_type().is_symlink());
        assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 1);
    }

    /// A seeking writer takes standard output only at offset 0 (`/dev/null`, whose offset
    /// stays 0), and refuses it, naming it, once something was written to it (a file
    /// truncated by `>`) or when it appends (`>>`).
    #[cfg(target_os = "linux")]
    #[test]
    fn seeking_writers_take_standard_output_only_at_its_start() {
        if std::env::var_os(CHILD_DIR).is_some() {
            println!("written first");
            std::io::stdout().flush().unwrap();
            match AtomicOutput::create_seekable(STDOUT, "a dataset store") {
                Ok(out) => eprintln!("seekable: ok, direct {}", out.is_direct()),
                Err(e) => eprintln!("seekable: {e}"),
            }
            return;
        }
        let dir = tempfile::tempdir().unwrap();
        let name = "output::tests::seeking_writers_take_standard_output_only_at_its_start";
        let refused = "seekable: <standard output>: cannot write a dataset store there";
        let file = |append: bool| {
            std::fs::OpenOptions::new()
                .create(true)
                .write(true)
                .append(append)
                .truncate(!append)
                .open(dir.path().join(if append { "b.out" } else { "a.out" }))
                .unwrap()
        };
        let (code, stderr) = run_child_with(name, dir.path(), |c| {
            c.stdout(File::create("/dev/null").unwrap());
        });
        assert_eq!(code, Some(0), "{stderr}");
        assert!(stderr.contains("seekable: ok, direct true"), "{stderr}");
        for append in [false, true] {
            let (code, stderr) = run_child_with(name, dir.path(), |c| {
                c.stdout(file(append));
            });
            assert_eq!(code, Some(0), "{stderr}");
            assert!(stderr.contains(refused), "append {append}: {stderr}");
        }
    }
}
