//! `G = exp(-½ q)` in f32, as every per-pixel loop evaluates it (SPEC §5, precision: the
//! per-pixel evaluation of `exp`): by libm ([`ExpMode::Std`]) or by an inlined range
//! reduction and degree-5 polynomial ([`ExpMode::Poly`], [`fast_exp_neg_half`]), whose fused
//! steps are the ones the AVX2 and AVX-512 twins (`super::avx2::exp_neg_half`,
//! `super::avx512::exp_neg_half`) take with FMA instructions: the same bits on every path.

use std::fmt;
use std::str::FromStr;

/// How the per-pixel loops evaluate `G = exp(-½ q)` in f32.
///
/// The default is [`ExpMode::Poly`], on the whole speed-against-error front of `splat4d
/// bench --sweep` at the same error against the f64 reference's model: it is evaluated a
/// vector of lanes at a time with the rest of the loop, where `Std` calls libm once per lane
/// (the time each takes: `docs/performance.md`, "The ceiling probe and the raster").
///
/// SPEC §5 (precision: the per-pixel evaluation of `exp`).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum ExpMode {
    /// The standard library's `f32::exp` (libm, within 1 ulp), one call per pair.
    Std,
    /// [`fast_exp_neg_half`]: inlined range reduction and a degree-5 polynomial by fused
    /// multiply-adds, relative error ≤ 2.14e-7 (measured; tested at 4e-7).
    #[default]
    Poly,
}

impl ExpMode {
    /// Every mode, for sweeps.
    pub const ALL: [ExpMode; 2] = [ExpMode::Std, ExpMode::Poly];
}

impl fmt::Display for ExpMode {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            ExpMode::Std => "std",
            ExpMode::Poly => "poly",
        })
    }
}

impl FromStr for ExpMode {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s {
            "std" => Ok(ExpMode::Std),
            "poly" => Ok(ExpMode::Poly),
            _ => Err(format!("unknown exp mode {s:?} (expected std or poly)")),
        }
    }
}

/// `exp(-½ q)` for `q ≥ 0` without a library call: `x = -½ q = n ln 2 + r` with
/// `|r| ≤ ½ ln 2` (Cody–Waite, two-part ln 2), `e^r` by a degree-5 polynomial fitted to the
/// relative error on that interval (7.7e-8 in exact arithmetic), and `2^n` assembled in the
/// exponent bits. `x` is clamped at -87 so `2^n` stays a normal f32: for `q > 174` the result
/// is about 1e-38 instead of less (never a subnormal). Relative error ≤ 4e-7 for
/// `0 ≤ q ≤ 174` (tested against f64).
///
/// The range reduction's two products and the Horner steps are fused multiply-adds
/// (`f32::mul_add`, one rounding each), as each SIMD path computes them with its FMA
/// instructions, so every path gives these bits: 8 operations fewer than separate products
/// and sums (at most 7 roundings fewer: `n ln2_hi` is exact), and a dependent chain of 12
/// steps instead of 19. Compiled without FMA (the baseline path) `mul_add` is a call to a
/// software `fmaf`: exact, and slow (what it costs the baseline path: `docs/performance.md`).
///
/// **Without forming `x`.** The steps work on `y = min(q, 174) = -2 x` and `r' = -2 r`
/// instead, with the constants scaled by powers of two (`exp_constants` in the source):
/// scaling by a power of two commutes with rounding away from underflow and overflow, so
/// each step rounds `(-½)^k` times the value the steps on `x` and `r` round, and the result
/// is the same bits. (A subnormal `q`, whose `-½ q` rounds, gives 1 both ways.) That saves
/// the product `-½ q`: one vector instruction of the 19 that a row entry spends on the FMA
/// pipes. Checked on all 2³² f32 inputs against the steps on
/// `x` (none differs), and against f64 by the tests.
#[inline(always)]
#[must_use]
pub fn fast_exp_neg_half(q: f32) -> f32 {
    use exp_constants::{HORNER, LN2_HI_TWICE, LN2_LO_TWICE, LOG2_E_NEG_HALF, Q_MAX, SHIFT};
    let y = q.min(Q_MAX);
    // `n = round(x log2 e)`: adding 1.5·2²³ rounds to the nearest integer (and vectorises,
    // unlike `f32::round`).
    let shifted = y.mul_add(LOG2_E_NEG_HALF, SHIFT);
    let n = shifted - SHIFT;
    let r = n.mul_add(LN2_LO_TWICE, n.mul_add(LN2_HI_TWICE, y));
    let p = r.mul_add(HORNER[0], HORNER[1]);
    let p = r.mul_add(p, HORNER[2]);
    let p = r.mul_add(p, HORNER[3]);
    let p = r.mul_add(p, HORNER[4]);
    let p = r.mul_add(p, HORNER[5]);
    // `shifted`'s low mantissa bits hold n exactly (|n| < 2²²): integer operations only, which
    // vectorise (`n as i32` is a saturating conversion and does not).
    let n_int = shifted.to_bits().wrapping_sub(SHIFT.to_bits()) as i32;
    let scale = f32::from_bits(((n_int + 127) as u32) << 23);
    p * scale
}

