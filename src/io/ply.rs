//! PLY files: 3D Gaussian Splatting time slices, and whole 4D scenes.
//!
//! **3DGS slice** ([`write_slice_ply`]), the layout common splat viewers read: binary little
//! endian, `element vertex N` with float properties
//! `x y z nx ny nz f_dc_0 f_dc_1 f_dc_2 opacity scale_0 scale_1 scale_2 rot_0 rot_1 rot_2 rot_3`:
//! the slice at τ (SPEC §2, §9) of every kernel alive under the cut-off, positions `m(τ)`,
//! `scale_i = ln σ_i`, `rot` the unit quaternion `q(τ)` (w first), normals zero. 3DGS composites
//! colour with opacity while splat4d adds amplitudes, so the mapping is approximate: with
//! `p = max_c |a_c(τ)|`, opacity `α = clamp(p, 0.01, 0.99)` stored as `logit(α)`, colour
//! `c = a(τ)/α` stored as the SH DC term `f_dc = (c - ½)/C0`, `C0 = 0.28209479177387814`. For
//! sparse kernels with `|a| ≤ 1` this reproduces `α c = a`. Alpha scenes (SPEC §8) map
//! exactly: `f_dc = (A - ½)/C0`, `f_rest` the SH channel by channel, opacity the logit of
//! `o(τ)`; a 3DGS rasterizer draws them as splat4d does, up to its own 3σ cut.
//!
//! **3DGS files read** ([`read_scene_ply`]): a graphdeco PLY (`x y z f_dc_* [f_rest_*]
//! opacity scale_* rot_*`, from gsplat, nerfstudio, brush or the Inria code) is an alpha scene
//! of static kernels: `t = 0`, `st = 1e30`, `o = sigmoid(opacity)`, `σ = exp(scale)`,
//! amplitude `C0 f_dc + ½`, SH from `f_rest`.
//!
//! **4D scene** ([`write_scene_ply`], [`read_scene_ply`]): binary little endian, `element
//! vertex N` with double properties `x y z t sigma_x sigma_y sigma_z sigma_t amp_0 amp_1 amp_2
//! rot_0 rot_1 rot_2 rot_3 vx vy vz` (σ linear, rotation w first), then for scenes with SPEC
//! §9 fields `ax ay az` and `omega_0 omega_1 omega_2 omega_3` (each only when the scene has
//! it; a turning kernel's quaternion as stored), the background as
//! `comment background r g b`, the up axis when known as `comment up z`. Exact: every f64 round-trips. 144 bytes a kernel, against about
//! 600 in JSON. Float properties are accepted too; other properties are ignored.
//!
//! Both are read through the shared header reader ([`super::ply_header`]); a scene PLY is
//! binary little endian 1.0 with one `vertex` element of scalar properties.

use std::io::Write;
use std::path::Path;

use crate::io::ply_header::{Encoding, Header, MAX_HEADER, read_header};
use crate::io::write_atomically;
use crate::model::Up;
use crate::model::error::{Error, Result};
use crate::model::scene::{Blend, Kernel, Scene};
use crate::parallel::extend_scene;
use crate::slice::{SlicedKernels, slice, turned_quaternion};

/// The zeroth-order spherical-harmonic constant of 3DGS.
pub const SH_C0: f64 = 0.282_094_791_773_878_14;

/// Properties of a 3DGS slice, in order.
pub const SLICE_PROPERTIES: [&str; 17] = [
    "x", "y", "z", "nx", "ny", "nz", "f_dc_0", "f_dc_1", "f_dc_2", "opacity", "scale_0", "scale_1",
    "scale_2", "rot_0", "rot_1", "rot_2", "rot_3",
];

/// Properties of a 4D scene, in order.
pub const SCENE_PROPERTIES: [&str; 18] = [
    "x", "y", "z", "t", "sigma_x", "sigma_y", "sigma_z", "sigma_t", "amp_0", "amp_1", "amp_2",
    "rot_0", "rot_1", "rot_2", "rot_3", "vx", "vy", "vz",
];

/// Optional properties of a 4D scene whose kernels accelerate (SPEC §9).
pub const ACCELERATION_PROPERTIES: [&str; 3] = ["ax", "ay", "az"];

/// Optional properties of a 4D scene whose kernels turn (SPEC §9), `ω` w first.
pub const ANGULAR_VELOCITY_PROPERTIES: [&str; 4] = ["omega_0", "omega_1", "omega_2", "omega_3"];

