//! Images: linear RGB, row-major, three interleaved f32 per pixel (SPEC §5: no sRGB curve).
//!
//! Pixel `(i, j)` is column `i`, row `j`, with its centre at `(i + 0.5, j + 0.5)` (SPEC §3).

/// A linear RGB image, row-major, 3 interleaved f32 per pixel.
///
/// SPEC §5: linear values, no sRGB curve; pixel `(i, j)` has its centre at `(i + ½, j + ½)`
/// (SPEC §3).
///
/// ```
/// use splat4d::Image;
/// let image = Image::filled(4, 3, [0.5, 0.25, 0.0]);
/// assert_eq!(image.pixel(3, 2), [0.5, 0.25, 0.0]);
/// ```
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Image {
    /// Width in pixels.
    pub width: u32,
    /// Height in pixels.
    pub height: u32,
    /// `[r, g, b]` of pixel `(i, j)` at `3 (j width + i)`.
    pub pixels: Vec<f32>,
}

impl Image {
    /// A `width × height` image filled with `colour`.
    #[must_use]
    pub fn filled(width: u32, height: u32, colour: [f32; 3]) -> Self {
        let n = width as usize * height as usize;
        Image {
            width,
            height,
            pixels: colour.iter().copied().cycle().take(3 * n).collect(),
        }
    }

    /// `[r, g, b]` of pixel `(i, j)`.
    #[must_use]
    pub fn pixel(&self, i: u32, j: u32) -> [f32; 3] {
        let k = 3 * (j as usize * self.width as usize + i as usize);
        [self.pixels[k], self.pixels[k + 1], self.pixels[k + 2]]
    }
}

/// The stored value of a linear channel in a file of `max + 1` levels (SPEC §5):
/// `round(max · clamp(c, 0, 1))`, rounding half away from zero; NaN stores 0.
#[must_use]
pub fn quantize(c: f32, max: u16) -> u16 {
    let v = f64::from(c).clamp(0.0, 1.0) * f64::from(max);
    if v.is_nan() { 0 } else { v.round() as u16 }
}
