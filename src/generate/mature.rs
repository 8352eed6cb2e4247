//! Parameter sets of mature trees (the default presets), and the young
//! trees of the two species added with them.
//!
//! Sizes, crown shapes and needle forms follow the species' descriptions
//! in the preset table of the README. Needle colours are linear
//! reflectances within what conifer needles measure (red and blue
//! 0.03–0.05, green 0.08–0.10). Needle density is given per metre of young
//! shoot, so the count follows from the tree; a record keeps at most
//! [`RECORD_NEEDLES`] of them, wider, keeping their summed area.

use super::params::{
    BranchParams, CrownParams, CrownShape, FoliageParams, NeedleCount, Phyllotaxy, SpeciesParams, SprayParams,
    TrunkParams, deg, srgb,
};
use crate::model::FoliageMaterial;

/// Most needles a mature preset's record carries at default options.
pub(crate) const RECORD_NEEDLES: usize = 2_000_000;

/// How far a needle element grows both ways past its widening limit (a
/// scale element: both ways), unless a species says otherwise: twice.
const ELEMENT_GROWTH: f32 = 2.0;

/// The spruce's needle elements grow up to 3.5× as long (the cypress's
/// scale elements 15×): both reach their growth limit, and at twice (10×)
/// their crowns were more see-through than the species (0.20 and 0.33 at
/// 100 m; 3× gives the spruce 0.146, at the range's edge).
const DENSE_CROWN_GROWTH: f32 = 3.5;

/// The cypress's scale elements' growth.
const SPRAY_ELEMENT_GROWTH: f32 = 15.0;

/// `foliage` with its elements growing up to `growth` (see [`NeedleCount::PerMetre`]).
fn with_growth(mut foliage: FoliageParams, growth: f32) -> FoliageParams {
    if let NeedleCount::PerMetre { per_metre, most, .. } = foliage.count {
        foliage.count = NeedleCount::PerMetre {
            per_metre,
            most,
            growth,
        };
    }
    foliage
}

/// Scots pine, ~70 years, 18–25 m: a bare bole over half the height, an
/// umbrella crown of crooked limbs with the needles clumped at their ends.
pub(crate) fn scots_pine() -> SpeciesParams {
    SpeciesParams {
        trunk: TrunkParams {
            age_years: 70,
            height: (18.0, 25.0),
            base_radius: 0.22,
            growth_acceleration: 0.15,
            wander: 0.03,
            nod: 0.0,
            nod_length: 0.0,
            nodes_per_year: 1,
            flare: 0.4,
        },
        crown: CrownParams {
            base_fraction: (0.55, 0.66),
            radius: 3.6,
            shape: CrownShape::Umbrella,
            irregularity: 0.45,
            dead_zone: 0.12,
        },
        branching: BranchParams {
            whorl_size: (3, 5),
            interwhorl_size: (0, 0),
            interwhorl_vigor: 0.0,
            angle_bottom: deg(78.0),
            angle_top: deg(42.0),
            sag: 0.06,
            upturn: 0.6,
            max_annual_growth: 0.3,
            max_order: 4,
            nodes_per_year: 1,
            laterals: (2, 3),
            sublaterals: (2, 2),
            lateral_angle: deg(40.0),
            lateral_length: 0.75,
            planarity: 0.4,
            hanging: 0.0,
            hanging_from_order: 9,
            shed_years: 9,
            loss: 0.35,
            crookedness: 0.25,
            min_shoot: 0.03,
            branch_units: 24,
            merge_pieces: 6,
            twig_order: 3,
            tip_radius: 0.002,
            stubs: true,
        },
        spray: None,
        foliage: FoliageFor::pine(2, (0.03, 0.06), (0.0007, 0.001), 3, 1_000.0),
        material: FoliageMaterial {
            // Grey-brown and scaly at the foot, turning thin, flaky and
            // orange between 30 % and 50 % of the height.
            young_needle_color: srgb(80, 112, 62),
            needle_underside_color: srgb(52, 84, 62),
            upper_wood_color: srgb(176, 98, 52),
            upper_wood_heights: [0.3, 0.5],
            ..FoliageMaterial::uniform(srgb(52, 84, 62), srgb(92, 74, 62), 0.7, 0.35)
        },
    }
}