fn header(count: usize, kind: &str, properties: &[&str], comments: &[String]) -> String {
    let mut h = String::from("ply\nformat binary_little_endian 1.0\ncomment written by splat4d\n");
    for c in comments {
        h.push_str(&format!("comment {c}\n"));
    }
    h.push_str(&format!("element vertex {count}\n"));
    for p in properties {
        h.push_str(&format!("property {kind} {p}\n"));
    }
    h.push_str("end_header\n");
    h
}

/// The 3DGS parameters of one sliced kernel: opacity logit, SH DC colour.
#[must_use]
pub fn splat_colour(amplitude: [f64; 3]) -> (f64, [f64; 3]) {
    let peak = amplitude.iter().fold(0.0_f64, |m, a| m.max(a.abs()));
    let alpha = peak.clamp(0.01, 0.99);
    let logit = (alpha / (1.0 - alpha)).ln();
    (logit, amplitude.map(|a| (a / alpha - 0.5) / SH_C0))
}

/// The 3DGS record of an alpha kernel (SPEC §8): the opacity logit of `o(τ)` (clamped to
/// `[1e-6, 1 - 1e-6]`), `f_dc` from the amplitude.
#[must_use]
pub fn alpha_splat_colour(amplitude: [f64; 3], opacity: f64) -> (f64, [f64; 3]) {
    let o = opacity.clamp(1e-6, 1.0 - 1e-6);
    ((o / (1.0 - o)).ln(), amplitude.map(|a| (a - 0.5) / SH_C0))
}

/// Writes the 3DGS slice of `scene` at `tau` (kernels alive under `cutoff`). Additive
/// scenes map as the module doc says; alpha scenes exactly (SPEC §8: `f_dc`, `f_rest` from the
/// amplitude and SH, the logit of `o(τ)`), with their SH as `f_rest_*` (stored channel by
/// channel). With `sh_rest`, `f_rest_*` are padded with zeros to degree 3 (45, as the
/// reference 3DGS loader expects). Returns the number of splats.
pub fn write_slice_ply(
    scene: &Scene,
    tau: f64,
    cutoff: f64,
    sh_rest: bool,
    path: &Path,
) -> Result<usize> {
    let mut sliced = SlicedKernels::default();
    slice(scene, tau, cutoff, &mut sliced);
    let n = sliced.len();
    let alpha = scene.blend == Blend::Alpha;
    let triplets = if sh_rest { 15 } else { scene.sh_count };
    let rest: Vec<String> = (0..3 * triplets).map(|k| format!("f_rest_{k}")).collect();
    let mut names: Vec<&str> = SLICE_PROPERTIES[..9].to_vec();
    names.extend(rest.iter().map(String::as_str));
    names.extend(&SLICE_PROPERTIES[9..]);
    let values_of = |s: usize| -> Vec<f64> {
        let i = sliced.kernel_from_slice[s] as usize;
        let [m0, m1, m2] = sliced.means[s];
        let (opacity, dc) = if alpha {
            alpha_splat_colour(sliced.amplitudes[s], sliced.opacities[s])
        } else {
            splat_colour(sliced.amplitudes[s])
        };
        // f_rest_{c·triplets + j} = sh_j,c, zero past the scene's own SH.
        let sh = scene.sh_of(i);
        let f_rest = (0..3 * triplets).map(|k| {
            let (c, j) = (k / triplets, k % triplets);
            sh.get(j).map_or(0.0, |t| t[c])
        });
        let [sx, sy, sz, _] = scene.scales[i];
        // SPEC §9: the axes at τ, `q(τ)` (a sliced kernel's is finite and nonzero).
        let omega = scene.angular_velocity(i);
        let q = if omega == [0.0; 4] {
            scene.rotations[i]
        } else {
            turned_quaternion(scene.rotations[i], omega, tau - scene.means[i][3])
                .expect("a sliced kernel's q(τ) is finite")
        };
        [m0, m1, m2, 0.0, 0.0, 0.0, dc[0], dc[1], dc[2]]
            .into_iter()
            .chain(f_rest)
            .chain([opacity, sx.ln(), sy.ln(), sz.ln(), q[0], q[1], q[2], q[3]])
            .collect()
    };
    // A float PLY holds what f32 holds: a kernel at x = 1e300 is refused, not written as inf.
    for s in 0..n {
        let values = values_of(s);
        if let Some(k) = values.iter().position(|&v| !(v as f32).is_finite()) {
            return Err(Error::Numeric(format!(
                "{}: not written: kernel {}'s `{}` at t = {tau} is {:e}, beyond what a float PLY holds",
                path.display(),
                sliced.kernel_from_slice[s],
                names[k],
                values[k]
            )));
        }
    }
    write_atomically(path, |w| {
        w.write_all(
            header(
                n,
                "float",
                &names,
                &[format!("slice of a 4D scene at t = {tau}")],
            )
            .as_bytes(),
        )?;
        for s in 0..n {
            for v in values_of(s) {
                w.write_all(&(v as f32).to_le_bytes())?;
            }
        }
        Ok(())
    })?;
    Ok(n)
}

