//! glTF 2.0 (`.gltf` with embedded or external buffers, `.glb`): cameras, and scenes sampled
//! into 4D kernels. This folder reads and checks; the math is scene math.
//!
//! | file | what |
//! |---|---|
//! | `check.rs` | what the importer relies on and the `gltf` crate does not check, one function per glTF array |
//! | `buffers.rs` | the buffers: GLB chunk, data URIs, files beside the model |
//! | `read.rs` | the checked document as plain data: node tree, tracks, triangles |
//! | `mod.rs` | cameras, and imports: the readers above, then [`crate::scenes::surfels`] |
//!
//! **Cameras.** A perspective camera (`yfov`, `aspectRatio`, `znear`, `zfar`) on a node looks
//! down the node's −Z with +Y up (OpenGL axes); its world transform (translation and
//! rotation; scale is ignored, as glTF asks of camera nodes) is converted to SPEC §3 by
//! [`Camera::from_opengl_camera_to_world`]. Square pixels: `fy = ½ H / tan(½ yfov)`, `fx = fy`,
//! principal point at the centre. `MODEL#k` picks the k-th camera node in node order.
//!
//! **Scenes** ([`import_scene`]). `N` points are spread over the triangles of every mesh of
//! the default scene, with their colour from `COLOR_0` (interpolated) or the material's base
//! colour factor (textures are not read); node animations (translation, rotation, scale;
//! LINEAR, STEP and CUBICSPLINE samplers) through the node hierarchy (all animations play
//! together, [`crate::scenes::animation`]) are followed at the sample times
//! [`crate::scenes::motion_sampling`] chooses, each point one surfel kernel per sample time
//! ([`crate::scenes::surfels`]). Skins and morph targets are refused with a clear message.

mod buffers;
mod check;
mod read;

use std::path::Path;

use glam::DMat4;

use crate::model::camera::Camera;
use crate::model::error::{Error, Result};
use crate::scenes::animation::{Animation, NodeTree, Side};
pub use crate::scenes::motion_sampling::Spacing;
use crate::scenes::surfels::surfels;
pub use crate::scenes::surfels::{Imported, MAX_IMPORT_KERNELS, SURFEL_OPACITY};

fn parse_document(path: &Path) -> Result<gltf::Gltf> {
    let origin = path.display().to_string();
    let bytes = crate::io::input::read(path, "cannot read glTF")?;
    let malformed =
        |e: gltf::Error| Error::malformed(&origin, format!("not a valid glTF 2.0 file: {e}"));
    // Our checks first: the crate's own validation indexes arrays without bounds checks.
    let unchecked = gltf::Gltf::from_slice_without_validation(&bytes).map_err(malformed)?;
    check::check_structure(unchecked.document.as_json(), &origin)?;
    gltf::Gltf::from_slice(&bytes).map_err(malformed)
}

/// Runs `work` and turns a panic inside it (the `gltf` crate's readers index buffers it has
/// not checked; [`check::check_structure`] covers what this importer walks, this is the net under
/// it) into an input error naming the file. The panic message is not printed.
fn without_panics<T>(path: &Path, work: impl FnOnce() -> Result<T>) -> Result<T> {
    let hook = std::panic::take_hook();
    std::panic::set_hook(Box::new(|_| {}));
    let result = std::panic::catch_unwind(std::panic::AssertUnwindSafe(work));
    std::panic::set_hook(hook);
    result.unwrap_or_else(|payload| {
        let what = payload
            .downcast_ref::<&str>()
            .map(|s| (*s).to_owned())
            .or_else(|| payload.downcast_ref::<String>().cloned())
            .unwrap_or_default();
        Err(Error::malformed(
            &path.display().to_string(),
            format!("a structure the glTF reader does not check is broken ({what})"),
        ))
    })
}

/// A `MODEL[#index]` argument: the path and the camera index (0 by default).
pub fn split_camera_spec(spec: &str) -> Result<(&Path, usize)> {
    match spec.rsplit_once('#') {
        Some((path, index)) => {
            let index = index
                .parse()
                .map_err(|_| Error::Usage(format!("{spec}: `#{index}` is not a camera index")))?;
            Ok((Path::new(path), index))
        }
        None => Ok((Path::new(spec), 0)),
    }
}

/// The `index`-th camera node (in node order) of the glTF at `path`, as a SPEC §3 camera of
/// `size` (default: 512 pixels high, the camera's aspect ratio wide).
pub fn load_camera(path: &Path, index: usize, size: Option<(u32, u32)>) -> Result<Camera> {
    without_panics(path, || load_camera_unguarded(path, index, size))
}

