//! Importing trees from glTF 2.0 files (`.glb`, or `.gltf` with its
//! buffers): needles become the paper's input, everything else is kept as
//! the wood mesh.
//!
//! * Needle geometry: the primitives whose node, mesh or material name
//!   contains `leaf`, `leaves`, `needle` or `foliage` (any case), or, when
//!   [`ImportOptions::needle_names`] is given, whose node, mesh or material
//!   name matches one of them (any case, `*` matches any run of characters).
//!   Every other triangle primitive is wood.
//! * Needles: split into edge-connected pieces,
//!   each fitted with a centerline, a radius (half its width) and a normal;
//!   degenerate pieces are counted in [`SkipCounts`] and skipped.
//! * Groups: a per-vertex attribute `_GROUP` (or `_SHOOT`, `_FASCICLE`,
//!   `_TWIG`; any numeric type; ids count within one placed mesh) when every
//!   needle primitive has one; else one group per placed needle primitive
//!   when there are several and none holds more than
//!   [`INSTANCE_GROUP_LIMIT`] needles (one node or primitive per shoot);
//!   else inferred by [`groups::infer_groups`].
//! * Scene: the default scene, else the only one, else every root node;
//!   node transforms (TRS or matrix) applied, meshes placed by several nodes
//!   placed each time, mirrored placements keep their winding.
//! * Units: glTF metres, times [`ImportOptions::scale`].
//!
//! Nothing in the file is trusted: every index, length and range is checked
//! before it is used, and a malformed file is an [`ImportError`], never a
//! panic or an allocation out of proportion to the file.

mod gltf;
pub mod groups;
mod instances;
mod needles;

pub use self::gltf::GROUP_ATTRIBUTES;
pub use groups::{GroupAgreement, GroupInferenceInfo, GroupRule, group_agreement, infer_groups};
pub use needles::OrientStats;

use crate::model::prism::TriangleMesh;
use crate::model::{FoliageMaterial, PrototypeInput, TreeInput};
use glam::Vec3;
use serde::Serialize;
use std::collections::HashMap;
use std::path::Path;

/// Most needles a placed primitive may hold for placed primitives to be
/// taken as the groups.
pub const INSTANCE_GROUP_LIMIT: usize = 1024;

/// Name fragments that mark needle geometry by default.
pub const NEEDLE_WORDS: [&str; 4] = ["leaf", "leaves", "needle", "foliage"];

/// Why a file could not be imported.
#[derive(Debug, thiserror::Error)]
pub enum ImportError {
    /// The file could not be read.
    #[error("cannot read the file: {0}")]
    Io(#[from] std::io::Error),
    /// Neither GLB nor glTF JSON.
    #[error("not a glTF file (no GLB header, no JSON object)")]
    NotGltf,
    /// The file ends before its own lengths say it does.
    #[error("truncated glTF: {0}")]
    Truncated(String),
    /// The JSON does not parse as a glTF document.
    #[error("malformed glTF JSON: {0}")]
    Json(String),
    /// The document contradicts itself (an index or range out of bounds...).
    #[error("invalid glTF: {0}")]
    Invalid(String),
    /// Valid glTF this importer does not read.
    #[error("unsupported glTF: {0}")]
    Unsupported(String),
    /// An external buffer could not be read.
    #[error("missing external buffer {uri}: {reason}")]
    MissingBuffer {
        /// The buffer's path or URI.
        uri: String,
        /// Why it could not be read.
        reason: String,
    },
    /// A needle primitive is made of points or lines.
    #[error("{primitive} holds needle geometry but is {mode}, not triangles")]
    NonTriangle {
        /// Which primitive.
        primitive: String,
        /// Its mode.
        mode: &'static str,
    },
    /// Nothing needle-like was found.
    #[error("no needle geometry: {0}")]
    NoNeedles(String),
    /// `scale` is not a finite positive number.
    #[error("the scale must be a finite number > 0, got {0}")]
    BadScale(f32),
}

/// How to import.
#[derive(Clone, Debug, PartialEq)]
pub struct ImportOptions {
    /// Node, mesh or material names of the needle geometry (any case, `*`
    /// wildcards); empty: by [`NEEDLE_WORDS`].
    pub needle_names: Vec<String>,
    /// Metres per file unit (glTF is in metres: 1).
    pub scale: f32,
    /// The group rule, where groups are inferred.
    pub group_rule: GroupRule,
}

impl Default for ImportOptions {
    fn default() -> Self {
        Self {
            needle_names: Vec::new(),
            scale: 1.0,
            group_rule: GroupRule::default(),
        }
    }
}

/// Pieces of needle geometry that were not needles.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize)]
pub struct SkipCounts {
    /// Triangles with a NaN or infinite coordinate.
    pub non_finite: usize,
    /// Pieces of zero area.
    pub zero_area: usize,
    /// Pieces with a zero-length centerline or zero width.
    pub degenerate: usize,
    /// Pieces at least as wide as long.
    pub not_elongated: usize,
}

impl SkipCounts {
    /// All skipped pieces.
    pub fn total(&self) -> usize {
        self.non_finite + self.zero_area + self.degenerate + self.not_elongated
    }
}

/// Where the groups came from.
#[derive(Clone, Debug, PartialEq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum GroupSource {
    /// A per-vertex attribute of this name.
    Attribute(String),
    /// One group per placed needle primitive.
    Primitives,
    /// Inferred by the group rule.
    Inferred(GroupInferenceInfo),
}

