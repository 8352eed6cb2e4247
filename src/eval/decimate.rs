//! What a Bevy user builds without this crate: the raw needle geometry as
//! one mesh, and a chain of decimated copies made with meshoptimizer's
//! simplifier (the `meshopt` crate), to switch with Bevy's
//! `VisibilityRange`.

use crate::model::LodRecord;
use crate::model::needle::Needle;
use crate::model::prism::{TriangleMesh, append_prism};
use glam::Vec3;
use meshopt::SimplifyOptions;

/// Every needle of `record` as a capped prism of `Lmax` sides: the raw
/// geometry (what loading the tree as an ordinary mesh draws).
pub fn raw_needle_mesh(record: &LodRecord) -> TriangleMesh {
    needle_mesh_with_corners_at(record, 1.0)
}

/// Every needle of `record` as a capped prism of `Lmax` sides whose
/// corners lie `scale` radii from its axis (1: [`raw_needle_mesh`]; the
/// eval's reference takes the round needle's mean width).
pub fn needle_mesh_with_corners_at(record: &LodRecord, scale: f32) -> TriangleMesh {
    let mut mesh = TriangleMesh::default();
    for needle in &record.needles {
        append_scaled_prism(&mut mesh, needle, scale, record.max_sides);
    }
    mesh
}

/// [`needle_mesh_with_corners_at`] with each vertex's needle group, in
/// vertex order (a flattened tree's groups are its placements).
pub fn needle_mesh_and_groups(record: &LodRecord, scale: f32) -> (TriangleMesh, Vec<u32>) {
    let mut mesh = TriangleMesh::default();
    let mut groups = Vec::new();
    for needle in &record.needles {
        append_scaled_prism(&mut mesh, needle, scale, record.max_sides);
        groups.resize(mesh.positions.len(), needle.group);
    }
    (mesh, groups)
}

fn append_scaled_prism(mesh: &mut TriangleMesh, needle: &Needle, scale: f32, sides: u8) {
    let scaled = Needle {
        radius: needle.radius * scale,
        ..*needle
    };
    append_prism(mesh, &scaled, sides);
}

/// One level of a decimated chain.
#[derive(Clone, Debug)]
pub struct DecimatedLevel {
    /// The simplified mesh (vertices compacted).
    pub mesh: TriangleMesh,
    /// Triangles kept over the input's.
    pub ratio: f32,
    /// The simplifier's geometric error, in the mesh's units (metres).
    pub error: f32,
    /// `true` when the topology-preserving simplifier could not get near
    /// the target and the vertex-clustering ("sloppy") one was used.
    pub sloppy: bool,
}

/// `mesh` simplified to about `ratio` of its triangles with meshoptimizer:
/// first `meshopt::simplify` (edge collapses, error reported in metres); if
/// that stays above 1.25× the target, as it does on a soup of separate
/// needles that cannot collapse past a tetrahedron each,
/// `meshopt::simplify_sloppy` (vertex clustering), as a user would.
pub fn decimate(mesh: &TriangleMesh, ratio: f32) -> DecimatedLevel {
    let positions: Vec<[f32; 3]> = mesh.positions.iter().map(|p| p.to_array()).collect();
    let triangles = mesh.triangle_count();
    let target = ((triangles as f32 * ratio.clamp(0.0, 1.0)) as usize).max(1) * 3;
    if triangles == 0 {
        return DecimatedLevel {
            mesh: mesh.clone(),
            ratio: 1.0,
            error: 0.0,
            sloppy: false,
        };
    }
    let mut error = 0.0f32;
    let mut indices = meshopt::simplify_decoder(
        &mesh.indices,
        &positions,
        target,
        f32::MAX,
        SimplifyOptions::ErrorAbsolute,
        Some(&mut error),
    );
    let mut sloppy = false;
    if indices.len() as f32 > 1.25 * target as f32 {
        let mut relative = 0.0f32;
        indices = meshopt::simplify_sloppy_decoder(&mesh.indices, &positions, target, f32::MAX, Some(&mut relative));
        error = relative * meshopt::simplify_scale_decoder(&positions);
        sloppy = true;
    }
    DecimatedLevel {
        ratio: indices.len() as f32 / mesh.indices.len() as f32,
        mesh: compact(mesh, &indices),
        error,
        sloppy,
    }
}

/// The vertices `indices` use, renumbered.
fn compact(mesh: &TriangleMesh, indices: &[u32]) -> TriangleMesh {
    let mut remap = vec![u32::MAX; mesh.positions.len()];
    let mut out = TriangleMesh::default();
    for &index in indices {
        let slot = &mut remap[index as usize];
        if *slot == u32::MAX {
            *slot = out.positions.len() as u32;
            out.positions.push(mesh.positions[index as usize]);
            out.normals
                .push(mesh.normals.get(index as usize).copied().unwrap_or(Vec3::Y));
        }
        out.indices.push(*slot);
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::generate::{GenerateOptions, Species, generate};
    use crate::model::{BakeOptions, bake};

    #[test]
    fn decimation_reaches_its_targets_with_growing_error() {
        let tree = generate(
            Species::ScotsPine,
            &GenerateOptions {
                seed: 1,
                target_needles: Some(5000),
                age: crate::generate::Age::Young,
            },
        );
        let record = bake(&tree, &BakeOptions::default(), &()).unwrap();
        let raw = raw_needle_mesh(&record);
        assert!(raw.is_valid());
        assert_eq!(
            raw.triangle_count(),
            record.needle_count() * crate::model::prism::prism_triangle_count(record.max_sides) as usize
        );
        let mut last_error = 0.0;
        for ratio in [0.5, 0.25, 0.12, 0.06] {
            let level = decimate(&raw, ratio);
            assert!(level.mesh.is_valid());
            assert!(
                level.ratio <= ratio * 1.25 && level.ratio > 0.0,
                "{ratio}: {}",
                level.ratio
            );
            assert!(level.error >= last_error && level.error.is_finite());
            last_error = level.error;
        }
    }
}