fn load_camera_unguarded(path: &Path, index: usize, size: Option<(u32, u32)>) -> Result<Camera> {
    let origin = path.display().to_string();
    let document = parse_document(path)?;
    let world: Vec<DMat4> = Animation::new(Vec::new(), read::read_node_tree(&document))
        .world(0.0, Side::Right)
        .into_iter()
        .map(|pose| pose.0)
        .collect();
    let nodes: Vec<gltf::Node<'_>> = document.nodes().filter(|n| n.camera().is_some()).collect();
    let node = nodes.get(index).ok_or_else(|| {
        Error::Usage(format!(
            "{origin}: camera #{index} asked for, the file has {} camera nodes",
            nodes.len()
        ))
    })?;
    let item = format!("camera node {}", node.index());
    let camera = node.camera().expect("filtered on cameras");
    let gltf::camera::Projection::Perspective(p) = camera.projection() else {
        return Err(Error::invalid(
            &origin,
            &item,
            "type",
            "orthographic cameras are not supported (perspective only)",
        ));
    };
    let yfov = f64::from(p.yfov());
    if !(yfov > 0.0 && yfov < std::f64::consts::PI) {
        return Err(Error::invalid(
            &origin,
            &item,
            "yfov",
            format!("{yfov} is not in (0, π)"),
        ));
    }
    let aspect = p.aspect_ratio().map_or(1.0, f64::from);
    let (w, h) = size.unwrap_or(((512.0 * aspect).round().max(1.0) as u32, 512));
    let (_, rotation, translation) = world[node.index()].to_scale_rotation_translation();
    let rigid = DMat4::from_rotation_translation(rotation, translation);
    let mut result = Camera::from_opengl_camera_to_world(
        w,
        h,
        Camera::centred_intrinsics(w, h, yfov),
        rigid.transpose().to_cols_array_2d(),
    )
    .map_err(|e| Error::malformed(&origin, format!("{item}: {e}")))?;
    result.near = f64::from(p.znear());
    if let Some(far) = p.zfar() {
        result.far = f64::from(far);
    }
    result.validate(&format!("{origin}: {item}"))?;
    Ok(result)
}

/// Every node's world matrix (column-major, as glTF writes them) at time `t`, the node
/// animation evaluated directly (the right limit at key times): what imported kernels are
/// checked against.
pub fn world_matrices_at(path: &Path, t: f64) -> Result<Vec<[[f64; 4]; 4]>> {
    without_panics(path, || {
        let (_, _, animation) = load_animated(path)?;
        Ok(animation
            .world(t, Side::Right)
            .into_iter()
            .map(|pose| pose.0.to_cols_array_2d())
            .collect())
    })
}

/// The document at `path`, its buffers and its node animation.
fn load_animated(path: &Path) -> Result<(gltf::Gltf, Vec<Vec<u8>>, Animation)> {
    let origin = path.display().to_string();
    let gltf = parse_document(path)?;
    let buffers = buffers::load_buffers(&gltf, path)?;
    let tree: NodeTree = read::read_node_tree(&gltf.document);
    let animation = Animation::new(read::read_tracks(&gltf.document, &buffers, &origin)?, tree);
    Ok((gltf, buffers, animation))
}

/// Samples the glTF at `path` into 4D kernels (see the module docs): `points` surface
/// points, their times as `spacing` says.
pub fn import_scene(path: &Path, points: usize, spacing: Spacing, seed: u64) -> Result<Imported> {
    without_panics(path, || import_scene_unguarded(path, points, spacing, seed))
}

fn import_scene_unguarded(
    path: &Path,
    points: usize,
    spacing: Spacing,
    seed: u64,
) -> Result<Imported> {
    let origin = path.display().to_string();
    match spacing {
        Spacing::Even(0) => return Err(Error::setting(&["times"], "`times` must be at least 1")),
        Spacing::Adaptive { tolerance } if !(tolerance > 0.0 && tolerance.is_finite()) => {
            return Err(Error::setting(
                &["tolerance"],
                format!("`tolerance` {tolerance} must be a positive number"),
            ));
        }
        _ => {}
    }
    if points == 0 {
        return Err(Error::setting(&["kernels"], "`kernels` must be at least 1"));
    }
    if points > MAX_IMPORT_KERNELS {
        return Err(Error::setting(
            &["kernels"],
            format!(
                "`kernels` {points} is more than the {MAX_IMPORT_KERNELS} kernels an import may make"
            ),
        ));
    }
    if let Spacing::Even(times) = spacing
        && points.saturating_mul(times) > MAX_IMPORT_KERNELS
    {
        return Err(Error::setting(
            &["kernels", "times"],
            format!(
                "`kernels` {points} × `times` {times} is more than the {MAX_IMPORT_KERNELS} kernels an import may make"
            ),
        ));
    }
    let (gltf, buffers, animation) = load_animated(path)?;
    let triangles = read::read_triangles(&gltf.document, &buffers, &origin)?;
    surfels(&animation, &triangles, points, spacing, seed, &origin)
}
