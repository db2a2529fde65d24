//! `toy`, `import-gltf` and `export-ply`: scenes made, imported and exported.

use std::fmt;
use std::path::{Path, PathBuf};

use crate::io::check_output;
use crate::io::gltf::Spacing;
use crate::io::gltf::import_scene;
use crate::io::ply::write_slice_ply;
use crate::io::scene_file::{load_scene, save_scene};
use crate::io::shards::{Shard, Sharding};
use crate::model::{Blend, Error, Result, Scene, check_non_negative_setting};
use crate::scenes::motion::three_blobs_scene;
use crate::scenes::toy::{blob_scene, points_scene};

/// Which toy scene (SPEC §7).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ToyKind {
    /// 30 frames × 1000 noisy points along (0,0,0) → (1,1,1), one small kernel each.
    Points,
    /// The single velocity kernel behind the points.
    Blob,
    /// Three blobs of non-linear motion ([`crate::scenes::motion`]).
    ThreeBlobs,
}

/// What a scene-writing task wrote: the file and its kernel count, and a detail.
#[derive(Clone, Debug, PartialEq)]
pub struct SceneSummary {
    out: PathBuf,
    line: String,
    /// Warnings for the user (stderr), such as what a viewer cannot show.
    pub warnings: Vec<String>,
}

impl fmt::Display for SceneSummary {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}: {}", self.out.display(), self.line)
    }
}

/// Writes the seed paper's toy scene (`seed` draws the points; `None`:
/// [`crate::scenes::toy::DEFAULT_SEED`]). A seed for a scene without randomness (the blob,
/// the three blobs) is refused.
pub fn write_toy(kind: ToyKind, seed: Option<u64>, out: &Path) -> Result<SceneSummary> {
    let scene = match (kind, seed) {
        (ToyKind::Points, _) => points_scene(seed.unwrap_or(crate::scenes::toy::DEFAULT_SEED)),
        (ToyKind::Blob | ToyKind::ThreeBlobs, Some(_)) => {
            return Err(Error::setting(
                &["seed"],
                format!(
                    "`seed` draws the points scene's noise, and the {} scene has none: leave `seed` out",
                    if kind == ToyKind::Blob {
                        "blob"
                    } else {
                        "three-blobs"
                    }
                ),
            ));
        }
        (ToyKind::Blob, None) => blob_scene(),
        (ToyKind::ThreeBlobs, None) => three_blobs_scene(),
    };
    save_scene(&scene, out)?;
    Ok(SceneSummary {
        out: out.to_path_buf(),
        line: format!("{} kernels", scene.len()),
        warnings: Vec::new(),
    })
}

/// `splat4d import-gltf`.
#[derive(Clone, Debug, PartialEq)]
pub struct ImportRequest {
    /// The model (`.gltf` or `.glb`).
    pub model: PathBuf,
    /// Surface points to sample.
    pub kernels: usize,
    /// Time samples: `None` for `auto` (key times and adaptive ones until every point follows
    /// its path within `tolerance`), or at most this many evenly ([`Spacing`]).
    pub times: Option<usize>,
    /// The largest path error of `auto` times, relative to the model's size (`None`:
    /// [`DEFAULT_TOLERANCE`]); refused with a count of times, which it cannot refine.
    pub tolerance: Option<f64>,
    /// Output scene (`.json` or `.ply`).
    pub out: PathBuf,
    /// Seed of the surface samples.
    pub seed: u64,
    /// `alpha`: opaque surfaces that hide what is behind them (SPEC §8); `additive`:
    /// glowing surfels whose intensities add.
    pub blend: Blend,
}

/// The largest path error of `import-gltf`'s `auto` times, relative to the model's size.
pub const DEFAULT_TOLERANCE: f64 = 1e-3;

impl ImportRequest {
    /// How the animation's time is sampled, or an error naming `tolerance` given with a count.
    fn spacing(&self) -> Result<Spacing> {
        match (self.times, self.tolerance) {
            (Some(n), Some(_)) => Err(Error::setting(
                &["tolerance"],
                format!(
                    "`tolerance` bounds the path error of `times` auto, and `times` is {n}, evenly spaced: leave `tolerance` out"
                ),
            )),
            (Some(n), None) => Ok(Spacing::Even(n)),
            (None, tolerance) => Ok(Spacing::Adaptive {
                tolerance: tolerance.unwrap_or(DEFAULT_TOLERANCE),
            }),
        }
    }
}

