//! Files: atomic writes and images. Nothing here knows about the command line.

pub mod dataset;
pub mod gltf_import;
pub mod image_file;
pub mod json;
pub mod ply;
pub mod video;

use std::io::{BufWriter, Write};
use std::path::Path;

use crate::error::{Error, Result};

/// The writer handed to [`write_atomically`]'s closure (buffered, seekable).
pub type AtomicWriter = BufWriter<tempfile::NamedTempFile>;

/// Writes `bytes` to `path` with [`write_atomically`].
pub fn write_bytes_atomically(path: &Path, bytes: &[u8]) -> Result<()> {
    write_atomically(path, |w| w.write_all(bytes))
}

/// Writes a file all at once or not at all: `write` fills a temporary file in the same
/// folder, which is then renamed over `path`. On any error nothing is left at `path` (an
/// existing file there is untouched). Missing parent folders are created.
pub fn write_atomically(
    path: &Path,
    write: impl FnOnce(&mut AtomicWriter) -> std::io::Result<()>,
) -> Result<()> {
    let parent = match path.parent() {
        Some(p) if !p.as_os_str().is_empty() => p,
        _ => Path::new("."),
    };
    std::fs::create_dir_all(parent)
        .map_err(|e| Error::io(parent, "cannot create the output folder", e))?;
    let temp = tempfile::Builder::new()
        .prefix(".splat4d-")
        .tempfile_in(parent)
        .map_err(|e| Error::io(path, "cannot create a temporary file beside the output", e))?;
    let mut writer = BufWriter::new(temp);
    write(&mut writer)
        .and_then(|()| writer.flush())
        .map_err(|e| Error::io(path, "cannot write", e))?;
    let temp = writer
        .into_inner()
        .map_err(|e| Error::io(path, "cannot write", e.into_error()))?;
    // Temporary files are private (0600); a finished output is an ordinary file.
    #[cfg(unix)]
    {
        use std::os::unix::fs::PermissionsExt;
        temp.as_file()
            .set_permissions(std::fs::Permissions::from_mode(0o644))
            .map_err(|e| Error::io(path, "cannot set the permissions of", e))?;
    }
    temp.persist(path)
        .map_err(|e| Error::io(path, "cannot move the finished file into place", e.error))?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

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
    }
}
