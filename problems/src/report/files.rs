//! Output folders and the files in them: column tables (CSV) behind the
//! figures, JSON, Markdown and the rendered figures.
//!
//! Every file goes through an [`OutputDir`], which makes a folder's results
//! all-or-nothing:
//! - [`OutputDir::open`] creates the folder and takes an exclusive lock on it
//!   (`.spark-lock`, an advisory `flock` held for the life of the value), so
//!   two runs never write into one folder at once; the second is refused
//!   with a message naming the lock and the process holding it. Callers open
//!   the folder before any computation, so an unwritable folder is reported
//!   at once.
//! - Each file is written to a hidden temporary name in the same folder
//!   (`.spark-tmp-…`, same extension) and flushed to disk; nothing under a
//!   final name changes while the files are written.
//! - [`OutputDir::commit`] renames the temporary files to their final names,
//!   in the order they were written (reports last), in one short burst.
//!   An interrupted run therefore leaves the previous complete results in
//!   place.
//!
//! Temporary files do not outlive the process that writes them:
//! - Every temporary file of the process, of an [`OutputDir`] or of
//!   [`replace_file`], is created, renamed and removed under one
//!   process-wide registry of the temporary files that exist.
//! - A binary's handler of SIGINT, SIGTERM and SIGHUP calls
//!   [`remove_temporary_files`], which removes every registered file and
//!   keeps the registry: no temporary file is created or renamed from then
//!   until the handler ends the process. A folder whose commit has begun is
//!   completed first (the commit holds the registry), so an interrupted run
//!   leaves the earlier results or the new ones, never a mix, and no
//!   temporary file. Figures are drawn in memory and written like any other
//!   file, so no drawing backend creates a file the registry does not know.
//! - A process killed outright (SIGKILL, a power cut) cannot remove its
//!   files: the next run that opens the folder removes them, under the
//!   folder's lock. A temporary file of [`replace_file`], which writes
//!   without the folder's lock, is held under an advisory `flock` by its
//!   writer from its creation to its rename or removal, and is removed by
//!   others (a later [`replace_file`] into its folder, a run opening the
//!   folder) only when they can take that lock: the lock ends with the
//!   writer however it ends, and it says so across PID namespaces
//!   (containers sharing a folder) and whatever process has taken the
//!   writer's process id since, which a process id in the name does not.
//! - A value dropped without a commit removes its temporary files.

use crate::report::plot::{render, render_scatter, Drawn, Figure, PlotError, Scatter};
use std::fs::{File, OpenOptions};
use std::io::{BufWriter, Read, Seek, SeekFrom, Write};
use std::os::unix::fs::OpenOptionsExt;
use std::path::{Path, PathBuf};
use std::sync::{Mutex, MutexGuard};

/// Name of the lock file inside an output folder.
pub const LOCK_FILE: &str = ".spark-lock";

/// Prefix of the temporary files inside an output folder.
pub const TEMP_PREFIX: &str = ".spark-tmp-";

/// Test-only hook: when this environment variable holds a number of
/// milliseconds, [`OutputDir`] sleeps that long after writing its first
/// temporary file, so that tests can interrupt a run in its write phase.
/// It is not a user setting and is not documented in `--help`.
pub const TEST_PAUSE_ENV: &str = "SPARK_TEST_PAUSE_AFTER_FIRST_FILE_MS";

/// The temporary files of this process that exist under their temporary
/// names. Creating, renaming and removing one happen while this is held.
static TEMPORARIES: Mutex<Vec<PathBuf>> = Mutex::new(Vec::new());

/// The registry of temporary files. A thread that panicked while holding
/// it left the list consistent (each operation updates it last), so a
/// poisoned lock is taken as is.
fn temporaries() -> MutexGuard<'static, Vec<PathBuf>> {
    TEMPORARIES.lock().unwrap_or_else(std::sync::PoisonError::into_inner)
}

/// Creates the temporary file `temp` (which must not exist) and registers it.
fn create_temporary(temp: &Path) -> Result<File, OutputError> {
    let mut live = temporaries();
    let file = OpenOptions::new().write(true).create_new(true).open(temp).map_err(io(temp))?;
    live.push(temp.to_path_buf());
    Ok(file)
}

