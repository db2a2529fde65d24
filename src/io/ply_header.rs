//! The PLY header, read the same way for every PLY the tool reads: 4D scenes and 3DGS files
//! ([`super::ply`]) and dataset point clouds ([`super::point_cloud`]). Each reader then
//! says which of what the header may declare it reads.
//!
//! ```text
//! ply
//! format ascii|binary_little_endian|binary_big_endian VERSION
//! comment TEXT                         (any number, anywhere; `obj_info` lines alike)
//! element NAME COUNT
//! property TYPE NAME                   (a scalar)
//! property list COUNT_TYPE TYPE NAME   (a list: a count, then that many items)
//! ...
//! end_header                           (then `\n` or `\r\n`, and the body)
//! ```
//!
//! Types: `char`/`int8`, `uchar`/`uint8`, `short`/`int16`, `ushort`/`uint16`, `int`/`int32`,
//! `uint`/`uint32`, `float`/`float32`, `double`/`float64`. The header must end within its
//! first 64 KiB ([`MAX_HEADER`]) and be text. A binary body's element counts are checked
//! against the bytes the file has left ([`Header::binary_rows`]) before anything is
//! allocated for them. Errors name the file, and the header line or element.

use crate::model::error::{Error, Result};

/// Longest header read, bytes.
pub const MAX_HEADER: usize = 1 << 16;

/// A scalar PLY type.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Scalar {
    /// `char`, `int8`.
    I8,
    /// `uchar`, `uint8`.
    U8,
    /// `short`, `int16`.
    I16,
    /// `ushort`, `uint16`.
    U16,
    /// `int`, `int32`.
    I32,
    /// `uint`, `uint32`.
    U32,
    /// `float`, `float32`.
    F32,
    /// `double`, `float64`.
    F64,
}

impl Scalar {
    /// The type a header names (`uchar` or `uint8`, ...).
    #[must_use]
    pub fn parse(name: &str) -> Option<Self> {
        Some(match name {
            "char" | "int8" => Scalar::I8,
            "uchar" | "uint8" => Scalar::U8,
            "short" | "int16" => Scalar::I16,
            "ushort" | "uint16" => Scalar::U16,
            "int" | "int32" => Scalar::I32,
            "uint" | "uint32" => Scalar::U32,
            "float" | "float32" => Scalar::F32,
            "double" | "float64" => Scalar::F64,
            _ => return None,
        })
    }

    /// Bytes of one value.
    #[must_use]
    pub fn size(self) -> usize {
        match self {
            Scalar::I8 | Scalar::U8 => 1,
            Scalar::I16 | Scalar::U16 => 2,
            Scalar::I32 | Scalar::U32 | Scalar::F32 => 4,
            Scalar::F64 => 8,
        }
    }

    /// A float type (`float` or `double`).
    #[must_use]
    pub fn is_float(self) -> bool {
        matches!(self, Scalar::F32 | Scalar::F64)
    }

    /// The value of little-endian `b` (of this type's size).
    #[must_use]
    pub fn read_le(self, b: &[u8]) -> f64 {
        match self {
            Scalar::I8 => f64::from(b[0] as i8),
            Scalar::U8 => f64::from(b[0]),
            Scalar::I16 => f64::from(i16::from_le_bytes([b[0], b[1]])),
            Scalar::U16 => f64::from(u16::from_le_bytes([b[0], b[1]])),
            Scalar::I32 => f64::from(i32::from_le_bytes([b[0], b[1], b[2], b[3]])),
            Scalar::U32 => f64::from(u32::from_le_bytes([b[0], b[1], b[2], b[3]])),
            Scalar::F32 => f64::from(f32::from_le_bytes([b[0], b[1], b[2], b[3]])),
            Scalar::F64 => f64::from_le_bytes([b[0], b[1], b[2], b[3], b[4], b[5], b[6], b[7]]),
        }
    }
}

/// One property of an element: a scalar, or a list.
#[derive(Clone, Debug)]
pub struct Property {
    /// Its name (`x`, `red`).
    pub name: String,
    /// The type as the header writes it (`uchar`, `float32`).
    pub kind: String,
    /// The value's type (a list's items').
    pub scalar: Scalar,
    /// A list's count type; `None` for a scalar.
    pub list: Option<Scalar>,
}

