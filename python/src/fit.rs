//! Datasets and fits from Python: `load_dataset` (a dataset folder's views as cameras,
//! times and images) and `fit` (the command line's `splat4d fit`, its options as keyword
//! arguments named like its flags, the same defaults: [`splat4d::fit::settings`]).
//!
//! A fit runs with the GIL released; each step hands its record to the progress callback
//! (and checks for Ctrl-C). An exception there stops the fit at that step and is raised.

use std::panic::{AssertUnwindSafe, catch_unwind, resume_unwind};
use std::path::PathBuf;

use pyo3::prelude::*;
use pyo3::types::{PyDict, PyList};
use splat4d::fit::settings::FitSettings;
use splat4d::fit::train::StepRecord;
use splat4d::io::dataset::{DatasetOptions, MAX_DOWNSCALE, load_dataset as read_dataset};
use splat4d::io::scene_file::load_scene_as_stored;
use splat4d::model::View;
use splat4d::tasks::fit::{FitProgress, FitRequest, fit_dataset};
use splat4d::{Blend, Error};

use crate::arrays::owned_array;
use crate::camera::Camera;
use crate::errors::{lib, to_py, usage};
use crate::scene::Scene;

/// A view as a dict: its camera, time, image `(H, W, 3)` float32, name and loss weights
/// `(H, W)` (or `None`: every pixel counts).
fn view_dict<'py>(py: Python<'py>, view: &View) -> PyResult<Bound<'py, PyDict>> {
    let dict = PyDict::new(py);
    let (w, h) = (view.image.width as usize, view.image.height as usize);
    dict.set_item("camera", Camera { inner: view.camera })?;
    dict.set_item("time", view.time)?;
    dict.set_item(
        "image",
        owned_array(py, view.image.pixels.clone(), &[h, w, 3])?,
    )?;
    dict.set_item("name", &view.name)?;
    let weights = match &view.weights {
        Some(weights) => Some(owned_array(py, weights.clone(), &[h, w])?),
        None => None,
    };
    dict.set_item("weights", weights)?;
    Ok(dict)
}

/// Reads a dataset folder (D-NeRF / Blender, nerfstudio or instant-ngp `transforms.json`,
/// COLMAP): `{"train": [view, …], "val": […], "test": […], "blend": …, "notes": […]}`,
/// each view a dict (`camera`, `time`, `image`, `name`, `weights`).
#[pyfunction]
#[pyo3(signature = (views, *, downscale=1, background=None, strict=false, allow_outside_images=false))]
pub fn load_dataset<'py>(
    py: Python<'py>,
    views: PathBuf,
    downscale: u32,
    background: Option<[f64; 3]>,
    strict: bool,
    allow_outside_images: bool,
) -> PyResult<Bound<'py, PyDict>> {
    check_downscale(py, downscale)?;
    let options = DatasetOptions {
        background: background.unwrap_or([0.0; 3]).map(|b| b as f32),
        downscale,
        strict,
        allow_outside_images,
        frames: None,
        fps: None,
    };
    let dataset = lib(py, py.detach(|| read_dataset(&views, &options)))?;
    let dict = PyDict::new(py);
    for (split, views) in [
        ("train", &dataset.train),
        ("val", &dataset.val),
        ("test", &dataset.test),
    ] {
        let list = PyList::empty(py);
        for view in views {
            list.append(view_dict(py, view)?)?;
        }
        dict.set_item(split, list)?;
    }
    dict.set_item("blend", dataset.blend.map(|b| b.to_string()))?;
    dict.set_item("notes", dataset.notes.clone())?;
    Ok(dict)
}

fn check_downscale(py: Python<'_>, downscale: u32) -> PyResult<()> {
    if (1..=MAX_DOWNSCALE).contains(&downscale) {
        return Ok(());
    }
    Err(to_py(
        py,
        Error::setting(
            &["downscale"],
            format!("`downscale` {downscale} must be between 1 and {MAX_DOWNSCALE}"),
        ),
    ))
}