/// Removes the temporary file `temp`, ignoring errors (it may be gone).
fn remove_temporary(temp: &Path) {
    let mut live = temporaries();
    let _ = std::fs::remove_file(temp);
    live.retain(|p| p != temp);
}

/// Renames the temporary file `temp` to `path` while `live` holds the
/// registry; on failure `temp` is removed.
fn rename_temporary(live: &mut Vec<PathBuf>, temp: &Path, path: &Path) -> std::io::Result<()> {
    let renamed = std::fs::rename(temp, path);
    if renamed.is_err() {
        let _ = std::fs::remove_file(temp);
    }
    live.retain(|p| p != temp);
    renamed
}

/// Removes every temporary file this process has created and not yet
/// renamed, and returns the registry, held: until it is dropped no
/// temporary file is created, renamed or removed by any thread. A folder
/// commit in progress is finished first. For a binary's signal handler,
/// which ends the process while holding the value:
///
/// ```no_run
/// let _held = problems::report::files::remove_temporary_files();
/// std::process::exit(130);
/// ```
pub fn remove_temporary_files() -> impl Sized {
    let mut live = temporaries();
    for temp in live.drain(..) {
        let _ = std::fs::remove_file(temp);
    }
    live
}

/// Errors while writing output files.
#[derive(Debug, thiserror::Error)]
pub enum OutputError {
    /// The output path exists and is not a folder (a file, a device).
    #[error("cannot write into {path}: it exists and is not a folder; give --out a folder (it is created if missing)")]
    NotAFolder {
        /// The path.
        path: PathBuf,
    },
    /// The output path is a symbolic link whose target does not exist.
    #[error(
        "cannot write into {path}: it is a symbolic link to {target}, which does not exist; create {target} or \
         give --out another folder"
    )]
    DanglingLink {
        /// The path.
        path: PathBuf,
        /// Where the link points.
        target: PathBuf,
    },
    /// The lock file's path is not a regular file: a symbolic link (which
    /// the lock would write through, into any file it names), a FIFO, a
    /// device.
    #[error(
        "cannot lock {path}: it is not a regular file (a symbolic link, a FIFO or a device), and spark writes its \
         lock only into a regular file of the output folder; remove it or give --out another folder"
    )]
    LockNotAFile {
        /// The lock file's path.
        path: PathBuf,
    },
    /// A file or directory could not be created or written.
    #[error("cannot write {path}: {source}")]
    Io {
        /// The path.
        path: PathBuf,
        /// The cause.
        source: std::io::Error,
    },
    /// CSV encoding failed.
    #[error("cannot write CSV {path}: {source}")]
    Csv {
        /// The path.
        path: PathBuf,
        /// The cause.
        source: csv::Error,
    },
    /// JSON encoding failed.
    #[error("cannot write JSON {path}: {source}")]
    Json {
        /// The path.
        path: PathBuf,
        /// The cause.
        source: serde_json::Error,
    },
    /// Another run holds the output folder's lock.
    #[error(
        "output folder {dir} is in use by another spark run ({holder}; lock file {lock}): wait for it to \
         finish or choose another --out"
    )]
    Locked {
        /// The output folder.
        dir: PathBuf,
        /// The lock file.
        lock: PathBuf,
        /// What the other run wrote into the lock file (process id and command line).
        holder: String,
    },
    /// A final name of the folder is held by a folder, which no file can
    /// replace; found before anything is renamed.
    #[error(
        "cannot write {path}: a folder of that name is in the way; move or remove it and run again (the folder's \
         earlier results are left as they were)"
    )]
    FolderInTheWay {
        /// The path.
        path: PathBuf,
    },
    /// A figure could not be drawn.
    #[error(transparent)]
    Plot(#[from] PlotError),
    /// Columns of a table differ in length.
    #[error("table {path}: column `{column}` has {got} rows, expected {expected}")]
    Ragged {
        /// The path.
        path: PathBuf,
        /// The offending column.
        column: String,
        /// Its length.
        got: usize,
        /// The first column's length.
        expected: usize,
    },
}

fn io(path: &Path) -> impl FnOnce(std::io::Error) -> OutputError + '_ {
    move |source| OutputError::Io { path: path.to_path_buf(), source }
}

