//! `render` and `grad`: one view of a scene at one time, written as an image, or its loss
//! against a target image and the gradient per kernel.

use std::fmt;
use std::path::PathBuf;

use crate::backward::Gradients;
use crate::fit::loss::{psnr, view_loss_and_gradients};
use crate::io::camera_file::load_camera;
use crate::io::gltf::{load_camera as load_gltf_camera, split_camera_spec};
use crate::io::gradients_file::gradients_to_json;
use crate::io::image_file::{
    BitDepth, ImageKind, image_size, load_image, save_rgb8_png, save_rows,
};
use crate::io::scene_file::{load_scene, load_scene_as_stored};
use crate::io::{check_output, write_bytes_atomically};
use crate::model::{Camera, Error, Result, Scene};
use crate::overlay::draw_overlay;
use crate::render::{RenderContext, RenderOptions, RenderStats};
use crate::tasks::{threads_for, with_threads, with_threads_on_pool};

/// Where the camera comes from.
#[derive(Clone, Debug, PartialEq)]
pub enum CameraSource {
    /// A camera JSON file.
    File(PathBuf),
    /// A glTF model's camera, `MODEL.gltf[#index]`, at `size` (default: 512 high, the
    /// camera's aspect ratio).
    Gltf {
        /// `MODEL.gltf[#index]`.
        spec: String,
        /// Image size `(width, height)`.
        size: Option<(u32, u32)>,
    },
}

impl CameraSource {
    /// A camera file, else a glTF model's camera `gltf` (`MODEL.gltf[#index]`) at `size`.
    /// `size` with a camera file is refused: the file gives the camera's own size.
    pub fn new(
        file: Option<PathBuf>,
        gltf: Option<String>,
        size: Option<(u32, u32)>,
    ) -> Result<Self> {
        match file {
            Some(_) if size.is_some() => Err(Error::setting(
                &["size"],
                "`size` sizes a glTF model's camera (`camera_from`), and a camera file gives its own size: leave `size` out",
            )),
            Some(path) => Ok(CameraSource::File(path)),
            None => Ok(CameraSource::Gltf {
                spec: gltf.unwrap_or_default(),
                size,
            }),
        }
    }

    /// Reads the camera.
    pub fn load(&self) -> Result<Camera> {
        match self {
            CameraSource::File(path) => load_camera(path),
            CameraSource::Gltf { spec, size } => {
                let (path, index) = split_camera_spec(spec)?;
                load_gltf_camera(path, index, *size)
            }
        }
    }

    /// The file it is read from.
    #[must_use]
    pub fn file(&self) -> PathBuf {
        match self {
            CameraSource::File(path) => path.clone(),
            CameraSource::Gltf { spec, .. } => split_camera_spec(spec)
                .map_or_else(|_| PathBuf::from(spec), |(path, _)| path.to_path_buf()),
        }
    }

    /// Its name, for messages.
    #[must_use]
    pub fn name(&self) -> String {
        match self {
            CameraSource::File(path) => path.display().to_string(),
            CameraSource::Gltf { spec, .. } => spec.clone(),
        }
    }
}

/// A scene seen through a camera at a time.
#[derive(Clone, Debug, PartialEq)]
pub struct ViewRequest {
    /// Scene file (JSON or 4D PLY).
    pub scene: PathBuf,
    /// The camera.
    pub camera: CameraSource,
    /// Scene time τ.
    pub time: f64,
    /// Rendering options.
    pub options: RenderOptions,
    /// Worker threads (`None`: one per core).
    pub threads: Option<usize>,
}

impl ViewRequest {
    fn load(&self) -> Result<(Scene, Camera)> {
        self.options.validate()?;
        let camera = self.camera.load()?;
        Ok((load_scene(&self.scene)?, camera))
    }
}

/// `splat4d render`.
#[derive(Clone, Debug, PartialEq)]
pub struct RenderRequest {
    /// What to render.
    pub view: ViewRequest,
    /// Output image: `.png` or `.exr`.
    pub out: PathBuf,
    /// Bits per channel of a PNG (`None`: 8). Refused with an EXR output or the overlay,
    /// where it cannot act.
    pub depth: Option<BitDepth>,
    /// Draw the debug overlay ([`crate::overlay`]) instead of the plain image (PNG only).
    pub overlay: bool,
}

