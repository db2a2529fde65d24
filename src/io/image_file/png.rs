//! PNG files: 8 or 16 bits per channel, RGB, written from rows as they are made
//! ([`super::save_rows`]): encoded in memory a band of rows at a time, then written with
//! their length known.

use std::io::Write;
use std::path::Path;

use image::{ImageBuffer, ImageFormat, Rgb};

use crate::io::{write_atomically, write_atomically_sized};
use crate::model::Image;
use crate::model::error::{Error, Result};
use crate::model::image::quantize_all_checked;

use super::{BitDepth, NotFinite, RowCount, RowSink, image_rows};

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

/// `image` encoded as a PNG at `depth` into `out` ([`super::encode_image`]).
pub(super) fn encode_png_image(
    image: &Image,
    depth: BitDepth,
    out: &mut impl Write,
) -> std::io::Result<()> {
    let size = (image.width, image.height);
    let png = encode_png(Path::new("<memory>"), size, depth, |sink| {
        image_rows(image, sink)
    })
    .map_err(std::io::Error::other)?;
    out.write_all(&png.bytes)
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

/// [`super::save_rows`] for a PNG: the rows encoded as they arrive ([`encode_png`]) and the
/// file written once encoded, or nothing when a value is not finite. A PNG whose compressed
/// data came out larger than its scanlines stored is encoded again, stored, with `produce`
/// run again.
pub(super) fn save_png_rows<T>(
    path: &Path,
    (width, height): (u32, u32),
    depth: BitDepth,
    mut produce: impl FnMut(&mut RowSink) -> Result<T>,
) -> Result<T> {
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::io::image_file::save_image;
    use crate::model::image::quantize;

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
}
