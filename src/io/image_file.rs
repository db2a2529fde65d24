//! Images on disk (SPEC §5): linear values, no sRGB curve either way.
//!
//! - `.exr`: float32 linear RGB, values as rendered (no clamp).
//! - `.png`: 8-bit stores `round(255 clamp(C, 0, 1))`, 16-bit `round(65535 clamp(C, 0, 1))`,
//!   rounding half away from zero.
//!
//! Reading returns `value / (2^bits - 1)` for integer files and the stored value for float
//! files; an image with alpha is composited over a background colour, `a C + (1 - a) b`.

use std::io::{Seek, Write};
use std::path::Path;

use image::{DynamicImage, ImageBuffer, ImageFormat, Rgb};

use crate::io::{write_atomically, write_atomically_sized};
use crate::model::Image;
use crate::model::error::{Error, Result};
use crate::model::image::{all_finite, quantize_all_checked};
use crate::parallel::Drain;

/// Bits per channel of an integer image file.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum BitDepth {
    /// 8 bits per channel.
    #[default]
    Eight,
    /// 16 bits per channel.
    Sixteen,
}

/// An image file format, from the file's extension.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ImageKind {
    /// OpenEXR, float32 linear RGB.
    Exr,
    /// PNG, 8 or 16 bits.
    Png,
}

impl ImageKind {
    /// The format for `path`'s extension (case-insensitive), or an error naming it.
    pub fn from_path(path: &Path) -> Result<Self> {
        let ext = path
            .extension()
            .and_then(|e| e.to_str())
            .map(str::to_ascii_lowercase);
        match ext.as_deref() {
            Some("exr") => Ok(ImageKind::Exr),
            Some("png") => Ok(ImageKind::Png),
            _ => Err(Error::Usage(format!(
                "{}: unsupported image extension (use .png or .exr)",
                path.display()
            ))),
        }
    }
}

/// Encodes `image` in `kind` to a seekable writer.
pub fn encode_image<W: Write + Seek>(
    image: &Image,
    kind: ImageKind,
    depth: BitDepth,
    out: &mut W,
) -> image::ImageResult<()> {
    match kind {
        ImageKind::Exr => ExrLayout::of(image.width as usize, image.height as usize)
            .and_then(|layout| write_exr(image, &layout, out))
            .map(drop),
        ImageKind::Png => encode_png(
            Path::new("<memory>"),
            (image.width, image.height),
            depth,
            |sink| image_rows(image, sink),
        )
        .map_err(std::io::Error::other)
        .and_then(|png| out.write_all(&png.bytes)),
    }
    .map_err(image::ImageError::IoError)
}

/// Rows of an image handed over in order, top to bottom: the index of the first row and
/// whole rows of RGB values, row-major ([`save_rows`]).
pub type RowSink<'a> = Drain<'a, Error>;

/// Rows handed over at a time from an image in memory: a band small enough to stay in cache.
const ROWS_OF_AN_IMAGE: usize = 64;

/// Hands `image`'s rows to `sink` in order, [`ROWS_OF_AN_IMAGE`] at a time.
fn image_rows(image: &Image, sink: &mut RowSink) -> Result<()> {
    let row = 3 * image.width.max(1) as usize;
    for (k, rows) in image.pixels.chunks(ROWS_OF_AN_IMAGE * row).enumerate() {
        sink(k * ROWS_OF_AN_IMAGE, rows)?;
    }
    Ok(())
}

/// Channels quantised at a time while encoding a PNG: a band of rows small enough to stay
/// in cache, so no full-size copy of the image's levels is ever made.
const PNG_BAND_CHANNELS: usize = 1 << 16;

/// The largest IDAT chunk a PNG is written in (12 bytes of framing each).
const PNG_CHUNK_BYTES: usize = 1 << 16;

/// A PNG encoded in memory, what made its rows, and its first channel that was not finite.
struct EncodedPng<T> {
    bytes: Vec<u8>,
    produced: T,
    not_finite: Option<NotFinite>,
}

/// Where an image first holds a value that is not finite: its index among the image's
/// channels, and the value.
#[derive(Clone, Copy, Debug)]
struct NotFinite {
    channel: usize,
    value: f32,
}

