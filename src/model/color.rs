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
//! [`far_needle_color`], the colour of the needles a level view sees
//! first, so a tree's colour does not jump when its placements merge.
//! A crown's outer shoots are its youngest (a fir keeps its needles for
//! many years, and each year's shoots grow outside the last), so the needles
//! seen from outside are lighter than all of them averaged by area: the
//! record's impostor carries the mix of ages and sides its views see
//! ([`NeedleMix::seen`]); a record without one falls back to the area mean
//! over the placements ([`NeedleMix::of_area`]).

use super::impostor::CrownImpostor;
use super::needle::{FoliageMaterial, Needle};
use super::prototype::PrototypeRecord;
use glam::Vec3;
use rayon::prelude::*;

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

/// Linear RGB of the whole crown from afar: the impostor's
/// [`NeedleMix::seen`] where the record has one, else
/// [`NeedleMix::of_area`]; the needle colour where neither has needles.
pub fn far_needle_color(record: &PrototypeRecord) -> Vec3 {
    record
        .impostor
        .as_deref()
        .and_then(|impostor| impostor.seen_needles)
        .or_else(|| NeedleMix::of_area(record))
        .map_or(rgb(record.material.needle_color), |mix| mix.color(&record.material))
}

/// Needle ages the far colour tells apart: this year's, last year's, and
/// [`NEEDLE_MATURE_YEARS`] or older ([`needle_age_color`] is linear in
/// between, so the three give every age's colour exactly).
pub const NEEDLE_AGE_CLASSES: usize = 3;

/// Sample columns a texel column of the impostor's views gets in
/// [`NeedleMix::seen`].
pub const SEEN_COLUMNS_PER_TEXEL: u32 = 4;

/// The impostor's views [`NeedleMix::seen`] looks from, at most, evenly
/// spread round the ring.
pub const SEEN_VIEWS: u32 = 4;

/// Sample rows a texel row of the impostor's views gets in
/// [`NeedleMix::seen`]. One, through each row's middle: on the mature
/// records four (with 16 columns a texel, all eight views) moved no
/// colour by more than 0.02 of 255 and took twice the time.
pub const SEEN_ROWS_PER_TEXEL: u32 = 1;

/// The mix of needles a far representation stands for, by what colours
/// them: for each age class (this year's, last year's, mature) the share
/// of the needles (the shares sum to 1) and that share times how much of
/// their underside shows ([`underside_weight`]). Its [`NeedleMix::color`]
/// under a material is their mean colour; keeping the mix rather than the
/// colour keeps it right when a game changes the material.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct NeedleMix {
    /// `[share, share × underside weight]` by age class (0, 1, 2 and
    /// older).
    pub by_age: [[f32; 2]; NEEDLE_AGE_CLASSES],
}

impl NeedleMix {
    /// The mean linear RGB of the mix's needles under `material`.
    pub fn color(&self, material: &FoliageMaterial) -> Vec3 {
        let underside = rgb(material.needle_underside_color);
        self.by_age
            .iter()
            .enumerate()
            .map(|(age, &[share, under])| (share - under) * needle_age_color(material, age as u8) + under * underside)
            .sum()
    }

    /// The placements' needles by area, each shoot seen edge-on (half its
    /// [`underside_weight`] at most): every needle counted, seen or not.
    /// `None` without needles.
    pub fn of_area(record: &PrototypeRecord) -> Option<Self> {
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
        let mut sums = [[0.0f64; 2]; NEEDLE_AGE_CLASSES];
        for placement in &record.placements {
            let Some(&(area, consistency)) = sides.get(placement.prototype as usize) else {
                continue;
            };
            let a = area * placement.scale * placement.scale;
            if !a.is_finite() {
                continue;
            }
            let sum = &mut sums[age_class(placement.needle_age)];
            sum[0] += f64::from(a);
            sum[1] += f64::from(a * 0.5 * consistency);
        }
        Self::from_sums(sums)
    }

