//! The numbers that make each species: one parameter set per preset, read
//! by the shared grower (`skeleton`, `spray`) and needle placer (`foliage`).
//! Lengths in metres, angles in radians.

use crate::model::FoliageMaterial;

/// Everything the generator needs to grow one species.
#[derive(Clone, Debug)]
pub(crate) struct SpeciesParams {
    pub trunk: TrunkParams,
    pub crown: CrownParams,
    pub branching: BranchParams,
    /// Flattened scale-leaf sprays (cypresses); `None` for needle-bearing shoots.
    pub spray: Option<SprayParams>,
    pub foliage: FoliageParams,
    /// The tree's material, its `upper_wood_heights` as fractions of the
    /// tree's height ([`SpeciesParams::material_for`]).
    pub material: FoliageMaterial,
}

impl SpeciesParams {
    /// The material of a grown tree `height` metres tall: the preset's
    /// bark heights, fractions of the height, in metres.
    pub(crate) fn material_for(&self, height: f32) -> FoliageMaterial {
        let [start, end] = self.material.upper_wood_heights;
        FoliageMaterial {
            upper_wood_heights: [start * height, end * height],
            ..self.material
        }
    }
}

/// The stem and its yearly height growth.
#[derive(Clone, Debug)]
pub(crate) struct TrunkParams {
    /// Number of annual growth units (the tree's age).
    pub age_years: u32,
    /// Range of the total height.
    pub height: (f32, f32),
    /// Radius at the ground.
    pub base_radius: f32,
    /// Yearly height increment grows like `year^growth_acceleration`.
    pub growth_acceleration: f32,
    /// Random lean added per trunk piece (crooked pines > straight spruce).
    pub wander: f32,
    /// How far the leader nods over at the top (cypress), radians at the tip.
    pub nod: f32,
    /// Length of the nodding part of the leader.
    pub nod_length: f32,
    /// Trunk pieces per annual unit; branching nodes sit at each piece's top.
    pub nodes_per_year: u32,
    /// Extra radius at the ground as a fraction of `base_radius` (root
    /// flare), fading within the lowest 3 % of the height.
    pub flare: f32,
}

/// The envelope the branches fill.
#[derive(Clone, Debug)]
pub(crate) struct CrownParams {
    /// The crown starts at this fraction of the height; lower branches are
    /// pruned (left as stubs when `BranchParams::stubs`).
    pub base_fraction: (f32, f32),
    /// Horizontal reach of the longest branch.
    pub radius: f32,
    /// How the reach varies from crown base to top.
    pub shape: CrownShape,
    /// Random spread of each branch's reach (fraction).
    pub irregularity: f32,
    /// Below the crown base, the top `dead_zone` fraction of the bare trunk
    /// keeps dead branches (bare wood, a fraction of a live branch's reach);
    /// lower down only stubs (`BranchParams::stubs`) or nothing.
    pub dead_zone: f32,
}

/// Crown silhouettes.
#[derive(Clone, Copy, Debug)]
pub(crate) enum CrownShape {
    /// Reach falls like `(1 - c)^exponent` from crown base (c = 0) to top (c = 1).
    Conical { exponent: f32 },
    /// Narrower at the crown base, widest a third of the way up, rounded top (pines).
    Rounded,
    /// A narrow column with a short tapering top (cypress).
    Columnar,
    /// Old pines: narrow low down, widest at 70 % of the crown, a flat dome
    /// on top (the upper branches level out under the leader's height).
    Umbrella,
    /// Old firs: a cone cut off flat, its upper branches still long and
    /// turned up to one height (the "stork's nest").
    StorksNest,
}

impl CrownShape {
    /// Fraction of the crown radius a branch at crown height `c` (0 = crown
    /// base, 1 = top) reaches.
    pub(crate) fn reach_fraction(self, c: f32) -> f32 {
        let c = c.clamp(0.0, 1.0);
        match self {
            CrownShape::Conical { exponent } => (1.0 - c).powf(exponent),
            CrownShape::Rounded => (1.0 - c).powf(0.4) * (0.6 + 0.4 * (c / 0.35).min(1.0)),
            CrownShape::Columnar => (1.0 - c).powf(0.45) * (0.75 + 0.25 * (1.0 - c)),
            CrownShape::Umbrella => {
                let rise = (c / 0.7).min(1.0);
                let fall = ((c - 0.7) / 0.3).max(0.0);
                (0.45 + 0.55 * (rise * std::f32::consts::FRAC_PI_2).sin()) * (1.0 - 0.55 * fall * fall)
            }
            CrownShape::StorksNest => (1.0 - 0.75 * c).powf(0.9),
        }
    }
}