impl NotFinite {
    /// The first value of `values`, the channels from index `start` of the image, that is
    /// not finite (none when all are).
    fn find(start: usize, values: &[f32]) -> Option<NotFinite> {
        let k = values.iter().position(|v| !v.is_finite())?;
        Some(NotFinite {
            channel: start + k,
            value: values[k],
        })
    }

    /// The error refusing to write `path`, `width` pixels wide, for this value.
    fn error(self, path: &Path, width: u32) -> Error {
        let pixel = self.channel / 3;
        let width = width.max(1) as usize;
        Error::Numeric(format!(
            "{}: not written: pixel ({}, {}) channel {} is {}, not finite (amplitudes or background too large for f32)",
            path.display(),
            pixel % width,
            pixel / width,
            self.channel % 3,
            self.value
        ))
    }
}

/// The rows `produce` hands over ([`RowSink`]), a `size` image, as an RGB PNG at `depth`,
/// and where it first holds a value that is not finite (found in the same pass): fdeflate's
/// fast compression with adaptive filters, or, where that comes out larger than the
/// scanlines stored uncompressed would (noise: its fixed codes spend up to 12 bits on a
/// byte), the scanlines stored, as png's whole-image writer does; `produce` then runs a
/// second time. Encoded in memory: png's stream writer drops an error of its last chunk's
/// write (its chunk writer flushes on drop), which a `Vec` cannot return. The memory is
/// bounded by the stored size: the compressed encoding stops as soon as it would grow past
/// it (instead of growing to twice that), and the stored one reuses its buffer.
fn encode_png<T>(
    path: &Path,
    size: (u32, u32),
    depth: BitDepth,
    mut produce: impl FnMut(&mut RowSink) -> Result<T>,
) -> Result<EncodedPng<T>> {
    let channel_bytes = match depth {
        BitDepth::Eight => 1,
        BitDepth::Sixteen => 2,
    };
    let (width, height) = (u64::from(size.0), u64::from(size.1));
    let scanlines = height * (1 + 3 * channel_bytes * width);
    // Stored: the scanlines, 5 bytes a deflate block of up to 65535, 12 a chunk of 64 KiB,
    // the zlib and PNG framing; a bound a little above.
    let stored = scanlines + scanlines / 4096 + 96;
    // The stored encoding's own size, for the buffer's growth: 5 bytes a deflate block,
    // 12 a 64 KiB chunk (s/13107 + s/5461 < s/2048), the framing.
    let most = usize::try_from(scanlines + scanlines / 2048 + 256).unwrap_or(usize::MAX);
    let mut out = Capped {
        bytes: Vec::new(),
        limit: usize::try_from(stored).unwrap_or(usize::MAX),
        grow_to: most,
        over: false,
    };
    let fast = encode_png_with(
        path,
        size,
        depth,
        png::Compression::Fast,
        &mut produce,
        &mut out,
    );
    if !out.over {
        let (produced, not_finite) = fast?;
        return Ok(EncodedPng {
            bytes: out.bytes,
            produced,
            not_finite,
        });
    }
    // Larger than stored (noise): stored, in the same buffer (no limit: the bound is only
    // a little above the stored size, which it never passes).
    out.bytes.clear();
    out.limit = usize::MAX;
    out.over = false;
    let (produced, not_finite) = encode_png_with(
        path,
        size,
        depth,
        png::Compression::NoCompression,
        &mut produce,
        &mut out,
    )?;
    Ok(EncodedPng {
        bytes: out.bytes,
        produced,
        not_finite,
    })
}

/// The bytes of a PNG encoded in memory, at most `limit` of them: a write past it fails and
/// sets `over`. The buffer grows as a `Vec` does, but not beyond `grow_to` (the size
/// expected at most) unless a write needs more.
struct Capped {
    bytes: Vec<u8>,
    limit: usize,
    grow_to: usize,
    over: bool,
}

impl Write for Capped {
    fn write(&mut self, data: &[u8]) -> std::io::Result<usize> {
        let needed = self.bytes.len().saturating_add(data.len());
        if needed > self.limit {
            self.over = true;
            return Err(std::io::Error::other(
                "the compressed PNG is larger than its scanlines stored",
            ));
        }
        if needed > self.bytes.capacity() {
            let grown = self.bytes.capacity().saturating_mul(2).min(self.grow_to);
            self.bytes
                .reserve_exact(grown.max(needed) - self.bytes.len());
        }
        self.bytes.extend_from_slice(data);
        Ok(data.len())
    }

