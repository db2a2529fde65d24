//! What the importer relies on and the `gltf` crate does not check (a file that breaks it
//! would panic or loop inside the crate's walkers): every index in range, a node hierarchy
//! that is a forest (no cycle, no node with two parents), a camera's projection object
//! present, index accessors of unsigned integers, and strides that hold their elements.
//! One function per glTF array, run in the order [`check_structure`] lists; errors name the
//! JSON path.

use gltf::json::Root;
use gltf::json::accessor::ComponentType;
use gltf::json::validation::Checked;

use crate::model::error::{Error, Result};

/// Every check of the module docs, array by array; the first problem found is the error.
pub(super) fn check_structure(root: &Root, origin: &str) -> Result<()> {
    let check = Check { root, origin };
    let parent = check.nodes()?;
    check.node_hierarchy_has_no_cycle(&parent)?;
    check.scenes(&parent)?;
    check.cameras()?;
    check.accessor_views()?;
    check.buffer_views()?;
    check.accessor_extents()?;
    check.primitive_accessors()?;
    check.node_skins()?;
    check.skins()?;
    check.primitive_materials()?;
    check.materials()?;
    check.textures()?;
    check.animations()
}

/// The document being checked and the name errors give it.
struct Check<'a> {
    root: &'a Root,
    origin: &'a str,
}

