//! A checked reader of the one NumPy file layout datasets ship camera rigs in: a 2-D array
//! of floats (`.npy` format versions 1 to 3; `descr` `<f8`, `>f8`, `<f4` or `>f4`; C or
//! Fortran order). The header is read as the few keys it must hold, the data's length is
//! checked against the shape before anything is allocated, and the file's size is bounded:
//! a lying header is an error naming the file, the item and the field, never a panic.

use std::path::Path;

use crate::model::error::{Error, Result};

/// Largest `.npy` file read (a rig of a million cameras is 136 MB; a camera file larger
/// than this is not one).
pub const MAX_NPY_BYTES: u64 = 1 << 28;

/// The magic string every `.npy` file opens with.
const MAGIC: &[u8] = b"\x93NUMPY";

/// A 2-D array of `f64`, row-major.
#[derive(Clone, Debug, PartialEq)]
pub struct Array2 {
    pub rows: usize,
    pub cols: usize,
    pub values: Vec<f64>,
}

impl Array2 {
    /// Row `r`.
    pub fn row(&self, r: usize) -> &[f64] {
        &self.values[r * self.cols..(r + 1) * self.cols]
    }
}

/// Reads the 2-D float array in the `.npy` file `path`.
pub fn read_npy(path: &Path) -> Result<Array2> {
    let origin = path.display().to_string();
    let size = std::fs::metadata(path)
        .map_err(|e| Error::read(path, "cannot open", e))?
        .len();
    if size > MAX_NPY_BYTES {
        return Err(Error::invalid(
            &origin,
            "file",
            "size",
            format!("{size} bytes, more than the {MAX_NPY_BYTES} a camera file may hold"),
        ));
    }
    let bytes = std::fs::read(path).map_err(|e| Error::read(path, "cannot read", e))?;
    parse_npy(&bytes, &origin)
}

/// The array in the bytes of a `.npy` file; `origin` names it in errors.
pub fn parse_npy(bytes: &[u8], origin: &str) -> Result<Array2> {
    let bad = |field: &str, message: String| Error::invalid(origin, "header", field, message);
    if bytes.len() < 10 || &bytes[..6] != MAGIC {
        return Err(bad(
            "magic",
            "not a NumPy .npy file (it does not open with \\x93NUMPY)".into(),
        ));
    }
    let (header_len, start) = match bytes[6] {
        1 => (
            usize::from(u16::from_le_bytes([bytes[8], bytes[9]])),
            10_usize,
        ),
        2 | 3 if bytes.len() >= 12 => {
            let len = u32::from_le_bytes([bytes[8], bytes[9], bytes[10], bytes[11]]);
            (usize::try_from(len).unwrap_or(usize::MAX), 12)
        }
        v => {
            return Err(bad(
                "version",
                format!("format version {v} is not 1, 2 or 3"),
            ));
        }
    };
    let Some(data) = bytes.get(start.saturating_add(header_len)..) else {
        return Err(bad(
            "header_len",
            format!(
                "the header says it is {header_len} bytes but the file has {} after the preamble",
                bytes.len() - start
            ),
        ));
    };
    let header = std::str::from_utf8(&bytes[start..start + header_len])
        .map_err(|_| bad("header", "the header is not text".into()))?;
    let descr = quoted_value(header, "descr").ok_or_else(|| bad("descr", missing("descr")))?;
    let (big_endian, width) = match descr {
        "<f8" => (false, 8),
        ">f8" => (true, 8),
        "<f4" => (false, 4),
        ">f4" => (true, 4),
        other => {
            return Err(bad(
                "descr",
                format!("dtype `{other}`: only 64- and 32-bit floats are read (<f8, <f4)"),
            ));
        }
    };
    let fortran = match raw_value(header, "fortran_order") {
        Some(v) if v.starts_with("False") => false,
        Some(v) if v.starts_with("True") => true,
        _ => return Err(bad("fortran_order", missing("fortran_order"))),
    };
    let (rows, cols) = shape(header).map_err(|message| bad("shape", message))?;
    let count = rows.checked_mul(cols);
    let expected = count.and_then(|c| c.checked_mul(width));
    if expected != Some(data.len()) {
        return Err(Error::invalid(
            origin,
            "data",
            "shape",
            format!(
                "shape ({rows}, {cols}) of {width}-byte floats needs {} bytes, the file holds {}",
                expected.map_or_else(|| "more than usize".to_string(), |e| e.to_string()),
                data.len()
            ),
        ));
    }
    let value = |i: usize| -> f64 {
        let b = &data[i * width..(i + 1) * width];
        match (width, big_endian) {
            (8, false) => f64::from_le_bytes(b.try_into().expect("8 bytes")),
            (8, true) => f64::from_be_bytes(b.try_into().expect("8 bytes")),
            (_, false) => f64::from(f32::from_le_bytes(b.try_into().expect("4 bytes"))),
            (_, true) => f64::from(f32::from_be_bytes(b.try_into().expect("4 bytes"))),
        }
    };
    let mut values = Vec::with_capacity(rows * cols);
    for r in 0..rows {
        for c in 0..cols {
            values.push(value(if fortran { c * rows + r } else { r * cols + c }));
        }
    }
    Ok(Array2 { rows, cols, values })
}

