//! `splat4d._native`: the native module of the Python package `splat4d` (PyO3, abi3 for
//! CPython 3.9 and newer). Thin: arrays in, the library's calls, arrays out; every rule
//! is the library's (`SPEC.md`), every error its message.
//!
//! | file | what |
//! |---|---|
//! | `scene.rs`, `camera.rs` | `Scene` and `Camera`: arrays validated once, files read and written |
//! | `frame.rs` | a frame's render and gradient, and their f64 twins |
//! | `fit.rs` | datasets and fits, with the command line's options and defaults |
//! | `image.rs` | image files as arrays |
//! | `arrays.rs`, `errors.rs` | numpy arrays in and out; errors as exceptions |
//!
//! The Python side (`python/splat4d/`) adds dicts as scenes, docstrings, stubs and the
//! torch interface.

use pyo3::prelude::*;

mod arrays;
mod camera;
mod errors;
mod fit;
mod frame;
mod image;
mod scene;

#[pymodule]
fn _native(m: &Bound<'_, PyModule>) -> PyResult<()> {
    // One version for the crate and the package (the workspace's).
    m.add("__version__", env!("CARGO_PKG_VERSION"))?;
    m.add_class::<scene::Scene>()?;
    m.add_class::<camera::Camera>()?;
    m.add_function(wrap_pyfunction!(frame::render, m)?)?;
    m.add_function(wrap_pyfunction!(frame::render_and_backward, m)?)?;
    m.add_function(wrap_pyfunction!(frame::reference_render, m)?)?;
    m.add_function(wrap_pyfunction!(frame::reference_loss_and_gradients_py, m)?)?;
    m.add_function(wrap_pyfunction!(image::save_image, m)?)?;
    m.add_function(wrap_pyfunction!(image::load_image, m)?)?;
    m.add_function(wrap_pyfunction!(fit::load_dataset, m)?)?;
    m.add_function(wrap_pyfunction!(fit::fit, m)?)?;
    m.add(
        "FIT_OPTIONS",
        splat4d::tasks::fit_options::FIT_OPTIONS.to_vec(),
    )?;
    Ok(())
}
