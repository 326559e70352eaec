//! How every `lipac` command writes its output, so that no command ever
//! destroys a file of the user's:
//!
//! * arguments are checked before anything is written;
//! * a file is written to a temporary file beside its target and renamed
//!   into place only on success ([`OutputFile`]); a report folder is written
//!   to a temporary folder beside it and its files renamed in
//!   ([`publish_dir`]). On failure only the temporary files, which the
//!   command created, are removed; the target is never truncated or
//!   removed;
//! * an output that is one of the command's inputs (the same file after
//!   resolving links: same device and inode, or the same canonical path) is
//!   refused before anything is read or written;
//! * a target that is a symbolic link is written through: the file it
//!   points to is replaced, the link stays.
//!
//! Inputs are opened once ([`open_input`]); `-` is standard input.

use std::fs::{self, File};
use std::io::{self, BufWriter, Read, Write};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU32, Ordering};

/// A failure to write an output, naming the path.
pub fn io_err(path: &Path, e: impl std::fmt::Display) -> String {
    format!("{}: {e}", path.display())
}

/// Whether `path` names standard input / output.
pub fn is_stdio(path: &Path) -> bool {
    path.as_os_str() == "-"
}

/// Opens the input `path` once (`-`: standard input), buffered.
pub fn open_input(path: &Path) -> Result<Box<dyn Read>, String> {
    if is_stdio(path) {
        return Ok(Box::new(io::stdin().lock()));
    }
    let f = File::open(path).map_err(|e| io_err(path, e))?;
    if f.metadata().map(|m| m.is_dir()).unwrap_or(false) {
        return Err(io_err(path, "is a directory, not a trace"));
    }
    Ok(Box::new(f))
}

/// Whether `a` and `b` name the same existing file (after links).
fn same_file(a: &Path, b: &Path) -> bool {
    let (Ok(ma), Ok(mb)) = (fs::metadata(a), fs::metadata(b)) else {
        return false;
    };
    #[cfg(unix)]
    {
        use std::os::unix::fs::MetadataExt;
        if (ma.dev(), ma.ino()) == (mb.dev(), mb.ino()) {
            return true;
        }
    }
    let _ = (ma, mb);
    matches!((fs::canonicalize(a), fs::canonicalize(b)), (Ok(x), Ok(y)) if x == y)
}

/// Refuses `output` if it is one of `inputs` (after resolving links).
pub fn check_not_input(output: &Path, inputs: &[&Path]) -> Result<(), String> {
    for input in inputs {
        if !is_stdio(input) && same_file(output, input) {
            return Err(format!(
                "the output {} is the input {}: refusing to overwrite it",
                output.display(),
                input.display()
            ));
        }
    }
    Ok(())
}

/// Refuses a report folder that is one of `inputs` or exists and is not a
/// folder: checked before the work ([`publish_dir`] checks again when it
/// writes).
pub fn check_out_dir(dir: &Path, inputs: &[&Path]) -> Result<(), String> {
    check_not_input(dir, inputs)?;
    if dir.exists() && !dir.is_dir() {
        return Err(io_err(dir, "exists and is not a folder"));
    }
    Ok(())
}

/// Where writing `target` actually lands: the file a symbolic link points
/// to (so the link is kept), else `target`.
fn resolve_target(target: &Path) -> PathBuf {
    match fs::symlink_metadata(target) {
        Ok(m) if m.file_type().is_symlink() => fs::canonicalize(target).unwrap_or_else(|_| {
            // A dangling link: write where it points.
            fs::read_link(target)
                .map(|l| match target.parent() {
                    Some(p) if l.is_relative() => p.join(l),
                    _ => l,
                })
                .unwrap_or_else(|_| target.to_path_buf())
        }),
        _ => target.to_path_buf(),
    }
}

/// A fresh, unused name beside `target`: `.<name>.<pid>-<n>.tmp`.
fn temp_beside(target: &Path) -> PathBuf {
    static N: AtomicU32 = AtomicU32::new(0);
    let name = target
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_else(|| "lipac-output".into());
    let n = N.fetch_add(1, Ordering::Relaxed);
    let tmp = format!(".{name}.{}-{n}.tmp", std::process::id());
    match target.parent() {
        Some(p) if !p.as_os_str().is_empty() => p.join(tmp),
        _ => PathBuf::from(tmp),
    }
}

/// A file being written: a temporary file beside the target, renamed onto
/// it by [`OutputFile::commit`]; dropped without commit, the temporary file
/// is removed and the target is untouched.
pub struct OutputFile {
    target: PathBuf,
    shown: PathBuf,
    tmp: PathBuf,
    file: Option<BufWriter<File>>,
}