/// Samples a glTF model and its node animation into 4D kernels.
pub fn import_gltf(request: &ImportRequest) -> Result<SceneSummary> {
    let spacing = request.spacing()?;
    // The model and the buffer files it names are inputs the output may not replace.
    let mut inputs = vec![request.model.clone()];
    inputs.extend(buffer_files(&request.model));
    let inputs: Vec<&Path> = inputs.iter().map(PathBuf::as_path).collect();
    check_output(&request.out, &["json", "ply"], &inputs)?;
    let imported = import_scene(&request.model, request.kernels, spacing, request.seed)?;
    let imported = match request.blend {
        Blend::Additive => imported,
        Blend::Alpha => imported.into_alpha(&request.model.display().to_string())?,
    };
    save_scene(&imported.scene, &request.out)?;
    let [t0, t1] = imported.time_range;
    let mut line = format!(
        "{} kernels ({} surface points × {} times over [{t0}, {t1}])",
        imported.scene.len(),
        imported.points,
        imported.times
    );
    if t1 > t0 {
        line.push_str(&format!(
            "; path error at most {:.2e} of the model's size, temporal weights sum to 1 ± {:.1e}, {} steps",
            imported.max_error, imported.weight_error, imported.steps
        ));
    }
    let mut warnings = Vec::new();
    if let Spacing::Adaptive { tolerance } = spacing
        && imported.max_error > tolerance
    {
        warnings.push(format!(
            "the path error {:.2e} is above the tolerance {tolerance:e}: the refinement reached its limits",
            imported.max_error
        ));
    }
    Ok(SceneSummary {
        out: request.out.clone(),
        line,
        warnings,
    })
}

/// The external buffer files a `.gltf` model names (as far as its JSON can be read; the
/// importer reports what cannot), beside the model.
fn buffer_files(model: &Path) -> Vec<PathBuf> {
    let Ok(text) = crate::io::input::read_to_string(model, "cannot read") else {
        return Vec::new();
    };
    let Ok(document) = serde_json::from_str::<serde_json::Value>(&text) else {
        return Vec::new();
    };
    let dir = crate::io::folder_of(model);
    document
        .get("buffers")
        .and_then(|b| b.as_array())
        .into_iter()
        .flatten()
        .filter_map(|buffer| buffer.get("uri").and_then(|u| u.as_str()))
        .filter(|uri| !uri.starts_with("data:"))
        .map(|uri| dir.join(uri))
        .collect()
}

/// `splat4d export-ply`.
#[derive(Clone, Debug, PartialEq)]
pub struct ExportRequest {
    /// Scene file.
    pub scene: PathBuf,
    /// Which slices: one time (a `.ply` out), or a sequence (a folder out).
    pub times: ExportTimes,
    /// Output `.ply`, or the sequence's folder.
    pub out: PathBuf,
    /// Kernels whose value at τ stays below this cut-off are left out.
    pub cutoff: f64,
    /// Add 45 zero `f_rest_*` properties.
    pub sh_rest: bool,
    /// A sequence's every slice, one shard of them, or its index from the shards' slices
    /// ([`crate::io::shards`]).
    pub sharding: Sharding,
}

/// The times `export-ply` slices at.
#[derive(Clone, Debug, PartialEq)]
pub enum ExportTimes {
    /// One slice, written to a `.ply` file.
    One(f64),
    /// A sequence at these times, written to a folder.
    List(Vec<f64>),
    /// A sequence of this many times evenly over the scene's time range
    /// ([`crate::scenes::paths::time_range`]), ends included.
    Frames(usize),
}

/// Most slices one sequence may hold (a bound checked before any work).
pub const MAX_EXPORT_FRAMES: usize = 10_000;

