//! The output folder ([`OutputDir`]): one writer at a time, files visible
//! only after the commit, leftovers of killed runs cleaned; and the
//! decimation that bounds the size of figures.

use problems::report::files::{OutputDir, OutputError, LOCK_FILE, TEMP_PREFIX};
use problems::report::plot::{decimate, Scale};
use std::path::Path;

fn visible_files(dir: &Path) -> Vec<String> {
    let mut names: Vec<String> = std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .filter(|n| n != LOCK_FILE)
        .collect();
    names.sort();
    names
}

#[test]
fn a_folder_has_one_writer_and_files_appear_only_at_commit() {
    let dir = std::env::temp_dir().join(format!("spark-out-lock-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    let mut out = OutputDir::open(&dir).unwrap();
    // A second opener (another open file description, as another process
    // would have) is refused with the lock file and this process named.
    match OutputDir::open(&dir) {
        Err(OutputError::Locked { lock, holder, .. }) => {
            assert_eq!(lock, dir.join(LOCK_FILE));
            assert!(holder.contains(&format!("pid {}", std::process::id())), "{holder}");
        }
        other => panic!("second open must be refused, got {other:?}"),
    }
    out.write_bytes("report.md", b"first").unwrap();
    out.write_columns("a.csv", &[("x", &[1.0, 2.0])]).unwrap();
    // Staged files exist only under temporary names.
    assert!(visible_files(&dir).iter().all(|n| n.starts_with(TEMP_PREFIX)), "{:?}", visible_files(&dir));
    let files = out.commit().unwrap();
    assert_eq!(files, vec![dir.join("report.md"), dir.join("a.csv")]);
    assert_eq!(visible_files(&dir), vec!["a.csv", "report.md"]);
    // Dropping an uncommitted folder removes its temporary files and
    // leaves the committed ones untouched; the lock is free again.
    let mut out = OutputDir::open(&dir).unwrap();
    out.write_bytes("report.md", b"second").unwrap();
    drop(out);
    assert_eq!(visible_files(&dir), vec!["a.csv", "report.md"]);
    assert_eq!(std::fs::read(dir.join("report.md")).unwrap(), b"first");
    // A temporary file left by a killed run is removed by the next open.
    std::fs::write(dir.join(format!("{TEMP_PREFIX}1-0-a.csv")), b"x,\n1").unwrap();
    let out = OutputDir::open(&dir).unwrap();
    assert_eq!(visible_files(&dir), vec!["a.csv", "report.md"]);
    drop(out);
    std::fs::remove_dir_all(&dir).unwrap();
}

/// A lock path that is not a regular file is refused and left as it is: a
/// symbolic link (the lock's note would overwrite the file it names,
/// anywhere), a FIFO (opening it could wait), a folder.
#[test]
fn a_lock_path_that_is_not_a_regular_file_is_refused_untouched() {
    let root = std::env::temp_dir().join(format!("spark-out-lock-kinds-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&root);
    let (dir, target) = (root.join("out"), root.join("precious.txt"));
    std::fs::create_dir_all(&dir).unwrap();
    std::fs::write(&target, b"keep me").unwrap();
    std::os::unix::fs::symlink(&target, dir.join(LOCK_FILE)).unwrap();
    let refused = |what: &str| match OutputDir::open(&dir) {
        Err(e @ OutputError::LockNotAFile { .. }) => assert!(e.to_string().contains("not a regular file"), "{e}"),
        other => panic!("{what}: the lock must be refused, got {other:?}"),
    };
    refused("a symbolic link to a file");
    assert_eq!(std::fs::read(&target).unwrap(), b"keep me");
    std::fs::remove_file(dir.join(LOCK_FILE)).unwrap();
    std::os::unix::fs::symlink(root.join("missing"), dir.join(LOCK_FILE)).unwrap();
    refused("a dangling symbolic link");
    assert!(!root.join("missing").exists(), "the link's target must not be created");
    std::fs::remove_file(dir.join(LOCK_FILE)).unwrap();
    let fifo = std::ffi::CString::new(dir.join(LOCK_FILE).into_os_string().into_encoded_bytes()).unwrap();
    // SAFETY: a valid NUL-terminated path.
    assert_eq!(unsafe { libc::mkfifo(fifo.as_ptr(), 0o600) }, 0);
    refused("a FIFO");
    std::fs::remove_file(dir.join(LOCK_FILE)).unwrap();
    // A regular lock file works again.
    drop(OutputDir::open(&dir).unwrap());
    std::fs::remove_dir_all(&root).unwrap();
}

#[test]
fn an_unwritable_folder_fails_at_open() {
    let err = OutputDir::open(Path::new("/proc/spark-cannot-exist/out")).unwrap_err();
    assert!(err.to_string().contains("/proc/spark-cannot-exist"), "{err}");
}
#[test]
fn decimation_keeps_the_envelope_of_a_million_points() {
    // A fast oscillation with a slow drift and one isolated spike: the
    // thinned curve must keep every bucket's extremes, hence the spike
    // and the global extremes, in at most 2·columns + 2 points.
    let n = 1_000_000;
    let pts: Vec<(f64, f64)> = (0..n)
        .map(|k| {
            let t = k as f64 * 1e-3;
            let spike = if k == 777_777 { 50.0 } else { 0.0 };
            (t, (t * 40.0).sin() + 1e-3 * t + spike)
        })
        .collect();
    let columns = 700;
    let thin = decimate(&pts, columns, Scale::Linear);
    assert!(thin.len() <= 2 * columns + 2, "{} points", thin.len());
    assert_eq!(thin.first(), pts.first());
    assert_eq!(thin.last(), pts.last());
    assert!(thin.contains(&pts[777_777]), "the spike is lost");
    let max = |p: &[(f64, f64)]| p.iter().map(|q| q.1).fold(f64::NEG_INFINITY, f64::max);
    let min = |p: &[(f64, f64)]| p.iter().map(|q| q.1).fold(f64::INFINITY, f64::min);
    assert_eq!(max(&thin), max(&pts));
    assert_eq!(min(&thin), min(&pts));
    // Every bucket of the full curve has its min and max in the thinned one.
    let width = pts[n - 1].0 / columns as f64;
    for b in (0..columns).step_by(37) {
        let inside = |p: &&(f64, f64)| ((p.0 / width) as usize).min(columns - 1) == b;
        let full: Vec<_> = pts.iter().filter(inside).copied().collect();
        let kept: Vec<_> = thin.iter().filter(inside).copied().collect();
        assert_eq!(max(&kept), max(&full), "bucket {b}");
        assert_eq!(min(&kept), min(&full), "bucket {b}");
    }
    // Points stay in drawing order.
    assert!(thin.windows(2).all(|w| w[1].0 >= w[0].0));
    // Short curves and non-monotone curves (by runs of points) are bounded too.
    assert_eq!(decimate(&pts[..1000], columns, Scale::Linear), pts[..1000].to_vec());
    let circle: Vec<(f64, f64)> = (0..100_000).map(|k| ((k as f64 * 1e-3).cos(), (k as f64 * 1e-3).sin())).collect();
    assert!(decimate(&circle, columns, Scale::Linear).len() <= 2 * columns + 2);
}

/// Holds an exclusive `flock` on `path` (creating it) for the life of the
/// file, as the writer of a temporary file of `replace_file` does.
fn hold_lock(path: &Path) -> std::fs::File {
    use std::os::unix::io::AsRawFd;
    let file = std::fs::OpenOptions::new().create(true).truncate(false).write(true).open(path).unwrap();
    // SAFETY: `flock` only reads the descriptor number, which `file` keeps open.
    assert_eq!(unsafe { libc::flock(file.as_raw_fd(), libc::LOCK_EX | libc::LOCK_NB) }, 0);
    file
}

/// `replace_file` replaces a file whole and removes from its folder the
/// temporary files of `replace_file` whose writers have ended, told by the
/// writer's lock and not by the process id in the name: a file whose lock
/// is held stays though no process of its id exists here (a writer in
/// another PID namespace), and one whose lock is free goes though a live
/// process has its id (an id taken again since). A folder's temporary
/// files are left to the next `OutputDir::open` of the folder, which also
/// leaves a held one of `replace_file`.
#[test]
fn replacing_a_file_removes_the_temporary_files_whose_writers_have_ended() {
    use problems::report::files::replace_file;
    let dir = std::env::temp_dir().join(format!("spark-out-orphans-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    let mut gone = std::process::Command::new("true").spawn().unwrap();
    let dead = gone.id();
    gone.wait().unwrap();
    let alive = std::os::unix::process::parent_id();
    let single = |pid: u32, seq: u32| dir.join(format!("{TEMP_PREFIX}{pid}-single-{seq}-export.json"));
    let (held_dead, free_alive, free_dead) = (single(dead, 1), single(alive, 2), single(dead, 3));
    let held_alive = single(alive, 4);
    let folders = dir.join(format!("{TEMP_PREFIX}{dead}-0-export.csv"));
    for path in [&free_alive, &free_dead, &folders] {
        std::fs::write(path, b"{\"half\":").unwrap();
    }
    let writers = [hold_lock(&held_dead), hold_lock(&held_alive)];
    replace_file(&dir.join("export.json"), |w| w.write_all(b"{}")).unwrap();
    assert_eq!(std::fs::read(dir.join("export.json")).unwrap(), b"{}");
    assert!(held_dead.exists(), "a held temporary file was removed for the process id in its name");
    assert!(held_alive.exists(), "a held temporary file was removed");
    assert!(!free_alive.exists(), "a temporary file nobody holds is left for the process id in its name");
    assert!(!free_dead.exists(), "a temporary file nobody holds is left");
    assert!(folders.exists(), "a folder's temporary file is removed without the folder's lock");

    // The folder's next run removes its own kind and leaves the held ones.
    drop(OutputDir::open(&dir).unwrap());
    assert!(!folders.exists(), "a folder's temporary file is left by the folder's next run");
    assert!(held_dead.exists() && held_alive.exists(), "the folder's next run removed a held temporary file");

    // Once their writers end, they go.
    drop(writers);
    replace_file(&dir.join("export.json"), |w| w.write_all(b"[]")).unwrap();
    assert_eq!(visible_files(&dir), ["export.json"]);
    std::fs::remove_dir_all(&dir).unwrap();
}

/// Threads replacing files in one folder at once, each cleaning the
/// folder's ended temporary files as it starts, never remove one another's
/// temporary files: every replacement succeeds and none is left.
#[test]
fn replacements_side_by_side_keep_their_temporary_files() {
    use problems::report::files::replace_file;
    let dir = std::env::temp_dir().join(format!("spark-out-side-by-side-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    std::thread::scope(|s| {
        for t in 0..4 {
            let dir = &dir;
            s.spawn(move || {
                for k in 0..200 {
                    let path = dir.join(format!("{t}.json"));
                    replace_file(&path, |w| write!(w, "{k}")).unwrap();
                }
            });
        }
    });
    assert_eq!(visible_files(&dir), ["0.json", "1.json", "2.json", "3.json"]);
    for t in 0..4 {
        assert_eq!(std::fs::read_to_string(dir.join(format!("{t}.json"))).unwrap(), "199");
    }
    std::fs::remove_dir_all(&dir).unwrap();
}
