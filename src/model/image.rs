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

/// The weighted box filter: per `n × n` block, the mean weight and the weighted mean colour
/// (the plain mean where every weight is 0).
#[must_use]
pub fn downscale_weighted(image: &Image, weights: &[f32], n: u32) -> (Image, Vec<f32>) {
    let (w, h) = (image.width / n, image.height / n);
    let mut pixels = Vec::with_capacity(3 * w as usize * h as usize);
    let mut out_weights = Vec::with_capacity(w as usize * h as usize);
    let inv = 1.0 / f64::from(n * n);
    let width = image.width as usize;
    for j in 0..h {
        for i in 0..w {
            let mut sum = [0.0_f64; 3];
            let mut plain = [0.0_f64; 3];
            let mut total = 0.0_f64;
            for dj in 0..n {
                for di in 0..n {
                    let (x, y) = (n * i + di, n * j + dj);
                    let weight = f64::from(weights[y as usize * width + x as usize]);
                    let p = image.pixel(x, y);
                    total += weight;
                    for c in 0..3 {
                        sum[c] += weight * f64::from(p[c]);
                        plain[c] += f64::from(p[c]);
                    }
                }
            }
            pixels.extend(if total > 0.0 {
                sum.map(|s| (s / total) as f32)
            } else {
                plain.map(|s| (s * inv) as f32)
            });
            out_weights.push((total * inv) as f32);
        }
    }
    (
        Image {
            width: w,
            height: h,
            pixels,
        },
        out_weights,
    )
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

/// A channel of an integer image file: 8 or 16 bits, `MAX` its largest level. Implemented
/// for `u8` and `u16` only (sealed).
pub trait Level: Copy + sealed::Sealed {
    /// The largest level, `2^bits - 1`.
    const MAX: u16;
    /// The level `v`, known to lie in `0..=MAX`.
    fn from_level(v: u16) -> Self;
    /// Stores sixteen levels, eight u16 lanes in each of `low` and `high`, at `out`.
    ///
    /// # Safety
    /// `out` must be valid for writes of sixteen `Self`.
    #[cfg(target_arch = "x86_64")]
    #[doc(hidden)]
    unsafe fn store16(
        low: std::arch::x86_64::__m128i,
        high: std::arch::x86_64::__m128i,
        out: *mut Self,
    );
}

mod sealed {
    pub trait Sealed {}
    impl Sealed for u8 {}
    impl Sealed for u16 {}
}

impl Level for u8 {
    const MAX: u16 = 255;
    fn from_level(v: u16) -> Self {
        v as u8
    }
    #[cfg(target_arch = "x86_64")]
    #[inline(always)]
    unsafe fn store16(
        low: std::arch::x86_64::__m128i,
        high: std::arch::x86_64::__m128i,
        out: *mut Self,
    ) {
        use std::arch::x86_64::{_mm_packus_epi16, _mm_storeu_si128};
        // Levels ≤ 255: the saturating pack is a plain narrowing.
        // SAFETY: the caller gives room for sixteen bytes.
        unsafe { _mm_storeu_si128(out.cast(), _mm_packus_epi16(low, high)) }
    }
}

impl Level for u16 {
    const MAX: u16 = 65535;
    fn from_level(v: u16) -> Self {
        v
    }
    #[cfg(target_arch = "x86_64")]
    #[inline(always)]
    unsafe fn store16(
        low: std::arch::x86_64::__m128i,
        high: std::arch::x86_64::__m128i,
        out: *mut Self,
    ) {
        use std::arch::x86_64::_mm_storeu_si128;
        // SAFETY: the caller gives room for sixteen u16.
        unsafe {
            _mm_storeu_si128(out.cast(), low);
            _mm_storeu_si128(out.add(8).cast(), high);
        }
    }
}

/// [`quantize`] of every channel of `pixels` at `T`'s depth (`u8`: 255, `u16`: 65535),
/// the same levels bit for bit. Every PNG written pays it once a channel (786 432 channels
/// at 512×512), so with AVX2 and FMA, or AVX-512 (chosen at run time), it runs sixteen
/// channels a step, in f64; elsewhere it is the scalar [`quantize`].
#[must_use]
pub fn quantize_all<T: Level>(pixels: &[f32]) -> Vec<T> {
    quantize_all_checked(pixels).0
}

/// [`quantize_all`], and whether every channel is finite, found in the same pass over the
/// pixels (a writer refuses non-finite images; the pass is bound by reading the pixels).
#[must_use]
pub fn quantize_all_checked<T: Level>(pixels: &[f32]) -> (Vec<T>, bool) {
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx512f")
        && std::arch::is_x86_feature_detected!("avx2")
        && std::arch::is_x86_feature_detected!("fma")
    {
        // SAFETY: the CPU supports the features `quantize_all_avx512` is compiled for.
        return unsafe { quantize_all_avx512(pixels) };
    }
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx2") && std::arch::is_x86_feature_detected!("fma") {
        // SAFETY: the CPU supports the features `quantize_all_avx2` is compiled for.
        return unsafe { quantize_all_avx2(pixels) };
    }
    (quantize_all_scalar(pixels), all_finite(pixels))
}

