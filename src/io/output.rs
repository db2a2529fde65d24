//! The output rule, in one place: a command only ever replaces what it created itself.
//!
//! - Every path is compared after [`resolve`] (absolute, `.` and `..` resolved, symlinks of
//!   its existing part followed), so `ds/../ds` is `ds` and a symlink is its target.
//! - [`Outputs::check`] refuses, before any work, an output that is an input, a folder output
//!   that holds an input (or lies inside an input folder), and two outputs of one run that
//!   overlap.
//! - An output folder is written under a temporary name beside it ([`FolderWriter`]) and
//!   renamed into place once complete. An existing folder is replaced only when it is empty
//!   or carries the [`MARKER`] file that the same command wrote into it; any other folder is
//!   refused (exit 2) before any work.
//! - Files written beside an output folder for it (a video's GIF, MP4 and camera path) are
//!   recorded in its marker with their [`Stamp`] (length, modification time, inode): a later
//!   run replaces or removes such a file only while it is the one recorded ([`check_beside`]),
//!   never one the user made or changed since.
//! - Several outputs of one run into one folder (a video's, a report's) are written into a
//!   temporary folder inside it and moved into place together at the end ([`Staging`]); a run
//!   that fails leaves nothing it created, not even the folders it made for its output.
//! - Names derived from labels (a path file's stem, an orbit's time) go through
//!   [`sanitize_label`] and [`unique_names`]: never `.`, `..`, empty, hidden, a separator, or
//!   the name of another output of the run.
//! - Temporaries are told apart from the leftovers of killed runs by a lock held on them
//!   ([`super::remove_stale_temps`]), not by a process id.

use std::path::{Component, Path, PathBuf};

use crate::model::{Error, Result};

/// The marker file splat4d writes into every folder it creates as a whole: the command's
/// name on the first line, then every path it wrote in the folder, then, as `../NAME` and
/// their [`Stamp`], the files it wrote beside the folder for it.
pub const MARKER: &str = ".splat4d-output";

/// What tells a file splat4d wrote from one put in its place or changed since: its length,
/// modification time (nanoseconds) and, on Unix, its device and inode. A rename keeps all of
/// them, so a file staged and moved into place keeps its stamp.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Stamp {
    len: u64,
    modified: u128,
    device: u64,
    inode: u64,
}

impl Stamp {
    /// The stamp of the regular file `path` (a link is not followed), if it is one.
    #[must_use]
    pub fn of(path: &Path) -> Option<Stamp> {
        let meta = std::fs::symlink_metadata(path).ok()?;
        if !meta.is_file() {
            return None;
        }
        let modified = meta
            .modified()
            .ok()?
            .duration_since(std::time::UNIX_EPOCH)
            .ok()?
            .as_nanos();
        #[cfg(unix)]
        let (device, inode) = {
            use std::os::unix::fs::MetadataExt;
            (meta.dev(), meta.ino())
        };
        #[cfg(not(unix))]
        let (device, inode) = (0, 0);
        Some(Stamp {
            len: meta.len(),
            modified,
            device,
            inode,
        })
    }

    fn to_line(self, name: &str) -> String {
        format!("../{name}\t{}", self.to_fields())
    }

    /// `len modified device inode`, as marker lines record a stamp.
    pub(crate) fn to_fields(self) -> String {
        format!(
            "{} {} {} {}",
            self.len, self.modified, self.device, self.inode
        )
    }

    /// The stamp of `len modified device inode` ([`Self::to_fields`]).
    pub(crate) fn from_fields(numbers: &str) -> Option<Stamp> {
        let mut numbers = numbers.split(' ');
        let mut next = || numbers.next();
        Some(Stamp {
            len: next()?.parse().ok()?,
            modified: next()?.parse().ok()?,
            device: next()?.parse().ok()?,
            inode: next()?.parse().ok()?,
        })
    }

