//! Reading image files: PNG (8 or 16 bits), EXR and JPEG as linear RGB (integers divided by
//! `2^bits - 1`, no sRGB curve), alpha composited over a background; sizes from the header
//! alone before anything is decoded.

use std::path::Path;

use image::{DynamicImage, ImageFormat};

use crate::model::Image;
use crate::model::error::{Error, Result};
use crate::model::image::all_finite;

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
}
