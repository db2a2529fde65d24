//! Outputs shared by several runs of one command (`--shard I/N`, a batch scheduler's array
//! job) and put together by one more (`--assemble`), under the one output rule
//! ([`super::output`]).
//!
//! - Shard `I/N` writes the frames `k` with `k mod N = I` into the folder one run writes
//!   (a video's frame folder, a sequence's or a dataset's folder), each frame staged and then
//!   moved into place, and records them in its own marker `.splat4d-shard-I-of-N`: the
//!   command and the shard (`video shard 0/4`), a fingerprint of what the frames depend on (the scene file's
//!   bytes, the cameras and times, the options), and each frame's [`Stamp`]. It never removes
//!   another shard's frames, so shards run side by side into one folder.
//! - A shard writes into a folder only when every file in it is recorded by a marker of the
//!   command (the single run's [`MARKER`] or a shard's); anything else is refused before any
//!   work, as a single run refuses a folder it did not write.
//! - `--assemble` takes every frame from a shard marker of the same fingerprint whose stamp
//!   the frame still has (a frame missing, or left by a run of other settings, is refused
//!   naming its file), removes what is not one of its frames (earlier frames, the shard
//!   markers), writes what a single run writes beyond the frames (the GIF, MP4 and camera
//!   path; a sequence's index; a dataset's `transforms_*.json`) and the folder's [`MARKER`]:
//!   the same files as a single run, byte for byte.

use std::collections::BTreeMap;
use std::path::Path;
use std::str::FromStr;

use crate::io::output::{MARKER, Stamp, listing};
use crate::model::{Error, Result};

/// Shard `index` of `count`: the frames `k` with `k mod count = index`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Shard {
    /// From 0 to `count - 1`.
    pub index: usize,
    /// At least 1.
    pub count: usize,
}

impl Shard {
    /// Whether frame `k` is this shard's.
    #[must_use]
    pub fn takes(&self, k: usize) -> bool {
        k % self.count == self.index
    }

    /// The name of this shard's marker in the folder it writes into.
    #[must_use]
    pub fn marker_name(&self) -> String {
        format!("{SHARD_MARKER_PREFIX}{}-of-{}", self.index, self.count)
    }
}

impl FromStr for Shard {
    type Err = String;

    /// `I/N` with `0 ≤ I < N`.
    fn from_str(text: &str) -> std::result::Result<Self, String> {
        let Some((i, n)) = text.split_once('/') else {
            return Err(format!(
                "`{}` is not `I/N` (shard I of N, e.g. 0/4)",
                crate::model::error::cut(text, crate::model::error::MAX_QUOTE)
            ));
        };
        let parse = |part: &str, what: &str| {
            part.trim().parse::<usize>().map_err(|_| {
                format!(
                    "{what} `{}` of `I/N` is not a whole number",
                    crate::model::error::cut(part, crate::model::error::MAX_QUOTE)
                )
            })
        };
        let (index, count) = (parse(i, "I")?, parse(n, "N")?);
        if count == 0 {
            return Err("N of `I/N` must be at least 1".into());
        }
        if index >= count {
            return Err(format!(
                "I = {index} of `I/N` must be below N = {count} (shards 0 to {})",
                count - 1
            ));
        }
        Ok(Shard { index, count })
    }
}

/// How a run shares its frames with other runs of the same command.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Sharding {
    /// One run writes everything.
    #[default]
    Whole,
    /// Only this shard's frames.
    Shard(Shard),
    /// Everything beyond the frames, from the frames the shards wrote.
    Assemble,
}

impl Sharding {
    /// Whether frame `k` is rendered by this run.
    #[must_use]
    pub fn renders(&self, k: usize) -> bool {
        match self {
            Sharding::Whole => true,
            Sharding::Shard(shard) => shard.takes(k),
            Sharding::Assemble => false,
        }
    }
}

/// The name prefix of a shard's marker (`.splat4d-shard-I-of-N`).
pub const SHARD_MARKER_PREFIX: &str = ".splat4d-shard-";

/// A fingerprint of what a shard's frames depend on: FNV-1a (64 bits) over `parts`, in hex.
#[must_use]
pub fn fingerprint(parts: &[&[u8]]) -> String {
    let mut hash: u64 = 0xcbf2_9ce4_8422_2325;
    for part in parts {
        for &byte in part.iter().chain(&[0xff]) {
            hash ^= u64::from(byte);
            hash = hash.wrapping_mul(0x0100_0000_01b3);
        }
    }
    format!("{hash:016x}")
}

