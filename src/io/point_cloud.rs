//! Point clouds shipped with a dataset as PLY (nerfstudio's `ply_file_path`, COLMAP exports):
//! `element vertex N` with `x y z` (any numeric type) and `red green blue` (`uchar`/`uint8`
//! read as `v / 255`, `ushort`/`uint16` as `v / 65535`, `float`/`double` as they are), in
//! `ascii` or `binary_little_endian`. Other properties are ignored; other elements may come
//! before the vertices when their properties are scalars (and after them, anything). The
//! header is read by [`super::ply_header`].
//!
//! Every count is checked against the bytes the file has left before anything is allocated
//! for it; errors name the file, the vertex and the property.

use std::path::Path;

use crate::io::ply_header::{Element, Encoding, Header, Scalar, read_header};
use crate::model::error::{Error, Result};
use crate::model::view::DatasetPoint;

/// The factor that maps a stored colour of type `scalar` to `[0, 1]`.
fn colour_scale(scalar: Scalar) -> Option<f64> {
    match scalar {
        Scalar::U8 => Some(1.0 / 255.0),
        Scalar::U16 => Some(1.0 / 65535.0),
        Scalar::F32 | Scalar::F64 => Some(1.0),
        _ => None,
    }
}

/// Where a vertex row holds what a point needs: the indices of `x y z` and of
/// `red green blue` among its properties, and each colour's scale to `[0, 1]`.
struct VertexLayout {
    coordinates: [usize; 3],
    colours: [usize; 3],
    scales: [f64; 3],
}

impl VertexLayout {
    /// The layout of `vertex`'s rows: its scalar properties `x y z red green blue`.
    fn of(vertex: &Element, origin: &str) -> Result<Self> {
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
            *scale = colour_scale(p.scalar).ok_or_else(|| {
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
        Ok(VertexLayout {
            coordinates,
            colours,
            scales,
        })
    }

    /// The point of vertex `i`'s row of values, checked finite.
    fn point(&self, i: usize, row: &[f64], vertex: &Element, origin: &str) -> Result<DatasetPoint> {
        let position = self.coordinates.map(|k| row[k]);
        let colour = std::array::from_fn(|c| (row[self.colours[c]] * self.scales[c]) as f32);
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
                &vertex.properties[self.colours[c]].name,
                format!("{:e} is not a finite colour", row[self.colours[c]]),
            ));
        }
        Ok(DatasetPoint { position, colour })
    }
}

/// Reads the point cloud in the PLY file at `path`.
pub fn read_point_cloud(path: &Path) -> Result<Vec<DatasetPoint>> {
    let bytes = crate::io::input::read(path, "cannot read")?;
    parse_point_cloud(&bytes, &path.display().to_string())
}

/// Parses a PLY point cloud; `origin` names it in errors.
pub fn parse_point_cloud(bytes: &[u8], origin: &str) -> Result<Vec<DatasetPoint>> {
    let header = read_header(bytes, origin)?;
    let ascii = match header.encoding {
        Encoding::Ascii => true,
        Encoding::BinaryLittleEndian => false,
        other => {
            return Err(Error::invalid(
                origin,
                "header",
                "format",
                format!(
                    "{} is not read (ascii or binary_little_endian)",
                    other.name()
                ),
            ));
        }
    };
    let (index, vertex) = header
        .element("vertex")
        .ok_or_else(|| Error::malformed(origin, "no `element vertex` in the PLY header"))?;
    let layout = VertexLayout::of(vertex, origin)?;
    let body = &bytes[header.body_start..];
    let rows = if ascii {
        ascii_rows(body, &header.elements[..index], vertex, origin)?
    } else {
        binary_rows(body, &header, index, origin)?
    };
    let mut points = Vec::with_capacity(rows.len() / vertex.properties.len().max(1));
    for (i, row) in rows.chunks_exact(vertex.properties.len()).enumerate() {
        points.push(layout.point(i, row, vertex, origin)?);
    }
    Ok(points)
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

/// The vertices' scalar values, row after row, of a binary little-endian body; the
/// vertices are element `index` of `header`.
fn binary_rows(body: &[u8], header: &Header, index: usize, origin: &str) -> Result<Vec<f64>> {
    let vertex = &header.elements[index];
    let (offset, length) = header.binary_rows(index, body.len() as u64, origin)?;
    // Both within `body`: checked against its length.
    let rows = &body[offset as usize..(offset + length) as usize];
    let size: usize = vertex.properties.iter().map(|p| p.scalar.size()).sum();
    let mut values = Vec::with_capacity(vertex.count * vertex.properties.len());
    for row in rows.chunks_exact(size.max(1)) {
        let mut at = 0;
        for p in &vertex.properties {
            values.push(p.scalar.read_le(&row[at..at + p.scalar.size()]));
            at += p.scalar.size();
        }
    }
    Ok(values)
}
