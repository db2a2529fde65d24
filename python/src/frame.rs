//! One frame from Python: the render (SPEC §2–5, §8), its exact gradient (SPEC §6, §8) and
//! the f64 twins of both (`splat4d::reference`), with the GIL released while they run.
//!
//! The gradient of the pixels' opacities `1 - T` (gsplat's `render_alphas`, SPEC §8: `T`
//! the transmittance after a pixel's last kernel) is the gradient of the same frame with
//! every colour 1 and a black background: `1 - T = Σ_i α̂_i T_i`, what that frame composites,
//! with the same pairs, order and stops.

use std::borrow::Cow;

use numpy::PyUntypedArrayMethods;
use pyo3::prelude::*;
use pyo3::types::PyDict;
use splat4d::backward::Gradients;
use splat4d::reference::composite::render_reference_alpha;
use splat4d::reference::{reference_loss_and_gradients, render_reference};
use splat4d::render::{DEFAULT_CUTOFF, DEFAULT_DILATION};
use splat4d::tasks::render::check_render_memory;
use splat4d::tasks::with_threads;
use splat4d::{Blend, RenderContext, RenderOptions};

use crate::arrays::{AnyF32, owned_array, rows_array, shape_text, values};
use crate::camera::Camera;
use crate::errors::{lib, usage};
use crate::scene::{Scene, parse_blend};

/// What every frame function reads beside the scene, camera and time.
struct Frame<'a> {
    scene: Cow<'a, splat4d::Scene>,
    camera: &'a splat4d::Camera,
    t: f64,
    options: RenderOptions,
    threads: Option<usize>,
}

impl<'a> Frame<'a> {
    /// The frame of `scene` (in `blend` when given) through `camera` at `t`, checked.
    #[allow(clippy::too_many_arguments)]
    fn new(
        py: Python<'_>,
        scene: &'a Scene,
        camera: &'a Camera,
        t: f64,
        blend: Option<&str>,
        dilation: f64,
        cutoff: f64,
        exp: &str,
        threads: Option<usize>,
    ) -> PyResult<Self> {
        let exp = exp
            .parse()
            .map_err(|e: String| usage(py, format!("exp: {e}")))?;
        let options = RenderOptions {
            dilation,
            cutoff,
            exp,
        };
        lib(py, options.validate())?;
        let scene = match blend {
            Some(text) => in_blend(&scene.inner, parse_blend(py, text)?),
            None => Cow::Borrowed(&scene.inner),
        };
        lib(py, check_render_memory(&camera.inner, &scene))?;
        Ok(Frame {
            scene,
            camera: &camera.inner,
            t,
            options,
            threads,
        })
    }

    fn shape(&self) -> [usize; 3] {
        [self.camera.height as usize, self.camera.width as usize, 3]
    }

    /// The pixel count.
    fn pixels(&self) -> usize {
        self.camera.pixel_count()
    }
}

/// `scene` rendered with `blend`: an additive scene as alpha has opacity 1 (SPEC §8's
/// default) and no SH; an alpha scene as additive leaves its opacities and SH aside.
fn in_blend(scene: &splat4d::Scene, blend: Blend) -> Cow<'_, splat4d::Scene> {
    if scene.blend == blend {
        return Cow::Borrowed(scene);
    }
    let mut other = scene.clone();
    other.blend = blend;
    match blend {
        Blend::Alpha => other.opacities = vec![1.0; scene.len()],
        Blend::Additive => other.opacities.clear(),
    }
    other.sh.clear();
    other.sh_count = 0;
    Cow::Owned(other)
}

/// The frame whose pixels are the opacities `1 - T` of an alpha scene's frame: every
/// colour 1, no SH, a black background.
fn opacity_frame(scene: &splat4d::Scene) -> splat4d::Scene {
    let mut ones = scene.clone();
    ones.amplitudes.iter_mut().for_each(|a| *a = [1.0; 3]);
    ones.sh.clear();
    ones.sh_count = 0;
    ones.background = [0.0; 3];
    ones
}

