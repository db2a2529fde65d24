//! The instruction-set paths of the per-pixel loops and which of them this CPU runs:
//! detected once per process, the widest chosen unless `SPLAT4D_SIMD` names a narrower one;
//! and `on_path`, which runs a portable loop compiled for a path.
//! Not part of SPEC: every path gives the same bits (see the rule in [`super`]).

use std::fmt;

/// The instruction set the per-pixel loops are compiled for, chosen once per render from
/// what the CPU has. Every path runs the same operations in the same order (the fused
/// multiply-adds are written out, `mul_add` or FMA instructions, and none is formed by the
/// compiler; conversions are exact), so the image is the same bit for bit on every path;
/// only the vector width differs.
///
/// Not part of SPEC: every path gives the same bits (SPEC §5's sum, evaluated identically).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum SimdPath {
    /// Baseline x86-64 (SSE2) or any other architecture.
    Baseline,
    /// AVX2 and FMA (x86-64).
    Avx2,
    /// AVX-512 F/BW/DQ/VL with AVX2 and FMA (x86-64).
    Avx512,
}

impl SimdPath {
    /// The widest path this CPU runs, or a narrower one named by the environment variable
    /// `SPLAT4D_SIMD` (`baseline`, `avx2`, `avx512`: to measure the narrower paths on a
    /// wider CPU; a path the CPU lacks, or another value, is ignored). Read once per
    /// process.
    #[must_use]
    pub fn detect() -> Self {
        static CHOSEN: std::sync::OnceLock<SimdPath> = std::sync::OnceLock::new();
        *CHOSEN.get_or_init(|| {
            let widest = *Self::available()
                .last()
                .expect("the baseline is always available");
            std::env::var("SPLAT4D_SIMD")
                .ok()
                .and_then(|name| {
                    Self::available()
                        .iter()
                        .find(|path| path.to_string() == name)
                        .copied()
                })
                .unwrap_or(widest)
        })
    }

    /// Panics when this CPU cannot run the path: every `unsafe` call of a path's loops
    /// relies on this check.
    pub fn assert_available(self) {
        assert!(
            Self::available().contains(&self),
            "this CPU cannot run the {self} path"
        );
    }

    /// Every path this CPU runs, narrowest first (the tests compare them all). Detected
    /// once per process: renders ask at every frame.
    #[must_use]
    pub fn available() -> &'static [SimdPath] {
        static PATHS: std::sync::OnceLock<Vec<SimdPath>> = std::sync::OnceLock::new();
        PATHS.get_or_init(Self::detect_all)
    }

    fn detect_all() -> Vec<SimdPath> {
        let mut paths = vec![SimdPath::Baseline];
        #[cfg(target_arch = "x86_64")]
        {
            if is_x86_feature_detected!("avx2") && is_x86_feature_detected!("fma") {
                paths.push(SimdPath::Avx2);
                // The AVX-512 loops count pairs with POPCNT too (every AVX-512 CPU has it;
                // a virtual machine may hide it).
                if is_x86_feature_detected!("popcnt")
                    && is_x86_feature_detected!("avx512f")
                    && is_x86_feature_detected!("avx512bw")
                    && is_x86_feature_detected!("avx512dq")
                    && is_x86_feature_detected!("avx512vl")
                {
                    paths.push(SimdPath::Avx512);
                }
            }
        }
        paths
    }
}

/// A loop not written with intrinsics (an element-wise pass over a line of values, a
/// filter's taps), compiled for each path by [`on_path`].
pub(crate) trait LineJob {
    /// Does the line's work; implementations are `#[inline(always)]`, so that each path's
    /// copy is compiled with its target features.
    fn run(self);
}

/// Runs `job` compiled for `path`: inlined into a function with the path's target
/// features, so that its loops are vectorised at the path's width. Every operation is one
/// IEEE operation per element (no fused multiply-add is formed), so the same bits on every
/// path.
///
/// # Panics
/// When this CPU cannot run `path` (checked on every call: a few nanoseconds against a
/// line's work).
#[inline(always)]
pub(crate) fn on_path(path: SimdPath, job: impl LineJob) {
    path.assert_available();
    match path {
        #[cfg(target_arch = "x86_64")]
        // SAFETY: the CPU has the path (checked just above).
        SimdPath::Avx512 => unsafe { on_avx512(job) },
        #[cfg(target_arch = "x86_64")]
        // SAFETY: as above.
        SimdPath::Avx2 => unsafe { on_avx2(job) },
        _ => job.run(),
    }
}

/// [`on_path`]'s AVX-512 copy.
///
/// # Safety
/// The CPU must have AVX-512 F/BW/DQ/VL.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f,avx512bw,avx512dq,avx512vl,avx2")]
unsafe fn on_avx512(job: impl LineJob) {
    job.run();
}

/// [`on_path`]'s AVX2 copy.
///
/// # Safety
/// The CPU must have AVX2.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn on_avx2(job: impl LineJob) {
    job.run();
}

impl fmt::Display for SimdPath {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            SimdPath::Baseline => "baseline",
            SimdPath::Avx2 => "avx2",
            SimdPath::Avx512 => "avx512",
        })
    }
}
