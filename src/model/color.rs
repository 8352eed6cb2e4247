//! Colour within a tree, free of Bevy: needles by their shoot's age and by
//! the side of the shoot the viewer sees, bark by height. CPU reference of
//! the vertex shader's `needle_albedo` and `bark_albedo`
//! (`conifer_compact.wgsl`).
//!
//! * **Age.** All needles of an annual shoot are the same age, so a
//!   placement (a shoot, twig or spray) carries it
//!   ([`super::Placement::needle_age`]). This year's needles take
//!   [`FoliageMaterial::young_needle_color`], turning linearly into
//!   [`FoliageMaterial::needle_color`] by [`NEEDLE_MATURE_YEARS`].
//! * **Side.** A shoot's *upper side* is the area-weighted mean normal of
//!   its prototype's needles ([`upper_side`]); its length (≤ 1) says how
//!   consistently they face one way (1 for a fir's two-ranked flat shoot,
//!   near 0 for needles all round a spruce shoot). Seen from beneath, the
//!   needles take [`FoliageMaterial::needle_underside_color`] by
//!   [`underside_weight`].
//! * **Bark.** [`bark_color`] turns from [`FoliageMaterial::wood_color`]
//!   to [`FoliageMaterial::upper_wood_color`] between the two
//!   [`FoliageMaterial::upper_wood_heights`] (tree metres).
//!
//! Far representations (the tree-level merged lines, a flat species and
//! the crown impostor) have no placement to take an age from: they take
//! [`far_needle_color`], the area-weighted mean over the placements as a
//! level view sees them, so a tree's colour does not jump when its
//! placements merge.

use super::needle::{FoliageMaterial, Needle};
use super::prototype::PrototypeRecord;
use glam::Vec3;

/// Age (years) from which needles have their mature colour.
pub const NEEDLE_MATURE_YEARS: f32 = 2.0;

/// The age [`super::Placement::identity`] gives: mature (the base colour).
pub const MATURE_NEEDLE_AGE: u8 = 2;

/// Linear RGB of needles `age` years old, seen from above their shoot.
pub fn needle_age_color(material: &FoliageMaterial, age: u8) -> Vec3 {
    let t = (age as f32 / NEEDLE_MATURE_YEARS).clamp(0.0, 1.0);
    rgb(material.young_needle_color).lerp(rgb(material.needle_color), t)
}

/// How much of a shoot's lower side a viewer sees, in `[0, 1]`: `upper`
/// the shoot's upper side in the viewer's frame ([`upper_side`], placed),
/// `to_viewer` a unit vector. Half edge-on, all of it from 15° under the
/// shoot's plane on, scaled by how consistently the needles face one way
/// (`|upper|`).
pub fn underside_weight(upper: Vec3, to_viewer: Vec3) -> f32 {
    let consistency = upper.length().min(1.0);
    if consistency < 1e-6 {
        return 0.0;
    }
    let facing = upper.dot(to_viewer) / upper.length();
    (0.5 - 2.0 * facing).clamp(0.0, 1.0) * consistency
}

/// Linear RGB of a placement's needles: its age's colour mixed with the
/// underside colour by [`underside_weight`].
pub fn needle_color(material: &FoliageMaterial, age: u8, upper: Vec3, to_viewer: Vec3) -> Vec3 {
    let weight = underside_weight(upper, to_viewer);
    needle_age_color(material, age).lerp(rgb(material.needle_underside_color), weight)
}

/// Linear RGB of bark at `height` (tree metres).
pub fn bark_color(material: &FoliageMaterial, height: f32) -> Vec3 {
    let [start, end] = material.upper_wood_heights;
    let t = if end > start {
        ((height - start) / (end - start)).clamp(0.0, 1.0)
    } else if height >= end {
        // A step (or no change when the two colours are equal).
        1.0
    } else {
        0.0
    };
    rgb(material.wood_color).lerp(rgb(material.upper_wood_color), t)
}