    /// `(NAME, stamp)` of a marker line `../NAME<TAB>len modified device inode`.
    fn from_line(line: &str) -> Option<(&str, Stamp)> {
        let (name, numbers) = line.strip_prefix("../")?.rsplit_once('\t')?;
        Some((name, Stamp::from_fields(numbers)?))
    }
}

/// `path` made absolute, with `.` and `..` resolved and the symlinks of its longest existing
/// ancestor followed (`canonicalize`); the part that does not exist yet is resolved
/// lexically.
#[must_use]
pub fn resolve(path: &Path) -> PathBuf {
    let absolute = if path.is_absolute() {
        path.to_path_buf()
    } else {
        std::env::current_dir()
            .unwrap_or_else(|_| PathBuf::from("/"))
            .join(path)
    };
    if let Ok(real) = absolute.canonicalize() {
        return real;
    }
    // Lexically first (so that `missing/..` does not stop the walk), then the longest
    // existing ancestor canonicalized.
    let mut lexical = PathBuf::new();
    for part in absolute.components() {
        match part {
            Component::CurDir => {}
            Component::ParentDir => {
                lexical.pop();
            }
            other => lexical.push(other.as_os_str()),
        }
    }
    let mut rest = Vec::new();
    let mut base = lexical.as_path();
    loop {
        if let Ok(real) = base.canonicalize() {
            let mut out = real;
            for part in rest.iter().rev() {
                out.push(part);
            }
            return out;
        }
        match (base.parent(), base.file_name()) {
            (Some(parent), Some(name)) => {
                rest.push(name.to_os_string());
                base = parent;
            }
            _ => return lexical,
        }
    }
}

/// Whether the existing file `file` lies, by its real path (symlinks followed), inside the
/// real folder `dir`: the confinement of files a model or dataset names.
#[must_use]
pub fn inside(file: &Path, dir: &Path) -> bool {
    let dir = if dir.as_os_str().is_empty() {
        Path::new(".")
    } else {
        dir
    };
    match (file.canonicalize(), dir.canonicalize()) {
        (Ok(file), Ok(dir)) => file.starts_with(dir),
        _ => false,
    }
}

/// Whether `inner` is `outer` or lies inside it (both resolved).
fn within(inner: &Path, outer: &Path) -> bool {
    inner.starts_with(outer)
}

/// A label made a safe file name: characters other than ASCII letters, digits, `-`, `_`,
/// `.` and `+` become `_`, leading dots are dropped (never hidden, `.` or `..`), at most 100
/// characters; `fallback` when nothing is left.
#[must_use]
pub fn sanitize_label(label: &str, fallback: &str) -> String {
    let cleaned: String = label
        .chars()
        .map(|c| {
            if c.is_ascii_alphanumeric() || matches!(c, '-' | '_' | '.' | '+') {
                c
            } else {
                '_'
            }
        })
        .collect();
    let trimmed: String = cleaned.trim_start_matches('.').chars().take(100).collect();
    if trimmed.is_empty() || trimmed.chars().all(|c| c == '.' || c == '_') {
        fallback.to_string()
    } else {
        trimmed
    }
}

/// A scene time `tau` for a file name: two decimals (`0.50`), or in scientific form beyond a
/// million (`1.00e308`, where two decimals would be a 312-character name).
#[must_use]
pub fn time_label(tau: f64) -> String {
    if tau.abs() < 1e6 {
        format!("{tau:.2}")
    } else {
        format!("{tau:.2e}")
    }
}

/// `names` made distinct: a name seen before gets `_2`, `_3`, … (compared without case, so
/// they stay distinct on case-insensitive file systems too).
#[must_use]
pub fn unique_names(names: &[String]) -> Vec<String> {
    let mut taken: Vec<String> = Vec::new();
    names
        .iter()
        .map(|name| {
            let mut candidate = name.clone();
            let mut k = 2;
            while taken.iter().any(|t| t.eq_ignore_ascii_case(&candidate)) {
                candidate = format!("{name}_{k}");
                k += 1;
            }
            taken.push(candidate.clone());
            candidate
        })
        .collect()
}

