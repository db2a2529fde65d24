//! Images as `(H, W, 3)` float32 arrays, linear RGB (SPEC §5: no sRGB curve), read and
//! written as the command line does: PNG (8 or 16 bits, `round(levels · clamp(C, 0, 1))`),
//! EXR (float, linear), JPEG (read only).

use std::path::PathBuf;

use numpy::PyUntypedArrayMethods;
use pyo3::prelude::*;
use splat4d::Image;
use splat4d::io::image_file::{BitDepth, load_image as read_image, save_image as write_image};

use crate::arrays::{AnyF32, owned_array, shape_text, values};
use crate::errors::{lib, usage};

/// Writes `image` `(H, W, 3)` to `path`: `.exr` float32 linear, else PNG of `bits` 8 or 16
/// (atomically).
#[pyfunction]
#[pyo3(signature = (image, path, *, bits=8))]
pub fn save_image(
    py: Python<'_>,
    image: &Bound<'_, PyAny>,
    path: PathBuf,
    bits: u32,
) -> PyResult<()> {
    let array = image
        .extract::<AnyF32<'_>>()
        .map_err(|e| usage(py, format!("image: not an array of numbers ({e})")))?;
    let shape = array.shape().to_vec();
    if shape.len() != 3 || shape[2] != 3 {
        return Err(usage(
            py,
            format!("image: shape {}, expected (H, W, 3)", shape_text(&shape)),
        ));
    }
    let depth = match bits {
        8 => BitDepth::Eight,
        16 => BitDepth::Sixteen,
        _ => return Err(usage(py, format!("bits: {bits} (8 or 16)"))),
    };
    let (height, width) = (u32::try_from(shape[0]), u32::try_from(shape[1]));
    let (Ok(height), Ok(width)) = (height, width) else {
        return Err(usage(
            py,
            format!("image: shape {} is too large", shape_text(&shape)),
        ));
    };
    let image = Image {
        width,
        height,
        pixels: values(&array),
    };
    lib(py, py.detach(|| write_image(&image, &path, depth)))
}

/// Reads an image file (EXR, PNG, JPEG) as `(H, W, 3)` float32, `value / (2^bits − 1)`;
/// RGBA pixels are composited over `background`.
#[pyfunction]
#[pyo3(signature = (path, *, background=[0.0; 3]))]
pub fn load_image<'py>(
    py: Python<'py>,
    path: PathBuf,
    background: [f32; 3],
) -> PyResult<Bound<'py, PyAny>> {
    let image = lib(py, py.detach(|| read_image(&path, background)))?;
    let shape = [image.height as usize, image.width as usize, 3];
    owned_array(py, image.pixels, &shape)
}
