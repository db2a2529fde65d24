//! Files: every format the tool reads or writes, and atomic writes. It reads and writes
//! model types ([`crate::model`]); nothing below it imports it, and nothing here knows of
//! the command line.
//!
//! | module | format |
//! |---|---|
//! | [`scene_file`] | scene JSON (SPEC §1), and 4D scene PLY through [`ply`] |
//! | [`camera_file`] | camera JSON (SPEC §3) |
//! | [`path_file`] | camera path JSON |
//! | [`gradients_file`] | the `splat4d grad` JSON |
//! | [`image_file`] | PNG (8/16 bit) and EXR images (SPEC §5: linear, no sRGB curve): `png`, `exr`, `read` |
//! | [`ply`] | 3DGS slice PLY for splat viewers, 4D scene PLY |
//! | [`ply_header`] | the PLY header every PLY reader reads first (format, elements, property types, counts against the file's length) |
//! | [`dataset`] | multi-view datasets, one file per layout tried in order (D-NeRF / Blender `transforms_*.json`, nerfstudio `transforms.json`, COLMAP), the steps they share (undistortion, masks, downscaling), and writing the D-NeRF layout |
//! | [`colmap`] | COLMAP sparse models, text and binary |
//! | [`point_cloud`] | PLY point clouds shipped with datasets |
//! | [`gltf`] | glTF 2.0 models and their cameras: read, checked, handed to the scene math as plain data |
//! | [`video`] | frame folders, GIF and MP4 from frames rendered above |
//! | [`shards`] | outputs shared by runs of one command (`--shard I/N`) and put together (`--assemble`) |
//! | [`json`] | JSON with errors that name the item and field |
//! | [`input`] | every input file opened: regular files only (FIFOs, sockets, devices refused at once) |
//!
//! [`memory`] holds the memory rule (estimates checked against what the machine has), and
//! [`output`] the one rule every output follows (what may be replaced, temporary
//! folders renamed into place, inputs never overwritten).

pub mod camera_file;
pub mod colmap;
pub mod dataset;
pub mod gltf;
pub mod gradients_file;
pub mod image_file;
pub mod input;
pub mod json;
pub mod memory;
pub mod output;
pub mod path_file;
pub mod ply;
pub mod ply_header;
pub mod point_cloud;
pub mod scene_file;
pub mod shards;
pub mod video;

use std::io::{BufWriter, Write};
use std::path::Path;

use crate::model::{Error, Result};

/// The name prefix of every temporary file and folder splat4d makes beside an output
/// (`.splat4d-tmp-` and a random part).
pub const TEMP_PREFIX: &str = ".splat4d-tmp-";

/// The name prefix of an earlier output folder moved aside while its successor takes its
/// place: `.splat4d-old-RANDOM-NAME` (see [`output::FolderWriter::commit`]).
pub const ASIDE_PREFIX: &str = ".splat4d-old-";

/// Takes the lock that marks a temporary as in use and says whether the temporary is still
/// there: a clean-up ([`remove_stale_temps`]) of another run may have taken it for a killed
/// run's leftover between its creation and this lock (then `false`: make another).
///
/// The lock is an exclusive `flock` on the file or folder itself (`File::lock`), held for as
/// long as `file` stays open; it is released by the kernel however the process ends, and it
/// is the same lock seen from every process of the machine, whatever its PID namespace (a
/// process id is not: a container sharing the folder sees other ids). Where the file system
/// offers no locks the temporary is left unlocked, and a clean-up, unable to lock it
/// either, keeps it.
fn hold(file: &std::fs::File) -> bool {
    if file.lock().is_err() {
        return true;
    }
    #[cfg(unix)]
    {
        use std::os::unix::fs::MetadataExt;
        file.metadata().is_ok_and(|m| m.nlink() > 0)
    }
    #[cfg(not(unix))]
    true
}

