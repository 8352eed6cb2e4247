//! Writing glTF 2.0 binary files (GLB): the cut of a record at a spatial
//! error, so LOD levels can be looked at in any glTF viewer or used by other
//! engines ([`encode_cut_glb`]), and a tree's input — needles as thin quads,
//! wood as cylinders — for round trips and test trees ([`encode_tree_glb`]).
//!
//! A cut is written as:
//!
//! * mesh `prisms`: each needle drawn as a prism, as triangles with smooth
//!   normals, side count as the cut says (material `needles`, opaque);
//! * mesh `lines`: the original and merged lines as a `LINES` primitive with
//!   `NORMAL` (the needles' normals) and `COLOR_0` (RGBA float): the needle
//!   colour and, in alpha, the line's opacity — `δ · 2R/e` for an original
//!   line (the paper's `δ · 2/ρ`), `δ · Σ(2R·L)/(length · e)` for a merged
//!   line (its needles' side area over the line's one-pixel-wide area),
//!   both capped at 1 (material `lines`, blended);
//! * mesh `wood`: the record's wood mesh and its wood segments as 8-sided
//!   cylinders (material `bark`).
//!
//! Empty meshes are left out. Every file is written to a temporary file
//! beside the target and renamed into place.

use crate::model::file::write_atomically;
use crate::model::metric::{line_opacity, relative_error};
use crate::model::prism::{TriangleMesh, append_prism};
use crate::model::{LodRecord, Needle, TreeInput, WoodSegment};
use glam::Vec3;
use std::fmt::Write as _;
use std::path::Path;

/// Sides of the cylinders standing for wood segments.
const WOOD_SIDES: u8 = 8;

/// Builds a GLB: one buffer (the binary chunk), views, accessors, meshes,
/// one node per mesh, one scene.
#[derive(Default)]
struct GlbBuilder {
    bin: Vec<u8>,
    views: Vec<String>,
    accessors: Vec<String>,
    materials: Vec<String>,
    meshes: Vec<String>,
    mesh_names: Vec<String>,
}

/// A JSON string literal.
fn quoted(s: &str) -> String {
    gltf::json::serialize::to_string(s).unwrap_or_else(|_| "\"\"".into())
}

/// A finite float for JSON.
fn number(x: f32) -> String {
    if x.is_finite() { format!("{x:?}") } else { "0.0".into() }
}

impl GlbBuilder {
    fn view(&mut self, bytes: &[u8], target: u32) -> usize {
        while !self.bin.len().is_multiple_of(4) {
            self.bin.push(0);
        }
        self.views.push(format!(
            r#"{{"buffer":0,"byteOffset":{},"byteLength":{},"target":{target}}}"#,
            self.bin.len(),
            bytes.len()
        ));
        self.bin.extend_from_slice(bytes);
        self.views.len() - 1
    }

    fn vec3(&mut self, data: &[Vec3]) -> usize {
        let bytes: Vec<u8> = data
            .iter()
            .flat_map(|v| v.to_array())
            .flat_map(f32::to_le_bytes)
            .collect();
        let view = self.view(&bytes, 34962);
        let (lo, hi) = data.iter().fold(
            (Vec3::splat(f32::INFINITY), Vec3::splat(f32::NEG_INFINITY)),
            |(lo, hi), &p| (lo.min(p), hi.max(p)),
        );
        let list = |v: Vec3| format!("[{},{},{}]", number(v.x), number(v.y), number(v.z));
        self.accessors.push(format!(
            r#"{{"bufferView":{view},"componentType":5126,"count":{},"type":"VEC3","min":{},"max":{}}}"#,
            data.len(),
            list(lo),
            list(hi)
        ));
        self.accessors.len() - 1
    }

    fn vec4(&mut self, data: &[[f32; 4]]) -> usize {
        let bytes: Vec<u8> = data.iter().flatten().flat_map(|x| x.to_le_bytes()).collect();
        let view = self.view(&bytes, 34962);
        self.accessors.push(format!(
            r#"{{"bufferView":{view},"componentType":5126,"count":{},"type":"VEC4"}}"#,
            data.len()
        ));
        self.accessors.len() - 1
    }