/// An element: its name, how many rows, and the properties of a row in order.
#[derive(Clone, Debug)]
pub struct Element {
    /// Its name (`vertex`, `face`).
    pub name: String,
    /// How many rows.
    pub count: usize,
    /// A row's properties, in order.
    pub properties: Vec<Property>,
}

impl Element {
    /// Bytes of one binary row, when it has no list property (a list's length varies).
    #[must_use]
    pub fn row_bytes(&self) -> Option<usize> {
        self.properties
            .iter()
            .map(|p| p.list.is_none().then_some(p.scalar.size()))
            .sum()
    }
}

/// How the body is written.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Encoding {
    /// Rows as lines of numbers.
    Ascii,
    /// Rows as little-endian values.
    BinaryLittleEndian,
    /// Rows as big-endian values.
    BinaryBigEndian,
}

impl Encoding {
    /// The name a `format` line gives it.
    #[must_use]
    pub fn name(self) -> &'static str {
        match self {
            Encoding::Ascii => "ascii",
            Encoding::BinaryLittleEndian => "binary_little_endian",
            Encoding::BinaryBigEndian => "binary_big_endian",
        }
    }
}

/// A PLY header as read.
#[derive(Clone, Debug)]
pub struct Header {
    /// How the body is written.
    pub encoding: Encoding,
    /// The `format` line's version (`1.0`).
    pub version: String,
    /// The `comment` lines' text, in order.
    pub comments: Vec<String>,
    /// The elements, in the order of the body.
    pub elements: Vec<Element>,
    /// Where the body starts in the file, bytes.
    pub body_start: usize,
}

/// Reads the header at the start of `bytes` (which holds at least its first
/// [`MAX_HEADER`] bytes, or the whole file when shorter); `origin` names it in errors.
pub fn read_header(bytes: &[u8], origin: &str) -> Result<Header> {
    let head = &bytes[..bytes.len().min(MAX_HEADER)];
    let marker = b"end_header";
    let end = head
        .windows(marker.len())
        .position(|w| w == marker)
        .ok_or_else(|| bad(origin, "no `end_header` line in its first 64 KiB"))?;
    let mut body_start = end + marker.len();
    if bytes.get(body_start) == Some(&b'\r') {
        body_start += 1;
    }
    if bytes.get(body_start) != Some(&b'\n') {
        return Err(bad(origin, "`end_header` is not followed by a newline"));
    }
    body_start += 1;
    let text =
        std::str::from_utf8(&bytes[..end]).map_err(|_| bad(origin, "the header is not text"))?;
    let mut lines = text.lines().map(str::trim);
    if lines.next() != Some("ply") {
        return Err(bad(origin, "not a PLY file: it does not start with `ply`"));
    }
    let mut header = Header {
        encoding: Encoding::Ascii,
        version: String::new(),
        comments: Vec::new(),
        elements: Vec::new(),
        body_start,
    };
    let mut format_seen = false;
    for (n, line) in lines.enumerate() {
        // Line 1 is `ply`.
        let at = HeaderLine {
            origin,
            number: n + 2,
            line,
        };
        format_seen |= header.read_line(&at)?;
    }
    if !format_seen {
        return Err(bad(origin, "no `format` line"));
    }
    Ok(header)
}

/// The error of a PLY file that is not one.
fn bad(origin: &str, message: &str) -> Error {
    Error::malformed(origin, format!("PLY: {message}"))
}

/// A line of the header, for reading it and naming it in errors.
struct HeaderLine<'a> {
    origin: &'a str,
    /// 1 for `ply`.
    number: usize,
    line: &'a str,
}

impl HeaderLine<'_> {
    fn error(&self, field: &str, message: impl Into<String>) -> Error {
        let item = format!("header line {}", self.number);
        Error::invalid(self.origin, item, field, message)
    }
}