/// The header comments of a 4D scene PLY: the background, and the up axis when known.
fn scene_comments(scene: &Scene) -> Vec<String> {
    let [r, g, b] = scene.background;
    let mut comments = vec![format!("background {r:?} {g:?} {b:?}")];
    if scene.blend == Blend::Alpha {
        comments.push("blend alpha".to_owned());
    }
    if let Some([t0, t1]) = scene.time_range {
        comments.push(format!("time_range {t0:?} {t1:?}"));
    }
    if let Some(([x, y, z], r)) = scene.framing {
        comments.push(format!("framing {x:?} {y:?} {z:?} {r:?}"));
    }
    if let Some(up) = scene.up {
        comments.push(format!("up {up}"));
    }
    comments
}

/// Name of the index file of a slice sequence ([`write_slice_sequence`]).
pub const SEQUENCE_INDEX: &str = "frames.json";

/// Writes one 3DGS slice PLY per time into folder `dir` (`frame_0000.ply`, …, as
/// [`write_slice_ply`]) and an index `frames.json`,
/// `{"frames": [{"file": "frame_0000.ply", "time": t0}, ...]}`, that sequence players read.
/// The sequence is written into a temporary folder beside `dir` and renamed into place, so a
/// failed run leaves no partial sequence; an existing `dir` is replaced only when it is empty
/// or an earlier `export-ply` sequence ([`super::output`]). Returns the splat count of each
/// frame.
pub fn write_slice_sequence(
    scene: &Scene,
    times: &[f64],
    cutoff: f64,
    sh_rest: bool,
    dir: &Path,
) -> Result<Vec<usize>> {
    let folder = super::output::FolderWriter::new(dir, "export-ply")?;
    let mut counts = Vec::with_capacity(times.len());
    let mut index = Vec::with_capacity(times.len());
    for (k, &tau) in times.iter().enumerate() {
        let file = slice_file(k);
        counts.push(write_slice_ply(
            scene,
            tau,
            cutoff,
            sh_rest,
            &folder.path().join(&file),
        )?);
        index.push(file);
    }
    write_sequence_index(folder.path(), &index, times)?;
    folder.commit()?;
    Ok(counts)
}

/// The file name of slice `k` of a sequence.
#[must_use]
pub fn slice_file(k: usize) -> String {
    format!("frame_{k:04}.ply")
}

/// Writes the index [`SEQUENCE_INDEX`] of the slices `files` at `times` into `dir`.
pub fn write_sequence_index(dir: &Path, files: &[String], times: &[f64]) -> Result<()> {
    let index: Vec<_> = files
        .iter()
        .zip(times)
        .map(|(file, tau)| serde_json::json!({"file": file, "time": tau}))
        .collect();
    let text = serde_json::to_string_pretty(&serde_json::json!({ "frames": index }))
        .expect("an index of finite times serialises");
    super::write_bytes_atomically(&dir.join(SEQUENCE_INDEX), text.as_bytes())
}