/// Smallest, median and largest.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize)]
pub struct Spread {
    /// Smallest.
    pub min: f64,
    /// Median (the lower one for an even count).
    pub median: f64,
    /// Largest.
    pub max: f64,
}

impl Spread {
    /// Of `values` (all zero when empty).
    pub fn of(mut values: Vec<f64>) -> Self {
        if values.is_empty() {
            return Self::default();
        }
        values.sort_by(f64::total_cmp);
        Self {
            min: values[0],
            median: values[(values.len() - 1) / 2],
            max: values[values.len() - 1],
        }
    }
}

/// What an import found.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct ImportReport {
    /// The placed primitives read as needle geometry.
    pub needle_primitives: Vec<String>,
    /// Placed primitives kept as wood.
    pub wood_primitives: usize,
    /// Triangles of the wood mesh.
    pub wood_triangles: usize,
    /// Needles found.
    pub needles: usize,
    /// Pieces skipped, by reason.
    pub skipped: SkipCounts,
    /// How base and tip were told apart.
    pub orientation: OrientStats,
    /// Where the groups came from.
    pub group_source: GroupSource,
    /// Number of groups.
    pub groups: usize,
    /// Needles per group.
    pub group_size: Spread,
    /// Needle radius, metres.
    pub radius: Spread,
    /// Needle length, metres.
    pub length: Spread,
    /// Shared prototypes once instanced needle primitives are kept as one
    /// prototype placed many times ([`import_gltf_prototypes`]); equal to
    /// `groups` for [`import_gltf`], which places every group's own copy.
    pub prototypes: usize,
    /// Things the user should know (skipped primitives, fallbacks).
    pub warnings: Vec<String>,
}

/// The bytes of the glTF file at `path`, the folder its external buffers
/// are read from, and the tree's name (the file's stem).
fn read_gltf_file(path: &Path) -> Result<(Vec<u8>, &Path, String), ImportError> {
    let bytes = std::fs::read(path)?;
    let dir = path
        .parent()
        .filter(|d| !d.as_os_str().is_empty())
        .unwrap_or(Path::new("."));
    let name = path
        .file_stem()
        .map_or_else(|| "tree".to_string(), |s| s.to_string_lossy().into_owned());
    Ok((bytes, dir, name))
}

/// Imports the glTF file at `path` (external buffers are read beside it).
pub fn import_gltf(path: &Path, options: &ImportOptions) -> Result<(TreeInput, ImportReport), ImportError> {
    let (bytes, dir, name) = read_gltf_file(path)?;
    import_gltf_bytes(&bytes, Some(dir), &name, options)
}

/// Imports a glTF file from its bytes; external buffers are read from
/// `base_dir` (none: only GLB-embedded and `data:` buffers).
pub fn import_gltf_bytes(
    bytes: &[u8],
    base_dir: Option<&Path>,
    name: &str,
    options: &ImportOptions,
) -> Result<(TreeInput, ImportReport), ImportError> {
    import_parts(bytes, base_dir, name, options).map(|imported| (imported.tree, imported.report))
}

/// Imports the glTF file at `path` as prototypes: a needle primitive that
/// several nodes place (rotated, moved, uniformly scaled) becomes one
/// prototype placed by each, so the record holds its needles once. Groups,
/// needles and wood are those of [`import_gltf`].
pub fn import_gltf_prototypes(
    path: &Path,
    options: &ImportOptions,
) -> Result<(PrototypeInput, ImportReport), ImportError> {
    let (bytes, dir, name) = read_gltf_file(path)?;
    import_gltf_bytes_prototypes(&bytes, Some(dir), &name, options)
}

