//! OpenEXR files: float32 linear RGB, uncompressed scan lines, written from rows as they
//! are made ([`super::save_rows`]) straight into the temporary file, whose length follows
//! from the image's size.

use std::io::{Seek, Write};
use std::path::Path;

use crate::io::write_atomically_sized;
use crate::model::Image;
use crate::model::error::{Error, Result};
use crate::model::image::all_finite;

use super::{NotFinite, ROWS_OF_AN_IMAGE, RowCount, RowSink};

/// The error of an image too large for an EXR file's 32-bit sizes.
fn too_large_for_exr() -> std::io::Error {
    std::io::Error::other("the image is too large for an EXR file")
}

/// What [`write_exr`] writes before the samples of a `w`×`h` image, which does not depend
/// on the pixels: its header, and each line's sample byte count.
struct ExrLayout {
    header: Vec<u8>,
    line_bytes: i32,
}

impl ExrLayout {
    fn of(w: usize, h: usize) -> std::io::Result<Self> {
        Ok(ExrLayout {
            header: exr_header(w, h)?,
            line_bytes: i32::try_from(12 * w).map_err(|_| too_large_for_exr())?,
        })
    }

    /// The length of the file: the header, the line offsets (8 bytes a line), and per line
    /// 8 bytes of y and size and the samples.
    fn file_bytes(&self, h: usize) -> u64 {
        self.header.len() as u64 + h as u64 * (8 + 8 + self.line_bytes as u64)
    }
}

/// An EXR file's header ([`write_exr`]) for a `w`×`h` image.
fn exr_header(w: usize, h: usize) -> std::io::Result<Vec<u8>> {
    let (x_max, y_max) = (
        i32::try_from(w).map_err(|_| too_large_for_exr())? - 1,
        i32::try_from(h).map_err(|_| too_large_for_exr())? - 1,
    );
    let mut header = Vec::with_capacity(400);
    header.extend_from_slice(&[0x76, 0x2f, 0x31, 0x01, 2, 0, 0, 0]);
    let mut attribute = |name: &str, kind: &str, value: &[u8]| {
        for text in [name, kind] {
            header.extend_from_slice(text.as_bytes());
            header.push(0);
        }
        header.extend_from_slice(&(value.len() as i32).to_le_bytes());
        header.extend_from_slice(value);
    };
    let mut channels = Vec::new();
    for name in ["B", "G", "R"] {
        channels.extend_from_slice(name.as_bytes());
        channels.push(0);
        // FLOAT samples, not perceptually linear, reserved, x and y sampling 1.
        channels.extend_from_slice(&2_i32.to_le_bytes());
        channels.extend_from_slice(&[0, 0, 0, 0]);
        channels.extend_from_slice(&1_i32.to_le_bytes());
        channels.extend_from_slice(&1_i32.to_le_bytes());
    }
    channels.push(0);
    let window: Vec<u8> = [0, 0, x_max, y_max]
        .iter()
        .flat_map(|v| v.to_le_bytes())
        .collect();
    attribute("channels", "chlist", &channels);
    attribute("compression", "compression", &[0]);
    attribute("dataWindow", "box2i", &window);
    attribute("displayWindow", "box2i", &window);
    attribute("lineOrder", "lineOrder", &[0]);
    attribute("pixelAspectRatio", "float", &1.0_f32.to_le_bytes());
    attribute("screenWindowCenter", "v2f", &[0; 8]);
    attribute("screenWindowWidth", "float", &1.0_f32.to_le_bytes());
    header.push(0);
    Ok(header)
}

/// `image` encoded as an OpenEXR file into `out` ([`super::encode_image`]).
pub(super) fn encode_exr<W: Write + Seek>(image: &Image, out: &mut W) -> std::io::Result<()> {
    let layout = ExrLayout::of(image.width as usize, image.height as usize)?;
    write_exr(image, &layout, out)
}

/// Writes `image` as an OpenEXR file ([`write_exr_header`], then its lines
/// [`write_exr_lines`]).
fn write_exr<W: Write + Seek>(
    image: &Image,
    layout: &ExrLayout,
    out: &mut W,
) -> std::io::Result<()> {
    write_exr_header(layout, image.height as usize, out)?;
    let row = 3 * image.width.max(1) as usize;
    let mut buffer = Vec::new();
    for (k, rows) in image.pixels.chunks(ROWS_OF_AN_IMAGE * row).enumerate() {
        write_exr_lines(layout, k * ROWS_OF_AN_IMAGE, rows, &mut buffer, out)?;
    }
    Ok(())
}

/// Writes the start of an OpenEXR file of `h` lines laid out as `layout`: float32 R, G, B,
/// uncompressed scan lines, increasing y — the simplest layout of the format (OpenEXR file
/// layout: magic and version, header attributes, line offset table, then per line its y,
/// its byte count and the channels' samples in alphabetical order, B, G, R). Float renders
/// hardly compress, so writing is a copy at memory speed; every reader of the format opens
/// it (tested with the `exr` crate's).
fn write_exr_header<W: Write>(
    ExrLayout { header, line_bytes }: &ExrLayout,
    h: usize,
    out: &mut W,
) -> std::io::Result<()> {
    out.write_all(header)?;
    // One block per line: 8 bytes of y and size, then the samples.
    let first_block = (header.len() + 8 * h) as u64;
    let block = 8 + *line_bytes as u64;
    let mut offsets = Vec::with_capacity(8 * h);
    for y in 0..h as u64 {
        offsets.extend_from_slice(&(first_block + y * block).to_le_bytes());
    }
    out.write_all(&offsets)
}