/// Branches off the trunk (order 1) and their laterals (orders 2, 3, ...).
#[derive(Clone, Debug)]
pub(crate) struct BranchParams {
    /// Branches in the whorl at the top of each annual trunk unit.
    pub whorl_size: (u32, u32),
    /// Branches at each node inside an annual trunk unit.
    pub interwhorl_size: (u32, u32),
    /// Reach of interwhorl branches relative to whorl branches.
    pub interwhorl_vigor: f32,
    /// Angle from the vertical of branches at the crown base and at the top.
    pub angle_bottom: f32,
    pub angle_top: f32,
    /// Downward bending per metre of the older part of a branch (weight).
    pub sag: f32,
    /// Upward bending per metre of the youngest part (tips turning up).
    pub upturn: f32,
    /// Longest annual shoot of a first-order branch: young branches near
    /// the top stay short even where the crown envelope leaves room.
    pub max_annual_growth: f32,
    /// Highest branching order (1 = branches without laterals).
    pub max_order: u32,
    /// Branching nodes per annual unit of a branch.
    pub nodes_per_year: u32,
    /// Laterals at each node of a first-order branch.
    pub laterals: (u32, u32),
    /// Laterals at each node of a higher-order axis.
    pub sublaterals: (u32, u32),
    /// Angle between a lateral and its parent.
    pub lateral_angle: f32,
    /// Yearly length of a lateral relative to its parent's.
    pub lateral_length: f32,
    /// Probability that a lateral lies in the branch's horizontal plane
    /// (left/right) rather than at a random azimuth.
    pub planarity: f32,
    /// Extra downward bending per metre of axes of order `hanging_from_order`
    /// and higher (hanging branchlets).
    pub hanging: f32,
    /// Lowest order that hangs (3 in young spruce; 2 gives an old spruce's
    /// curtains of branchlets).
    pub hanging_from_order: u32,
    /// Nodes of an axis older than this many years carry no laterals: they
    /// were shed in the shaded interior, so foliage sits at the branch ends.
    pub shed_years: u32,
    /// Chance that a branch of a whorl is missing; half as many again are
    /// broken off at a random age.
    pub loss: f32,
    /// Random sideways turn per metre of a branch (crooked old pine limbs).
    pub crookedness: f32,
    /// Laterals whose yearly shoot would be shorter than this (metres) do
    /// not grow.
    pub min_shoot: f32,
    /// Most growth units a first-order branch is grown as: an older branch
    /// grew most of its length while young and lit, so it is grown as this
    /// many longer units (its shaded old wood carries nothing).
    pub branch_units: u32,
    /// Consecutive pieces of an axis merged into one foliage site and one
    /// wood segment (1: every piece its own), so a big tree's shoots and
    /// wood stay within a record's budget.
    pub merge_pieces: u32,
    /// Laterals of this order, with all they carry, are twigs grown once
    /// per age, shoot length class and variant and placed many times
    /// (shared prototypes); 0: none.
    pub twig_order: u32,
    /// Radius of a shoot tip (pipe model: a branch's cross-section is the
    /// sum of its tips').
    pub tip_radius: f32,
    /// Leave short dead stubs where branches were pruned below the crown.
    pub stubs: bool,
}

/// Flattened fern-like sprays of scale leaves (cypress).
#[derive(Clone, Debug)]
pub(crate) struct SprayParams {
    /// Distance between sprays along a young branch.
    pub spacing: f32,
    /// Length of a spray's main axis.
    pub length: (f32, f32),
    /// Angle between a spray and the axis it sits on.
    pub angle: f32,
    /// Distance between side branchlets along the spray axis.
    pub pinna_spacing: f32,
    /// Angle between a branchlet and the spray axis.
    pub pinna_angle: f32,
    /// Length of the lowest branchlet relative to the spray axis.
    pub pinna_length: f32,
    /// How much a spray's tip bends down (radians over its length).
    pub droop: f32,
    /// Random roll of the spray plane about the spray axis, up to this many
    /// radians either way (0: every spray lies in the branch plane).
    pub roll: f32,
}

