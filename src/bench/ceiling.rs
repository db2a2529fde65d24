//! The ceiling probes: the ideal inner loop of each blend on this CPU, the figure every
//! measured render is a share of (pairs per second over the probe's, on the same threads in
//! the same run).
//!
//! - **Additive** ([`ceiling_probe`], SPEC §5): per pair `q = Qxx t² + row_q`,
//!   `G = exp(-½ q)` by the degree-5 polynomial, `acc += a G` in f32.
//! - **Alpha** ([`alpha_ceiling_probe`], SPEC §8): the same `q` and `G` in f32, then
//!   `α̂ = min(0.99, o G)`, `C += colour α̂ T`, `T ← T (1 - α̂)` in f64 (the renderer's
//!   precision), with no stop.
//!
//! Both run one row of 16 pixels whose accumulators stay in registers while every kernel
//! passes over it; the kernels' constants sit in L1; no binning, no pair test, no memory
//! traffic; every lane counts as a pair. Each loop is compiled for each [`SimdPath`] as the
//! renderer's loops are (the additive one with AVX2 intrinsics or portably, the alpha one as
//! one portable body per path), and [`measure_ceiling`] runs one probe per worker thread.

use std::time::Instant;

use crate::composite::clamped_alpha;
use crate::model::Result;
use crate::simd::{ROW, SimdPath, fast_exp_neg_half};

use super::measure::{BenchRow, thread_pool};

/// Which blend's ideal loop a probe runs.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Probe {
    /// [`ceiling_probe`].
    Additive,
    /// [`alpha_ceiling_probe`].
    Alpha,
}

impl Probe {
    /// Both probes, additive first.
    pub const ALL: [Probe; 2] = [Probe::Additive, Probe::Alpha];

    /// The probe a scene of `blend` is measured against.
    #[must_use]
    pub fn of(blend: crate::model::Blend) -> Self {
        match blend {
            crate::model::Blend::Additive => Probe::Additive,
            crate::model::Blend::Alpha => Probe::Alpha,
        }
    }

    /// Runs the probe on `path`: the pairs evaluated and a checksum.
    fn run(self, path: SimdPath, kernels: usize, passes: usize) -> (u64, f64) {
        match self {
            Probe::Additive => {
                let (pairs, checksum) = ceiling_probe(path, kernels, passes);
                (pairs, f64::from(checksum))
            }
            Probe::Alpha => alpha_ceiling_probe(path, kernels, passes),
        }
    }
}

impl std::fmt::Display for Probe {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            Probe::Additive => "ceiling probe",
            Probe::Alpha => "alpha ceiling probe",
        })
    }
}

/// `probe` on `threads` workers, each running its own probe on the widest SIMD path: total
/// pairs per second, the median of 3 runs of about 0.2 s.
pub fn measure_ceiling(probe: Probe, threads: usize) -> Result<f64> {
    use rayon::prelude::*;
    const KERNELS: usize = 256;
    let path = SimdPath::detect();
    let pool = thread_pool(threads)?;
    let run = |passes: usize| -> (f64, u64) {
        pool.install(|| {
            let start = Instant::now();
            let (pairs, checksum) = (0..threads.max(1))
                .into_par_iter()
                .map(|_| probe.run(path, KERNELS, passes))
                .reduce(|| (0, 0.0), |a, b| (a.0 + b.0, a.1 + b.1));
            std::hint::black_box(checksum);
            (start.elapsed().as_secs_f64(), pairs)
        })
    };
    let (seconds, _) = run(200);
    let passes = ((0.2 / seconds.max(1e-6)) * 200.0).clamp(200.0, 1e8) as usize;
    let mut rates: Vec<f64> = (0..3)
        .map(|_| {
            let (seconds, pairs) = run(passes);
            pairs as f64 / seconds
        })
        .collect();
    rates.sort_by(f64::total_cmp);
    Ok(rates[1])
}

/// One ceiling probe's measurement ([`super::ceiling::measure_ceiling`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Ceiling {
    /// The probe.
    pub probe: Probe,
    /// Worker threads it ran on.
    pub threads: usize,
    /// Its pairs per second.
    pub pairs_per_second: f64,
}

/// Fills each row's `efficiency` from the ceiling of its blend's probe on its threads.
pub fn fill_efficiencies(rows: &mut [BenchRow], ceilings: &[Ceiling]) {
    for row in rows {
        let probe = Probe::of(row.blend);
        row.efficiency = ceilings
            .iter()
            .find(|c| c.probe == probe && c.threads == row.threads)
            .map(|c| row.pairs_per_second / c.pairs_per_second);
    }
}