/// Norway spruce, ~80 years, 25–35 m: a deep cone down to a third of the
/// height or lower, upturned branch tips with curtains of hanging
/// branchlets, single needles all round the shoot.
pub(crate) fn norway_spruce() -> SpeciesParams {
    SpeciesParams {
        trunk: TrunkParams {
            age_years: 80,
            height: (25.0, 35.0),
            base_radius: 0.3,
            growth_acceleration: 0.3,
            wander: 0.008,
            nod: 0.0,
            nod_length: 0.0,
            nodes_per_year: 1,
            flare: 0.35,
        },
        crown: CrownParams {
            base_fraction: (0.12, 0.28),
            radius: 4.3,
            shape: CrownShape::Conical { exponent: 0.85 },
            irregularity: 0.2,
            dead_zone: 0.5,
        },
        branching: BranchParams {
            whorl_size: (5, 7),
            interwhorl_size: (1, 2),
            interwhorl_vigor: 0.5,
            angle_bottom: deg(100.0),
            angle_top: deg(55.0),
            sag: 0.15,
            upturn: 0.9,
            max_annual_growth: 0.3,
            max_order: 4,
            nodes_per_year: 1,
            laterals: (3, 3),
            sublaterals: (2, 2),
            lateral_angle: deg(55.0),
            lateral_length: 0.6,
            planarity: 0.8,
            hanging: 3.0,
            hanging_from_order: 2,
            shed_years: 30,
            loss: 0.05,
            crookedness: 0.05,
            min_shoot: 0.04,
            branch_units: 30,
            merge_pieces: 8,
            twig_order: 2,
            tip_radius: 0.0012,
            stubs: true,
        },
        spray: None,
        foliage: with_growth(
            FoliageFor::single((0.013, 0.025), (0.0005, 0.0007), 7, 60_000.0, Phyllotaxy::Spiral),
            DENSE_CROWN_GROWTH,
        ),
        material: FoliageMaterial {
            // This year's shoots a bright light green.
            young_needle_color: srgb(96, 132, 58),
            ..FoliageMaterial::uniform(srgb(48, 82, 50), srgb(104, 78, 62), 0.65, 0.3)
        },
    }
}

/// Eastern white pine, ~60 years, 25–30 m: level tiers of long branches
/// with gaps between them, an irregular top, drooping tufts of soft
/// 5-needle fascicles at the shoot ends.
pub(crate) fn eastern_white_pine() -> SpeciesParams {
    let mut foliage = FoliageFor::pine(5, (0.06, 0.13), (0.0004, 0.0005), 2, 1_000.0);
    // 8° rather than the young preset's sheathed 1°: a mature element
    // stands for several needles (widened), so its five spread like the
    // tuft they stand for (1° put the crown's see-through at 0.38).
    foliage.phyllotaxy = Phyllotaxy::Fascicle {
        needles: 5,
        spread: deg(8.0),
        twist: deg(30.0),
    };
    foliage.droop = 0.6;
    foliage.tip_crowding = 2.2;
    foliage.divergence = (deg(20.0), deg(40.0));
    SpeciesParams {
        trunk: TrunkParams {
            age_years: 60,
            height: (25.0, 30.0),
            base_radius: 0.3,
            growth_acceleration: 0.3,
            wander: 0.02,
            nod: 0.0,
            nod_length: 0.0,
            nodes_per_year: 1,
            flare: 0.3,
        },
        crown: CrownParams {
            base_fraction: (0.35, 0.48),
            radius: 5.0,
            shape: CrownShape::Conical { exponent: 0.6 },
            irregularity: 0.45,
            dead_zone: 0.3,
        },
        branching: BranchParams {
            whorl_size: (4, 5),
            interwhorl_size: (0, 0),
            interwhorl_vigor: 0.0,
            angle_bottom: deg(88.0),
            angle_top: deg(50.0),
            sag: 0.05,
            upturn: 0.35,
            max_annual_growth: 0.45,
            max_order: 4,
            nodes_per_year: 1,
            laterals: (3, 4),
            sublaterals: (2, 2),
            lateral_angle: deg(45.0),
            lateral_length: 0.7,
            planarity: 0.9,
            hanging: 0.4,
            hanging_from_order: 3,
            shed_years: 9,
            loss: 0.25,
            crookedness: 0.1,
            min_shoot: 0.03,
            branch_units: 24,
            merge_pieces: 6,
            twig_order: 3,
            tip_radius: 0.002,
            stubs: true,
        },
        spray: None,
        foliage,
        material: FoliageMaterial {
            // White stomatal lines on the needles' inner faces; dark,
            // furrowed bark at the foot, smooth grey-green above. This
            // year's needles only a little lighter: its twigs hold both of
            // its two years and are placed at their mean age, which rounds
            // to 0 for 88 % of them.
            young_needle_color: srgb(66, 98, 68),
            needle_underside_color: srgb(76, 102, 88),
            upper_wood_color: srgb(108, 106, 96),
            upper_wood_heights: [0.35, 0.6],
            ..FoliageMaterial::uniform(srgb(56, 88, 66), srgb(76, 70, 66), 0.5, 0.3)
        },
    }
}

