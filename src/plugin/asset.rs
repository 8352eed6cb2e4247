//! The species asset: a `.conifer` record turned into GPU-ready meshes.

use super::material::{ATTRIBUTE_LINE_LOD, ATTRIBUTE_PRISM_CODE};
use crate::model::compact::CompactSpecies;
use crate::model::gpu_layout::{
    BandErrors, LineBuffers, PrismBuffers, line_bands, merge_depths, prism_buffers, wood_prism_buffers,
    wood_segment_error,
};
use crate::model::prism::{TriangleMesh, append_wood_segment};
use crate::model::{LodRecord, PrototypeRecord, RecordError, WoodSegment, decode_prototype_record};
use bevy::asset::io::Reader;
use bevy::asset::{AssetLoader, LoadContext, RenderAssetUsages};
use bevy::camera::primitives::Aabb;
use bevy::mesh::{Indices, PrimitiveTopology};
use bevy::prelude::*;
use bevy::render::storage::ShaderBuffer;
use std::sync::Arc;

/// One tree species, loaded from a `.conifer` record: the record itself,
/// its compact GPU layout, and (once a tree is drawn by the mesh path) the
/// meshes every instance shares.
#[derive(Asset, TypePath, Debug, Clone)]
pub struct ConiferSpecies {
    /// The LOD record (merge forest, needles, errors), flattened.
    pub record: Arc<LodRecord>,
    /// The mesh path's meshes and buffers ([`RenderPath::Meshes`]): built
    /// the first frame a tree of the species is drawn by that path, never
    /// for a species only the compact path draws (a mature tree's would
    /// weigh hundreds of megabytes).
    ///
    /// [`RenderPath::Meshes`]: super::RenderPath::Meshes
    pub meshes: Option<SpeciesMeshHandles>,
    /// Largest wood segment error `2·r_max`: no wood prism is drawn at or
    /// above it.
    pub max_wood_error: f32,
    /// Tree-local bounds of needles and wood, widened by the largest needle radius.
    pub aabb: Aabb,
    /// Tree-local centre of the crown (where the viewing distance is measured to).
    pub crown_center: Vec3,
    /// Largest line error `2R`: no prism is drawn at or above it.
    pub max_line_error: f32,
    /// Smallest line error `2R`: no line is drawn below it.
    pub min_line_error: f32,
    /// Deepest merge level of the lines (0 without merged lines).
    pub max_merge_depth: u32,
    /// The record in the compact GPU layout of [`RenderPath::Compact`]
    /// (`None` when the record does not fit it: more than 8,388,608
    /// needles, or positions beyond 65 km); a tree of shared prototypes
    /// keeps them shared.
    ///
    /// [`RenderPath::Compact`]: super::RenderPath::Compact
    pub compact: Option<Arc<CompactSpecies>>,
}

/// The mesh path's shared meshes and buffers of a species.
#[derive(Debug, Clone)]
pub struct SpeciesMeshHandles {
    /// Every needle as an `Lmax`-slot prism (vertex codes; the needles are in
    /// `needles`). Drawn opaque.
    pub prisms: Handle<Mesh>,
    /// Every original and merged line (`LineList`), split into bands by
    /// parent error so a tree draws only the bands its cut can use. Drawn
    /// blended.
    pub lines: Vec<SpeciesLineBand>,
    /// Trunk and branches (the record's wood segments) as `Lmax`-slot
    /// tapered prisms, chosen per vertex like the needles: a segment is a
    /// prism while `e < 2·r_max`, then a fading wood line in `lines`.
    /// `None` without wood segments.
    pub wood_prisms: Option<Handle<Mesh>>,
    /// The wood segments for `wood_prisms`' vertex shader.
    pub wood_segments: Handle<ShaderBuffer>,
    /// Imported wood triangles (glTF trees), an ordinary mesh; `None` if
    /// the record has none.
    pub wood: Option<Handle<Mesh>>,
    /// Needle cylinders for the prism mesh's vertex shader.
    pub needles: Handle<ShaderBuffer>,
}

/// One band of a species' lines (see [`line_bands`]).
#[derive(Debug, Clone)]
pub struct SpeciesLineBand {
    /// The band's `LineList` mesh.
    pub mesh: Handle<Mesh>,
    /// The span of its lines' error intervals: whether it can draw at an error.
    pub errors: BandErrors,
}