/// What [`render`] did.
#[derive(Clone, Debug, PartialEq)]
pub struct RenderSummary {
    out: PathBuf,
    size: (u32, u32),
    time: f64,
    /// Kernels some tile lists (their cut-off ellipse reaches the image).
    on_screen: usize,
    kernels: usize,
    pairs: u64,
}

impl fmt::Display for RenderSummary {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(
            f,
            "{}: {}×{} at t = {}, {} of {} kernels on screen, {} pairs",
            self.out.display(),
            self.size.0,
            self.size.1,
            self.time,
            self.on_screen,
            self.kernels,
            self.pairs
        )
    }
}

/// Refuses a render whose image and kernels would not fit in memory
/// ([`crate::io::memory`]).
pub fn check_render_memory(camera: &Camera, scene: &Scene) -> Result<()> {
    use crate::io::memory::{FIT_BYTES_PER_KERNEL, RENDER_BYTES_PER_PIXEL, check};
    let pixels = u64::from(camera.width) * u64::from(camera.height);
    check(
        pixels.saturating_mul(RENDER_BYTES_PER_PIXEL)
            + (scene.len() as u64).saturating_mul(FIT_BYTES_PER_KERNEL / 4),
        &format!(
            "a {}×{} render of {} kernels",
            camera.width,
            camera.height,
            scene.len()
        ),
    )
}

/// Renders a scene through a camera at one time into a PNG or EXR image.
pub fn render(request: &RenderRequest) -> Result<RenderSummary> {
    // Check the output's extension before any work, so a typo costs nothing.
    let kind = ImageKind::from_path(&request.out)?;
    if request.overlay && kind != ImageKind::Png {
        return Err(Error::setting(
            &["overlay"],
            format!(
                "{}: `overlay` draws an 8-bit PNG; use a .png output",
                request.out.display()
            ),
        ));
    }
    if request.depth.is_some() {
        let why = if kind != ImageKind::Png {
            Some("an EXR holds float32")
        } else if request.overlay {
            Some("`overlay` draws an 8-bit PNG")
        } else {
            None
        };
        if let Some(why) = why {
            return Err(Error::setting(
                &["bit_depth"],
                format!(
                    "{}: `bit_depth` sets a PNG's bits per channel, and {why}: leave `bit_depth` out",
                    request.out.display()
                ),
            ));
        }
    }
    let view = &request.view;
    check_output(
        &request.out,
        &["png", "exr"],
        &[&view.scene, &view.camera.file()],
    )?;
    // With `threads` given, everything runs on those threads (a one-thread render starts no
    // thread at all). Without, loading uses the global pool, and the render's size decides
    // where the frame and its writing run: small work on this thread, the rest on a thread
    // of the global pool.
    with_threads(view.threads, || -> Result<RenderSummary> {
        let (scene, camera) = view.load()?;
        check_render_memory(&camera, &scene)?;
        let mut context = RenderContext::new();
        let units = camera.pixel_count() as f64 * (1.0 + scene.len() as f64);
        let render_and_write = || -> Result<RenderStats> {
            if request.overlay {
                let stats = context.render(&scene, &camera, view.time, &view.options)?;
                let (w, h, rgb) = draw_overlay(&context)?;
                save_rgb8_png(&request.out, w, h, &rgb)?;
                return Ok(stats);
            }
            // The frame's rows go to the file as they are made: no image in memory.
            let size = (camera.width, camera.height);
            let depth = request.depth.unwrap_or_default();
            save_rows(&request.out, size, depth, |rows| {
                context.render_in_bands(&scene, &camera, view.time, &view.options, rows)
            })
        };
        let stats = with_threads_on_pool(threads_for(view.threads, units), render_and_write)??;
        Ok(RenderSummary {
            out: request.out.clone(),
            size: (camera.width, camera.height),
            time: view.time,
            on_screen: context.bins.kernels_listed(),
            kernels: scene.len(),
            pairs: stats.pairs,
        })
    })?
}