/// Creates `dir` and its parents.
pub fn create_dir(dir: &Path) -> Result<(), OutputError> {
    if dir.exists() && !dir.is_dir() {
        return Err(OutputError::NotAFolder { path: dir.to_path_buf() });
    }
    // `create_dir_all` on a link to nowhere fails with a bare "File exists".
    if !dir.exists() {
        if let Ok(target) = std::fs::read_link(dir) {
            return Err(OutputError::DanglingLink { path: dir.to_path_buf(), target });
        }
    }
    std::fs::create_dir_all(dir).map_err(io(dir))
}

/// An output folder held exclusively by this process; see the module
/// documentation for the guarantees.
#[derive(Debug)]
pub struct OutputDir {
    dir: PathBuf,
    /// Keeps the `flock` (released when the file is closed, also when the
    /// process is killed).
    _lock: File,
    /// `(temporary, final)` paths written and not yet renamed, in order.
    staged: Vec<(PathBuf, PathBuf)>,
    /// Files of an earlier run removed at [`OutputDir::commit`].
    stale: Vec<PathBuf>,
    /// Test hook ([`TEST_PAUSE_ENV`]): pause after the first staged file.
    pause: Option<std::time::Duration>,
}

impl OutputDir {
    /// Creates `dir` (and its parents), takes its lock and removes temporary
    /// files that an interrupted run left behind.
    pub fn open(dir: &Path) -> Result<OutputDir, OutputError> {
        create_dir(dir)?;
        let lock_path = dir.join(LOCK_FILE);
        // Not through a symbolic link (the lock's note would overwrite the
        // file it names) and without waiting on a FIFO; a path that is not a
        // regular file is refused below.
        let not_a_file = || OutputError::LockNotAFile { path: lock_path.clone() };
        let mut lock = OpenOptions::new()
            .read(true)
            .write(true)
            .create(true)
            .truncate(false)
            .custom_flags(libc::O_NOFOLLOW | libc::O_NONBLOCK)
            .open(&lock_path)
            .map_err(|e| if e.raw_os_error() == Some(libc::ELOOP) { not_a_file() } else { io(&lock_path)(e) })?;
        if !lock.metadata().map_err(io(&lock_path))?.is_file() {
            return Err(not_a_file());
        }
        if !try_lock_exclusive(&lock).map_err(io(&lock_path))? {
            let mut holder = String::new();
            let _ = lock.read_to_string(&mut holder);
            let holder = holder.trim();
            let holder = if holder.is_empty() { "process unknown".to_string() } else { holder.to_string() };
            return Err(OutputError::Locked { dir: dir.to_path_buf(), lock: lock_path, holder });
        }
        // `args()` panics on an argument that is not UTF-8 (an `--out` path
        // such as `/tmp/\xff`); the note is for people, a lossy form will do.
        let command: Vec<String> = std::env::args_os().map(|a| a.to_string_lossy().into_owned()).collect();
        let note = format!("pid {}: {}", std::process::id(), command.join(" "));
        lock.set_len(0)
            .and_then(|()| lock.seek(SeekFrom::Start(0)))
            .and_then(|_| lock.write_all(note.as_bytes()))
            .map_err(io(&lock_path))?;
        // The lock is ours, so any temporary file of a folder here belongs
        // to a run that ended without committing; one of [`replace_file`]
        // may be a live writer's, which holds its lock.
        let entries = std::fs::read_dir(dir).map_err(io(dir))?;
        for entry in entries.flatten() {
            let name = entry.file_name();
            let name = name.to_string_lossy();
            if is_single_temporary(&name) {
                remove_if_unlocked(&entry.path());
            } else if name.starts_with(TEMP_PREFIX) {
                let _ = std::fs::remove_file(entry.path());
            }
        }
        let pause = std::env::var(TEST_PAUSE_ENV)
            .ok()
            .and_then(|v| v.trim().parse::<u64>().ok())
            .map(std::time::Duration::from_millis);
        Ok(OutputDir { dir: dir.to_path_buf(), _lock: lock, staged: Vec::new(), stale: Vec::new(), pause })
    }

    /// The folder.
    pub fn path(&self) -> &Path {
        &self.dir
    }

