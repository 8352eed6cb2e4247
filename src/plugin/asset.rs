//! The species asset: a `.conifer` record turned into GPU-ready meshes.

use super::material::{ATTRIBUTE_LINE_LOD, ATTRIBUTE_PRISM_CODE};
use crate::model::gpu_layout::{LineBuffers, PrismBuffers, line_buffers, prism_buffers};
use crate::model::prism::TriangleMesh;
use crate::model::{LodRecord, RecordError, WoodSegment, decode_record};
use bevy::asset::io::Reader;
use bevy::asset::{AssetLoader, LoadContext, RenderAssetUsages};
use bevy::camera::primitives::Aabb;
use bevy::mesh::{Indices, PrimitiveTopology};
use bevy::prelude::*;
use bevy::render::storage::ShaderBuffer;
use std::sync::Arc;

/// One tree species, loaded from a `.conifer` record: the record itself and
/// the meshes every instance shares.
#[derive(Asset, TypePath, Debug, Clone)]
pub struct ConiferSpecies {
    /// The LOD record (merge forest, needles, errors).
    pub record: Arc<LodRecord>,
    /// Every needle as an `Lmax`-slot prism (vertex codes; the needles are in
    /// `needles`). Drawn opaque.
    pub prisms: Handle<Mesh>,
    /// Every original and merged line (`LineList`). Drawn blended.
    pub lines: Handle<Mesh>,
    /// Trunk and branches.
    pub wood: Handle<Mesh>,
    /// Needle cylinders for the prism mesh's vertex shader.
    pub needles: Handle<ShaderBuffer>,
    /// Tree-local bounds of needles and wood, widened by the largest needle radius.
    pub aabb: Aabb,
    /// Tree-local centre of the crown (where the viewing distance is measured to).
    pub crown_center: Vec3,
    /// Largest line error `2R`: no prism is drawn at or above it.
    pub max_line_error: f32,
    /// Smallest line error `2R`: no line is drawn below it.
    pub min_line_error: f32,
}

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
        load_context: &mut LoadContext<'_>,
    ) -> Result<ConiferSpecies, ConiferLoadError> {
        let mut bytes = Vec::new();
        reader.read_to_end(&mut bytes).await?;
        let record = decode_record(&bytes)?;
        let parts = SpeciesMeshes::build(&record)?;
        Ok(ConiferSpecies {
            prisms: load_context.add_labeled_asset("prisms", parts.prisms),
            lines: load_context.add_labeled_asset("lines", parts.lines),
            wood: load_context.add_labeled_asset("wood", parts.wood),
            needles: load_context.add_labeled_asset("needles", parts.needles),
            aabb: parts.aabb,
            crown_center: parts.crown_center,
            max_line_error: parts.max_line_error,
            min_line_error: parts.min_line_error,
            record: Arc::new(record),
        })
    }

    fn extensions(&self) -> &[&str] {
        &["conifer"]
    }
}

/// The GPU-ready parts of a record, before they become assets.
pub struct SpeciesMeshes {
    /// Prism mesh (vertex codes).
    pub prisms: Mesh,
    /// Line mesh.
    pub lines: Mesh,
    /// Wood mesh.
    pub wood: Mesh,
    /// Needle storage buffer.
    pub needles: ShaderBuffer,
    /// Bounds.
    pub aabb: Aabb,
    /// Crown centre.
    pub crown_center: Vec3,
    /// Largest `2R`.
    pub max_line_error: f32,
    /// Smallest `2R`.
    pub min_line_error: f32,
}

impl SpeciesMeshes {
    /// Builds the meshes and buffer of `record`.
    pub fn build(record: &LodRecord) -> Result<Self, ConiferLoadError> {
        let prisms = prism_buffers(record).ok_or(ConiferLoadError::TooManyNeedles(record.needle_count()))?;
        let lines = line_buffers(record);
        let ranges = record.part_ranges();
        let (lo, hi) = record.bounds();
        let margin = Vec3::splat(ranges.original_lines.max * 0.5);
        Ok(Self {
            needles: ShaderBuffer::from(prisms.needles.clone()),
            prisms: prism_mesh(&prisms),
            lines: line_mesh(lines),
            wood: wood_mesh(&record.wood, &record.wood_mesh, 8),
            aabb: Aabb::from_min_max(lo - margin, hi + margin),
            crown_center: record.crown_center(),
            max_line_error: ranges.original_lines.max,
            min_line_error: ranges.original_lines.min,
        })
    }
}

fn prism_mesh(buffers: &PrismBuffers) -> Mesh {
    Mesh::new(PrimitiveTopology::TriangleList, RenderAssetUsages::RENDER_WORLD)
        .with_inserted_attribute(ATTRIBUTE_PRISM_CODE, buffers.codes.clone())
        .with_inserted_indices(Indices::U32(buffers.indices.clone()))
}

fn line_mesh(buffers: LineBuffers) -> Mesh {
    Mesh::new(PrimitiveTopology::LineList, RenderAssetUsages::RENDER_WORLD)
        .with_inserted_attribute(Mesh::ATTRIBUTE_POSITION, buffers.positions)
        .with_inserted_attribute(Mesh::ATTRIBUTE_NORMAL, buffers.normals)
        .with_inserted_attribute(ATTRIBUTE_LINE_LOD, buffers.lod)
}

/// Trunk and branches: the record's wood segments as open truncated cones of
/// `sides` sides with smooth normals, plus its imported wood triangles.
pub fn wood_mesh(segments: &[WoodSegment], triangles: &TriangleMesh, sides: u32) -> Mesh {
    let mut positions: Vec<[f32; 3]> = triangles.positions.iter().map(|p| p.to_array()).collect();
    let mut normals: Vec<[f32; 3]> = triangles.normals.iter().map(|n| n.to_array()).collect();
    let mut indices: Vec<u32> = triangles.indices.clone();
    positions.reserve(segments.len() * 2 * sides as usize);
    normals.reserve(segments.len() * 2 * sides as usize);
    indices.reserve(segments.len() * 6 * sides as usize);
    for segment in segments {
        let axis = segment.end - segment.start;
        let Some(direction) = axis.try_normalize() else {
            continue;
        };
        let u = direction.any_orthonormal_vector();
        let v = direction.cross(u);
        // The cone's normal tilts by the slope of its radius.
        let slope = (segment.start_radius - segment.end_radius) / axis.length();
        let first = positions.len() as u32;
        for (centre, radius) in [(segment.start, segment.start_radius), (segment.end, segment.end_radius)] {
            for k in 0..sides {
                let angle = std::f32::consts::TAU * k as f32 / sides as f32;
                let radial = u * angle.cos() + v * angle.sin();
                positions.push((centre + radial * radius).to_array());
                normals.push((radial + direction * slope).normalize().to_array());
            }
        }
        for k in 0..sides {
            let next = (k + 1) % sides;
            let (b0, b1, t0, t1) = (first + k, first + next, first + sides + k, first + sides + next);
            indices.extend_from_slice(&[b0, b1, t1, b0, t1, t0]);
        }
    }
    Mesh::new(PrimitiveTopology::TriangleList, RenderAssetUsages::RENDER_WORLD)
        .with_inserted_attribute(Mesh::ATTRIBUTE_POSITION, positions)
        .with_inserted_attribute(Mesh::ATTRIBUTE_NORMAL, normals)
        .with_inserted_indices(Indices::U32(indices))
}