/// The upper side of a set of needles: their area-weighted mean normal
/// (length ≤ 1; zero without needles).
pub fn upper_side(needles: &[Needle]) -> Vec3 {
    let (mut sum, mut area) = (Vec3::ZERO, 0.0f32);
    for needle in needles {
        let a = needle.side_area();
        if needle.normal.is_finite() && a.is_finite() {
            sum += needle.normal.normalize_or_zero() * a;
            area += a;
        }
    }
    if area > 0.0 { sum / area } else { Vec3::ZERO }
}

/// Linear RGB of the whole crown from afar: the needles' colours averaged
/// by area over the placements, each seen edge-on (half its
/// [`underside_weight`] at most).
pub fn far_needle_color(record: &PrototypeRecord) -> Vec3 {
    let material = &record.material;
    let sides: Vec<(f32, f32)> = record
        .prototypes
        .iter()
        .map(|p| {
            (
                p.needles.iter().map(Needle::side_area).sum::<f32>(),
                upper_side(&p.needles).length().min(1.0),
            )
        })
        .collect();
    let (mut sum, mut total) = (Vec3::ZERO, 0.0f32);
    for placement in &record.placements {
        let Some(&(area, consistency)) = sides.get(placement.prototype as usize) else {
            continue;
        };
        let a = area * placement.scale * placement.scale;
        if !a.is_finite() {
            continue;
        }
        let edge_on = needle_age_color(material, placement.needle_age)
            .lerp(rgb(material.needle_underside_color), 0.5 * consistency);
        sum += edge_on * a;
        total += a;
    }
    if total > 0.0 {
        sum / total
    } else {
        rgb(material.needle_color)
    }
}

/// What colours one placed shoot's needles ([`needle_color`]), in the
/// tree's frame: the colour of their age seen from above, the shoot's
/// upper side and the point the viewer is taken from.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ShootColor {
    /// Linear RGB of the shoot's needles seen from above
    /// ([`needle_age_color`] of its placement's age).
    pub age_color: Vec3,
    /// The placed prototype's bounding-sphere centre, tree metres: the
    /// point [`underside_weight`]'s viewer direction is taken from.
    pub center: Vec3,
    /// The shoot's upper side ([`upper_side`] of its prototype, rotated
    /// into the tree; its length says how consistently the needles face
    /// one way).
    pub upper: Vec3,
}

impl ShootColor {
    /// Linear RGB of the shoot's needles seen from `eye` (tree metres):
    /// [`needle_color`] with the viewer's direction from [`Self::center`];
    /// from the centre itself, as seen edge-on (the shader's rule).
    pub fn seen_from(&self, material: &FoliageMaterial, eye: Vec3) -> Vec3 {
        let to_viewer = (eye - self.center).normalize_or_zero();
        self.age_color.lerp(
            rgb(material.needle_underside_color),
            underside_weight(self.upper, to_viewer),
        )
    }
}

/// Every placement's [`ShootColor`], in placement order: what the vertex
/// shader's `placed_needle_albedo` reads from a placement and its
/// prototype. A [`PrototypeRecord::flatten`]ed needle's group is its
/// placement, so `shoot_colors(record)[needle.group]` colours it.
///
/// [`PrototypeRecord::flatten`]: super::PrototypeRecord::flatten
pub fn shoot_colors(record: &PrototypeRecord) -> Vec<ShootColor> {
    let uppers: Vec<Vec3> = record.prototypes.iter().map(|p| upper_side(&p.needles)).collect();
    record
        .placements
        .iter()
        .map(|placement| {
            let k = placement.prototype as usize;
            let upper_local = uppers.get(k).copied().unwrap_or(Vec3::ZERO);
            let center = if k < record.prototypes.len() {
                placement.place_point(record.prototype_sphere(k).center)
            } else {
                placement.translation
            };
            ShootColor {
                age_color: needle_age_color(&record.material, placement.needle_age),
                center,
                upper: (placement.rotation * upper_local).normalize_or_zero() * upper_local.length(),
            }
        })
        .collect()
}