/// A shard marker: its first line, its fingerprint, and the files it records (with their
/// stamps once moved into place).
struct ShardMarker {
    header: String,
    fingerprint: String,
    files: BTreeMap<String, Option<Stamp>>,
}

impl ShardMarker {
    fn read(path: &Path) -> Option<ShardMarker> {
        let text = std::fs::read_to_string(path).ok()?;
        let mut lines = text.lines();
        let header = lines.next()?.to_string();
        let fingerprint = lines.next()?.strip_prefix("fingerprint ")?.to_string();
        let files = lines
            .map(|line| match line.split_once('\t') {
                Some((name, stamp)) => (name.to_string(), Stamp::from_fields(stamp)),
                None => (line.to_string(), None),
            })
            .collect();
        Some(ShardMarker {
            header,
            fingerprint,
            files,
        })
    }

    fn write(&self, path: &Path) -> Result<()> {
        let mut text = format!("{}\nfingerprint {}\n", self.header, self.fingerprint);
        for (name, stamp) in &self.files {
            text.push_str(name);
            if let Some(stamp) = stamp {
                text.push('\t');
                text.push_str(&stamp.to_fields());
            }
            text.push('\n');
        }
        super::write_bytes_atomically(path, text.as_bytes())
    }
}

/// The shard markers of `command` in `dir`, by file name.
fn shard_markers(dir: &Path, command: &str) -> BTreeMap<String, ShardMarker> {
    let Ok(entries) = std::fs::read_dir(dir) else {
        return BTreeMap::new();
    };
    entries
        .filter_map(|e| e.ok())
        .map(|e| e.file_name().to_string_lossy().into_owned())
        .filter(|name| name.starts_with(SHARD_MARKER_PREFIX))
        .filter_map(|name| {
            let marker = ShardMarker::read(&dir.join(&name))?;
            let ours = marker
                .header
                .strip_prefix(command)
                .is_some_and(|rest| rest.starts_with(" shard "));
            ours.then_some((name, marker))
        })
        .collect()
}

/// The files of `dir` (relative, `/`-separated): neither folders, nor markers, nor the
/// temporaries of runs under way.
fn present_files(dir: &Path) -> Result<Vec<String>> {
    let present = listing(dir).ok_or_else(|| {
        Error::usage(format!(
            "{}: cannot be listed; name a folder splat4d may read",
            dir.display()
        ))
    })?;
    Ok(present
        .into_iter()
        .filter(|p| !p.starts_with(super::TEMP_PREFIX))
        .filter(|p| p != MARKER && !p.starts_with(SHARD_MARKER_PREFIX))
        .filter(|p| std::fs::symlink_metadata(dir.join(p)).is_ok_and(|m| !m.file_type().is_dir()))
        .collect())
}

/// The files `dir`'s markers of `command` record: its [`MARKER`] (when it names
/// `command`) and its shard markers.
fn recorded_files(dir: &Path, command: &str) -> Vec<String> {
    let mut recorded: Vec<String> = Vec::new();
    if let Ok(marker) = std::fs::read_to_string(dir.join(MARKER)) {
        let mut lines = marker.lines();
        if lines.next().map(str::trim) == Some(command) {
            recorded.extend(lines.map(String::from));
        }
    }
    for marker in shard_markers(dir, command).into_values() {
        recorded.extend(marker.files.into_keys());
    }
    recorded
}

/// Refuses, before any work, a folder `dir` that runs of `command` sharing its frames may
/// not write into: one that is not a folder, or holds a file no marker of `command` in it
/// records (the user's, or another command's).
pub fn check_shared_folder(dir: &Path, command: &str) -> Result<()> {
    match std::fs::symlink_metadata(dir) {
        Err(_) => return Ok(()),
        Ok(meta) if !meta.is_dir() => {
            return Err(Error::usage(format!(
                "{}: exists and is not a folder; name a new folder for the output",
                dir.display()
            )));
        }
        Ok(_) => {}
    }
    if let Ok(marker) = std::fs::read_to_string(dir.join(MARKER))
        && marker.lines().next().map(str::trim) != Some(command)
    {
        return Err(Error::usage(format!(
            "{}: was not written by `splat4d {command}` (its {MARKER} names another command), so it is not written into; name a new folder, or move that one away yourself",
            dir.display()
        )));
    }
    let recorded = recorded_files(dir, command);
    if let Some(extra) = present_files(dir)?
        .into_iter()
        .find(|p| !recorded.contains(p))
    {
        return Err(Error::usage(format!(
            "{}: holds {}, which `splat4d {command}` did not write there, so it is not written into; name a new folder, or move that one away yourself",
            dir.display(),
            super::json::cut(&extra)
        )));
    }
    Ok(())
}

