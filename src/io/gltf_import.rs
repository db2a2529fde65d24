//! glTF 2.0 (`.gltf` with embedded or external buffers, `.glb`): cameras, and scenes sampled
//! into 4D kernels.
//!
//! **Cameras.** A perspective camera (`yfov`, `aspectRatio`, `znear`, `zfar`) on a node looks
//! down the node's −Z with +Y up (OpenGL axes); its world transform (translation and
//! rotation; scale is ignored, as glTF asks of camera nodes) is converted to SPEC §3 by
//! [`Camera::from_opengl_camera_to_world`]. Square pixels: `fy = ½ H / tan(½ yfov)`, `fx = fy`,
//! principal point at the centre. `MODEL#k` picks the k-th camera node in node order.
//!
//! **Scenes** ([`import_scene`]). `N` points are spread (stratified, seeded) over the
//! triangles of every mesh of the default scene, area-weighted at the first sample time, with their colour from
//! `COLOR_0` (interpolated) or the material's base colour factor (textures are not read).
//! Node animations (translation, rotation, scale; LINEAR, STEP and CUBICSPLINE samplers)
//! through the node hierarchy (all animations play together) are followed at the sample
//! times [`crate::io::gltf_motion`] chooses, and each point becomes one kernel
//! per sample time `t_k`: a surfel with σ = (s, s, 0.3 s), `s = √(area/N)`, its thin axis
//! along the triangle's normal at `t_k`, at the point's (curvature-corrected) position,
//! moving with its analytic velocity, temporal σ `σ_k` and amplitude `colour · g · a_k`,
//! where `g = 1/(2π)` makes surfels at that density sum to the colour face-on and the
//! weights `a_k` make the point's temporal Gaussians sum to one. Without animation (or with
//! `--times 1`) each point is one static kernel (σt = 1000, amplitude `colour · g`). Skins and
//! morph targets are refused with a clear message.

use std::path::{Path, PathBuf};

use base64::Engine;
use glam::{DMat4, DQuat, DVec3};
use rand::RngExt;

use crate::io::gltf_motion::{Animation, PosedSample, Side, Spacing, plan_samples, read_tracks};
use crate::model::camera::Camera;
use crate::model::error::{Error, Result};
use crate::model::random::seeded_rng;
use crate::model::scene::{Kernel, Scene};
use crate::scenes::time_samples::{Place, TimeSample};

/// σ of a surfel, as a fraction of the mean spacing √(area/N).
const SURFEL_SPREAD: f64 = 1.0;
/// Thickness of a surfel along its normal, relative to its width.
const SURFEL_THICKNESS: f64 = 0.3;

fn parse_document(path: &Path) -> Result<gltf::Gltf> {
    let origin = path.display().to_string();
    let bytes = std::fs::read(path).map_err(|e| Error::read(path, "cannot read glTF", e))?;
    let malformed =
        |e: gltf::Error| Error::malformed(&origin, format!("not a valid glTF 2.0 file: {e}"));
    // Our checks first: the crate's own validation indexes arrays without bounds checks.
    let unchecked = gltf::Gltf::from_slice_without_validation(&bytes).map_err(malformed)?;
    check_structure(unchecked.document.as_json(), &origin)?;
    gltf::Gltf::from_slice(&bytes).map_err(malformed)
}