/// Writes the 3D Gaussian Splatting PLY of a scene's slice at one time, or a sequence of them
/// with an index ([`crate::io::ply::write_slice_sequence`]).
pub fn export_ply(request: &ExportRequest) -> Result<SceneSummary> {
    check_export_settings(request)?;
    if let ExportTimes::One(tau) = request.times {
        check_output(&request.out, &["ply"], &[&request.scene])?;
        let scene = load_scene(&request.scene)?;
        check_sh_rest(request, &scene)?;
        let n = write_slice_ply(&scene, tau, request.cutoff, request.sh_rest, &request.out)?;
        return Ok(SceneSummary {
            out: request.out.clone(),
            line: format!("{n} splats of {} kernels at t = {tau}", scene.len()),
            warnings: viewer_warnings(&scene),
        });
    }
    if crate::io::same_file(&request.out, &request.scene) {
        return Err(Error::setting(
            &["out"],
            format!(
                "{}: `out` names the scene; a sequence goes to a folder",
                request.out.display()
            ),
        ));
    }
    // Before any work: the folder holds no input and may be replaced.
    let mut outputs = crate::io::output::Outputs::new();
    outputs.input(&request.scene).folder(&request.out);
    outputs.check()?;
    if request.sharding == Sharding::Whole {
        crate::io::output::check_replaceable(&request.out, "export-ply")?;
    } else {
        crate::io::shards::check_shared_folder(&request.out, "export-ply")?;
    }
    let scene = load_scene(&request.scene)?;
    check_sh_rest(request, &scene)?;
    let times = match &request.times {
        ExportTimes::List(times) => times.clone(),
        ExportTimes::Frames(n) => {
            crate::scenes::paths::even_times(crate::scenes::paths::time_range(&scene), *n)
        }
        ExportTimes::One(_) => unreachable!("handled above"),
    };
    match request.sharding {
        Sharding::Whole => {}
        Sharding::Shard(shard) => return export_shard(request, &scene, &times, shard),
        Sharding::Assemble => return assemble_sequence(request, &scene, &times),
    }
    let counts = crate::io::ply::write_slice_sequence(
        &scene,
        &times,
        request.cutoff,
        request.sh_rest,
        &request.out,
    )?;
    let (fewest, most) = counts
        .iter()
        .fold((usize::MAX, 0), |(lo, hi), &n| (lo.min(n), hi.max(n)));
    Ok(SceneSummary {
        out: request.out.clone(),
        line: format!(
            "{} slices (t = {} … {}) of {} kernels, {fewest}–{most} splats each, indexed in {}",
            times.len(),
            times[0],
            times[times.len() - 1],
            scene.len(),
            crate::io::ply::SEQUENCE_INDEX
        ),
        warnings: viewer_warnings(&scene),
    })
}

/// Refuses, before any work, settings `export-ply` cannot act on: a negative cut-off, a
/// time that is not finite, a sequence of no or too many times, and sharding of one slice.
fn check_export_settings(request: &ExportRequest) -> Result<()> {
    check_non_negative_setting("cutoff", request.cutoff)?;
    match &request.times {
        ExportTimes::One(tau) if !tau.is_finite() => {
            return Err(Error::setting(&["time"], "`time` must be finite"));
        }
        ExportTimes::List(times) if times.is_empty() || times.len() > MAX_EXPORT_FRAMES => {
            return Err(Error::setting(
                &["times"],
                format!("`times` needs 1 to {MAX_EXPORT_FRAMES} times"),
            ));
        }
        ExportTimes::List(times) if !times.iter().all(|t| t.is_finite()) => {
            return Err(Error::setting(&["times"], "`times` must be finite"));
        }
        ExportTimes::Frames(n) if !(1..=MAX_EXPORT_FRAMES).contains(n) => {
            return Err(Error::setting(
                &["frames"],
                format!("`frames` {n} must be from 1 to {MAX_EXPORT_FRAMES}"),
            ));
        }
        _ => {}
    }
    if let ExportTimes::One(_) = request.times
        && request.sharding != Sharding::Whole
    {
        let field = if request.sharding == Sharding::Assemble {
            "assemble"
        } else {
            "shard"
        };
        return Err(Error::setting(
            &[field],
            format!(
                "`{field}` shares a sequence's slices (`times` or `frames`) among runs, and one slice at `time` is one file: leave `{field}` out"
            ),
        ));
    }
    Ok(())
}