/// The ceiling probe: the ideal inner loop of an additive tile rasterizer on this CPU, to
/// measure [`crate::raster`] against (`splat4d bench --ceiling`). One row of 16 pixels, three
/// channels of f32 accumulators kept in registers while every one of `kernels` kernels
/// passes over it (`q = Qxx t² + row_q` with the sum fused, the degree-5 polynomial exp by
/// fused multiply-adds, `acc += a G` fused on the SIMD paths); the kernels' constants sit in
/// L1; no binning, no test, no memory traffic. Every lane counts as a pair. Compiled for
/// `path` like the renderer. Returns the pairs evaluated and a checksum
/// (so that the work cannot be optimised away).
///
/// # Panics
/// When the CPU lacks `path`'s instructions.
#[must_use]
pub fn ceiling_probe(path: SimdPath, kernels: usize, passes: usize) -> (u64, f32) {
    path.assert_available();
    // Kernels of a few pixels, centred near the row, with q in the exp's useful range.
    let constants: Vec<[f32; 6]> = (0..kernels.max(1))
        .map(|k| {
            let x = k as f32;
            [
                -7.5 + (x * 0.37) % 3.0,
                0.02 + (x * 0.013) % 0.1,
                (x * 0.21) % 2.0,
                0.3 + (x * 0.07) % 0.5,
                0.2,
                0.1,
            ]
        })
        .collect();
    let checksum = match path {
        #[cfg(target_arch = "x86_64")]
        // SAFETY: checked above.
        SimdPath::Avx512 => unsafe { avx512::ceiling(&constants, passes) },
        #[cfg(target_arch = "x86_64")]
        // SAFETY: checked above.
        SimdPath::Avx2 => unsafe { avx2::ceiling(&constants, passes) },
        _ => ceiling_portable(&constants, passes),
    };
    ((constants.len() * passes * ROW) as u64, checksum)
}

/// The portable [`ceiling_probe`] loop.
fn ceiling_portable(constants: &[[f32; 6]], passes: usize) -> f32 {
    let mut checksum = 0.0;
    for _ in 0..passes {
        let mut acc = [[0.0_f32; 3]; ROW];
        for &[t0, qxx, row_q, r, g, b] in constants {
            for (i, pixel) in acc.iter_mut().enumerate() {
                let t = t0 + i as f32;
                let value = fast_exp_neg_half((qxx * t).mul_add(t, row_q));
                pixel[0] += r * value;
                pixel[1] += g * value;
                pixel[2] += b * value;
            }
        }
        checksum += acc.iter().flatten().sum::<f32>();
    }
    checksum
}

/// [`ceiling_probe`]'s loop with AVX2 intrinsics.
#[cfg(target_arch = "x86_64")]
mod avx2 {
    use std::arch::x86_64::*;

    use crate::simd::avx2::exp_neg_half;

    /// [`super::ceiling_probe`]'s loop: 16 lanes as two registers, f32 accumulators.
    #[target_feature(enable = "avx2,fma")]
    pub(super) fn ceiling(constants: &[[f32; 6]], passes: usize) -> f32 {
        let iota_lo = _mm256_setr_ps(0.0, 1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0);
        let iota_hi = _mm256_add_ps(iota_lo, _mm256_set1_ps(8.0));
        let mut checksum = 0.0;
        for _ in 0..passes {
            let mut acc = [_mm256_setzero_ps(); 6];
            for &[t0, qxx, row_q, r, g, b] in constants {
                let (qxx, row_q) = (_mm256_set1_ps(qxx), _mm256_set1_ps(row_q));
                let amplitude = [_mm256_set1_ps(r), _mm256_set1_ps(g), _mm256_set1_ps(b)];
                for (h, iota) in [iota_lo, iota_hi].into_iter().enumerate() {
                    let t = _mm256_add_ps(iota, _mm256_set1_ps(t0));
                    let q = _mm256_fmadd_ps(_mm256_mul_ps(qxx, t), t, row_q);
                    let value = exp_neg_half(q);
                    for c in 0..3 {
                        acc[2 * c + h] = _mm256_fmadd_ps(amplitude[c], value, acc[2 * c + h]);
                    }
                }
            }
            let mut lanes = [0.0_f32; 8];
            for a in acc {
                // SAFETY: `lanes` holds 8 floats.
                unsafe { _mm256_storeu_ps(lanes.as_mut_ptr(), a) };
                checksum += lanes.iter().sum::<f32>();
            }
        }
        checksum
    }
}

