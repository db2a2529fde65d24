//! Coarse to fine: a fit's first steps on downscaled training views (SPEC §3, §6).
//!
//! A step's cost grows with the pixels it renders, while early in a fit the kernels are few
//! and wide, and a view at ¼ size gives nearly the gradient the whole view gives for 1/16 of
//! the pixels. A fit's [`SizeStage`]s each name a downscale factor `n` and the fraction of
//! the run they end at; the steps up to the first stage's end fit the views downscaled by
//! its `n`, then the next stage's, and the steps after the last stage the views as they are.
//! The kernels, the optimiser's moments and the density statistics carry over from stage to
//! stage.
//!
//! Downscaling is [`View::downscaled`]: the box filter over `n × n` blocks, the intrinsics
//! divided by `n`. The centre of pixel `(i, j)` of the small image, `(i + ½, j + ½)`, is then
//! the centre of the block it averages, so the scene's coordinates and every parameter mean
//! the same at every stage; only the screen, in pixels, is `n` times smaller (a kernel's
//! screen σ and its dilation, SPEC §4, are in the stage's pixels).
//!
//! The loss is each stage's mean over its own pixels (SPEC §6): the mean of a block is the
//! block's mean, so the loss at a coarse stage is that of the scene filtered by the box, not
//! a different objective.

use crate::model::View;
use crate::model::error::{Error, Result};

/// One stage of a coarse-to-fine fit: its views downscaled by `downscale`, until the
/// fraction `until` of the run.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SizeStage {
    /// The downscale factor of the stage's views (≥ 2).
    pub downscale: u32,
    /// The stage ends after this fraction of the steps, in (0, 1).
    pub until: f64,
}

/// How a fit chooses its coarse stages from its training views.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum CoarseToFine {
    /// Every step at full size.
    Off,
    /// A stage at ¼ size until `ends[0]` of the run and one at ½ until `ends[1]`, each only
    /// where every training view keeps at least `min_side` pixels on its shorter side.
    Auto {
        /// The shorter side, in pixels, below which a view is not shrunk further.
        min_side: u32,
        /// The ends of the ¼ and the ½ stages, as fractions of the run.
        ends: [f64; 2],
    },
}

impl CoarseToFine {
    /// The stages for training views `train` (see the variants).
    #[must_use]
    pub fn stages(&self, train: &[View]) -> Vec<SizeStage> {
        let CoarseToFine::Auto { min_side, ends } = *self else {
            return Vec::new();
        };
        let shortest = train
            .iter()
            .map(|v| v.image.width.min(v.image.height))
            .min()
            .unwrap_or(0);
        [(4, ends[0]), (2, ends[1])]
            .into_iter()
            .filter(|&(n, _)| shortest / n >= min_side.max(1))
            .map(|(downscale, until)| SizeStage { downscale, until })
            .collect()
    }
}

/// The downscale factor of step `step` (from 1) of a run of `steps`: that of the first
/// stage that has not ended (stage `s` ends after step `round(until_s · steps)`), else 1.
#[must_use]
pub fn downscale_at(stages: &[SizeStage], step: usize, steps: usize) -> u32 {
    stages
        .iter()
        .find(|stage| step as f64 <= (stage.until * steps as f64).round())
        .map_or(1, |stage| stage.downscale)
}

/// The training views of the current stage: the caller's views at full size, or their
/// downscaled copies, made when a stage starts and dropped when it ends.
pub struct StagedViews {
    stages: Vec<SizeStage>,
    downscale: u32,
    views: Vec<View>,
}

impl StagedViews {
    /// Stages `stages`; no views made before the first [`StagedViews::at`].
    #[must_use]
    pub fn new(stages: &[SizeStage]) -> Self {
        StagedViews {
            stages: stages.to_vec(),
            downscale: 1,
            views: Vec::new(),
        }
    }

    /// The views of step `step` of `steps` (`train` itself at full size). A stage whose
    /// factor leaves some image smaller than one pixel is refused naming the view.
    pub fn at<'a>(
        &'a mut self,
        train: &'a [View],
        step: usize,
        steps: usize,
    ) -> Result<&'a [View]> {
        let downscale = downscale_at(&self.stages, step, steps);
        if downscale != self.downscale {
            self.downscale = downscale;
            self.views = if downscale == 1 {
                Vec::new()
            } else {
                downscaled_views(train, downscale)?
            };
        }
        Ok(if self.downscale == 1 {
            train
        } else {
            &self.views
        })
    }

    /// The downscale factor of the views [`StagedViews::at`] gave last.
    #[must_use]
    pub fn downscale(&self) -> u32 {
        self.downscale
    }
}

/// `train` downscaled by `n`, or an error naming the first view too small for it.
fn downscaled_views(train: &[View], n: u32) -> Result<Vec<View>> {
    use rayon::prelude::*;
    train
        .par_iter()
        .map(|view| {
            view.downscaled(n).ok_or_else(|| {
                Error::usage(format!(
                    "{}: {}×{} is smaller than the coarse stage's downscale {n}",
                    view.name, view.image.width, view.image.height
                ))
            })
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn stage(downscale: u32, until: f64) -> SizeStage {
        SizeStage { downscale, until }
    }

    #[test]
    fn steps_go_through_the_stages_in_order_and_end_at_full_size() {
        let stages = [stage(4, 0.25), stage(2, 0.5)];
        let factors: Vec<u32> = (1..=8).map(|s| downscale_at(&stages, s, 8)).collect();
        assert_eq!(factors, [4, 4, 2, 2, 1, 1, 1, 1]);
        assert_eq!(downscale_at(&[], 1, 8), 1);
    }

    #[test]
    fn automatic_stages_keep_the_shorter_side_above_the_bound() {
        let view = |side: u32| {
            let camera = crate::model::Camera::look_at(
                [0.0, 0.0, 5.0],
                [0.0; 3],
                [0.0, 1.0, 0.0],
                40.0,
                side,
                side,
            )
            .unwrap();
            View {
                camera,
                time: 0.0,
                image: std::sync::Arc::new(crate::model::Image::filled(side, side, [0.0; 3])),
                name: String::new(),
                weights: None,
            }
        };
        let auto = CoarseToFine::Auto {
            min_side: 100,
            ends: [0.3, 0.6],
        };
        assert_eq!(auto.stages(&[view(400)]), [stage(4, 0.3), stage(2, 0.6)]);
        assert_eq!(auto.stages(&[view(400), view(399)]), [stage(2, 0.6)]);
        assert_eq!(auto.stages(&[view(199)]), []);
        assert_eq!(CoarseToFine::Off.stages(&[view(400)]), []);
    }
}
