//! `splat4d.Camera`: the pinhole camera of SPEC §3 (OpenCV axes: x right, y down, z
//! forward; `u = fx x/z + cx`; pixel centres at `i + ½`), validated once when built.

use std::path::PathBuf;

use numpy::PyUntypedArrayMethods;
use pyo3::prelude::*;
use splat4d::io::camera_file::{load_camera, save_camera};
use splat4d::model::camera::{DEFAULT_FAR, DEFAULT_NEAR};

use crate::arrays::{array_f64, owned_array, rows, shape_text, values};
use crate::errors::{lib, usage};

/// A pinhole camera (SPEC §3), immutable.
#[pyclass(module = "splat4d", name = "Camera", frozen)]
pub struct Camera {
    pub inner: splat4d::Camera,
}

/// A 4×4 matrix from an array-like; `what` names it.
fn matrix4(py: Python<'_>, value: &Bound<'_, PyAny>, what: &str) -> PyResult<[[f64; 4]; 4]> {
    let rows = rows::<4>(py, &array_f64(value, what)?, what, Some(4))?;
    Ok([rows[0], rows[1], rows[2], rows[3]])
}

/// `camera` with `near` and `far`, validated; `origin` names it in errors.
fn checked(
    py: Python<'_>,
    mut camera: splat4d::Camera,
    near: f64,
    far: f64,
    origin: &str,
) -> PyResult<Camera> {
    camera.near = near;
    camera.far = far;
    lib(py, camera.validate(origin))?;
    Ok(Camera { inner: camera })
}

/// `[fx, fy, cx, cy]` of an intrinsic matrix `[[fx, 0, cx], [0, fy, cy], [0, 0, 1]]`.
pub fn intrinsics(py: Python<'_>, k: &Bound<'_, PyAny>) -> PyResult<[f64; 4]> {
    let array = array_f64(k, "K")?;
    let m = values(&array);
    if array.shape() != [3, 3] {
        return Err(usage(
            py,
            format!("K: shape {}, expected (3, 3)", shape_text(array.shape())),
        ));
    }
    if m[1] != 0.0 || m[3] != 0.0 || m[6..] != [0.0, 0.0, 1.0] {
        return Err(usage(
            py,
            format!(
                "K: {m:?} is not [[fx, 0, cx], [0, fy, cy], [0, 0, 1]] (a pinhole without skew, SPEC §3)"
            ),
        ));
    }
    Ok([m[0], m[4], m[2], m[5]])
}

#[pymethods]
impl Camera {
    /// A camera from its size, intrinsics (pixels) and world→camera matrix (4×4, OpenCV
    /// axes, last row `[0, 0, 0, 1]`). Kernels whose slice centre has camera z outside
    /// `[near, far]` are culled.
    #[new]
    #[pyo3(signature = (width, height, fx, fy, cx, cy, world_to_camera, *, near=DEFAULT_NEAR, far=DEFAULT_FAR))]
    #[allow(clippy::too_many_arguments)]
    fn new(
        py: Python<'_>,
        width: u32,
        height: u32,
        fx: f64,
        fy: f64,
        cx: f64,
        cy: f64,
        world_to_camera: &Bound<'_, PyAny>,
        near: f64,
        far: f64,
    ) -> PyResult<Self> {
        let camera = splat4d::Camera {
            width,
            height,
            fx,
            fy,
            cx,
            cy,
            world_to_camera: matrix4(py, world_to_camera, "world_to_camera")?,
            near,
            far,
            clamp: None,
        };
        checked(py, camera, near, far, "<camera>")
    }

    /// A camera at `eye` looking at `target`, `up` up in the image, a vertical field of view
    /// in degrees, the principal point at the centre.
    #[staticmethod]
    #[pyo3(signature = (eye, target, up, fov_y_degrees, width, height, *, near=DEFAULT_NEAR, far=DEFAULT_FAR))]
    #[allow(clippy::too_many_arguments)]
    fn look_at(
        py: Python<'_>,
        eye: [f64; 3],
        target: [f64; 3],
        up: [f64; 3],
        fov_y_degrees: f64,
        width: u32,
        height: u32,
        near: f64,
        far: f64,
    ) -> PyResult<Self> {
        let camera = lib(
            py,
            splat4d::Camera::look_at(eye, target, up, fov_y_degrees, width, height),
        )?;
        checked(py, camera, near, far, "<look-at camera>")
    }

    /// A camera from gsplat's arguments: `viewmat` (4×4 world→camera, OpenCV axes) and `K`
    /// (3×3 intrinsics without skew).
    #[staticmethod]
    #[pyo3(signature = (viewmat, K, width, height, *, near=DEFAULT_NEAR, far=DEFAULT_FAR))]
    #[allow(non_snake_case)]
    fn from_viewmat(
        py: Python<'_>,
        viewmat: &Bound<'_, PyAny>,
        K: &Bound<'_, PyAny>,
        width: u32,
        height: u32,
        near: f64,
        far: f64,
    ) -> PyResult<Self> {
        let [fx, fy, cx, cy] = intrinsics(py, K)?;
        let camera = splat4d::Camera {
            width,
            height,
            fx,
            fy,
            cx,
            cy,
            world_to_camera: matrix4(py, viewmat, "viewmat")?,
            near,
            far,
            clamp: None,
        };
        checked(py, camera, near, far, "<viewmat camera>")
    }

    /// Reads a camera JSON file (`docs/formats.md`).
    #[staticmethod]
    fn load(py: Python<'_>, path: PathBuf) -> PyResult<Self> {
        Ok(Camera {
            inner: lib(py, load_camera(&path))?,
        })
    }

    /// Writes the camera as JSON (atomically).
    fn save(&self, py: Python<'_>, path: PathBuf) -> PyResult<()> {
        lib(py, save_camera(&self.inner, &path))
    }

    #[getter]
    fn width(&self) -> u32 {
        self.inner.width
    }

    #[getter]
    fn height(&self) -> u32 {
        self.inner.height
    }

    #[getter]
    fn fx(&self) -> f64 {
        self.inner.fx
    }

    #[getter]
    fn fy(&self) -> f64 {
        self.inner.fy
    }

    #[getter]
    fn cx(&self) -> f64 {
        self.inner.cx
    }

    #[getter]
    fn cy(&self) -> f64 {
        self.inner.cy
    }

    #[getter]
    fn near(&self) -> f64 {
        self.inner.near
    }

    #[getter]
    fn far(&self) -> f64 {
        self.inner.far
    }

    /// `(4, 4)`: the world→camera matrix (gsplat's `viewmat`).
    #[getter]
    fn world_to_camera<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyAny>> {
        owned_array(
            py,
            self.inner.world_to_camera.as_flattened().to_vec(),
            &[4, 4],
        )
    }

    /// `(3, 3)`: the intrinsic matrix (gsplat's `K`).
    #[getter]
    #[allow(non_snake_case)]
    fn K<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyAny>> {
        let c = &self.inner;
        let k = vec![c.fx, 0.0, c.cx, 0.0, c.fy, c.cy, 0.0, 0.0, 1.0];
        owned_array(py, k, &[3, 3])
    }

    /// `(3,)`: the camera centre in world space.
    #[getter]
    fn centre<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyAny>> {
        owned_array(py, self.inner.centre().to_vec(), &[3])
    }

    fn __repr__(&self) -> String {
        let c = &self.inner;
        format!(
            "splat4d.Camera({}×{}, fx {}, fy {}, cx {}, cy {}, centre {:?})",
            c.width,
            c.height,
            c.fx,
            c.fy,
            c.cx,
            c.cy,
            c.centre()
        )
    }
}