    fn flush(&mut self) -> std::io::Result<()> {
        Ok(())
    }
}

/// [`encode_png`] with `compression`, into `out`: the channels quantised
/// ([`quantize_all_checked`]) as they arrive, a band at a time, and streamed into the
/// encoder; the encoder's errors name `path`. Returns what `produce` returned and the first
/// value not finite.
fn encode_png_with<T>(
    path: &Path,
    (width, height): (u32, u32),
    depth: BitDepth,
    compression: png::Compression,
    produce: &mut impl FnMut(&mut RowSink) -> Result<T>,
    out: &mut Capped,
) -> Result<(T, Option<NotFinite>)> {
    let cannot = |e| Error::write(path, "cannot encode", e);
    let mut encoder = png::Encoder::new(out, width, height);
    encoder.set_color(png::ColorType::Rgb);
    encoder.set_depth(match depth {
        BitDepth::Eight => png::BitDepth::Eight,
        BitDepth::Sixteen => png::BitDepth::Sixteen,
    });
    encoder.set_compression(compression);
    if !matches!(compression, png::Compression::NoCompression) {
        encoder.set_filter(png::Filter::Adaptive);
    }
    let mut writer = encoder.write_header().map_err(|e| cannot(e.into()))?;
    let mut stream = writer
        .stream_writer_with_size(PNG_CHUNK_BYTES)
        .map_err(|e| cannot(e.into()))?;
    let row = 3 * width.max(1) as usize;
    let band = row * (PNG_BAND_CHANNELS / row).max(1);
    let mut not_finite = None;
    let mut big_endian = Vec::new();
    let mut sink = |first_row: usize, rows: &[f32]| -> Result<()> {
        for (k, channels) in rows.chunks(band).enumerate() {
            let finite = match depth {
                BitDepth::Eight => {
                    let (levels, finite) = quantize_all_checked::<u8>(channels);
                    stream.write_all(&levels).map(|()| finite)
                }
                BitDepth::Sixteen => {
                    let (levels, finite) = quantize_all_checked::<u16>(channels);
                    big_endian.clear();
                    big_endian.extend(levels.iter().flat_map(|level| level.to_be_bytes()));
                    stream.write_all(&big_endian).map(|()| finite)
                }
            }
            .map_err(&cannot)?;
            if !finite && not_finite.is_none() {
                not_finite = NotFinite::find(first_row * row + k * band, channels);
            }
        }
        Ok(())
    };
    let produced = produce(&mut sink)?;
    stream.finish().map_err(|e| cannot(e.into()))?;
    writer.finish().map_err(|e| cannot(e.into()))?;
    Ok((produced, not_finite))
}

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

/// Writes `image` to `path` (format from the extension), atomically ([`save_rows`]).
pub fn save_image(image: &Image, path: &Path, depth: BitDepth) -> Result<()> {
    save_rows(path, (image.width, image.height), depth, |sink| {
        image_rows(image, sink)
    })
}

/// The rows a producer of [`save_rows`] has handed over: each group must start where the
/// last ended and hold whole rows within the image, and all must be there at the end, or
/// nothing is written (a file with rows missing or misplaced would read as an image).
struct RowCount<'a> {
    path: &'a Path,
    row_values: usize,
    height: usize,
    taken: usize,
}

impl<'a> RowCount<'a> {
    fn new(path: &'a Path, (width, height): (u32, u32)) -> Self {
        RowCount {
            path,
            row_values: 3 * width.max(1) as usize,
            height: height as usize,
            taken: 0,
        }
    }

    /// Counts rows from `first_row` holding `values`, or refuses them out of order.
    fn take(&mut self, first_row: usize, values: &[f32]) -> Result<()> {
        let rows = values.len() / self.row_values;
        if first_row != self.taken
            || !values.len().is_multiple_of(self.row_values)
            || first_row + rows > self.height
        {
            return Err(self.refuse(format!(
                "rows {first_row}.. ({} values) handed over after {} of {} rows",
                values.len(),
                self.taken,
                self.height
            )));
        }
        self.taken += rows;
        Ok(())
    }

    /// Refuses an image whose rows are not all there.
    fn all_taken(&self) -> Result<()> {
        if self.taken == self.height {
            return Ok(());
        }
        Err(self.refuse(format!("{} of {} rows made", self.taken, self.height)))
    }

