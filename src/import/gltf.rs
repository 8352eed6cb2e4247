//! Reading a glTF 2.0 document (GLB or JSON with its buffers) into flat,
//! world-space triangle lists, one per placed primitive.
//!
//! Everything the file says is checked before it is used: GLB chunk lengths,
//! every index into the document's arrays, accessor ranges against their
//! buffer views and the views against their buffers (with overflow-checked
//! arithmetic, before anything is allocated), index values against the
//! vertex count, and the node hierarchy against cycles. A malformed file is an
//! [`ImportError`], never a panic, and never an allocation larger than a
//! small multiple of the file.

use super::ImportError;
use base64::Engine;
use glam::{Mat3, Mat4, Quat, Vec3};
use gltf::json;
use gltf::json::accessor::{ComponentType, Type};
use gltf::json::mesh::{Mode, Semantic};
use gltf::json::validation::Checked;
use std::collections::HashMap;
use std::path::{Path, PathBuf};

/// Vertex attribute names (after the leading `_`, case-insensitive) read as
/// phyllotaxy group ids.
pub const GROUP_ATTRIBUTES: [&str; 4] = ["GROUP", "SHOOT", "FASCICLE", "TWIG"];

/// Most vertices all placed primitives together may have (instancing can
/// multiply a small file): 2^27, about 134 million.
const MAX_TOTAL_VERTICES: u64 = 1 << 27;

/// Deepest node hierarchy followed.
const MAX_NODE_DEPTH: usize = 256;

/// One primitive placed in the world by one node.
#[derive(Clone, Debug, Default)]
pub(crate) struct PlacedPrimitive {
    /// Index of the node placing it.
    pub node: usize,
    /// Node, mesh and material names (empty when unnamed).
    pub node_name: String,
    pub mesh_name: String,
    pub material_name: String,
    /// Index of the mesh and of the primitive in it.
    pub mesh: usize,
    pub primitive: usize,
    /// The node's world transform (with the import scale).
    pub world: Mat4,
    /// World-space positions (metres, after `--scale`).
    pub positions: Vec<Vec3>,
    /// World-space unit normals, when the file has them.
    pub normals: Option<Vec<Vec3>>,
    /// Triangles (counter-clockwise seen from the front in world space).
    pub triangles: Vec<[u32; 3]>,
    /// Per-vertex group ids from a `_GROUP`-like attribute.
    pub groups: Option<Vec<i64>>,
    /// Non-triangle primitive mode, when it is one (no triangles then).
    pub non_triangle_mode: Option<&'static str>,
}

impl PlacedPrimitive {
    /// "node `a` / mesh `b` primitive 0", for messages.
    pub fn describe(&self) -> String {
        let name = |s: &str, i: usize| {
            if s.is_empty() {
                format!("#{i}")
            } else {
                format!("`{s}`")
            }
        };
        format!(
            "node {} / mesh {} primitive {}",
            name(&self.node_name, self.node),
            name(&self.mesh_name, self.mesh),
            self.primitive
        )
    }
}