/// The names `fit` takes as keyword options: the command line's flags (`--lr-mean` is
/// `lr_mean`), which the library's messages name.
pub const OPTIONS: [&str; 53] = [
    "init",
    "blend",
    "downscale",
    "strict",
    "allow_outside_images",
    "log",
    "threads",
    "dilation",
    "cutoff",
    "exp",
    "steps",
    "batch",
    "start_kernels",
    "max_kernels",
    "eval_every",
    "seed",
    "background",
    "lr_mean",
    "lr_time",
    "lr_velocity",
    "lr_scale",
    "lr_amplitude",
    "lr_background",
    "lr_opacity",
    "lr_rotation",
    "lr_sh",
    "lr_final",
    "densify_every",
    "densify_from",
    "densify_until",
    "densify_threshold",
    "max_growth",
    "prune_below",
    "freeze_mean",
    "freeze_time",
    "freeze_amplitude",
    "freeze_background",
    "mode",
    "fit_velocity",
    "fit_scale",
    "adaptive",
    "min_improvement",
    "merge_tolerance",
    "min_scale",
    "box",
    "time_range",
    "init_scale",
    "init_amplitude",
    "sh",
    "sh_raise_every",
    "opacity_reset_every",
    "percent_dense",
    "time_split_fraction",
];

/// One option's value, `None` when given as `None`.
fn value<'py, T: FromPyObjectOwned<'py>>(
    value: &Bound<'py, PyAny>,
    name: &'static str,
) -> PyResult<Option<T>> {
    if value.is_none() {
        return Ok(None);
    }
    value.extract::<T>().map(Some).map_err(|e| {
        let e: PyErr = e.into();
        to_py(
            value.py(),
            Error::setting(&[name], format!("`{name}`: {}", e.value(value.py()))),
        )
    })
}

/// A finite number (NaN and ±∞ are refused, as the command line refuses them).
fn number(v: &Bound<'_, PyAny>, name: &'static str) -> PyResult<Option<f64>> {
    let x = value::<f64>(v, name)?;
    match x {
        Some(x) if !x.is_finite() => Err(to_py(
            v.py(),
            Error::setting(&[name], format!("`{name}` {x} is not finite")),
        )),
        _ => Ok(x),
    }
}

/// Finite numbers, `K` of them.
fn numbers<const K: usize>(v: &Bound<'_, PyAny>, name: &'static str) -> PyResult<Option<[f64; K]>> {
    let x = value::<[f64; K]>(v, name)?;
    if let Some(x) = x
        && !x.iter().all(|v| v.is_finite())
    {
        return Err(to_py(
            v.py(),
            Error::setting(&[name], format!("`{name}` {x:?} is not finite")),
        ));
    }
    Ok(x)
}

fn flag(v: &Bound<'_, PyAny>, name: &'static str) -> PyResult<bool> {
    Ok(value::<bool>(v, name)?.unwrap_or(false))
}

/// A fit's request from its keyword options (the others as the command line's defaults).
fn request(
    py: Python<'_>,
    views: PathBuf,
    out: PathBuf,
    options: Option<&Bound<'_, PyDict>>,
) -> PyResult<FitRequest> {
    let mut s = FitSettings::default();
    let mut request = FitRequest {
        views,
        downscale: 1,
        strict: false,
        allow_outside_images: false,
        init: "auto".into(),
        settings: FitSettings::default(),
        blend: None,
        out,
        log: None,
        threads: None,
        view: None,
        frames: None,
        fps: None,
    };
    for (key, v) in options.into_iter().flat_map(|d| d.iter()) {
        let key: String = key.extract()?;
        let Some(&name) = OPTIONS.iter().find(|n| **n == key) else {
            return Err(usage(
                py,
                format!(
                    "fit: no option `{key}` (the options are the command line's flags: {})",
                    OPTIONS.join(", ")
                ),
            ));
        };
        let v = &v;
        match name {
            "init" => request.init = value::<String>(v, name)?.unwrap_or_else(|| "auto".into()),
            "blend" => {
                request.blend = match value::<String>(v, name)?.as_deref() {
                    None | Some("auto") => None,
                    Some(text) => Some(text.parse::<Blend>().map_err(|e| {
                        to_py(py, Error::setting(&["blend"], format!("`blend`: {e}")))
                    })?),
                }
            }
            "downscale" => {
                request.downscale = value::<u32>(v, name)?.unwrap_or(1);
                check_downscale(py, request.downscale)?;
            }
            "strict" => request.strict = flag(v, name)?,
            "allow_outside_images" => request.allow_outside_images = flag(v, name)?,
            "log" => request.log = value::<PathBuf>(v, name)?,
            "threads" => request.threads = value::<usize>(v, name)?,
            "dilation" => s.render.dilation = number(v, name)?.unwrap_or(s.render.dilation),
            "cutoff" => s.render.cutoff = number(v, name)?.unwrap_or(s.render.cutoff),
            "exp" => {
                if let Some(text) = value::<String>(v, name)? {
                    s.render.exp = text.parse().map_err(|e: String| {
                        to_py(py, Error::setting(&["exp"], format!("`exp`: {e}")))
                    })?;
                }
            }
            _ => setting(py, &mut s, name, v)?,
        }
    }
    request.settings = s;
    Ok(request)
}