/// [`ceiling_probe`]'s loop with AVX-512: the whole 16-pixel row is one register, as in the
/// renderer's AVX-512 rows.
#[cfg(target_arch = "x86_64")]
mod avx512 {
    use std::arch::x86_64::*;

    use crate::simd::avx512::exp_neg_half;

    /// [`super::ceiling_probe`]'s loop: 16 lanes in one register, f32 accumulators.
    #[target_feature(enable = "avx512f,avx512bw,avx512dq,avx512vl,avx2,fma,popcnt")]
    pub(super) fn ceiling(constants: &[[f32; 6]], passes: usize) -> f32 {
        let iota = _mm512_setr_ps(
            0.0, 1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0, 8.0, 9.0, 10.0, 11.0, 12.0, 13.0, 14.0, 15.0,
        );
        let mut checksum = 0.0;
        for _ in 0..passes {
            let mut acc = [_mm512_setzero_ps(); 3];
            for &[t0, qxx, row_q, r, g, b] in constants {
                let t = _mm512_add_ps(iota, _mm512_set1_ps(t0));
                let q = _mm512_fmadd_ps(
                    _mm512_mul_ps(_mm512_set1_ps(qxx), t),
                    t,
                    _mm512_set1_ps(row_q),
                );
                let value = exp_neg_half(q);
                for (acc, a) in acc.iter_mut().zip([r, g, b]) {
                    *acc = _mm512_fmadd_ps(_mm512_set1_ps(a), value, *acc);
                }
            }
            for a in acc {
                checksum += _mm512_reduce_add_ps(a);
            }
        }
        checksum
    }
}

/// The alpha blend's ceiling probe: the ideal inner loop of a front-to-back compositor on
/// this CPU, with the renderer's precision (SPEC §8: `G` in f32 by the fast exp, `α̂`, `T`
/// and the colour in f64), to measure [`crate::composite`] against (`splat4d bench --blend
/// alpha`). One row of 16 pixels whose colour and transmittance stay in registers while
/// every one of `kernels` kernels passes over it (`q = Qxx t² + row_q`, `α̂ = min(0.99,
/// o G)`, `C += colour α̂ T`, `T ← T (1 - α̂)`); the kernels' constants sit in L1; no
/// binning, no pair test, no stop, no memory traffic. Every lane counts as a pair. Compiled
/// for `path` like the renderer. Returns the pairs composited and a checksum (so that the
/// work cannot be optimised away).
///
/// # Panics
/// When the CPU lacks `path`'s instructions.
#[must_use]
pub fn alpha_ceiling_probe(path: SimdPath, kernels: usize, passes: usize) -> (u64, f64) {
    path.assert_available();
    // Kernels of a few pixels near the row, q in the exp's useful range, opacities that
    // keep T well above f64's smallest normal over a pass.
    let constants: Vec<ProbeKernel> = (0..kernels.max(1))
        .map(|k| {
            let x = k as f32;
            ProbeKernel {
                t0: -7.5 + (x * 0.37) % 3.0,
                qxx: 0.02 + (x * 0.013) % 0.1,
                row_q: (x * 0.21) % 2.0,
                opacity: 0.02 + f64::from((x * 0.11) % 0.2),
                colour: [0.3 + f64::from((x * 0.07) % 0.5), 0.2, 0.1],
            }
        })
        .collect();
    let checksum = match path {
        #[cfg(target_arch = "x86_64")]
        // SAFETY: checked above.
        SimdPath::Avx512 => unsafe { alpha_ceiling_avx512(&constants, passes) },
        #[cfg(target_arch = "x86_64")]
        // SAFETY: checked above.
        SimdPath::Avx2 => unsafe { alpha_ceiling_avx2(&constants, passes) },
        _ => alpha_ceiling_loop(&constants, passes),
    };
    ((constants.len() * passes * ROW) as u64, checksum)
}

/// One kernel of [`alpha_ceiling_probe`].
struct ProbeKernel {
    t0: f32,
    qxx: f32,
    row_q: f32,
    opacity: f64,
    colour: [f64; 3],
}

