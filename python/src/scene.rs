//! `splat4d.Scene`: the kernels of SPEC §1 (and §8's opacity and SH) as arrays, validated
//! once when built or loaded; `load_scene` and `save_scene` read and write the project's
//! files (JSON, 4D PLY, 3DGS PLY).

use std::path::PathBuf;

use numpy::PyUntypedArrayMethods;
use pyo3::prelude::*;
use pyo3::types::PyDict;
use splat4d::io::ply::STATIC_TIME_SCALE;
use splat4d::io::scene_file::{load_scene_as_stored, save_scene};
use splat4d::{Blend, Kernel};

use crate::arrays::{array_f64, for_rows, rows, rows_array, shape_text, values};
use crate::errors::{lib, usage};

/// Where a scene built from arrays comes from, in error messages.
const ORIGIN: &str = "<scene>";

/// A scene of 4D Gaussian kernels (SPEC §1; the alpha blend's fields, §8), immutable: build
/// another to change it. Arrays in, arrays out (float64).
#[pyclass(module = "splat4d", name = "Scene", frozen)]
pub struct Scene {
    pub inner: splat4d::Scene,
    /// The norm of each quaternion as given (the scene holds them normalised): gradients
    /// are of the quaternions as given (SPEC §8).
    pub rotation_norms: Vec<f64>,
}

impl Scene {
    /// A scene loaded or built elsewhere, its quaternions given as unit ones unless `norms`.
    pub fn wrap(inner: splat4d::Scene, norms: Option<Vec<f64>>) -> Self {
        let rotation_norms = norms
            .filter(|n| n.len() == inner.len())
            .unwrap_or_else(|| vec![1.0; inner.len()]);
        Scene {
            inner,
            rotation_norms,
        }
    }
}

/// `(N, 4)` rows, or `(N, 3)` ones completed with `fourth`.
fn rows_of_four(
    py: Python<'_>,
    value: &Bound<'_, PyAny>,
    what: &str,
    n: Option<usize>,
    fourth: f64,
) -> PyResult<Vec<[f64; 4]>> {
    let array = array_f64(value, what)?;
    let shape = array.shape().to_vec();
    if shape.len() == 2 && shape[1] == 3 && n.is_none_or(|n| shape[0] == n) {
        let mut out = Vec::with_capacity(shape[0]);
        for_rows::<3>(&array, |[a, b, c]| out.push([a, b, c, fourth]));
        return Ok(out);
    }
    if shape.len() == 2 && shape[1] == 4 {
        return rows::<4>(py, &array, what, n);
    }
    let n = n.map_or("N".to_owned(), |n| n.to_string());
    Err(usage(
        py,
        format!(
            "{what}: shape {}, expected ({n}, 4) or ({n}, 3)",
            shape_text(&shape)
        ),
    ))
}

/// The blend named `text`.
pub fn parse_blend(py: Python<'_>, text: &str) -> PyResult<Blend> {
    text.parse::<Blend>()
        .map_err(|e| usage(py, format!("blend: {e}")))
}

