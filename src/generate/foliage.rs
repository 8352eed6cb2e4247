//! Needle placement: how many needles each foliage site gets (calibrated to
//! the requested total), and where they go for each phyllotaxy — pine
//! fascicles, spruce spirals, cypress scale leaves.

use std::f32::consts::{FRAC_PI_2, TAU};

use glam::{Mat3, Quat, Vec3};

use super::geometry::{GOLDEN_ANGLE, UP, bend, cone_direction, perpendicular_toward, rotate_around};
use super::params::{FoliageParams, Phyllotaxy};
use super::random::TreeRng;
use super::skeleton::{FoliageSite, Skeleton};
use crate::model::{Needle, Placement};

/// Radius of a young shoot: needles attach on its surface.
const SHOOT_RADIUS: f32 = 0.0015;

/// How many needles to place, and how much wider than the species' they are.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) struct NeedleBudget {
    /// Needles to place.
    pub target: usize,
    /// The species' natural count on this tree: the spiral floor is taken
    /// at its density.
    pub natural: usize,
    /// Radius factor (≥ 1) that keeps the summed needle area of the
    /// natural count.
    pub widening: f32,
    /// Length factor (≥ 1), for scale leaves, which grow in both directions
    /// to keep their shape.
    pub lengthening: f32,
}

/// Covers `sites` with about `budget.target` needles.
pub(crate) fn grow_needles(
    sites: &[FoliageSite],
    params: &FoliageParams,
    budget: NeedleBudget,
    rng: &mut TreeRng,
) -> Vec<Needle> {
    let units = units_per_site(sites, params, budget);
    let total_units: usize = units.iter().map(|&u| u as usize).sum();
    let mut placer = Placer::new(params, rng, UP, budget);
    placer.needles.reserve(total_units * needles_per_unit(params) as usize);
    for (site, &count) in sites.iter().zip(&units) {
        placer.grow(site, count);
    }
    placer.needles
}

/// Prototype variants grown per unit count and vigour class.
const VARIANTS: u32 = 3;

/// Ratio between neighbouring unit counts of the prototype library.
const UNIT_STEP: f32 = 1.25;

/// Shoots of the prototype library: `(units, vigour class, variant)`.
type ShootKey = (u32, u32, u32);