    /// The final path of the file `name` in this folder.
    pub fn join(&self, name: impl AsRef<Path>) -> PathBuf {
        self.dir.join(name)
    }

    /// A fresh temporary path for the file `name`, with the same extension
    /// (plotters picks the image format from it).
    fn temp_path(&self, name: &str) -> PathBuf {
        let seq = self.staged.len();
        self.dir.join(format!("{TEMP_PREFIX}{}-{seq}-{name}", std::process::id()))
    }

    /// Records a written temporary file; runs the test pause after the first.
    fn staged(&mut self, temp: PathBuf, name: &str) -> PathBuf {
        let path = self.dir.join(name);
        self.staged.push((temp, path.clone()));
        if self.staged.len() == 1 {
            if let Some(pause) = self.pause {
                std::thread::sleep(pause);
            }
        }
        path
    }

    /// Writes the file `name` through `write` into a temporary file and
    /// stages it; returns the final path (written at [`OutputDir::commit`]).
    pub fn write_with<E>(
        &mut self,
        name: &str,
        write: impl FnOnce(&mut dyn Write) -> Result<(), E>,
    ) -> Result<PathBuf, OutputError>
    where
        E: Into<WriteFailure>,
    {
        let temp = self.temp_path(name);
        let file = create_temporary(&temp)?;
        let result = (|| {
            let mut w = BufWriter::new(file);
            write(&mut w).map_err(|e| e.into().into_output(&self.dir.join(name)))?;
            let file = w.into_inner().map_err(|e| e.into_error()).map_err(io(&temp))?;
            file.sync_all().map_err(io(&temp))
        })();
        if let Err(e) = result {
            remove_temporary(&temp);
            return Err(e);
        }
        Ok(self.staged(temp, name))
    }

    /// Stages `bytes` as the file `name`.
    pub fn write_bytes(&mut self, name: &str, bytes: &[u8]) -> Result<PathBuf, OutputError> {
        self.write_with(name, |w| w.write_all(bytes))
    }

    /// Stages `value` as pretty JSON in the file `name`.
    pub fn write_json<T: serde::Serialize + ?Sized>(&mut self, name: &str, value: &T) -> Result<PathBuf, OutputError> {
        self.write_with(name, |w| serde_json::to_writer_pretty(w, value))
    }

    /// Stages named columns of equal length as the CSV file `name` (see
    /// [`write_columns`]).
    pub fn write_columns(&mut self, name: &str, columns: &[(&str, &[f64])]) -> Result<PathBuf, OutputError> {
        let path = self.dir.join(name);
        check_columns(&path, columns)?;
        self.write_with(name, |w| write_columns_to(w, columns))
    }

    /// Stages `fig` as `<stem>.png` and `<stem>.svg`; returns both final paths.
    pub fn render(&mut self, fig: &Figure, stem: &str) -> Result<Vec<PathBuf>, OutputError> {
        let (png, svg) = (format!("{stem}.png"), format!("{stem}.svg"));
        let drawn = render(fig, &self.join(&png), &self.join(&svg))?;
        self.stage_drawn(&drawn, &png, &svg)
    }

    /// Stages the scatter plot `fig` as `<stem>.png` and `<stem>.svg`;
    /// returns both final paths.
    pub fn render_scatter(&mut self, fig: &Scatter, stem: &str) -> Result<Vec<PathBuf>, OutputError> {
        let (png, svg) = (format!("{stem}.png"), format!("{stem}.svg"));
        let drawn = render_scatter(fig, &self.join(&png), &self.join(&svg))?;
        self.stage_drawn(&drawn, &png, &svg)
    }

    /// Stages a figure drawn in memory as the files `png` and `svg`.
    fn stage_drawn(&mut self, drawn: &Drawn, png: &str, svg: &str) -> Result<Vec<PathBuf>, OutputError> {
        Ok(vec![self.write_bytes(png, &drawn.png)?, self.write_bytes(svg, &drawn.svg)?])
    }

    /// Marks the file `name` for removal at [`OutputDir::commit`]: a file an
    /// earlier run wrote and this one does not rewrite, which would
    /// otherwise sit beside this run's reports and describe another run.
    pub fn remove_stale(&mut self, name: &str) {
        self.stale.push(self.dir.join(name));
    }