/// How needles sit on a shoot.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) enum Phyllotaxy {
    /// Pines: bundles of `needles` needles, spread `spread` radians from the
    /// bundle's axis, each needle rolled up to `twist` radians.
    Fascicle { needles: u32, spread: f32, twist: f32 },
    /// Spruces: single needles spirally all around the shoot, the shoot
    /// (or a run of it) being the group.
    Spiral,
    /// Cypresses: scale leaves lying flat in the spray plane, one spray a group.
    Scales,
    /// Firs: needles in two flat rows either side of the shoot, raised by
    /// `lift` radians above the shoot's plane (a shallow V).
    TwoRanked { lift: f32 },
}

/// How many needles a tree of the species carries.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) enum NeedleCount {
    /// This many at default options (young presets), the density on the
    /// shoots following from it.
    Total(usize),
    /// Needles per metre of young shoot at full survival: the count follows
    /// from the tree. A record carries at most `most` needles; above it the
    /// needles widen, keeping their summed area (and the crown's density),
    /// then grow both ways up to `growth` times as long (scale leaves: both
    /// ways from the start, up to `growth` times).
    PerMetre { per_metre: f32, most: usize, growth: f32 },
}

/// Needle shape, density and grouping.
#[derive(Clone, Debug)]
pub(crate) struct FoliageParams {
    pub phyllotaxy: Phyllotaxy,
    /// Needle count at default options (before a ±8 % per-seed vigour factor).
    pub count: NeedleCount,
    /// Shoots (or sprays) younger than this carry needles.
    pub retention_years: u32,
    /// Needle density on a shoot one year older, relative (needle fall).
    pub survival_per_year: f32,
    pub length: (f32, f32),
    pub radius: (f32, f32),
    /// Angle between a needle (or fascicle, or lateral scale) and its shoot.
    pub divergence: (f32, f32),
    /// How much needles bend toward the ground (soft needles).
    pub droop: f32,
    /// ≥ 1: above 1 crowds the needles toward the shoot tip (tufts).
    pub tip_crowding: f32,
    /// Group sizes for `Spiral`/`Scales`: a shoot with fewer than `.0`
    /// needles at default density gets `.0`; a group never exceeds `.1`.
    pub group_size: (usize, usize),
}

pub(crate) const fn deg(degrees: f32) -> f32 {
    degrees * (std::f32::consts::PI / 180.0)
}

/// Linear colour from 8-bit sRGB.
pub(crate) fn srgb(r: u8, g: u8, b: u8) -> [f32; 4] {
    let lin = |c: u8| {
        let c = f32::from(c) / 255.0;
        if c <= 0.04045 {
            c / 12.92
        } else {
            ((c + 0.055) / 1.055).powf(2.4)
        }
    };
    [lin(r), lin(g), lin(b), 1.0]
}

/// Scots pine (*Pinus sylvestris*), about 10 years old, 3.3–4.3 m: an
/// irregular rounded crown on a trunk bare of live branches in its lower
/// quarter, 2-needle fascicles of stiff twisted blue-green needles.
pub(crate) fn scots_pine() -> SpeciesParams {
    SpeciesParams {
        trunk: TrunkParams {
            age_years: 10,
            height: (3.3, 4.3),
            base_radius: 0.065,
            growth_acceleration: 0.6,
            wander: 0.06,
            nod: 0.0,
            nod_length: 0.0,
            nodes_per_year: 2,
            flare: 0.0,
        },
        crown: CrownParams {
            base_fraction: (0.22, 0.32),
            radius: 1.4,
            shape: CrownShape::Rounded,
            irregularity: 0.45,
            dead_zone: 0.0,
        },
        branching: BranchParams {
            whorl_size: (4, 6),
            interwhorl_size: (0, 0),
            interwhorl_vigor: 0.0,
            angle_bottom: deg(72.0),
            angle_top: deg(50.0),
            sag: 0.25,
            upturn: 0.9,
            max_annual_growth: 0.32,
            max_order: 3,
            nodes_per_year: 1,
            laterals: (3, 4),
            sublaterals: (2, 3),
            lateral_angle: deg(42.0),
            lateral_length: 0.7,
            planarity: 0.45,
            hanging: 0.0,
            hanging_from_order: 3,
            shed_years: u32::MAX,
            loss: 0.0,
            crookedness: 0.0,
            min_shoot: 0.0,
            branch_units: u32::MAX,
            merge_pieces: 1,
            twig_order: 0,
            tip_radius: 0.002,
            stubs: true,
        },
        spray: None,
        foliage: FoliageParams {
            phyllotaxy: Phyllotaxy::Fascicle {
                needles: 2,
                spread: deg(9.0),
                twist: deg(60.0),
            },
            count: NeedleCount::Total(56_000),
            retention_years: 3,
            survival_per_year: 0.8,
            length: (0.03, 0.07),
            radius: (0.0007, 0.001),
            divergence: (deg(30.0), deg(55.0)),
            droop: 0.05,
            tip_crowding: 1.0,
            group_size: (2, 2),
        },
        material: FoliageMaterial::uniform(srgb(62, 98, 80), srgb(120, 72, 44), 0.7, 0.35),
    }
}