/// Splits the bytes of a file into the glTF JSON and the GLB binary chunk
/// (`None` for a `.gltf` JSON file).
fn split_glb(bytes: &[u8]) -> Result<(&[u8], Option<&[u8]>), ImportError> {
    if bytes.len() < 4 || &bytes[..4] != b"glTF" {
        let start = bytes.iter().position(|b| !b.is_ascii_whitespace()).map(|i| bytes[i]);
        if start == Some(b'{') {
            return Ok((bytes, None));
        }
        if b"glTF".starts_with(&bytes[..bytes.len().min(4)]) && !bytes.is_empty() {
            return Err(ImportError::Truncated(format!(
                "{} bytes: shorter than the 12-byte GLB header",
                bytes.len()
            )));
        }
        return Err(ImportError::NotGltf);
    }
    if bytes.len() < 12 {
        return Err(ImportError::Truncated(format!(
            "{} bytes: shorter than the 12-byte GLB header",
            bytes.len()
        )));
    }
    let u32_at = |at: usize| u32::from_le_bytes([bytes[at], bytes[at + 1], bytes[at + 2], bytes[at + 3]]);
    let version = u32_at(4);
    if version != 2 {
        return Err(ImportError::Unsupported(format!(
            "GLB container version {version} (only 2 is read)"
        )));
    }
    let declared = u32_at(8) as usize;
    if declared > bytes.len() {
        return Err(ImportError::Truncated(format!(
            "the GLB header says {declared} bytes, the file has {}",
            bytes.len()
        )));
    }
    let body = &bytes[..declared.max(12)];
    let mut at = 12usize;
    let mut json = None;
    let mut bin = None;
    while at < body.len() {
        if body.len() - at < 8 {
            return Err(ImportError::Truncated(format!(
                "a GLB chunk header at byte {at} is cut short"
            )));
        }
        let length = u32_at(at) as usize;
        let kind = u32_at(at + 4);
        let start = at + 8;
        if length > body.len() - start {
            return Err(ImportError::Truncated(format!(
                "GLB chunk at byte {at} announces {length} bytes, {} remain",
                body.len() - start
            )));
        }
        let data = &body[start..start + length];
        match kind {
            0x4E4F_534A if json.is_none() => json = Some(data),
            0x004E_4942 if bin.is_none() && json.is_some() => bin = Some(data),
            _ => {} // Unknown chunks are skipped, as the specification asks.
        }
        // Chunks are 4-byte aligned; a missing final padding is tolerated.
        at = start + length.next_multiple_of(4).min(body.len() - start);
    }
    let json = json.ok_or_else(|| ImportError::Truncated("the GLB has no JSON chunk".into()))?;
    Ok((json, bin))
}

/// Where buffers live, and the ones loaded so far.
struct Buffers<'a> {
    root: &'a json::Root,
    bin: Option<&'a [u8]>,
    base_dir: Option<&'a Path>,
    loaded: HashMap<usize, Vec<u8>>,
}

impl<'a> Buffers<'a> {
    /// The bytes of buffer `index`, at least as many as it declares.
    fn get(&mut self, index: usize) -> Result<&[u8], ImportError> {
        let buffer = self
            .root
            .buffers
            .get(index)
            .ok_or_else(|| ImportError::Invalid(format!("buffer {index} does not exist")))?;
        let declared = buffer.byte_length.0;
        if buffer.uri.is_none() {
            // The GLB binary chunk (buffer 0 only, by the specification).
            let bin = match (index, self.bin) {
                (0, Some(bin)) => bin,
                _ => {
                    return Err(ImportError::Invalid(format!(
                        "buffer {index} has no uri and is not the GLB binary chunk"
                    )));
                }
            };
            if (bin.len() as u64) < declared {
                return Err(ImportError::Truncated(format!(
                    "the GLB binary chunk has {} bytes, buffer 0 declares {declared}",
                    bin.len()
                )));
            }
            return Ok(bin);
        }
        if !self.loaded.contains_key(&index) {
            let uri = buffer.uri.as_deref().unwrap_or_default();
            let data = self.load_uri(index, uri)?;
            if (data.len() as u64) < declared {
                return Err(ImportError::Truncated(format!(
                    "buffer {index} ({}) has {} bytes, it declares {declared}",
                    short(uri),
                    data.len()
                )));
            }
            self.loaded.insert(index, data);
        }
        Ok(&self.loaded[&index])
    }