    /// The needles the impostor's level views see first, as its bake
    /// rasterizes them (`needles` are `record`'s placed needles, each in
    /// its placement's group, as [`PrototypeRecord::placed_needles`] gives
    /// them): [`SEEN_VIEWS`] of its views, orthographic, on a grid of [`SEEN_COLUMNS_PER_TEXEL`]
    /// columns and [`SEEN_ROWS_PER_TEXEL`] rows a texel; a sample takes
    /// the nearest needle whose silhouette holds it (a capsule of its
    /// radius round its projected axis) unless wood lies in front, and
    /// counts that needle's age and the underside its view sees. `None`
    /// where no sample sees a needle.
    pub fn seen(record: &PrototypeRecord, needles: &[Needle], impostor: &CrownImpostor) -> Option<Self> {
        let uppers: Vec<Vec3> = shoot_colors(record).iter().map(|shoot| shoot.upper).collect();
        // The sample rows are level, the same in every view: a needle
        // between two (half the mature spruce's) is dropped once, not in
        // every view.
        let step_y = impostor.texel / SEEN_ROWS_PER_TEXEL as f32;
        let top = impostor.top();
        let crosses_a_row = |needle: &&Needle| {
            let (a, b) = ((top - needle.base.y) / step_y, (top - needle.tip.y) / step_y);
            let reach = needle.radius / step_y;
            // A sample row `k` lies at `k + 0.5`.
            (a.min(b) - reach - 0.5).ceil() <= (a.max(b) + reach - 0.5).floor()
        };
        let crossing: Vec<&Needle> = needles.iter().filter(|n| n.is_valid()).filter(crosses_a_row).collect();
        // Every other view of a ring of eight: a crown looks alike from
        // neighbouring sides.
        let views = impostor.views.min(SEEN_VIEWS);
        let views: Vec<[[f64; 2]; NEEDLE_AGE_CLASSES]> = (0..views)
            .into_par_iter()
            .map(|k| seen_in_view(record, &uppers, &crossing, impostor, k * impostor.views / views))
            .collect();
        let mut sums = [[0.0f64; 2]; NEEDLE_AGE_CLASSES];
        for view in &views {
            for (sum, add) in sums.iter_mut().zip(view) {
                sum[0] += add[0];
                sum[1] += add[1];
            }
        }
        Self::from_sums(sums)
    }

    /// The mix as six numbers (the record file's layout).
    pub fn to_array(&self) -> [f32; 2 * NEEDLE_AGE_CLASSES] {
        let mut out = [0.0; 2 * NEEDLE_AGE_CLASSES];
        out.copy_from_slice(self.by_age.as_flattened());
        out
    }

    /// The mix of [`Self::to_array`]'s six numbers; `None` unless every
    /// share lies in `[0, 1]`, every underside part within its share, and
    /// the shares sum to 1 (within 10⁻³).
    pub fn from_array(values: [f32; 2 * NEEDLE_AGE_CLASSES]) -> Option<Self> {
        let mut by_age = [[0.0; 2]; NEEDLE_AGE_CLASSES];
        for (pair, chunk) in by_age.iter_mut().zip(values.chunks_exact(2)) {
            let (share, under) = (chunk[0], chunk[1]);
            if !((0.0..=1.0).contains(&share) && (0.0..=share).contains(&under)) {
                return None;
            }
            *pair = [share, under];
        }
        let total: f32 = by_age.iter().map(|pair| pair[0]).sum();
        ((total - 1.0).abs() <= 1e-3).then_some(Self { by_age })
    }

    fn from_sums(sums: [[f64; 2]; NEEDLE_AGE_CLASSES]) -> Option<Self> {
        let total: f64 = sums.iter().map(|sum| sum[0]).sum();
        if !(total > 0.0 && total.is_finite()) {
            return None;
        }
        Some(Self {
            by_age: sums.map(|[share, under]| {
                [
                    (share / total) as f32,
                    ((under / total) as f32).min((share / total) as f32),
                ]
            }),
        })
    }
}

fn age_class(age: u8) -> usize {
    usize::from(age).min(NEEDLE_AGE_CLASSES - 1)
}