/// What the importer relies on and the `gltf` crate does not check (a file that breaks it
/// would panic or loop inside the crate's walkers): every index in range, a node hierarchy
/// that is a forest (no cycle, no node with two parents), a camera's projection object
/// present, index accessors of unsigned integers, and strides that hold their elements.
/// Errors name the JSON path.
fn check_structure(root: &gltf::json::Root, origin: &str) -> Result<()> {
    use gltf::json::accessor::ComponentType;
    use gltf::json::validation::Checked;
    let bad =
        |item: String, field: &str, message: String| Error::invalid(origin, item, field, message);
    let in_range = |index: usize, len: usize, item: String, field: &str| -> Result<()> {
        if index < len {
            Ok(())
        } else {
            Err(bad(
                item,
                field,
                format!("index {index} is out of range ({len} items)"),
            ))
        }
    };
    let (nodes, accessors) = (root.nodes.len(), root.accessors.len());
    let mut parent: Vec<Option<usize>> = vec![None; nodes];
    for (i, node) in root.nodes.iter().enumerate() {
        for child in node.children.iter().flatten() {
            let c = child.value();
            in_range(c, nodes, format!("nodes[{i}]"), "children")?;
            if c == i || parent[c].is_some() {
                return Err(bad(
                    format!("nodes[{i}]"),
                    "children",
                    format!(
                        "node {c} has two parents or is its own child: the node hierarchy must be a tree"
                    ),
                ));
            }
            parent[c] = Some(i);
        }
        if let Some(camera) = &node.camera {
            in_range(
                camera.value(),
                root.cameras.len(),
                format!("nodes[{i}]"),
                "camera",
            )?;
        }
        if let Some(mesh) = &node.mesh {
            in_range(
                mesh.value(),
                root.meshes.len(),
                format!("nodes[{i}]"),
                "mesh",
            )?;
        }
    }
    // With one parent each, a cycle is a chain of parents that comes back to its start.
    for start in 0..nodes {
        let mut node = start;
        for _ in 0..=nodes {
            match parent[node] {
                Some(p) if p == start => {
                    return Err(bad(
                        format!("nodes[{start}]"),
                        "children",
                        "the node hierarchy has a cycle".into(),
                    ));
                }
                Some(p) => node = p,
                None => break,
            }
        }
    }
    for (s, scene) in root.scenes.iter().enumerate() {
        for node in &scene.nodes {
            in_range(node.value(), nodes, format!("scenes[{s}]"), "nodes")?;
            if let Some(p) = parent[node.value()] {
                return Err(bad(
                    format!("scenes[{s}]"),
                    "nodes",
                    format!(
                        "node {} is a root of the scene and a child of node {p}",
                        node.value()
                    ),
                ));
            }
        }
    }
    for (c, camera) in root.cameras.iter().enumerate() {
        let missing = match camera.type_ {
            Checked::Valid(gltf::json::camera::Type::Perspective) => camera.perspective.is_none(),
            Checked::Valid(gltf::json::camera::Type::Orthographic) => camera.orthographic.is_none(),
            Checked::Invalid => true,
        };
        if missing {
            return Err(bad(
                format!("cameras[{c}]"),
                "type",
                "the projection object named by `type` is missing".into(),
            ));
        }
    }
    for (a, accessor) in root.accessors.iter().enumerate() {
        let item = format!("accessors[{a}]");
        let Some(view) = &accessor.buffer_view else {
            return Err(bad(
                item,
                "bufferView",
                "accessors without a buffer view are not supported".into(),
            ));
        };
        in_range(
            view.value(),
            root.buffer_views.len(),
            item.clone(),
            "bufferView",
        )?;
        let stride = root.buffer_views[view.value()]
            .byte_stride
            .as_ref()
            .map(|s| s.0);
        if let (Some(stride), Checked::Valid(kind), Checked::Valid(component)) =
            (stride, &accessor.type_, &accessor.component_type)
        {
            let element = kind.multiplicity() * component.0.size();
            if stride < element {
                return Err(bad(
                    item,
                    "bufferView",
                    format!("byteStride {stride} is smaller than one element ({element} bytes)"),
                ));
            }
        }
    }
    for (v, view) in root.buffer_views.iter().enumerate() {
        let item = format!("bufferViews[{v}]");
        in_range(
            view.buffer.value(),
            root.buffers.len(),
            item.clone(),
            "buffer",
        )?;
        let end = view
            .byte_offset
            .map_or(0, |o| o.0)
            .checked_add(view.byte_length.0);
        let buffer = root.buffers[view.buffer.value()].byte_length.0;
        if end.is_none_or(|end| end > buffer) {
            return Err(bad(
                item,
                "byteLength",
                format!("the view ends past its buffer's {buffer} bytes"),
            ));
        }
    }
    // Every element an accessor reads lies inside its view.
    for (a, accessor) in root.accessors.iter().enumerate() {
        let (Some(view), Checked::Valid(kind), Checked::Valid(component)) = (
            &accessor.buffer_view,
            &accessor.type_,
            &accessor.component_type,
        ) else {
            continue;
        };
        let view = &root.buffer_views[view.value()];
        let element = (kind.multiplicity() * component.0.size()) as u64;
        let stride = view.byte_stride.as_ref().map_or(element, |s| s.0 as u64);
        let count = accessor.count.0;
        let offset = accessor.byte_offset.map_or(0, |o| o.0);
        let end = count
            .checked_sub(1)
            .and_then(|last| last.checked_mul(stride))
            .and_then(|span| span.checked_add(element))
            .and_then(|span| span.checked_add(offset));
        if count > 0 && end.is_none_or(|end| end > view.byte_length.0) {
            return Err(bad(
                format!("accessors[{a}]"),
                "count",
                format!(
                    "{count} elements from byteOffset {offset} do not fit the view's {} bytes",
                    view.byte_length.0
                ),
            ));
        }
    }
    for (m, mesh) in root.meshes.iter().enumerate() {
        for (p, primitive) in mesh.primitives.iter().enumerate() {
            let item = format!("meshes[{m}].primitives[{p}]");
            for accessor in primitive.attributes.values() {
                in_range(accessor.value(), accessors, item.clone(), "attributes")?;
            }
            if let Some(indices) = &primitive.indices {
                in_range(indices.value(), accessors, item.clone(), "indices")?;
                let component = &root.accessors[indices.value()].component_type;
                if !matches!(
                    component,
                    Checked::Valid(gltf::json::accessor::GenericComponentType(
                        ComponentType::U8 | ComponentType::U16 | ComponentType::U32
                    ))
                ) {
                    return Err(bad(
                        item,
                        "indices",
                        "indices must be unsigned integers (UNSIGNED_BYTE, UNSIGNED_SHORT or UNSIGNED_INT)".into(),
                    ));
                }
            }
        }
    }
    for (i, node) in root.nodes.iter().enumerate() {
        if let Some(skin) = &node.skin {
            in_range(
                skin.value(),
                root.skins.len(),
                format!("nodes[{i}]"),
                "skin",
            )?;
        }
    }
    for (s, skin) in root.skins.iter().enumerate() {
        for joint in &skin.joints {
            in_range(joint.value(), nodes, format!("skins[{s}]"), "joints")?;
        }
        if let Some(matrices) = &skin.inverse_bind_matrices {
            in_range(
                matrices.value(),
                accessors,
                format!("skins[{s}]"),
                "inverseBindMatrices",
            )?;
        }
    }
    for (m, mesh) in root.meshes.iter().enumerate() {
        for (p, primitive) in mesh.primitives.iter().enumerate() {
            if let Some(material) = &primitive.material {
                let item = format!("meshes[{m}].primitives[{p}]");
                in_range(material.value(), root.materials.len(), item, "material")?;
            }
        }
    }
    let textures = root.textures.len();
    for (m, material) in root.materials.iter().enumerate() {
        let pbr = &material.pbr_metallic_roughness;
        let indices = [
            (
                "pbrMetallicRoughness.baseColorTexture",
                pbr.base_color_texture.as_ref().map(|t| t.index.value()),
            ),
            (
                "pbrMetallicRoughness.metallicRoughnessTexture",
                pbr.metallic_roughness_texture
                    .as_ref()
                    .map(|t| t.index.value()),
            ),
            (
                "normalTexture",
                material.normal_texture.as_ref().map(|t| t.index.value()),
            ),
            (
                "occlusionTexture",
                material.occlusion_texture.as_ref().map(|t| t.index.value()),
            ),
            (
                "emissiveTexture",
                material.emissive_texture.as_ref().map(|t| t.index.value()),
            ),
        ];
        for (field, index) in indices {
            if let Some(index) = index {
                in_range(index, textures, format!("materials[{m}]"), field)?;
            }
        }
    }
    for (t, texture) in root.textures.iter().enumerate() {
        in_range(
            texture.source.value(),
            root.images.len(),
            format!("textures[{t}]"),
            "source",
        )?;
        if let Some(sampler) = &texture.sampler {
            in_range(
                sampler.value(),
                root.samplers.len(),
                format!("textures[{t}]"),
                "sampler",
            )?;
        }
    }
    for (a, animation) in root.animations.iter().enumerate() {
        for (c, channel) in animation.channels.iter().enumerate() {
            let item = format!("animations[{a}].channels[{c}]");
            in_range(
                channel.target.node.value(),
                nodes,
                item.clone(),
                "target.node",
            )?;
            in_range(
                channel.sampler.value(),
                animation.samplers.len(),
                item,
                "sampler",
            )?;
        }
        for (s, sampler) in animation.samplers.iter().enumerate() {
            let item = format!("animations[{a}].samplers[{s}]");
            in_range(sampler.input.value(), accessors, item.clone(), "input")?;
            in_range(sampler.output.value(), accessors, item, "output")?;
        }
    }
    Ok(())
}