    fn load_uri(&self, index: usize, uri: &str) -> Result<Vec<u8>, ImportError> {
        if let Some(rest) = uri.strip_prefix("data:") {
            let Some((_, payload)) = rest.split_once(";base64,") else {
                return Err(ImportError::Unsupported(format!(
                    "buffer {index}: data URI without base64 encoding"
                )));
            };
            return base64::engine::general_purpose::STANDARD
                .decode(payload.trim_end())
                .map_err(|e| ImportError::Invalid(format!("buffer {index}: bad base64 data URI: {e}")));
        }
        if uri.contains("://") {
            return Err(ImportError::Unsupported(format!(
                "buffer {index}: remote uri {} (only files beside the glTF and data URIs are read)",
                short(uri)
            )));
        }
        let Some(dir) = self.base_dir else {
            return Err(ImportError::MissingBuffer {
                uri: uri.to_string(),
                reason: "external buffers need a file path".into(),
            });
        };
        let relative = percent_decode(uri);
        let path: PathBuf = dir.join(&relative);
        std::fs::read(&path).map_err(|e| ImportError::MissingBuffer {
            uri: path.display().to_string(),
            reason: e.to_string(),
        })
    }
}

/// `%20` and friends of a relative URI.
fn percent_decode(uri: &str) -> String {
    let bytes = uri.as_bytes();
    let mut out = Vec::with_capacity(bytes.len());
    let mut i = 0;
    while i < bytes.len() {
        if bytes[i] == b'%'
            && i + 2 < bytes.len()
            && let Ok(v) = u8::from_str_radix(std::str::from_utf8(&bytes[i + 1..i + 3]).unwrap_or("zz"), 16)
        {
            out.push(v);
            i += 3;
            continue;
        }
        out.push(bytes[i]);
        i += 1;
    }
    String::from_utf8_lossy(&out).into_owned()
}

/// A long string cut for messages.
fn short(s: &str) -> String {
    if s.chars().count() > 60 {
        format!("{}…", s.chars().take(60).collect::<String>())
    } else {
        s.to_string()
    }
}

fn component_size(c: ComponentType) -> usize {
    match c {
        ComponentType::I8 | ComponentType::U8 => 1,
        ComponentType::I16 | ComponentType::U16 => 2,
        ComponentType::U32 | ComponentType::F32 => 4,
    }
}

fn component_name(c: ComponentType) -> &'static str {
    match c {
        ComponentType::I8 => "BYTE",
        ComponentType::U8 => "UNSIGNED_BYTE",
        ComponentType::I16 => "SHORT",
        ComponentType::U16 => "UNSIGNED_SHORT",
        ComponentType::U32 => "UNSIGNED_INT",
        ComponentType::F32 => "FLOAT",
    }
}

/// Reads component `at` of `data` as f64 (integers as integers, or
/// normalized to [-1, 1] / [0, 1] as the specification says).
fn read_component(data: &[u8], at: usize, c: ComponentType, normalized: bool) -> f64 {
    let b = |k: usize| data[at + k];
    match c {
        ComponentType::F32 => f32::from_le_bytes([b(0), b(1), b(2), b(3)]) as f64,
        ComponentType::U32 => u32::from_le_bytes([b(0), b(1), b(2), b(3)]) as f64,
        ComponentType::I8 => {
            let v = b(0) as i8 as f64;
            if normalized { (v / 127.0).max(-1.0) } else { v }
        }
        ComponentType::U8 => {
            let v = b(0) as f64;
            if normalized { v / 255.0 } else { v }
        }
        ComponentType::I16 => {
            let v = i16::from_le_bytes([b(0), b(1)]) as f64;
            if normalized { (v / 32767.0).max(-1.0) } else { v }
        }
        ComponentType::U16 => {
            let v = u16::from_le_bytes([b(0), b(1)]) as f64;
            if normalized { v / 65535.0 } else { v }
        }
    }
}

/// Which accessors a use accepts.
#[derive(Clone, Copy)]
enum Use {
    /// Indices: SCALAR of unsigned byte, short or int, not normalized.
    Indices,
    /// POSITION/NORMAL: VEC3 of float, or of (normalized) 8/16-bit integers
    /// (KHR_mesh_quantization).
    Vec3,
    /// A group id: SCALAR of any component type.
    Scalar,
}