/// Opens `path` (a file or a folder) to lock it, without following a symbolic link and
/// without waiting on a FIFO.
fn open_for_lock(path: &Path) -> std::io::Result<std::fs::File> {
    let mut options = std::fs::OpenOptions::new();
    options.read(true);
    #[cfg(unix)]
    {
        use std::os::unix::fs::OpenOptionsExt;
        options.custom_flags(libc::O_NOFOLLOW | libc::O_NONBLOCK);
    }
    options.open(path)
}

/// How many times a temporary is made again when a concurrent clean-up removed it before it
/// was locked (each time takes a new random name; more than once is already unlikely).
const TEMP_TRIES: usize = 16;

/// A new temporary file in `dir`, named [`TEMP_PREFIX`]…`suffix`, locked (`hold`) until it
/// is dropped or persisted and closed.
pub(crate) fn temp_file_in(dir: &Path, suffix: &str) -> std::io::Result<tempfile::NamedTempFile> {
    for _ in 0..TEMP_TRIES {
        let temp = tempfile::Builder::new()
            .prefix(TEMP_PREFIX)
            .suffix(suffix)
            .tempfile_in(dir)?;
        if hold(temp.as_file()) {
            return Ok(temp);
        }
    }
    Err(std::io::Error::other(
        "the temporary file kept being removed by another run",
    ))
}

/// A new temporary folder in `dir`, named [`TEMP_PREFIX`]`label`…, and the open folder that
/// holds its lock (`hold`): the folder is in use until that is dropped.
pub(crate) fn temp_dir_in(
    dir: &Path,
    label: &str,
) -> std::io::Result<(tempfile::TempDir, Option<std::fs::File>)> {
    for _ in 0..TEMP_TRIES {
        let temp = tempfile::Builder::new()
            .prefix(&format!("{TEMP_PREFIX}{label}"))
            .tempdir_in(dir)?;
        let Ok(lock) = open_for_lock(temp.path()) else {
            // Folders cannot be opened here (not Linux or macOS): unlocked, and never taken
            // for a leftover either.
            return Ok((temp, None));
        };
        if hold(&lock) {
            return Ok((temp, Some(lock)));
        }
    }
    Err(std::io::Error::other(
        "the temporary folder kept being removed by another run",
    ))
}

/// Locks the folder `dir` (an output about to be moved aside, [`ASIDE_PREFIX`]) so that a
/// concurrent clean-up leaves it to this run; `None` where folders cannot be locked.
pub(crate) fn lock_folder(dir: &Path) -> Option<std::fs::File> {
    let file = open_for_lock(dir).ok()?;
    hold(&file).then_some(file)
}

/// Whether the open `file` is still what `path` names (the same device and inode; `path` not
/// a symbolic link): a temporary renamed into place, or replaced, since it was opened is not
/// removed by its old name.
fn still_at(file: &std::fs::File, path: &Path) -> bool {
    #[cfg(unix)]
    {
        use std::os::unix::fs::MetadataExt;
        match (file.metadata(), std::fs::symlink_metadata(path)) {
            (Ok(open), Ok(named)) => {
                !named.file_type().is_symlink()
                    && open.dev() == named.dev()
                    && open.ino() == named.ino()
            }
            _ => false,
        }
    }
    #[cfg(not(unix))]
    {
        let _ = (file, path);
        false
    }
}