fn load_buffers(document: &gltf::Gltf, path: &Path) -> Result<Vec<Vec<u8>>> {
    let origin = path.display().to_string();
    let dir = path.parent().unwrap_or(Path::new("."));
    document
        .buffers()
        .map(|buffer| {
            let item = format!("buffer {}", buffer.index());
            let data = match buffer.source() {
                gltf::buffer::Source::Bin => document.blob.clone().ok_or_else(|| {
                    Error::invalid(
                        &origin,
                        &item,
                        "uri",
                        "refers to the GLB binary chunk, which is missing",
                    )
                })?,
                gltf::buffer::Source::Uri(uri) if uri.starts_with("data:") => {
                    let (_, encoded) = uri.split_once(',').ok_or_else(|| {
                        Error::invalid(&origin, &item, "uri", "a data URI without a comma")
                    })?;
                    base64::engine::general_purpose::STANDARD
                        .decode(encoded)
                        .map_err(|e| {
                            Error::invalid(&origin, &item, "uri", format!("bad base64: {e}"))
                        })?
                }
                gltf::buffer::Source::Uri(uri) => {
                    let file = buffer_file(dir, uri, &origin, &item)?;
                    read_at_most(&file, buffer.length() as u64).map_err(|e| {
                        Error::read(&file, &format!("{origin}: {item}: cannot read"), e)
                    })?
                }
            };
            if data.len() < buffer.length() {
                return Err(Error::invalid(
                    &origin,
                    &item,
                    "byteLength",
                    format!("{} bytes declared, {} present", buffer.length(), data.len()),
                ));
            }
            Ok(data)
        })
        .collect()
}