/// Norway spruce (*Picea abies*), about 8 years old, ~3 m: a dense cone down
/// to the ground, single needles all round each shoot, hanging branchlets.
pub(crate) fn norway_spruce() -> SpeciesParams {
    SpeciesParams {
        trunk: TrunkParams {
            age_years: 8,
            height: (2.7, 3.3),
            base_radius: 0.04,
            growth_acceleration: 0.8,
            wander: 0.015,
            nod: 0.0,
            nod_length: 0.0,
            nodes_per_year: 3,
            flare: 0.0,
        },
        crown: CrownParams {
            base_fraction: (0.0, 0.04),
            radius: 0.75,
            shape: CrownShape::Conical { exponent: 0.8 },
            irregularity: 0.15,
            dead_zone: 0.0,
        },
        branching: BranchParams {
            whorl_size: (4, 6),
            interwhorl_size: (1, 2),
            interwhorl_vigor: 0.6,
            angle_bottom: deg(90.0),
            angle_top: deg(55.0),
            sag: 0.6,
            upturn: 1.2,
            max_annual_growth: 0.22,
            max_order: 3,
            nodes_per_year: 1,
            laterals: (2, 2),
            sublaterals: (1, 1),
            lateral_angle: deg(50.0),
            lateral_length: 0.5,
            planarity: 0.9,
            hanging: 2.5,
            hanging_from_order: 3,
            shed_years: u32::MAX,
            loss: 0.0,
            crookedness: 0.0,
            min_shoot: 0.0,
            branch_units: u32::MAX,
            merge_pieces: 1,
            twig_order: 0,
            tip_radius: 0.001,
            stubs: false,
        },
        spray: None,
        foliage: FoliageParams {
            phyllotaxy: Phyllotaxy::Spiral,
            count: NeedleCount::Total(70_000),
            retention_years: 5,
            survival_per_year: 0.75,
            length: (0.013, 0.025),
            radius: (0.0005, 0.0007),
            divergence: (deg(45.0), deg(70.0)),
            droop: 0.0,
            tip_crowding: 1.0,
            group_size: (10, 60),
        },
        material: FoliageMaterial::uniform(srgb(34, 72, 36), srgb(96, 66, 50), 0.65, 0.3),
    }
}

