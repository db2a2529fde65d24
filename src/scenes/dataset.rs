//! Synthetic multi-view datasets rendered from a scene: what `splat4d dataset` writes.
//!
//! - train: `views` seeded cameras on a sphere around the scene, each at `times` times spread
//!   evenly over the time range (both ends included);
//! - val: the first (up to 4) training cameras at the midpoints between training times;
//! - test: `max(2, views/4)` new cameras at those midpoints: unseen views at unseen times.
//!
//! A **monocular** dataset is laid out as D-NeRF's captures are, one camera per time:
//! training camera i sees only time i (of `times` = `views` times spread evenly), there is
//! no val split, and test camera j (of `max(2, views/4)`) sees time `t0 + (j + ½)/count ·
//! (t1 - t0)`.

use crate::model::error::{Error, Result};
use crate::model::scene::Scene;
use crate::model::{Dataset, View};
use crate::render::{RenderContext, RenderOptions};
use crate::{
    model::random::seeded_rng,
    scenes::synthetic::{bounding_sphere, sphere_cameras},
};

/// What to render.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct DatasetSpec {
    /// Training cameras.
    pub views: usize,
    /// Training times.
    pub times: usize,
    /// Image width, pixels.
    pub width: u32,
    /// Image height, pixels.
    pub height: u32,
    /// Time range `[t0, t1]`.
    pub time_range: [f64; 2],
    /// Vertical field of view, degrees.
    pub fov_y_degrees: f64,
    /// Seed of the cameras.
    pub seed: u64,
    /// One camera per time (D-NeRF's layout): `views` must equal `times`.
    pub monocular: bool,
}

impl Default for DatasetSpec {
    fn default() -> Self {
        DatasetSpec {
            views: 8,
            times: 5,
            width: 128,
            height: 128,
            time_range: [0.0, 1.0],
            fov_y_degrees: 40.0,
            seed: 0,
            monocular: false,
        }
    }
}

/// Most cameras, and most times, of a synthetic dataset.
pub const MAX_VIEWS: usize = 10_000;

impl DatasetSpec {
    /// Checks the spec before any camera is placed or frame rendered: counts from 1 to
    /// [`MAX_VIEWS`], a frame size a camera accepts, a field of view in (0°, 180°), a finite
    /// ordered time range.
    pub fn validate(&self) -> Result<()> {
        for (field, value) in [("views", self.views), ("times", self.times)] {
            if !(1..=MAX_VIEWS).contains(&value) {
                return Err(Error::setting(
                    &[field],
                    format!("`{field}` {value} must be between 1 and {MAX_VIEWS}"),
                ));
            }
        }
        let pixels = u64::from(self.width) * u64::from(self.height);
        if self.width == 0 || self.height == 0 || pixels > crate::model::camera::MAX_PIXELS {
            return Err(Error::setting(
                &["size"],
                format!(
                    "`size` {}x{} must be at least 1×1 and at most 16384² pixels",
                    self.width, self.height
                ),
            ));
        }
        if self.monocular && self.views != self.times {
            return Err(Error::setting(
                &["monocular", "views", "times"],
                format!(
                    "a `monocular` dataset has one camera per time: `views` {} must equal `times` {}",
                    self.views, self.times
                ),
            ));
        }
        let fov = self.fov_y_degrees;
        if !(fov > 0.0 && fov < 180.0) {
            return Err(Error::setting(
                &["fov"],
                format!("`fov` {fov} must be in (0, 180) degrees"),
            ));
        }
        let [t0, t1] = self.time_range;
        if !(t0.is_finite() && t1.is_finite() && t0 <= t1 && (t1 - t0).is_finite()) {
            return Err(Error::usage(format!(
                "time range {t0}..{t1} is not a finite, ordered pair"
            )));
        }
        Ok(())
    }
}

/// Renders the dataset of `spec` from `scene`, calling `on_frame` after each image.
pub fn render_dataset(
    scene: &Scene,
    spec: &DatasetSpec,
    options: &RenderOptions,
    mut on_frame: impl FnMut(),
) -> Result<Dataset> {
    let mut dataset = Dataset::default();
    render_views(scene, spec, options, |split, view| {
        on_frame();
        match split {
            Split::Train => dataset.train.push(view),
            Split::Val => dataset.val.push(view),
            Split::Test => dataset.test.push(view),
        }
        Ok(())
    })?;
    Ok(dataset)
}

/// The split a rendered view belongs to.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Split {
    /// Seen cameras at training times.
    Train,
    /// Seen cameras at the times between.
    Val,
    /// New cameras at the times between.
    Test,
}

impl Split {
    /// Its place in file order (train, val, test).
    #[must_use]
    pub fn index(self) -> usize {
        self as usize
    }