/// Writes `scene` as a 4D scene PLY (alpha scenes with `comment blend alpha`, `opacity`
/// and `sh_0 …`).
pub fn write_scene_ply(scene: &Scene, path: &Path) -> Result<()> {
    let alpha = scene.blend == Blend::Alpha;
    let sh_names: Vec<String> = (0..3 * scene.sh_count).map(|k| format!("sh_{k}")).collect();
    let mut names: Vec<&str> = SCENE_PROPERTIES.to_vec();
    if alpha {
        names.push("opacity");
        names.extend(sh_names.iter().map(String::as_str));
    }
    let (accelerating, turning) = (
        !scene.accelerations.is_empty(),
        !scene.angular_velocities.is_empty(),
    );
    if accelerating {
        names.extend(ACCELERATION_PROPERTIES);
    }
    if turning {
        names.extend(ANGULAR_VELOCITY_PROPERTIES);
    }
    write_atomically(path, |w| {
        w.write_all(header(scene.len(), "double", &names, &scene_comments(scene)).as_bytes())?;
        for i in 0..scene.len() {
            let (m, s, a, q, v) = (
                scene.means[i],
                scene.scales[i],
                scene.amplitudes[i],
                scene.rotations[i],
                scene.velocities[i],
            );
            let values = [
                m[0], m[1], m[2], m[3], s[0], s[1], s[2], s[3], a[0], a[1], a[2], q[0], q[1], q[2],
                q[3], v[0], v[1], v[2],
            ];
            for value in values {
                w.write_all(&value.to_le_bytes())?;
            }
            if alpha {
                w.write_all(&scene.opacity(i).to_le_bytes())?;
                for value in scene.sh_of(i).iter().flatten() {
                    w.write_all(&value.to_le_bytes())?;
                }
            }
            if accelerating {
                for value in scene.accelerations[i] {
                    w.write_all(&value.to_le_bytes())?;
                }
            }
            if turning {
                for value in scene.angular_velocities[i] {
                    w.write_all(&value.to_le_bytes())?;
                }
            }
        }
        Ok(())
    })
}

/// Reads a 4D scene PLY, or a graphdeco 3DGS PLY as an alpha scene of static kernels (SPEC
/// §8). Every problem is an error naming the file (and the vertex and field for bad values);
/// nothing is allocated before the header's counts are checked against the file's length.
/// The rows are read a block at a time into one buffer and decoded in parallel straight into
/// the scene's arrays.
pub fn read_scene_ply(path: &Path) -> Result<Scene> {
    read_scene_ply_as_stored(path, false).map(|(scene, _)| scene)
}

/// [`read_scene_ply`], and with `rotation_norms` the norm of each kernel's quaternion as the
/// file stores it (the scene holds it normalised): what the gradient of the stored
/// quaternion needs ([`crate::backward::Gradients::rotations_as_stored`]).
pub fn read_scene_ply_as_stored(
    path: &Path,
    rotation_norms: bool,
) -> Result<(Scene, Option<Vec<f64>>)> {
    use std::io::Read;
    let origin = path.display().to_string();
    let cannot = |e| Error::read(path, "cannot read scene", e);
    let mut file = crate::io::input::open(path, "cannot read scene")?;
    let length = file.metadata().map_err(cannot)?.len();
    let mut start = Vec::with_capacity(MAX_HEADER);
    (&mut file)
        .take(MAX_HEADER as u64)
        .read_to_end(&mut start)
        .map_err(cannot)?;
    let layout = parse_header(&start, &origin)?;
    layout.check_body_length(length.saturating_sub(layout.body_start as u64), &origin)?;
    let mut scene = layout.empty_scene(&origin)?;
    let mut appearance = Appearance {
        rotation_norms: rotation_norms.then(Vec::new),
        ..Appearance::default()
    };
    // The rows already read, then the rest a block at a time: while one block is decoded
    // (in parallel), the next is read, so that the copy out of the file overlaps the
    // decoding on another thread (one after the other on one thread).
    let mut pending = start.split_off(layout.body_start.min(start.len()));
    let block_rows = (BLOCK_BYTES / layout.stride.max(1)).clamp(1, layout.count.max(1));
    // `rows` rows into `block`, emptied first: room for exactly them, read into without
    // being cleared (`read_to_end` fills the spare capacity), so that its pages are first
    // touched by the copy from the file. No rows: an empty block, and nothing read.
    let mut read_rows = |block: &mut Vec<u8>, rows: usize| -> Result<()> {
        let want = rows * layout.stride;
        block.clear();
        block.reserve(want);
        let carried = pending.len().min(want);
        block.extend_from_slice(&pending[..carried]);
        pending.drain(..carried);
        (&mut file)
            .take((want - carried) as u64)
            .read_to_end(block)
            .map_err(cannot)?;
        if block.len() < want {
            return Err(cannot(std::io::ErrorKind::UnexpectedEof.into()));
        }
        Ok(())
    };
    let (mut block, mut next) = (Vec::new(), Vec::new());
    let mut rows_read = layout.count.min(block_rows);
    read_rows(&mut block, rows_read)?;
    while !block.is_empty() {
        let rows_next = (layout.count - rows_read).min(block_rows);
        let (read, decoded) = rayon::join(
            || read_rows(&mut next, rows_next),
            || layout.decode_into(&mut scene, &mut appearance, &block, &origin),
        );
        decoded?;
        read?;
        rows_read += rows_next;
        std::mem::swap(&mut block, &mut next);
    }
    let norms = appearance.rotation_norms.take();
    Ok((layout.finish(scene, appearance, &origin)?, norms))
}

