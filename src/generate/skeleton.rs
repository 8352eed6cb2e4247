//! The shared branch grower: a trunk of annual growth units with whorls of
//! branches, each branch a chain of annual units with laterals at its nodes
//! (up to `max_order`), radii from the pipe model. It emits the wood and the
//! foliage sites (young shoots, or the branchlets of sprays) that the needle
//! placer then covers.

use std::f32::consts::{PI, TAU};

use std::collections::HashMap;

use glam::{Mat3, Quat, Vec3};

use super::geometry::{
    GOLDEN_ANGLE, UP, bend_vertically, cone_direction, from_vertical, horizontal, perpendicular_toward,
};
use super::params::{SpeciesParams, SprayParams};
use super::random::TreeRng;
use super::spray::{SprayStart, grow_spray};
use crate::model::WoodSegment;

/// A straight piece of shoot (or spray branchlet) that carries needles.
#[derive(Clone, Copy, Debug)]
pub(crate) struct FoliageSite {
    pub start: Vec3,
    pub end: Vec3,
    /// Unit vector perpendicular to the shoot: its upper side, or the normal
    /// of the spray plane.
    pub up: Vec3,
    /// Needle capacity at unit density: length × needle survival.
    pub weight: f32,
    /// Consecutive sites with the same key form one phyllotaxy group (a spray).
    pub group_key: u32,
    /// Shoot vigour (≈ 0.5–1.2): weaker shoots carry shorter needles.
    pub vigor: f32,
    /// Age of its needles, years (0: grown this year); the mean over the
    /// annual pieces it spans.
    pub age: f32,
}

impl FoliageSite {
    /// Unit direction from start to end.
    pub(crate) fn axis(&self) -> Vec3 {
        (self.end - self.start).normalize_or(UP)
    }
}

/// Exponent of the pipe model (da Vinci's rule): a branch's `r^e` is the
/// sum of its children's. 2 conserves area; real trees are nearer 2.5.
const PIPE_EXPONENT: f32 = 2.5;

/// Lowest height a branch may reach.
const GROUND_CLEARANCE: f32 = 0.05;

/// `dir`, levelled (and then turned slightly up) when a piece of `length`
/// along it from `pos` would dip below the ground clearance.
fn keep_above_ground(pos: Vec3, dir: Vec3, length: f32) -> Vec3 {
    if pos.y + dir.y * length >= GROUND_CLEARANCE {
        return dir;
    }
    let climb = ((GROUND_CLEARANCE - pos.y) / length).clamp(0.0, 0.5);
    let flat = Vec3::new(dir.x, 0.0, dir.z).normalize_or(Vec3::X);
    (flat * (1.0 - climb * climb).sqrt() + UP * climb).normalize()
}

/// `dir`, levelled when a piece of `length` along it from `pos` would rise
/// above 97 % of the tree's height: no branch overtops the leader.
fn keep_below_leader(pos: Vec3, dir: Vec3, length: f32, height: f32) -> Vec3 {
    let ceiling = 0.97 * height;
    if pos.y + dir.y * length <= ceiling || dir.y <= 0.0 {
        return dir;
    }
    let rise = ((ceiling - pos.y) / length).clamp(-0.3, dir.y);
    let flat = Vec3::new(dir.x, 0.0, dir.z).normalize_or(Vec3::X);
    (flat * (1.0 - rise * rise).sqrt() + UP * rise).normalize()
}

/// The grown tree without needles.
pub(crate) struct Skeleton {
    pub wood: Vec<WoodSegment>,
    pub sites: Vec<FoliageSite>,
    /// Twigs grown once in their own frame (`BranchParams::twig_order`).
    pub twigs: Vec<Twig>,
    /// Where each twig stands in the tree.
    pub twig_placements: Vec<TwigPlacement>,
}

impl Skeleton {
    /// Summed weight of the foliage sites (needle capacity at unit density).
    pub(crate) fn site_weight(&self) -> f32 {
        self.sites.iter().map(|s| s.weight).sum()
    }

    /// Summed weight of the twigs as placed, each counted once per
    /// placement at its prototype's size (a placement carries its
    /// prototype's needles whatever its scale).
    pub(crate) fn placed_twig_weight(&self) -> f32 {
        self.twig_placements
            .iter()
            .map(|p| self.twigs[p.twig as usize].weight())
            .sum()
    }
}