#[pymethods]
impl Scene {
    /// Builds and validates a scene. `means` is `(N, 4)` `[x, y, z, t]` (or `(N, 3)`: t = 0),
    /// `scales` `(N, 4)` standard deviations `[sx, sy, sz, st]` (or `(N, 3)`: static kernels,
    /// st = 1e30), `amplitudes` `(N, 3)`; `rotations` `(N, 4)` quaternions `[w, x, y, z]`
    /// (normalised; default identity), `velocities` `(N, 3)` (default 0), `background` `(3,)`.
    /// `opacities` `(N,)` in [0, 1] and `sh` `(N, K, 3)` (K = 0, 3, 8 or 15) make it an alpha
    /// scene; `blend` is `"additive"` or `"alpha"` (default: alpha when either is given).
    #[new]
    #[pyo3(signature = (means, scales, amplitudes, *, rotations=None, velocities=None, background=None, blend=None, opacities=None, sh=None))]
    #[allow(clippy::too_many_arguments)]
    fn new(
        py: Python<'_>,
        means: &Bound<'_, PyAny>,
        scales: &Bound<'_, PyAny>,
        amplitudes: &Bound<'_, PyAny>,
        rotations: Option<&Bound<'_, PyAny>>,
        velocities: Option<&Bound<'_, PyAny>>,
        background: Option<&Bound<'_, PyAny>>,
        blend: Option<&str>,
        opacities: Option<&Bound<'_, PyAny>>,
        sh: Option<&Bound<'_, PyAny>>,
    ) -> PyResult<Self> {
        let means = rows_of_four(py, means, "means", None, 0.0)?;
        let n = Some(means.len());
        let scales = rows_of_four(py, scales, "scales", n, STATIC_TIME_SCALE)?;
        let amplitudes = rows::<3>(py, &array_f64(amplitudes, "amplitudes")?, "amplitudes", n)?;
        let rotations = match rotations {
            Some(r) => rows::<4>(py, &array_f64(r, "rotations")?, "rotations", n)?,
            None => vec![[1.0, 0.0, 0.0, 0.0]; means.len()],
        };
        let velocities = match velocities {
            Some(v) => rows::<3>(py, &array_f64(v, "velocities")?, "velocities", n)?,
            None => vec![[0.0; 3]; means.len()],
        };
        let background = match background {
            Some(b) => {
                let array = array_f64(b, "background")?;
                let v = values(&array);
                <[f64; 3]>::try_from(v.as_slice()).map_err(|_| {
                    usage(
                        py,
                        format!(
                            "background: shape {}, expected (3,)",
                            shape_text(array.shape())
                        ),
                    )
                })?
            }
            None => [0.0; 3],
        };
        let blend = match blend {
            Some(text) => parse_blend(py, text)?,
            None if opacities.is_some() || sh.is_some() => Blend::Alpha,
            None => Blend::Additive,
        };
        let kernels: Vec<Kernel> = (0..means.len())
            .map(|i| Kernel {
                mean: means[i],
                scale: scales[i],
                amplitude: amplitudes[i],
                rotation: rotations[i],
                velocity: velocities[i],
                ..Kernel::new([0.0; 4], [1.0; 4], [0.0; 3])
            })
            .collect();
        let norms = rotations
            .iter()
            .map(|q| q.iter().map(|v| v * v).sum::<f64>().sqrt())
            .collect();
        let mut scene = lib(
            py,
            splat4d::Scene::from_kernels(&kernels, background, ORIGIN),
        )?;
        scene.blend = blend;
        if blend == Blend::Alpha || opacities.is_some() || sh.is_some() {
            let opacities = match opacities {
                Some(o) => {
                    let array = array_f64(o, "opacities")?;
                    if array.shape() != [means.len()] {
                        return Err(usage(
                            py,
                            format!(
                                "opacities: shape {}, expected ({},)",
                                shape_text(array.shape()),
                                means.len()
                            ),
                        ));
                    }
                    values(&array)
                }
                None => vec![1.0; means.len()],
            };
            let (count, sh) = match sh {
                Some(s) => sh_rows(py, s, means.len())?,
                None => (0, Vec::new()),
            };
            let additive = blend == Blend::Additive;
            scene = lib(py, scene.into_alpha(opacities, count, sh, ORIGIN))?;
            if additive {
                // Refused with the library's message: the alpha fields need the alpha blend.
                scene.blend = Blend::Additive;
                lib(py, scene.validate(ORIGIN))?;
            }
        }
        Ok(Scene::wrap(scene, Some(norms)))
    }

    /// Reads a scene file: splat4d JSON, 4D PLY or a graphdeco 3DGS PLY.
    #[staticmethod]
    fn load(py: Python<'_>, path: PathBuf) -> PyResult<Self> {
        let (scene, norms) = lib(py, py.detach(|| load_scene_as_stored(&path)))?;
        Ok(Scene::wrap(scene, Some(norms)))
    }

    /// Writes the scene: 4D PLY for `.ply`, JSON otherwise (atomically: the old file or the
    /// new one, never a mix).
    fn save(&self, py: Python<'_>, path: PathBuf) -> PyResult<()> {
        lib(py, py.detach(|| save_scene(&self.inner, &path)))
    }

    fn __len__(&self) -> usize {
        self.inner.len()
    }