/// Covers `sites` with about `target` needles as shared shoot prototypes.
///
/// Every site gets its unit count as in [`grow_needles`], rounded to a
/// ladder of counts (steps of 25 %, the rounding errors diffused along the
/// sites so the total is kept) and drawn from [`VARIANTS`] variants and two
/// vigour classes. Each prototype is grown once on a canonical shoot (from
/// the origin along +Y, its upper side +Z, as long as the median site that
/// uses it); a site places it with the rotation onto its own axis and upper
/// side and the scale of its length. The species' droop and the spruce's
/// needles turning from beneath the shoot are grown toward the canonical
/// shoot's upper side, which is the world's up for the level shoots that
/// carry most foliage.
pub(crate) fn grow_shoot_prototypes(
    skeleton: &Skeleton,
    params: &FoliageParams,
    budget: NeedleBudget,
    rng: &mut TreeRng,
) -> (Vec<Vec<Needle>>, Vec<Placement>) {
    let sites = &skeleton.sites;
    // The budget is shared between the shoots and the twigs by weight.
    let (site_weight, twig_weight) = (skeleton.site_weight(), skeleton.placed_twig_weight());
    let share = site_weight / (site_weight + twig_weight).max(f32::MIN_POSITIVE);
    let site_budget = NeedleBudget {
        target: (budget.target as f32 * share).round() as usize,
        natural: (budget.natural as f32 * share).round() as usize,
        ..budget
    };
    let units = units_per_site(sites, params, site_budget);
    let largest = units.iter().copied().max().unwrap_or(0);
    let mut ladder = vec![1u32];
    while *ladder.last().expect("not empty") < largest {
        let last = *ladder.last().expect("not empty");
        ladder.push(((last as f32 * UNIT_STEP).round() as u32).max(last + 1));
    }
    // Each site's key, the rounding error carried to the next site.
    let mut carry = 0.0f32;
    let mut keyed: Vec<(usize, ShootKey)> = Vec::new();
    for (index, (site, &count)) in sites.iter().zip(&units).enumerate() {
        if count == 0 {
            continue;
        }
        let wanted = count as f32 + carry;
        let rung = ladder
            .iter()
            .copied()
            .min_by(|a, b| (*a as f32 - wanted).abs().total_cmp(&(*b as f32 - wanted).abs()))
            .unwrap_or(1);
        carry = wanted - rung as f32;
        let vigor_class = u32::from(site.vigor >= 0.85);
        keyed.push((index, (rung, vigor_class, rng.count((0, VARIANTS - 1)))));
    }
    // One prototype per key in use, as long as its median site.
    let mut library: std::collections::BTreeMap<ShootKey, Vec<usize>> = std::collections::BTreeMap::new();
    for &(index, key) in &keyed {
        library.entry(key).or_default().push(index);
    }
    let mut prototype_of = std::collections::HashMap::new();
    let mut prototypes = Vec::with_capacity(library.len());
    for (key, members) in &library {
        let mut lengths: Vec<f32> = members.iter().map(|&i| sites[i].start.distance(sites[i].end)).collect();
        lengths.sort_by(f32::total_cmp);
        let length = lengths[lengths.len() / 2].max(1e-3);
        let mut vigors: Vec<f32> = members.iter().map(|&i| sites[i].vigor).collect();
        vigors.sort_by(f32::total_cmp);
        let canonical = FoliageSite {
            start: Vec3::ZERO,
            end: Vec3::Y * length,
            up: Vec3::Z,
            weight: length,
            group_key: 0,
            vigor: vigors[vigors.len() / 2],
            age: 0.0,
        };
        let mut placer = Placer::new(params, &mut *rng, Vec3::Z, budget);
        placer.grow(&canonical, key.0);
        prototype_of.insert(*key, (prototypes.len() as u32, length));
        prototypes.push(placer.needles);
    }
    let mut placements: Vec<Placement> = keyed
        .iter()
        .map(|&(index, key)| {
            let site = &sites[index];
            let (prototype, length) = prototype_of[&key];
            let axis = site.axis();
            let up = perpendicular_toward(axis, site.up);
            let frame = Mat3::from_cols(axis.cross(up), axis, up);
            Placement {
                prototype,
                rotation: Quat::from_mat3(&frame).normalize(),
                translation: site.start,
                scale: (site.start.distance(site.end) / length).max(1e-3),
                needle_age: needle_age(site.age),
            }
        })
        .collect();
    if twig_weight > 0.0 {
        let twig_share = twig_weight / (site_weight + twig_weight);
        grow_twig_prototypes(
            skeleton,
            params,
            budget,
            twig_share,
            rng,
            &mut prototypes,
            &mut placements,
        );
    }
    (prototypes, placements)
}

/// Covers each used twig of `skeleton` with needles at one density (the
/// budget's `share`, calibrated like [`units_per_site`]) as one prototype,
/// and places it wherever the twig stands. The placed twigs must weigh
/// more than nothing.
fn grow_twig_prototypes(
    skeleton: &Skeleton,
    params: &FoliageParams,
    budget: NeedleBudget,
    share: f32,
    rng: &mut TreeRng,
    prototypes: &mut Vec<Vec<Needle>>,
    placements: &mut Vec<Placement>,
) {
    let twig_weight = skeleton.placed_twig_weight();
    let per_unit = needles_per_unit(params) as f32;
    let target_units = budget.target as f32 * share / per_unit;
    let default_density = budget.natural.max(1) as f32 * share / per_unit / twig_weight;
    let mut uses = vec![0u32; skeleton.twigs.len()];
    for placement in &skeleton.twig_placements {
        uses[placement.twig as usize] += 1;
    }
    let units = calibrate(params, target_units, twig_weight, default_density, |density, floor| {
        let units: Vec<Vec<u32>> = skeleton
            .twigs
            .iter()
            .map(|t| diffuse(&t.sites, density, floor))
            .collect();
        let total: f32 = units
            .iter()
            .zip(&uses)
            .map(|(u, &n)| u.iter().sum::<u32>() as f32 * n as f32)
            .sum();
        (units, total)
    });
    let mut prototype_of = vec![None; skeleton.twigs.len()];
    // A twig's needles are of several ages; it is placed at their mean.
    let twig_ages: Vec<u8> = skeleton
        .twigs
        .iter()
        .zip(&units)
        .map(|(twig, units)| {
            let (sum, count) = twig
                .sites
                .iter()
                .zip(units)
                .fold((0.0f32, 0u32), |(sum, count), (site, &u)| {
                    (sum + site.age * u as f32, count + u)
                });
            needle_age(sum / count.max(1) as f32)
        })
        .collect();
    for (index, twig) in skeleton.twigs.iter().enumerate() {
        if uses[index] == 0 || units[index].iter().all(|&u| u == 0) {
            continue;
        }
        let mut placer = Placer::new(params, &mut *rng, UP, budget);
        for (site, &count) in twig.sites.iter().zip(&units[index]) {
            placer.grow(site, count);
        }
        prototype_of[index] = Some(prototypes.len() as u32);
        prototypes.push(placer.needles);
    }
    placements.extend(skeleton.twig_placements.iter().filter_map(|p| {
        Some(Placement {
            prototype: prototype_of[p.twig as usize]?,
            rotation: p.rotation,
            translation: p.translation,
            scale: p.scale.max(1e-3),
            needle_age: twig_ages[p.twig as usize],
        })
    }));
}