/// A lateral system grown once in its own frame and placed many times: its
/// base at the origin, its first shoot along +X, the world's up +Y.
#[derive(Clone, Debug)]
pub(crate) struct Twig {
    /// Its foliage sites, in its frame.
    pub sites: Vec<FoliageSite>,
}

impl Twig {
    /// Summed site weight (needle capacity at unit density).
    pub(crate) fn weight(&self) -> f32 {
        self.sites.iter().map(|s| s.weight).sum()
    }
}

/// One twig in the tree: `p ↦ rotation · (scale · p) + translation`.
#[derive(Clone, Copy, Debug)]
pub(crate) struct TwigPlacement {
    pub twig: u32,
    pub rotation: Quat,
    pub translation: Vec3,
    pub scale: f32,
}

/// Ratio between neighbouring yearly shoot lengths of the twig library: a
/// twig is placed scaled by at most ±15 % of its prototype's.
const TWIG_LENGTH_STEP: f32 = 1.35;

/// Twig variants grown per age and length class.
const TWIG_VARIANTS: u32 = 2;

/// A twig class: age, shoot length class and variant.
type TwigKey = (u32, i32, u32);

/// Cuts the wood of an axis leaving an upright trunk `trunk_radius` thick
/// at `node` (on the trunk's axis) where it leaves the bark: `segments`
/// (tip first, each starting where the next ends) lose the base-most ones
/// that lie wholly inside the trunk's cylinder, and the one that crosses
/// the bark starts there, its radius taken at that point. Inside, a
/// branch's wood is hidden by the trunk in a picture of prisms, but as a
/// line it would lie over the trunk's line and the blend would count both.
fn cut_at_bark(segments: &mut Vec<WoodSegment>, node: Vec3, trunk_radius: f32) {
    if trunk_radius.is_nan() || trunk_radius <= 0.0 {
        return;
    }
    let from_axis = |point: Vec3| (point - node).with_y(0.0);
    let outside = |point: Vec3| from_axis(point).length_squared() >= trunk_radius * trunk_radius;
    while let Some(base) = segments.last_mut() {
        if outside(base.start) {
            return;
        }
        if !outside(base.end) {
            segments.pop();
            continue;
        }
        // |a + t·d| = r across the horizontal plane: the start is inside
        // (c < 0) and the end outside, so the larger root lies in (0, 1].
        let (a, d) = (from_axis(base.start), from_axis(base.end) - from_axis(base.start));
        let (qa, qb, qc) = (
            d.length_squared(),
            2.0 * a.dot(d),
            a.length_squared() - trunk_radius * trunk_radius,
        );
        let t = ((-qb + (qb * qb - 4.0 * qa * qc).max(0.0).sqrt()) / (2.0 * qa)).clamp(0.0, 1.0);
        base.start = base.start.lerp(base.end, t);
        base.start_radius += (base.end_radius - base.start_radius) * t;
        return;
    }
}

/// One branch (or lateral) to grow.
#[derive(Clone, Copy, Debug)]
struct Axis {
    origin: Vec3,
    direction: Vec3,
    /// Annual units, the oldest first.
    age: u32,
    order: u32,
    /// Length of one annual unit.
    segment_length: f32,
    vigor: f32,
    /// The pipe model's radius is capped here (a branch thinner than its parent).
    max_radius: f32,
    /// A dead branch below the crown: bare wood, no laterals.
    dead: bool,
    /// The radius of the trunk it leaves (0 for a lateral): its wood
    /// starts where it leaves the bark, so its line does not lie over the
    /// trunk's.
    trunk_radius: f32,
}

/// The site a run of consecutive pieces of one axis is merged into
/// (`BranchParams::merge_pieces`).
#[derive(Clone, Copy, Debug, Default)]
struct SiteRun {
    site: Option<usize>,
    pieces: u32,
}

/// A grown piece of an axis, waiting for its radius.
struct Piece {
    start: Vec3,
    end: Vec3,
    /// Sum of the laterals' base cross-section measures at `end`.
    children_measure: f32,
}