/// The reader of one document.
struct Reader<'a> {
    root: &'a json::Root,
    buffers: Buffers<'a>,
    /// Limit on elements an accessor without buffer view may have.
    unbacked_limit: u64,
}

impl Reader<'_> {
    /// Reads accessor `index` as rows of `width` f64 numbers, checking its
    /// type, its byte range and (for sparse accessors) every index.
    fn read(&mut self, index: usize, usage: Use, what: &str) -> Result<(Vec<f64>, usize), ImportError> {
        let root = self.root;
        let accessor = root
            .accessors
            .get(index)
            .ok_or_else(|| ImportError::Invalid(format!("{what}: accessor {index} does not exist")))?;
        let Checked::Valid(json::accessor::GenericComponentType(component)) = accessor.component_type else {
            return Err(ImportError::Invalid(format!(
                "{what}: accessor {index} has an unknown component type"
            )));
        };
        let Checked::Valid(kind) = accessor.type_ else {
            return Err(ImportError::Invalid(format!(
                "{what}: accessor {index} has an unknown type"
            )));
        };
        let width = kind.multiplicity();
        let normalized = accessor.normalized;
        let ok = match usage {
            Use::Indices => {
                kind == Type::Scalar
                    && !normalized
                    && matches!(component, ComponentType::U8 | ComponentType::U16 | ComponentType::U32)
            }
            Use::Vec3 => kind == Type::Vec3 && component != ComponentType::U32,
            Use::Scalar => kind == Type::Scalar,
        };
        if !ok {
            return Err(ImportError::Unsupported(format!(
                "{what}: accessor {index} is {}{} {:?}, which this importer does not read here",
                if normalized { "normalized " } else { "" },
                component_name(component),
                kind
            )));
        }
        let count = accessor.count.0;
        let element = component_size(component) * width;
        let mut values: Vec<f64>;
        match accessor.buffer_view {
            Some(view_index) => {
                let (data, stride) = self.view(view_index.value(), element, what)?;
                let offset = accessor.byte_offset.map_or(0, |o| o.0);
                let needed = if count == 0 {
                    0
                } else {
                    (count - 1)
                        .checked_mul(stride as u64)
                        .and_then(|x| x.checked_add(offset))
                        .and_then(|x| x.checked_add(element as u64))
                        .ok_or_else(|| ImportError::Invalid(format!("{what}: accessor {index} overflows")))?
                };
                if needed > data.len() as u64 {
                    return Err(ImportError::Invalid(format!(
                        "{what}: accessor {index} needs {needed} bytes ({count} elements) but its buffer view has {}",
                        data.len()
                    )));
                }
                let (count, offset) = (count as usize, offset as usize);
                values = Vec::with_capacity(count * width);
                let size = component_size(component);
                for e in 0..count {
                    let start = offset + e * stride;
                    for k in 0..width {
                        values.push(read_component(data, start + k * size, component, normalized));
                    }
                }
            }
            None => {
                if accessor.sparse.is_none() {
                    return Err(ImportError::Invalid(format!(
                        "{what}: accessor {index} has neither a buffer view nor sparse data"
                    )));
                }
                if count > self.unbacked_limit {
                    return Err(ImportError::Invalid(format!(
                        "{what}: accessor {index} claims {count} zero-initialised elements, far more than the file holds"
                    )));
                }
                values = vec![0.0; count as usize * width];
            }
        }
        if let Some(sparse) = &accessor.sparse {
            let n = sparse.count.0;
            if n > count {
                return Err(ImportError::Invalid(format!(
                    "{what}: accessor {index} has {n} sparse entries for {count} elements"
                )));
            }
            let Checked::Valid(json::accessor::IndexComponentType(index_type)) = sparse.indices.component_type else {
                return Err(ImportError::Invalid(format!(
                    "{what}: accessor {index}: bad sparse index type"
                )));
            };
            if !matches!(index_type, ComponentType::U8 | ComponentType::U16 | ComponentType::U32) {
                return Err(ImportError::Invalid(format!(
                    "{what}: accessor {index}: bad sparse index type"
                )));
            }
            let index_size = component_size(index_type);
            let targets = {
                let (data, _) = self.view(sparse.indices.buffer_view.value(), index_size, what)?;
                let data = checked_range(data, sparse.indices.byte_offset.0, n, index_size as u64, what)?;
                (0..n as usize)
                    .map(|k| read_component(data, k * index_size, index_type, false) as u64)
                    .collect::<Vec<u64>>()
            };
            let size = component_size(component);
            let (data, _) = self.view(sparse.values.buffer_view.value(), element, what)?;
            let data = checked_range(data, sparse.values.byte_offset.0, n, element as u64, what)?;
            for (k, &target) in targets.iter().enumerate() {
                if target >= count {
                    return Err(ImportError::Invalid(format!(
                        "{what}: accessor {index}: sparse index {target} is out of range (count {count})"
                    )));
                }
                for c in 0..width {
                    values[target as usize * width + c] =
                        read_component(data, k * element + c * size, component, normalized);
                }
            }
        }
        Ok((values, width))
    }

    /// The bytes of buffer view `index` and its stride (for elements of
    /// `element` bytes), checked against its buffer.
    fn view(&mut self, index: usize, element: usize, what: &str) -> Result<(&[u8], usize), ImportError> {
        let view = self
            .root
            .buffer_views
            .get(index)
            .ok_or_else(|| ImportError::Invalid(format!("{what}: buffer view {index} does not exist")))?;
        let stride = match view.byte_stride {
            Some(json::buffer::Stride(s)) if s < element => {
                return Err(ImportError::Invalid(format!(
                    "{what}: buffer view {index} has a stride of {s} bytes for {element}-byte elements"
                )));
            }
            Some(json::buffer::Stride(s)) => s,
            None => element,
        };
        let offset = view.byte_offset.map_or(0, |o| o.0);
        let length = view.byte_length.0;
        let buffer = view.buffer.value();
        let data = self.buffers.get(buffer)?;
        let end = offset
            .checked_add(length)
            .filter(|&end| end <= data.len() as u64)
            .ok_or_else(|| {
                ImportError::Invalid(format!(
                    "{what}: buffer view {index} ({length} bytes at {offset}) lies outside buffer {buffer} ({} bytes)",
                    data.len()
                ))
            })?;
        Ok((&data[offset as usize..end as usize], stride))
    }
}