/// Bytes of rows read at a time: large enough to amortise a parallel pass, small enough
/// that the block being decoded and the one being read stay in cache together.
const BLOCK_BYTES: usize = 1 << 18;

/// [`read_scene_ply`] on bytes in memory.
pub fn parse_scene_ply(bytes: &[u8], origin: &str) -> Result<Scene> {
    let layout = parse_header(bytes, origin)?;
    let body = &bytes[layout.body_start..];
    layout.check_body_length(body.len() as u64, origin)?;
    let mut scene = layout.empty_scene(origin)?;
    let mut appearance = Appearance::default();
    layout.decode_into(&mut scene, &mut appearance, body, origin)?;
    layout.finish(scene, appearance, origin)
}

/// Properties of a graphdeco 3DGS PLY that [`read_scene_ply`] needs, in order (f_rest_* and
/// normals are optional).
pub const GAUSSIAN_3D_PROPERTIES: [&str; 14] = [
    "x", "y", "z", "f_dc_0", "f_dc_1", "f_dc_2", "opacity", "scale_0", "scale_1", "scale_2",
    "rot_0", "rot_1", "rot_2", "rot_3",
];

/// The time scale of a static kernel read from a 3DGS PLY (SPEC §8: `st ≥ 1e15` is static).
pub const STATIC_TIME_SCALE: f64 = 1e30;

/// Which kind of PLY the header describes.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum PlyKind {
    /// splat4d's 4D scene ([`SCENE_PROPERTIES`], alpha fields when `comment blend alpha`).
    Scene4d,
    /// A graphdeco 3DGS file ([`GAUSSIAN_3D_PROPERTIES`]): static alpha kernels.
    Gaussian3d,
}

/// Opacities and SH triplets decoded so far (alpha scenes).
#[derive(Default)]
struct Appearance {
    opacities: Vec<f64>,
    sh: Vec<[f64; 3]>,
    /// When asked for: the norm of each row's quaternion as stored.
    rotation_norms: Option<Vec<f64>>,
}

/// What a scene PLY's header says: where the rows start, how many, and where each property
/// sits in a row (byte offset and size, 4 or 8).
struct SceneLayout {
    /// The header as read.
    header: Header,
    body_start: usize,
    count: usize,
    stride: usize,
    kind: PlyKind,
    /// The required properties of `kind`, in the order of its list.
    fields: Vec<(usize, usize)>,
    /// 4D alpha scenes: `opacity`.
    opacity: Option<(usize, usize)>,
    /// 4D scenes with SPEC §9 fields: `ax ay az` ([`ACCELERATION_PROPERTIES`]).
    acceleration: Option<Vec<(usize, usize)>>,
    /// 4D scenes with SPEC §9 fields: `omega_0 … omega_3` ([`ANGULAR_VELOCITY_PROPERTIES`]).
    angular_velocity: Option<Vec<(usize, usize)>>,
    /// The SH coefficients, in the file's naming order (`sh_k` or `f_rest_k`).
    sh: Vec<(usize, usize)>,
    blend: Blend,
    background: [f64; 3],
    up: Option<Up>,
    time_range: Option<[f64; 2]>,
    framing: Option<([f64; 3], f64)>,
}

/// The header at the start of `bytes` (which holds at least its first 64 KiB, or the whole
/// file when shorter), read by [`super::ply_header`]: a scene PLY is binary little endian
/// 1.0 with one `vertex` element of scalar properties.
fn parse_header(bytes: &[u8], origin: &str) -> Result<SceneLayout> {
    let header = read_header(bytes, origin)?;
    if (header.encoding, header.version.as_str()) != (Encoding::BinaryLittleEndian, "1.0") {
        return Err(bad_ply(
            origin,
            format!(
                "format `{} {}` is not supported (only `binary_little_endian 1.0`)",
                header.encoding.name(),
                header.version
            ),
        ));
    }
    match header.elements.as_slice() {
        [] => return Err(bad_ply(origin, "no `element vertex` line".into())),
        [vertex] if vertex.name == "vertex" => {}
        elements => {
            let other = elements
                .iter()
                .skip(1)
                .chain(elements)
                .find(|e| e.name != "vertex");
            let name = other.map_or("vertex", |e| e.name.as_str());
            return Err(bad_ply(
                origin,
                format!("element `{name}` is not supported (one `vertex` element only)"),
            ));
        }
    }
    if let Some(list) = header.elements[0]
        .properties
        .iter()
        .find(|p| p.list.is_some())
    {
        return Err(bad_ply(
            origin,
            format!(
                "property `{}` is a list (a scalar type: float, double or an integer)",
                list.name
            ),
        ));
    }
    let comments = SceneComments::read(&header.comments, origin)?;
    header_layout(header, comments, origin)
}