/// Removes from `dir` the temporary files and folders that runs killed before they could
/// rename them left behind ([`TEMP_PREFIX`]…, [`ASIDE_PREFIX`]…): those whose lock can be
/// taken. Every temporary is locked by its run as it is made (an exclusive `flock` on the
/// file or folder itself, released by the kernel however the run ends), so no run still
/// writing one loses it — whatever process, PID namespace or container it runs in. An
/// earlier output moved aside goes back to its name when nothing took its place. Best
/// effort: errors are ignored, and what cannot be locked is kept.
pub fn remove_stale_temps(dir: &Path) {
    let Ok(entries) = std::fs::read_dir(dir) else {
        return;
    };
    for entry in entries.filter_map(std::result::Result::ok) {
        let name = entry.file_name().to_string_lossy().into_owned();
        let aside = name.strip_prefix(ASIDE_PREFIX);
        if aside.is_none() && !name.starts_with(TEMP_PREFIX) {
            continue;
        }
        let path = entry.path();
        let Ok(meta) = std::fs::symlink_metadata(&path) else {
            continue;
        };
        // Links, FIFOs and devices are no temporaries of ours.
        if !(meta.is_file() || meta.is_dir()) {
            continue;
        }
        let Ok(file) = open_for_lock(&path) else {
            continue;
        };
        // Taken: another run still uses it. An error: locks are not offered here, so
        // nothing tells a leftover from a live temporary, and it is kept.
        if file.try_lock().is_err() || !still_at(&file, &path) {
            continue;
        }
        // An earlier output moved aside by a run killed before its successor took its
        // place: it goes back rather than away.
        let original = aside
            .and_then(|rest| rest.split_once('-'))
            .map(|(_, original)| dir.join(original))
            .filter(|_| meta.is_dir());
        if let Some(original) = original
            && std::fs::symlink_metadata(&original).is_err()
            && std::fs::rename(&path, &original).is_ok()
        {
            continue;
        }
        let _ = if meta.is_dir() {
            std::fs::remove_dir_all(&path)
        } else {
            std::fs::remove_file(&path)
        };
        // The lock goes with `file`, after the removal.
    }
}

/// A random name part (16 hex digits), for names that must not clash between runs.
#[must_use]
pub(crate) fn random_part() -> String {
    use std::hash::BuildHasher;
    let hash = std::collections::hash_map::RandomState::new().hash_one(
        std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .map_or(0, |d| d.as_nanos()),
    );
    format!("{hash:016x}")
}

/// The writer handed to [`write_atomically`]'s closure (buffered, seekable).
pub type AtomicWriter = FirstError<BufWriter<tempfile::NamedTempFile>>;

/// A writer that remembers the first I/O error its inner writer returned. Encoders (EXR,
/// PNG, GIF) wrap I/O errors in their own types and lose their kind — a full disk came back as
/// "Format error decoding OpenExr" — so [`write_atomically`] reports this one instead.
pub struct FirstError<W> {
    inner: W,
    first: Option<std::io::Error>,
}

impl<W> FirstError<W> {
    /// Wraps `inner`.
    pub fn new(inner: W) -> Self {
        FirstError { inner, first: None }
    }

    /// The first error seen (a copy with its kind and OS code), if any.
    #[must_use]
    pub fn first_error(&self) -> Option<std::io::Error> {
        self.first.as_ref().map(|e| match e.raw_os_error() {
            Some(code) => std::io::Error::from_raw_os_error(code),
            None => std::io::Error::new(e.kind(), e.to_string()),
        })
    }

    fn record<T>(&mut self, result: std::io::Result<T>) -> std::io::Result<T> {
        if let Err(e) = &result
            && self.first.is_none()
        {
            self.first = Some(match e.raw_os_error() {
                Some(code) => std::io::Error::from_raw_os_error(code),
                None => std::io::Error::new(e.kind(), e.to_string()),
            });
        }
        result
    }
}

impl<W: Write> Write for FirstError<W> {
    fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
        let result = self.inner.write(buf);
        self.record(result)
    }
    fn flush(&mut self) -> std::io::Result<()> {
        let result = self.inner.flush();
        self.record(result)
    }
}

impl<W: std::io::Seek> std::io::Seek for FirstError<W> {
    fn seek(&mut self, pos: std::io::SeekFrom) -> std::io::Result<u64> {
        let result = self.inner.seek(pos);
        self.record(result)
    }
}

/// The folder a file `path` is written in (`.` for a bare file name).
#[must_use]
pub fn folder_of(path: &Path) -> &Path {
    match path.parent() {
        Some(p) if !p.as_os_str().is_empty() => p,
        _ => Path::new("."),
    }
}

