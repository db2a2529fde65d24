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

    /// The pixels of the image's border (first and last row and column), each once, row by
    /// row.
    pub fn border_pixels(&self) -> impl Iterator<Item = [f32; 3]> + '_ {
        let (w, h) = (self.width, self.height);
        (0..h).flat_map(move |j| {
            (0..w)
                .filter(move |&i| i == 0 || j == 0 || i + 1 == w || j + 1 == h)
                .map(move |i| self.pixel(i, j))
        })
    }

    /// `[r, g, b]` of pixel `(i, j)`.
    #[must_use]
    pub fn pixel(&self, i: u32, j: u32) -> [f32; 3] {
        let k = 3 * (j as usize * self.width as usize + i as usize);
        [self.pixels[k], self.pixels[k + 1], self.pixels[k + 2]]
    }

    /// The mean of each `n × n` block (a box filter, summed in f64); the image shrinks to
    /// `⌊w/n⌋ × ⌊h/n⌋`.
    #[must_use]
    pub fn downscaled(&self, n: u32) -> Image {
        if n == 1 {
            return self.clone();
        }
        let (w, h) = (self.width / n, self.height / n);
        let mut pixels = Vec::with_capacity(3 * w as usize * h as usize);
        let inv = 1.0 / f64::from(n * n);
        for j in 0..h {
            for i in 0..w {
                let mut sum = [0.0_f64; 3];
                for dj in 0..n {
                    for di in 0..n {
                        let p = self.pixel(n * i + di, n * j + dj);
                        for c in 0..3 {
                            sum[c] += f64::from(p[c]);
                        }
                    }
                }
                pixels.extend(sum.map(|s| (s * inv) as f32));
            }
        }
        Image {
            width: w,
            height: h,
            pixels,
        }
    }
}

/// The stored value of a linear channel in a file of `max + 1` levels (SPEC §5):
/// `round(max · clamp(c, 0, 1))`, rounding half away from zero; NaN stores 0.
#[must_use]
pub fn quantize(c: f32, max: u16) -> u16 {
    // clamp(c, 0, 1) with NaN to 0 (`c > 0` is false for NaN), branch-free.
    let clamped = if c > 0.0 { f64::from(c).min(1.0) } else { 0.0 };
    let v = clamped * f64::from(max);
    // `v.round()` for v ≥ 0 without the libm call (a per-channel cost of every PNG): the
    // integer part by truncation, then up when the exact fractional part reaches ½.
    let whole = v as u16;
    whole + u16::from(v - f64::from(whole) >= 0.5)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn quantize_rounds_as_round_does_on_every_f32_near_the_half_steps() {
        let mut checked = 0;
        for max in [255_u16, 65535] {
            for step in 0..=u32::from(max) {
                let centre = (f64::from(step) + 0.5) / f64::from(max);
                let bits = (centre as f32).to_bits();
                for b in bits.saturating_sub(4)..=bits + 4 {
                    let c = f32::from_bits(b);
                    let v = f64::from(c).clamp(0.0, 1.0) * f64::from(max);
                    assert_eq!(quantize(c, max), v.round() as u16, "{c:e} at {max}");
                    checked += 1;
                }
            }
        }
        assert!(checked > 500_000);
    }
}