    /// Its name in file and folder names.
    #[must_use]
    pub fn name(self) -> &'static str {
        ["train", "val", "test"][self.index()]
    }
}

/// One frame of a dataset: its split, its place in the split, its camera and time.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct DatasetFrame {
    /// The split it belongs to.
    pub split: Split,
    /// Its index in the split (`r_000`, …).
    pub index: usize,
    /// The camera.
    pub camera: crate::model::camera::Camera,
    /// Scene time.
    pub time: f64,
}

impl DatasetFrame {
    /// Its name in the dataset, `./SPLIT/r_NNN`.
    #[must_use]
    pub fn name(&self) -> String {
        format!("./{}/r_{:03}", self.split.name(), self.index)
    }
}

/// The frames of `spec`'s dataset of `scene`, in file order (train, then val and test by
/// time): what [`render_views`] renders.
pub fn dataset_frames(scene: &Scene, spec: &DatasetSpec) -> Result<Vec<DatasetFrame>> {
    spec.validate()?;
    let train_times = crate::scenes::paths::even_times(spec.time_range, spec.times);
    let mid_times: Vec<f64> = if spec.times == 1 {
        vec![spec.time_range[0]]
    } else {
        train_times
            .windows(2)
            .map(|w| 0.5 * (w[0] + w[1]))
            .collect()
    };
    let mut sweep = train_times.clone();
    sweep.extend(&mid_times);
    let (centre, radius) = bounding_sphere(scene, &sweep);
    let mut rng = seeded_rng(spec.seed);
    let test_count = (spec.views / 4).max(2);
    let cameras = sphere_cameras(
        centre,
        radius,
        spec.views + test_count,
        spec.fov_y_degrees,
        spec.width,
        spec.height,
        &mut rng,
    )?;
    if !radius.is_finite() {
        return Err(Error::Numeric(
            "the scene's extent is not finite: no camera can frame it".into(),
        ));
    }
    let (train_cameras, test_cameras) = cameras.split_at(spec.views);
    let mut frames = Vec::new();
    let mut counts = [0_usize; 3];
    let mut push = |camera: &crate::model::camera::Camera, time: f64, split: Split| {
        frames.push(DatasetFrame {
            split,
            index: counts[split.index()],
            camera: *camera,
            time,
        });
        counts[split.index()] += 1;
    };
    if spec.monocular {
        for (camera, &time) in train_cameras.iter().zip(&train_times) {
            push(camera, time, Split::Train);
        }
        let [t0, t1] = spec.time_range;
        for (j, camera) in test_cameras.iter().enumerate() {
            let time = t0 + (j as f64 + 0.5) / test_count as f64 * (t1 - t0);
            push(camera, time, Split::Test);
        }
        return Ok(frames);
    }
    for &time in &train_times {
        for camera in train_cameras {
            push(camera, time, Split::Train);
        }
    }
    for &time in &mid_times {
        for camera in train_cameras.iter().take(4) {
            push(camera, time, Split::Val);
        }
        for camera in test_cameras {
            push(camera, time, Split::Test);
        }
    }
    Ok(frames)
}

/// Renders frame `frame` of a dataset of `scene` in `context`: the view `sink`s receive.
pub fn render_frame(
    scene: &Scene,
    frame: &DatasetFrame,
    options: &RenderOptions,
    context: &mut RenderContext,
) -> Result<View> {
    context.render(scene, &frame.camera, frame.time, options)?;
    Ok(View {
        camera: frame.camera,
        time: frame.time,
        image: context.image().clone().into(),
        name: frame.name(),
        weights: None,
    })
}

/// Renders the views of `spec` one at a time, in file order (train, then val and test by
/// time), handing each to `sink` as soon as it is rendered: memory does not grow with the
/// dataset ([`render_dataset`] collects them).
pub fn render_views(
    scene: &Scene,
    spec: &DatasetSpec,
    options: &RenderOptions,
    mut sink: impl FnMut(Split, View) -> Result<()>,
) -> Result<()> {
    let mut context = RenderContext::new();
    for frame in dataset_frames(scene, spec)? {
        sink(
            frame.split,
            render_frame(scene, &frame, options, &mut context)?,
        )?;
    }
    Ok(())
}

/// Frames [`render_dataset`] will render for `spec`.
#[must_use]
pub fn frame_count(spec: &DatasetSpec) -> usize {
    if spec.monocular {
        return spec.views.saturating_add((spec.views / 4).max(2));
    }
    let mids = spec.times.saturating_sub(1).max(1);
    let per_mid = spec.views.min(4) + (spec.views / 4).max(2);
    spec.views
        .saturating_mul(spec.times)
        .saturating_add(mids.saturating_mul(per_mid))
}