/// One view's sums for [`NeedleMix::seen`]: by age class, the samples
/// whose nearest piece is a needle of that age, and those times the
/// underside the view sees of its shoot.
fn seen_in_view(
    record: &PrototypeRecord,
    uppers: &[Vec3],
    needles: &[&Needle],
    impostor: &CrownImpostor,
    view: u32,
) -> [[f64; 2]; NEEDLE_AGE_CLASSES] {
    let toward = impostor.view_toward(view);
    let nearest = impostor.nearest_pieces(
        view,
        &record.wood,
        needles,
        [SEEN_COLUMNS_PER_TEXEL, SEEN_ROWS_PER_TEXEL],
    );
    let mut sums = [[0.0f64; 2]; NEEDLE_AGE_CLASSES];
    for piece in nearest.needle_samples() {
        let group = needles[piece].group as usize;
        let (Some(placement), Some(&upper)) = (record.placements.get(group), uppers.get(group)) else {
            continue;
        };
        let sum = &mut sums[age_class(placement.needle_age)];
        sum[0] += 1.0;
        sum[1] += f64::from(underside_weight(upper, toward));
    }
    sums
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
        let mut record = bake_prototypes(&input, &BakeOptions::default(), &()).unwrap();
        let m = material();
        let edge_on = |age| needle_age_color(&m, age).lerp(rgb(m.needle_underside_color), 0.5);
        let expected = (edge_on(0) * 4.0 + edge_on(3)) / 5.0;
        let area = NeedleMix::of_area(&record).expect("needles");
        assert!(
            area.color(&m).distance(expected) < 1e-4,
            "{} against {expected}",
            area.color(&m)
        );
        // Without an impostor's seen mix the far colour is the area mean.
        record.impostor = None;
        assert_eq!(far_needle_color(&record), area.color(&m));
    }

    /// A panel of 25 touching needles, 10 cm wide and 10 cm tall, in the
    /// `x`–`y` plane, facing `+z`.
    fn panel() -> Vec<Needle> {
        (0..25)
            .map(|k| Needle {
                base: Vec3::new(-0.048 + k as f32 * 0.004, 0.0, 0.0),
                tip: Vec3::new(-0.048 + k as f32 * 0.004, 0.1, 0.0),
                radius: 0.0021,
                normal: Vec3::Z,
                group: 0,
            })
            .collect()
    }

    /// Panels round the `y` axis at `radius`, facing out, `per_ring` a
    /// ring and five rings from 0 to 0.4 m, their needles `age` years old.
    fn ring_of_panels(radius: f32, per_ring: u32, age: u8) -> Vec<Placement> {
        use glam::Quat;
        (0..5 * per_ring)
            .map(|k| {
                let angle = std::f32::consts::TAU * (k % per_ring) as f32 / per_ring as f32;
                Placement {
                    translation: Vec3::new(radius * angle.sin(), 0.1 * (k / per_ring) as f32, radius * angle.cos()),
                    rotation: Quat::from_rotation_y(angle),
                    needle_age: age,
                    ..Placement::identity(0)
                }
            })
            .collect()
    }

    #[test]
    fn the_far_colour_is_the_colour_of_the_needles_seen_from_outside() {
        use crate::model::{BakeOptions, PrototypeInput, bake_prototypes};
        // A closed shell of this year's shoots round a core of old ones
        // with as much needle area: from outside only the young show.
        let mut placements = ring_of_panels(0.5, 40, 0);
        let young = placements.len();
        placements.extend(ring_of_panels(0.15, 12, 5));
        placements.extend(ring_of_panels(0.25, 28, 5));
        let old = placements.len() - young;
        let input = PrototypeInput {
            name: "shell".into(),
            prototypes: vec![panel()],
            placements,
            material: material(),
            ..Default::default()
        };
        let record = bake_prototypes(&input, &BakeOptions::default(), &()).unwrap();
        let area = NeedleMix::of_area(&record).expect("needles");
        let impostor = record.impostor.as_deref().expect("an impostor");
        let seen = impostor.seen_needles.expect("needles seen");
        // The area counts every shoot; the views, the shell.
        assert!(
            (area.by_age[2][0] - old as f32 / (old + young) as f32).abs() < 1e-4,
            "{area:?}"
        );
        assert!(seen.by_age[0][0] > 0.99, "{seen:?}");
        assert_eq!(seen.by_age[1][0], 0.0);
        // Each view sees the panels at its sides edge-on, the rest
        // upright: undersides between none and half.
        assert!(
            seen.by_age[0][1] > 0.0 && seen.by_age[0][1] < 0.5 * seen.by_age[0][0],
            "{seen:?}"
        );
        let m = material();
        assert_eq!(far_needle_color(&record), seen.color(&m));
        assert!(
            seen.color(&m).distance(needle_age_color(&m, 0)) < 0.06,
            "{}",
            seen.color(&m)
        );
        // Measured again from the same needles, the same mix.
        assert_eq!(NeedleMix::seen(&record, &record.placed_needles(), impostor), Some(seen));
    }

    #[test]
    fn a_mix_of_one_age_is_that_ages_colour_and_keeps_its_six_numbers() {
        let m = material();
        for age in 0..NEEDLE_AGE_CLASSES {
            let mut by_age = [[0.0; 2]; NEEDLE_AGE_CLASSES];
            by_age[age] = [1.0, 0.0];
            let mix = NeedleMix { by_age };
            assert!(mix.color(&m).distance(needle_age_color(&m, age as u8)) < 1e-6);
            by_age[age] = [1.0, 1.0];
            let under = NeedleMix { by_age };
            assert!(under.color(&m).distance(rgb(m.needle_underside_color)) < 1e-6);
            assert_eq!(NeedleMix::from_array(under.to_array()), Some(under));
        }
        let mixed = NeedleMix {
            by_age: [[0.25, 0.1], [0.25, 0.0], [0.5, 0.2]],
        };
        assert_eq!(NeedleMix::from_array(mixed.to_array()), Some(mixed));
        for bad in [
            [0.5, 0.1, 0.25, 0.0, 0.5, 0.2], // sums to 1.25
            [1.0, 1.5, 0.0, 0.0, 0.0, 0.0],  // more underside than share
            [1.5, 0.0, -0.5, 0.0, 0.0, 0.0], // a share out of [0, 1]
            [f32::NAN, 0.0, 1.0, 0.0, 0.0, 0.0],
        ] {
            assert_eq!(NeedleMix::from_array(bad), None, "{bad:?}");
        }
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