/// Whether two paths name one file once resolved ([`output::resolve`]: `..` and symlinks).
#[must_use]
pub fn same_file(a: &Path, b: &Path) -> bool {
    a == b || output::resolve(a) == output::resolve(b)
}

/// A usage error when `path`, where a file is to be written, is a folder.
fn refuse_folder(path: &Path) -> Result<()> {
    if path.is_dir() {
        return Err(Error::usage(format!(
            "{}: is a folder; name a file to write",
            path.display()
        )));
    }
    Ok(())
}

/// Checks, before any work, that a command may write `out`: its extension is one of
/// `extensions` (lower case, without the dot; empty: any), it is none of the command's
/// `inputs` (so a typo never replaces an input), and its folder can be made and written
/// (a temporary file is created there, or in its nearest existing parent, and removed;
/// nothing is made yet, so a run that fails later leaves no folder behind).
pub fn check_output(out: &Path, extensions: &[&str], inputs: &[&Path]) -> Result<()> {
    let extension = out
        .extension()
        .and_then(|e| e.to_str())
        .map(str::to_ascii_lowercase);
    if !extensions.is_empty()
        && !extension
            .as_deref()
            .is_some_and(|e| extensions.contains(&e))
    {
        return Err(Error::usage(format!(
            "{}: this command writes {}",
            out.display(),
            extensions
                .iter()
                .map(|e| format!(".{e}"))
                .collect::<Vec<_>>()
                .join(" or ")
        )));
    }
    refuse_folder(out)?;
    let mut outputs = output::Outputs::new();
    outputs.file(out);
    for input in inputs {
        outputs.input(input);
    }
    outputs.check()?;
    // Its folder, or the nearest one that exists: a temporary file made there and removed
    // says it can be written (and the missing folders made), without making anything yet.
    let parent = folder_of(out);
    let existing = parent
        .ancestors()
        .find(|a| a.as_os_str().is_empty() || std::fs::symlink_metadata(a).is_ok())
        .filter(|a| !a.as_os_str().is_empty())
        .unwrap_or(Path::new("."));
    if !existing.is_dir() {
        return Err(Error::write(
            out,
            &format!("cannot create its folder {}", parent.display()),
            std::io::Error::other(format!("{} is not a folder", existing.display())),
        ));
    }
    let what = if existing == parent {
        "cannot write in its folder".to_string()
    } else {
        format!("cannot create its folder {}", parent.display())
    };
    tempfile::Builder::new()
        .prefix(TEMP_PREFIX)
        .tempfile_in(existing)
        .map(drop)
        .map_err(|e| Error::write(out, &what, e))
}

/// The folders [`make_folders`] made for an output: removed again, when still empty, unless
/// [`MadeFolders::keep`] is called once the output is in place — a failed run leaves no
/// folder it made.
#[must_use = "the folders are removed again when this is dropped"]
pub struct MadeFolders {
    /// Deepest first.
    made: Vec<std::path::PathBuf>,
}

impl MadeFolders {
    /// The output is in place: the folders stay.
    pub fn keep(mut self) {
        self.made.clear();
    }
}

impl Drop for MadeFolders {
    fn drop(&mut self) {
        // `remove_dir` removes only an empty folder: one that another run has filled
        // meanwhile stays.
        for dir in &self.made {
            let _ = std::fs::remove_dir(dir);
        }
    }
}

/// Makes the folder `dir` and its missing parents, remembering which it made.
pub fn make_folders(dir: &Path) -> std::io::Result<MadeFolders> {
    let mut made = Vec::new();
    for ancestor in dir.ancestors() {
        if ancestor.as_os_str().is_empty() || std::fs::symlink_metadata(ancestor).is_ok() {
            break;
        }
        made.push(ancestor.to_path_buf());
    }
    let made = MadeFolders { made };
    std::fs::create_dir_all(dir)?;
    Ok(made)
}

/// Writes `bytes` to `path` with [`write_atomically`].
pub fn write_bytes_atomically(path: &Path, bytes: &[u8]) -> Result<()> {
    write_atomically(path, |w| w.write_all(bytes))
}