/// `count` tightly packed elements of `size` bytes at `offset` in `data`.
fn checked_range<'d>(data: &'d [u8], offset: u64, count: u64, size: u64, what: &str) -> Result<&'d [u8], ImportError> {
    let end = count
        .checked_mul(size)
        .and_then(|x| x.checked_add(offset))
        .filter(|&end| end <= data.len() as u64)
        .ok_or_else(|| ImportError::Invalid(format!("{what}: sparse data lies outside its buffer view")))?;
    Ok(&data[offset as usize..end as usize])
}

/// The local transform of a node.
fn local_transform(node: &json::Node) -> Mat4 {
    if let Some(m) = node.matrix {
        return Mat4::from_cols_array(&m);
    }
    let t = node.translation.map_or(Vec3::ZERO, Vec3::from);
    let s = node.scale.map_or(Vec3::ONE, Vec3::from);
    let r = node
        .rotation
        .map_or(Quat::IDENTITY, |q| Quat::from_array(q.0).normalize());
    Mat4::from_scale_rotation_translation(s, r, t)
}

fn mode_name(mode: Mode) -> Option<&'static str> {
    match mode {
        Mode::Points => Some("POINTS"),
        Mode::Lines => Some("LINES"),
        Mode::LineLoop => Some("LINE_LOOP"),
        Mode::LineStrip => Some("LINE_STRIP"),
        Mode::Triangles | Mode::TriangleStrip | Mode::TriangleFan => None,
    }
}