/// Moves the files `names` (relative paths) staged in `staged` into `dir`, as shard `shard`
/// of `command` with `fingerprint`, and records them in the shard's marker. The frames this
/// shard's earlier marker recorded that it does not write again, and no other marker
/// records, are removed (they were this shard's, and would pass for frames of this run).
/// The marker lists the names before the first move (so that a shard starting meanwhile
/// finds every file recorded) and their stamps after the last.
pub fn commit_shard(
    staged: &Path,
    dir: &Path,
    command: &str,
    shard: Shard,
    fingerprint: &str,
    names: &[String],
) -> Result<()> {
    std::fs::create_dir_all(dir)
        .map_err(|e| Error::write(dir, "cannot create the output folder", e))?;
    let marker_path = dir.join(shard.marker_name());
    let earlier = ShardMarker::read(&marker_path);
    let mut marker = ShardMarker {
        header: format!("{command} shard {}/{}", shard.index, shard.count),
        fingerprint: fingerprint.to_string(),
        files: names.iter().map(|n| (n.clone(), None)).collect(),
    };
    if let Some(earlier) = earlier {
        let mut others = BTreeMap::new();
        for (name, other) in shard_markers(dir, command) {
            if name != shard.marker_name() {
                others.extend(other.files);
            }
        }
        let mut kept: Vec<String> = recorded_files_main(dir, command);
        kept.extend(others.into_keys());
        for name in earlier.files.into_keys() {
            if !marker.files.contains_key(&name) && !kept.contains(&name) {
                let path = dir.join(&name);
                if std::fs::symlink_metadata(&path).is_ok() {
                    std::fs::remove_file(&path).map_err(|e| {
                        Error::write(&path, "cannot remove the shard's earlier frame", e)
                    })?;
                }
            }
        }
    }
    marker.write(&marker_path)?;
    for name in names {
        let target = dir.join(name);
        if let Some(parent) = target.parent() {
            std::fs::create_dir_all(parent)
                .map_err(|e| Error::write(parent, "cannot create the output folder", e))?;
        }
        std::fs::rename(staged.join(name), &target)
            .map_err(|e| Error::write(&target, "cannot move the output into place", e))?;
    }
    for (name, stamp) in &mut marker.files {
        *stamp = Stamp::of(&dir.join(name));
    }
    marker.write(&marker_path)
}

/// The files the single run's [`MARKER`] of `command` in `dir` records.
fn recorded_files_main(dir: &Path, command: &str) -> Vec<String> {
    let Ok(marker) = std::fs::read_to_string(dir.join(MARKER)) else {
        return Vec::new();
    };
    let mut lines = marker.lines();
    if lines.next().map(str::trim) != Some(command) {
        return Vec::new();
    }
    lines.map(String::from).collect()
}

/// Checks, before `--assemble` writes anything, that every file of `names` is in `dir` as a
/// shard of `command` with `fingerprint` wrote it (its stamp unchanged): a missing one is
/// refused naming it. `dir` must hold nothing the command's markers do not record.
pub fn check_assembled(
    dir: &Path,
    command: &str,
    fingerprint: &str,
    names: &[String],
) -> Result<()> {
    if !dir.is_dir() {
        return Err(Error::usage(format!(
            "{}: missing: `assemble` puts together the frames written by the `shard` runs of `splat4d {command}` with the same settings; run them first",
            dir.display()
        )));
    }
    check_shared_folder(dir, command)?;
    let mut written: BTreeMap<String, Stamp> = BTreeMap::new();
    for marker in shard_markers(dir, command).into_values() {
        if marker.fingerprint == fingerprint {
            written.extend(
                marker
                    .files
                    .into_iter()
                    .filter_map(|(name, stamp)| Some((name, stamp?))),
            );
        }
    }
    for name in names {
        let path = dir.join(name);
        let stamp = Stamp::of(&path);
        if stamp.is_none() || stamp != written.get(name).copied() {
            let why = if stamp.is_none() {
                "missing"
            } else {
                "not written by a `shard` run of these settings (or changed since)"
            };
            return Err(Error::usage(format!(
                "{}: {why}: `assemble` needs every frame written by the `shard` runs of `splat4d {command}` with the same settings (run the missing shard)",
                path.display()
            )));
        }
    }
    Ok(())
}