/// Renders `scene` through `camera` at time `t`: `(H, W, 3)` float32, linear RGB. With
/// `alphas`, also the pixels' opacities `1 - T` `(H, W, 1)` (0 for the additive blend).
#[pyfunction]
#[pyo3(signature = (scene, camera, t, *, blend=None, dilation=DEFAULT_DILATION, cutoff=DEFAULT_CUTOFF, exp="poly", threads=None, alphas=false))]
#[allow(clippy::too_many_arguments)]
pub fn render<'py>(
    py: Python<'py>,
    scene: &Bound<'py, Scene>,
    camera: &Bound<'py, Camera>,
    t: f64,
    blend: Option<&str>,
    dilation: f64,
    cutoff: f64,
    exp: &str,
    threads: Option<usize>,
    alphas: bool,
) -> PyResult<Bound<'py, PyAny>> {
    let frame = Frame::new(
        py,
        scene.get(),
        camera.get(),
        t,
        blend,
        dilation,
        cutoff,
        exp,
        threads,
    )?;
    let alpha = frame.scene.blend == Blend::Alpha;
    let (image, opacities) = lib(
        py,
        py.detach(|| {
            with_threads(frame.threads, || -> splat4d::Result<_> {
                let mut context = RenderContext::new();
                if !(alphas && alpha) {
                    context.render(&frame.scene, frame.camera, frame.t, &frame.options)?;
                    return Ok((context.image().pixels.clone(), None));
                }
                // The stops a frame for a backward keeps carry each pixel's T.
                context.render_for_backward(&frame.scene, frame.camera, frame.t, &frame.options)?;
                let opacities = context
                    .pixel_stops()
                    .iter()
                    .map(|stop| (1.0 - stop.transmittance) as f32)
                    .collect::<Vec<f32>>();
                Ok((context.image().pixels.clone(), Some(opacities)))
            })
        })
        .and_then(|r| r),
    )?;
    let [h, w, _] = frame.shape();
    let image = owned_array(py, image, &frame.shape())?;
    if !alphas {
        return Ok(image);
    }
    let opacities = opacities.unwrap_or_else(|| vec![0.0; h * w]);
    if opacities.len() != h * w {
        return Err(usage(py, "internal: the frame kept no stop per pixel"));
    }
    let opacities = owned_array(py, opacities, &[h, w, 1])?;
    Ok((image, opacities).into_pyobject(py)?.into_any())
}

/// `(H, W, C)` values of an array-like; `what` names it.
fn pixel_values(
    py: Python<'_>,
    value: &Bound<'_, PyAny>,
    what: &str,
    shape: &[usize],
) -> PyResult<Vec<f32>> {
    let array = value
        .extract::<AnyF32<'_>>()
        .map_err(|e| usage(py, format!("{what}: not an array of numbers ({e})")))?;
    let fits = array.shape() == shape || (shape[2] == 1 && array.shape() == &shape[..2]);
    if !fits {
        return Err(usage(
            py,
            format!(
                "{what}: shape {}, expected {} (the camera's height, width)",
                shape_text(array.shape()),
                shape_text(shape)
            ),
        ));
    }
    Ok(values(&array))
}