    /// Removes the files marked by [`OutputDir::remove_stale`], then renames
    /// every staged file to its final name, in the order staged, and returns
    /// the final paths. Files staged later (the reports) appear last.
    pub fn commit(mut self) -> Result<Vec<PathBuf>, OutputError> {
        // A rename onto a folder fails, and the files renamed before it
        // would sit beside the earlier run's reports: every final name is
        // checked first, so that the folder changes completely or not at all.
        let finals = self.staged.iter().map(|(_, path)| path).chain(self.stale.iter());
        if let Some(path) = finals.into_iter().find(|p| p.symlink_metadata().is_ok_and(|m| m.is_dir())) {
            return Err(OutputError::FolderInTheWay { path: path.clone() });
        }
        // Held over the removals and renames: a signal handler's
        // [`remove_temporary_files`] waits until the folder is complete.
        let mut live = temporaries();
        for path in std::mem::take(&mut self.stale) {
            match std::fs::remove_file(&path) {
                Err(e) if e.kind() != std::io::ErrorKind::NotFound => {
                    return Err(OutputError::Io { path, source: e });
                }
                _ => {}
            }
        }
        let staged = std::mem::take(&mut self.staged);
        let mut done = Vec::with_capacity(staged.len());
        let mut pending = staged.into_iter();
        for (temp, path) in pending.by_ref() {
            if let Err(source) = rename_temporary(&mut live, &temp, &path) {
                for (t, _) in pending {
                    let _ = std::fs::remove_file(&t);
                    live.retain(|p| *p != t);
                }
                return Err(OutputError::Io { path, source });
            }
            done.push(path);
        }
        drop(live);
        // Make the renames durable (best effort: not every file system
        // supports syncing a directory).
        if let Ok(d) = File::open(&self.dir) {
            let _ = d.sync_all();
        }
        Ok(done)
    }
}

impl Drop for OutputDir {
    /// Removes the temporary files of an uncommitted folder.
    fn drop(&mut self) {
        for (temp, _) in &self.staged {
            remove_temporary(temp);
        }
    }
}

/// Takes an exclusive advisory lock on `file`, waiting for another holder
/// (a cleanup that holds it for a moment) to release it.
fn lock_exclusive(file: &File) -> std::io::Result<()> {
    use std::os::unix::io::AsRawFd;
    loop {
        // SAFETY: `flock` only reads the descriptor number, which `file` keeps open.
        if unsafe { libc::flock(file.as_raw_fd(), libc::LOCK_EX) } == 0 {
            return Ok(());
        }
        let e = std::io::Error::last_os_error();
        if e.kind() != std::io::ErrorKind::Interrupted {
            return Err(e);
        }
    }
}

/// Takes an exclusive advisory lock on `file` without waiting; `false` when
/// another open file description holds it.
fn try_lock_exclusive(file: &File) -> std::io::Result<bool> {
    use std::os::unix::io::AsRawFd;
    // SAFETY: `flock` only reads the descriptor number, which `file` keeps open.
    let rc = unsafe { libc::flock(file.as_raw_fd(), libc::LOCK_EX | libc::LOCK_NB) };
    if rc == 0 {
        return Ok(true);
    }
    let e = std::io::Error::last_os_error();
    if e.raw_os_error() == Some(libc::EWOULDBLOCK) {
        Ok(false)
    } else {
        Err(e)
    }
}

/// What a file-writing closure of [`OutputDir::write_with`] may fail with.
#[derive(Debug)]
pub enum WriteFailure {
    /// An I/O error.
    Io(std::io::Error),
    /// A CSV encoding error.
    Csv(csv::Error),
    /// A JSON encoding error.
    Json(serde_json::Error),
}

impl WriteFailure {
    fn into_output(self, path: &Path) -> OutputError {
        let path = path.to_path_buf();
        match self {
            WriteFailure::Io(source) => OutputError::Io { path, source },
            WriteFailure::Csv(source) => OutputError::Csv { path, source },
            WriteFailure::Json(source) => OutputError::Json { path, source },
        }
    }
}