fn missing(key: &str) -> String {
    format!("the header has no `{key}`")
}

/// What follows `'key':` in the header dict, spaces skipped.
fn raw_value<'a>(header: &'a str, key: &str) -> Option<&'a str> {
    let at = header.find(&format!("'{key}'"))? + key.len() + 2;
    let rest = header[at..].trim_start().strip_prefix(':')?;
    Some(rest.trim_start())
}

/// The quoted string value of `key`.
fn quoted_value<'a>(header: &'a str, key: &str) -> Option<&'a str> {
    let rest = raw_value(header, key)?;
    let quote = rest.chars().next().filter(|&c| c == '\'' || c == '"')?;
    let rest = &rest[1..];
    rest.find(quote).map(|end| &rest[..end])
}

/// The header's `shape`, which must be a 2-tuple of whole numbers.
fn shape(header: &str) -> std::result::Result<(usize, usize), String> {
    let rest = raw_value(header, "shape").ok_or_else(|| missing("shape"))?;
    let inner = rest
        .strip_prefix('(')
        .and_then(|r| r.find(')').map(|end| &r[..end]))
        .ok_or_else(|| "`shape` is not a tuple".to_string())?;
    let dims: Vec<&str> = inner
        .split(',')
        .map(str::trim)
        .filter(|s| !s.is_empty())
        .collect();
    let parse = |s: &str| {
        s.trim_end_matches('L')
            .parse::<usize>()
            .map_err(|_| format!("`shape` ({inner}): `{s}` is not a whole number"))
    };
    match dims.as_slice() {
        [rows, cols] => Ok((parse(rows)?, parse(cols)?)),
        _ => Err(format!(
            "`shape` ({inner}) has {} dimensions, not 2",
            dims.len()
        )),
    }
}

#[cfg(test)]
/// The bytes of a `.npy` file (version 1, `<f8`, C order) holding `values` as a
/// `rows × cols` array: what `numpy.save` writes.
pub fn npy_bytes(rows: usize, cols: usize, values: &[f64]) -> Vec<u8> {
    let mut header =
        format!("{{'descr': '<f8', 'fortran_order': False, 'shape': ({rows}, {cols}), }}");
    // The preamble and header are padded with spaces to a multiple of 64, ending in '\n'.
    while (10 + header.len() + 1) % 64 != 0 {
        header.push(' ');
    }
    header.push('\n');
    let mut bytes = MAGIC.to_vec();
    bytes.extend([1, 0]);
    bytes.extend(
        u16::try_from(header.len())
            .unwrap_or(u16::MAX)
            .to_le_bytes(),
    );
    bytes.extend(header.as_bytes());
    for v in values {
        bytes.extend(v.to_le_bytes());
    }
    bytes
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn reads_what_it_writes_and_refuses_lying_headers() {
        let values: Vec<f64> = (0..34).map(|i| f64::from(i) * 0.5).collect();
        let bytes = npy_bytes(2, 17, &values);
        assert_eq!(bytes.len() % 16, 0);
        let array = parse_npy(&bytes, "p.npy").unwrap();
        assert_eq!((array.rows, array.cols), (2, 17));
        assert_eq!(array.values, values);
        // Shorter data than the shape says, a huge shape, a header longer than the file.
        for cut in [1, 8, 200] {
            let short = &bytes[..bytes.len() - cut];
            assert!(parse_npy(short, "p.npy").is_err());
        }
        let huge = replace(&bytes, b"(2, 17)", b"(9999999999999, 17)");
        let err = parse_npy(&huge, "p.npy").unwrap_err().to_string();
        assert!(err.contains("shape"), "{err}");
        let mut long = bytes.clone();
        long[8] = 0xff;
        long[9] = 0xff;
        let err = parse_npy(&long, "p.npy").unwrap_err().to_string();
        assert!(err.contains("p.npy"), "{err}");
        let int = replace(&bytes, b"<f8", b"<i8");
        let err = parse_npy(&int, "p.npy").unwrap_err().to_string();
        assert!(err.contains("descr"), "{err}");
        let three = replace(&bytes, b"(2, 17)", b"(2,17,1)");
        let err = parse_npy(&three, "p.npy").unwrap_err().to_string();
        assert!(err.contains("3 dimensions"), "{err}");
    }

    /// `bytes` with the first `from` replaced by `to`.
    fn replace(bytes: &[u8], from: &[u8], to: &[u8]) -> Vec<u8> {
        let at = bytes.windows(from.len()).position(|w| w == from).unwrap();
        [&bytes[..at], to, &bytes[at + from.len()..]].concat()
    }
}