/// A parsed document with its buffers resolved: every primitive placed by
/// the scene's nodes, in world space, scaled by `scale`.
pub(crate) fn read_document(
    bytes: &[u8],
    base_dir: Option<&Path>,
    scale: f32,
) -> Result<Vec<PlacedPrimitive>, ImportError> {
    let (json_bytes, bin) = split_glb(bytes)?;
    let root: json::Root = json::deserialize::from_slice(json_bytes).map_err(|e| ImportError::Json(e.to_string()))?;
    for required in &root.extensions_required {
        if required != "KHR_mesh_quantization" && required != "KHR_materials_unlit" {
            return Err(ImportError::Unsupported(format!(
                "the file requires the glTF extension {required}, which this importer does not read"
            )));
        }
    }
    let roots = scene_roots(&root)?;
    let mut reader = Reader {
        root: &root,
        buffers: Buffers {
            root: &root,
            bin,
            base_dir,
            loaded: HashMap::new(),
        },
        unbacked_limit: 0,
    };
    reader.unbacked_limit = 16 * bytes.len() as u64 + 1024;
    let scale_matrix = Mat4::from_scale(Vec3::splat(scale));

    // Depth-first over the node trees, with cycle and depth checks.
    let mut placed = Vec::new();
    let mut cache: HashMap<(usize, usize), MeshData> = HashMap::new();
    let mut total_vertices = 0u64;
    let mut on_path = vec![false; root.nodes.len()];
    let mut stack: Vec<(usize, Mat4, usize, bool)> = roots.iter().rev().map(|&n| (n, scale_matrix, 0, false)).collect();
    while let Some((node_index, parent, depth, leaving)) = stack.pop() {
        if leaving {
            on_path[node_index] = false;
            continue;
        }
        let node = root
            .nodes
            .get(node_index)
            .ok_or_else(|| ImportError::Invalid(format!("node {node_index} does not exist")))?;
        if on_path[node_index] {
            return Err(ImportError::Invalid(format!(
                "node {node_index} is its own ancestor (a cycle)"
            )));
        }
        if depth > MAX_NODE_DEPTH {
            return Err(ImportError::Invalid(format!(
                "the node hierarchy is deeper than {MAX_NODE_DEPTH}"
            )));
        }
        let world = parent * local_transform(node);
        if !world.is_finite() {
            return Err(ImportError::Invalid(format!(
                "node {node_index} has a non-finite transform"
            )));
        }
        if let Some(mesh_index) = node.mesh {
            let mesh_index = mesh_index.value();
            let mesh = root
                .meshes
                .get(mesh_index)
                .ok_or_else(|| ImportError::Invalid(format!("node {node_index}: mesh {mesh_index} does not exist")))?;
            for (p, primitive) in mesh.primitives.iter().enumerate() {
                let data = match cache.entry((mesh_index, p)) {
                    std::collections::hash_map::Entry::Occupied(entry) => entry.into_mut(),
                    std::collections::hash_map::Entry::Vacant(entry) => {
                        entry.insert(read_primitive(&mut reader, primitive, mesh_index, p)?)
                    }
                };
                total_vertices += data.positions.len() as u64;
                if total_vertices > MAX_TOTAL_VERTICES {
                    return Err(ImportError::Invalid(format!(
                        "the scene places more than {MAX_TOTAL_VERTICES} vertices (instancing)"
                    )));
                }
                let material_name = primitive
                    .material
                    .and_then(|m| root.materials.get(m.value()))
                    .and_then(|m| m.name.clone())
                    .unwrap_or_default();
                placed.push(data.place(world, node_index, node, mesh_index, mesh, p, material_name));
            }
        }
        on_path[node_index] = true;
        stack.push((node_index, world, depth, true));
        for child in node.children.iter().flatten().rev() {
            stack.push((child.value(), world, depth + 1, false));
        }
    }
    Ok(placed)
}