/// [`import_gltf_prototypes`] from a file's bytes (see [`import_gltf_bytes`]).
pub fn import_gltf_bytes_prototypes(
    bytes: &[u8],
    base_dir: Option<&Path>,
    name: &str,
    options: &ImportOptions,
) -> Result<(PrototypeInput, ImportReport), ImportError> {
    let Imported {
        tree,
        mut report,
        parts,
        part_of,
        group_values,
    } = import_parts(bytes, base_dir, name, options)?;
    let input = instances::share_instances(&tree, &parts, &part_of, &group_values);
    report.prototypes = input.prototypes.len();
    Ok((input, report))
}

/// What [`import_parts`] read: the tree, its report, and where each needle
/// came from (its placed primitive and group attribute value).
struct Imported {
    tree: TreeInput,
    report: ImportReport,
    parts: Vec<instances::PartInstance>,
    part_of: Vec<usize>,
    group_values: Vec<Option<i64>>,
}

fn import_parts(
    bytes: &[u8],
    base_dir: Option<&Path>,
    name: &str,
    options: &ImportOptions,
) -> Result<Imported, ImportError> {
    if !(options.scale.is_finite() && options.scale > 0.0) {
        return Err(ImportError::BadScale(options.scale));
    }
    let placed = gltf::read_document(bytes, base_dir, options.scale)?;
    let mut warnings = Vec::new();
    let (needle_parts, wood_parts): (Vec<_>, Vec<_>) = placed
        .into_iter()
        .partition(|p| is_needle_geometry(p, &options.needle_names));
    if needle_parts.is_empty() {
        let what = if options.needle_names.is_empty() {
            format!(
                "no node, mesh or material name contains {} (name them with --needles NAME)",
                NEEDLE_WORDS.join("/")
            )
        } else {
            format!(
                "no node, mesh or material is named {}",
                options.needle_names.join(" or ")
            )
        };
        return Err(ImportError::NoNeedles(what));
    }
    for part in &needle_parts {
        if let Some(mode) = part.non_triangle_mode {
            return Err(ImportError::NonTriangle {
                primitive: part.describe(),
                mode,
            });
        }
    }

    // Wood: every other triangle primitive, as one mesh.
    let mut wood_mesh = TriangleMesh::default();
    let mut wood_primitives = 0;
    for part in &wood_parts {
        if let Some(mode) = part.non_triangle_mode {
            warnings.push(format!("{} is {mode}: skipped", part.describe()));
            continue;
        }
        if part.positions.iter().any(|p| !p.is_finite()) {
            warnings.push(format!("{} has non-finite positions: skipped", part.describe()));
            continue;
        }
        wood_primitives += 1;
        wood_mesh.append(&wood_piece(part));
    }

    // Needles.
    let mut skipped = SkipCounts::default();
    let mut fitted = Vec::new();
    let mut part_of = Vec::new();
    for (k, part) in needle_parts.iter().enumerate() {
        let found = needles::fit_needles(&part.positions, &part.triangles, part.groups.as_deref(), &mut skipped);
        part_of.extend(std::iter::repeat_n(k, found.len()));
        fitted.extend(found);
    }
    if fitted.is_empty() {
        return Err(ImportError::NoNeedles(format!(
            "{} needle primitive(s) hold no needle-shaped pieces ({} skipped)",
            needle_parts.len(),
            skipped.total()
        )));
    }
    if skipped.total() > 0 {
        warnings.push(format!(
            "skipped {} pieces of needle geometry: {} non-finite, {} zero-area, {} degenerate, {} not elongated",
            skipped.total(),
            skipped.non_finite,
            skipped.zero_area,
            skipped.degenerate,
            skipped.not_elongated
        ));
    }
    let (mut needles, orientation) = needles::orient(&fitted, &wood_mesh.positions);

    // Groups.
    let all_attributed = needle_parts.iter().all(|p| p.groups.is_some());
    let mut per_part = vec![0usize; needle_parts.len()];
    for &k in &part_of {
        per_part[k] += 1;
    }
    let group_source = if all_attributed {
        let mut ids: HashMap<(usize, usize, i64), u32> = HashMap::new();
        for ((needle, f), &k) in needles.iter_mut().zip(&fitted).zip(&part_of) {
            let part = &needle_parts[k];
            let key = (part.node, part.mesh, f.group_value.unwrap_or(i64::MIN));
            let next = ids.len() as u32;
            needle.group = *ids.entry(key).or_insert(next);
        }
        GroupSource::Attribute(format!("_{}", GROUP_ATTRIBUTES[0]))
    } else if needle_parts.len() > 1 && per_part.iter().all(|&c| c <= INSTANCE_GROUP_LIMIT) {
        for (needle, &k) in needles.iter_mut().zip(&part_of) {
            needle.group = k as u32;
        }
        GroupSource::Primitives
    } else {
        if needle_parts.iter().any(|p| p.groups.is_some()) {
            warnings.push("only some needle primitives have a group attribute: groups inferred instead".into());
        }
        let (groups, info) = infer_groups(&needles, &options.group_rule);
        for (needle, g) in needles.iter_mut().zip(groups) {
            needle.group = g;
        }
        GroupSource::Inferred(info)
    };

    let mut sizes: HashMap<u32, usize> = HashMap::new();
    for needle in &needles {
        *sizes.entry(needle.group).or_default() += 1;
    }
    let report = ImportReport {
        needle_primitives: needle_parts.iter().map(|p| p.describe()).collect(),
        wood_primitives,
        wood_triangles: wood_mesh.triangle_count(),
        needles: needles.len(),
        skipped,
        orientation,
        group_source,
        groups: sizes.len(),
        group_size: Spread::of(sizes.values().map(|&s| s as f64).collect()),
        radius: Spread::of(needles.iter().map(|n| n.radius as f64).collect()),
        length: Spread::of(needles.iter().map(|n| n.length() as f64).collect()),
        prototypes: sizes.len(),
        warnings,
    };
    let tree = TreeInput {
        name: name.to_string(),
        needles,
        wood: Vec::new(),
        wood_mesh,
        material: FoliageMaterial::default(),
    };
    Ok(Imported {
        tree,
        report,
        parts: needle_parts
            .iter()
            .map(|p| instances::PartInstance {
                mesh: p.mesh,
                primitive: p.primitive,
                world: p.world,
            })
            .collect(),
        part_of,
        group_values: fitted.iter().map(|f| f.group_value).collect(),
    })
}