/// What a sequence's slices depend on: the scene file's bytes, the times, the cut-off and
/// `sh_rest` ([`crate::io::shards::fingerprint`]).
fn sequence_fingerprint(request: &ExportRequest, times: &[f64]) -> Result<String> {
    let scene =
        std::fs::read(&request.scene).map_err(|e| Error::read(&request.scene, "cannot read", e))?;
    let settings = format!("{times:?} {:?} {}", request.cutoff, request.sh_rest);
    Ok(crate::io::shards::fingerprint(&[
        &scene,
        settings.as_bytes(),
    ]))
}

/// Shard `shard`'s slices of the sequence, moved into its folder beside the other shards'.
fn export_shard(
    request: &ExportRequest,
    scene: &Scene,
    times: &[f64],
    shard: Shard,
) -> Result<SceneSummary> {
    let fingerprint = sequence_fingerprint(request, times)?;
    let staging = crate::io::output::Staging::new(&request.out)?;
    let mut names = Vec::new();
    for (k, &tau) in times.iter().enumerate().filter(|&(k, _)| shard.takes(k)) {
        let file = crate::io::ply::slice_file(k);
        write_slice_ply(
            scene,
            tau,
            request.cutoff,
            request.sh_rest,
            &staging.path().join(&file),
        )?;
        names.push(file);
    }
    crate::io::shards::commit_shard(
        staging.path(),
        &request.out,
        "export-ply",
        shard,
        &fingerprint,
        &names,
    )?;
    Ok(SceneSummary {
        out: request.out.clone(),
        line: format!(
            "{} of {} slices (shard {}/{}); `assemble` writes the index once every shard is done",
            names.len(),
            times.len(),
            shard.index,
            shard.count
        ),
        warnings: viewer_warnings(scene),
    })
}

/// The sequence's index from the slices its shards wrote, and the folder's marker: the
/// files of one run.
fn assemble_sequence(
    request: &ExportRequest,
    scene: &Scene,
    times: &[f64],
) -> Result<SceneSummary> {
    let fingerprint = sequence_fingerprint(request, times)?;
    let names: Vec<String> = (0..times.len()).map(crate::io::ply::slice_file).collect();
    let out = &request.out;
    crate::io::shards::check_assembled(out, "export-ply", &fingerprint, &names)?;
    crate::io::shards::keep_only(out, &names)?;
    crate::io::ply::write_sequence_index(out, &names, times)?;
    crate::io::shards::drop_shard_markers(out)?;
    crate::io::output::write_marker(out, "export-ply", &[])?;
    Ok(SceneSummary {
        out: out.clone(),
        line: format!(
            "{} slices (t = {} … {}) assembled, indexed in {}",
            times.len(),
            times[0],
            times[times.len() - 1],
            crate::io::ply::SEQUENCE_INDEX
        ),
        warnings: viewer_warnings(scene),
    })
}

/// SH triplets of degree 3, the most a 3DGS PLY holds and what `sh_rest` pads to.
const DEGREE_3_TRIPLETS: usize = 15;

/// `sh_rest` pads `f_rest_*` to degree 3: refused for a scene whose SH is degree 3 already.
fn check_sh_rest(request: &ExportRequest, scene: &Scene) -> Result<()> {
    if request.sh_rest && scene.sh_count >= DEGREE_3_TRIPLETS {
        return Err(Error::setting(
            &["sh_rest"],
            format!(
                "{}: `sh_rest` pads the `f_rest_*` properties to degree 3, and this scene's SH is degree 3 already: leave `sh_rest` out",
                request.scene.display()
            ),
        ));
    }
    Ok(())
}

/// What an alpha-compositing splat viewer cannot show of `scene`: negative amplitudes (a
/// viewer's colours and opacities are ≥ 0, so those kernels come out clamped) and a
/// background other than black (a viewer draws its own).
#[must_use]
pub fn viewer_warnings(scene: &Scene) -> Vec<String> {
    let mut warnings = Vec::new();
    let negative = scene
        .amplitudes
        .iter()
        .filter(|a| a.iter().any(|&v| v < 0.0))
        .count();
    if negative > 0 {
        warnings.push(format!(
            "{negative} of {} kernels have negative amplitudes, which splat viewers cannot show (their colour is negative and viewers clamp it to black)",
            scene.len()
        ));
    }
    if scene.background != [0.0; 3] {
        let [r, g, b] = scene.background;
        warnings.push(format!(
            "the scene's background ({r}, {g}, {b}) is not written: set it as the viewer's background colour"
        ));
    }
    warnings
}