/// The root nodes to place: the default scene's; the only scene's; or,
/// with several scenes and no default (or none at all), every node that is
/// no other node's child.
fn scene_roots(root: &json::Root) -> Result<Vec<usize>, ImportError> {
    let scene = match root.scene {
        Some(s) => Some(
            root.scenes
                .get(s.value())
                .ok_or_else(|| ImportError::Invalid(format!("the default scene {} does not exist", s.value())))?,
        ),
        None if root.scenes.len() == 1 => root.scenes.first(),
        None => None,
    };
    if let Some(scene) = scene {
        return Ok(scene.nodes.iter().map(|n| n.value()).collect());
    }
    let mut is_child = vec![false; root.nodes.len()];
    for node in &root.nodes {
        for child in node.children.iter().flatten() {
            if let Some(flag) = is_child.get_mut(child.value()) {
                *flag = true;
            }
        }
    }
    let roots: Vec<usize> = (0..root.nodes.len()).filter(|&n| !is_child[n]).collect();
    if roots.is_empty() && !root.nodes.is_empty() {
        return Err(ImportError::Invalid(
            "every node is some node's child: the hierarchy has a cycle".into(),
        ));
    }
    Ok(roots)
}

/// A primitive's data in its mesh's own space.
struct MeshData {
    positions: Vec<Vec3>,
    normals: Option<Vec<Vec3>>,
    triangles: Vec<[u32; 3]>,
    groups: Option<Vec<i64>>,
    non_triangle_mode: Option<&'static str>,
}

impl MeshData {
    #[allow(clippy::too_many_arguments)]
    fn place(
        &self,
        world: Mat4,
        node_index: usize,
        node: &json::Node,
        mesh_index: usize,
        mesh: &json::Mesh,
        primitive: usize,
        material_name: String,
    ) -> PlacedPrimitive {
        let linear = Mat3::from_mat4(world);
        let normal_matrix = linear.inverse().transpose();
        let mirrored = linear.determinant() < 0.0;
        PlacedPrimitive {
            node: node_index,
            node_name: node.name.clone().unwrap_or_default(),
            mesh_name: mesh.name.clone().unwrap_or_default(),
            material_name,
            mesh: mesh_index,
            primitive,
            world,
            positions: self.positions.iter().map(|&p| world.transform_point3(p)).collect(),
            normals: self
                .normals
                .as_ref()
                .filter(|_| normal_matrix.is_finite())
                .map(|ns| ns.iter().map(|&n| (normal_matrix * n).normalize_or_zero()).collect()),
            triangles: if mirrored {
                self.triangles.iter().map(|&[a, b, c]| [a, c, b]).collect()
            } else {
                self.triangles.clone()
            },
            groups: self.groups.clone(),
            non_triangle_mode: self.non_triangle_mode,
        }
    }
}