/// Lawson cypress, ~50 years, 15–25 m: a narrow column with a nodding
/// leader, short ascending branches hung with flat drooping sprays.
pub(crate) fn lawson_cypress() -> SpeciesParams {
    let mut foliage = with_growth(
        FoliageFor::single((0.0025, 0.004), (0.00045, 0.00055), 3, 40_000.0, Phyllotaxy::Scales),
        SPRAY_ELEMENT_GROWTH,
    );
    foliage.divergence = (deg(25.0), deg(35.0));
    foliage.group_size = (1, 600);
    SpeciesParams {
        trunk: TrunkParams {
            age_years: 50,
            height: (15.0, 25.0),
            base_radius: 0.25,
            growth_acceleration: 0.4,
            wander: 0.01,
            nod: deg(75.0),
            nod_length: 1.2,
            nodes_per_year: 4,
            flare: 0.3,
        },
        crown: CrownParams {
            base_fraction: (0.02, 0.08),
            radius: 2.2,
            shape: CrownShape::Columnar,
            irregularity: 0.25,
            dead_zone: 1.0,
        },
        branching: BranchParams {
            whorl_size: (2, 3),
            interwhorl_size: (1, 1),
            interwhorl_vigor: 0.9,
            angle_bottom: deg(75.0),
            angle_top: deg(35.0),
            sag: 0.3,
            upturn: 0.3,
            max_annual_growth: 0.35,
            max_order: 3,
            nodes_per_year: 1,
            laterals: (2, 3),
            sublaterals: (1, 1),
            lateral_angle: deg(45.0),
            lateral_length: 0.55,
            planarity: 1.0,
            hanging: 0.8,
            hanging_from_order: 3,
            shed_years: 25,
            loss: 0.05,
            crookedness: 0.05,
            min_shoot: 0.03,
            branch_units: 24,
            merge_pieces: 4,
            twig_order: 2,
            tip_radius: 0.0008,
            stubs: false,
        },
        spray: Some(SprayParams {
            spacing: 0.06,
            length: (0.35, 0.7),
            angle: deg(50.0),
            pinna_spacing: 0.01,
            pinna_angle: deg(45.0),
            pinna_length: 0.35,
            droop: 1.0,
            roll: 0.9,
        }),
        foliage,
        material: FoliageMaterial {
            // Faint pale marks under the sprays.
            young_needle_color: srgb(72, 106, 62),
            needle_underside_color: srgb(70, 100, 80),
            ..FoliageMaterial::uniform(srgb(50, 86, 54), srgb(120, 80, 60), 0.55, 0.3)
        },
    }
}