/// The gradient of a loss with respect to every field of `scene`, given `v_image = ∂L/∂C`
/// `(H, W, 3)` for the frame through `camera` at `t` (SPEC §6, §8), and, for alpha scenes,
/// `v_alphas = ∂L/∂(1 - T)` `(H, W)` or `(H, W, 1)`. A dict named like the scene's fields.
#[pyfunction]
#[pyo3(signature = (scene, camera, t, v_image, *, v_alphas=None, blend=None, dilation=DEFAULT_DILATION, cutoff=DEFAULT_CUTOFF, exp="poly", threads=None))]
#[allow(clippy::too_many_arguments)]
pub fn render_and_backward<'py>(
    py: Python<'py>,
    scene: &Bound<'py, Scene>,
    camera: &Bound<'py, Camera>,
    t: f64,
    v_image: &Bound<'py, PyAny>,
    v_alphas: Option<&Bound<'py, PyAny>>,
    blend: Option<&str>,
    dilation: f64,
    cutoff: f64,
    exp: &str,
    threads: Option<usize>,
) -> PyResult<Bound<'py, PyDict>> {
    let owner = scene.get();
    let frame = Frame::new(
        py,
        owner,
        camera.get(),
        t,
        blend,
        dilation,
        cutoff,
        exp,
        threads,
    )?;
    let shape = frame.shape();
    let v_image = pixel_values(py, v_image, "v_image", &shape)?;
    let v_alphas = match v_alphas {
        Some(v) => Some(pixel_values(py, v, "v_alphas", &[shape[0], shape[1], 1])?),
        None => None,
    };
    let grads = lib(
        py,
        py.detach(|| {
            with_threads(frame.threads, || {
                backward(&frame, &v_image, v_alphas.as_deref())
            })
        })
        .and_then(|r| r),
    )?;
    gradients_dict(py, &frame.scene, grads, &owner.rotation_norms)
}

/// The frame's gradient (see [`render_and_backward`]).
fn backward(
    frame: &Frame<'_>,
    v_image: &[f32],
    v_alphas: Option<&[f32]>,
) -> splat4d::Result<Gradients> {
    let (scene, camera, t, options) = (&*frame.scene, frame.camera, frame.t, &frame.options);
    let mut context = RenderContext::new();
    let mut grads = Gradients::for_scene(scene);
    context.render_for_backward(scene, camera, t, options)?;
    context.backward(scene, camera, t, options, v_image, &mut grads);
    let v_alphas = v_alphas.filter(|v| scene.blend == Blend::Alpha && v.iter().any(|&x| x != 0.0));
    if let Some(v_alphas) = v_alphas {
        let ones = opacity_frame(scene);
        let v: Vec<f32> = v_alphas.iter().flat_map(|&a| [a, 0.0, 0.0]).collect();
        let mut more = Gradients::for_scene(&ones);
        context.render_for_backward(&ones, camera, t, options)?;
        context.backward(&ones, camera, t, options, &v, &mut more);
        // Only the geometry and the opacity shape `T`.
        add_rows(&mut grads.v_means, &more.v_means);
        add_rows(&mut grads.v_scales, &more.v_scales);
        add_rows(&mut grads.v_rotations, &more.v_rotations);
        add_rows(&mut grads.v_velocities, &more.v_velocities);
        for (total, part) in grads.v_opacities.iter_mut().zip(&more.v_opacities) {
            *total += part;
        }
    }
    Ok(grads)
}

fn add_rows<const K: usize>(total: &mut [[f64; K]], part: &[[f64; K]]) {
    for (total, part) in total.iter_mut().zip(part) {
        for (total, part) in total.iter_mut().zip(part) {
            *total += part;
        }
    }
}

/// `grads` as a dict named like the scene's fields; rotations' gradients are of the
/// quaternions as given (norms `norms`).
fn gradients_dict<'py>(
    py: Python<'py>,
    scene: &splat4d::Scene,
    mut grads: Gradients,
    norms: &[f64],
) -> PyResult<Bound<'py, PyDict>> {
    grads.rotations_as_stored(norms);
    let dict = PyDict::new(py);
    dict.set_item("means", rows_array(py, &grads.v_means)?)?;
    dict.set_item("scales", rows_array(py, &grads.v_scales)?)?;
    dict.set_item("amplitudes", rows_array(py, &grads.v_amplitudes)?)?;
    dict.set_item("rotations", rows_array(py, &grads.v_rotations)?)?;
    dict.set_item("velocities", rows_array(py, &grads.v_velocities)?)?;
    dict.set_item(
        "background",
        owned_array(py, grads.v_background.to_vec(), &[3])?,
    )?;
    if scene.blend == Blend::Alpha {
        let n = scene.len();
        dict.set_item("opacities", owned_array(py, grads.v_opacities, &[n])?)?;
        let sh = grads.v_sh.as_flattened().to_vec();
        dict.set_item("sh", owned_array(py, sh, &[n, scene.sh_count, 3])?)?;
    }
    Ok(dict)
}