/// The paths under `dir` (relative, `/`-separated, sorted; symlinks not followed), or
/// `None` when it cannot be listed.
pub(crate) fn listing(dir: &Path) -> Option<Vec<String>> {
    let mut found = Vec::new();
    let mut stack = vec![PathBuf::new()];
    while let Some(relative) = stack.pop() {
        for entry in std::fs::read_dir(dir.join(&relative)).ok()? {
            let entry = entry.ok()?;
            let path = relative.join(entry.file_name());
            if entry.file_type().ok()?.is_dir() {
                stack.push(path.clone());
            }
            found.push(path.to_string_lossy().replace('\\', "/"));
        }
    }
    found.sort();
    Some(found)
}

/// Why `command` may not replace the existing folder `dir`, or `None` when it may: it is
/// empty, or it holds the [`MARKER`] naming `command` and nothing but what the marker lists
/// (what that command wrote there; a file added since keeps the folder).
fn not_replaceable(dir: &Path, command: &str) -> Option<String> {
    let Some(present) = listing(dir) else {
        return Some("cannot be listed".into());
    };
    if present.is_empty() {
        return None;
    }
    let Ok(marker) = crate::io::input::read_to_string(&dir.join(MARKER), "cannot read") else {
        return Some(format!(
            "was not written by `splat4d {command}` (it has no {MARKER} file naming it)"
        ));
    };
    let mut lines = marker.lines();
    if lines.next().map(str::trim) != Some(command) {
        return Some(format!(
            "was not written by `splat4d {command}` (its {MARKER} names another command)"
        ));
    }
    let written: std::collections::BTreeSet<&str> = lines.collect();
    present
        .iter()
        .find(|p| *p != MARKER && !written.contains(p.as_str()))
        .map(|extra| {
            format!(
                "holds {}, which `splat4d {command}` did not write there",
                super::json::cut(extra)
            )
        })
}

/// Writes the [`MARKER`] of the finished folder `dir`: `command`, every path in it, and the
/// [`Stamp`] of each file of `beside` (files in `dir`'s own folder written for this output).
pub fn write_marker(dir: &Path, command: &str, beside: &[PathBuf]) -> Result<()> {
    let written = listing(dir).ok_or_else(|| {
        Error::write(
            dir,
            "cannot list the finished output",
            std::io::Error::other("read_dir failed"),
        )
    })?;
    let mut marker = format!("{command}\n");
    for path in written.iter().filter(|p| *p != MARKER) {
        marker.push_str(path);
        marker.push('\n');
    }
    for file in beside {
        let name = file.file_name().unwrap_or_default().to_string_lossy();
        let stamp = Stamp::of(file).ok_or_else(|| {
            Error::write(
                file,
                "cannot read what was written",
                std::io::Error::other("not a regular file"),
            )
        })?;
        marker.push_str(&stamp.to_line(&name));
        marker.push('\n');
    }
    super::write_bytes_atomically(&dir.join(MARKER), marker.as_bytes())
}

/// The stamp with which the marker of the output folder `dir` records `file` (beside `dir`),
/// when `file` still has it: the file is what that run wrote, unchanged since.
#[must_use]
fn recorded_beside(dir: &Path, file: &Path) -> Option<Stamp> {
    let marker = std::fs::read_to_string(dir.join(MARKER)).ok()?;
    let name = file.file_name()?.to_str()?;
    let now = Stamp::of(file)?;
    marker
        .lines()
        .filter_map(Stamp::from_line)
        .any(|(recorded, stamp)| recorded == name && stamp == now)
        .then_some(now)
}