/// Sets the [`FitSettings`] option `name` (every option but the request's own).
fn setting(
    py: Python<'_>,
    s: &mut FitSettings,
    name: &'static str,
    v: &Bound<'_, PyAny>,
) -> PyResult<()> {
    let r = &mut s.rates;
    match name {
        "steps" => s.steps = value(v, name)?,
        "batch" => s.batch = value(v, name)?,
        "start_kernels" => s.start_kernels = value(v, name)?,
        "max_kernels" => s.max_kernels = value(v, name)?,
        "eval_every" => s.eval_every = value(v, name)?,
        "seed" => s.seed = value(v, name)?,
        "background" => s.background = numbers::<3>(v, name)?,
        "lr_mean" => r.mean = number(v, name)?,
        "lr_time" => r.time = number(v, name)?,
        "lr_velocity" => r.velocity = number(v, name)?,
        "lr_scale" => r.scale = number(v, name)?,
        "lr_amplitude" => r.amplitude = number(v, name)?,
        "lr_background" => r.background = number(v, name)?,
        "lr_opacity" => r.opacity = number(v, name)?,
        "lr_rotation" => r.rotation = number(v, name)?,
        "lr_sh" => r.sh = number(v, name)?,
        "lr_final" => s.lr_final = number(v, name)?,
        "densify_every" => s.densify_every = value(v, name)?,
        "densify_from" => s.densify_from = number(v, name)?,
        "densify_until" => s.densify_until = number(v, name)?,
        "densify_threshold" => s.densify_threshold = number(v, name)?,
        "max_growth" => s.max_growth = number(v, name)?,
        "prune_below" => s.prune_below = number(v, name)?,
        "freeze_mean" => s.freeze_mean = flag(v, name)?,
        "freeze_time" => s.freeze_time = flag(v, name)?,
        "freeze_amplitude" => s.freeze_amplitude = flag(v, name)?,
        "freeze_background" => s.freeze_background = flag(v, name)?,
        "mode" => {
            s.mode = match value::<String>(v, name)? {
                None => None,
                Some(text) => Some(text.parse().map_err(|e: String| {
                    to_py(py, Error::setting(&["mode"], format!("`mode`: {e}")))
                })?),
            }
        }
        "fit_velocity" => s.fit_velocity = flag(v, name)?,
        "fit_scale" => s.fit_scale = flag(v, name)?,
        "adaptive" => s.adaptive = flag(v, name)?,
        "min_improvement" => s.min_improvement = number(v, name)?,
        "merge_tolerance" => s.merge_tolerance = number(v, name)?,
        "min_scale" => s.min_scale = number(v, name)?,
        "box" => s.bounds = numbers::<6>(v, name)?,
        "time_range" => s.time_range = numbers::<2>(v, name)?,
        "init_scale" => s.init_scale = numbers::<4>(v, name)?,
        "init_amplitude" => s.init_amplitude = number(v, name)?,
        "sh" => s.sh = value(v, name)?,
        "sh_raise_every" => s.sh_raise_every = value(v, name)?,
        "opacity_reset_every" => s.opacity_reset_every = value(v, name)?,
        "percent_dense" => s.percent_dense = number(v, name)?,
        "time_split_fraction" => s.time_split_fraction = number(v, name)?,
        _ => unreachable!("every name of OPTIONS has its arm"),
    }
    Ok(())
}

/// What unwinds out of a fit whose progress callback raised (or saw Ctrl-C).
struct Stopped;