/// Whether every value is finite: blocks of 64 checked without an early exit vectorise.
#[must_use]
pub fn all_finite(values: &[f32]) -> bool {
    values
        .chunks(64)
        .all(|block| block.iter().fold(true, |ok, v| ok & v.is_finite()))
}

/// [`quantize_all`] one channel at a time by [`quantize`]: the definition, and the path
/// without AVX2.
fn quantize_all_scalar<T: Level>(pixels: &[f32]) -> Vec<T> {
    pixels
        .iter()
        .map(|&c| T::from_level(quantize(c, T::MAX)))
        .collect()
}

/// [`quantize_all`] with AVX2 and FMA, sixteen channels a step. The clamp is exact (in f32:
/// `max(c, 0)` gives 0 for NaN, the instruction returning its second operand, then
/// `min(·, 1)`). The level is then `trunc(fl(c·max + ½))`, one fused multiply-add in f64
/// and a truncation, and that is `⌊c·max + ½⌋`, [`quantize`]'s round half up. `fl` is
/// monotonic and whole numbers are exact, so it can only go wrong by carrying
/// `y = c·max + ½ < K + 1` up to `K + 1`: that needs `d = K + ½ − c·max` with
/// `0 < d ≤ (K + 1) 2^-53` (half an ulp of `K + 1`). Then `c·max ≥ (K + ½) / 2`, so `c` is
/// a normal f32 whose ulp `u > c 2^-24` is more than `(K + ½) 2^-25 / max ≥ (K + ½) 2^-41`
/// (`max ≤ 2^16`). `c·max` and `K + ½` are multiples of `u` (`u ≤ 2^-23`), so
/// `d ≥ u > (K + ½) 2^-41`, more than `(K + 1) 2^-53`: no carry. The level is a whole
/// number in `0..=max`, converted exactly; a test checks every f32 at both depths.
/// The tail (fewer than sixteen) goes through [`quantize`]. Also whether every channel is
/// finite: `c - c` is NaN exactly for NaN and the infinities.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
fn quantize_all_avx2<T: Level>(pixels: &[f32]) -> (Vec<T>, bool) {
    use std::arch::x86_64::{
        __m128, __m128i, _CMP_ORD_Q, _mm_packus_epi32, _mm256_and_ps, _mm256_castps256_ps128,
        _mm256_cmp_ps, _mm256_cvtps_pd, _mm256_cvttpd_epi32, _mm256_extractf128_ps,
        _mm256_fmadd_pd, _mm256_loadu_ps, _mm256_max_ps, _mm256_min_ps, _mm256_movemask_ps,
        _mm256_set1_pd, _mm256_set1_ps, _mm256_setzero_ps, _mm256_sub_ps,
    };
    let max = _mm256_set1_pd(f64::from(T::MAX));
    let half = _mm256_set1_pd(0.5);
    let (zero, one) = (_mm256_setzero_ps(), _mm256_set1_ps(1.0));
    // Four clamped channels → four levels (i32).
    let levels = |c: __m128| -> __m128i {
        _mm256_cvttpd_epi32(_mm256_fmadd_pd(_mm256_cvtps_pd(c), max, half))
    };
    let mut out: Vec<T> = Vec::with_capacity(pixels.len());
    let mut finite = _mm256_cmp_ps::<_CMP_ORD_Q>(zero, zero);
    let chunks = pixels.chunks_exact(16);
    let tail = chunks.remainder();
    for (k, chunk) in chunks.enumerate() {
        // SAFETY: `chunk` holds sixteen f32; `out` has capacity for `pixels.len()`, of which
        // this writes 16 k .. 16 k + 16.
        unsafe {
            let a = _mm256_loadu_ps(chunk.as_ptr());
            let b = _mm256_loadu_ps(chunk.as_ptr().add(8));
            // Ordered (neither NaN) exactly when both are finite.
            finite = _mm256_and_ps(
                finite,
                _mm256_cmp_ps::<_CMP_ORD_Q>(_mm256_sub_ps(a, a), _mm256_sub_ps(b, b)),
            );
            let a = _mm256_min_ps(_mm256_max_ps(a, zero), one);
            let b = _mm256_min_ps(_mm256_max_ps(b, zero), one);
            // i32 → u16 (levels ≤ 65535: a plain narrowing), in order.
            let low = _mm_packus_epi32(
                levels(_mm256_castps256_ps128(a)),
                levels(_mm256_extractf128_ps::<1>(a)),
            );
            let high = _mm_packus_epi32(
                levels(_mm256_castps256_ps128(b)),
                levels(_mm256_extractf128_ps::<1>(b)),
            );
            T::store16(low, high, out.as_mut_ptr().add(16 * k));
        }
    }
    let done = pixels.len() - tail.len();
    // SAFETY: the first `done` elements were written above.
    unsafe { out.set_len(done) };
    out.extend(tail.iter().map(|&c| T::from_level(quantize(c, T::MAX))));
    let finite = _mm256_movemask_ps(finite) == 0xff && all_finite(tail);
    (out, finite)
}