/// Removes from `dir` the files that are not among `names` (checked by
/// [`check_assembled`]: earlier frames of the command) and folders left empty; the markers
/// stay until [`drop_shard_markers`].
pub fn keep_only(dir: &Path, names: &[String]) -> Result<()> {
    for file in present_files(dir)? {
        if !names.contains(&file) {
            let path = dir.join(file);
            std::fs::remove_file(&path)
                .map_err(|e| Error::write(&path, "cannot remove the earlier frame", e))?;
        }
    }
    let Ok(entries) = std::fs::read_dir(dir) else {
        return Ok(());
    };
    for entry in entries.filter_map(|e| e.ok()) {
        let name = entry.file_name().to_string_lossy().into_owned();
        if entry.file_type().is_ok_and(|t| t.is_dir())
            && !name.starts_with(super::TEMP_PREFIX)
            && !names.iter().any(|n| n.starts_with(&format!("{name}/")))
        {
            // A folder of earlier frames only: empty by now.
            let _ = std::fs::remove_dir(entry.path());
        }
    }
    Ok(())
}

/// Removes the shard markers of `dir`, once what they record is assembled (the folder's
/// [`MARKER`] is written next).
pub fn drop_shard_markers(dir: &Path) -> Result<()> {
    let Ok(entries) = std::fs::read_dir(dir) else {
        return Ok(());
    };
    for entry in entries.filter_map(|e| e.ok()) {
        if entry
            .file_name()
            .to_string_lossy()
            .starts_with(SHARD_MARKER_PREFIX)
        {
            let path = entry.path();
            std::fs::remove_file(&path)
                .map_err(|e| Error::write(&path, "cannot remove the shard's marker", e))?;
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn shards_parse_and_split_the_frames() {
        let shard: Shard = "1/3".parse().unwrap();
        assert_eq!(shard, Shard { index: 1, count: 3 });
        let taken: Vec<usize> = (0..8).filter(|&k| shard.takes(k)).collect();
        assert_eq!(taken, [1, 4, 7]);
        for bad in ["3/3", "0/0", "1", "a/2", "1/b", "-1/2", ""] {
            assert!(bad.parse::<Shard>().is_err(), "{bad}");
        }
        assert_ne!(fingerprint(&[b"ab", b"c"]), fingerprint(&[b"a", b"bc"]));
    }

    #[test]
    fn shards_share_a_folder_and_assemble_refuses_a_missing_frame() {
        let dir = tempfile::tempdir().unwrap();
        let out = dir.path().join("frames");
        let names: Vec<String> = (0..4).map(|k| format!("f{k}")).collect();
        for index in [0, 1] {
            let shard = Shard { index, count: 2 };
            check_shared_folder(&out, "video").unwrap();
            let staged = tempfile::tempdir().unwrap();
            let mine: Vec<String> = (0..4)
                .filter(|&k| shard.takes(k))
                .map(|k| names[k].clone())
                .collect();
            for name in &mine {
                std::fs::write(staged.path().join(name), name).unwrap();
            }
            if index == 1 {
                let missing = check_assembled(&out, "video", "x", &names).unwrap_err();
                assert!(missing.to_string().contains("f1: missing"), "{missing}");
            }
            commit_shard(staged.path(), &out, "video", shard, "x", &mine).unwrap();
        }
        check_assembled(&out, "video", "x", &names).unwrap();
        assert!(check_assembled(&out, "video", "y", &names).is_err());
        // A file of the user's: refused.
        std::fs::write(out.join("notes.txt"), "mine").unwrap();
        assert!(check_shared_folder(&out, "video").is_err());
        std::fs::remove_file(out.join("notes.txt")).unwrap();
        keep_only(&out, &names[..3]).unwrap();
        drop_shard_markers(&out).unwrap();
        let mut left: Vec<_> = std::fs::read_dir(&out)
            .unwrap()
            .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
            .collect();
        left.sort();
        assert_eq!(left, ["f0", "f1", "f2"]);
    }
}