/// Writes whole lines `rows` (RGB, row-major) of an OpenEXR file laid out as `layout`, the
/// first of them line `first_row`, after the lines before it ([`write_exr_header`]): each
/// line's block laid out in `buffer`, in parallel, then written.
fn write_exr_lines<W: Write>(
    &ExrLayout { line_bytes, .. }: &ExrLayout,
    first_row: usize,
    rows: &[f32],
    buffer: &mut Vec<u8>,
    out: &mut W,
) -> std::io::Result<()> {
    use rayon::prelude::*;
    let samples = line_bytes as usize / 4;
    let block_bytes = 8 + 4 * samples;
    let lines = rows.len() / samples.max(1);
    buffer.resize(lines * block_bytes, 0);
    buffer
        .par_chunks_mut(block_bytes)
        .zip(rows.par_chunks(samples.max(1)))
        .enumerate()
        .for_each(|(k, (block, row))| {
            let y = (first_row + k) as i32;
            block[..4].copy_from_slice(&y.to_le_bytes());
            block[4..8].copy_from_slice(&line_bytes.to_le_bytes());
            // The B, G and R planes of the line, each a pass over its pixels.
            let planes = block[8..].chunks_exact_mut((samples / 3).max(1) * 4);
            for (plane, c) in planes.zip([2, 1, 0]) {
                for (sample, pixel) in plane.chunks_exact_mut(4).zip(row.chunks_exact(3)) {
                    sample.copy_from_slice(&pixel[c].to_le_bytes());
                }
            }
        });
    out.write_all(buffer)
}

/// [`super::save_rows`] for an EXR: the header, then the rows written as they arrive, into a
/// file whose length is known beforehand; nothing is written when a value is not finite or
/// `produce` fails (its own error comes back as it was).
pub(super) fn save_exr_rows<T>(
    path: &Path,
    (width, height): (u32, u32),
    mut produce: impl FnMut(&mut RowSink) -> Result<T>,
) -> Result<T> {
    let (w, h) = (width as usize, height as usize);
    let layout = ExrLayout::of(w, h).map_err(|e| Error::write(path, "cannot write", e))?;
    // `produce`'s own error (or a sink's: a value not finite, a failed write) is
    // kept here, and the writing stopped with a placeholder.
    let mut failure = None;
    let mut produced = None;
    let written = write_atomically_sized(path, layout.file_bytes(h), |out| {
        write_exr_header(&layout, h, out)?;
        let mut buffer = Vec::new();
        let mut count = RowCount::new(path, (width, height));
        let mut sink = |first_row: usize, rows: &[f32]| -> Result<()> {
            count.take(first_row, rows)?;
            if !all_finite(rows) {
                let channel = first_row * 3 * w;
                if let Some(first) = NotFinite::find(channel, rows) {
                    return Err(first.error(path, width));
                }
            }
            write_exr_lines(&layout, first_row, rows, &mut buffer, out)
                .map_err(|e| Error::write(path, "cannot write", e))
        };
        match produce(&mut sink).and_then(|value| count.all_taken().map(|()| value)) {
            Ok(value) => {
                produced = Some(value);
                Ok(())
            }
            Err(error) => {
                failure = Some(error);
                Err(std::io::Error::other("stopped"))
            }
        }
    });
    if let Some(error) = failure {
        return Err(error);
    }
    written?;
    produced.ok_or_else(|| {
        let never = std::io::Error::other("no rows were made");
        Error::write(path, "cannot write", never)
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::io::image_file::{BitDepth, load_image, save_image};

    #[test]
    fn exr_files_read_back_exactly_with_an_independent_reader() {
        use exr::prelude::{ReadChannels, ReadLayers};
        let dir = tempfile::tempdir().unwrap();
        for (w, h) in [(1, 1), (7, 3), (64, 40)] {
            let mut image = Image::filled(w, h, [0.0; 3]);
            for (k, v) in image.pixels.iter_mut().enumerate() {
                *v = (k as f32 * 0.37).sin() * 1e3 + 1e-30 * k as f32;
            }
            image.pixels[0] = -0.0;
            let path = dir.path().join(format!("i{w}x{h}.exr"));
            save_image(&image, &path, BitDepth::Eight).unwrap();
            // The length reserved before writing is the length written.
            let written = std::fs::metadata(&path).unwrap().len();
            let layout = ExrLayout::of(w as usize, h as usize).unwrap();
            assert_eq!(layout.file_bytes(h as usize), written, "{w}×{h}");
            // The exr crate's own reader, not the image crate's.
            let read = exr::prelude::read()
                .no_deep_data()
                .largest_resolution_level()
                .rgb_channels(
                    |size, _| vec![[0.0_f32; 3]; size.width() * size.height()],
                    move |pixels: &mut Vec<[f32; 3]>, p, (r, g, b): (f32, f32, f32)| {
                        pixels[p.y() * w as usize + p.x()] = [r, g, b];
                    },
                )
                .first_valid_layer()
                .all_attributes()
                .from_file(&path)
                .unwrap();
            let pixels: Vec<f32> = read.layer_data.channel_data.pixels.concat();
            assert_eq!(pixels.len(), image.pixels.len());
            for (a, b) in pixels.iter().zip(&image.pixels) {
                assert_eq!(a.to_bits(), b.to_bits(), "{w}×{h}");
            }
            // And our loader (the image crate's decoder).
            let loaded = load_image(&path, [0.0; 3]).unwrap();
            assert_eq!(loaded.pixels.len(), image.pixels.len());
            assert!(
                loaded
                    .pixels
                    .iter()
                    .zip(&image.pixels)
                    .all(|(a, b)| a.to_bits() == b.to_bits())
            );
        }
    }
}