impl From<std::io::Error> for WriteFailure {
    fn from(e: std::io::Error) -> Self {
        WriteFailure::Io(e)
    }
}

impl From<csv::Error> for WriteFailure {
    fn from(e: csv::Error) -> Self {
        WriteFailure::Csv(e)
    }
}

impl From<serde_json::Error> for WriteFailure {
    fn from(e: serde_json::Error) -> Self {
        WriteFailure::Json(e)
    }
}

fn check_columns(path: &Path, columns: &[(&str, &[f64])]) -> Result<(), OutputError> {
    let rows = columns.first().map_or(0, |c| c.1.len());
    for (name, col) in columns {
        if col.len() != rows {
            return Err(OutputError::Ragged {
                path: path.into(),
                column: name.to_string(),
                got: col.len(),
                expected: rows,
            });
        }
    }
    Ok(())
}

fn write_columns_to(w: &mut dyn Write, columns: &[(&str, &[f64])]) -> Result<(), csv::Error> {
    let rows = columns.first().map_or(0, |c| c.1.len());
    let mut w = csv::Writer::from_writer(w);
    w.write_record(columns.iter().map(|c| c.0))?;
    for r in 0..rows {
        w.write_record(columns.iter().map(|c| format!("{:?}", c.1[r])))?;
    }
    w.flush()?;
    Ok(())
}

/// Writes named columns of equal length as CSV (numbers in shortest
/// round-trip form, so reading them back gives the same `f64`), replacing
/// `path` atomically. Holds no folder lock: inside a command, use
/// [`OutputDir::write_columns`].
pub fn write_columns(path: &Path, columns: &[(&str, &[f64])]) -> Result<(), OutputError> {
    check_columns(path, columns)?;
    replace_file(path, |w| write_columns_to(w, columns))
}

/// Writes the file `path` through `write` into a temporary file in its
/// folder, syncs it and renames it to `path`: a reader of `path` (or of a
/// link to the file it was) sees the earlier file or the whole new one,
/// never a part; a failed or interrupted write leaves the earlier file as
/// it was and no temporary file (see the module documentation; the
/// temporary files of writers killed outright, `.spark-tmp-…-single-…`
/// whose lock nobody holds, are removed from the folder here).
/// Holds no folder lock: inside a command, use [`OutputDir::write_with`].
pub fn replace_file<E>(path: &Path, write: impl FnOnce(&mut dyn Write) -> Result<(), E>) -> Result<(), OutputError>
where
    E: Into<WriteFailure>,
{
    let dir = path.parent().filter(|d| !d.as_os_str().is_empty()).unwrap_or(Path::new("."));
    let name = path.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
    remove_orphaned_temporaries(dir);
    // Open, and so locked, until the file is renamed or removed.
    let (temp, file) = create_locked_temporary(dir, &name)?;
    let result = (|| {
        let mut w = BufWriter::new(&file);
        write(&mut w).map_err(|e| e.into().into_output(path))?;
        w.into_inner().map_err(|e| e.into_error()).map_err(io(&temp))?;
        file.sync_all().map_err(io(&temp))
    })();
    let result = match result {
        Ok(()) => rename_temporary(&mut temporaries(), &temp, path).map_err(io(path)),
        Err(e) => {
            remove_temporary(&temp);
            Err(e)
        }
    };
    drop(file);
    result
}

/// Marks the temporary files of [`replace_file`], which carry their
/// writer's lock, among those of a folder, which do not.
const SINGLE: &str = "single-";

/// Whether `name` is a temporary file of [`replace_file`]
/// (`.spark-tmp-PID-single-…`).
fn is_single_temporary(name: &str) -> bool {
    name.strip_prefix(TEMP_PREFIX)
        .and_then(|rest| rest.split_once('-'))
        .is_some_and(|(_, rest)| rest.starts_with(SINGLE))
}

/// Most attempts at a temporary file of [`replace_file`]: a name can be
/// taken (a process of the same id in another PID namespace writing into
/// the same folder) or the file removed by another process's cleanup
/// before its writer locks it; each attempt takes a fresh name.
const CREATE_ATTEMPTS: usize = 64;

