//! The methods compared by the seed experiment (paper §4.2): each named once ([`Method`]),
//! and rendered behind one interface ([`Predictor`]):
//!
//! - **4D**: one scene of 4D kernels, rendered at τ (SPEC §2–5);
//! - **frame 3D**: one static scene per training time (kernels constant in time), fitted on
//!   that time's views alone; at any τ the nearest training time's scene;
//! - **interpolation**: the same per-frame scenes; at τ between training times `t_k ≤ τ ≤
//!   t_{k+1}` the linear blend `(1 - α) C_k + α C_{k+1}`, `α = (τ - t_k)/(t_{k+1} - t_k)`, of
//!   their renders (clamped to the ends outside).

use crate::model::Image;
use crate::model::camera::Camera;
use crate::model::error::Result;
use crate::model::scene::Scene;
use crate::render::{RenderContext, RenderOptions};

/// One static scene per training time, in ascending time.
#[derive(Clone, Debug)]
pub struct FrameModels {
    /// Training times, ascending.
    pub times: Vec<f64>,
    /// The scene fitted at each time.
    pub scenes: Vec<Scene>,
}

impl FrameModels {
    /// Index of the training time nearest to `tau` (the earlier one on a tie).
    #[must_use]
    pub fn nearest(&self, tau: f64) -> usize {
        (0..self.times.len())
            .min_by(|&a, &b| {
                (self.times[a] - tau)
                    .abs()
                    .total_cmp(&(self.times[b] - tau).abs())
            })
            .expect("at least one frame")
    }

    /// `(k, α)` with `t_k ≤ τ ≤ t_{k+1}`, clamped to the ends.
    #[must_use]
    pub fn bracket(&self, tau: f64) -> (usize, f64) {
        let n = self.times.len();
        if n == 1 || tau <= self.times[0] {
            return (0, 0.0);
        }
        if tau >= self.times[n - 1] {
            return (n - 2, 1.0);
        }
        let k = self.times.partition_point(|&t| t <= tau) - 1;
        (
            k,
            (tau - self.times[k]) / (self.times[k + 1] - self.times[k]),
        )
    }
}

/// What every method of the report is, named once: its text in tables, legends and file
/// names ([`Method::name`]) and its colour in every chart ([`Method::palette_index`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Method {
    /// The paper's 4D model, the headline comparison.
    Paper4d,
    /// The nearest per-frame scene.
    FrameNearest,
    /// The linear blend of the two neighbouring per-frame renders.
    FrameInterpolation,
    /// The model size section's fixed-count 4D model (the paper's).
    FixedCount,
    /// The model size section's adaptive fit with static kernels.
    AdaptiveStatic,
    /// The model size section's adaptive fit with velocity kernels.
    AdaptiveVelocity,
    /// The model size section's per-frame baseline.
    FrameBaseline,
}

impl Method {
    /// Its name in tables, charts and file names.
    #[must_use]
    pub fn name(self) -> &'static str {
        match self {
            Method::Paper4d => "4D (paper)",
            Method::FrameNearest => "frame 3D",
            Method::FrameInterpolation => "interpolation",
            Method::FixedCount => "4D fixed count (paper)",
            Method::AdaptiveStatic => "4D adaptive, static kernels",
            Method::AdaptiveVelocity => "4D adaptive, velocity kernels",
            Method::FrameBaseline => "frame 3D (per-frame baseline)",
        }
    }

    /// Its entry in the charts' palette, the same in every chart: every 4D model 0, the
    /// per-frame scenes 1, the interpolation 2 (other series take the entries after these).
    #[must_use]
    pub fn palette_index(self) -> usize {
        match self {
            Method::Paper4d
            | Method::FixedCount
            | Method::AdaptiveStatic
            | Method::AdaptiveVelocity => 0,
            Method::FrameNearest | Method::FrameBaseline => 1,
            Method::FrameInterpolation => 2,
        }
    }
}

impl std::fmt::Display for Method {
    /// [`Method::name`], padded as the format asks.
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.pad(self.name())
    }
}