/// A site's mean needle age as a placement's whole years.
fn needle_age(age: f32) -> u8 {
    age.round().clamp(0.0, u8::MAX as f32) as u8
}

/// Needles per placed unit: a fascicle's needles, or 1.
fn needles_per_unit(params: &FoliageParams) -> u32 {
    match params.phyllotaxy {
        Phyllotaxy::Fascicle { needles, .. } => needles.max(1),
        Phyllotaxy::Spiral | Phyllotaxy::Scales | Phyllotaxy::TwoRanked { .. } => 1,
    }
}

/// Units (fascicles or needles) per site, proportional to the site's
/// weight, rounded with error diffusion, with the minimum shoot group size
/// for spirals; the density is adjusted until the total meets `target`.
fn units_per_site(sites: &[FoliageSite], params: &FoliageParams, budget: NeedleBudget) -> Vec<u32> {
    let per_unit = needles_per_unit(params) as f32;
    let target_units = (budget.target as f32 / per_unit).round();
    let total_weight: f32 = sites.iter().map(|s| s.weight).sum();
    if target_units < 1.0 || total_weight <= 0.0 {
        return vec![0; sites.len()];
    }
    let default_density = budget.natural.max(1) as f32 / per_unit / total_weight;
    calibrate(params, target_units, total_weight, default_density, |density, floor| {
        let units = diffuse(sites, density, floor);
        let total = units.iter().map(|&u| u as f32).sum();
        (units, total)
    })
}

/// The units of the density (per unit of site weight) that best meets
/// `target_units`: `place(density, floor)` gives the units at a density
/// with the phyllotaxy's floor and their total. Up to 12 tries, each
/// scaling the density by the miss; the closest is kept (the floor can make
/// the total jump over the target back and forth).
fn calibrate<T>(
    params: &FoliageParams,
    target_units: f32,
    weight: f32,
    default_density: f32,
    mut place: impl FnMut(f32, u32) -> (T, f32),
) -> T {
    let mut density = target_units / weight;
    let mut best: Option<(f32, T)> = None;
    for _ in 0..12 {
        let floor = minimum_units(params, density / default_density);
        let (units, total) = place(density, floor);
        let total = total.max(1.0);
        let miss = (total - target_units).abs();
        if best.as_ref().is_none_or(|(closest, _)| miss < *closest) {
            best = Some((miss, units));
        }
        if miss <= 0.002 * target_units {
            break;
        }
        density *= target_units / total;
    }
    best.expect("at least one try").1
}

/// The fewest needles a spiral or two-rowed shoot gets at
/// `relative_density` (1 = the species' default density); other
/// phyllotaxies have no floor.
fn minimum_units(params: &FoliageParams, relative_density: f32) -> u32 {
    match params.phyllotaxy {
        Phyllotaxy::Spiral | Phyllotaxy::TwoRanked { .. } => {
            // Full floor from 85 % of the default density: the default
            // count's per-seed vigour (±8 %) keeps it.
            let scale = (relative_density / 0.85).min(1.0);
            (params.group_size.0 as f32 * scale).round() as u32
        }
        Phyllotaxy::Fascicle { .. } | Phyllotaxy::Scales => 0,
    }
}

/// `weight × density` per site, rounded so the rounding errors cancel out
/// along the list, then raised to `floor`.
fn diffuse(sites: &[FoliageSite], density: f32, floor: u32) -> Vec<u32> {
    let mut carry = 0.0_f32;
    sites
        .iter()
        .map(|site| {
            let wanted = site.weight * density + carry;
            let rounded = wanted.round().max(0.0);
            carry = wanted - rounded;
            (rounded as u32).max(floor)
        })
        .collect()
}