/// The constants of [`fast_exp_neg_half`], shared by every path's loop. The reduction and
/// the polynomial are written for `x = -½ q` and `r`; the steps run on `-2 x` and `-2 r`,
/// so each constant a step meets is the written one times a power of two (exact).
pub(crate) mod exp_constants {
    /// `log2 e`, times the `-½` that turns `y = -2 x` back into `x`.
    pub(crate) const LOG2_E_NEG_HALF: f32 = -0.5 * std::f32::consts::LOG2_E;
    /// ln 2 in two parts (`n ln2_hi` is exact for the `n` that occur), each times 2.
    pub(crate) const LN2_HI_TWICE: f32 = 2.0 * 0.693_145_75;
    /// The low part of ln 2, times 2.
    pub(crate) const LN2_LO_TWICE: f32 = 2.0 * 1.428_606_8e-6;
    /// `1.5·2²³`: added, it rounds to the nearest integer.
    pub(crate) const SHIFT: f32 = 12_582_912.0;
    /// The clamp of `q` (`x ≥ -87`).
    pub(crate) const Q_MAX: f32 = 174.0;
    /// The polynomial `c0 + r (c1 + r (c2 + r (c3 + r (c4 + r c5))))` in `r' = -2 r`:
    /// `c5 (-½)⁵, c4 (-½)⁴, …, c0`, highest first.
    pub(crate) const HORNER: [f32; 6] = [
        -0.008_291_717 / 32.0,
        0.041_915_03 / 16.0,
        -0.166_676_63 / 8.0,
        0.499_989 / 4.0,
        -0.999_999_64 / 2.0,
        1.000_000_1,
    ];
}

/// `exp(-½ q)` as `mode` says; `FAST` is `mode == ExpMode::Poly`, a constant so that each
/// loop is compiled once per mode with no branch inside.
#[inline(always)]
pub(crate) fn gaussian<const FAST: bool>(q: f32) -> f32 {
    if FAST {
        fast_exp_neg_half(q)
    } else {
        (-0.5 * q).exp()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fast_exp_is_within_its_documented_relative_error() {
        // Dense over [0, 174] plus the interval ends of the range reduction.
        let mut worst = 0.0_f64;
        let mut q = 0.0_f32;
        while q <= 174.0 {
            let exact = (-0.5 * f64::from(q)).exp();
            let error = (f64::from(fast_exp_neg_half(q)) / exact - 1.0).abs();
            worst = worst.max(error);
            q = (q + 1e-3).max(q.next_up());
        }
        eprintln!("fast exp: worst relative error {worst:e}");
        assert!(worst <= 4e-7, "relative error {worst:e}");
        // Beyond the clamp: tiny, normal, never NaN; exactly 1 at 0.
        for q in [175.0_f32, 1e3, 1e30, f32::INFINITY] {
            let g = fast_exp_neg_half(q);
            assert!(g.is_normal() && g < 1e-37, "{q}: {g:e}");
        }
        assert!((fast_exp_neg_half(0.0) - 1.0).abs() <= 2.0 * f32::EPSILON);
    }

    /// The exp's steps on `x = -½ q` and `r`, as written before they ran on `-2 x` and
    /// `-2 r`: the definition [`fast_exp_neg_half`] must keep bit for bit.
    fn exp_neg_half_on_x(q: f32) -> f32 {
        const SHIFT: f32 = 12_582_912.0;
        let x = (-0.5 * q).max(-87.0);
        let shifted = x.mul_add(std::f32::consts::LOG2_E, SHIFT);
        let n = shifted - SHIFT;
        let r = (-n).mul_add(1.428_606_8e-6, (-n).mul_add(0.693_145_75, x));
        let p = r.mul_add(0.008_291_717, 0.041_915_03);
        let p = r.mul_add(p, 0.166_676_63);
        let p = r.mul_add(p, 0.499_989);
        let p = r.mul_add(p, 0.999_999_64);
        let p = r.mul_add(p, 1.000_000_1);
        let n_int = shifted.to_bits().wrapping_sub(SHIFT.to_bits()) as i32;
        p * f32::from_bits(((n_int + 127) as u32) << 23)
    }

    #[test]
    fn the_exp_on_scaled_steps_gives_the_exp_on_x_bit_for_bit() {
        // Dense over [0, 200] (past the clamp), every 4099th bit pattern of every f32
        // (negatives and NaNs included), and the specials. All 2³² agree as well (checked
        // once, 5 s on two cores: too long for the suite).
        let mut q = 0.0_f32;
        let mut checked = 0;
        while q <= 200.0 {
            assert_eq!(
                fast_exp_neg_half(q).to_bits(),
                exp_neg_half_on_x(q).to_bits(),
                "{q:e}"
            );
            q = (q + 1e-4).max(q.next_up());
            checked += 1;
        }
        let specials = [
            0.0,
            -0.0,
            f32::INFINITY,
            f32::NEG_INFINITY,
            f32::NAN,
            f32::MIN_POSITIVE,
            f32::from_bits(1),
            f32::from_bits(0x0040_0001),
            174.0,
            174.0_f32.next_up(),
            174.0_f32.next_down(),
            f32::MAX,
        ];
        let sampled = (0..=u32::MAX).step_by(4099).map(f32::from_bits);
        for q in specials.into_iter().chain(sampled) {
            let (new, old) = (fast_exp_neg_half(q), exp_neg_half_on_x(q));
            assert!(
                new.to_bits() == old.to_bits(),
                "{q:e}: {new:e} against {old:e}"
            );
            checked += 1;
        }
        assert!(checked > 2_900_000);
    }

    #[test]
    fn exp_modes_parse_and_print_as_written() {
        for mode in ExpMode::ALL {
            assert_eq!(mode.to_string().parse::<ExpMode>(), Ok(mode));
        }
        assert!("fast".parse::<ExpMode>().is_err());
    }
}
