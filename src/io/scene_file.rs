//! Scene files: JSON, and 4D scene PLY ([`super::ply`]) for paths ending in `.ply`.
//!
//! JSON layout (keys in this order, `rotation`, `velocity`, `background` and `up` optional):
//! `{"kernels":[{"mean":[x,y,z,t],"scale":[sx,sy,sz,st],"amplitude":[r,g,b],
//! "rotation":[w,x,y,z],"velocity":[vx,vy,vz]}],"background":[r,g,b],"up":"z"}` (SPEC §1;
//! `up` is the world's up axis, `x`, `y`, `z`, `-x`, `-y` or `-z`, written only when known:
//! videos turn about it). Unknown
//! keys are errors, so that a typo never silently falls back to a default. Numbers are
//! written so that they read back exactly (serde_json's `float_roundtrip`).

use std::path::Path;

use serde::{Deserialize, Serialize};

use crate::io::json::parse_json;
use crate::io::write_bytes_atomically;
use crate::model::{Error, Kernel, Result, Scene, Up};

#[derive(Serialize, Deserialize)]
#[serde(
    deny_unknown_fields,
    expecting = "a scene object {\"kernels\": [...], \"background\": [r, g, b]}"
)]
struct SceneFile {
    kernels: Vec<Kernel>,
    #[serde(default)]
    background: [f64; 3],
    #[serde(default, skip_serializing_if = "Option::is_none")]
    up: Option<Up>,
}

/// Parses and validates a scene JSON document. `origin` names it in error messages.
pub fn scene_from_json(text: &str, origin: &str) -> Result<Scene> {
    let file: SceneFile = parse_json(text, origin, "scene")?;
    let mut scene = Scene::from_kernels(&file.kernels, file.background, origin)?;
    scene.up = file.up;
    Ok(scene)
}

/// The scene as a JSON document (the format of [`scene_from_json`]).
#[must_use]
pub fn scene_to_json(scene: &Scene) -> String {
    let file = SceneFile {
        kernels: scene.kernels(),
        background: scene.background,
        up: scene.up,
    };
    serde_json::to_string_pretty(&file).expect("a scene of finite numbers serialises")
}

/// Reads a scene file: 4D scene PLY for `.ply`, JSON otherwise.
pub fn load_scene(path: &Path) -> Result<Scene> {
    if is_ply(path) {
        return super::ply::read_scene_ply(path);
    }
    let text =
        std::fs::read_to_string(path).map_err(|e| Error::read(path, "cannot read scene", e))?;
    scene_from_json(&text, &path.display().to_string())
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
