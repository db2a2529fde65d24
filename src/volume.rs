//! The Eq. 1 sum evaluated on a 3D grid at time τ (the seed paper's Fig. 1 and §5.2):
//!
//! ```text
//! V(p, τ) = Σ_i [q_i(p) ≤ qmax_i] ā_i(τ) exp(-½ q_i(p)),   q_i(p) = (p - m_i)ᵀ Σ3_i⁻¹ (p - m_i)
//! ```
//!
//! with the slice of SPEC §2 (`m_i`, `Σ3_i`, `a_i(τ)`), `ā` the mean of the three channels,
//! and the cut-off of SPEC §5 applied in 3D (`qmax = 2 ln(max|a|/ε)`; ε = 0 sums everything).
//! Cell centres are `min + (i + ½) h`. Each kernel visits only the cells inside the exact
//! axis-aligned bound of its ellipsoid `q ≤ qmax`, `|Δx_a| ≤ √(qmax Σ3_aa)`; z-slabs run in
//! parallel and each cell sums its kernels in ascending order, so the result does not depend
//! on the thread count. Per-kernel work in f64, per-cell sums in f32.
//!
//! For alpha scenes (SPEC §8) the grid holds the opacity density `Σ_i [q ≤ qmax] o_i(τ)
//! exp(-½ q_i(p))` instead (`ā` replaced by `o(τ) = o w(τ)`, the cut-off on `o(τ)`).

use glam::{DMat3, DVec3};
use rayon::prelude::*;

use crate::model::scene::{Blend, Scene};
use crate::slice::{SlicedKernels, slice};

/// A cubic grid of `res³` cells over an axis-aligned box.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Grid {
    /// Lower corner.
    pub min: [f64; 3],
    /// Upper corner.
    pub max: [f64; 3],
    /// Cells per axis.
    pub res: usize,
}

impl Grid {
    /// Centre of cell `i` along `axis`.
    #[must_use]
    pub fn centre(&self, axis: usize, i: usize) -> f64 {
        self.min[axis] + (i as f64 + 0.5) * (self.max[axis] - self.min[axis]) / self.res as f64
    }
}

/// Values on a grid, x fastest: cell `(x, y, z)` at `(z res + y) res + x`.
#[derive(Clone, Debug, PartialEq)]
pub struct Volume {
    /// The grid.
    pub grid: Grid,
    /// One value per cell.
    pub values: Vec<f32>,
}

impl Volume {
    /// Value of cell `(x, y, z)`.
    #[must_use]
    pub fn at(&self, x: usize, y: usize, z: usize) -> f32 {
        let r = self.grid.res;
        self.values[(z * r + y) * r + x]
    }

    /// Largest and smallest value.
    #[must_use]
    pub fn range(&self) -> (f32, f32) {
        self.values
            .iter()
            .fold((f32::NEG_INFINITY, f32::INFINITY), |(hi, lo), &v| {
                (hi.max(v), lo.min(v))
            })
    }

    /// The cell `(x, y, z)` holding the largest value (the first, in storage order).
    #[must_use]
    pub fn peak_cell(&self) -> [usize; 3] {
        let r = self.grid.res;
        let k =
            self.values.iter().enumerate().fold(
                0,
                |best, (k, &v)| if v > self.values[best] { k } else { best },
            );
        [k % r, (k / r) % r, k / (r * r)]
    }

    /// The axis-aligned slices through cell `[cx, cy, cz]`: `[xy at z = cz, xz at y = cy,
    /// yz at x = cx]`, each `res²`, row-major with the second named axis along rows.
    #[must_use]
    pub fn slices_through(&self, [cx, cy, cz]: [usize; 3]) -> [Vec<f32>; 3] {
        let r = self.grid.res;
        let mut xy = Vec::with_capacity(r * r);
        let mut xz = Vec::with_capacity(r * r);
        let mut yz = Vec::with_capacity(r * r);
        for row in 0..r {
            for col in 0..r {
                xy.push(self.at(col, row, cz));
                xz.push(self.at(col, cy, row));
                yz.push(self.at(cx, col, row));
            }
        }
        [xy, xz, yz]
    }
}

/// The box holding every kernel alive at any of `times` (under `cutoff`): slice centres
/// widened by 3 of each kernel's largest spatial σ. `None` when no kernel is alive.
#[must_use]
pub fn scene_bounds(scene: &Scene, times: &[f64], cutoff: f64) -> Option<([f64; 3], [f64; 3])> {
    let mut lo = [f64::INFINITY; 3];
    let mut hi = [f64::NEG_INFINITY; 3];
    let mut sliced = SlicedKernels::default();
    for &tau in times {
        slice(scene, tau, cutoff, &mut sliced);
        for s in 0..sliced.len() {
            let i = sliced.kernel_from_slice[s] as usize;
            let reach = 3.0 * scene.scales[i][..3].iter().cloned().fold(0.0, f64::max);
            for a in 0..3 {
                lo[a] = lo[a].min(sliced.means[s][a] - reach);
                hi[a] = hi[a].max(sliced.means[s][a] + reach);
            }
        }
    }
    lo[0].is_finite().then_some((lo, hi))
}

