//! Scene files: JSON, and 4D scene PLY ([`super::ply`]) for paths ending in `.ply`.
//!
//! JSON layout (keys in this order, `rotation`, `velocity`, `background` and `up` optional):
//! `{"kernels":[{"mean":[x,y,z,t],"scale":[sx,sy,sz,st],"amplitude":[r,g,b],
//! "rotation":[w,x,y,z],"velocity":[vx,vy,vz]}],"background":[r,g,b],"up":"z"}` (SPEC §1;
//! `up` is the world's up axis, `x`, `y`, `z`, `-x`, `-y` or `-z`, written only when known:
//! videos turn about it). Unknown
//! keys are errors, so that a typo never silently falls back to a default. Numbers are
//! written so that they read back exactly (serde_json's `float_roundtrip`).
//!
//! A fitted scene records `"time_range": [t0, t1]`, the times of the data it came from
//! (videos and sequences span it by default), and `"framing": {"centre": [x, y, z],
//! "radius": r}`, the sphere its cameras look at (videos frame it by default).
//!
//! Alpha scenes (SPEC §8) add `"blend": "alpha"` at the top and per kernel `"opacity": o`
//! (0–1, default 1) and `"sh": [[r, g, b], …]` (3, 8 or 15 triplets, the same count for
//! every kernel, or absent). Additive scenes write neither (`"blend": "additive"` is
//! accepted and is the default).

use std::path::Path;

use serde::{Deserialize, Serialize};

use crate::io::json::parse_json;
use crate::io::write_bytes_atomically;
use crate::model::{Blend, Error, Kernel, Result, Scene, Up};

#[derive(Serialize, Deserialize)]
#[serde(
    deny_unknown_fields,
    expecting = "a scene object {\"kernels\": [...], \"background\": [r, g, b]}"
)]
struct SceneFile {
    #[serde(default, skip_serializing_if = "is_additive")]
    blend: Blend,
    kernels: Vec<KernelRecord>,
    #[serde(default)]
    background: [f64; 3],
    #[serde(default, skip_serializing_if = "Option::is_none")]
    up: Option<Up>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    time_range: Option<[f64; 2]>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    framing: Option<Framing>,
}

/// The sphere a fitted scene's cameras look at.
#[derive(Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct Framing {
    centre: [f64; 3],
    radius: f64,
}

fn is_additive(blend: &Blend) -> bool {
    *blend == Blend::Additive
}

/// One kernel as the file has it: [`Kernel`]'s fields, then the alpha blend's.
#[derive(Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct KernelRecord {
    mean: [f64; 4],
    scale: [f64; 4],
    amplitude: [f64; 3],
    #[serde(default = "identity_rotation")]
    rotation: [f64; 4],
    #[serde(default)]
    velocity: [f64; 3],
    #[serde(default, skip_serializing_if = "is_zero")]
    acceleration: [f64; 3],
    #[serde(default, skip_serializing_if = "is_zero")]
    angular_velocity: [f64; 4],
    #[serde(default, skip_serializing_if = "Option::is_none")]
    opacity: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    sh: Option<Vec<[f64; 3]>>,
}

/// True for an all-zero SPEC §9 field, which is not written.
fn is_zero<const N: usize>(values: &[f64; N]) -> bool {
    values.iter().all(|&v| v == 0.0)
}

fn identity_rotation() -> [f64; 4] {
    [1.0, 0.0, 0.0, 0.0]
}

/// Parses and validates a scene JSON document. `origin` names it in error messages.
pub fn scene_from_json(text: &str, origin: &str) -> Result<Scene> {
    scene_from_json_as_stored(text, origin).map(|(scene, _)| scene)
}

/// [`scene_from_json`], and the norm of each kernel's quaternion as the document stores it
/// (the scene holds it normalised).
pub fn scene_from_json_as_stored(text: &str, origin: &str) -> Result<(Scene, Vec<f64>)> {
    let file: SceneFile = parse_json(text, origin, "scene")?;
    let norms = file
        .kernels
        .iter()
        .map(|k| k.rotation.iter().map(|v| v * v).sum::<f64>().sqrt())
        .collect();
    Ok((scene_from_file(file, origin)?, norms))
}