/// The file a buffer `uri` names: relative to the model's folder and inside it (no absolute
/// path, no `..` that leaves it, percent-escapes decoded first), and a regular file (not a
/// device, FIFO or folder), so a model cannot make the importer read `/etc/passwd`,
/// `/dev/zero` or block on a pipe.
fn buffer_file(dir: &Path, uri: &str, origin: &str, item: &str) -> Result<PathBuf> {
    let refuse = |message: String| Error::invalid(origin, item, "uri", message);
    let decoded = percent_decode(uri);
    let relative = Path::new(&decoded);
    let mut depth = 0_i64;
    for part in relative.components() {
        match part {
            std::path::Component::Normal(_) => depth += 1,
            std::path::Component::CurDir => {}
            std::path::Component::ParentDir => depth -= 1,
            _ => {
                return Err(refuse(format!(
                    "{uri}: absolute paths are not read (a buffer must sit beside the model)"
                )));
            }
        }
        if depth < 0 {
            return Err(refuse(format!("{uri}: leaves the model's folder")));
        }
    }
    let file = dir.join(relative);
    let meta = std::fs::metadata(&file)
        .map_err(|e| Error::read(&file, &format!("{origin}: {item}: cannot read"), e))?;
    if !meta.is_file() {
        return Err(refuse(format!("{uri}: not a regular file")));
    }
    // By the real path too: a symlink beside the model may point anywhere.
    if !crate::io::output::inside(&file, dir) {
        return Err(refuse(format!(
            "{uri}: is a link to a file outside the model's folder, which is not read"
        )));
    }
    Ok(file)
}

/// `%XX` escapes of a URI decoded (invalid ones kept as they are).
fn percent_decode(uri: &str) -> String {
    let bytes = uri.as_bytes();
    let mut out = Vec::with_capacity(bytes.len());
    let mut i = 0;
    while i < bytes.len() {
        let hex = |b: u8| (b as char).to_digit(16);
        if bytes[i] == b'%' && i + 2 < bytes.len() {
            if let (Some(h), Some(l)) = (hex(bytes[i + 1]), hex(bytes[i + 2])) {
                out.push((h * 16 + l) as u8);
                i += 3;
                continue;
            }
        }
        out.push(bytes[i]);
        i += 1;
    }
    String::from_utf8_lossy(&out).into_owned()
}

/// The first `limit` bytes of `path` (a buffer's declared `byteLength`): a file longer than
/// its declaration is not read to its end.
fn read_at_most(path: &Path, limit: u64) -> std::io::Result<Vec<u8>> {
    use std::io::Read;
    let mut data = Vec::new();
    std::fs::File::open(path)?
        .take(limit)
        .read_to_end(&mut data)?;
    Ok(data)
}