/// The sphere around [`scene_bounds`]' box: its centre and half its diagonal, for framing
/// the kernels alive at `times` with a camera.
#[must_use]
pub fn scene_sphere(scene: &Scene, times: &[f64], cutoff: f64) -> Option<([f64; 3], f64)> {
    let (lo, hi) = scene_bounds(scene, times, cutoff)?;
    let centre = std::array::from_fn(|a| 0.5 * (lo[a] + hi[a]));
    let radius = 0.5 * (0..3).map(|a| (hi[a] - lo[a]).powi(2)).sum::<f64>().sqrt();
    Some((centre, radius))
}

struct VolumeKernel {
    mean: DVec3,
    precision: DMat3,
    qmax: f64,
    amplitude: f32,
    reach: [f64; 3],
}

/// Evaluates `V(·, τ)` of `scene` on `grid` with cut-off `cutoff` (ε of SPEC §5).
#[must_use]
pub fn evaluate_volume(scene: &Scene, tau: f64, grid: &Grid, cutoff: f64) -> Volume {
    let mut sliced = SlicedKernels::default();
    slice(scene, tau, cutoff, &mut sliced);
    let kernels: Vec<VolumeKernel> = (0..sliced.len())
        .filter_map(|s| {
            let [xx, xy, xz, yy, yz, zz] = sliced.covariances[s];
            let sigma = DMat3::from_cols_array(&[xx, xy, xz, xy, yy, yz, xz, yz, zz]);
            let precision = sigma.inverse();
            let qmax = sliced.qmax[s];
            precision.is_finite().then(|| VolumeKernel {
                mean: DVec3::from(sliced.means[s]),
                precision,
                qmax,
                amplitude: match scene.blend {
                    Blend::Additive => (sliced.amplitudes[s].iter().sum::<f64>() / 3.0) as f32,
                    Blend::Alpha => sliced.opacities[s] as f32,
                },
                reach: [(qmax * xx).sqrt(), (qmax * yy).sqrt(), (qmax * zz).sqrt()],
            })
        })
        .collect();
    let r = grid.res;
    let h: [f64; 3] = std::array::from_fn(|a| (grid.max[a] - grid.min[a]) / r as f64);
    // Cells i with |min + (i + ½) h - m| ≤ reach, as a half-open range.
    let cells = |a: usize, m: f64, reach: f64| -> (usize, usize) {
        let lo = ((m - reach - grid.min[a]) / h[a] - 0.5).ceil().max(0.0);
        let hi = ((m + reach - grid.min[a]) / h[a] - 0.5)
            .floor()
            .min(r as f64 - 1.0);
        if lo.is_nan() || hi.is_nan() || lo > hi {
            (0, 0)
        } else {
            (lo as usize, hi as usize + 1)
        }
    };
    let mut values = vec![0.0_f32; r * r * r];
    values
        .par_chunks_mut(r * r)
        .enumerate()
        .for_each(|(z, slab)| {
            let pz = grid.centre(2, z);
            for k in &kernels {
                if (pz - k.mean.z).abs() > k.reach[2] {
                    continue;
                }
                let (y0, y1) = cells(1, k.mean.y, k.reach[1]);
                let (x0, x1) = cells(0, k.mean.x, k.reach[0]);
                for y in y0..y1 {
                    for x in x0..x1 {
                        let d = DVec3::new(grid.centre(0, x), grid.centre(1, y), pz) - k.mean;
                        let q = d.dot(k.precision * d);
                        if q <= k.qmax {
                            slab[y * r + x] += k.amplitude * (-0.5 * q as f32).exp();
                        }
                    }
                }
            }
        });
    Volume {
        grid: *grid,
        values,
    }
}

/// The dense f64 twin of [`evaluate_volume`]: every kernel at every cell, no bounds.
#[must_use]
pub fn evaluate_volume_reference(scene: &Scene, tau: f64, grid: &Grid, cutoff: f64) -> Vec<f64> {
    let mut sliced = SlicedKernels::default();
    slice(scene, tau, cutoff, &mut sliced);
    let r = grid.res;
    let mut values = vec![0.0; r * r * r];
    for s in 0..sliced.len() {
        let [xx, xy, xz, yy, yz, zz] = sliced.covariances[s];
        let precision = DMat3::from_cols_array(&[xx, xy, xz, xy, yy, yz, xz, yz, zz]).inverse();
        let amplitude = sliced.amplitudes[s].iter().sum::<f64>() / 3.0;
        for z in 0..r {
            for y in 0..r {
                for x in 0..r {
                    let d = DVec3::new(grid.centre(0, x), grid.centre(1, y), grid.centre(2, z))
                        - DVec3::from(sliced.means[s]);
                    let q = d.dot(precision * d);
                    if q <= sliced.qmax[s] {
                        values[(z * r + y) * r + x] += amplitude * (-0.5 * q).exp();
                    }
                }
            }
        }
    }
    values
}
