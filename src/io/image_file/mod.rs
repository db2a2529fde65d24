//! Images on disk (SPEC §5): linear values, no sRGB curve either way.
//!
//! - `.exr`: float32 linear RGB, values as rendered (no clamp) ([`exr`]).
//! - `.png`: 8-bit stores `round(255 clamp(C, 0, 1))`, 16-bit `round(65535 clamp(C, 0, 1))`,
//!   rounding half away from zero ([`png`]).
//!
//! Reading ([`read`]) returns `value / (2^bits - 1)` for integer files and the stored value
//! for float files; an image with alpha is composited over a background colour,
//! `a C + (1 - a) b`. Writing takes an image's rows as they are made ([`save_rows`]), so that
//! no image needs to be whole in memory; this file holds what both writers share: the row
//! hand-over and its checks.

pub mod exr;
pub mod png;
pub mod read;

use std::io::{Seek, Write};
use std::path::Path;

use crate::model::Image;
use crate::model::error::{Error, Result};
use crate::parallel::Drain;

pub use png::save_rgb8_png;
pub use read::{image_size, load_image, load_image_with_alpha, to_linear_rgb};

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
        ImageKind::Exr => exr::encode_exr(image, out),
        ImageKind::Png => png::encode_png_image(image, depth, out),
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
/// as its rows arrive, its levels a band at a time, then written
/// (`png::save_png_rows`); an EXR's rows go into its temporary file as they arrive
/// (`exr::save_exr_rows`). Nothing non-finite leaves: an EXR would hold inf, a PNG a
/// clamped lie; the first such value is named in the error, and nothing is written. Both
/// are written with their length known beforehand ([`crate::io::write_atomically_sized`]).
pub fn save_rows<T>(
    path: &Path,
    size: (u32, u32),
    depth: BitDepth,
    produce: impl FnMut(&mut RowSink) -> Result<T>,
) -> Result<T> {
    match ImageKind::from_path(path)? {
        ImageKind::Png => png::save_png_rows(path, size, depth, produce),
        ImageKind::Exr => exr::save_exr_rows(path, size, produce),
    }
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