/// The scene of a parsed document, validated.
fn scene_from_file(file: SceneFile, origin: &str) -> Result<Scene> {
    let kernels: Vec<Kernel> = file
        .kernels
        .iter()
        .map(|k| Kernel {
            mean: k.mean,
            scale: k.scale,
            amplitude: k.amplitude,
            rotation: k.rotation,
            velocity: k.velocity,
            acceleration: k.acceleration,
            angular_velocity: k.angular_velocity,
        })
        .collect();
    let mut scene = Scene::from_kernels(&kernels, file.background, origin)?;
    scene.up = file.up;
    scene.time_range = file.time_range;
    scene.framing = file.framing.map(|f| (f.centre, f.radius));
    scene.check_time_range(origin)?;
    match file.blend {
        Blend::Additive => {
            if let Some(i) = file
                .kernels
                .iter()
                .position(|k| k.opacity.is_some() || k.sh.is_some())
            {
                let field = if file.kernels[i].opacity.is_some() {
                    "opacity"
                } else {
                    "sh"
                };
                return Err(Error::invalid(
                    origin,
                    format!("kernel {i}"),
                    field,
                    "a field of the alpha blend in an additive scene: add \"blend\": \"alpha\" to the scene",
                ));
            }
            Ok(scene)
        }
        Blend::Alpha => {
            let sh_count = file
                .kernels
                .first()
                .and_then(|k| k.sh.as_ref())
                .map_or(0, Vec::len);
            let mut sh = Vec::with_capacity(sh_count * file.kernels.len());
            for (i, k) in file.kernels.iter().enumerate() {
                let triplets = k.sh.as_deref().unwrap_or(&[]);
                if triplets.len() != sh_count {
                    return Err(Error::invalid(
                        origin,
                        format!("kernel {i}"),
                        "sh",
                        format!(
                            "{} triplets where kernel 0 has {sh_count}: every kernel has the same number",
                            triplets.len()
                        ),
                    ));
                }
                sh.extend_from_slice(triplets);
            }
            let opacities = file
                .kernels
                .iter()
                .map(|k| k.opacity.unwrap_or(1.0))
                .collect();
            scene.into_alpha(opacities, sh_count, sh, origin)
        }
    }
}

/// The scene as a JSON document (the format of [`scene_from_json`]).
#[must_use]
pub fn scene_to_json(scene: &Scene) -> String {
    let alpha = scene.blend == Blend::Alpha;
    let kernels = (0..scene.len())
        .map(|i| {
            let k = scene.kernel(i);
            KernelRecord {
                mean: k.mean,
                scale: k.scale,
                amplitude: k.amplitude,
                rotation: k.rotation,
                velocity: k.velocity,
                acceleration: k.acceleration,
                angular_velocity: k.angular_velocity,
                opacity: alpha.then(|| scene.opacity(i)),
                sh: (alpha && scene.sh_count > 0).then(|| scene.sh_of(i).to_vec()),
            }
        })
        .collect();
    let file = SceneFile {
        blend: scene.blend,
        kernels,
        background: scene.background,
        up: scene.up,
        time_range: scene.time_range,
        framing: scene
            .framing
            .map(|(centre, radius)| Framing { centre, radius }),
    };
    serde_json::to_string_pretty(&file).expect("a scene of finite numbers serialises")
}

/// Reads a scene file: 4D scene PLY for `.ply`, JSON otherwise.
pub fn load_scene(path: &Path) -> Result<Scene> {
    read_scene(path, false).map(|(scene, _)| scene)
}

/// [`load_scene`], and the norm of each kernel's quaternion as the file stores it (the
/// scene holds it normalised): `splat4d grad` gives the gradient of the stored quaternion
/// ([`crate::backward::Gradients::rotations_as_stored`]).
pub fn load_scene_as_stored(path: &Path) -> Result<(Scene, Vec<f64>)> {
    read_scene(path, true).map(|(scene, norms)| (scene, norms.unwrap_or_default()))
}

/// [`load_scene`], with the stored quaternions' norms when `rotation_norms`.
fn read_scene(path: &Path, rotation_norms: bool) -> Result<(Scene, Option<Vec<f64>>)> {
    if is_ply(path) {
        return super::ply::read_scene_ply_as_stored(path, rotation_norms);
    }
    let text = crate::io::input::read_to_string(path, "cannot read scene")?;
    let origin = path.display().to_string();
    if rotation_norms {
        let (scene, norms) = scene_from_json_as_stored(&text, &origin)?;
        return Ok((scene, Some(norms)));
    }
    Ok((scene_from_json(&text, &origin)?, None))
}

/// Writes a scene atomically: 4D scene PLY for `.ply`, JSON otherwise.
pub fn save_scene(scene: &Scene, path: &Path) -> Result<()> {
    // Only what splat4d reads back leaves (a NaN would be written as `null`).
    scene
        .validate("<scene to write>")
        .map_err(|e| Error::Numeric(format!("{}: not written: {e}", path.display())))?;
    if is_ply(path) {
        return super::ply::write_scene_ply(scene, path);
    }
    write_bytes_atomically(path, scene_to_json(scene).as_bytes())
}

fn is_ply(path: &Path) -> bool {
    path.extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("ply"))
}
