//! Point clouds shipped with a dataset as PLY (nerfstudio's `ply_file_path`, COLMAP exports):
//! `element vertex N` with `x y z` (any numeric type) and `red green blue` (`uchar`/`uint8`
//! read as `v / 255`, `ushort`/`uint16` as `v / 65535`, `float`/`double` as they are), in
//! `ascii` or `binary_little_endian`. Other properties are ignored; other elements may come
//! before the vertices when their properties are scalars (and after them, anything).
//!
//! Every count is checked against the bytes the file has left before anything is allocated
//! for it; errors name the file, the vertex and the property.

use std::path::Path;

use crate::model::error::{Error, Result};
use crate::model::view::DatasetPoint;

/// Longest header read, bytes.
const MAX_HEADER: usize = 1 << 16;

/// A scalar PLY type.
#[derive(Clone, Copy, Debug, PartialEq)]
enum Scalar {
    I8,
    U8,
    I16,
    U16,
    I32,
    U32,
    F32,
    F64,
}

impl Scalar {
    fn parse(name: &str) -> Option<Self> {
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

    fn size(self) -> usize {
        match self {
            Scalar::I8 | Scalar::U8 => 1,
            Scalar::I16 | Scalar::U16 => 2,
            Scalar::I32 | Scalar::U32 | Scalar::F32 => 4,
            Scalar::F64 => 8,
        }
    }

    /// The value of little-endian `bytes` (of this type's size).
    fn read(self, b: &[u8]) -> f64 {
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

    /// The factor that maps a stored colour to `[0, 1]`.
    fn colour_scale(self) -> Option<f64> {
        match self {
            Scalar::U8 => Some(1.0 / 255.0),
            Scalar::U16 => Some(1.0 / 65535.0),
            Scalar::F32 | Scalar::F64 => Some(1.0),
            _ => None,
        }
    }
}

/// One property of an element: a scalar, or a list (count type, item type).
#[derive(Clone, Debug)]
struct Property {
    name: String,
    scalar: Scalar,
    list: Option<Scalar>,
}

#[derive(Clone, Debug)]
struct Element {
    name: String,
    count: usize,
    properties: Vec<Property>,
}

/// Reads the point cloud in the PLY file at `path`.
pub fn read_point_cloud(path: &Path) -> Result<Vec<DatasetPoint>> {
    let bytes = crate::io::input::read(path, "cannot read")?;
    parse_point_cloud(&bytes, &path.display().to_string())
}

/// Parses a PLY point cloud; `origin` names it in errors.
pub fn parse_point_cloud(bytes: &[u8], origin: &str) -> Result<Vec<DatasetPoint>> {
    let head = &bytes[..bytes.len().min(MAX_HEADER)];
    let marker = b"end_header";
    let end = head
        .windows(marker.len())
        .position(|w| w == marker)
        .ok_or_else(|| {
            Error::malformed(origin, "not a PLY file: no end_header in its first 64 KiB")
        })?;
    let mut body = end + marker.len();
    if bytes.get(body) == Some(&b'\r') {
        body += 1;
    }
    if bytes.get(body) != Some(&b'\n') {
        return Err(Error::malformed(
            origin,
            "end_header is not followed by a newline",
        ));
    }
    body += 1;
    let header = std::str::from_utf8(&bytes[..end])
        .map_err(|_| Error::malformed(origin, "the PLY header is not text"))?;
    let mut lines = header.lines().map(str::trim);
    if lines.next() != Some("ply") {
        return Err(Error::malformed(
            origin,
            "not a PLY file: it does not start with `ply`",
        ));
    }
    let (ascii, elements) = read_header_lines(lines, origin)?;
    let ascii =
        ascii.ok_or_else(|| Error::malformed(origin, "no `format` line in the PLY header"))?;
    let index = elements
        .iter()
        .position(|e| e.name == "vertex")
        .ok_or_else(|| Error::malformed(origin, "no `element vertex` in the PLY header"))?;
    let vertex = &elements[index];
    let find = |name: &str| -> Result<usize> {
        vertex
            .properties
            .iter()
            .position(|p| p.name == name && p.list.is_none())
            .ok_or_else(|| {
                Error::invalid(
                    origin,
                    "element vertex",
                    name,
                    "no such scalar property (need x y z red green blue)",
                )
            })
    };
    let coordinates = [find("x")?, find("y")?, find("z")?];
    let colours = [find("red")?, find("green")?, find("blue")?];
    let mut scales = [0.0; 3];
    for (scale, &k) in scales.iter_mut().zip(&colours) {
        let p = &vertex.properties[k];
        *scale = p.scalar.colour_scale().ok_or_else(|| {
            Error::invalid(
                origin,
                "element vertex",
                &p.name,
                format!(
                    "{:?} colours are not read (uchar, ushort, float or double)",
                    p.scalar
                ),
            )
        })?;
    }
    let rest = &bytes[body..];
    let rows = if ascii {
        ascii_rows(rest, &elements[..index], vertex, origin)?
    } else {
        binary_rows(rest, &elements[..index], vertex, origin)?
    };
    let mut points = Vec::with_capacity(rows.len() / vertex.properties.len().max(1));
    for (i, row) in rows.chunks_exact(vertex.properties.len()).enumerate() {
        let position = coordinates.map(|k| row[k]);
        let colour = std::array::from_fn(|c| (row[colours[c]] * scales[c]) as f32);
        for (field, v) in ["x", "y", "z"].iter().zip(position) {
            if !v.is_finite() {
                return Err(Error::invalid(
                    origin,
                    format!("vertex {i}"),
                    field,
                    format!("{v} is not finite"),
                ));
            }
        }
        // A float colour of NaN or beyond f32 would start a kernel of that colour.
        if let Some(c) = colour.iter().position(|v| !v.is_finite()) {
            return Err(Error::invalid(
                origin,
                format!("vertex {i}"),
                &vertex.properties[colours[c]].name,
                format!("{:e} is not a finite colour", row[colours[c]]),
            ));
        }
        points.push(DatasetPoint { position, colour });
    }
    Ok(points)
}

/// The header's lines after `ply`: whether the body is ascii (if a `format` line says),
/// and its elements.
fn read_header_lines<'a>(
    lines: impl Iterator<Item = &'a str>,
    origin: &str,
) -> Result<(Option<bool>, Vec<Element>)> {
    let mut ascii = None;
    let mut elements: Vec<Element> = Vec::new();
    for (n, line) in lines.enumerate() {
        let where_ = || format!("header line {}", n + 2);
        let words: Vec<&str> = line.split_whitespace().collect();
        match words.as_slice() {
            [] | ["comment" | "obj_info", ..] => {}
            ["format", format, _] => {
                ascii = Some(match *format {
                    "ascii" => true,
                    "binary_little_endian" => false,
                    other => {
                        return Err(Error::invalid(
                            origin,
                            where_(),
                            "format",
                            format!("{other} is not read (ascii or binary_little_endian)"),
                        ));
                    }
                });
            }
            ["element", name, count] => {
                let count = count.parse::<usize>().map_err(|_| {
                    Error::invalid(
                        origin,
                        where_(),
                        "element",
                        format!("count {count:?} is not a number"),
                    )
                })?;
                elements.push(Element {
                    name: (*name).to_owned(),
                    count,
                    properties: Vec::new(),
                });
            }
            ["property", rest @ ..] => {
                let property = match rest {
                    ["list", count, item, name] => Scalar::parse(count)
                        .zip(Scalar::parse(item))
                        .map(|(c, i)| Property {
                            name: (*name).to_owned(),
                            scalar: i,
                            list: Some(c),
                        }),
                    [ty, name] => Scalar::parse(ty).map(|scalar| Property {
                        name: (*name).to_owned(),
                        scalar,
                        list: None,
                    }),
                    _ => None,
                }
                .ok_or_else(|| {
                    Error::invalid(
                        origin,
                        where_(),
                        "property",
                        format!("{line:?} is not a PLY property"),
                    )
                })?;
                elements
                    .last_mut()
                    .ok_or_else(|| {
                        Error::invalid(
                            origin,
                            where_(),
                            "property",
                            "a property before any element",
                        )
                    })?
                    .properties
                    .push(property);
            }
            _ => {
                return Err(Error::invalid(
                    origin,
                    where_(),
                    "header",
                    format!("{line:?} is not a PLY header line"),
                ));
            }
        }
    }
    Ok((ascii, elements))
}

/// The vertices' scalar values, row after row, of an ascii body.
fn ascii_rows(body: &[u8], before: &[Element], vertex: &Element, origin: &str) -> Result<Vec<f64>> {
    let text = std::str::from_utf8(body)
        .map_err(|_| Error::malformed(origin, "the ascii PLY body is not text"))?;
    let mut lines = text.lines().filter(|l| !l.trim().is_empty());
    for element in before {
        for k in 0..element.count {
            lines.next().ok_or_else(|| {
                Error::invalid(
                    origin,
                    format!("{} {k}", element.name),
                    "line",
                    "the file ends here",
                )
            })?;
        }
    }
    let n = vertex.properties.len();
    if vertex.properties.iter().any(|p| p.list.is_some()) {
        return Err(Error::invalid(
            origin,
            "element vertex",
            "property",
            "list properties in vertices are not read",
        ));
    }
    // A row takes at least 2 bytes a value ("0 "): never allocate past what the file holds.
    let mut values = Vec::with_capacity(vertex.count.min(body.len() / (2 * n.max(1))) * n);
    for i in 0..vertex.count {
        let line = lines.next().ok_or_else(|| {
            Error::invalid(
                origin,
                format!("vertex {i}"),
                "line",
                format!("the file ends after {i} of {} vertices", vertex.count),
            )
        })?;
        let words: Vec<&str> = line.split_whitespace().collect();
        if words.len() < n {
            return Err(Error::invalid(
                origin,
                format!("vertex {i}"),
                "line",
                format!("{} values, expected {n}", words.len()),
            ));
        }
        for (p, word) in vertex.properties.iter().zip(&words) {
            let v: f64 = word.parse().map_err(|_| {
                Error::invalid(
                    origin,
                    format!("vertex {i}"),
                    &p.name,
                    format!("{word:?} is not a number"),
                )
            })?;
            values.push(v);
        }
    }
    Ok(values)
}

/// The vertices' scalar values, row after row, of a binary little-endian body.
fn binary_rows(
    body: &[u8],
    before: &[Element],
    vertex: &Element,
    origin: &str,
) -> Result<Vec<f64>> {
    let mut offset = 0usize;
    for element in before {
        if element.properties.iter().any(|p| p.list.is_some()) {
            return Err(Error::invalid(
                origin,
                format!("element {}", element.name),
                "property",
                "list properties before the vertices are not read",
            ));
        }
        let size: usize = element.properties.iter().map(|p| p.scalar.size()).sum();
        let skip = size
            .checked_mul(element.count)
            .filter(|&s| s <= body.len() - offset)
            .ok_or_else(|| {
                Error::invalid(
                    origin,
                    format!("element {}", element.name),
                    "count",
                    format!("{} items do not fit in the file", element.count),
                )
            })?;
        offset += skip;
    }
    if vertex.properties.iter().any(|p| p.list.is_some()) {
        return Err(Error::invalid(
            origin,
            "element vertex",
            "property",
            "list properties in vertices are not read",
        ));
    }
    let size: usize = vertex.properties.iter().map(|p| p.scalar.size()).sum();
    let remaining = body.len() - offset;
    let needed = size.checked_mul(vertex.count).filter(|&s| s <= remaining).ok_or_else(|| {
        Error::invalid(
            origin,
            "element vertex",
            "count",
            format!("{} vertices of {size} bytes need more than the {remaining} bytes the file has left", vertex.count),
        )
    })?;
    let mut values = Vec::with_capacity(vertex.count * vertex.properties.len());
    for row in body[offset..offset + needed].chunks_exact(size.max(1)) {
        let mut at = 0;
        for p in &vertex.properties {
            values.push(p.scalar.read(&row[at..at + p.scalar.size()]));
            at += p.scalar.size();
        }
    }
    Ok(values)
}