/// Runs `work` and turns a panic inside it (the `gltf` crate's readers index buffers it has
/// not checked; [`check_structure`] covers what this importer walks, this is the net under
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
    let world: Vec<DMat4> = Animation::new(Vec::new(), document.nodes().count())
        .world(&document, 0.0, Side::Right)
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

/// A triangle of a mesh, in its node's local space.
struct Triangle {
    node: usize,
    corners: [DVec3; 3],
    colours: [[f64; 3]; 3],
}

fn read_triangles(
    document: &gltf::Document,
    buffers: &[Vec<u8>],
    origin: &str,
) -> Result<Vec<Triangle>> {
    let mut triangles = Vec::new();
    let scene = document
        .default_scene()
        .or_else(|| document.scenes().next());
    let mut stack: Vec<gltf::Node<'_>> = scene.map(|s| s.nodes().collect()).unwrap_or_default();
    while let Some(node) = stack.pop() {
        stack.extend(node.children());
        let Some(mesh) = node.mesh() else { continue };
        let item = format!("node {} mesh {}", node.index(), mesh.index());
        if node.skin().is_some() {
            return Err(Error::invalid(
                origin,
                &item,
                "skin",
                "skinned meshes are not supported",
            ));
        }
        for primitive in mesh.primitives() {
            if primitive.morph_targets().next().is_some() {
                return Err(Error::invalid(
                    origin,
                    &item,
                    "targets",
                    "morph targets are not supported",
                ));
            }
            if primitive.mode() != gltf::mesh::Mode::Triangles {
                continue; // points and lines have no area
            }
            let reader = primitive.reader(|b| buffers.get(b.index()).map(|d| d.as_slice()));
            let positions: Vec<DVec3> = reader
                .read_positions()
                .ok_or_else(|| Error::invalid(origin, &item, "POSITION", "missing or unreadable"))?
                .map(|p| DVec3::from(p.map(f64::from)))
                .collect();
            let base = primitive
                .material()
                .pbr_metallic_roughness()
                .base_color_factor();
            let colours: Vec<[f64; 3]> = match reader.read_colors(0) {
                Some(c) => c.into_rgb_f32().map(|c| c.map(f64::from)).collect(),
                None => vec![
                    [f64::from(base[0]), f64::from(base[1]), f64::from(base[2])];
                    positions.len()
                ],
            };
            let indices: Vec<usize> = match reader.read_indices() {
                Some(i) => i.into_u32().map(|i| i as usize).collect(),
                None => (0..positions.len()).collect(),
            };
            for tri in indices.chunks_exact(3) {
                if tri
                    .iter()
                    .any(|&i| i >= positions.len() || i >= colours.len())
                {
                    return Err(Error::invalid(
                        origin,
                        &item,
                        "indices",
                        "an index is out of range",
                    ));
                }
                triangles.push(Triangle {
                    node: node.index(),
                    corners: [positions[tri[0]], positions[tri[1]], positions[tri[2]]],
                    colours: [colours[tri[0]], colours[tri[1]], colours[tri[2]]],
                });
            }
        }
    }
    Ok(triangles)
}

/// Every node's world matrix (column-major, as glTF writes them) at time `t`, the node
/// animation evaluated directly (the right limit at key times): what imported kernels are
/// checked against.
pub fn world_matrices_at(path: &Path, t: f64) -> Result<Vec<[[f64; 4]; 4]>> {
    without_panics(path, || {
        let (gltf, _, animation) = load_animated(path)?;
        Ok(animation
            .world(&gltf.document, t, Side::Right)
            .into_iter()
            .map(|pose| pose.0.to_cols_array_2d())
            .collect())
    })
}

/// The document at `path`, its buffers and its node animation.
fn load_animated(path: &Path) -> Result<(gltf::Gltf, Vec<Vec<u8>>, Animation)> {
    let origin = path.display().to_string();
    let gltf = parse_document(path)?;
    let buffers = load_buffers(&gltf, path)?;
    let animation = Animation::new(
        read_tracks(&gltf.document, &buffers, &origin)?,
        gltf.document.nodes().count(),
    );
    Ok((gltf, buffers, animation))
}