    fn refuse(&self, what: String) -> Error {
        let e = std::io::Error::other(format!("the image's rows are not whole: {what}"));
        Error::write(self.path, "not written", e)
    }
}

/// Writes to `path` (format from the extension), atomically, the `width`×`height` image
/// whose rows `produce` hands to its sink, in order and each once ([`RowSink`]), and returns
/// what `produce` returned. The image never needs to be whole in memory: a PNG is encoded
/// as its rows arrive, its levels a band at a time, then written; an EXR's rows go into its
/// temporary file as they arrive. Nothing non-finite leaves: an EXR would hold inf, a PNG a
/// clamped lie; the first such value is named in the error, and nothing is written. Both
/// are written with their length known beforehand ([`write_atomically_sized`]), an EXR's
/// following from its size, a PNG's once encoded. A PNG whose compressed data came out
/// larger than its scanlines stored is encoded again, stored, with `produce` run again.
pub fn save_rows<T>(
    path: &Path,
    (width, height): (u32, u32),
    depth: BitDepth,
    mut produce: impl FnMut(&mut RowSink) -> Result<T>,
) -> Result<T> {
    match ImageKind::from_path(path)? {
        ImageKind::Png => {
            let png = encode_png(path, (width, height), depth, |sink| {
                let mut rows = RowCount::new(path, (width, height));
                let produced = produce(&mut |first_row: usize, values: &[f32]| {
                    rows.take(first_row, values)?;
                    sink(first_row, values)
                })?;
                rows.all_taken()?;
                Ok(produced)
            })?;
            if let Some(first) = png.not_finite {
                return Err(first.error(path, width));
            }
            write_atomically_sized(path, png.bytes.len() as u64, |w| w.write_all(&png.bytes))?;
            Ok(png.produced)
        }
        ImageKind::Exr => {
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
    }
}

/// Writes 8-bit RGB bytes (`3 width height`, row-major) as a PNG, atomically: for charts and
/// figures drawn directly in 8 bits.
pub fn save_rgb8_png(path: &Path, width: u32, height: u32, bytes: &[u8]) -> Result<()> {
    let buf: ImageBuffer<Rgb<u8>, &[u8]> =
        ImageBuffer::from_raw(width, height, bytes).ok_or_else(|| {
            Error::Usage(format!(
                "{}: {} bytes do not make a {width}×{height} RGB image",
                path.display(),
                bytes.len()
            ))
        })?;
    write_atomically(path, |w| {
        buf.write_to(w, ImageFormat::Png)
            .map_err(std::io::Error::other)
    })
}

/// Reads an image file as linear RGB, compositing any alpha over `background`.
pub fn load_image(path: &Path, background: [f32; 3]) -> Result<Image> {
    load_image_with_alpha(path, background).map(|(image, _)| image)
}

/// A reader of the image file `path` ([`crate::io::input::open`]: a regular file), its
/// format from its first bytes, else from its extension.
fn open_reader(path: &Path) -> Result<image::ImageReader<std::io::BufReader<std::fs::File>>> {
    let file = crate::io::input::open(path, "cannot read image")?;
    let mut reader = image::ImageReader::new(std::io::BufReader::new(file));
    if let Ok(format) = ImageFormat::from_path(path) {
        reader.set_format(format);
    }
    reader
        .with_guessed_format()
        .map_err(|e| Error::read(path, "cannot read image", e))
}

/// The size `(width, height)` an image file declares, read from its header alone (nothing
/// is decoded); an error when it is larger than a frame may be
/// ([`crate::model::camera::MAX_PIXELS`]), so a small file cannot make a huge allocation.
pub fn image_size(path: &Path) -> Result<(u32, u32)> {
    let origin = path.display().to_string();
    let (w, h) = open_reader(path)?
        .into_dimensions()
        .map_err(|e| Error::malformed(&origin, format!("cannot read the image header: {e}")))?;
    if u64::from(w) * u64::from(h) > crate::model::camera::MAX_PIXELS {
        return Err(Error::invalid(
            &origin,
            "image",
            "size",
            format!("{w}×{h} is more than the 16384² pixels a frame may have"),
        ));
    }
    Ok((w, h))
}

/// [`load_image`], also telling whether some pixel was transparent (alpha below 1). Every
/// pixel must be finite: a NaN or infinity is an error naming the file and the pixel.
pub fn load_image_with_alpha(path: &Path, background: [f32; 3]) -> Result<(Image, bool)> {
    let origin = path.display().to_string();
    let readable = path
        .extension()
        .and_then(|e| e.to_str())
        .map(str::to_ascii_lowercase)
        .is_some_and(|e| ["exr", "png", "jpg", "jpeg"].contains(&e.as_str()));
    if !readable {
        return Err(Error::usage(format!(
            "{}: unsupported image extension (read: .png, .exr, .jpg, .jpeg)",
            path.display()
        )));
    }
    let (w, h) = image_size(path)?;
    let mut reader = open_reader(path)?;
    if reader.format() == Some(ImageFormat::Jpeg) {
        let bytes = crate::io::input::read(path, "cannot read image")?;
        if !jpeg_is_complete(&bytes) {
            return Err(Error::malformed(
                &origin,
                "cannot decode image: the JPEG ends before its last scan does (a truncated file)",
            ));
        }
    }
    let mut limits = image::Limits::default();
    limits.max_image_width = Some(w);
    limits.max_image_height = Some(h);
    reader.limits(limits);
    let decoded = reader
        .decode()
        .map_err(|e| Error::malformed(&origin, format!("cannot decode image: {e}")))?;
    let (image, transparent) = composite(&decoded, background);
    // The position only on failure.
    let all_finite = all_finite(&image.pixels);
    if let Some(k) = (!all_finite)
        .then(|| image.pixels.iter().position(|v| !v.is_finite()))
        .flatten()
    {
        let pixel = k / 3;
        let width = image.width as usize;
        return Err(Error::invalid(
            &origin,
            format!("pixel ({}, {})", pixel % width, pixel / width),
            "value",
            format!("{} is not finite", image.pixels[k]),
        ));
    }
    Ok((image, transparent))
}

/// Converts a decoded image to linear RGB f32 (integers divided by `2^bits - 1`), alpha
/// composited over `background`.
#[must_use]
pub fn to_linear_rgb(decoded: &DynamicImage, background: [f32; 3]) -> Image {
    composite(decoded, background).0
}

/// [`to_linear_rgb`], and whether some pixel had alpha below 1. The decoded samples are
/// converted straight into the one output buffer (no whole-image intermediate: a 16384²
/// grey PNG needs its 268 MB of samples and the 3.2 GB result, not four more copies).
fn composite(decoded: &DynamicImage, background: [f32; 3]) -> (Image, bool) {
    let (w, h) = (decoded.width(), decoded.height());
    // 8-bit values v are read as 257 v / 65535 (= v / 255), as 16-bit ones, bit for bit.
    let u8f = |v: u8| (f64::from(u16::from(v) * 257) / 65535.0) as f32;
    let u16f = |v: u16| (f64::from(v) / 65535.0) as f32;
    let f32f = |v: f32| v;
    let mut pixels = Vec::with_capacity(3 * w as usize * h as usize);
    let transparent = match decoded {
        DynamicImage::ImageLuma8(b) => push_pixels(b.as_raw(), 1, u8f, background, &mut pixels),
        DynamicImage::ImageLumaA8(b) => push_pixels(b.as_raw(), 2, u8f, background, &mut pixels),
        DynamicImage::ImageRgb8(b) => push_pixels(b.as_raw(), 3, u8f, background, &mut pixels),
        DynamicImage::ImageRgba8(b) => push_pixels(b.as_raw(), 4, u8f, background, &mut pixels),
        DynamicImage::ImageLuma16(b) => push_pixels(b.as_raw(), 1, u16f, background, &mut pixels),
        DynamicImage::ImageLumaA16(b) => push_pixels(b.as_raw(), 2, u16f, background, &mut pixels),
        DynamicImage::ImageRgb16(b) => push_pixels(b.as_raw(), 3, u16f, background, &mut pixels),
        DynamicImage::ImageRgba16(b) => push_pixels(b.as_raw(), 4, u16f, background, &mut pixels),
        DynamicImage::ImageRgb32F(b) => push_pixels(b.as_raw(), 3, f32f, background, &mut pixels),
        DynamicImage::ImageRgba32F(b) => push_pixels(b.as_raw(), 4, f32f, background, &mut pixels),
        other => {
            let rgba = other.to_rgba32f();
            push_pixels(rgba.as_raw(), 4, f32f, background, &mut pixels)
        }
    };
    let image = Image {
        width: w,
        height: h,
        pixels,
    };
    (image, transparent)
}

/// Appends the linear RGB of `samples` (`channels` per pixel: grey, grey+alpha, RGB or
/// RGBA) to `out`, alpha composited over `background`; whether some alpha was below 1.
fn push_pixels<S: Copy>(
    samples: &[S],
    channels: usize,
    to_f32: impl Fn(S) -> f32,
    background: [f32; 3],
    out: &mut Vec<f32>,
) -> bool {
    let mut transparent = false;
    for p in samples.chunks_exact(channels) {
        let (rgb, a) = match channels {
            1 => ([to_f32(p[0]); 3], 1.0),
            2 => ([to_f32(p[0]); 3], to_f32(p[1])),
            3 => ([to_f32(p[0]), to_f32(p[1]), to_f32(p[2])], 1.0),
            _ => ([to_f32(p[0]), to_f32(p[1]), to_f32(p[2])], to_f32(p[3])),
        };
        transparent |= a < 1.0;
        for (c, bg) in rgb.into_iter().zip(background) {
            out.push(if a == 1.0 { c } else { a * c + (1.0 - a) * bg });
        }
    }
    transparent
}

/// Whether the JPEG `bytes` end their last scan with an end-of-image marker (`FF D9` after
/// the last start-of-scan `FF DA`; entropy-coded data stuffs every `FF` byte, so neither
/// appears inside a scan). A file cut in the middle of a scan has none: the decoder would
/// fill the rest of the image silently.
fn jpeg_is_complete(bytes: &[u8]) -> bool {
    let last_scan = bytes.windows(2).rposition(|w| w == [0xFF, 0xDA]);
    last_scan.is_some_and(|start| bytes[start..].windows(2).any(|w| w == [0xFF, 0xD9]))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::image::quantize;

    #[test]
    fn quantize_clamps_and_rounds_half_away_from_zero() {
        assert_eq!(quantize(-0.2, 255), 0);
        assert_eq!(quantize(1.7, 255), 255);
        assert_eq!(quantize(f32::NAN, 255), 0);
        assert_eq!(quantize(0.5, 255), 128); // 127.5 rounds up
        assert_eq!(quantize(0.5, 65535), 32768);
        assert_eq!(quantize(1.0 / 255.0, 255), 1);
    }

    #[test]
    fn pngs_read_back_as_the_levels_of_every_channel_with_an_independent_reader() {
        // Sizes of one band, of several bands and a partial last one, and of several IDAT
        // chunks (noise compresses poorly); channels below 0, above 1, and near half steps.
        let dir = tempfile::tempdir().unwrap();
        for (w, h) in [(1, 1), (5, 3), (301, 257)] {
            let mut image = Image::filled(w, h, [0.0; 3]);
            let mut state = 0x9e37_79b9_u32;
            for v in &mut image.pixels {
                state ^= state << 13;
                state ^= state >> 17;
                state ^= state << 5;
                *v = (state >> 8) as f32 / (1 << 24) as f32 * 1.2 - 0.1;
            }
            for depth in [BitDepth::Eight, BitDepth::Sixteen] {
                let path = dir.path().join(format!("i{w}x{h}_{depth:?}.png"));
                save_image(&image, &path, depth).unwrap();
                let bytes = std::fs::read(&path).unwrap();
                let chunks = bytes.windows(4).filter(|t| *t == b"IDAT").count();
                assert!(w < 300 || chunks > 1, "{chunks} IDAT chunks");
                // Noise is stored rather than grown by the fast compressor's fixed codes:
                // the file is its scanlines and a little framing.
                let channel_bytes = if depth == BitDepth::Eight { 1 } else { 2 };
                let scanlines = (h * (1 + 3 * channel_bytes * w)) as usize;
                assert!(
                    bytes.len() <= scanlines + scanlines / 1000 + 100,
                    "{} bytes for {scanlines} of scanlines",
                    bytes.len()
                );
                let read = image::open(&path).unwrap();
                let levels: Vec<u16> = match depth {
                    BitDepth::Eight => read
                        .into_rgb8()
                        .into_raw()
                        .into_iter()
                        .map(u16::from)
                        .collect(),
                    BitDepth::Sixteen => read.into_rgb16().into_raw(),
                };
                let max = match depth {
                    BitDepth::Eight => 255,
                    BitDepth::Sixteen => 65535,
                };
                let expected: Vec<u16> = image.pixels.iter().map(|&c| quantize(c, max)).collect();
                assert_eq!(levels, expected, "{w}×{h} {depth:?}");
            }
        }
    }

    #[test]
    fn a_non_finite_channel_in_the_last_band_leaves_no_png() {
        let dir = tempfile::tempdir().unwrap();
        let mut image = Image::filled(300, 300, [0.5; 3]);
        let last = image.pixels.len() - 2;
        image.pixels[last] = f32::INFINITY;
        let path = dir.path().join("i.png");
        let message = save_image(&image, &path, BitDepth::Sixteen)
            .unwrap_err()
            .to_string();
        assert!(
            message.contains("pixel (299, 299) channel 1 is inf"),
            "{message}"
        );
        assert!(!path.exists());
        assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 0);
    }

    /// A PNG encoded in memory never holds more than its scanlines stored: noise, which
    /// compresses to more than that, stops its compressed encoding at the bound and is
    /// stored in the same buffer.
    #[test]
    fn a_png_in_memory_stays_within_its_stored_size() {
        let mut noise = Image::filled(512, 300, [0.0; 3]);
        let mut state = 0x9e37_79b9_u32;
        for v in &mut noise.pixels {
            state ^= state << 13;
            state ^= state >> 17;
            state ^= state << 5;
            *v = (state >> 8) as f32 / (1 << 24) as f32;
        }
        let path = Path::new("noise.png");
        for (depth, bytes) in [(BitDepth::Eight, 1), (BitDepth::Sixteen, 2)] {
            let scanlines = 300 * (1 + 3 * bytes * 512);
            // The scanlines, 0.1% and half a KiB of framing (a `Vec` grown by doubling
            // held up to twice the stored size).
            let most = scanlines + scanlines / 1000 + 512;
            let png = encode_png(path, (512, 300), depth, |sink| image_rows(&noise, sink)).unwrap();
            assert!(png.bytes.len() > scanlines, "{depth:?}: stored");
            assert!(
                png.bytes.capacity() <= most,
                "{depth:?}: {} bytes held for at most {most}",
                png.bytes.capacity()
            );
        }
    }

    /// Hands `image`'s rows to `sink` `rows` at a time, as a renderer would.
    fn rows_of(image: &Image, rows: usize, sink: &mut RowSink) -> Result<()> {
        let row = 3 * image.width as usize;
        for (k, values) in image.pixels.chunks(rows * row).enumerate() {
            sink(k * rows, values)?;
        }
        Ok(())
    }

    #[test]
    fn rows_handed_over_in_groups_write_the_same_files_as_the_whole_image() {
        // A smooth image (compressed) and noise (stored, so the rows are made twice).
        let dir = tempfile::tempdir().unwrap();
        let mut smooth = Image::filled(70, 45, [0.0; 3]);
        for (k, v) in smooth.pixels.iter_mut().enumerate() {
            *v = (k % 210) as f32 / 209.0;
        }
        let mut noise = smooth.clone();
        let mut state = 0x2545_f491_u32;
        for v in &mut noise.pixels {
            state ^= state << 13;
            state ^= state >> 17;
            state ^= state << 5;
            *v = (state >> 8) as f32 / (1 << 24) as f32;
        }
        for (image, what, passes) in [(&smooth, "smooth", 1), (&noise, "noise", 2)] {
            for name in ["a.png", "a.exr"] {
                let whole = dir.path().join(format!("whole-{what}-{name}"));
                save_image(image, &whole, BitDepth::Sixteen).unwrap();
                let grouped = dir.path().join(format!("grouped-{what}-{name}"));
                let mut runs = 0;
                let size = (image.width, image.height);
                let made = save_rows(&grouped, size, BitDepth::Sixteen, |sink| {
                    runs += 1;
                    rows_of(image, 7, sink).map(|()| 42)
                })
                .unwrap();
                assert_eq!(made, 42);
                let expected_runs = if name.ends_with("png") { passes } else { 1 };
                assert_eq!(runs, expected_runs, "{what} {name}");
                assert_eq!(
                    std::fs::read(&whole).unwrap(),
                    std::fs::read(&grouped).unwrap(),
                    "{what} {name}"
                );
            }
        }
    }

    #[test]
    fn a_non_finite_row_or_a_failed_producer_leaves_the_previous_file_alone() {
        let dir = tempfile::tempdir().unwrap();
        let mut image = Image::filled(40, 30, [0.5; 3]);
        // Pixel (5, 17), in the third group of 7 rows, channel 2.
        image.pixels[3 * (17 * 40 + 5) + 2] = f32::NAN;
        for name in ["a.exr", "a.png"] {
            let path = dir.path().join(name);
            std::fs::write(&path, b"previous").unwrap();
            let message = save_rows(&path, (40, 30), BitDepth::Eight, |sink| {
                rows_of(&image, 7, sink)
            })
            .unwrap_err()
            .to_string();
            assert!(
                message.contains("pixel (5, 17) channel 2 is NaN"),
                "{name}: {message}"
            );
            // The producer's own error comes back as it was.
            let failed = save_rows(&path, (40, 30), BitDepth::Eight, |_| -> Result<()> {
                Err(Error::Usage("the frame failed".into()))
            })
            .unwrap_err();
            assert_eq!(failed.to_string(), "the frame failed", "{name}");
            assert_eq!(std::fs::read(&path).unwrap(), b"previous", "{name}");
        }
        assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 2);
    }

    #[test]
    fn rows_missing_or_out_of_order_write_nothing() {
        let dir = tempfile::tempdir().unwrap();
        let image = Image::filled(20, 30, [0.5; 3]);
        let row = 3 * 20;
        for name in ["a.exr", "a.png"] {
            let path = dir.path().join(name);
            std::fs::write(&path, b"previous").unwrap();
            type Producer<'a> = &'a dyn Fn(&mut RowSink) -> Result<()>;
            let attempts: [(&str, Producer); 4] = [
                ("too few", &|sink| sink(0, &image.pixels[..29 * row])),
                ("a gap", &|sink| {
                    sink(0, &image.pixels[..10 * row])?;
                    sink(11, &image.pixels[11 * row..])
                }),
                ("twice", &|sink| {
                    sink(0, &image.pixels)?;
                    sink(0, &image.pixels[..row])
                }),
                ("part of a row", &|sink| sink(0, &image.pixels[..row + 1])),
            ];
            for (what, produce) in attempts {
                let message = save_rows(&path, (20, 30), BitDepth::Eight, produce)
                    .unwrap_err()
                    .to_string();
                assert!(
                    message.contains(name) && message.contains("rows are not whole"),
                    "{name}, {what}: {message}"
                );
                assert_eq!(std::fs::read(&path).unwrap(), b"previous", "{name}, {what}");
            }
        }
        assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 2);
    }

    #[test]
    fn a_non_finite_value_past_the_first_band_of_a_group_is_placed_right() {
        // 400 pixels wide: a PNG band holds 54 rows, so a group of 64 rows is quantised in
        // two bands; the NaN is in the second, at pixel (7, 60), channel 1.
        let dir = tempfile::tempdir().unwrap();
        let mut image = Image::filled(400, 70, [0.5; 3]);
        image.pixels[3 * (60 * 400 + 7) + 1] = f32::NAN;
        for name in ["a.png", "a.exr"] {
            let path = dir.path().join(name);
            let message = save_rows(&path, (400, 70), BitDepth::Eight, |sink| {
                rows_of(&image, 64, sink)
            })
            .unwrap_err()
            .to_string();
            assert!(
                message.contains("pixel (7, 60) channel 1 is NaN"),
                "{name}: {message}"
            );
            assert!(!path.exists());
        }
    }

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

    #[test]
    fn alpha_is_composited_over_the_background() {
        let rgba = image::RgbaImage::from_raw(1, 1, vec![255, 0, 0, 51]).unwrap();
        let image = to_linear_rgb(&DynamicImage::ImageRgba8(rgba), [0.0, 0.0, 1.0]);
        let expected = [0.2, 0.0, 0.8];
        assert!(
            image
                .pixels
                .iter()
                .zip(expected)
                .all(|(a, b)| (a - b).abs() < 1e-6),
            "{:?}",
            image.pixels
        );
    }

    #[test]
    fn unsupported_extensions_are_named() {
        let message = ImageKind::from_path(Path::new("a/b.jpg"))
            .unwrap_err()
            .to_string();
        assert!(message.contains("b.jpg") && message.contains("unsupported"));
        assert_eq!(
            ImageKind::from_path(Path::new("x.EXR")).unwrap(),
            ImageKind::Exr
        );
    }
}