struct Placer<'a> {
    params: &'a FoliageParams,
    rng: &'a mut TreeRng,
    /// The world's up in the frame needles are grown in (droop, needles
    /// turning away from beneath the shoot).
    up: Vec3,
    /// Radius factor of every needle ([`NeedleBudget::widening`]).
    widening: f32,
    /// Length factor of every needle ([`NeedleBudget::lengthening`]).
    lengthening: f32,
    needles: Vec<Needle>,
    next_group: u32,
    /// Spray key and size of the scale-leaf group being filled.
    spray: Option<(u32, usize)>,
}

impl<'a> Placer<'a> {
    /// A placer of needles sized by `budget`, growing in a frame whose
    /// world up is `up`.
    fn new(params: &'a FoliageParams, rng: &'a mut TreeRng, up: Vec3, budget: NeedleBudget) -> Self {
        Self {
            params,
            rng,
            up,
            widening: budget.widening,
            lengthening: budget.lengthening,
            needles: Vec::new(),
            next_group: 0,
            spray: None,
        }
    }

    /// `count` units of the species' phyllotaxy on `site`.
    fn grow(&mut self, site: &FoliageSite, count: u32) {
        match self.params.phyllotaxy {
            Phyllotaxy::Fascicle { needles, spread, twist } => self.fascicles(site, count, needles, spread, twist),
            Phyllotaxy::Spiral => self.spiral(site, count),
            Phyllotaxy::Scales => self.scales(site, count),
            Phyllotaxy::TwoRanked { lift } => self.two_ranked(site, count, lift),
        }
    }

    /// Position of unit `index` of `count` along the site, 0 at its base:
    /// evenly spaced with jitter, crowded toward the tip for tufted species.
    fn position(&mut self, site: &FoliageSite, index: u32, count: u32) -> (f32, Vec3) {
        let even = ((index as f32 + 0.5 + 0.4 * self.rng.signed()) / count as f32).clamp(0.0, 1.0);
        let t = even.powf(1.0 / self.params.tip_crowding.max(1.0));
        (t, site.start.lerp(site.end, t))
    }

    /// Needle length for a site, shorter on weak shoots.
    fn length(&mut self, site: &FoliageSite) -> f32 {
        self.rng.range(self.params.length) * (0.8 + 0.2 * site.vigor.min(1.0))
    }

    /// Adds a needle; its length is kept within the species' range.
    fn push(&mut self, base: Vec3, dir: Vec3, length: f32, normal: Vec3, group: u32) {
        let (shortest, longest) = self.params.length;
        let radius = self.rng.range(self.params.radius) * self.widening;
        let length = length.clamp(shortest, longest) * self.lengthening;
        self.needles.push(Needle {
            base,
            tip: base + dir * length,
            radius,
            normal,
            group,
        });
    }

    /// Pine fascicles spirally on the shoot, each its own group: `needles`
    /// needles fanning `spread` from the bundle's axis, flat faces toward
    /// it, rolled by up to `twist`.
    fn fascicles(&mut self, site: &FoliageSite, count: u32, needles: u32, spread: f32, twist: f32) {
        let axis = site.axis();
        let phase = self.rng.unit() * TAU;
        for index in 0..count {
            let (_, pos) = self.position(site, index, count);
            let radial = cone_direction(axis, site.up, FRAC_PI_2, phase + index as f32 * GOLDEN_ANGLE);
            let divergence = self.rng.range(self.params.divergence);
            let bundle = (axis * divergence.cos() + radial * divergence.sin()).normalize();
            let bundle = bend(bundle, -self.up, self.params.droop * (0.6 + 0.4 * self.rng.unit()));
            let length = self.length(site);
            let roll = self.rng.unit() * TAU;
            let group = self.new_group();
            let base = pos + radial * SHOOT_RADIUS;
            for needle in 0..needles {
                let azimuth = roll + needle as f32 * TAU / needles as f32;
                let dir = cone_direction(bundle, radial, self.rng.jitter(spread, 0.3), azimuth);
                let outward = perpendicular_toward(dir, dir - bundle);
                let normal = rotate_around(outward, dir, twist * self.rng.signed());
                let needle_length = self.rng.jitter(length, 0.1);
                self.push(base, dir, needle_length, normal, group);
            }
        }
    }