/// What [`import_scene`] made.
#[derive(Clone, Debug)]
pub struct Imported {
    /// The 4D scene.
    pub scene: Scene,
    /// The animations' time range (`[0, 0]` when static).
    pub time_range: [f64; 2],
    /// Surface points sampled.
    pub points: usize,
    /// Time samples per point (kernels = points × times).
    pub times: usize,
    /// Largest distance, over the model's size, between where the kernels put any surface
    /// point and where the animation does, at the test times (0 when static).
    pub max_error: f64,
    /// Largest `|Σ temporal weights - 1|` of a point's kernels over the range.
    pub weight_error: f64,
    /// Key times where the pose jumps (STEP keys).
    pub steps: usize,
    /// Per kernel, the temporal weight of its time sample (the partition of unity).
    pub sample_weights: Vec<f64>,
}

/// Peak opacity of an opaque surfel of the alpha blend: with neighbours one σ apart, a
/// point of the surface is covered by several surfels, so the surface closes (T < 1e-3
/// behind it, tested).
pub const SURFEL_OPACITY: f64 = 0.9;

impl Imported {
    /// The import as opaque surfaces (SPEC §8): each kernel's colour is its point's colour
    /// and its opacity [`SURFEL_OPACITY`] times its temporal weight, so that surfaces hide
    /// what is behind them.
    pub fn into_alpha(mut self, origin: &str) -> Result<Imported> {
        let gain = 1.0 / (std::f64::consts::TAU * SURFEL_SPREAD * SURFEL_SPREAD);
        let mut opacities = Vec::with_capacity(self.scene.len());
        for (amplitude, &weight) in self.scene.amplitudes.iter_mut().zip(&self.sample_weights) {
            let scale = gain * weight;
            if scale > 0.0 {
                *amplitude = amplitude.map(|a| a / scale);
            }
            opacities.push((SURFEL_OPACITY * weight).clamp(0.0, 1.0));
        }
        self.scene = self.scene.into_alpha(opacities, 0, Vec::new(), origin)?;
        Ok(self)
    }
}