fn rgb(color: [f32; 4]) -> Vec3 {
    Vec3::new(color[0], color[1], color[2])
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::{FoliageMaterial, Placement};

    fn material() -> FoliageMaterial {
        FoliageMaterial {
            young_needle_color: [0.2, 0.3, 0.05, 1.0],
            needle_underside_color: [0.3, 0.4, 0.4, 1.0],
            upper_wood_color: [0.5, 0.2, 0.05, 1.0],
            upper_wood_heights: [5.0, 10.0],
            ..FoliageMaterial::uniform([0.03, 0.09, 0.04, 1.0], [0.1, 0.09, 0.08, 1.0], 0.6, 0.3)
        }
    }

    /// Four parallel needles in a plane, their normals +Z: a flat shoot.
    fn flat_shoot() -> Vec<Needle> {
        (0..4)
            .map(|k| Needle {
                base: Vec3::new(k as f32 * 0.01, 0.0, 0.0),
                tip: Vec3::new(k as f32 * 0.01, 0.05, 0.0),
                radius: 5e-4,
                normal: Vec3::Z,
                group: 0,
            })
            .collect()
    }

    #[test]
    fn needles_age_from_the_young_colour_to_the_base_colour() {
        let m = material();
        assert!(needle_age_color(&m, 0).distance(Vec3::new(0.2, 0.3, 0.05)) < 1e-6);
        assert!(needle_age_color(&m, 1).distance(Vec3::new(0.115, 0.195, 0.045)) < 1e-6);
        for age in [2, 3, 200] {
            assert!(needle_age_color(&m, age).distance(Vec3::new(0.03, 0.09, 0.04)) < 1e-6);
        }
    }

    #[test]
    fn undersides_show_from_beneath_in_proportion_to_how_flat_the_shoot_is() {
        assert_eq!(underside_weight(Vec3::Y, Vec3::Y), 0.0);
        assert_eq!(underside_weight(Vec3::Y, -Vec3::Y), 1.0);
        assert!((underside_weight(Vec3::Y, Vec3::X) - 0.5).abs() < 1e-6);
        assert!((underside_weight(0.4 * Vec3::Y, -Vec3::Y) - 0.4).abs() < 1e-6);
        assert_eq!(underside_weight(Vec3::ZERO, -Vec3::Y), 0.0);
        // A weight never leaves [0, 1], whatever the length.
        assert_eq!(underside_weight(3.0 * Vec3::Y, -Vec3::Y), 1.0);
        let m = material();
        assert!(needle_color(&m, 5, Vec3::Y, -Vec3::Y).distance(Vec3::new(0.3, 0.4, 0.4)) < 1e-6);
        assert_eq!(needle_color(&m, 5, Vec3::Y, Vec3::Y), Vec3::new(0.03, 0.09, 0.04));
    }

    #[test]
    fn bark_turns_between_the_two_heights() {
        let m = material();
        assert_eq!(bark_color(&m, 0.0), Vec3::new(0.1, 0.09, 0.08));
        assert_eq!(bark_color(&m, 5.0), Vec3::new(0.1, 0.09, 0.08));
        assert!(bark_color(&m, 7.5).distance(Vec3::new(0.3, 0.145, 0.065)) < 1e-6);
        assert!(bark_color(&m, 30.0).distance(Vec3::new(0.5, 0.2, 0.05)) < 1e-6);
        let uniform = FoliageMaterial::default();
        assert!(bark_color(&uniform, 12.0).distance(Vec3::new(0.23, 0.16, 0.11)) < 1e-6);
    }

    #[test]
    fn the_far_colour_is_the_area_weighted_mean_seen_edge_on() {
        use crate::model::{BakeOptions, PrototypeInput, bake_prototypes};
        let shoot = flat_shoot();
        let placed = |x: f32, scale: f32, needle_age: u8| Placement {
            translation: Vec3::new(x, 0.0, 0.0),
            scale,
            needle_age,
            ..Placement::identity(0)
        };
        let input = PrototypeInput {
            name: "two shoots".into(),
            prototypes: vec![shoot],
            // This year's shoot twice the size (four times the area) of a
            // 3-year-old one.
            placements: vec![placed(0.0, 2.0, 0), placed(1.0, 1.0, 3)],
            material: material(),
            ..Default::default()
        };
        let record = bake_prototypes(&input, &BakeOptions::default(), &()).unwrap();
        let m = material();
        let edge_on = |age| needle_age_color(&m, age).lerp(rgb(m.needle_underside_color), 0.5);
        let expected = (edge_on(0) * 4.0 + edge_on(3)) / 5.0;
        assert!(
            far_needle_color(&record).distance(expected) < 1e-4,
            "{} against {expected}",
            far_needle_color(&record)
        );
    }

    #[test]
    fn each_flattened_needle_finds_its_shoots_colour_by_its_group() {
        use crate::model::{BakeOptions, PrototypeInput, bake_prototypes};
        use glam::Quat;
        // A flat shoot placed upright, turned on its back, and small and
        // young.
        let shoot = flat_shoot();
        let placements = vec![
            Placement {
                translation: Vec3::new(0.0, 1.0, 0.0),
                needle_age: 4,
                ..Placement::identity(0)
            },
            Placement {
                translation: Vec3::new(2.0, 1.0, 0.0),
                rotation: Quat::from_rotation_x(std::f32::consts::PI),
                needle_age: 4,
                ..Placement::identity(0)
            },
            Placement {
                translation: Vec3::new(4.0, 1.0, 0.0),
                scale: 0.5,
                needle_age: 0,
                ..Placement::identity(0)
            },
        ];
        let input = PrototypeInput {
            name: "three shoots".into(),
            prototypes: vec![shoot],
            placements,
            material: material(),
            ..Default::default()
        };
        let record = bake_prototypes(&input, &BakeOptions::default(), &()).unwrap();
        let m = material();
        let shoots = shoot_colors(&record);
        assert_eq!(shoots.len(), 3);
        // (The record stores needle normals quantized.)
        assert!(shoots[1].upper.distance(-Vec3::Z) < 1e-4);
        assert!(shoots[2].upper.distance(Vec3::Z) < 1e-4);
        assert_eq!(shoots[2].age_color, needle_age_color(&m, 0));
        // Every needle of the flat record lies in the sphere of the shoot
        // its group names.
        let flat = record.flatten().unwrap();
        for needle in &flat.needles {
            let shoot = shoots[needle.group as usize];
            let placement = record.placements[needle.group as usize];
            let reach = record.prototype_sphere(0).radius * placement.scale + 1e-5;
            assert!(needle.base.distance(shoot.center) <= reach && needle.tip.distance(shoot.center) <= reach);
        }
        // Seen from in front (+Z) the first shows its upper side, the
        // second (on its back) its underside; from its own centre, half
        // of each, as edge-on.
        let front = Vec3::new(0.0, 1.0, 50.0);
        assert_eq!(shoots[0].seen_from(&m, front), needle_age_color(&m, 4));
        assert!(shoots[1].seen_from(&m, front).distance(rgb(m.needle_underside_color)) < 1e-6);
        let edge_on = needle_age_color(&m, 4).lerp(rgb(m.needle_underside_color), 0.5);
        assert!(shoots[0].seen_from(&m, shoots[0].center).distance(edge_on) < 1e-6);
        // The shader's rule, placement by placement.
        let side = Vec3::new(60.0, 1.0, 0.0);
        for shoot in &shoots {
            let to_viewer = (side - shoot.center).normalize();
            let expected = shoot
                .age_color
                .lerp(rgb(m.needle_underside_color), underside_weight(shoot.upper, to_viewer));
            assert!(shoot.seen_from(&m, side).distance(expected) < 1e-6);
        }
    }

    #[test]
    fn upper_side_is_the_area_weighted_normal() {
        let needle = |normal: Vec3, radius: f32| Needle {
            base: Vec3::ZERO,
            tip: Vec3::X * 0.02,
            radius,
            normal,
            group: 0,
        };
        assert_eq!(upper_side(&[]), Vec3::ZERO);
        assert!((upper_side(&[needle(Vec3::Z, 1e-3), needle(Vec3::Z, 2e-3)]) - Vec3::Z).length() < 1e-6);
        // Opposite normals cancel; the wider needle wins.
        let mixed = upper_side(&[needle(Vec3::Z, 1e-3), needle(-Vec3::Z, 3e-3)]);
        assert!((mixed - Vec3::new(0.0, 0.0, -0.5)).length() < 1e-6);
    }
}