/// Most line bands a species is split into.
pub const MAX_LINE_BANDS: usize = crate::model::gpu_layout::LINE_BANDS;

/// Why a `.conifer` file did not load as a [`ConiferSpecies`].
#[derive(Debug, thiserror::Error)]
pub enum ConiferLoadError {
    /// Reading the bytes failed.
    #[error("cannot read the record: {0}")]
    Io(#[from] std::io::Error),
    /// The bytes are not a valid record.
    #[error("invalid conifer record: {0}")]
    Record(#[from] RecordError),
    /// The record has more needles than the GPU layout addresses.
    #[error("record has {0} needles; the GPU layout holds at most 16,777,216")]
    TooManyNeedles(usize),
}

/// Loads `.conifer` records as [`ConiferSpecies`].
#[derive(Default, TypePath)]
pub struct ConiferRecordLoader;

impl AssetLoader for ConiferRecordLoader {
    type Asset = ConiferSpecies;
    type Settings = ();
    type Error = ConiferLoadError;

    async fn load(
        &self,
        reader: &mut dyn Reader,
        _settings: &(),
        _load_context: &mut LoadContext<'_>,
    ) -> Result<ConiferSpecies, ConiferLoadError> {
        let mut bytes = Vec::new();
        reader.read_to_end(&mut bytes).await?;
        // Shared prototypes stay shared on the compact path; the mesh path
        // and the CPU-side cut use the flattened tree.
        let prototypes = decode_prototype_record(&bytes)?;
        ConiferSpecies::from_prototype_record(&prototypes)
    }

    fn extensions(&self) -> &[&str] {
        &["conifer"]
    }
}

impl ConiferSpecies {
    /// A species from a record made in code (e.g. baked at build time or
    /// at startup). Add it to `Assets<ConiferSpecies>` and spawn
    /// [`super::ConiferFoliage`] with the handle.
    pub fn from_record(record: LodRecord) -> Result<Self, ConiferLoadError> {
        Self::new(record, None)
    }

    /// A species from a tree of shared prototypes made in code (e.g.
    /// [`crate::model::bake_prototypes`] of
    /// [`crate::generate::generate_prototypes`]), as
    /// [`ConiferSpecies::from_record`]; the compact path keeps its
    /// prototypes shared.
    pub fn from_prototype_record(record: &PrototypeRecord) -> Result<Self, ConiferLoadError> {
        let flat = record.flatten().map_err(RecordError::from)?;
        Self::new(flat, Some(record))
    }

    fn new(record: LodRecord, prototypes: Option<&PrototypeRecord>) -> Result<Self, ConiferLoadError> {
        let ranges = record.part_ranges();
        let (lo, hi) = record.bounds();
        let margin = Vec3::splat(ranges.original_lines.max * 0.5);
        let compact = match prototypes.map_or_else(
            || CompactSpecies::build(&record),
            |prototypes| CompactSpecies::build_placed(prototypes, &record),
        ) {
            Ok(compact) => Some(Arc::new(compact)),
            Err(error) => {
                warn!("`{}` cannot be drawn by the compact render path: {error}", record.name);
                None
            }
        };
        Ok(Self {
            max_wood_error: record.wood.iter().map(wood_segment_error).fold(0.0, f32::max),
            aabb: Aabb::from_min_max(lo - margin, hi + margin),
            crown_center: record.crown_center(),
            max_line_error: ranges.original_lines.max,
            min_line_error: ranges.original_lines.min,
            max_merge_depth: merge_depths(&record).into_iter().max().unwrap_or(0),
            compact,
            meshes: None,
            record: Arc::new(record),
        })
    }

    /// The mesh path's line bands (empty until its meshes are built).
    pub fn line_bands(&self) -> &[SpeciesLineBand] {
        self.meshes.as_ref().map_or(&[], |m| &m.lines)
    }
}

/// The mesh path's GPU-ready parts of a record, before they become assets.
pub struct SpeciesMeshes {
    /// Prism mesh (vertex codes).
    pub prisms: Mesh,
    /// Line band meshes, with their error spans.
    pub lines: Vec<(Mesh, BandErrors)>,
    /// Wood segment prisms (vertex codes), if any.
    pub wood_prisms: Option<Mesh>,
    /// Wood segment storage buffer.
    pub wood_segments: ShaderBuffer,
    /// Imported wood triangles, if any.
    pub wood: Option<Mesh>,
    /// Needle storage buffer.
    pub needles: ShaderBuffer,
}

impl SpeciesMeshes {
    /// Builds the meshes and buffers of `record`.
    pub fn build(record: &LodRecord) -> Result<Self, ConiferLoadError> {
        let prisms = prism_buffers(record).ok_or(ConiferLoadError::TooManyNeedles(record.needle_count()))?;
        let wood = wood_prism_buffers(record).ok_or(ConiferLoadError::TooManyNeedles(record.wood.len()))?;
        let lines = line_bands(record, MAX_LINE_BANDS)
            .into_iter()
            .map(|band| (line_mesh(band.buffers), band.errors))
            .collect();
        Ok(Self {
            needles: ShaderBuffer::from(prisms.needles.clone()),
            prisms: prism_mesh(&prisms),
            lines,
            wood_prisms: (!record.wood.is_empty()).then(|| prism_mesh(&wood)),
            wood_segments: ShaderBuffer::from(if wood.needles.is_empty() {
                // A storage binding cannot be empty.
                vec![[0.0f32; 4]; 3]
            } else {
                wood.needles
            }),
            wood: (record.wood_mesh.triangle_count() > 0).then(|| wood_mesh(&[], &record.wood_mesh, 8)),
        })
    }

    /// The meshes and buffers added to `meshes` and `buffers`.
    pub fn into_handles(self, meshes: &mut Assets<Mesh>, buffers: &mut Assets<ShaderBuffer>) -> SpeciesMeshHandles {
        SpeciesMeshHandles {
            prisms: meshes.add(self.prisms),
            lines: self
                .lines
                .into_iter()
                .map(|(mesh, errors)| SpeciesLineBand {
                    mesh: meshes.add(mesh),
                    errors,
                })
                .collect(),
            wood_prisms: self.wood_prisms.map(|mesh| meshes.add(mesh)),
            wood_segments: buffers.add(self.wood_segments),
            wood: self.wood.map(|mesh| meshes.add(mesh)),
            needles: buffers.add(self.needles),
        }
    }
}

fn prism_mesh(buffers: &PrismBuffers) -> Mesh {
    Mesh::new(PrimitiveTopology::TriangleList, RenderAssetUsages::RENDER_WORLD)
        .with_inserted_attribute(ATTRIBUTE_PRISM_CODE, buffers.codes.clone())
        .with_inserted_indices(Indices::U32(buffers.indices.clone()))
}

/// A band's line buffers as the plugin's line mesh (`LineList` with the
/// per-vertex `[error, parent_error, width, kind]` attribute).
pub fn line_mesh(buffers: LineBuffers) -> Mesh {
    Mesh::new(PrimitiveTopology::LineList, RenderAssetUsages::RENDER_WORLD)
        .with_inserted_attribute(Mesh::ATTRIBUTE_POSITION, buffers.positions)
        .with_inserted_attribute(Mesh::ATTRIBUTE_NORMAL, buffers.normals)
        .with_inserted_attribute(ATTRIBUTE_LINE_LOD, buffers.lod)
}

/// Trunk and branches as one ordinary mesh: the wood segments as open
/// truncated cones of `sides` sides with smooth normals, plus imported wood
/// triangles (the plugin draws segments as LOD prisms and uses this only
/// for imported triangles).
pub fn wood_mesh(segments: &[WoodSegment], triangles: &TriangleMesh, sides: u32) -> Mesh {
    let mut mesh = triangles.clone();
    for segment in segments {
        append_wood_segment(&mut mesh, segment, sides);
    }
    triangle_mesh(&mesh)
}

/// A model [`TriangleMesh`] as a Bevy triangle-list mesh (positions,
/// normals, `u32` indices), for the render world only.
pub fn triangle_mesh(mesh: &TriangleMesh) -> Mesh {
    let positions: Vec<[f32; 3]> = mesh.positions.iter().map(|p| p.to_array()).collect();
    let normals: Vec<[f32; 3]> = mesh.normals.iter().map(|n| n.to_array()).collect();
    Mesh::new(PrimitiveTopology::TriangleList, RenderAssetUsages::RENDER_WORLD)
        .with_inserted_attribute(Mesh::ATTRIBUTE_POSITION, positions)
        .with_inserted_attribute(Mesh::ATTRIBUTE_NORMAL, normals)
        .with_inserted_indices(Indices::U32(mesh.indices.clone()))
}