/// Douglas fir, ~90 years, 35–50 m: low branches drooping, middle ones
/// level, top ones rising; single needles parted to the sides of the shoot.
pub(crate) fn douglas_fir() -> SpeciesParams {
    SpeciesParams {
        trunk: TrunkParams {
            age_years: 90,
            height: (35.0, 50.0),
            base_radius: 0.45,
            growth_acceleration: 0.25,
            wander: 0.01,
            nod: 0.0,
            nod_length: 0.0,
            nodes_per_year: 1,
            flare: 0.35,
        },
        crown: CrownParams {
            base_fraction: (0.35, 0.5),
            radius: 4.5,
            shape: CrownShape::Conical { exponent: 0.75 },
            irregularity: 0.3,
            dead_zone: 0.4,
        },
        branching: BranchParams {
            whorl_size: (5, 7),
            interwhorl_size: (1, 2),
            interwhorl_vigor: 0.5,
            angle_bottom: deg(105.0),
            angle_top: deg(45.0),
            sag: 0.15,
            upturn: 0.7,
            max_annual_growth: 0.4,
            max_order: 4,
            nodes_per_year: 1,
            laterals: (2, 2),
            sublaterals: (2, 2),
            lateral_angle: deg(50.0),
            lateral_length: 0.6,
            planarity: 0.85,
            hanging: 1.0,
            hanging_from_order: 3,
            shed_years: 25,
            loss: 0.15,
            crookedness: 0.08,
            min_shoot: 0.04,
            branch_units: 30,
            merge_pieces: 8,
            twig_order: 2,
            tip_radius: 0.0015,
            stubs: true,
        },
        spray: None,
        foliage: FoliageFor::single((0.015, 0.03), (0.0006, 0.0008), 6, 45_000.0, Phyllotaxy::Spiral),
        material: FoliageMaterial {
            // Two pale bands under each needle; thick, dark, furrowed bark
            // at the foot, smoother and greyer up the stem.
            young_needle_color: srgb(92, 126, 62),
            needle_underside_color: srgb(72, 98, 78),
            upper_wood_color: srgb(112, 98, 86),
            upper_wood_heights: [0.3, 0.6],
            ..FoliageMaterial::uniform(srgb(54, 85, 52), srgb(80, 60, 48), 0.6, 0.3)
        },
    }
}

/// Silver fir, ~100 years, 30–40 m: a cone whose top has flattened into a
/// stork's nest, flat needles in two rows, pale grey bark.
pub(crate) fn silver_fir() -> SpeciesParams {
    SpeciesParams {
        trunk: TrunkParams {
            age_years: 100,
            height: (30.0, 40.0),
            base_radius: 0.4,
            growth_acceleration: 0.2,
            wander: 0.01,
            nod: 0.0,
            nod_length: 0.0,
            nodes_per_year: 1,
            flare: 0.3,
        },
        crown: CrownParams {
            base_fraction: (0.3, 0.45),
            radius: 4.0,
            shape: CrownShape::StorksNest,
            irregularity: 0.25,
            dead_zone: 0.4,
        },
        branching: BranchParams {
            whorl_size: (5, 7),
            interwhorl_size: (1, 2),
            interwhorl_vigor: 0.5,
            angle_bottom: deg(90.0),
            angle_top: deg(35.0),
            sag: 0.1,
            upturn: 0.6,
            max_annual_growth: 0.35,
            max_order: 4,
            nodes_per_year: 1,
            laterals: (2, 2),
            sublaterals: (2, 2),
            lateral_angle: deg(55.0),
            lateral_length: 0.6,
            planarity: 0.95,
            hanging: 0.0,
            hanging_from_order: 9,
            shed_years: 20,
            loss: 0.1,
            crookedness: 0.05,
            min_shoot: 0.04,
            branch_units: 30,
            merge_pieces: 8,
            twig_order: 2,
            tip_radius: 0.0015,
            stubs: true,
        },
        spray: None,
        foliage: FoliageFor::single(
            (0.015, 0.03),
            (0.0009, 0.0012),
            8,
            60_000.0,
            Phyllotaxy::TwoRanked { lift: deg(15.0) },
        ),
        material: FoliageMaterial {
            // Dark, glossy above with two white stomatal bands beneath
            // (the "silver"); pale grey bark.
            young_needle_color: srgb(86, 122, 64),
            needle_underside_color: srgb(84, 112, 98),
            ..FoliageMaterial::uniform(srgb(46, 80, 50), srgb(150, 147, 140), 0.5, 0.35)
        },
    }
}