/// The fit's progress, handed to Python: notes to `sys.stderr` as the command line prints
/// them, each step's record to the callback.
struct Progress {
    callback: Option<Py<PyAny>>,
    steps: usize,
    last: Option<StepRecord>,
    failure: Option<PyErr>,
}

impl FitProgress for Progress {
    fn start(&mut self, steps: usize) {
        self.steps = steps;
    }

    fn note(&mut self, text: &str) {
        Python::attach(|py| {
            let written = py
                .import("sys")
                .and_then(|sys| sys.getattr("stderr"))
                .and_then(|err| err.call_method1("write", (format!("note: {text}\n"),)));
            if let Err(e) = written {
                self.failure = Some(e);
            }
        });
    }

    fn step(&mut self, record: &StepRecord, heldout_psnr: Option<f64>, seconds_left: Option<f64>) {
        self.last = Some(*record);
        Python::attach(|py| {
            let outcome = py.check_signals().and_then(|()| {
                let Some(callback) = &self.callback else {
                    return Ok(());
                };
                let event = PyDict::new(py);
                event.set_item("step", record.step)?;
                event.set_item("steps", self.steps)?;
                event.set_item("seconds", record.seconds)?;
                event.set_item("loss", record.train_loss)?;
                event.set_item("heldout_psnr", heldout_psnr)?;
                event.set_item("kernels", record.kernels)?;
                event.set_item("seconds_left", seconds_left)?;
                callback.call1(py, (event,)).map(drop)
            });
            if let Err(e) = outcome {
                self.failure = Some(e);
            }
        });
        if self.failure.is_some() {
            // Out of the training loop without the panic hook's message.
            resume_unwind(Box::new(Stopped));
        }
    }
}

/// Fits a scene to the dataset in `views` with the command line's plan (`splat4d fit`):
/// every keyword option is one of its flags, `None` or left out for its default. Writes the
/// scene to `out` when given. Returns `(scene, summary)`.
#[pyfunction]
#[pyo3(signature = (views, *, out=None, progress=None, **options))]
pub fn fit<'py>(
    py: Python<'py>,
    views: PathBuf,
    out: Option<PathBuf>,
    progress: Option<Py<PyAny>>,
    options: Option<&Bound<'py, PyDict>>,
) -> PyResult<(Scene, Bound<'py, PyDict>)> {
    let scratch = match &out {
        Some(_) => None,
        None => Some(tempfile::tempdir().map_err(|e| {
            to_py(
                py,
                Error::write(&std::env::temp_dir(), "cannot make a folder for the fit", e),
            )
        })?),
    };
    let out_path = out
        .clone()
        .unwrap_or_else(|| scratch.as_ref().expect("a folder").path().join("fit.json"));
    let request = request(py, views, out_path.clone(), options)?;
    let mut progress = Progress {
        callback: progress,
        steps: 0,
        last: None,
        failure: None,
    };
    let outcome =
        py.detach(|| catch_unwind(AssertUnwindSafe(|| fit_dataset(&request, &mut progress))));
    let summary = match outcome {
        Ok(result) => lib(py, result)?,
        Err(payload) => match progress.failure.take() {
            Some(error) => return Err(error),
            None => resume_unwind(payload),
        },
    };
    if let Some(error) = progress.failure.take() {
        return Err(error);
    }
    let (scene, norms) = lib(py, load_scene_as_stored(&out_path))?;
    let scene = Scene::wrap(scene, Some(norms));
    let dict = PyDict::new(py);
    dict.set_item("out", out)?;
    dict.set_item("kernels", scene.inner.len())?;
    dict.set_item("steps", progress.last.map_or(0, |r| r.step))?;
    dict.set_item("seconds", progress.last.map_or(0.0, |r| r.seconds))?;
    dict.set_item("blend", scene.inner.blend.to_string())?;
    let splits = PyDict::new(py);
    for score in &summary.splits {
        let split = PyDict::new(py);
        split.set_item("views", score.views)?;
        split.set_item("mse", score.mse)?;
        split.set_item("psnr", score.psnr())?;
        splits.set_item(score.split, split)?;
    }
    dict.set_item("splits", splits)?;
    dict.set_item("text", summary.to_string())?;
    Ok((scene, dict))
}