/// Creates and registers a temporary file for `name` in `dir` and takes its
/// exclusive lock, which the returned file keeps. Another process's
/// cleanup may take the lock in the moment between creation and locking
/// and remove the file: the file is then no longer under its name, and a
/// fresh one is made.
fn create_locked_temporary(dir: &Path, name: &str) -> Result<(PathBuf, File), OutputError> {
    // Numbered, so that threads replacing one file at once each have their own.
    static SEQUENCE: std::sync::atomic::AtomicU64 = std::sync::atomic::AtomicU64::new(0);
    let mut attempt = 0;
    loop {
        attempt += 1;
        let seq = SEQUENCE.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
        let temp = dir.join(format!("{TEMP_PREFIX}{}-{SINGLE}{seq}-{name}", std::process::id()));
        let file = match create_temporary(&temp) {
            Err(OutputError::Io { source, .. })
                if source.kind() == std::io::ErrorKind::AlreadyExists && attempt < CREATE_ATTEMPTS =>
            {
                continue;
            }
            created => created?,
        };
        lock_exclusive(&file).map_err(|e| {
            remove_temporary(&temp);
            io(&temp)(e)
        })?;
        if same_file(&file, &temp) {
            return Ok((temp, file));
        }
        // Removed by another process; the name is no longer this file's.
        temporaries().retain(|p| *p != temp);
        if attempt >= CREATE_ATTEMPTS {
            return Err(OutputError::Io {
                path: temp,
                source: std::io::Error::other("the temporary file was removed by another process as it was created"),
            });
        }
    }
}

/// Whether `path` names the file `file` has open (same device and inode).
fn same_file(file: &File, path: &Path) -> bool {
    use std::os::unix::fs::MetadataExt;
    match (file.metadata(), path.symlink_metadata()) {
        (Ok(a), Ok(b)) => a.dev() == b.dev() && a.ino() == b.ino(),
        _ => false,
    }
}

/// Removes from `dir` the temporary files of [`replace_file`] whose writers
/// have ended (see [`remove_if_unlocked`]), ignoring errors. Those of a
/// folder, which an [`OutputDir`] holds under the folder's lock, are left to
/// the next [`OutputDir::open`] of the folder.
fn remove_orphaned_temporaries(dir: &Path) {
    let Ok(entries) = std::fs::read_dir(dir) else { return };
    for entry in entries.flatten() {
        if entry.file_name().to_str().is_some_and(is_single_temporary) {
            remove_if_unlocked(&entry.path());
        }
    }
}

/// Removes the temporary file `path` of [`replace_file`] when its lock can
/// be taken: its writer holds the lock from before the file has content to
/// after it is renamed or removed, so a free lock means the writer has
/// ended (or is about to lock it, and then makes a fresh file). Anything
/// that cannot be opened or locked (another user's file, a file system
/// without `flock`) is left as it is.
fn remove_if_unlocked(path: &Path) {
    // Not through a symbolic link and without waiting on a FIFO.
    let Ok(file) = OpenOptions::new().read(true).custom_flags(libc::O_NOFOLLOW | libc::O_NONBLOCK).open(path) else {
        return;
    };
    if !file.metadata().is_ok_and(|m| m.is_file()) {
        return;
    }
    // The writer may have renamed the file (and released the lock) since it
    // was listed: only the file still under the temporary name goes.
    if try_lock_exclusive(&file).unwrap_or(false) && same_file(&file, path) {
        let _ = std::fs::remove_file(path);
    }
}

/// Reads a CSV written by [`write_columns`] back as `(header, columns)`.
pub fn read_columns(path: &Path) -> Result<(Vec<String>, Vec<Vec<f64>>), OutputError> {
    let csv_err = |source| OutputError::Csv { path: path.to_path_buf(), source };
    let mut r = csv::Reader::from_path(path).map_err(csv_err)?;
    let header: Vec<String> = r.headers().map_err(csv_err)?.iter().map(str::to_string).collect();
    let mut cols = vec![Vec::new(); header.len()];
    for rec in r.records() {
        let rec = rec.map_err(csv_err)?;
        for (c, field) in cols.iter_mut().zip(rec.iter()) {
            c.push(field.trim().parse::<f64>().unwrap_or(f64::NAN));
        }
    }
    Ok((header, cols))
}
