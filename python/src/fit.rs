//! Datasets and fits from Python: `load_dataset` (a dataset folder's views as cameras,
//! times and images) and `fit` (the command line's `splat4d fit`, its options as keyword
//! arguments named like its flags, set by the library's one definition of them with the
//! same values, defaults and refusals: [`splat4d::tasks::fit_options`]).
//!
//! A fit runs with the GIL released; each step hands its record to the progress callback
//! (and checks for Ctrl-C). An exception there stops the fit at that step and is raised.

use std::panic::{AssertUnwindSafe, catch_unwind, resume_unwind};
use std::path::PathBuf;

use pyo3::prelude::*;
use pyo3::types::{PyDict, PyList, PyString};
use splat4d::Error;
use splat4d::fit::train::StepRecord;
use splat4d::io::dataset::{DatasetOptions, load_dataset as read_dataset};
use splat4d::io::scene_file::load_scene_as_stored;
use splat4d::model::View;
use splat4d::tasks::fit::{FitProgress, FitRequest, fit_dataset};
use splat4d::tasks::fit_options::{FIT_OPTIONS, OptionValue};

use crate::arrays::owned_array;
use crate::camera::Camera;
use crate::errors::{lib, to_py};
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
    lib(py, splat4d::tasks::fit_options::check_downscale(downscale))
}

/// An option's value from Python, owned: [`OptionValue`] borrows it.
enum Given {
    Switch(bool),
    Text(String),
    List(Vec<String>),
}

impl Given {
    fn value(&self) -> OptionValue<'_> {
        match self {
            Given::Switch(on) => OptionValue::Switch(*on),
            Given::Text(text) => OptionValue::Text(text),
            Given::List(items) => OptionValue::List(items),
        }
    }
}

/// A Python value as an option's: `True`/`False` a switch's state; a string, or a path,
/// the text its flag takes; a list, tuple or array a list's numbers; any other value
/// (a number) as `str()` writes it, which Python writes so that it reads back the same
/// (`repr` of a float, the digits of an int).
fn given(v: &Bound<'_, PyAny>) -> PyResult<Given> {
    if let Ok(on) = v.extract::<bool>() {
        return Ok(Given::Switch(on));
    }
    if let Ok(text) = v.cast::<PyString>() {
        return Ok(Given::Text(text.to_cow()?.into_owned()));
    }
    if v.hasattr("__fspath__")? {
        let path = v.py().import("os")?.call_method1("fspath", (v,))?;
        return Ok(Given::Text(path.str()?.to_cow()?.into_owned()));
    }
    // A list, a tuple, an array (a 0-d array or a number does not iterate).
    if let Ok(items) = v.try_iter() {
        let items = items
            .map(|item| Ok(item?.str()?.to_cow()?.into_owned()))
            .collect::<PyResult<_>>()?;
        return Ok(Given::List(items));
    }
    Ok(Given::Text(v.str()?.to_cow()?.into_owned()))
}

/// A fit's request from its keyword options (the others at the command line's defaults):
/// each set as the library sets a named option ([`FitRequest::set`]).
fn request(
    py: Python<'_>,
    views: PathBuf,
    out: PathBuf,
    options: Option<&Bound<'_, PyDict>>,
) -> PyResult<FitRequest> {
    let mut request = FitRequest::new(views, out);
    for (key, v) in options.into_iter().flat_map(|d| d.iter()) {
        let key: String = key.extract()?;
        let given = match v.is_none() {
            // `None`: the option's default (an unknown name is still refused).
            true if FIT_OPTIONS.contains(&key.as_str()) => continue,
            true => Given::Switch(false),
            false => given(&v)?,
        };
        lib(py, request.set(&key, given.value()))?;
    }
    Ok(request)
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
                event.set_item("pairs", record.pairs)?;
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
