//! A checked glTF document's content as plain data: its node tree, its animation tracks,
//! and its meshes' triangles (skins and morph targets refused).

use glam::DVec3;

use crate::model::error::{Error, Result};
use crate::scenes::animation::{Interpolation, Node, NodeTree, Property, Track};
use crate::scenes::surfels::Triangle;

/// The roots of the scene shown: the default scene, else the first.
fn shown_scene<'a>(document: &'a gltf::Document) -> Option<gltf::Scene<'a>> {
    document
        .default_scene()
        .or_else(|| document.scenes().next())
}

/// Every node of `document` at rest, and the roots of the scene shown.
pub(super) fn read_node_tree(document: &gltf::Document) -> NodeTree {
    let nodes = document
        .nodes()
        .map(|node| {
            let matrix = node.transform().matrix().map(|c| c.map(f64::from));
            let (translation, rotation, scale) = node.transform().decomposed();
            Node {
                matrix: glam::DMat4::from_cols_array_2d(&matrix),
                translation: DVec3::from(translation.map(f64::from)),
                rotation: rotation.map(f64::from),
                scale: DVec3::from(scale.map(f64::from)),
                children: node.children().map(|c| c.index()).collect(),
            }
        })
        .collect();
    let roots = shown_scene(document)
        .map(|scene| scene.nodes().map(|n| n.index()).collect())
        .unwrap_or_default();
    NodeTree { nodes, roots }
}

/// Every channel of every animation of `document`, checked (keys finite, ascending, one value
/// per key or three for CUBICSPLINE; morph target weights refused).
pub(super) fn read_tracks(
    document: &gltf::Document,
    buffers: &[Vec<u8>],
    origin: &str,
) -> Result<Vec<Track>> {
    let mut tracks = Vec::new();
    for animation in document.animations() {
        for channel in animation.channels() {
            let item = format!(
                "animation {} channel {}",
                animation.index(),
                channel.index()
            );
            let reader = channel.reader(|b| buffers.get(b.index()).map(|d| d.as_slice()));
            let times: Vec<f64> = reader
                .read_inputs()
                .ok_or_else(|| Error::invalid(origin, &item, "sampler.input", "cannot be read"))?
                .map(f64::from)
                .collect();
            let outputs = reader
                .read_outputs()
                .ok_or_else(|| Error::invalid(origin, &item, "sampler.output", "cannot be read"))?;
            use gltf::animation::util::ReadOutputs;
            let values: Vec<Vec<f64>> = match outputs {
                ReadOutputs::Translations(it) => it.map(|v| v.map(f64::from).to_vec()).collect(),
                ReadOutputs::Scales(it) => it.map(|v| v.map(f64::from).to_vec()).collect(),
                ReadOutputs::Rotations(it) => {
                    it.into_f32().map(|v| v.map(f64::from).to_vec()).collect()
                }
                ReadOutputs::MorphTargetWeights(_) => {
                    return Err(Error::invalid(
                        origin,
                        &item,
                        "target.path",
                        "morph target weights are not supported",
                    ));
                }
            };
            let interpolation = match channel.sampler().interpolation() {
                gltf::animation::Interpolation::Step => Interpolation::Step,
                gltf::animation::Interpolation::Linear => Interpolation::Linear,
                gltf::animation::Interpolation::CubicSpline => Interpolation::CubicSpline,
            };
            let per_key = if interpolation == Interpolation::CubicSpline {
                3
            } else {
                1
            };
            if times.is_empty()
                || values.len() != per_key * times.len()
                || times.iter().any(|t| !t.is_finite())
                || times.windows(2).any(|w| w[1] < w[0])
            {
                return Err(Error::invalid(
                    origin,
                    &item,
                    "sampler",
                    "keyframe times and values do not match (count, order or finiteness)",
                ));
            }
            if let Some(key) = values.iter().position(|v| v.iter().any(|x| !x.is_finite())) {
                return Err(Error::invalid(
                    origin,
                    &item,
                    "sampler.output",
                    format!("keyframe value {key} is not finite (NaN or infinity)"),
                ));
            }
            tracks.push(Track {
                node: channel.target().node().index(),
                property: match channel.target().property() {
                    gltf::animation::Property::Translation => Property::Translation,
                    gltf::animation::Property::Rotation => Property::Rotation,
                    gltf::animation::Property::Scale => Property::Scale,
                    // Refused above: their outputs are morph target weights.
                    gltf::animation::Property::MorphTargetWeights => unreachable!(),
                },
                interpolation,
                times,
                values,
            });
        }
    }
    Ok(tracks)
}

/// Every triangle of every mesh of the scene shown, in its node's local space.
pub(super) fn read_triangles(
    document: &gltf::Document,
    buffers: &[Vec<u8>],
    origin: &str,
) -> Result<Vec<Triangle>> {
    let mut triangles = Vec::new();
    let scene = shown_scene(document);
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