/// The f64 twin's frame (`splat4d::reference`: every kernel at every pixel, SPEC §5 or §8
/// as written): `(H, W, 3)` float64, and with `uncertain` the pixels where SPEC lets two
/// implementations differ (a pair within the cut-off band, or a stop within 1e-6 of
/// `T_stop`), `(H, W)` bool.
#[pyfunction]
#[pyo3(signature = (scene, camera, t, *, blend=None, dilation=DEFAULT_DILATION, cutoff=DEFAULT_CUTOFF, uncertain=false))]
#[allow(clippy::too_many_arguments)]
pub fn reference_render<'py>(
    py: Python<'py>,
    scene: &Bound<'py, Scene>,
    camera: &Bound<'py, Camera>,
    t: f64,
    blend: Option<&str>,
    dilation: f64,
    cutoff: f64,
    uncertain: bool,
) -> PyResult<Bound<'py, PyAny>> {
    let frame = Frame::new(
        py,
        scene.get(),
        camera.get(),
        t,
        blend,
        dilation,
        cutoff,
        "std",
        None,
    )?;
    let (scene, camera, options) = (&*frame.scene, frame.camera, &frame.options);
    let (pixels, mask) = py.detach(|| match scene.blend {
        Blend::Additive => {
            let image = render_reference(scene, camera, t, options);
            let mask: Vec<bool> = image.borderline.iter().map(|&b| b > 0).collect();
            (image.pixels, mask)
        }
        Blend::Alpha => {
            let image = render_reference_alpha(scene, camera, t, options);
            let mask = image
                .borderline
                .iter()
                .zip(&image.stop_margin)
                .map(|(&b, &m)| b || m <= 1e-6)
                .collect();
            (image.pixels, mask)
        }
    });
    let shape = frame.shape();
    let image = owned_array(py, pixels, &shape)?;
    if !uncertain {
        return Ok(image);
    }
    let mask = owned_array(py, mask, &shape[..2])?;
    Ok((image, mask).into_pyobject(py)?.into_any())
}

/// The f64 twin's MSE against `target` `(H, W, 3)` and its exact gradient (SPEC §6), for the
/// additive blend: `(loss, gradients)` named like [`render_and_backward`]'s.
#[pyfunction]
#[pyo3(signature = (scene, camera, t, target, *, dilation=DEFAULT_DILATION, cutoff=DEFAULT_CUTOFF))]
#[pyo3(name = "reference_loss_and_gradients")]
pub fn reference_loss_and_gradients_py<'py>(
    py: Python<'py>,
    scene: &Bound<'py, Scene>,
    camera: &Bound<'py, Camera>,
    t: f64,
    target: &Bound<'py, PyAny>,
    dilation: f64,
    cutoff: f64,
) -> PyResult<(f64, Bound<'py, PyDict>)> {
    let owner = scene.get();
    if owner.inner.blend != Blend::Additive {
        return Err(usage(
            py,
            "the f64 twin's gradient covers the additive blend (alpha gradients are checked against finite differences of reference_render)",
        ));
    }
    let frame = Frame::new(
        py,
        owner,
        camera.get(),
        t,
        None,
        dilation,
        cutoff,
        "std",
        None,
    )?;
    let target = pixel_values(py, target, "target", &frame.shape())?;
    debug_assert_eq!(target.len(), 3 * frame.pixels());
    let (loss, grads) = py.detach(|| {
        reference_loss_and_gradients(&frame.scene, frame.camera, t, &frame.options, &target)
    });
    Ok((
        loss,
        gradients_dict(py, &frame.scene, grads, &owner.rotation_norms)?,
    ))
}