/// Douglas fir, ~9 years, about 3.7 m: a young cone to the ground.
pub(crate) fn young_douglas_fir() -> SpeciesParams {
    let mut params = super::params::norway_spruce();
    params.trunk.age_years = 9;
    params.trunk.height = (3.2, 4.2);
    params.trunk.base_radius = 0.06;
    params.crown.radius = 1.2;
    params.crown.shape = CrownShape::Conical { exponent: 0.75 };
    params.branching.angle_bottom = deg(95.0);
    params.branching.angle_top = deg(45.0);
    params.branching.hanging = 0.8;
    params.branching.max_annual_growth = 0.35;
    params.foliage.length = (0.015, 0.03);
    params.foliage.radius = (0.0006, 0.0008);
    params.foliage.divergence = (deg(50.0), deg(80.0));
    params.foliage.count = NeedleCount::Total(70_000);
    params.material = douglas_fir().material;
    params
}

/// Silver fir, ~9 years, about 2.8 m: a young cone of level branches with
/// two-rowed flat needles.
pub(crate) fn young_silver_fir() -> SpeciesParams {
    let mut params = super::params::norway_spruce();
    params.trunk.age_years = 9;
    params.trunk.height = (2.4, 3.2);
    params.trunk.base_radius = 0.05;
    params.crown.radius = 1.0;
    params.branching.angle_bottom = deg(88.0);
    params.branching.angle_top = deg(50.0);
    params.branching.hanging = 0.0;
    params.branching.planarity = 0.95;
    params.foliage.phyllotaxy = Phyllotaxy::TwoRanked { lift: deg(15.0) };
    params.foliage.length = (0.015, 0.03);
    params.foliage.radius = (0.0009, 0.0012);
    params.foliage.divergence = (deg(65.0), deg(85.0));
    params.foliage.count = NeedleCount::Total(60_000);
    params.material = silver_fir().material;
    params
}

/// Foliage sets shared by the mature species.
struct FoliageFor;

impl FoliageFor {
    /// Pine fascicles of `needles` needles, `per_metre` needles a metre of shoot.
    fn pine(
        needles: u32,
        length: (f32, f32),
        radius: (f32, f32),
        retention_years: u32,
        per_metre: f32,
    ) -> FoliageParams {
        FoliageParams {
            phyllotaxy: Phyllotaxy::Fascicle {
                needles,
                spread: deg(9.0),
                twist: deg(60.0),
            },
            count: NeedleCount::PerMetre {
                per_metre,
                most: RECORD_NEEDLES,
                growth: ELEMENT_GROWTH,
            },
            retention_years,
            survival_per_year: 0.8,
            length,
            radius,
            divergence: (deg(30.0), deg(55.0)),
            droop: 0.05,
            tip_crowding: 1.0,
            group_size: (needles as usize, needles as usize),
        }
    }

    /// Single needles (or scale leaves) in `phyllotaxy`.
    fn single(
        length: (f32, f32),
        radius: (f32, f32),
        retention_years: u32,
        per_metre: f32,
        phyllotaxy: Phyllotaxy,
    ) -> FoliageParams {
        FoliageParams {
            phyllotaxy,
            count: NeedleCount::PerMetre {
                per_metre,
                most: RECORD_NEEDLES,
                growth: ELEMENT_GROWTH,
            },
            retention_years,
            survival_per_year: 0.8,
            length,
            radius,
            divergence: (deg(45.0), deg(70.0)),
            droop: 0.0,
            tip_crowding: 1.0,
            group_size: (10, 60),
        }
    }
}