impl Header {
    /// Reads one line after `ply` into the header; whether it was the `format` line.
    fn read_line(&mut self, at: &HeaderLine) -> Result<bool> {
        let words: Vec<&str> = at.line.split_whitespace().collect();
        match words.as_slice() {
            [] | ["obj_info", ..] => {}
            ["comment", ..] => {
                let text = at.line["comment".len()..].trim();
                self.comments.push(text.to_owned());
            }
            ["format", encoding, version] => {
                self.encoding = match *encoding {
                    "ascii" => Encoding::Ascii,
                    "binary_little_endian" => Encoding::BinaryLittleEndian,
                    "binary_big_endian" => Encoding::BinaryBigEndian,
                    other => {
                        let known = "ascii, binary_little_endian or binary_big_endian";
                        return Err(at.error("format", format!("`{other}` is not {known}")));
                    }
                };
                self.version = (*version).to_owned();
                return Ok(true);
            }
            ["element", name, count] => {
                let count = count.parse::<usize>().map_err(|_| {
                    at.error("element", format!("count `{count}` is not a whole number"))
                })?;
                self.elements.push(Element {
                    name: (*name).to_owned(),
                    count,
                    properties: Vec::new(),
                });
            }
            ["property", rest @ ..] => {
                let property = property(rest, at)?;
                self.elements
                    .last_mut()
                    .ok_or_else(|| at.error("property", "a property before any element"))?
                    .properties
                    .push(property);
            }
            _ => {
                let line = at.line;
                return Err(at.error("header", format!("`{line}` is not a PLY header line")));
            }
        }
        Ok(false)
    }

    /// The element named `name`, and its index.
    #[must_use]
    pub fn element(&self, name: &str) -> Option<(usize, &Element)> {
        self.elements
            .iter()
            .enumerate()
            .find(|(_, e)| e.name == name)
    }

    /// Where the rows of element `index` lie in a binary body of `body_bytes`: their offset
    /// and length. The elements before it and it must have rows of a fixed size (no list
    /// properties), and its rows must fit in what the file has left.
    pub fn binary_rows(&self, index: usize, body_bytes: u64, origin: &str) -> Result<(u64, u64)> {
        let mut offset = 0_u64;
        for element in &self.elements[..index] {
            offset += element.binary_bytes(body_bytes - offset, origin)?;
        }
        let bytes = self.elements[index].binary_bytes(body_bytes - offset, origin)?;
        Ok((offset, bytes))
    }
}

impl Element {
    /// Bytes of its binary rows, which must fit in the `left` bytes of the body.
    fn binary_bytes(&self, left: u64, origin: &str) -> Result<u64> {
        let (item, count) = (format!("element {}", self.name), self.count);
        let size = self.row_bytes().ok_or_else(|| {
            let message = "binary rows with list properties are not read here";
            Error::invalid(origin, &item, "property", message)
        })?;
        let bytes = (count as u64).checked_mul(size as u64).ok_or_else(|| {
            let message = format!("{count} rows of {size} bytes overflow");
            Error::invalid(origin, &item, "count", message)
        })?;
        if bytes > left {
            let message = format!(
                "{count} rows of {size} bytes need {bytes} bytes of data, more than the {left} the file has left"
            );
            return Err(Error::invalid(origin, &item, "count", message));
        }
        Ok(bytes)
    }
}

/// The property of a `property` line's words after `property`.
fn property(words: &[&str], at: &HeaderLine) -> Result<Property> {
    let scalar = |kind: &str| {
        Scalar::parse(kind).ok_or_else(|| {
            at.error(
                "property",
                format!("type `{kind}` is not a PLY type (char, uchar, short, ushort, int, uint, float, double)"),
            )
        })
    };
    match words {
        ["list", count, item, name] => Ok(Property {
            name: (*name).to_owned(),
            kind: (*item).to_owned(),
            scalar: scalar(item)?,
            list: Some(scalar(count)?),
        }),
        [kind, name] => Ok(Property {
            name: (*name).to_owned(),
            kind: (*kind).to_owned(),
            scalar: scalar(kind)?,
            list: None,
        }),
        _ => {
            let line = at.line;
            Err(at.error("property", format!("`{line}` is not a PLY property")))
        }
    }
}