/// [`quantize_all_avx2`] with AVX-512: the same operations on sixteen channels a register
/// (eight f64 lanes a half), so the same levels bit for bit, and the same finite check
/// (`c - c` ordered), kept as a mask.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f,avx2,fma")]
fn quantize_all_avx512<T: Level>(pixels: &[f32]) -> (Vec<T>, bool) {
    use std::arch::x86_64::{
        __m256, __m256i, _CMP_ORD_Q, _mm256_castpd_ps, _mm256_castsi256_si128,
        _mm256_extracti128_si256, _mm512_castps_pd, _mm512_castps512_ps256, _mm512_castsi256_si512,
        _mm512_cmp_ps_mask, _mm512_cvtepi32_epi16, _mm512_cvtps_pd, _mm512_cvttpd_epi32,
        _mm512_extractf64x4_pd, _mm512_fmadd_pd, _mm512_inserti64x4, _mm512_loadu_ps,
        _mm512_max_ps, _mm512_min_ps, _mm512_set1_pd, _mm512_set1_ps, _mm512_setzero_ps,
        _mm512_sub_ps,
    };
    let max = _mm512_set1_pd(f64::from(T::MAX));
    let half = _mm512_set1_pd(0.5);
    let (zero, one) = (_mm512_setzero_ps(), _mm512_set1_ps(1.0));
    // Eight clamped channels → eight levels (i32).
    let levels = |c: __m256| -> __m256i {
        _mm512_cvttpd_epi32(_mm512_fmadd_pd(_mm512_cvtps_pd(c), max, half))
    };
    let mut out: Vec<T> = Vec::with_capacity(pixels.len());
    let mut finite = 0xffff_u16;
    let chunks = pixels.chunks_exact(16);
    let tail = chunks.remainder();
    for (k, chunk) in chunks.enumerate() {
        // SAFETY: `chunk` holds sixteen f32; `out` has capacity for `pixels.len()`, of which
        // this writes 16 k .. 16 k + 16.
        unsafe {
            let c = _mm512_loadu_ps(chunk.as_ptr());
            let d = _mm512_sub_ps(c, c);
            finite &= _mm512_cmp_ps_mask::<_CMP_ORD_Q>(d, d);
            let c = _mm512_min_ps(_mm512_max_ps(c, zero), one);
            let low = levels(_mm512_castps512_ps256(c));
            let high = levels(_mm256_castpd_ps(_mm512_extractf64x4_pd::<1>(
                _mm512_castps_pd(c),
            )));
            // 16 × i32 → 16 × u16 (levels ≤ 65535: a plain narrowing), in order.
            let both = _mm512_inserti64x4::<1>(_mm512_castsi256_si512(low), high);
            let narrow = _mm512_cvtepi32_epi16(both);
            T::store16(
                _mm256_castsi256_si128(narrow),
                _mm256_extracti128_si256::<1>(narrow),
                out.as_mut_ptr().add(16 * k),
            );
        }
    }
    let done = pixels.len() - tail.len();
    // SAFETY: the first `done` elements were written above.
    unsafe { out.set_len(done) };
    out.extend(tail.iter().map(|&c| T::from_level(quantize(c, T::MAX))));
    (out, finite == 0xffff && all_finite(tail))
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

    /// Every f32 bit pattern at both depths: the dispatched path against [`quantize`] (6 s
    /// on two cores once built: `cargo test --release -- --ignored every_f32`).
    #[test]
    #[ignore = "exhaustive: every f32 at both depths"]
    fn quantize_all_gives_quantize_of_every_f32() {
        use rayon::prelude::*;
        let blocks = 1_u64 << 12;
        let mismatches: u64 = (0..blocks)
            .into_par_iter()
            .map(|block| {
                let size = (1_u64 << 32) / blocks;
                let values: Vec<f32> = (block * size..(block + 1) * size)
                    .map(|bits| f32::from_bits(bits as u32))
                    .collect();
                let eight = quantize_all::<u8>(&values);
                let sixteen = quantize_all::<u16>(&values);
                values
                    .iter()
                    .zip(eight.iter().zip(&sixteen))
                    .filter(|&(&c, (&l8, &l16))| {
                        u16::from(l8) != quantize(c, 255) || l16 != quantize(c, 65535)
                    })
                    .count() as u64
            })
            .sum();
        assert_eq!(mismatches, 0);
    }

    /// Values around every half step of both depths, the specials (NaN of both signs and
    /// other payloads, infinities, zeros, subnormals, the largest finite), negatives, values
    /// above 1 and a spread of bit patterns over the whole f32 range.
    fn awkward_values() -> Vec<f32> {
        let mut values = vec![
            f32::NAN,
            -f32::NAN,
            f32::from_bits(0x7fc0_1234),
            f32::from_bits(0xffa0_0001),
            f32::from_bits(0x7f80_0001),
            f32::INFINITY,
            f32::NEG_INFINITY,
            0.0,
            -0.0,
            f32::MIN_POSITIVE,
            f32::from_bits(1),
            -f32::from_bits(1),
            f32::MAX,
            f32::MIN,
            1.0,
            -1.0,
            0.5,
            1.5,
            255.0,
            65535.0,
            1e30,
            -1e-30,
        ];
        for max in [255_u16, 65535] {
            for step in 0..=u32::from(max) {
                for centre in [f64::from(step), f64::from(step) + 0.5] {
                    let bits = ((centre / f64::from(max)) as f32).to_bits();
                    values.extend((bits.saturating_sub(2)..=bits + 2).map(f32::from_bits));
                }
            }
        }
        // Every 4099th bit pattern: all exponents, both signs, NaN payloads.
        values.extend((0..=u32::MAX).step_by(4099).map(f32::from_bits));
        values
    }

    #[test]
    fn quantize_all_gives_quantize_of_every_channel_at_both_depths() {
        let values = awkward_values();
        assert!(values.len() > 1_000_000);
        let expected8: Vec<u8> = values.iter().map(|&c| quantize(c, 255) as u8).collect();
        let expected16: Vec<u16> = values.iter().map(|&c| quantize(c, 65535)).collect();
        // The dispatched path, the scalar path, and (where the CPU has them) the AVX2 and
        // AVX-512 paths.
        assert_eq!(quantize_all::<u8>(&values), expected8);
        assert_eq!(quantize_all::<u16>(&values), expected16);
        assert_eq!(quantize_all_scalar::<u8>(&values), expected8);
        assert_eq!(quantize_all_scalar::<u16>(&values), expected16);
        #[cfg(target_arch = "x86_64")]
        if std::arch::is_x86_feature_detected!("avx2") && std::arch::is_x86_feature_detected!("fma")
        {
            // SAFETY: the CPU supports AVX2 and FMA.
            let (fast8, fast16) = unsafe {
                (
                    quantize_all_avx2::<u8>(&values).0,
                    quantize_all_avx2::<u16>(&values).0,
                )
            };
            assert_eq!(fast8, expected8);
            assert_eq!(fast16, expected16);
        }
        #[cfg(target_arch = "x86_64")]
        if std::arch::is_x86_feature_detected!("avx512f")
            && std::arch::is_x86_feature_detected!("avx2")
            && std::arch::is_x86_feature_detected!("fma")
        {
            // SAFETY: the CPU supports AVX-512F, AVX2 and FMA.
            let (fast8, fast16) = unsafe {
                (
                    quantize_all_avx512::<u8>(&values).0,
                    quantize_all_avx512::<u16>(&values).0,
                )
            };
            assert_eq!(fast8, expected8);
            assert_eq!(fast16, expected16);
        }
        // Every length's tail (the vector loop's remainder) as well.
        for n in 0..40 {
            assert_eq!(quantize_all::<u8>(&values[..n]), expected8[..n]);
        }
        // The finite check of the same pass: one NaN or infinity anywhere, in a block or in
        // the tail, is found.
        let finite: Vec<f32> = (0..100).map(|k| k as f32 * 0.013 - 0.2).collect();
        for n in [0, 1, 15, 16, 17, 33, 100] {
            assert!(quantize_all_checked::<u8>(&finite[..n]).1, "{n}");
        }
        for bad in [f32::NAN, -f32::NAN, f32::INFINITY, f32::NEG_INFINITY] {
            for at in [0, 7, 8, 15, 16, 31, 95, 99] {
                let mut values = finite.clone();
                values[at] = bad;
                let (levels, ok) = quantize_all_checked::<u16>(&values);
                assert!(!ok, "{bad} at {at}");
                assert_eq!(levels, quantize_all_scalar::<u16>(&values));
                assert!(!all_finite(&values));
            }
        }
        // Spot checks of the definition itself.
        let specials = [f32::NAN, -1.0, f32::INFINITY, 0.5, 2.0 / 255.0];
        assert_eq!(quantize_all::<u8>(&specials), [0, 0, 255, 128, 2]);
    }
}