/// What the comments of a scene PLY's header say.
#[derive(Default)]
struct SceneComments {
    background: [f64; 3],
    up: Option<Up>,
    blend: Blend,
    time_range: Option<[f64; 2]>,
    framing: Option<([f64; 3], f64)>,
}

impl SceneComments {
    /// Reads `comments` (the text after `comment`); those it does not know are skipped.
    fn read(comments: &[String], origin: &str) -> Result<Self> {
        let bad = |message: String| bad_ply(origin, message);
        let number = |what: &str, v: &str| {
            v.parse::<f64>()
                .map_err(|_| bad(format!("{what} value `{v}` is not a number")))
        };
        let mut read = SceneComments::default();
        for comment in comments {
            let words: Vec<&str> = comment.split_whitespace().collect();
            match words.as_slice() {
                ["up", axis] => {
                    let up = axis.parse::<Up>();
                    read.up = Some(up.map_err(|e| bad(format!("up axis: {e}")))?);
                }
                ["time_range", t0, t1] => {
                    read.time_range = Some([number("time range", t0)?, number("time range", t1)?]);
                }
                ["framing", x, y, z, r] => {
                    let centre = [x, y, z].map(|v| number("framing", v));
                    let [x, y, z] = centre;
                    read.framing = Some(([x?, y?, z?], number("framing", r)?));
                }
                ["blend", name] => {
                    read.blend = name.parse().map_err(|e| bad(format!("blend: {e}")))?;
                }
                ["background", r, g, b] => {
                    for (slot, v) in read.background.iter_mut().zip([r, g, b]) {
                        *slot = number("background", v)?;
                    }
                }
                _ => {}
            }
        }
        Ok(read)
    }
}

/// The layout of a scene's rows from its header (one `vertex` element of scalars) and what
/// its comments say.
fn header_layout(header: Header, comments: SceneComments, origin: &str) -> Result<SceneLayout> {
    let bad = |message: String| bad_ply(origin, message);
    let SceneComments {
        background,
        up,
        mut blend,
        time_range,
        framing,
    } = comments;
    let vertex = &header.elements[0];
    let (count, properties) = (vertex.count, &vertex.properties);
    let stride: usize = properties.iter().map(|p| p.scalar.size()).sum();
    let find = |name: &str| -> Option<Result<(usize, usize)>> {
        let index = properties.iter().position(|p| p.name == name)?;
        Some(if properties[index].scalar.is_float() {
            Ok((
                properties[..index].iter().map(|p| p.scalar.size()).sum(),
                properties[index].scalar.size(),
            ))
        } else {
            Err(bad(format!(
                "property `{name}` has type `{}`: it must be float or double",
                properties[index].kind
            )))
        })
    };
    let has = |name: &str| properties.iter().any(|p| p.name == name);
    // A file with `t` is splat4d's 4D scene; one with `f_dc_0` and no `t` a 3DGS file.
    let kind = if !has("t") && has("f_dc_0") {
        PlyKind::Gaussian3d
    } else {
        PlyKind::Scene4d
    };
    let required: &[&str] = match kind {
        PlyKind::Scene4d => &SCENE_PROPERTIES,
        PlyKind::Gaussian3d => &GAUSSIAN_3D_PROPERTIES,
    };
    let fields = required
        .iter()
        .map(|name| find(name).unwrap_or_else(|| Err(bad(format!("missing property `{name}`")))))
        .collect::<Result<Vec<_>>>()?;
    let sh_prefix = match kind {
        PlyKind::Scene4d => "sh_",
        PlyKind::Gaussian3d => "f_rest_",
    };
    let mut sh = Vec::new();
    while let Some(field) = find(&format!("{sh_prefix}{}", sh.len())) {
        sh.push(field?);
    }
    let opacity = match kind {
        PlyKind::Scene4d => find("opacity").transpose()?,
        PlyKind::Gaussian3d => None,
    };
    // SPEC §9: all of a field's properties or none.
    let optional = |names: &[&str]| -> Result<Option<Vec<(usize, usize)>>> {
        if kind == PlyKind::Gaussian3d || !names.iter().any(|n| has(n)) {
            return Ok(None);
        }
        names
            .iter()
            .map(|name| {
                find(name).unwrap_or_else(|| Err(bad(format!("missing property `{name}`"))))
            })
            .collect::<Result<Vec<_>>>()
            .map(Some)
    };
    let acceleration = optional(&ACCELERATION_PROPERTIES)?;
    let angular_velocity = optional(&ANGULAR_VELOCITY_PROPERTIES)?;
    if kind == PlyKind::Gaussian3d {
        blend = Blend::Alpha;
    }
    if blend == Blend::Additive && (opacity.is_some() || !sh.is_empty()) {
        return Err(bad(
            "properties `opacity` or `sh_*` without `comment blend alpha`".into(),
        ));
    }
    if !matches!(sh.len(), 0 | 9 | 24 | 45) {
        return Err(bad(format!(
            "{} `{sh_prefix}*` properties: expected 9, 24 or 45 (SH degree 1, 2 or 3) or none",
            sh.len()
        )));
    }
    Ok(SceneLayout {
        body_start: header.body_start,
        header,
        count,
        stride,
        kind,
        fields,
        opacity,
        acceleration,
        angular_velocity,
        sh,
        blend,
        background,
        up,
        time_range,
        framing,
    })
}