impl Check<'_> {
    fn bad(&self, item: String, field: &str, message: String) -> Error {
        Error::invalid(self.origin, item, field, message)
    }

    fn in_range(&self, index: usize, len: usize, item: String, field: &str) -> Result<()> {
        if index < len {
            Ok(())
        } else {
            Err(self.bad(
                item,
                field,
                format!("index {index} is out of range ({len} items)"),
            ))
        }
    }

    /// `nodes`: children, camera and mesh indices in range, one parent a node; returns each
    /// node's parent.
    fn nodes(&self) -> Result<Vec<Option<usize>>> {
        let root = self.root;
        let nodes = root.nodes.len();
        let mut parent: Vec<Option<usize>> = vec![None; nodes];
        for (i, node) in root.nodes.iter().enumerate() {
            for child in node.children.iter().flatten() {
                let c = child.value();
                self.in_range(c, nodes, format!("nodes[{i}]"), "children")?;
                if c == i || parent[c].is_some() {
                    return Err(self.bad(
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
                let item = format!("nodes[{i}]");
                self.in_range(camera.value(), root.cameras.len(), item, "camera")?;
            }
            if let Some(mesh) = &node.mesh {
                let item = format!("nodes[{i}]");
                self.in_range(mesh.value(), root.meshes.len(), item, "mesh")?;
            }
        }
        Ok(parent)
    }

    /// With one parent each, a cycle is a chain of parents that comes back to its start.
    fn node_hierarchy_has_no_cycle(&self, parent: &[Option<usize>]) -> Result<()> {
        let nodes = parent.len();
        for start in 0..nodes {
            let mut node = start;
            for _ in 0..=nodes {
                match parent[node] {
                    Some(p) if p == start => {
                        return Err(self.bad(
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
        Ok(())
    }

    /// `scenes`: root nodes in range and without a parent.
    fn scenes(&self, parent: &[Option<usize>]) -> Result<()> {
        for (s, scene) in self.root.scenes.iter().enumerate() {
            for node in &scene.nodes {
                self.in_range(node.value(), parent.len(), format!("scenes[{s}]"), "nodes")?;
                if let Some(p) = parent[node.value()] {
                    return Err(self.bad(
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
        Ok(())
    }

    /// `cameras`: the projection object `type` names is there.
    fn cameras(&self) -> Result<()> {
        for (c, camera) in self.root.cameras.iter().enumerate() {
            let missing = match camera.type_ {
                Checked::Valid(gltf::json::camera::Type::Perspective) => {
                    camera.perspective.is_none()
                }
                Checked::Valid(gltf::json::camera::Type::Orthographic) => {
                    camera.orthographic.is_none()
                }
                Checked::Invalid => true,
            };
            if missing {
                return Err(self.bad(
                    format!("cameras[{c}]"),
                    "type",
                    "the projection object named by `type` is missing".into(),
                ));
            }
        }
        Ok(())
    }

    /// `accessors`: a buffer view each, in range, whose stride holds one element.
    fn accessor_views(&self) -> Result<()> {
        let root = self.root;
        for (a, accessor) in root.accessors.iter().enumerate() {
            let item = format!("accessors[{a}]");
            let Some(view) = &accessor.buffer_view else {
                return Err(self.bad(
                    item,
                    "bufferView",
                    "accessors without a buffer view are not supported".into(),
                ));
            };
            self.in_range(
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
                    return Err(self.bad(
                        item,
                        "bufferView",
                        format!(
                            "byteStride {stride} is smaller than one element ({element} bytes)"
                        ),
                    ));
                }
            }
        }
        Ok(())
    }

    /// `bufferViews`: the buffer in range, and the view inside it.
    fn buffer_views(&self) -> Result<()> {
        let root = self.root;
        for (v, view) in root.buffer_views.iter().enumerate() {
            let item = format!("bufferViews[{v}]");
            self.in_range(
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
                return Err(self.bad(
                    item,
                    "byteLength",
                    format!("the view ends past its buffer's {buffer} bytes"),
                ));
            }
        }
        Ok(())
    }

    /// `accessors` again: every element an accessor reads lies inside its view.
    fn accessor_extents(&self) -> Result<()> {
        let root = self.root;
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
                return Err(self.bad(
                    format!("accessors[{a}]"),
                    "count",
                    format!(
                        "{count} elements from byteOffset {offset} do not fit the view's {} bytes",
                        view.byte_length.0
                    ),
                ));
            }
        }
        Ok(())
    }

    /// `meshes[].primitives`: attribute and index accessors in range, indices unsigned.
    fn primitive_accessors(&self) -> Result<()> {
        let root = self.root;
        let accessors = root.accessors.len();
        for (m, mesh) in root.meshes.iter().enumerate() {
            for (p, primitive) in mesh.primitives.iter().enumerate() {
                let item = format!("meshes[{m}].primitives[{p}]");
                for accessor in primitive.attributes.values() {
                    self.in_range(accessor.value(), accessors, item.clone(), "attributes")?;
                }
                if let Some(indices) = &primitive.indices {
                    self.in_range(indices.value(), accessors, item.clone(), "indices")?;
                    let component = &root.accessors[indices.value()].component_type;
                    if !matches!(
                        component,
                        Checked::Valid(gltf::json::accessor::GenericComponentType(
                            ComponentType::U8 | ComponentType::U16 | ComponentType::U32
                        ))
                    ) {
                        return Err(self.bad(
                            item,
                            "indices",
                            "indices must be unsigned integers (UNSIGNED_BYTE, UNSIGNED_SHORT or UNSIGNED_INT)".into(),
                        ));
                    }
                }
            }
        }
        Ok(())
    }

    /// `nodes[].skin` in range.
    fn node_skins(&self) -> Result<()> {
        for (i, node) in self.root.nodes.iter().enumerate() {
            if let Some(skin) = &node.skin {
                let item = format!("nodes[{i}]");
                self.in_range(skin.value(), self.root.skins.len(), item, "skin")?;
            }
        }
        Ok(())
    }

    /// `skins`: joints and inverse bind matrices in range.
    fn skins(&self) -> Result<()> {
        let root = self.root;
        for (s, skin) in root.skins.iter().enumerate() {
            for joint in &skin.joints {
                let item = format!("skins[{s}]");
                self.in_range(joint.value(), root.nodes.len(), item, "joints")?;
            }
            if let Some(matrices) = &skin.inverse_bind_matrices {
                self.in_range(
                    matrices.value(),
                    root.accessors.len(),
                    format!("skins[{s}]"),
                    "inverseBindMatrices",
                )?;
            }
        }
        Ok(())
    }

    /// `meshes[].primitives[].material` in range.
    fn primitive_materials(&self) -> Result<()> {
        for (m, mesh) in self.root.meshes.iter().enumerate() {
            for (p, primitive) in mesh.primitives.iter().enumerate() {
                if let Some(material) = &primitive.material {
                    let item = format!("meshes[{m}].primitives[{p}]");
                    let materials = self.root.materials.len();
                    self.in_range(material.value(), materials, item, "material")?;
                }
            }
        }
        Ok(())
    }

    /// `materials`: every texture index in range.
    fn materials(&self) -> Result<()> {
        let textures = self.root.textures.len();
        for (m, material) in self.root.materials.iter().enumerate() {
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
                    self.in_range(index, textures, format!("materials[{m}]"), field)?;
                }
            }
        }
        Ok(())
    }

    /// `textures`: source image and sampler in range.
    fn textures(&self) -> Result<()> {
        let root = self.root;
        for (t, texture) in root.textures.iter().enumerate() {
            let item = format!("textures[{t}]");
            self.in_range(texture.source.value(), root.images.len(), item, "source")?;
            if let Some(sampler) = &texture.sampler {
                let item = format!("textures[{t}]");
                self.in_range(sampler.value(), root.samplers.len(), item, "sampler")?;
            }
        }
        Ok(())
    }

    /// `animations`: channels' target nodes and samplers, samplers' accessors in range.
    fn animations(&self) -> Result<()> {
        let root = self.root;
        let (nodes, accessors) = (root.nodes.len(), root.accessors.len());
        for (a, animation) in root.animations.iter().enumerate() {
            for (c, channel) in animation.channels.iter().enumerate() {
                let item = format!("animations[{a}].channels[{c}]");
                let node = channel.target.node.value();
                self.in_range(node, nodes, item.clone(), "target.node")?;
                let samplers = animation.samplers.len();
                self.in_range(channel.sampler.value(), samplers, item, "sampler")?;
            }
            for (s, sampler) in animation.samplers.iter().enumerate() {
                let item = format!("animations[{a}].samplers[{s}]");
                self.in_range(sampler.input.value(), accessors, item.clone(), "input")?;
                self.in_range(sampler.output.value(), accessors, item, "output")?;
            }
        }
        Ok(())
    }
}