    fn __repr__(&self) -> String {
        format!(
            "splat4d.Scene({} kernels, blend {}{})",
            self.inner.len(),
            self.inner.blend,
            if self.inner.sh_count > 0 {
                format!(", {} SH triplets", self.inner.sh_count)
            } else {
                String::new()
            }
        )
    }

    /// `(N, 4)`: `[x, y, z, t]` per kernel.
    #[getter]
    fn means<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyAny>> {
        rows_array(py, &self.inner.means)
    }

    /// `(N, 4)`: standard deviations `[sx, sy, sz, st]`.
    #[getter]
    fn scales<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyAny>> {
        rows_array(py, &self.inner.scales)
    }

    /// `(N, 3)`: peak amplitudes (alpha scenes: the colour's view-independent part).
    #[getter]
    fn amplitudes<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyAny>> {
        rows_array(py, &self.inner.amplitudes)
    }

    /// `(N, 4)`: unit quaternions `[w, x, y, z]`.
    #[getter]
    fn rotations<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyAny>> {
        rows_array(py, &self.inner.rotations)
    }

    /// `(N, 3)`: world units per time unit.
    #[getter]
    fn velocities<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyAny>> {
        rows_array(py, &self.inner.velocities)
    }

    /// `(3,)`: the background colour, linear RGB.
    #[getter]
    fn background<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyAny>> {
        crate::arrays::owned_array(py, self.inner.background.to_vec(), &[3])
    }

    /// `"additive"` or `"alpha"`.
    #[getter]
    fn blend(&self) -> String {
        self.inner.blend.to_string()
    }

    /// `(N,)` peak opacities of an alpha scene; `None` for an additive one.
    #[getter]
    fn opacities<'py>(&self, py: Python<'py>) -> PyResult<Option<Bound<'py, PyAny>>> {
        if self.inner.blend != Blend::Alpha {
            return Ok(None);
        }
        let n = self.inner.opacities.len();
        crate::arrays::owned_array(py, self.inner.opacities.clone(), &[n]).map(Some)
    }

    /// `(N, K, 3)` SH coefficients of an alpha scene (K = 0, 3, 8 or 15); `None` for an
    /// additive one.
    #[getter]
    fn sh<'py>(&self, py: Python<'py>) -> PyResult<Option<Bound<'py, PyAny>>> {
        if self.inner.blend != Blend::Alpha {
            return Ok(None);
        }
        let values = self.inner.sh.as_flattened().to_vec();
        let shape = [self.inner.len(), self.inner.sh_count, 3];
        crate::arrays::owned_array(py, values, &shape).map(Some)
    }

    /// The arrays as keyword arguments of `Scene(...)`: `Scene(**scene.to_dict())` is the
    /// same scene.
    fn to_dict<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        let dict = PyDict::new(py);
        dict.set_item("means", self.means(py)?)?;
        dict.set_item("scales", self.scales(py)?)?;
        dict.set_item("amplitudes", self.amplitudes(py)?)?;
        dict.set_item("rotations", self.rotations(py)?)?;
        dict.set_item("velocities", self.velocities(py)?)?;
        dict.set_item("background", self.background(py)?)?;
        dict.set_item("blend", self.blend())?;
        if let (Some(o), Some(sh)) = (self.opacities(py)?, self.sh(py)?) {
            dict.set_item("opacities", o)?;
            dict.set_item("sh", sh)?;
        }
        Ok(dict)
    }
}

/// SH triplets from an `(N, K, 3)` array: K and the triplets, kernel by kernel.
fn sh_rows(py: Python<'_>, value: &Bound<'_, PyAny>, n: usize) -> PyResult<(usize, Vec<[f64; 3]>)> {
    let array = array_f64(value, "sh")?;
    let shape = array.shape().to_vec();
    if shape.len() != 3 || shape[0] != n || shape[2] != 3 {
        return Err(usage(
            py,
            format!("sh: shape {}, expected ({n}, K, 3)", shape_text(&shape)),
        ));
    }
    let flat = values(&array);
    let triplets = flat.chunks_exact(3).map(|t| [t[0], t[1], t[2]]).collect();
    Ok((shape[1], triplets))
}