/// Writes a file all at once or not at all: `write` fills a temporary file in the same
/// folder, which is then renamed over `path`. On any error nothing is left at `path` (an
/// existing file there is untouched). Missing parent folders are created. A `path` that is
/// a folder is a usage error; failures to write are output errors
/// ([`crate::model::ErrorKind`]).
pub fn write_atomically(
    path: &Path,
    write: impl FnOnce(&mut AtomicWriter) -> std::io::Result<()>,
) -> Result<()> {
    write_atomically_reserving(path, None, write)
}

/// [`write_atomically`] for a file whose length, `bytes`, is known before it is written:
/// the temporary file's blocks are reserved first (Linux: `fallocate` keeping its size), so
/// that renaming it over an earlier output does not wait for the file system to write it out.
/// The trade (see `reserve_blocks` in the source): after a power loss in the seconds before
/// the kernel writes the file out, it may read as zeros. For renders (`image_file`), which
/// can be made again, not for scenes and logs. Pass the exact length: a larger one leaves
/// the blocks past the end reserved until the file is replaced or deleted.
pub fn write_atomically_sized(
    path: &Path,
    bytes: u64,
    write: impl FnOnce(&mut AtomicWriter) -> std::io::Result<()>,
) -> Result<()> {
    write_atomically_reserving(path, Some(bytes), write)
}

/// Reserves the first `bytes` of `file` on disk without changing its length (Linux:
/// `fallocate(FALLOC_FL_KEEP_SIZE)`; a no-op elsewhere or where the file system cannot).
///
/// Why: file systems with delayed allocation (ext4, by default) write a file's data out
/// when it is renamed over an existing file (ext4's `auto_da_alloc`), and the rename waits
/// for that: measured on ext4, writing and renaming a 3 MiB image over an earlier one took
/// ~3 ms, and 20 ms at 25 MiB (a 1080p EXR), against 0.5 and 6 ms with the blocks
/// reserved first, when there is nothing left to allocate at the rename. What it changes:
/// after a power loss within the few seconds before the kernel writes the file out, the
/// new file may read as zeros where the heuristic would have had the old one or the new;
/// no output is ever synced to disk, with or without it, and outputs stay atomic for every
/// reader and every way the process can end.
fn reserve_blocks(file: &std::fs::File, bytes: u64) {
    #[cfg(target_os = "linux")]
    {
        use std::os::fd::AsRawFd;
        if let Ok(length) = libc::off_t::try_from(bytes)
            && length > 0
        {
            // SAFETY: `file` is an open file descriptor for the duration of the call. A
            // failure (no space, a file system without it) is left to the writes to report.
            unsafe { libc::fallocate(file.as_raw_fd(), libc::FALLOC_FL_KEEP_SIZE, 0, length) };
        }
    }
    #[cfg(not(target_os = "linux"))]
    let _ = (file, bytes);
}