fn read_primitive(
    reader: &mut Reader,
    primitive: &json::mesh::Primitive,
    mesh: usize,
    p: usize,
) -> Result<MeshData, ImportError> {
    let what = format!("mesh {mesh} primitive {p}");
    let Checked::Valid(mode) = primitive.mode else {
        return Err(ImportError::Invalid(format!("{what} has an unknown primitive mode")));
    };
    let mut position = None;
    let mut normal = None;
    let mut group = None;
    for (semantic, accessor) in &primitive.attributes {
        match semantic {
            Checked::Valid(Semantic::Positions) => position = Some(accessor.value()),
            Checked::Valid(Semantic::Normals) => normal = Some(accessor.value()),
            Checked::Valid(Semantic::Extras(name))
                if GROUP_ATTRIBUTES.iter().any(|g| g.eq_ignore_ascii_case(name)) && group.is_none() =>
            {
                group = Some(accessor.value())
            }
            _ => {}
        }
    }
    let Some(position) = position else {
        return Err(ImportError::Invalid(format!("{what} has no POSITION attribute")));
    };
    let (values, _) = reader.read(position, Use::Vec3, &format!("{what} POSITION"))?;
    let positions: Vec<Vec3> = values
        .chunks_exact(3)
        .map(|c| Vec3::new(c[0] as f32, c[1] as f32, c[2] as f32))
        .collect();
    let vertex_count = positions.len();
    let normals = match normal {
        Some(a) => {
            let (values, _) = reader.read(a, Use::Vec3, &format!("{what} NORMAL"))?;
            if values.len() != values.len() / 3 * 3 || values.len() / 3 != vertex_count {
                return Err(ImportError::Invalid(format!(
                    "{what}: NORMAL and POSITION counts differ"
                )));
            }
            Some(
                values
                    .chunks_exact(3)
                    .map(|c| Vec3::new(c[0] as f32, c[1] as f32, c[2] as f32))
                    .collect(),
            )
        }
        None => None,
    };
    let groups = match group {
        Some(a) => {
            let (values, _) = reader.read(a, Use::Scalar, &format!("{what} group attribute"))?;
            if values.len() != vertex_count {
                return Err(ImportError::Invalid(format!(
                    "{what}: group attribute and POSITION counts differ"
                )));
            }
            Some(
                values
                    .iter()
                    .map(|v| {
                        if v.is_finite() {
                            v.round().clamp(-9e15, 9e15) as i64
                        } else {
                            i64::MIN
                        }
                    })
                    .collect(),
            )
        }
        None => None,
    };
    if let Some(name) = mode_name(mode) {
        return Ok(MeshData {
            positions,
            normals,
            triangles: Vec::new(),
            groups,
            non_triangle_mode: Some(name),
        });
    }
    let indices: Vec<u32> = match primitive.indices {
        Some(a) => {
            let (values, _) = reader.read(a.value(), Use::Indices, &format!("{what} indices"))?;
            let mut indices = Vec::with_capacity(values.len());
            for v in values {
                if v >= vertex_count as f64 {
                    return Err(ImportError::Invalid(format!(
                        "{what}: index {v} is out of range ({vertex_count} vertices)"
                    )));
                }
                indices.push(v as u32);
            }
            indices
        }
        None => (0..vertex_count as u32).collect(),
    };
    let triangles = match mode {
        Mode::Triangles => indices.chunks_exact(3).map(|t| [t[0], t[1], t[2]]).collect(),
        Mode::TriangleStrip => (2..indices.len())
            .map(|k| {
                if k % 2 == 0 {
                    [indices[k - 2], indices[k - 1], indices[k]]
                } else {
                    [indices[k - 1], indices[k - 2], indices[k]]
                }
            })
            .collect(),
        _ => (2..indices.len())
            .map(|k| [indices[0], indices[k - 1], indices[k]])
            .collect(),
    };
    Ok(MeshData {
        positions,
        normals,
        triangles,
        groups,
        non_triangle_mode: None,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn glb_headers_are_checked() {
        assert!(matches!(split_glb(b"hello"), Err(ImportError::NotGltf)));
        assert!(matches!(split_glb(b"glT"), Err(ImportError::Truncated(_))));
        assert!(matches!(split_glb(b"glTF\x02\0\0\0"), Err(ImportError::Truncated(_))));
        let mut glb = b"glTF\x02\0\0\0\x14\0\0\0".to_vec();
        glb.extend_from_slice(&[0, 0, 0, 0, 0x4A, 0x53, 0x4F, 0x4E]);
        assert!(split_glb(&glb).is_ok());
        glb[8] = 0xFF;
        assert!(matches!(split_glb(&glb), Err(ImportError::Truncated(_))));
        assert!(matches!(split_glb(b"  {\"asset\":{}}"), Ok((_, None))));
    }

    #[test]
    fn percent_decoding() {
        assert_eq!(percent_decode("my%20tree.bin"), "my tree.bin");
        assert_eq!(percent_decode("100%"), "100%");
        assert_eq!(percent_decode("%zz"), "%zz");
    }
}
