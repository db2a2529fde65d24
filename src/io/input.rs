//! Input files: every file a command reads — scenes, cameras, paths, images, masks, point
//! clouds, COLMAP models, transforms files, glTF models and buffers — is opened here, and
//! must be a regular file (symbolic links followed). A FIFO, socket, device or folder
//! named where a file is read is refused at once, naming it: reading a FIFO waits for a
//! writer that may never come, and a device may never end.
//!
//! The path is checked before it is opened (a device is never opened), and the opened
//! descriptor again: it is opened without waiting (`O_NONBLOCK` on Linux, which opens a
//! FIFO at once and changes nothing for a regular file), so that a file replaced by a FIFO
//! between the check and the open cannot block the open either.

use std::fs::{File, Metadata};
use std::io::Read;
use std::path::Path;

use crate::model::{Error, Result};

/// What `metadata` (of a path, links followed) is when it is not a regular file: "a FIFO
/// (named pipe)", "a socket", "a character device", "a block device", "a folder"; `None`
/// for a regular file.
#[must_use]
pub fn kind_of(metadata: &Metadata) -> Option<&'static str> {
    let kind = metadata.file_type();
    if kind.is_file() {
        return None;
    }
    if kind.is_dir() {
        return Some("a folder");
    }
    #[cfg(unix)]
    {
        use std::os::unix::fs::FileTypeExt;
        if kind.is_fifo() {
            return Some("a FIFO (named pipe)");
        }
        if kind.is_socket() {
            return Some("a socket");
        }
        if kind.is_char_device() {
            return Some("a character device");
        }
        if kind.is_block_device() {
            return Some("a block device");
        }
    }
    Some("not a regular file")
}

/// What `path` is when it exists (links followed) and is not a regular file (see
/// [`kind_of`]); `None` for a regular file and for a path that does not exist.
#[must_use]
pub fn special_kind(path: &Path) -> Option<&'static str> {
    std::fs::metadata(path).ok().and_then(|m| kind_of(&m))
}

/// The sentence refusing a file that is `kind`.
#[must_use]
pub fn not_regular(kind: &str) -> String {
    format!("{kind}, not a regular file (refused: reading it could wait forever)")
}

/// Opens the input file `path` for reading. `message` says what was being read, as in
/// [`Error::read`] ("cannot read scene"): an error that cannot open it is a read error
/// with it; a path that is not a regular file is refused naming what it is.
pub fn open(path: &Path, message: &str) -> Result<File> {
    let refuse = |kind: &str| {
        Error::malformed(
            &path.display().to_string(),
            format!("{message}: {}", not_regular(kind)),
        )
    };
    let metadata = std::fs::metadata(path).map_err(|e| Error::read(path, message, e))?;
    if let Some(kind) = kind_of(&metadata) {
        return Err(refuse(kind));
    }
    let mut options = std::fs::OpenOptions::new();
    options.read(true);
    #[cfg(target_os = "linux")]
    {
        use std::os::unix::fs::OpenOptionsExt;
        options.custom_flags(libc::O_NONBLOCK);
    }
    let file = options
        .open(path)
        .map_err(|e| Error::read(path, message, e))?;
    let metadata = file.metadata().map_err(|e| Error::read(path, message, e))?;
    if let Some(kind) = kind_of(&metadata) {
        return Err(refuse(kind));
    }
    Ok(file)
}

/// The whole of the input file `path` ([`open`]).
pub fn read(path: &Path, message: &str) -> Result<Vec<u8>> {
    let mut file = open(path, message)?;
    // Room for the whole file at once (its length as opened; it may still change).
    let length = file.metadata().map_or(0, |m| m.len());
    let mut bytes = Vec::with_capacity(usize::try_from(length).unwrap_or(0));
    file.read_to_end(&mut bytes)
        .map_err(|e| Error::read(path, message, e))?;
    Ok(bytes)
}

/// The whole of the input file `path` as UTF-8 text ([`open`]).
pub fn read_to_string(path: &Path, message: &str) -> Result<String> {
    String::from_utf8(read(path, message)?).map_err(|_| {
        Error::read(
            path,
            message,
            std::io::Error::new(
                std::io::ErrorKind::InvalidData,
                "stream did not contain valid UTF-8",
            ),
        )
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[cfg(unix)]
    #[test]
    fn fifos_and_folders_are_refused_without_blocking_and_files_read() {
        let dir = tempfile::tempdir().unwrap();
        let fifo = dir.path().join("pipe.json");
        let status = std::process::Command::new("mkfifo")
            .arg(&fifo)
            .status()
            .unwrap();
        assert!(status.success());
        // A link to the FIFO is followed to it.
        let link = dir.path().join("link.json");
        std::os::unix::fs::symlink(&fifo, &link).unwrap();
        for path in [&fifo, &link] {
            let error = read(path, "cannot read scene").unwrap_err();
            let message = error.to_string();
            assert!(message.contains("a FIFO (named pipe)"), "{message}");
            assert!(message.contains("pipe.json") || message.contains("link.json"));
            assert_eq!(error.kind(), crate::model::ErrorKind::Input);
        }
        let message = read(dir.path(), "cannot read").unwrap_err().to_string();
        assert!(message.contains("a folder"), "{message}");
        let file = dir.path().join("a.txt");
        std::fs::write(&file, "héllo").unwrap();
        assert_eq!(read_to_string(&file, "cannot read").unwrap(), "héllo");
        std::fs::write(&file, [0xff, 0xfe]).unwrap();
        assert!(read_to_string(&file, "cannot read").is_err());
        assert!(special_kind(&dir.path().join("missing")).is_none());
        assert_eq!(special_kind(&fifo), Some("a FIFO (named pipe)"));
    }
}