/// Checks, before any work, that `command` may write `file` beside its output folder `dir`:
/// it is absent (`None`), or the marker of `dir` written by `command` records it unchanged
/// (its stamp, to remove it later with [`remove_if_unchanged`] if this run does not write it
/// again). Anything else — the user's own file, or ours changed since — is refused.
pub fn check_beside(dir: &Path, file: &Path, command: &str) -> Result<Option<Stamp>> {
    if std::fs::symlink_metadata(file).is_err() {
        return Ok(None);
    }
    let ours = std::fs::read_to_string(dir.join(MARKER))
        .is_ok_and(|m| m.lines().next().map(str::trim) == Some(command));
    match recorded_beside(dir, file).filter(|_| ours) {
        Some(stamp) => Ok(Some(stamp)),
        None => Err(Error::usage(format!(
            "{}: exists and is not recorded as written by `splat4d {command}` beside {} (or it was changed since), so it is not replaced; name another folder, or move it away yourself",
            file.display(),
            dir.display()
        ))),
    }
}

/// Removes `file` when it still has `stamp` (an earlier run's output, unchanged, that this run
/// did not write again and that would otherwise pass for this run's).
pub fn remove_if_unchanged(file: &Path, stamp: Stamp) -> Result<()> {
    if Stamp::of(file) == Some(stamp) {
        std::fs::remove_file(file)
            .map_err(|e| Error::write(file, "cannot remove the earlier run's output", e))?;
    }
    Ok(())
}

/// Whether the folder `dir` may be replaced by `command`'s new output ([`check_replaceable`]).
#[must_use]
pub fn replaceable(dir: &Path, command: &str) -> bool {
    not_replaceable(dir, command).is_none()
}

/// Refuses (usage error) a folder `dir` that exists and may not be replaced by `command`:
/// only an empty folder, or one that command wrote and nobody added to since, is replaced.
pub fn check_replaceable(dir: &Path, command: &str) -> Result<()> {
    match std::fs::symlink_metadata(dir) {
        Err(_) => Ok(()),
        Ok(meta) if !meta.is_dir() => Err(Error::usage(format!(
            "{}: exists and is not a folder; name a new folder for the output",
            dir.display()
        ))),
        Ok(_) => match not_replaceable(dir, command) {
            None => Ok(()),
            Some(why) => Err(Error::usage(format!(
                "{}: exists and {why}, so it is not replaced; name a new folder, or move that one away yourself",
                dir.display()
            ))),
        },
    }
}

#[derive(Clone, Debug)]
struct Entry {
    shown: PathBuf,
    real: PathBuf,
    folder: bool,
}

/// The inputs and outputs of one run, checked against each other before any work.
#[derive(Clone, Debug, Default)]
pub struct Outputs {
    inputs: Vec<Entry>,
    outputs: Vec<Entry>,
}

impl Outputs {
    /// An empty set.
    #[must_use]
    pub fn new() -> Self {
        Outputs::default()
    }

    /// A file the command reads.
    pub fn input(&mut self, path: &Path) -> &mut Self {
        self.inputs.push(Entry {
            shown: path.to_path_buf(),
            real: resolve(path),
            folder: false,
        });
        self
    }

    /// A folder the command reads (no output may lie inside it or hold it whole).
    pub fn input_folder(&mut self, path: &Path) -> &mut Self {
        self.inputs.push(Entry {
            shown: path.to_path_buf(),
            real: resolve(path),
            folder: true,
        });
        self
    }

    /// A file the command writes (replacing a file of that name).
    pub fn file(&mut self, path: &Path) -> &mut Self {
        self.outputs.push(Entry {
            shown: path.to_path_buf(),
            real: resolve(path),
            folder: false,
        });
        self
    }

    /// A folder the command writes whole (replacing only its own earlier output).
    pub fn folder(&mut self, path: &Path) -> &mut Self {
        self.outputs.push(Entry {
            shown: path.to_path_buf(),
            real: resolve(path),
            folder: true,
        });
        self
    }