    /// Spruce: single needles spirally all round the shoot, pointing
    /// forward; the ones beneath turn to the sides. The shoot is one group,
    /// split into even runs when it exceeds the maximum group size.
    fn spiral(&mut self, site: &FoliageSite, count: u32) {
        let axis = site.axis();
        let phase = self.rng.unit() * TAU;
        let (first_group, run_length) = self.shoot_runs(count);
        for index in 0..count {
            let (t, pos) = self.position(site, index, count);
            let mut radial = cone_direction(axis, site.up, FRAC_PI_2, phase + index as f32 * GOLDEN_ANGLE);
            let downward = -radial.dot(self.up);
            if downward > 0.0 {
                radial = perpendicular_toward(axis, radial + self.up * (0.8 * downward));
            }
            let divergence = self.rng.range(self.params.divergence);
            let dir = (axis * divergence.cos() + radial * divergence.sin()).normalize();
            let length = self.length(site) * (0.7 + 0.3 * (std::f32::consts::PI * t).sin());
            let normal = perpendicular_toward(dir, radial);
            self.push(
                pos + radial * SHOOT_RADIUS,
                dir,
                length,
                normal,
                first_group + index / run_length,
            );
        }
    }

    /// Fir: needles in two flat rows either side of the shoot, alternating
    /// left and right, raised `lift` above the shoot's plane; the ones from
    /// beneath the shoot twist round to the rows, so none hangs below it.
    /// Flat faces up. The shoot is one group, split like a spiral's.
    fn two_ranked(&mut self, site: &FoliageSite, count: u32, lift: f32) {
        let axis = site.axis();
        let up = perpendicular_toward(axis, site.up);
        let side = axis.cross(up).normalize_or(axis.any_orthonormal_vector());
        let (first_group, run_length) = self.shoot_runs(count);
        for index in 0..count {
            let (t, pos) = self.position(site, index, count);
            let row = if index % 2 == 0 { side } else { -side };
            let raise = lift * self.rng.jitter(1.0, 0.4) + 0.15 * self.rng.signed();
            let radial = (row * raise.cos() + up * raise.sin()).normalize();
            let divergence = self.rng.range(self.params.divergence);
            let dir = (axis * divergence.cos() + radial * divergence.sin()).normalize();
            let dir = bend(dir, -self.up, self.params.droop * self.rng.unit());
            // Shorter at both ends of the shoot.
            let length = self.length(site) * (0.75 + 0.25 * (std::f32::consts::PI * t).sin());
            self.push(
                pos + radial * SHOOT_RADIUS,
                dir,
                length,
                perpendicular_toward(dir, up),
                first_group + index / run_length,
            );
        }
    }

    /// Cypress scale leaves flat in the spray plane, cycling through a
    /// facial scale along the branchlet and lateral scales either side.
    fn scales(&mut self, site: &FoliageSite, count: u32) {
        let axis = site.axis();
        let in_plane = site.up.cross(axis).normalize_or(axis.any_orthonormal_vector());
        let first_kind = self.rng.count((0, 2));
        for index in 0..count {
            let (_, pos) = self.position(site, index, count);
            let angle = match (first_kind + index) % 3 {
                0 => 0.08 * self.rng.signed(),
                1 => self.rng.range(self.params.divergence),
                _ => -self.rng.range(self.params.divergence),
            };
            let dir = (axis * angle.cos() + in_plane * angle.sin()).normalize();
            let length = self.length(site);
            let group = self.spray_group(site.group_key);
            self.push(pos, dir, length, perpendicular_toward(dir, site.up), group);
        }
    }

    /// Groups for a shoot of `count` needles: one, or even runs when it
    /// exceeds the maximum group size. Returns the first group and the run
    /// length (needle `i` is in group `first + i / run_length`).
    fn shoot_runs(&mut self, count: u32) -> (u32, u32) {
        let max_group = self.params.group_size.1.max(1) as u32;
        let runs = count.div_ceil(max_group).max(1);
        let first_group = self.next_group;
        self.next_group += runs;
        (first_group, count.div_ceil(runs).max(1))
    }

    fn new_group(&mut self) -> u32 {
        let group = self.next_group;
        self.next_group += 1;
        group
    }

    /// The group of the next scale of spray `key`: the spray's current
    /// group, or a new one when the spray changes or the group is full.
    fn spray_group(&mut self, key: u32) -> u32 {
        let max_group = self.params.group_size.1.max(1);
        match self.spray {
            Some((current, size)) if current == key && size < max_group => {
                self.spray = Some((key, size + 1));
                self.next_group - 1
            }
            _ => {
                self.spray = Some((key, 1));
                self.new_group()
            }
        }
    }
}