/// Eastern white pine (*Pinus strobus*), about 10 years old, 3.9–4.8 m: an open
/// crown of nearly level branch layers, soft drooping 5-needle fascicles in
/// tufts at the shoot ends.
pub(crate) fn eastern_white_pine() -> SpeciesParams {
    SpeciesParams {
        trunk: TrunkParams {
            age_years: 10,
            height: (3.9, 4.8),
            base_radius: 0.08,
            growth_acceleration: 1.2,
            wander: 0.02,
            nod: 0.0,
            nod_length: 0.0,
            nodes_per_year: 2,
            flare: 0.0,
        },
        crown: CrownParams {
            base_fraction: (0.1, 0.18),
            radius: 1.5,
            shape: CrownShape::Conical { exponent: 0.9 },
            irregularity: 0.2,
            dead_zone: 0.0,
        },
        branching: BranchParams {
            whorl_size: (4, 6),
            interwhorl_size: (0, 0),
            interwhorl_vigor: 0.0,
            angle_bottom: deg(84.0),
            angle_top: deg(55.0),
            sag: 0.15,
            upturn: 0.5,
            max_annual_growth: 0.4,
            max_order: 3,
            nodes_per_year: 1,
            laterals: (2, 3),
            sublaterals: (2, 3),
            lateral_angle: deg(45.0),
            lateral_length: 0.65,
            planarity: 0.9,
            hanging: 0.0,
            hanging_from_order: 3,
            shed_years: u32::MAX,
            loss: 0.0,
            crookedness: 0.0,
            min_shoot: 0.0,
            branch_units: u32::MAX,
            merge_pieces: 1,
            twig_order: 0,
            tip_radius: 0.002,
            stubs: false,
        },
        spray: None,
        foliage: FoliageParams {
            // Sheathed: the five needles leave the sheath together and lie
            // nearly parallel for most of their length.
            phyllotaxy: Phyllotaxy::Fascicle {
                needles: 5,
                spread: deg(1.0),
                twist: deg(30.0),
            },
            count: NeedleCount::Total(62_000),
            retention_years: 2,
            survival_per_year: 0.7,
            length: (0.06, 0.13),
            radius: (0.0004, 0.0005),
            divergence: (deg(20.0), deg(40.0)),
            droop: 0.5,
            tip_crowding: 2.2,
            group_size: (5, 5),
        },
        material: FoliageMaterial::uniform(srgb(74, 110, 88), srgb(88, 80, 68), 0.5, 0.3),
    }
}

/// Lawson cypress (*Chamaecyparis lawsoniana*). The paper's is 30 years old
/// and 8–10 m; modelled as scale leaves that tree would need millions of
/// needles, so this preset is a young tree, about 6 years old and 2.0–2.4 m,
/// with the species' form: a narrow columnar cone with a nodding leader,
/// many short ascending branches carrying flat fern-like sprays of tiny
/// scale leaves.
pub(crate) fn lawson_cypress() -> SpeciesParams {
    SpeciesParams {
        trunk: TrunkParams {
            age_years: 6,
            height: (2.0, 2.4),
            base_radius: 0.016,
            growth_acceleration: 0.8,
            wander: 0.015,
            nod: deg(75.0),
            nod_length: 0.3,
            nodes_per_year: 10,
            flare: 0.0,
        },
        crown: CrownParams {
            base_fraction: (0.0, 0.03),
            radius: 0.42,
            shape: CrownShape::Columnar,
            irregularity: 0.2,
            dead_zone: 0.0,
        },
        branching: BranchParams {
            whorl_size: (1, 2),
            interwhorl_size: (1, 1),
            interwhorl_vigor: 0.9,
            angle_bottom: deg(70.0),
            angle_top: deg(35.0),
            sag: 0.3,
            upturn: 0.2,
            max_annual_growth: 0.18,
            max_order: 2,
            nodes_per_year: 1,
            laterals: (1, 1),
            sublaterals: (1, 1),
            lateral_angle: deg(45.0),
            lateral_length: 0.5,
            planarity: 1.0,
            hanging: 0.0,
            hanging_from_order: 3,
            shed_years: u32::MAX,
            loss: 0.0,
            crookedness: 0.0,
            min_shoot: 0.0,
            branch_units: u32::MAX,
            merge_pieces: 1,
            twig_order: 0,
            tip_radius: 0.0006,
            stubs: false,
        },
        spray: Some(SprayParams {
            spacing: 0.06,
            length: (0.07, 0.12),
            angle: deg(50.0),
            pinna_spacing: 0.004,
            pinna_angle: deg(45.0),
            pinna_length: 0.35,
            droop: 0.8,
            roll: 0.9,
        }),
        foliage: FoliageParams {
            phyllotaxy: Phyllotaxy::Scales,
            count: NeedleCount::Total(74_000),
            retention_years: 2,
            survival_per_year: 0.8,
            length: (0.0025, 0.004),
            radius: (0.00045, 0.00055),
            divergence: (deg(25.0), deg(35.0)),
            droop: 0.0,
            tip_crowding: 1.0,
            group_size: (1, 600),
        },
        material: FoliageMaterial::uniform(srgb(40, 88, 48), srgb(110, 62, 42), 0.55, 0.3),
    }
}
