//! A glTF's buffers, read: the GLB binary chunk, `data:` URIs (base64), and files beside
//! the model (never outside its folder, never a device or a pipe).

use std::path::{Path, PathBuf};

use base64::Engine;

use crate::model::error::{Error, Result};

/// Every buffer of `document` (the model at `path`), at least as long as it declares.
pub(super) fn load_buffers(document: &gltf::Gltf, path: &Path) -> Result<Vec<Vec<u8>>> {
    let origin = path.display().to_string();
    let dir = path.parent().unwrap_or(Path::new("."));
    document
        .buffers()
        .map(|buffer| {
            let item = format!("buffer {}", buffer.index());
            let data = match buffer.source() {
                gltf::buffer::Source::Bin => document.blob.clone().ok_or_else(|| {
                    Error::invalid(
                        &origin,
                        &item,
                        "uri",
                        "refers to the GLB binary chunk, which is missing",
                    )
                })?,
                gltf::buffer::Source::Uri(uri) if uri.starts_with("data:") => {
                    let (_, encoded) = uri.split_once(',').ok_or_else(|| {
                        Error::invalid(&origin, &item, "uri", "a data URI without a comma")
                    })?;
                    base64::engine::general_purpose::STANDARD
                        .decode(encoded)
                        .map_err(|e| {
                            Error::invalid(&origin, &item, "uri", format!("bad base64: {e}"))
                        })?
                }
                gltf::buffer::Source::Uri(uri) => {
                    let file = buffer_file(dir, uri, &origin, &item)?;
                    read_at_most(
                        &file,
                        buffer.length() as u64,
                        &format!("{origin}: {item}: cannot read"),
                    )?
                }
            };
            if data.len() < buffer.length() {
                return Err(Error::invalid(
                    &origin,
                    &item,
                    "byteLength",
                    format!("{} bytes declared, {} present", buffer.length(), data.len()),
                ));
            }
            Ok(data)
        })
        .collect()
}

/// The file a buffer `uri` names: relative to the model's folder and inside it (no absolute
/// path, no `..` that leaves it, percent-escapes decoded first), and a regular file (not a
/// device, FIFO or folder), so a model cannot make the importer read `/etc/passwd`,
/// `/dev/zero` or block on a pipe.
fn buffer_file(dir: &Path, uri: &str, origin: &str, item: &str) -> Result<PathBuf> {
    let refuse = |message: String| Error::invalid(origin, item, "uri", message);
    let decoded = percent_decode(uri);
    let relative = Path::new(&decoded);
    let mut depth = 0_i64;
    for part in relative.components() {
        match part {
            std::path::Component::Normal(_) => depth += 1,
            std::path::Component::CurDir => {}
            std::path::Component::ParentDir => depth -= 1,
            _ => {
                return Err(refuse(format!(
                    "{uri}: absolute paths are not read (a buffer must sit beside the model)"
                )));
            }
        }
        if depth < 0 {
            return Err(refuse(format!("{uri}: leaves the model's folder")));
        }
    }
    let file = dir.join(relative);
    let meta = std::fs::metadata(&file)
        .map_err(|e| Error::read(&file, &format!("{origin}: {item}: cannot read"), e))?;
    if let Some(kind) = crate::io::input::kind_of(&meta) {
        return Err(refuse(format!(
            "{uri}: {}",
            crate::io::input::not_regular(kind)
        )));
    }
    // By the real path too: a symlink beside the model may point anywhere.
    if !crate::io::output::inside(&file, dir) {
        return Err(refuse(format!(
            "{uri}: is a link to a file outside the model's folder, which is not read"
        )));
    }
    Ok(file)
}

/// `%XX` escapes of a URI decoded (invalid ones kept as they are).
fn percent_decode(uri: &str) -> String {
    let bytes = uri.as_bytes();
    let mut out = Vec::with_capacity(bytes.len());
    let mut i = 0;
    while i < bytes.len() {
        let hex = |b: u8| (b as char).to_digit(16);
        if bytes[i] == b'%'
            && i + 2 < bytes.len()
            && let (Some(h), Some(l)) = (hex(bytes[i + 1]), hex(bytes[i + 2]))
        {
            out.push((h * 16 + l) as u8);
            i += 3;
            continue;
        }
        out.push(bytes[i]);
        i += 1;
    }
    String::from_utf8_lossy(&out).into_owned()
}

/// The first `limit` bytes of `path` (a buffer's declared `byteLength`): a file longer than
/// its declaration is not read to its end.
fn read_at_most(path: &Path, limit: u64, message: &str) -> Result<Vec<u8>> {
    use std::io::Read;
    let mut data = Vec::new();
    crate::io::input::open(path, message)?
        .take(limit)
        .read_to_end(&mut data)
        .map_err(|e| Error::read(path, message, e))?;
    Ok(data)
}