/// Reads the value at `(offset, size)` of `row`.
fn value_at(row: &[u8], (o, size): (usize, usize)) -> f64 {
    match size {
        8 => f64::from_le_bytes(row[o..o + 8].try_into().expect("8 bytes")),
        _ => f64::from(f32::from_le_bytes(
            row[o..o + 4].try_into().expect("4 bytes"),
        )),
    }
}

/// `1 / (1 + e^-x)`.
fn sigmoid(x: f64) -> f64 {
    1.0 / (1.0 + (-x).exp())
}

impl SceneLayout {
    /// The rows must fill the rest of the file exactly (before anything is allocated).
    fn check_body_length(&self, body: u64, origin: &str) -> Result<()> {
        let (_, expected) = self.header.binary_rows(0, body, origin)?;
        if body != expected {
            let (count, stride) = (self.count, self.stride);
            return Err(bad_ply(
                origin,
                format!(
                    "{count} vertices of {stride} bytes need {expected} bytes of data, the file has {body}"
                ),
            ));
        }
        Ok(())
    }

    /// A scene with room for the rows.
    fn empty_scene(&self, origin: &str) -> Result<Scene> {
        let mut scene = Scene::from_kernels(&[], self.background, origin)?;
        scene.up = self.up;
        scene.time_range = self.time_range;
        scene.framing = self.framing;
        scene.check_time_range(origin)?;
        // The length check says what the file can hold, not what it holds (a sparse file's
        // hole reads as zeros): the scene must fit in memory, and it grows as rows arrive
        // beyond a first reservation.
        let per_kernel = std::mem::size_of::<[f64; 18]>() as u64;
        super::memory::check(
            (self.count as u64).saturating_mul(per_kernel),
            &format!("{origin}: {} kernels", self.count),
        )?;
        scene.reserve(self.count.min(1 << 20));
        Ok(scene)
    }

    /// The kernel of one row.
    fn kernel(&self, row: &[u8]) -> Kernel {
        let v = |k: usize| value_at(row, self.fields[k]);
        match self.kind {
            PlyKind::Scene4d => Kernel {
                mean: [v(0), v(1), v(2), v(3)],
                scale: [v(4), v(5), v(6), v(7)],
                amplitude: [v(8), v(9), v(10)],
                rotation: [v(11), v(12), v(13), v(14)],
                velocity: [v(15), v(16), v(17)],
                acceleration: self.acceleration.as_ref().map_or([0.0; 3], |fields| {
                    std::array::from_fn(|k| value_at(row, fields[k]))
                }),
                angular_velocity: self.angular_velocity.as_ref().map_or([0.0; 4], |fields| {
                    std::array::from_fn(|k| value_at(row, fields[k]))
                }),
            },
            PlyKind::Gaussian3d => Kernel {
                mean: [v(0), v(1), v(2), 0.0],
                scale: [v(7).exp(), v(8).exp(), v(9).exp(), STATIC_TIME_SCALE],
                amplitude: [3, 4, 5].map(|k| SH_C0 * v(k) + 0.5),
                rotation: [v(10), v(11), v(12), v(13)],
                velocity: [0.0; 3],
                acceleration: [0.0; 3],
                angular_velocity: [0.0; 4],
            },
        }
    }