    fn scalar_u32(&mut self, data: &[u32], target: Option<u32>) -> usize {
        let bytes: Vec<u8> = data.iter().flat_map(|x| x.to_le_bytes()).collect();
        let view = self.view(&bytes, target.unwrap_or(34962));
        self.accessors.push(format!(
            r#"{{"bufferView":{view},"componentType":5125,"count":{},"type":"SCALAR"}}"#,
            data.len()
        ));
        self.accessors.len() - 1
    }

    fn material(&mut self, name: &str, color: [f32; 4], roughness: f32, blend: bool) -> usize {
        let [r, g, b, a] = color.map(|c| number(c.clamp(0.0, 1.0)));
        self.materials.push(format!(
            r#"{{"name":{},"pbrMetallicRoughness":{{"baseColorFactor":[{r},{g},{b},{a}],"metallicFactor":0.0,"roughnessFactor":{}}},"doubleSided":true{}}}"#,
            quoted(name),
            number(roughness.clamp(0.0, 1.0)),
            if blend { r#","alphaMode":"BLEND""# } else { "" }
        ));
        self.materials.len() - 1
    }

    /// A triangle mesh (with optional per-vertex group ids) as mesh `name`.
    fn triangles(&mut self, name: &str, mesh: &TriangleMesh, material: usize, groups: Option<&[u32]>) {
        if mesh.indices.is_empty() {
            return;
        }
        let position = self.vec3(&mesh.positions);
        let normal = self.vec3(&mesh.normals);
        let indices = self.scalar_u32(&mesh.indices, Some(34963));
        let group = groups
            .map(|g| format!(r#","_GROUP":{}"#, self.scalar_u32(g, None)))
            .unwrap_or_default();
        self.meshes.push(format!(
            r#"{{"name":{},"primitives":[{{"attributes":{{"POSITION":{position},"NORMAL":{normal}{group}}},"indices":{indices},"material":{material},"mode":4}}]}}"#,
            quoted(name)
        ));
        self.mesh_names.push(name.to_string());
    }

    /// Line segments (vertex pairs) with normals and RGBA colours.
    fn lines(&mut self, name: &str, positions: &[Vec3], normals: &[Vec3], colors: &[[f32; 4]], material: usize) {
        if positions.is_empty() {
            return;
        }
        let position = self.vec3(positions);
        let normal = self.vec3(normals);
        let color = self.vec4(colors);
        self.meshes.push(format!(
            r#"{{"name":{},"primitives":[{{"attributes":{{"POSITION":{position},"NORMAL":{normal},"COLOR_0":{color}}},"material":{material},"mode":1}}]}}"#,
            quoted(name)
        ));
        self.mesh_names.push(name.to_string());
    }

    fn finish(mut self, generator: &str) -> Vec<u8> {
        while !self.bin.len().is_multiple_of(4) {
            self.bin.push(0);
        }
        let nodes: Vec<String> = self
            .mesh_names
            .iter()
            .enumerate()
            .map(|(k, name)| format!(r#"{{"name":{},"mesh":{k}}}"#, quoted(name)))
            .collect();
        let roots: Vec<String> = (0..nodes.len()).map(|k| k.to_string()).collect();
        let mut json = format!(
            r#"{{"asset":{{"version":"2.0","generator":{}}},"scene":0,"scenes":[{{"nodes":[{}]}}]"#,
            quoted(generator),
            roots.join(",")
        );
        let mut array = |key: &str, items: &[String]| {
            if !items.is_empty() {
                let _ = write!(json, r#","{key}":[{}]"#, items.join(","));
            }
        };
        array("nodes", &nodes);
        array("meshes", &self.meshes);
        array("materials", &self.materials);
        array("accessors", &self.accessors);
        array("bufferViews", &self.views);
        if !self.bin.is_empty() {
            let _ = write!(json, r#","buffers":[{{"byteLength":{}}}]"#, self.bin.len());
        }
        json.push('}');
        while !json.len().is_multiple_of(4) {
            json.push(' ');
        }
        let total = 12 + 8 + json.len() + if self.bin.is_empty() { 0 } else { 8 + self.bin.len() };
        let mut out = Vec::with_capacity(total);
        out.extend_from_slice(b"glTF");
        out.extend_from_slice(&2u32.to_le_bytes());
        out.extend_from_slice(&(total as u32).to_le_bytes());
        out.extend_from_slice(&(json.len() as u32).to_le_bytes());
        out.extend_from_slice(b"JSON");
        out.extend_from_slice(json.as_bytes());
        if !self.bin.is_empty() {
            out.extend_from_slice(&(self.bin.len() as u32).to_le_bytes());
            out.extend_from_slice(b"BIN\0");
            out.extend_from_slice(&self.bin);
        }
        out
    }
}

/// Appends an open cylinder (a truncated cone) for a wood segment.
fn append_wood(mesh: &mut TriangleMesh, segment: &WoodSegment) {
    let Some(axis) = (segment.end - segment.start).try_normalize() else {
        return;
    };
    let u = axis.any_orthonormal_vector();
    let v = axis.cross(u);
    let m = WOOD_SIDES as u32;
    let first = mesh.positions.len() as u32;
    for (centre, radius) in [(segment.start, segment.start_radius), (segment.end, segment.end_radius)] {
        for k in 0..m {
            let angle = std::f32::consts::TAU * k as f32 / m as f32;
            let radial = u * angle.cos() + v * angle.sin();
            mesh.positions.push(centre + radial * radius);
            mesh.normals.push(radial);
        }
    }
    for k in 0..m {
        let next = (k + 1) % m;
        let (b0, b1, t0, t1) = (first + k, first + next, first + m + k, first + m + next);
        mesh.indices.extend_from_slice(&[b0, b1, t1, b0, t1, t0]);
    }
}

/// Appends a needle as a flat quad of width `2R` in the plane whose normal
/// is the needle's (four vertices of its own, base edge first).
fn append_needle_quad(mesh: &mut TriangleMesh, needle: &Needle) {
    let axis = (needle.tip - needle.base).normalize_or_zero();
    let across = needle.normal.cross(axis).normalize_or(axis.any_orthonormal_vector()) * needle.radius;
    let normal = axis.cross(across).normalize_or(needle.normal);
    let first = mesh.positions.len() as u32;
    mesh.positions.extend_from_slice(&[
        needle.base - across,
        needle.tip - across,
        needle.tip + across,
        needle.base + across,
    ]);
    mesh.normals.extend_from_slice(&[normal; 4]);
    mesh.indices
        .extend_from_slice(&[first, first + 1, first + 2, first, first + 2, first + 3]);
}

/// How to write a tree's input.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct TreeGlbOptions {
    /// Write each needle's group as a per-vertex `_GROUP` attribute.
    pub groups: bool,
}

/// A tree's input as GLB bytes: needles as thin quads of width `2R` in mesh
/// `needles`, wood (segments as cylinders, plus any wood mesh) in mesh
/// `wood`.
pub fn encode_tree_glb(tree: &TreeInput, options: &TreeGlbOptions) -> Vec<u8> {
    let mut builder = GlbBuilder::default();
    let needles_material = builder.material("needles", tree.material.needle_color, tree.material.roughness, false);
    let bark = builder.material("bark", tree.material.wood_color, 0.9, false);
    let mut quads = TriangleMesh::default();
    let mut groups = Vec::new();
    for needle in tree.needles.iter().filter(|n| n.is_valid()) {
        append_needle_quad(&mut quads, needle);
        groups.extend_from_slice(&[needle.group; 4]);
    }
    builder.triangles(
        "needles",
        &quads,
        needles_material,
        options.groups.then_some(&groups[..]),
    );
    let mut wood = tree.wood_mesh.clone();
    for segment in &tree.wood {
        append_wood(&mut wood, segment);
    }
    builder.triangles("wood", &wood, bark, None);
    builder.finish("bevy_conifer_lod tree input")
}

/// [`encode_tree_glb`] written atomically to `path`.
pub fn write_tree_glb(tree: &TreeInput, options: &TreeGlbOptions, path: &Path) -> std::io::Result<u64> {
    let bytes = encode_tree_glb(tree, options);
    write_atomically(path, &bytes)?;
    Ok(bytes.len() as u64)
}

/// What a cut export holds.
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize)]
pub struct CutExport {
    /// The spatial error of the cut, metres.
    pub spatial_error: f32,
    /// Needles drawn as prisms.
    pub prisms: usize,
    /// Prism triangles written.
    pub prism_triangles: usize,
    /// Original lines written.
    pub lines_original: usize,
    /// Merged lines written.
    pub lines_merged: usize,
    /// Wood triangles written.
    pub wood_triangles: usize,
    /// Bytes of the GLB.
    pub bytes: usize,
}

/// The cut of `record` at `spatial_error` (metres) as GLB bytes (see the
/// module docs); `transition` is δ.
pub fn encode_cut_glb(record: &LodRecord, spatial_error: f32, transition: f32) -> (Vec<u8>, CutExport) {
    let e = if spatial_error > 0.0 { spatial_error } else { 0.0 };
    let cut = record.cut(e);
    let mut builder = GlbBuilder::default();
    let m = &record.material;
    let needles_material = builder.material("needles", m.needle_color, m.roughness, false);
    let lines_material = builder.material("lines", m.needle_color, m.roughness, true);
    let bark = builder.material("bark", m.wood_color, 0.9, false);

    let mut prisms = TriangleMesh::default();
    for &(needle, sides) in &cut.prisms {
        append_prism(&mut prisms, &record.needles[needle as usize], sides);
    }
    builder.triangles("prisms", &prisms, needles_material, None);

    let [r, g, b, _] = m.needle_color;
    let (mut positions, mut normals, mut colors) = (Vec::new(), Vec::new(), Vec::new());
    let transition = transition.clamp(0.0, 1.0);
    for &needle in &cut.original_lines {
        let n = &record.needles[needle as usize];
        let alpha = line_opacity(relative_error(e, n.radius), transition);
        positions.extend_from_slice(&[n.base, n.tip]);
        normals.extend_from_slice(&[n.normal, n.normal]);
        colors.extend_from_slice(&[[r, g, b, alpha]; 2]);
    }
    for &node in &cut.merged_lines {
        let [(a, na), (b2, nb)] = record.node_ends(node);
        let length = a.distance(b2).max(1e-6);
        let alpha = if e > 0.0 {
            (transition * record.node_needle_area(node) / (length * e)).min(1.0)
        } else {
            transition
        };
        positions.extend_from_slice(&[a, b2]);
        normals.extend_from_slice(&[na, nb]);
        colors.extend_from_slice(&[[r, g, b, alpha]; 2]);
    }
    builder.lines("lines", &positions, &normals, &colors, lines_material);

    let mut wood = record.wood_mesh.clone();
    for segment in &record.wood {
        append_wood(&mut wood, segment);
    }
    builder.triangles("wood", &wood, bark, None);

    let bytes = builder.finish("bevy_conifer_lod cut");
    let report = CutExport {
        spatial_error: e,
        prisms: cut.prisms.len(),
        prism_triangles: prisms.triangle_count(),
        lines_original: cut.original_lines.len(),
        lines_merged: cut.merged_lines.len(),
        wood_triangles: wood.triangle_count(),
        bytes: bytes.len(),
    };
    (bytes, report)
}

/// [`encode_cut_glb`] written atomically to `path`.
pub fn write_cut_glb(
    record: &LodRecord,
    spatial_error: f32,
    transition: f32,
    path: &Path,
) -> std::io::Result<CutExport> {
    let (bytes, report) = encode_cut_glb(record, spatial_error, transition);
    write_atomically(path, &bytes)?;
    Ok(report)
}