    /// Refuses (usage error) an output that is, holds or lies in an input it must not
    /// replace, and two outputs that overlap.
    pub fn check(&self) -> Result<()> {
        for out in &self.outputs {
            for input in &self.inputs {
                let clash = out.real == input.real
                    || (out.folder && within(&input.real, &out.real))
                    || (input.folder && within(&out.real, &input.real) && out.folder);
                if clash {
                    let how = if out.real == input.real {
                        "is"
                    } else if within(&input.real, &out.real) {
                        "holds"
                    } else {
                        "lies inside"
                    };
                    return Err(Error::usage(format!(
                        "{}: {how} an input of this command ({}); write the output elsewhere",
                        out.shown.display(),
                        input.shown.display()
                    )));
                }
            }
        }
        for (k, a) in self.outputs.iter().enumerate() {
            for b in &self.outputs[k + 1..] {
                let clash = a.real == b.real
                    || (a.folder && within(&b.real, &a.real))
                    || (b.folder && within(&a.real, &b.real));
                if clash {
                    return Err(Error::usage(format!(
                        "{} and {}: two outputs of this command name the same place; give them different names",
                        a.shown.display(),
                        b.shown.display()
                    )));
                }
            }
        }
        Ok(())
    }
}

/// Moves the finished folder `new` to `target`. An earlier output there is moved aside only
/// now (the new one complete beside it; locked meanwhile, so that a concurrent clean-up leaves
/// it to this run), then removed; it is moved back if the new one cannot take its place.
/// `shown` names the output in messages.
fn replace_folder(new: &Path, target: &Path, shown: &Path) -> Result<()> {
    if std::fs::symlink_metadata(target).is_err() {
        return std::fs::rename(new, target)
            .map_err(|e| Error::write(shown, "cannot move the output into place", e));
    }
    // Named after the target: a run killed between the two renames leaves it, and the next
    // run's clean-up ([`super::remove_stale_temps`]) moves it back.
    let name = target.file_name().unwrap_or_default().to_string_lossy();
    let old = super::folder_of(target).join(format!(
        "{}{}-{name}",
        super::ASIDE_PREFIX,
        super::random_part()
    ));
    let _held = super::lock_folder(target);
    std::fs::rename(target, &old)
        .map_err(|e| Error::write(shown, "cannot move the previous output aside", e))?;
    if let Err(e) = std::fs::rename(new, target) {
        let _ = std::fs::rename(&old, target);
        return Err(Error::write(
            shown,
            "cannot move the new output into place",
            e,
        ));
    }
    std::fs::remove_dir_all(&old)
        .map_err(|e| Error::write(&old, "cannot remove the previous output", e))
}

/// An output folder written under a temporary name beside its target and moved into place
/// by [`FolderWriter::commit`] once complete, with the [`MARKER`] naming the command. Dropped
/// without a commit (a failed run), it leaves nothing: neither the temporary folder nor the
/// folders made for it.
pub struct FolderWriter {
    shown: PathBuf,
    target: PathBuf,
    command: String,
    temp: tempfile::TempDir,
    /// The temporary folder's lock ([`super::remove_stale_temps`]).
    _lock: Option<std::fs::File>,
    /// Dropped after `temp`, so that the folders are empty by then.
    made: super::MadeFolders,
}

impl FolderWriter {
    /// Checks that `command` may replace `out` (absent, empty, or its own earlier output) and
    /// makes the temporary folder beside it.
    pub fn new(out: &Path, command: &str) -> Result<Self> {
        check_replaceable(out, command)?;
        let target = resolve(out);
        if target.parent().is_none() || target.file_name().is_none() {
            return Err(Error::usage(format!(
                "{}: cannot be an output folder; name a folder to write",
                out.display()
            )));
        }
        let parent = super::folder_of(&target).to_path_buf();
        let made = super::make_folders(&parent).map_err(|e| {
            Error::write(
                out,
                &format!("cannot create its folder {}", parent.display()),
                e,
            )
        })?;
        super::remove_stale_temps(&parent);
        let (temp, lock) = super::temp_dir_in(&parent, &format!("{command}-"))
            .map_err(|e| Error::write(out, "cannot create a temporary folder beside it", e))?;
        Ok(FolderWriter {
            shown: out.to_path_buf(),
            target,
            command: command.to_string(),
            temp,
            _lock: lock,
            made,
        })
    }