/// Grows the trunk, branches and foliage sites of one tree.
pub(crate) fn grow_skeleton(params: &SpeciesParams, rng: &mut TreeRng) -> Skeleton {
    let height = rng.range(params.trunk.height);
    let crown_base = height * rng.range(params.crown.base_fraction);
    let mut grower = Grower {
        params,
        rng,
        wood: Vec::new(),
        sites: Vec::new(),
        height,
        crown_base,
        next_group_key: 0,
        whorl_count: 0,
        in_tree: true,
        twigs: Vec::new(),
        twig_classes: HashMap::new(),
        twig_placements: Vec::new(),
    };
    grower.grow_trunk();
    Skeleton {
        wood: grower.wood,
        sites: grower.sites,
        twigs: grower.twigs,
        twig_placements: grower.twig_placements,
    }
}

struct Grower<'a> {
    params: &'a SpeciesParams,
    rng: &'a mut TreeRng,
    wood: Vec<WoodSegment>,
    sites: Vec<FoliageSite>,
    height: f32,
    crown_base: f32,
    next_group_key: u32,
    whorl_count: u32,
    /// Growing in the tree (kept above the ground and under the leader), not
    /// a twig in its own frame.
    in_tree: bool,
    twigs: Vec<Twig>,
    /// Each twig class's index, base cross-section measure and yearly shoot length.
    twig_classes: HashMap<TwigKey, (u32, f32, f32)>,
    twig_placements: Vec<TwigPlacement>,
}