    /// Error naming the 3DGS file's own property (`scale_0`, `f_dc_0`, `opacity`,
    /// `f_rest_3`, …) unless the row's stored values are finite and its log scales give a
    /// finite, positive `σ = exp(scale)`: checked before the conversion, whose fields
    /// (`scale[0]`, `amplitude`) are not what the file calls them.
    fn check_gaussian_row(&self, row: &[u8], index: usize, origin: &str) -> Result<()> {
        let named = GAUSSIAN_3D_PROPERTIES
            .iter()
            .map(|name| (*name).to_owned())
            .zip(self.fields.iter().copied())
            .chain(
                (0..self.sh.len())
                    .map(|k| format!("f_rest_{k}"))
                    .zip(self.sh.iter().copied()),
            );
        for (name, field) in named {
            let value = value_at(row, field);
            let problem = if !value.is_finite() {
                Some("is not finite".to_owned())
            } else if name.starts_with("scale_") && !(value.exp() > 0.0 && value.exp().is_finite())
            {
                Some(format!(
                    "is a log scale: σ = exp({value}) is {}, outside the numbers a kernel can hold",
                    value.exp()
                ))
            } else {
                None
            };
            if let Some(problem) = problem {
                return Err(Error::invalid(
                    origin,
                    format!("vertex {index}"),
                    &name,
                    format!("{value} {problem}"),
                ));
            }
        }
        Ok(())
    }

    /// Decodes whole rows `bytes` (in parallel) and appends them to `scene` (checked), their
    /// opacities and SH to `appearance`.
    fn decode_into(
        &self,
        scene: &mut Scene,
        appearance: &mut Appearance,
        bytes: &[u8],
        origin: &str,
    ) -> Result<()> {
        let stride = self.stride.max(1);
        let rows = bytes.len() / stride;
        let first = scene.len();
        if self.kind == PlyKind::Gaussian3d {
            for (i, row) in bytes.chunks_exact(stride).take(rows).enumerate() {
                self.check_gaussian_row(row, first + i, origin)?;
            }
        }
        extend_scene(
            scene,
            rows,
            first,
            |i| self.kernel(&bytes[i * stride..(i + 1) * stride]),
            origin,
        )?;
        if let Some(norms) = &mut appearance.rotation_norms {
            norms.extend(bytes.chunks_exact(stride).take(rows).map(|row| {
                let q = self.kernel(row).rotation;
                q.iter().map(|v| v * v).sum::<f64>().sqrt()
            }));
        }
        if self.blend == Blend::Alpha {
            let triplets = self.sh.len() / 3;
            for row in bytes.chunks_exact(stride).take(rows) {
                appearance.opacities.push(match self.kind {
                    PlyKind::Scene4d => self.opacity.map_or(1.0, |field| value_at(row, field)),
                    PlyKind::Gaussian3d => sigmoid(value_at(row, self.fields[6])),
                });
                // 4D scenes store triplet j's channel c at sh_{3j+c}; 3DGS files channel by
                // channel, f_rest_{c·n + j}.
                appearance.sh.extend((0..triplets).map(|j| {
                    std::array::from_fn(|c| {
                        let k = match self.kind {
                            PlyKind::Scene4d => 3 * j + c,
                            PlyKind::Gaussian3d => c * triplets + j,
                        };
                        value_at(row, self.sh[k])
                    })
                }));
            }
        }
        Ok(())
    }

    /// The scene with its blend and appearance, checked.
    fn finish(&self, scene: Scene, appearance: Appearance, origin: &str) -> Result<Scene> {
        match self.blend {
            Blend::Additive => Ok(scene),
            Blend::Alpha => scene.into_alpha(
                appearance.opacities,
                self.sh.len() / 3,
                appearance.sh,
                origin,
            ),
        }
    }
}

fn bad_ply(origin: &str, message: String) -> Error {
    Error::malformed(origin, format!("PLY: {message}"))
}