    /// The temporary folder to fill.
    #[must_use]
    pub fn path(&self) -> &Path {
        self.temp.path()
    }

    /// Writes the marker and moves the finished folder into place: an earlier output there is
    /// moved aside only now, the new one complete, and back if the new one cannot take its
    /// place.
    pub fn commit(self) -> Result<()> {
        // The marker lists what was written, so that a later run can tell it from files
        // added since.
        write_marker(self.temp.path(), &self.command, &[])?;
        // Checked again: the folder may have appeared or changed during the work.
        check_replaceable(&self.target, &self.command)?;
        replace_folder(self.temp.path(), &self.target, &self.shown)?;
        // In place: nothing is left at the temporary name to remove.
        let _ = self.temp.keep();
        self.made.keep();
        Ok(())
    }
}

/// The command named by the marker of the folder `dir`, if it has one.
fn marker_command(dir: &Path) -> Option<String> {
    let marker = std::fs::read_to_string(dir.join(MARKER)).ok()?;
    marker.lines().next().map(|l| l.trim().to_string())
}

/// Several outputs of one run into the folder `out` — a video's frame folders, GIFs, MP4s and
/// camera paths, a report's files — written into a temporary folder inside `out` and moved
/// into place together by [`Staging::commit`]: files replace files of their name, a folder
/// (with its [`MARKER`]) replaces only an earlier output of the command its marker names.
/// Dropped without a commit (a failed run), it leaves nothing it created: the temporary folder
/// goes, and so do the folders made for `out` (when still empty).
pub struct Staging {
    shown: PathBuf,
    target: PathBuf,
    temp: tempfile::TempDir,
    /// The temporary folder's lock ([`super::remove_stale_temps`]).
    _lock: Option<std::fs::File>,
    /// Dropped after `temp`, so that the folders are empty by then.
    made: super::MadeFolders,
}

impl Staging {
    /// Makes `out` (a folder, or absent) and the temporary folder inside it: a folder that
    /// cannot be written is refused here, before any work.
    pub fn new(out: &Path) -> Result<Self> {
        if std::fs::metadata(out).is_ok_and(|m| !m.is_dir()) {
            return Err(Error::usage(format!(
                "{}: exists and is not a folder; name a folder for the output",
                out.display()
            )));
        }
        let target = resolve(out);
        let made = super::make_folders(&target)
            .map_err(|e| Error::write(out, "cannot create the output folder", e))?;
        super::remove_stale_temps(&target);
        let (temp, lock) = super::temp_dir_in(&target, "stage-")
            .map_err(|e| Error::write(out, "cannot write in the output folder", e))?;
        Ok(Staging {
            shown: out.to_path_buf(),
            target,
            temp,
            _lock: lock,
            made,
        })
    }

    /// The temporary folder to fill.
    #[must_use]
    pub fn path(&self) -> &Path {
        self.temp.path()
    }

