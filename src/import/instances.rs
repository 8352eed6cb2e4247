//! glTF instancing kept: a needle primitive placed by several nodes becomes
//! one prototype placed many times (record format 3), instead of a copy of
//! its needles per node.
//!
//! A group whose needles all come from one placed primitive, of a mesh
//! primitive that several nodes place, whose node transform is a similarity (rotation, translation, uniform positive scale)
//! is mapped back into the primitive's own frame; groups of the same mesh
//! primitive (and group attribute value) whose needles agree there share a
//! prototype. Everything else (mirrored, sheared or non-uniformly scaled
//! nodes; inferred groups spanning primitives) is a prototype of its own,
//! placed once as it is.

use crate::model::{Needle, Placement, PrototypeInput, TreeInput};
use glam::{Mat4, Quat, Vec3};
use std::collections::HashMap;

/// Where a needle primitive was placed: its mesh primitive and node transform.
#[derive(Clone, Copy, Debug)]
pub(crate) struct PartInstance {
    /// Index of the mesh.
    pub mesh: usize,
    /// Index of the primitive in the mesh.
    pub primitive: usize,
    /// The node's world transform (with the import scale).
    pub world: Mat4,
}

/// `world` as rotation, translation and uniform scale, if it is one (to
/// 1e-4 of its size): no mirror, shear or non-uniform scale.
pub(crate) fn similarity(world: Mat4) -> Option<(Quat, Vec3, f32)> {
    let (scale, rotation, translation) = world.to_scale_rotation_translation();
    let s = (scale.x + scale.y + scale.z) / 3.0;
    if !(s.is_finite() && s > 0.0 && scale.min_element() > 0.0 && rotation.is_finite()) {
        return None;
    }
    if (scale - Vec3::splat(s)).abs().max_element() > 1e-4 * s {
        return None;
    }
    let rotation = rotation.normalize();
    let rebuilt = Mat4::from_scale_rotation_translation(Vec3::splat(s), rotation, translation);
    let size = world.to_cols_array().iter().fold(0.0f32, |m, x| m.max(x.abs()));
    let off = rebuilt
        .to_cols_array()
        .iter()
        .zip(world.to_cols_array())
        .fold(0.0f32, |m, (a, b)| m.max((a - b).abs()));
    (off <= 1e-4 * size.max(1e-6)).then_some((rotation, translation, s))
}

/// A tree-space needle in the frame of a placement `(rotation, translation, scale)`.
fn to_local(needle: &Needle, (rotation, translation, scale): (Quat, Vec3, f32)) -> Needle {
    let inverse = rotation.inverse();
    let local = |p: Vec3| inverse * (p - translation) / scale;
    Needle {
        base: local(needle.base),
        tip: local(needle.tip),
        radius: needle.radius / scale,
        normal: inverse * needle.normal,
        group: 0,
    }
}

/// `true` when two prototype-frame needle lists are the same needles (in
/// order; a needle's ends may be swapped, since which end is the base is
/// decided per placed copy near the wood).
fn same_needles(a: &[Needle], b: &[Needle]) -> bool {
    let extent =
        crate::model::needle::bounds(a.iter().flat_map(|n| [n.base, n.tip])).map_or(0.0, |(lo, hi)| lo.distance(hi));
    let tolerance = 1e-4 * extent + 1e-7;
    a.len() == b.len()
        && a.iter().zip(b).all(|(x, y)| {
            let ends = (x.base.distance(y.base) <= tolerance && x.tip.distance(y.tip) <= tolerance)
                || (x.base.distance(y.tip) <= tolerance && x.tip.distance(y.base) <= tolerance);
            ends && (x.radius - y.radius).abs() <= 1e-3 * x.radius + 1e-9
        })
}