/// [`write_atomically`], reserving `reserve` bytes of the temporary file first when given.
fn write_atomically_reserving(
    path: &Path,
    reserve: Option<u64>,
    write: impl FnOnce(&mut AtomicWriter) -> std::io::Result<()>,
) -> Result<()> {
    refuse_folder(path)?;
    let parent = folder_of(path);
    let made = make_folders(parent).map_err(|e| {
        let message = format!("cannot create its folder {}", parent.display());
        Error::write(path, &message, e)
    })?;
    // Inside our own temporary folders there is nothing stale to look for (and a frame
    // folder being written would be listed once per frame).
    let in_temp = parent
        .components()
        .any(|c| c.as_os_str().to_string_lossy().starts_with(TEMP_PREFIX));
    if !in_temp {
        remove_stale_temps(parent);
    }
    let temp = temp_file_in(parent, "")
        .map_err(|e| Error::write(path, "cannot create a temporary file beside the output", e))?;
    if let Some(bytes) = reserve {
        reserve_blocks(temp.as_file(), bytes);
    }
    let mut writer = FirstError::new(BufWriter::new(temp));
    write(&mut writer)
        .and_then(|()| writer.flush())
        .map_err(|e| Error::write(path, "cannot write", writer.first_error().unwrap_or(e)))?;
    let temp = writer
        .inner
        .into_inner()
        .map_err(|e| Error::write(path, "cannot write", e.into_error()))?;
    // Temporary files are private (0600); a finished output is an ordinary file.
    #[cfg(unix)]
    {
        use std::os::unix::fs::PermissionsExt;
        temp.as_file()
            .set_permissions(std::fs::Permissions::from_mode(0o644))
            .map_err(|e| Error::write(path, "cannot set the permissions of", e))?;
    }
    temp.persist(path)
        .map_err(|e| Error::write(path, "cannot move the finished file into place", e.error))?;
    made.keep();
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A seekable sink that takes `room` bytes, then fails like a full disk (ENOSPC).
    struct SmallDisk {
        data: std::io::Cursor<Vec<u8>>,
        room: usize,
    }

    impl Write for SmallDisk {
        fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
            if self.data.get_ref().len() + buf.len() > self.room {
                return Err(std::io::Error::from_raw_os_error(28));
            }
            self.data.write(buf)
        }
        fn flush(&mut self) -> std::io::Result<()> {
            Ok(())
        }
    }

    impl std::io::Seek for SmallDisk {
        fn seek(&mut self, pos: std::io::SeekFrom) -> std::io::Result<u64> {
            self.data.seek(pos)
        }
    }

    #[test]
    fn a_full_disk_under_an_encoder_is_reported_as_a_full_disk() {
        use crate::io::image_file::{BitDepth, ImageKind, encode_image};
        let image = crate::model::Image::filled(64, 64, [0.25, 0.5, 0.75]);
        for kind in [ImageKind::Exr, ImageKind::Png] {
            let mut disk = FirstError::new(SmallDisk {
                data: std::io::Cursor::new(Vec::new()),
                room: 64,
            });
            let wrapped = encode_image(&image, kind, BitDepth::Sixteen, &mut disk).unwrap_err();
            let first = disk.first_error().expect("the sink's error is kept");
            assert_eq!(
                first.kind(),
                std::io::ErrorKind::StorageFull,
                "{kind:?}: {wrapped}"
            );
            let message = Error::write(Path::new("out.img"), "cannot write", first).to_string();
            assert!(message.contains("disk full"), "{message}");
        }
        // Other errors are not called a full disk.
        let denied = std::io::Error::from(std::io::ErrorKind::PermissionDenied);
        let message = Error::write(Path::new("out.img"), "cannot write", denied).to_string();
        assert!(!message.contains("disk full"), "{message}");
    }

    #[test]
    fn writes_whole_files_readable_by_others_and_leaves_nothing_on_failure() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("sub/out.txt");
        write_bytes_atomically(&path, b"hello").unwrap();
        assert_eq!(std::fs::read(&path).unwrap(), b"hello");
        #[cfg(unix)]
        {
            use std::os::unix::fs::PermissionsExt;
            assert_eq!(
                std::fs::metadata(&path).unwrap().permissions().mode() & 0o777,
                0o644
            );
        }
        let failed = write_atomically(&dir.path().join("sub/failed.txt"), |w| {
            w.write_all(b"partial")?;
            Err(std::io::Error::other("the writer failed"))
        });
        assert!(failed.unwrap_err().to_string().contains("failed.txt"));
        let names: Vec<_> = std::fs::read_dir(dir.path().join("sub"))
            .unwrap()
            .map(|e| e.unwrap().file_name())
            .collect();
        assert_eq!(names, ["out.txt"]);
        // A write that fails into folders it made removes them again.
        let failed = write_atomically(&dir.path().join("new/deeper/failed.txt"), |_| {
            Err(std::io::Error::other("the writer failed"))
        });
        assert!(failed.is_err());
        assert!(!dir.path().join("new").exists());
    }
}