/// `true` when the primitive's node, mesh or material name marks it as
/// needle geometry.
fn is_needle_geometry(part: &gltf::PlacedPrimitive, names: &[String]) -> bool {
    let candidates = [&part.node_name, &part.mesh_name, &part.material_name];
    if names.is_empty() {
        candidates.iter().any(|c| {
            let lower = c.to_lowercase();
            NEEDLE_WORDS.iter().any(|w| lower.contains(w))
        })
    } else {
        candidates
            .iter()
            .any(|c| !c.is_empty() && names.iter().any(|n| glob_match(&n.to_lowercase(), &c.to_lowercase())))
    }
}

/// `pattern` with `*` wildcards matches the whole of `text`.
fn glob_match(pattern: &str, text: &str) -> bool {
    let parts: Vec<&str> = pattern.split('*').collect();
    if parts.len() == 1 {
        return pattern == text;
    }
    let (first, last) = (parts[0], parts[parts.len() - 1]);
    if !text.starts_with(first) || text.len() < first.len() + last.len() || !text.ends_with(last) {
        return false;
    }
    let mut rest = &text[first.len()..text.len() - last.len()];
    for middle in &parts[1..parts.len() - 1] {
        match rest.find(middle) {
            Some(at) => rest = &rest[at + middle.len()..],
            None => return false,
        }
    }
    true
}

/// A wood primitive as a mesh, with face normals where the file has none.
fn wood_piece(part: &gltf::PlacedPrimitive) -> TriangleMesh {
    let normals = match &part.normals {
        Some(normals) if normals.iter().all(|n| n.is_finite()) => normals.clone(),
        _ => {
            let mut normals = vec![Vec3::ZERO; part.positions.len()];
            for t in &part.triangles {
                let [a, b, c] = t.map(|i| part.positions[i as usize]);
                let face = (b - a).cross(c - a);
                if face.is_finite() {
                    for &i in t {
                        normals[i as usize] += face;
                    }
                }
            }
            normals.iter().map(|n| n.normalize_or_zero()).collect()
        }
    };
    TriangleMesh {
        positions: part.positions.clone(),
        normals,
        indices: part.triangles.iter().flatten().copied().collect(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn glob() {
        assert!(glob_match("leaves", "leaves"));
        assert!(glob_match("leaves*", "leaves.001"));
        assert!(glob_match("*needle*", "pine_needles_lod0"));
        assert!(!glob_match("*needle*", "pine_bark"));
        assert!(glob_match("a*b*c", "axxbyyc"));
        assert!(!glob_match("a*b*c", "ac"));
    }
}