/// How a method predicts an image, behind one rendering interface.
#[derive(Clone, Copy, Debug)]
pub enum Predictor<'a> {
    /// The 4D model.
    Model4d(&'a Scene),
    /// Nearest per-frame scene.
    FrameNearest(&'a FrameModels),
    /// Linear blend of the two neighbouring per-frame renders.
    FrameInterpolation(&'a FrameModels),
}

impl Predictor<'_> {
    /// Renders the method's prediction at `(camera, tau)` into `out`.
    pub fn render(
        &self,
        camera: &Camera,
        tau: f64,
        options: &RenderOptions,
        context: &mut RenderContext,
        out: &mut Image,
    ) -> Result<()> {
        match *self {
            Predictor::Model4d(scene) => {
                context.render(scene, camera, tau, options)?;
                out.clone_from(context.image());
            }
            Predictor::FrameNearest(frames) => {
                let k = frames.nearest(tau);
                context.render(&frames.scenes[k], camera, frames.times[k], options)?;
                out.clone_from(context.image());
            }
            Predictor::FrameInterpolation(frames) => {
                let (k, alpha) = frames.bracket(tau);
                context.render(&frames.scenes[k], camera, frames.times[k], options)?;
                out.clone_from(context.image());
                let k1 = (k + 1).min(frames.scenes.len() - 1);
                context.render(&frames.scenes[k1], camera, frames.times[k1], options)?;
                let (a, b) = ((1.0 - alpha) as f32, alpha as f32);
                for (o, n) in out.pixels.iter_mut().zip(&context.image().pixels) {
                    *o = a * *o + b * *n;
                }
            }
        }
        Ok(())
    }

    /// Numbers the method stores: 11 per 4D kernel (mean 4, scale 4, amplitude 3; +3 when
    /// it has a velocity, +4 when rotated), 9 per static 3D kernel and frame (mean 3, scale
    /// 3, amplitude 3).
    #[must_use]
    pub fn parameter_count(&self) -> usize {
        match *self {
            Predictor::Model4d(scene) => {
                let moving = scene.velocities.iter().any(|v| *v != [0.0; 3]);
                let rotated = scene.rotations.iter().any(|q| *q != [1.0, 0.0, 0.0, 0.0]);
                scene.len() * (11 + if moving { 3 } else { 0 } + if rotated { 4 } else { 0 })
            }
            Predictor::FrameNearest(frames) | Predictor::FrameInterpolation(frames) => {
                frames.scenes.iter().map(|s| 9 * s.len()).sum()
            }
        }
    }
}

/// Mean absolute difference of consecutive frames, over pixels and channels and over the
/// sequence: the temporal smoothness metric (0 for a still sequence).
#[must_use]
pub fn temporal_roughness(frames: &[Image]) -> f64 {
    let pairs = frames.windows(2).count();
    if pairs == 0 {
        return 0.0;
    }
    frames
        .windows(2)
        .map(|w| {
            w[0].pixels
                .iter()
                .zip(&w[1].pixels)
                .map(|(a, b)| f64::from((a - b).abs()))
                .sum::<f64>()
                / w[0].pixels.len() as f64
        })
        .sum::<f64>()
        / pairs as f64
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn nearest_and_bracket() {
        let frames = FrameModels {
            times: vec![0.0, 0.5, 1.0],
            scenes: vec![Scene::default(); 3],
        };
        assert_eq!(frames.nearest(0.2), 0);
        assert_eq!(frames.nearest(0.3), 1);
        assert_eq!(frames.nearest(0.25), 0);
        assert_eq!(frames.bracket(-1.0), (0, 0.0));
        assert_eq!(frames.bracket(0.25), (0, 0.5));
        assert_eq!(frames.bracket(0.5), (1, 0.0));
        assert_eq!(frames.bracket(0.75), (1, 0.5));
        assert_eq!(frames.bracket(2.0), (1, 1.0));
    }

    #[test]
    fn roughness_of_a_ramp() {
        let frame = |v: f32| Image::filled(2, 2, [v; 3]);
        assert_eq!(
            temporal_roughness(&[frame(0.0), frame(0.5), frame(1.0)]),
            0.5
        );
        assert_eq!(temporal_roughness(&[frame(0.3)]), 0.0);
    }
}