/// The tree as prototypes: see the module docs. `part_of[i]` is the placed
/// primitive needle `i` came from, `group_values[i]` its group attribute.
/// Groups keep their order of first appearance; placement `p` is group `p`.
pub(crate) fn share_instances(
    tree: &TreeInput,
    parts: &[PartInstance],
    part_of: &[usize],
    group_values: &[Option<i64>],
) -> PrototypeInput {
    let mut slot: HashMap<u32, usize> = HashMap::new();
    let mut groups: Vec<Vec<usize>> = Vec::new();
    for (i, needle) in tree.needles.iter().enumerate() {
        let k = *slot.entry(needle.group).or_insert_with(|| {
            groups.push(Vec::new());
            groups.len() - 1
        });
        groups[k].push(i);
    }
    type Key = (usize, usize, Option<i64>, usize);
    let mut library: HashMap<Key, Vec<u32>> = HashMap::new();
    let mut prototypes: Vec<Vec<Needle>> = Vec::new();
    let mut placements = Vec::with_capacity(groups.len());
    // Mesh primitives placed by more than one node: only these are shared.
    let mut uses: HashMap<(usize, usize), usize> = HashMap::new();
    for part in parts {
        *uses.entry((part.mesh, part.primitive)).or_default() += 1;
    }
    for members in &groups {
        let part = part_of[members[0]];
        let instanced = uses[&(parts[part].mesh, parts[part].primitive)] > 1;
        let transform = (instanced && members.iter().all(|&i| part_of[i] == part))
            .then(|| similarity(parts[part].world))
            .flatten();
        let Some((rotation, translation, scale)) = transform else {
            placements.push(Placement::identity(prototypes.len() as u32));
            prototypes.push(
                members
                    .iter()
                    .map(|&i| Needle {
                        group: 0,
                        ..tree.needles[i]
                    })
                    .collect(),
            );
            continue;
        };
        let local: Vec<Needle> = members
            .iter()
            .map(|&i| to_local(&tree.needles[i], (rotation, translation, scale)))
            .collect();
        let key = (
            parts[part].mesh,
            parts[part].primitive,
            group_values[members[0]],
            members.len(),
        );
        let candidates = library.entry(key).or_default();
        let prototype = match candidates
            .iter()
            .find(|&&k| same_needles(&prototypes[k as usize], &local))
        {
            Some(&k) => k,
            None => {
                prototypes.push(local);
                candidates.push(prototypes.len() as u32 - 1);
                prototypes.len() as u32 - 1
            }
        };
        placements.push(Placement {
            prototype,
            rotation,
            translation,
            scale,
            ..Placement::identity(prototype)
        });
    }
    PrototypeInput {
        name: tree.name.clone(),
        prototypes,
        placements,
        wood: tree.wood.clone(),
        wood_mesh: tree.wood_mesh.clone(),
        material: tree.material,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn similarities_are_found_and_the_rest_refused() {
        let rotation = Quat::from_euler(glam::EulerRot::YXZ, 0.7, -0.3, 1.1);
        let world = Mat4::from_scale_rotation_translation(Vec3::splat(2.5), rotation, Vec3::new(1.0, -2.0, 3.0));
        let (r, t, s) = similarity(world).unwrap();
        assert!(r.angle_between(rotation) < 1e-4 && t.distance(Vec3::new(1.0, -2.0, 3.0)) < 1e-5);
        assert!((s - 2.5).abs() < 1e-5);
        assert!(similarity(Mat4::from_scale(Vec3::new(1.0, 2.0, 1.0))).is_none());
        assert!(similarity(Mat4::from_scale(Vec3::new(-1.0, 1.0, 1.0))).is_none());
        assert!(similarity(Mat4::from_scale(Vec3::ZERO)).is_none());
        let shear = Mat4::from_cols_array(&[
            1.0, 0.0, 0.0, 0.0, 0.5, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0,
        ]);
        assert!(similarity(shear).is_none());
        assert!(similarity(Mat4::from_cols_array(&[f32::NAN; 16])).is_none());
    }
}