    /// Moves everything in the temporary folder into `out`, the names in `last` after the
    /// rest (`report.md`, so that it appears once all it shows is there). Every move is
    /// checked before the first is made: a file may not take the place of a folder, and a
    /// folder replaces only an earlier output of its command.
    pub fn commit(self, last: &[&str]) -> Result<()> {
        let entries = std::fs::read_dir(self.temp.path())
            .and_then(|entries| {
                entries
                    .map(|e| e.map(|e| e.file_name()))
                    .collect::<std::io::Result<Vec<_>>>()
            })
            .map_err(|e| Error::write(&self.shown, "cannot list the finished output", e))?;
        let mut names: Vec<String> = entries
            .iter()
            .map(|n| n.to_string_lossy().into_owned())
            .collect();
        names.sort_by_key(|n| (last.iter().position(|l| l == n), n.clone()));
        let mut moves = Vec::new();
        for name in &names {
            let staged = self.temp.path().join(name);
            let target = self.target.join(name);
            let shown = self.shown.join(name);
            if staged.is_dir() {
                let command = marker_command(&staged).unwrap_or_default();
                check_replaceable(&target, &command)?;
                moves.push((staged, target, shown, true));
            } else {
                if std::fs::symlink_metadata(&target).is_ok_and(|m| m.is_dir()) {
                    return Err(Error::usage(format!(
                        "{}: is a folder, so it is not replaced; name another folder for the output, or move that one away yourself",
                        shown.display()
                    )));
                }
                moves.push((staged, target, shown, false));
            }
        }
        for (staged, target, shown, folder) in moves {
            if folder {
                replace_folder(&staged, &target, &shown)?;
            } else {
                std::fs::rename(&staged, &target)
                    .map_err(|e| Error::write(&shown, "cannot move the output into place", e))?;
            }
        }
        self.made.keep();
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn labels_become_safe_distinct_names() {
        assert_eq!(time_label(0.5), "0.50");
        assert_eq!(time_label(-1e308), "-1.00e308");
        assert_eq!(sanitize_label("..", "path"), "path");
        assert_eq!(sanitize_label(".", "path"), "path");
        assert_eq!(sanitize_label("", "path"), "path");
        assert_eq!(sanitize_label(".hidden", "path"), "hidden");
        assert_eq!(sanitize_label("a/b\\c", "path"), "a_b_c");
        assert_eq!(sanitize_label("orbit_t0.50", "x"), "orbit_t0.50");
        let names = ["a", "A", "a", "b"].map(String::from);
        assert_eq!(unique_names(&names), ["a", "A_2", "a_3", "b"]);
    }

    #[test]
    fn paths_are_compared_resolved() {
        let dir = tempfile::tempdir().unwrap();
        let d = dir.path();
        std::fs::create_dir(d.join("ds")).unwrap();
        assert_eq!(resolve(&d.join("ds/../ds")), resolve(&d.join("ds")));
        assert_eq!(resolve(&d.join("new/../x")), resolve(&d.join("x")));
        assert_eq!(
            resolve(&d.join("ds/./a/b")),
            resolve(&d.join("ds")).join("a/b")
        );
        let mut outputs = Outputs::new();
        outputs
            .input(&d.join("ds/scene.json"))
            .folder(&d.join("ds/../ds"));
        assert!(outputs.check().is_err());
        let mut outputs = Outputs::new();
        outputs.file(&d.join("a.gif")).file(&d.join("ds/../a.gif"));
        assert!(outputs.check().is_err());
    }

    #[cfg(target_os = "linux")]
    #[test]
    fn an_output_moved_aside_by_a_killed_run_comes_back() {
        let dir = tempfile::tempdir().unwrap();
        let d = dir.path();
        // Left by a killed run: nobody holds its lock.
        let aside = d.join(".splat4d-old-0123456789abcdef-ds");
        std::fs::create_dir(&aside).unwrap();
        std::fs::write(aside.join("a.txt"), "kept").unwrap();
        super::super::remove_stale_temps(d);
        assert_eq!(std::fs::read_to_string(d.join("ds/a.txt")).unwrap(), "kept");
        assert!(!aside.exists());
        // With its successor in place, it goes.
        std::fs::create_dir(&aside).unwrap();
        super::super::remove_stale_temps(d);
        assert!(!aside.exists());
        assert!(d.join("ds/a.txt").exists());
    }

    #[test]
    fn a_failed_staging_leaves_nothing_and_a_commit_moves_everything() {
        let dir = tempfile::tempdir().unwrap();
        let d = dir.path();
        let out = d.join("a/b/out");
        {
            let staging = Staging::new(&out).unwrap();
            std::fs::write(staging.path().join("x.txt"), "x").unwrap();
            // Dropped without a commit: a run that failed.
        }
        assert!(!d.join("a").exists(), "the folders it made are gone");
        std::fs::create_dir_all(&out).unwrap();
        std::fs::write(out.join("x.txt"), "old").unwrap();
        std::fs::write(out.join("mine.txt"), "mine").unwrap();
        let staging = Staging::new(&out).unwrap();
        std::fs::write(staging.path().join("x.txt"), "new").unwrap();
        std::fs::write(staging.path().join("report.md"), "md").unwrap();
        let frames = staging.path().join("frames");
        std::fs::create_dir(&frames).unwrap();
        std::fs::write(frames.join("f.png"), "png").unwrap();
        write_marker(&frames, "video", &[staging.path().join("x.txt")]).unwrap();
        staging.commit(&["report.md"]).unwrap();
        let names = |dir: &Path| {
            let mut names: Vec<String> = std::fs::read_dir(dir)
                .unwrap()
                .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
                .collect();
            names.sort();
            names
        };
        assert_eq!(names(&out), ["frames", "mine.txt", "report.md", "x.txt"]);
        assert_eq!(std::fs::read_to_string(out.join("x.txt")).unwrap(), "new");
        // Moved into place, the file keeps the stamp its folder's marker recorded.
        assert!(recorded_beside(&out.join("frames"), &out.join("x.txt")).is_some());
        assert!(check_beside(&out.join("frames"), &out.join("x.txt"), "video").is_ok());
        assert!(check_beside(&out.join("frames"), &out.join("mine.txt"), "video").is_err());
        std::fs::write(out.join("x.txt"), "changed").unwrap();
        assert!(check_beside(&out.join("frames"), &out.join("x.txt"), "video").is_err());
        // A folder of the user's in the way: refused before anything moves.
        std::fs::create_dir(out.join("other")).unwrap();
        std::fs::write(out.join("other/notes.txt"), "mine").unwrap();
        let staging = Staging::new(&out).unwrap();
        std::fs::write(staging.path().join("y.txt"), "y").unwrap();
        let other = staging.path().join("other");
        std::fs::create_dir(&other).unwrap();
        write_marker(&other, "video", &[]).unwrap();
        assert!(staging.commit(&[]).is_err());
        assert_eq!(
            names(&out),
            ["frames", "mine.txt", "other", "report.md", "x.txt"]
        );
        assert_eq!(names(&out.join("other")), ["notes.txt"]);
    }

    #[test]
    fn only_a_marked_folder_is_replaced() {
        let dir = tempfile::tempdir().unwrap();
        let out = dir.path().join("out");
        std::fs::create_dir(&out).unwrap();
        std::fs::write(out.join("notes.txt"), "mine").unwrap();
        assert!(FolderWriter::new(&out, "dataset").is_err());
        std::fs::remove_file(out.join("notes.txt")).unwrap();
        let writer = FolderWriter::new(&out, "dataset").unwrap();
        std::fs::write(writer.path().join("a.txt"), "new").unwrap();
        writer.commit().unwrap();
        assert_eq!(
            std::fs::read_to_string(out.join(MARKER)).unwrap(),
            "dataset\na.txt\n"
        );
        assert!(FolderWriter::new(&out, "video").is_err());
        // A file added to it since keeps it.
        std::fs::write(out.join("b.txt"), "mine").unwrap();
        assert!(FolderWriter::new(&out, "dataset").is_err());
        std::fs::remove_file(out.join("b.txt")).unwrap();
        let writer = FolderWriter::new(&dir.path().join("out/../out"), "dataset").unwrap();
        writer.commit().unwrap();
        assert!(!out.join("a.txt").exists());
        assert!(out.join(MARKER).exists());
        let names: Vec<_> = std::fs::read_dir(dir.path()).unwrap().collect();
        assert_eq!(names.len(), 1);
    }
}