impl Grower<'_> {
    /// Length of each annual trunk unit, summing to the tree's height.
    fn annual_increments(&mut self) -> Vec<f32> {
        let trunk = &self.params.trunk;
        let weights: Vec<f32> = (1..=trunk.age_years)
            .map(|year| (year as f32).powf(trunk.growth_acceleration) * self.rng.jitter(1.0, 0.15))
            .collect();
        let total: f32 = weights.iter().sum();
        weights.iter().map(|w| w * self.height / total).collect()
    }

    fn trunk_radius(&self, path: f32) -> f32 {
        let trunk = &self.params.trunk;
        let tip = self.params.branching.tip_radius * 1.5;
        let rest = (1.0 - path / self.height).clamp(0.0, 1.0);
        let flare = trunk.flare * (-path / (0.03 * self.height).max(1e-3)).exp();
        tip + (trunk.base_radius - tip) * rest.powf(0.9) + trunk.base_radius * flare
    }

    /// The trunk's direction at `path` metres up: vertical plus a slowly
    /// wandering lean, nodding over toward `nod_toward` near the top.
    fn trunk_direction(&self, lean: Vec3, path: f32, nod_toward: Vec3) -> Vec3 {
        let trunk = &self.params.trunk;
        let dir = (UP + lean).normalize();
        let nod_start = self.height - trunk.nod_length;
        if trunk.nod <= 0.0 || path <= nod_start {
            return dir;
        }
        let along = ((path - nod_start) / trunk.nod_length).min(1.0);
        let angle = trunk.nod * along.powf(1.5);
        let toward = perpendicular_toward(dir, nod_toward);
        dir * angle.cos() + toward * angle.sin()
    }

    fn grow_trunk(&mut self) {
        let params = self.params;
        let trunk = &params.trunk;
        let nodes = trunk.nodes_per_year.max(1);
        let nod_toward = horizontal(self.rng.unit() * TAU);
        let increments = self.annual_increments();
        let (mut pos, mut lean, mut path) = (Vec3::ZERO, Vec3::ZERO, 0.0);
        for (year, increment) in increments.iter().enumerate() {
            let years_old = trunk.age_years - 1 - year as u32;
            let piece = increment / nodes as f32;
            for node in 1..=nodes {
                lean = lean * 0.7 + horizontal(self.rng.unit() * TAU) * trunk.wander * self.rng.unit();
                let dir = self.trunk_direction(lean, path + 0.5 * piece, nod_toward);
                let end = pos + dir * piece;
                self.wood.push(WoodSegment {
                    start: pos,
                    end,
                    start_radius: self.trunk_radius(path),
                    end_radius: self.trunk_radius(path + piece),
                });
                let is_tip = year as u32 + 1 == trunk.age_years && node == nodes;
                self.add_foliage(&mut SiteRun::default(), pos, end, years_old, 1.2, is_tip);
                if years_old >= 1 {
                    let is_whorl = node == nodes;
                    self.grow_whorl(end, years_old, is_whorl, self.trunk_radius(path + piece));
                }
                pos = end;
                path += piece;
            }
        }
    }

    /// The branches at one trunk node: a whorl evenly spread around the
    /// trunk, or the few weaker interwhorl branches.
    fn grow_whorl(&mut self, node: Vec3, age: u32, is_whorl: bool, trunk_radius: f32) {
        let branching = &self.params.branching;
        let (size, vigor) = if is_whorl {
            (branching.whorl_size, 1.0)
        } else {
            (branching.interwhorl_size, branching.interwhorl_vigor)
        };
        let count = self.rng.count(size);
        self.whorl_count += 1;
        let first_azimuth = self.whorl_count as f32 * GOLDEN_ANGLE;
        let loss = self.params.branching.loss;
        for index in 0..count {
            let spread = TAU / count as f32;
            let azimuth = first_azimuth + index as f32 * spread + 0.35 * spread * self.rng.signed();
            // (No draws without loss: young presets keep their trees.)
            if loss > 0.0 && self.rng.chance(loss) {
                // Missing: lost long ago, a stub where the wood healed over.
                if self.params.branching.stubs {
                    self.grow_stub(node, azimuth, trunk_radius);
                }
                continue;
            }
            // Broken: the branch stopped growing at a random age.
            let age = if loss > 0.0 && self.rng.chance(0.5 * loss) {
                1 + self.rng.count((0, age.saturating_sub(1)))
            } else {
                age
            };
            self.grow_branch(node, azimuth, age, vigor, trunk_radius);
        }
    }

    /// One first-order branch, sized so its reach follows the crown shape.
    fn grow_branch(&mut self, node: Vec3, azimuth: f32, age: u32, vigor: f32, trunk_radius: f32) {
        let params = self.params;
        let crown = &params.crown;
        let dead = node.y < self.crown_base;
        if dead && node.y < self.crown_base * (1.0 - crown.dead_zone) {
            if params.branching.stubs {
                self.grow_stub(node, azimuth, trunk_radius);
            }
            return;
        }
        let crown_height = (self.height - self.crown_base).max(1e-3);
        let c = ((node.y - self.crown_base) / crown_height).max(0.0);
        // A dead branch keeps part of the reach it had when it died.
        let vigor = if dead { 0.4 * vigor } else { vigor };
        let reach = crown.radius * crown.shape.reach_fraction(c) * self.rng.jitter(1.0, crown.irregularity) * vigor;
        let branching = &params.branching;
        let angle =
            branching.angle_bottom + (branching.angle_top - branching.angle_bottom) * c + 0.12 * self.rng.signed();
        let age = age.min(branching.branch_units.max(1));
        let segment_length = (reach / (age as f32 * angle.sin().max(0.4))).clamp(0.02, branching.max_annual_growth);
        self.grow_axis(Axis {
            origin: node,
            direction: from_vertical(angle, azimuth),
            age,
            order: 1,
            segment_length,
            vigor: 0.8 + 0.2 * vigor,
            max_radius: if dead { 0.3 } else { 0.6 } * trunk_radius,
            dead,
            trunk_radius,
        });
    }

    /// A short dead stub where a branch below the crown was shed.
    fn grow_stub(&mut self, node: Vec3, azimuth: f32, trunk_radius: f32) {
        let direction = from_vertical(1.3 + 0.2 * self.rng.signed(), azimuth);
        let length = self.rng.range((0.03, 0.12));
        let radius = (0.25 * trunk_radius).min(0.008);
        // It sticks out of the bark (it leaves 4–27° from level).
        let start = node + direction * (trunk_radius / direction.with_y(0.0).length());
        self.wood.push(WoodSegment {
            start,
            end: start + direction * length,
            start_radius: radius,
            end_radius: 0.5 * radius,
        });
    }

    /// Grows an axis unit by unit (bending with age), its laterals
    /// recursively, and emits its wood. Returns its base cross-section
    /// measure for the parent's pipe model.
    fn grow_axis(&mut self, axis: Axis) -> f32 {
        let branching = &self.params.branching;
        let nodes = branching.nodes_per_year.max(1);
        let mut pieces = Vec::with_capacity((axis.age * nodes) as usize);
        let (mut pos, mut dir) = (axis.origin, axis.direction);
        let mut node_index = self.rng.count((0, 1));
        let mut run = SiteRun::default();
        for year in 0..axis.age {
            let years_old = axis.age - 1 - year;
            let youth = 1.0 - years_old as f32 / axis.age as f32;
            let piece_length = self.rng.jitter(axis.segment_length, 0.2) / nodes as f32;
            for node in 1..=nodes {
                dir = bend_vertically(dir, self.bending(axis.order, youth) * piece_length);
                if branching.crookedness > 0.0 {
                    let turn = horizontal(self.rng.unit() * TAU) * (branching.crookedness * piece_length);
                    dir = (dir + turn).normalize_or(dir);
                }
                if self.in_tree {
                    dir = keep_above_ground(pos, dir, piece_length);
                    dir = keep_below_leader(pos, dir, piece_length, self.height);
                }
                let end = pos + dir * piece_length;
                let is_tip = year + 1 == axis.age && node == nodes;
                if !axis.dead {
                    self.add_foliage(&mut run, pos, end, years_old, axis.vigor, is_tip);
                }
                let bears_laterals = years_old >= 1 && years_old < branching.shed_years && !axis.dead;
                let children_measure = if bears_laterals && axis.order < branching.max_order {
                    node_index += 1;
                    self.grow_laterals(end, dir, years_old, &axis, node_index)
                } else {
                    0.0
                };
                pieces.push(Piece {
                    start: pos,
                    end,
                    children_measure,
                });
                pos = end;
            }
        }
        self.emit_wood(&pieces, axis.max_radius, axis.trunk_radius)
    }

    /// Upward (positive) bending per metre: tips turn up, older wood sags,
    /// high-order branchlets hang.
    fn bending(&self, order: u32, youth: f32) -> f32 {
        let branching = &self.params.branching;
        let hanging = if order >= branching.hanging_from_order {
            branching.hanging
        } else {
            0.0
        };
        branching.upturn * youth * youth - branching.sag * (1.0 - youth) - hanging
    }

    /// The laterals at one node of `parent`, alternating left and right in
    /// the branch plane (with probability `planarity`) or at random azimuths.
    fn grow_laterals(&mut self, node: Vec3, parent_dir: Vec3, age: u32, parent: &Axis, node_index: u32) -> f32 {
        let branching = &self.params.branching;
        let count = self.rng.count(if parent.order == 1 {
            branching.laterals
        } else {
            branching.sublaterals
        });
        let side = perpendicular_toward(parent_dir, parent_dir.cross(UP));
        let mut measure = 0.0;
        for index in 0..count {
            let azimuth = if self.rng.chance(branching.planarity) {
                let left = (node_index + index).is_multiple_of(2);
                (if left { 0.0 } else { PI }) + 0.25 * self.rng.signed()
            } else {
                self.rng.unit() * TAU
            };
            let angle = self.rng.jitter(branching.lateral_angle, 0.2);
            let length_ratio = self.rng.jitter(branching.lateral_length, 0.2);
            if parent.segment_length * length_ratio < branching.min_shoot {
                // Too weak to grow: shaded buds stay dormant.
                continue;
            }
            let lateral = Axis {
                origin: node,
                direction: cone_direction(parent_dir, side, angle, azimuth),
                age,
                order: parent.order + 1,
                segment_length: parent.segment_length * length_ratio,
                vigor: parent.vigor * 0.85,
                max_radius: parent.max_radius * 0.7,
                dead: false,
                // The parent branch's radius here is known only once its
                // laterals are grown (the pipe model), so its laterals
                // start on its axis (a branch is far thinner than a trunk).
                trunk_radius: 0.0,
            };
            measure += if self.in_tree && lateral.order == branching.twig_order {
                self.place_twig(lateral)
            } else {
                self.grow_axis(lateral)
            };
        }
        measure
    }

    /// Places a twig of `axis`'s class, growing the class in its own frame
    /// the first time. Returns the placed twig's base cross-section measure.
    fn place_twig(&mut self, axis: Axis) -> f32 {
        let length_class = (axis.segment_length.max(1e-4).ln() / TWIG_LENGTH_STEP.ln()).round() as i32;
        let variant = self.rng.count((0, TWIG_VARIANTS - 1));
        let key = (axis.age, length_class, variant);
        let (twig, measure, length) = match self.twig_classes.get(&key) {
            Some(&class) => class,
            None => {
                let length = TWIG_LENGTH_STEP.powi(length_class);
                let (sites, measure) = self.grow_in_own_frame(Axis {
                    origin: Vec3::ZERO,
                    direction: Vec3::X,
                    segment_length: length,
                    ..axis
                });
                let class = (self.twigs.len() as u32, measure, length);
                self.twigs.push(Twig { sites });
                self.twig_classes.insert(key, class);
                class
            }
        };
        let scale = axis.segment_length / length;
        let up = perpendicular_toward(axis.direction, UP);
        let frame = Mat3::from_cols(axis.direction, up, axis.direction.cross(up));
        self.twig_placements.push(TwigPlacement {
            twig,
            rotation: Quat::from_mat3(&frame).normalize(),
            translation: axis.origin,
            scale,
        });
        measure * scale.powf(PIPE_EXPONENT)
    }

    /// Grows `axis` (at the origin) outside the tree: its foliage sites,
    /// and its base cross-section measure; its wood is left out (a twig's is
    /// millimetres thick, hidden by its needles).
    fn grow_in_own_frame(&mut self, axis: Axis) -> (Vec<FoliageSite>, f32) {
        let (wood, sites) = (std::mem::take(&mut self.wood), std::mem::take(&mut self.sites));
        self.in_tree = false;
        let measure = self.grow_axis(axis);
        self.in_tree = true;
        self.wood = wood;
        (std::mem::replace(&mut self.sites, sites), measure)
    }

    /// Wood of an axis from the pipe model: walking from the tip down, the
    /// cross-section measure `r^PIPE_EXPONENT` grows by each lateral's and
    /// a little per piece. Its wood starts where it leaves a trunk
    /// `trunk_radius` thick ([`cut_at_bark`]). Returns the measure at the
    /// base.
    fn emit_wood(&mut self, pieces: &[Piece], max_radius: f32, trunk_radius: f32) -> f32 {
        let tip = self.params.branching.tip_radius.powf(PIPE_EXPONENT);
        let max = max_radius.powf(PIPE_EXPONENT);
        let radius = |measure: f32| measure.min(max).powf(PIPE_EXPONENT.recip());
        let mut measure = tip;
        let mut segments = Vec::with_capacity(pieces.len());
        for piece in pieces.iter().rev() {
            measure += piece.children_measure;
            let end_radius = radius(measure);
            measure += 0.15 * tip;
            segments.push(WoodSegment {
                start: piece.start,
                end: piece.end,
                start_radius: radius(measure),
                end_radius,
            });
        }
        // Runs of `merge_pieces` pieces (from the tip) become one segment.
        let merge = self.params.branching.merge_pieces.max(1) as usize;
        let mut merged: Vec<WoodSegment> = segments
            .chunks(merge)
            .map(|run| {
                let (tip_most, base_most) = (run[0], run[run.len() - 1]);
                WoodSegment {
                    start: base_most.start,
                    end: tip_most.end,
                    start_radius: base_most.start_radius,
                    end_radius: tip_most.end_radius,
                }
            })
            .collect();
        if let Some(base) = pieces.first() {
            cut_at_bark(&mut merged, base.start, trunk_radius);
        }
        self.wood.extend(merged);
        measure.min(max)
    }

    /// Records the needle-bearing part of a young piece: the piece itself
    /// (needle shoots) or the sprays along it (scale-leaf species).
    fn add_foliage(&mut self, run: &mut SiteRun, start: Vec3, end: Vec3, years_old: u32, vigor: f32, is_tip: bool) {
        let foliage = &self.params.foliage;
        if years_old >= foliage.retention_years {
            return;
        }
        let weight_scale = foliage.survival_per_year.powi(years_old as i32);
        match &self.params.spray {
            Some(spray) => self.add_sprays(spray, start, end, weight_scale, vigor, years_old as f32, is_tip),
            None => {
                let weight = start.distance(end) * weight_scale;
                let merge = self.params.branching.merge_pieces.max(1);
                if let Some(index) = run.site.filter(|_| run.pieces < merge) {
                    let site = &mut self.sites[index];
                    if site.end.distance_squared(start) < 1e-12 {
                        site.age = (site.age * run.pieces as f32 + years_old as f32) / (run.pieces + 1) as f32;
                        site.end = end;
                        site.weight += weight;
                        site.up = perpendicular_toward((end - site.start).normalize_or(UP), UP);
                        run.pieces += 1;
                        return;
                    }
                }
                let dir = (end - start).normalize_or(UP);
                self.sites.push(FoliageSite {
                    start,
                    end,
                    up: perpendicular_toward(dir, UP),
                    weight,
                    group_key: self.next_group_key,
                    vigor,
                    age: years_old as f32,
                });
                self.next_group_key += 1;
                *run = SiteRun {
                    site: Some(self.sites.len() - 1),
                    pieces: 1,
                };
            }
        }
    }

    /// Sprays along a young piece, alternating sides in the branch plane,
    /// plus one continuing the axis at its tip.
    #[allow(clippy::too_many_arguments)] // The piece, as `add_foliage` takes it.
    fn add_sprays(
        &mut self,
        spray: &SprayParams,
        start: Vec3,
        end: Vec3,
        weight_scale: f32,
        vigor: f32,
        age: f32,
        is_tip: bool,
    ) {
        let dir = (end - start).normalize_or(UP);
        let side = perpendicular_toward(dir, dir.cross(UP));
        let count = self.rng.round(start.distance(end) / spray.spacing);
        for index in 0..count {
            let t = (index as f32 + 0.5 + 0.3 * self.rng.signed()) / count as f32;
            let toward = if (index + self.next_group_key).is_multiple_of(2) {
                side
            } else {
                -side
            };
            let angle = self.rng.jitter(spray.angle, 0.2);
            let spray_dir = (dir * angle.cos() + toward * angle.sin()).normalize();
            self.grow_one_spray(spray, start.lerp(end, t), spray_dir, weight_scale, vigor, age);
        }
        if is_tip {
            self.grow_one_spray(spray, end, dir, weight_scale, vigor, age);
        }
    }

    #[allow(clippy::too_many_arguments)] // The spray's start, as `SprayStart` holds it.
    fn grow_one_spray(
        &mut self,
        spray: &SprayParams,
        origin: Vec3,
        direction: Vec3,
        weight_scale: f32,
        vigor: f32,
        age: f32,
    ) {
        let start = SprayStart {
            origin,
            direction,
            group_key: self.next_group_key,
            weight_scale,
            vigor,
            age,
        };
        self.next_group_key += 1;
        grow_spray(&mut self.sites, self.rng, spray, start);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn segment(start: Vec3, end: Vec3) -> WoodSegment {
        WoodSegment {
            start,
            end,
            start_radius: 0.02,
            end_radius: 0.01,
        }
    }

    #[test]
    fn wood_is_cut_where_it_leaves_the_bark() {
        let node = Vec3::new(1.0, 2.0, 3.0);
        // Tip first: a level branch from the axis in two segments, the
        // base-most one crossing the bark 0.1 m out.
        let mut wood = vec![
            segment(node + Vec3::X * 0.4, node + Vec3::X),
            segment(node, node + Vec3::X * 0.4),
        ];
        cut_at_bark(&mut wood, node, 0.1);
        assert_eq!(wood.len(), 2);
        assert!(
            (wood[1].start - (node + Vec3::X * 0.1)).length() < 1e-6,
            "{:?}",
            wood[1].start
        );
        assert!(
            (wood[1].start_radius - 0.0175).abs() < 1e-6,
            "the radius a quarter along"
        );
        assert_eq!(
            wood[0],
            segment(node + Vec3::X * 0.4, node + Vec3::X),
            "the tip is untouched"
        );
        // Rising at 45°: it leaves the bark 0.1 m out, √2·0.1 along.
        let rising = Vec3::new(1.0, 1.0, 0.0).normalize();
        let mut wood = vec![segment(node, node + rising)];
        cut_at_bark(&mut wood, node, 0.1);
        assert!((wood[0].start.distance(node) - 0.1 * 2f32.sqrt()).abs() < 1e-5);
        // A base segment wholly inside the trunk goes; one wholly inside
        // branch goes all.
        let mut wood = vec![
            segment(node + Vec3::Z * 0.05, node + Vec3::Z),
            segment(node, node + Vec3::Z * 0.05),
        ];
        cut_at_bark(&mut wood, node, 0.1);
        assert_eq!(wood.len(), 1);
        assert!((wood[0].start - (node + Vec3::Z * 0.1)).length() < 1e-6);
        let mut wood = vec![segment(node, node + Vec3::Z * 0.05)];
        cut_at_bark(&mut wood, node, 0.1);
        assert!(wood.is_empty());
        // Wood that starts outside, and a trunk of no (or no valid)
        // radius, leave it as it is.
        for (start, radius) in [(node + Vec3::X * 0.2, 0.1), (node, 0.0), (node, f32::NAN)] {
            let mut wood = vec![segment(start, start + Vec3::X)];
            cut_at_bark(&mut wood, node, radius);
            assert_eq!(wood, vec![segment(start, start + Vec3::X)]);
        }
    }
}