impl OutputFile {
    /// Starts writing `target`, refusing it if it is one of `inputs` or an
    /// existing folder.
    pub fn create(target: &Path, inputs: &[&Path]) -> Result<Self, String> {
        check_not_input(target, inputs)?;
        if target.is_dir() {
            return Err(io_err(target, "is a folder; expected a file to write"));
        }
        let resolved = resolve_target(target);
        let tmp = temp_beside(&resolved);
        let file = fs::OpenOptions::new()
            .write(true)
            .create_new(true)
            .open(&tmp)
            .map_err(|e| io_err(target, format!("cannot create a file beside it: {e}")))?;
        Ok(Self {
            target: resolved,
            shown: target.to_path_buf(),
            tmp,
            file: Some(BufWriter::new(file)),
        })
    }

    /// The sink to write to.
    pub fn writer(&mut self) -> &mut BufWriter<File> {
        self.file.as_mut().expect("open until committed")
    }

    /// Flushes, syncs and renames the temporary file onto the target.
    pub fn commit(mut self) -> Result<(), String> {
        let shown = self.shown.clone();
        let mut w = self.file.take().expect("open until committed");
        w.flush().map_err(|e| io_err(&shown, e))?;
        let f = w.into_inner().map_err(|e| io_err(&shown, e.error()))?;
        f.sync_all().map_err(|e| io_err(&shown, e))?;
        drop(f);
        fs::rename(&self.tmp, &self.target).map_err(|e| io_err(&shown, e))?;
        self.tmp = PathBuf::new();
        Ok(())
    }
}

impl Drop for OutputFile {
    fn drop(&mut self) {
        if !self.tmp.as_os_str().is_empty() {
            self.file = None;
            let _ = fs::remove_file(&self.tmp);
        }
    }
}

/// The files under `root/rel`, as paths relative to `root`.
fn collect_files(root: &Path, rel: &Path, out: &mut Vec<PathBuf>) -> Result<(), String> {
    let here = root.join(rel);
    for entry in fs::read_dir(&here).map_err(|e| io_err(&here, e))? {
        let entry = entry.map_err(|e| io_err(&here, e))?;
        let rel = rel.join(entry.file_name());
        if entry.file_type().map_err(|e| io_err(&here, e))?.is_dir() {
            collect_files(root, &rel, out)?;
        } else {
            out.push(rel);
        }
    }
    Ok(())
}

/// Writes a report folder (subfolders included): `write` fills a fresh temporary folder beside
/// `dir`; on success `dir` is created if missing and each written file is
/// renamed into it (replacing only files of the same names, earlier
/// outputs of the same command); then the temporary folder is removed.
/// Nothing in `dir` is touched when `write` fails. Refuses a `dir` that is
/// one of `inputs` or an existing file.
pub fn publish_dir<T>(
    dir: &Path,
    inputs: &[&Path],
    write: impl FnOnce(&Path) -> Result<T, String>,
) -> Result<T, String> {
    check_not_input(dir, inputs)?;
    if dir.exists() && !dir.is_dir() {
        return Err(io_err(dir, "exists and is not a folder"));
    }
    let parent_dir = match dir.parent() {
        Some(p) if !p.as_os_str().is_empty() => p.to_path_buf(),
        _ => PathBuf::from("."),
    };
    fs::create_dir_all(&parent_dir).map_err(|e| io_err(&parent_dir, e))?;
    let tmp = temp_beside(dir);
    fs::create_dir(&tmp)
        .map_err(|e| io_err(dir, format!("cannot create a folder beside it: {e}")))?;
    let result = write(&tmp).and_then(|out| {
        fs::create_dir_all(dir).map_err(|e| io_err(dir, e))?;
        let mut files = Vec::new();
        collect_files(&tmp, Path::new(""), &mut files)?;
        files.sort();
        // Every target checked before the first one is replaced.
        let mut moves = Vec::with_capacity(files.len());
        for rel in files {
            let to = resolve_target(&dir.join(&rel));
            if to.is_dir() {
                return Err(io_err(
                    &to,
                    "is a folder; cannot replace it with a report file",
                ));
            }
            check_not_input(&to, inputs)?;
            moves.push((tmp.join(&rel), to));
        }
        for (from, to) in moves {
            if let Some(parent) = to.parent() {
                fs::create_dir_all(parent).map_err(|e| io_err(parent, e))?;
            }
            fs::rename(&from, &to).map_err(|e| io_err(&to, e))?;
        }
        Ok(out)
    });
    // Only what this command created: the temporary folder and whatever of
    // its files were not moved.
    let _ = fs::remove_dir_all(&tmp);
    result
}