/// Most kernels an import makes (surface points × time samples): about 1.5 GB of scene.
pub const MAX_IMPORT_KERNELS: usize = 10_000_000;

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
        Spacing::Even(0) => return Err(Error::usage("--times must be at least 1")),
        Spacing::Adaptive { tolerance } if !(tolerance > 0.0 && tolerance.is_finite()) => {
            return Err(Error::usage(format!(
                "--tolerance {tolerance} must be a positive number"
            )));
        }
        _ => {}
    }
    if points == 0 {
        return Err(Error::usage("--kernels must be at least 1"));
    }
    if points > MAX_IMPORT_KERNELS {
        return Err(Error::usage(format!(
            "--kernels {points} is more than the {MAX_IMPORT_KERNELS} kernels an import may make"
        )));
    }
    if let Spacing::Even(times) = spacing
        && points.saturating_mul(times) > MAX_IMPORT_KERNELS
    {
        return Err(Error::usage(format!(
            "--kernels {points} × --times {times} is more than the {MAX_IMPORT_KERNELS} kernels an import may make"
        )));
    }
    let (gltf, buffers, animation) = load_animated(path)?;
    let document = &gltf.document;
    let triangles = read_triangles(document, &buffers, &origin)?;
    let range = animation.range().filter(|_| spacing != Spacing::Even(1));
    let first = range.map_or(0.0, |r| r[0]);
    let start = animation.world(document, first, Side::Right);
    // Area-weighted triangle choice at the first time.
    let areas: Vec<f64> = triangles
        .iter()
        .map(|tri| {
            let m = start[tri.node].0;
            let [a, b, c] = tri.corners.map(|p| m.transform_point3(p));
            0.5 * (b - a).cross(c - a).length()
        })
        .collect();
    let total: f64 = areas.iter().sum();
    if !(total > 0.0 && total.is_finite()) {
        return Err(Error::invalid(
            &origin,
            "scene",
            "meshes",
            "no triangle with a finite, positive area in the default scene",
        ));
    }
    // The samples: every node's pose at each, and each one's temporal σ and weight.
    let (samples, time_range, max_error, weight_error, steps) = match range {
        Some(range) => {
            let mut corners = vec![Vec::new(); start.len()];
            for tri in &triangles {
                corners[tri.node].extend_from_slice(&tri.corners);
            }
            let (mut lo, mut hi) = (DVec3::splat(f64::INFINITY), DVec3::splat(f64::NEG_INFINITY));
            for tri in &triangles {
                for p in tri.corners {
                    let w = start[tri.node].0.transform_point3(p);
                    (lo, hi) = (lo.min(w), hi.max(w));
                }
            }
            let size = (hi - lo).length().max(f64::MIN_POSITIVE);
            let plan = plan_samples(
                document, &animation, range, &corners, size, spacing, &origin,
            )?;
            if points.saturating_mul(plan.samples.len()) > MAX_IMPORT_KERNELS {
                return Err(Error::usage(format!(
                    "--kernels {points} × {} sample times is more than the {MAX_IMPORT_KERNELS} kernels an import may make; lower --kernels or raise --tolerance",
                    plan.samples.len()
                )));
            }
            (
                plan.samples,
                range,
                plan.max_error,
                plan.weight_error,
                plan.steps,
            )
        }
        // Static: one kernel per point, σt = 1000, weight 1.
        None => {
            let sample = TimeSample {
                time: 0.0,
                sigma: 1e3,
                weight: 1.0,
                place: Place::Inside { piece: 0 },
            };
            let posed = PosedSample {
                sample,
                poses: start,
            };
            (vec![posed], [0.0, 0.0], 0.0, 0.0, 0)
        }
    };
    let cumulative: Vec<f64> = areas
        .iter()
        .scan(0.0, |acc, a| {
            *acc += a;
            Some(*acc)
        })
        .collect();
    let sigma = SURFEL_SPREAD * (total / points as f64).sqrt();
    let gain = 1.0 / (std::f64::consts::TAU * SURFEL_SPREAD * SURFEL_SPREAD);
    let mut rng = seeded_rng(seed);
    let mut kernels = Vec::with_capacity(points.saturating_mul(samples.len()).min(1 << 16));
    let mut sample_weights = Vec::with_capacity(kernels.capacity());
    // Stratified over the cumulative area (point k in the k-th N-th of it, jittered), with
    // barycentric coordinates from the R2 low-discrepancy sequence (seeded offset): far
    // more even coverage than independent draws, whose density fluctuates by ~30% at this
    // surfel size.
    const R2: [f64; 2] = [0.754_877_666_246_692_8, 0.569_840_290_998_053_3];
    let offset: [f64; 2] = [rng.random(), rng.random()];
    for point in 0..points {
        let jitter: f64 = rng.random();
        let r = total * (point as f64 + jitter) / points as f64;
        let index = cumulative
            .partition_point(|&c| c <= r)
            .min(triangles.len() - 1);
        let tri = &triangles[index];
        let (mut u, mut v) = (
            (offset[0] + point as f64 * R2[0]).fract(),
            (offset[1] + point as f64 * R2[1]).fract(),
        );
        if u + v > 1.0 {
            (u, v) = (1.0 - u, 1.0 - v);
        }
        let local = tri.corners[0]
            + u * (tri.corners[1] - tri.corners[0])
            + v * (tri.corners[2] - tri.corners[0]);
        let colour: [f64; 3] = std::array::from_fn(|c| {
            tri.colours[0][c]
                + u * (tri.colours[1][c] - tri.colours[0][c])
                + v * (tri.colours[2][c] - tri.colours[0][c])
        });
        for PosedSample { sample, poses } in &samples {
            let (m, rate) = poses[tri.node];
            let [a, b, c] = tri.corners.map(|p| m.transform_point3(p));
            let normal = (b - a).cross(c - a).normalize_or_zero();
            let q = if normal == DVec3::ZERO {
                DQuat::IDENTITY
            } else {
                DQuat::from_rotation_arc(DVec3::Z, normal)
            };
            let p = m.transform_point3(local);
            kernels.push(Kernel {
                mean: [p.x, p.y, p.z, sample.time],
                scale: [sigma, sigma, SURFEL_THICKNESS * sigma, sample.sigma],
                amplitude: colour.map(|c| c * gain * sample.weight),
                rotation: [q.w, q.x, q.y, q.z],
                velocity: rate.transform_point3(local).into(),
            });
            sample_weights.push(sample.weight);
        }
    }
    let scene = Scene::from_kernels(&kernels, [0.0; 3], &origin)?;
    Ok(Imported {
        scene,
        time_range,
        points,
        times: samples.len(),
        max_error,
        weight_error,
        steps,
        sample_weights,
    })
}