/// `splat4d grad`.
#[derive(Clone, Debug, PartialEq)]
pub struct GradRequest {
    /// What to render.
    pub view: ViewRequest,
    /// Target image (`.exr` or `.png`), the camera's size.
    pub target: PathBuf,
    /// Output JSON ([`crate::io::gradients_file`]).
    pub out: PathBuf,
}

/// What [`grad`] did.
#[derive(Clone, Debug, PartialEq)]
pub struct GradSummary {
    out: PathBuf,
    loss: f64,
    kernels: usize,
}

impl fmt::Display for GradSummary {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(
            f,
            "{}: loss {:e} (PSNR {:.2} dB), gradients of {} kernels",
            self.out.display(),
            self.loss,
            psnr(self.loss),
            self.kernels
        )
    }
}

/// The MSE of a render against a target image and its gradient per kernel, as JSON.
pub fn grad(request: &GradRequest) -> Result<GradSummary> {
    let view = &request.view;
    check_output(
        &request.out,
        &["json"],
        &[&view.scene, &request.target, &view.camera.file()],
    )?;
    view.options.validate()?;
    let camera = view.camera.load()?;
    // The gradient is of the quaternions as the file stores them (SPEC §8), not of the
    // normalised ones the scene holds.
    let (scene, rotation_norms) = load_scene_as_stored(&view.scene)?;
    check_render_memory(&camera, &scene)?;
    let background = scene.background.map(|b| b as f32);
    // The header first: a target of the wrong size is refused before it is decoded.
    let size = image_size(&request.target)?;
    if size != (camera.width, camera.height) {
        return Err(Error::usage(format!(
            "{}: the target is {}×{} but {} is {}×{}",
            request.target.display(),
            size.0,
            size.1,
            view.camera.name(),
            camera.width,
            camera.height
        )));
    }
    let target = load_image(&request.target, background)?;
    let mut context = RenderContext::new();
    let mut grads = Gradients::for_scene(&scene);
    let loss = with_threads(view.threads, || {
        view_loss_and_gradients(
            &mut context,
            &scene,
            &camera,
            view.time,
            &view.options,
            &target,
            &mut grads,
        )
    })??;
    // A turning kernel's quaternion is held as stored (SPEC §9): its gradient already is.
    let rotation_norms: Vec<f64> = (rotation_norms.iter().enumerate())
        .map(|(i, &norm)| {
            if scene.angular_velocity(i) == [0.0; 4] {
                norm
            } else {
                1.0
            }
        })
        .collect();
    grads.rotations_as_stored(&rotation_norms);
    // Nothing non-finite leaves (JSON would hold `null`).
    let count = scene.sh_count;
    let bad_kernel = (0..grads.len()).find(|&i| {
        grads.v_means[i]
            .iter()
            .chain(&grads.v_amplitudes[i])
            .chain(&grads.v_velocities[i])
            .chain(&grads.v_scales[i])
            .chain(&grads.v_rotations[i])
            .chain(grads.v_accelerations.get(i).into_iter().flatten())
            .chain(grads.v_angular_velocities.get(i).into_iter().flatten())
            .chain(grads.v_opacities.get(i))
            .chain(
                grads
                    .v_sh
                    .get(i * count..(i + 1) * count)
                    .into_iter()
                    .flatten()
                    .flatten(),
            )
            .any(|v| !v.is_finite())
    });
    if !loss.is_finite() || bad_kernel.is_some() {
        let what = bad_kernel.map_or_else(
            || format!("the loss is {loss}"),
            |i| format!("kernel {i}'s gradient is not finite"),
        );
        return Err(Error::Numeric(format!(
            "{}: not written: {what} (the scene's amplitudes, background or the target's values are too large for f32)",
            request.out.display()
        )));
    }
    write_bytes_atomically(&request.out, gradients_to_json(&grads, loss).as_bytes())?;
    Ok(GradSummary {
        out: request.out.clone(),
        loss,
        kernels: scene.len(),
    })
}
