//! The D-NeRF / Blender layout (what `splat4d dataset` writes, [`super::write`]):
//!
//! ```text
//! DIR/transforms_train.json  transforms_val.json  transforms_test.json
//! DIR/train/r_000.png ...
//! ```
//!
//! A folder with a `transforms_train.json` is this format's; each split's file is a
//! transforms file ([`super::transforms`]) holding that split's frames, and a split without
//! its file is empty. A `splat4d_blend` key (written by `splat4d dataset`) names the blend
//! the images were rendered with.

use std::path::{Path, PathBuf};

use crate::model::Dataset;
use crate::model::error::Result;

use super::photo_memory::FramePhoto;
use super::transforms::Transforms;
use super::{DatasetFiles, DatasetOptions, Description, Format, SPLITS, no_training_frames};

/// The D-NeRF / Blender layout.
pub(super) struct Blender;

/// The transforms file of `split` in `dir`.
fn split_file(dir: &Path, split: &str) -> PathBuf {
    dir.join(format!("transforms_{split}.json"))
}

impl Format for Blender {
    fn sign(&self) -> &'static str {
        "transforms_train.json"
    }

    fn description_files(&self, dir: &Path) -> Vec<PathBuf> {
        SPLITS.iter().map(|split| split_file(dir, split)).collect()
    }

    fn claims(&self, dir: &Path) -> Option<PathBuf> {
        let train = split_file(dir, "train");
        train.is_file().then_some(train)
    }

    fn read(&self, dir: &Path) -> Box<dyn Description> {
        let splits = SPLITS.map(|split| {
            let path = split_file(dir, split);
            path.is_file().then(|| Transforms::read(&path))
        });
        Box::new(Splits {
            dir: dir.to_path_buf(),
            splits,
        })
    }
}

/// The split files of a D-NeRF / Blender dataset, in [`SPLITS`] order (`None`: no file).
struct Splits {
    dir: PathBuf,
    splits: [Option<Transforms>; 3],
}

impl Description for Splits {
    fn named_files(&self) -> DatasetFiles {
        let mut files = DatasetFiles::default();
        for split in self.splits.iter().flatten() {
            split.add_named_files(&self.dir, &mut files);
        }
        files
    }

    fn frame_photos(&self) -> Vec<FramePhoto> {
        let splits = self.splits.iter().flatten();
        splits.flat_map(|s| s.frame_photos(&self.dir)).collect()
    }

    fn load(self: Box<Self>, options: &DatasetOptions) -> Result<Dataset> {
        let Splits { dir, splits } = *self;
        let mut dataset = Dataset::default();
        for (split, transforms) in SPLITS.into_iter().zip(splits) {
            let Some(transforms) = transforms else {
                continue;
            };
            let read = transforms.load(&dir, options)?;
            dataset.transparent |= read.transparent;
            dataset.notes.extend(read.notes);
            dataset.blend = dataset.blend.or(read.blend);
            if read.points.is_some() {
                dataset.points = read.points;
            }
            match split {
                "train" => dataset.train = read.views,
                "val" => dataset.val = read.views,
                _ => dataset.test = read.views,
            }
        }
        if dataset.train.is_empty() {
            let train = split_file(&dir, "train");
            return Err(no_training_frames(
                &train,
                "frames",
                "the `frames` list is empty",
            ));
        }
        Ok(dataset)
    }
}