/// [`alpha_ceiling_loop`] compiled for AVX-512.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f,avx512bw,avx512dq,avx512vl,avx2,fma")]
fn alpha_ceiling_avx512(constants: &[ProbeKernel], passes: usize) -> f64 {
    alpha_ceiling_loop(constants, passes)
}

/// [`alpha_ceiling_loop`] compiled for AVX2 and FMA.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
fn alpha_ceiling_avx2(constants: &[ProbeKernel], passes: usize) -> f64 {
    alpha_ceiling_loop(constants, passes)
}

/// The loop of [`alpha_ceiling_probe`]: branch-free over the 16 lanes (vectorised by the
/// compiler on each path).
#[inline(always)]
fn alpha_ceiling_loop(constants: &[ProbeKernel], passes: usize) -> f64 {
    let mut checksum = 0.0;
    for _ in 0..passes {
        let mut colour = [[0.0_f64; ROW]; 3];
        let mut transmittance = [1.0_f64; ROW];
        for kernel in constants {
            let mut g = [0.0_f32; ROW];
            for (i, g) in g.iter_mut().enumerate() {
                let t = kernel.t0 + i as f32;
                *g = fast_exp_neg_half((kernel.qxx * t).mul_add(t, kernel.row_q));
            }
            for i in 0..ROW {
                let alpha = clamped_alpha(kernel.opacity, g[i]);
                let weight = alpha * transmittance[i];
                for (channel, &value) in colour.iter_mut().zip(&kernel.colour) {
                    channel[i] += value * weight;
                }
                transmittance[i] *= 1.0 - alpha;
            }
        }
        checksum += colour.iter().flatten().sum::<f64>() + transmittance.iter().sum::<f64>();
    }
    checksum
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::bench::measure::Renderer;
    use crate::model::Blend;

    #[test]
    fn the_ceiling_probe_counts_every_lane_and_agrees_across_paths() {
        let mut sums = Vec::new();
        for &path in SimdPath::available() {
            let (pairs, checksum) = ceiling_probe(path, 37, 3);
            assert_eq!(pairs, 37 * 3 * 16, "{path}");
            assert!(checksum.is_finite() && checksum > 0.0, "{path}: {checksum}");
            sums.push(checksum);
        }
        // f32 sums in another order: equal to rounding.
        for s in &sums {
            assert!((s / sums[0] - 1.0).abs() < 1e-5, "{sums:?}");
        }
    }

    #[test]
    fn the_alpha_ceiling_probe_counts_every_lane_and_agrees_across_paths() {
        let sums: Vec<f64> = SimdPath::available()
            .iter()
            .map(|&path| {
                let (pairs, checksum) = alpha_ceiling_probe(path, 37, 3);
                assert_eq!(pairs, 37 * 3 * 16, "{path}");
                assert!(checksum.is_finite() && checksum > 0.0, "{path}: {checksum}");
                checksum
            })
            .collect();
        // The same operations on every path: the same bits.
        assert!(
            sums.iter().all(|s| s.to_bits() == sums[0].to_bits()),
            "{sums:?}"
        );
    }

    fn row(blend: Blend, threads: usize) -> BenchRow {
        BenchRow {
            scene: "s".into(),
            blend,
            renderer: Renderer::Tiles,
            kernels: 1,
            size: (1, 1),
            threads,
            ms_per_frame: 1.0,
            pairs: 1,
            pairs_per_second: 100.0,
            max_error: 0.0,
            mean_error: 0.0,
            bound_ratio: 0.0,
            speedup: None,
            efficiency: None,
        }
    }

    #[test]
    fn each_row_is_a_share_of_its_own_blends_probe_on_its_threads() {
        let mut rows = [
            row(Blend::Additive, 1),
            row(Blend::Alpha, 1),
            row(Blend::Alpha, 2),
            row(Blend::Additive, 4),
        ];
        let ceiling = |probe, threads, pairs_per_second| Ceiling {
            probe,
            threads,
            pairs_per_second,
        };
        fill_efficiencies(
            &mut rows,
            &[
                ceiling(Probe::Additive, 1, 400.0),
                ceiling(Probe::Alpha, 1, 200.0),
                ceiling(Probe::Additive, 2, 1000.0),
                ceiling(Probe::Alpha, 2, 500.0),
            ],
        );
        let shares: Vec<Option<f64>> = rows.iter().map(|r| r.efficiency).collect();
        assert_eq!(shares, [Some(0.25), Some(0.5), Some(0.2), None]);
    }
}
