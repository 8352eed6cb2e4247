//! Deterministic procedural conifers: the default input of the bake.
//!
//! One shared grower builds every species from its own parameter set, at
//! either [`Age`]: a trunk of annual growth units with whorls of branches,
//! laterals at the branch nodes (radii from the pipe model; shed in the
//! shaded interior of mature trees), and needles on the young shoots in the
//! species' phyllotaxy: 2-needle fascicles (Scots pine), 5-needle fascicles
//! (eastern white pine), single needles spirally round each shoot (Norway
//! spruce, Douglas fir), two flat rows (silver fir), or scale leaves lying
//! flat in fern-like sprays (Lawson cypress). Mature trees share their
//! twigs: each class is grown once and placed many times. Everything is drawn from a PCG stream seeded by
//! [`GenerateOptions::seed`], so a seed always gives the same tree, bit for
//! bit.
//!
//! Trees stand at the origin, +Y up, in metres.
//!
//! ```
//! use bevy_conifer_lod::generate::{Age, GenerateOptions, Species, generate};
//!
//! let options = GenerateOptions { seed: 7, target_needles: Some(10_000), age: Age::Young };
//! let tree = generate(Species::NorwaySpruce, &options);
//! assert!(tree.needles.iter().all(|n| n.is_valid()));
//! ```

mod foliage;
mod geometry;
mod mature;
mod params;
mod preset;
mod random;
mod skeleton;
mod spray;

use std::fmt;
use std::str::FromStr;

use serde::{Deserialize, Serialize};

use self::foliage::NeedleBudget;
use self::params::{NeedleCount, SpeciesParams};
pub use self::preset::{Preset, PresetParseError};
use self::random::{Stream, TreeRng};
use crate::model::{PrototypeInput, TreeInput, WoodSegment};

/// The conifer presets: the paper's four species and two firs. Each grows
/// at either [`Age`]; [`Species::description`] gives its size at each.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Species {
    /// *Pinus sylvestris*: mature 18–25 m with a bare bole over half its
    /// height and an umbrella crown; young (~10 years) 3.3–4.3 m.
    /// 2-needle fascicles (3–7 cm).
    ScotsPine,
    /// *Picea abies*: mature 25–35 m, a deep cone with hanging branchlets;
    /// young (~8 years) 2.7–3.3 m. Single needles (1–2.5 cm) spirally round
    /// each shoot.
    NorwaySpruce,
    /// *Pinus strobus*: mature 25–30 m in level tiers; young (~10 years)
    /// 3.9–4.8 m. Soft drooping 5-needle fascicles (6–13 cm) tufted at the
    /// shoot ends.
    EasternWhitePine,
    /// *Chamaecyparis lawsoniana*: mature 15–25 m, a narrow column with a
    /// nodding leader; young (~6 years) 2.0–2.4 m. Flat fern-like sprays of
    /// scale leaves (2.5–4 mm).
    LawsonCypress,
    /// *Pseudotsuga menziesii*: mature 35–50 m, low branches drooping, top
    /// ones rising; young (~9 years) ~3.7 m. Single needles (1.5–3 cm)
    /// parted to the sides of the shoot.
    DouglasFir,
    /// *Abies alba*: mature 30–40 m with a flattened "stork's nest" top;
    /// young (~9 years) ~2.8 m. Flat needles (1.5–3 cm) in two rows, pale
    /// grey bark.
    SilverFir,
}

/// How old a preset tree is.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Age {
    /// A 6–10-year-old sapling, 2–5 m, tens of thousands of needles (the
    /// presets of the first releases).
    Young,
    /// A mature tree at its species' real size and crown density (15–50 m),
    /// a million or more needles.
    #[default]
    Mature,
}

impl Age {
    /// Both ages.
    pub const ALL: [Age; 2] = [Age::Young, Age::Mature];

    /// The age's name on the command line and in preset strings.
    pub fn name(self) -> &'static str {
        match self {
            Age::Young => "young",
            Age::Mature => "mature",
        }
    }

    /// The age called `name` (case is not significant).
    pub fn from_name(name: &str) -> Option<Age> {
        Age::ALL
            .into_iter()
            .find(|a| a.name().eq_ignore_ascii_case(name.trim()))
    }
}

impl fmt::Display for Age {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

impl Species {
    /// Every preset.
    pub const ALL: [Species; 6] = [
        Species::ScotsPine,
        Species::NorwaySpruce,
        Species::EasternWhitePine,
        Species::LawsonCypress,
        Species::DouglasFir,
        Species::SilverFir,
    ];

    /// The preset's name on the command line and in file names.
    pub fn name(self) -> &'static str {
        match self {
            Species::ScotsPine => "scots-pine",
            Species::NorwaySpruce => "norway-spruce",
            Species::EasternWhitePine => "eastern-white-pine",
            Species::LawsonCypress => "lawson-cypress",
            Species::DouglasFir => "douglas-fir",
            Species::SilverFir => "silver-fir",
        }
    }

    /// The preset called `name` (as [`Species::name`] spells it; case and
    /// `_`/`-`/space are not significant).
    pub fn from_name(name: &str) -> Option<Species> {
        let wanted: String = name
            .trim()
            .chars()
            .map(|c| {
                if c == '_' || c == ' ' {
                    '-'
                } else {
                    c.to_ascii_lowercase()
                }
            })
            .collect();
        Species::ALL.into_iter().find(|s| s.name() == wanted)
    }

    /// One line about the preset at `age`: botanical name, age, height, phyllotaxy.
    pub fn description(self, age: Age) -> &'static str {
        match (self, age) {
            (Species::ScotsPine, Age::Young) => "Pinus sylvestris, ~10 years, 3.3-4.3 m, 2-needle fascicles",
            (Species::ScotsPine, Age::Mature) => {
                "Pinus sylvestris, ~70 years, 18-25 m, bare bole, umbrella top, 2-needle fascicles"
            }
            (Species::NorwaySpruce, Age::Young) => "Picea abies, ~8 years, ~3 m, single needles round each shoot",
            (Species::NorwaySpruce, Age::Mature) => {
                "Picea abies, ~80 years, 25-35 m, deep cone, hanging branchlets, single needles"
            }
            (Species::EasternWhitePine, Age::Young) => "Pinus strobus, ~10 years, 3.9-4.8 m, 5-needle fascicles",
            (Species::EasternWhitePine, Age::Mature) => {
                "Pinus strobus, ~60 years, 25-30 m, level tiers, drooping 5-needle tufts"
            }
            (Species::LawsonCypress, Age::Young) => {
                "Chamaecyparis lawsoniana, young (~6 years, ~2.2 m), scale-leaf sprays"
            }
            (Species::LawsonCypress, Age::Mature) => {
                "Chamaecyparis lawsoniana, ~50 years, 15-25 m, narrow column, drooping sprays"
            }
            (Species::DouglasFir, Age::Young) => "Pseudotsuga menziesii, ~9 years, ~3.7 m, single needles",
            (Species::DouglasFir, Age::Mature) => {
                "Pseudotsuga menziesii, ~90 years, 35-50 m, drooping low branches, single needles"
            }
            (Species::SilverFir, Age::Young) => "Abies alba, ~9 years, ~2.8 m, two-rowed flat needles",
            (Species::SilverFir, Age::Mature) => {
                "Abies alba, ~100 years, 30-40 m, stork's nest top, two-rowed flat needles"
            }
        }
    }

    fn params(self, age: Age) -> SpeciesParams {
        match (self, age) {
            (Species::ScotsPine, Age::Young) => params::scots_pine(),
            (Species::NorwaySpruce, Age::Young) => params::norway_spruce(),
            (Species::EasternWhitePine, Age::Young) => params::eastern_white_pine(),
            (Species::LawsonCypress, Age::Young) => params::lawson_cypress(),
            (Species::DouglasFir, Age::Young) => mature::young_douglas_fir(),
            (Species::SilverFir, Age::Young) => mature::young_silver_fir(),
            (Species::ScotsPine, Age::Mature) => mature::scots_pine(),
            (Species::NorwaySpruce, Age::Mature) => mature::norway_spruce(),
            (Species::EasternWhitePine, Age::Mature) => mature::eastern_white_pine(),
            (Species::LawsonCypress, Age::Mature) => mature::lawson_cypress(),
            (Species::DouglasFir, Age::Mature) => mature::douglas_fir(),
            (Species::SilverFir, Age::Mature) => mature::silver_fir(),
        }
    }
}

impl fmt::Display for Species {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

/// A species name that is not a preset.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct UnknownSpecies {
    /// The name that was given.
    pub name: String,
}

impl fmt::Display for UnknownSpecies {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let valid: Vec<&str> = Species::ALL.iter().map(|s| s.name()).collect();
        write!(
            f,
            "unknown species `{}` (expected one of: {})",
            self.name,
            valid.join(", ")
        )
    }
}

impl std::error::Error for UnknownSpecies {}

impl FromStr for Species {
    type Err = UnknownSpecies;

    fn from_str(name: &str) -> Result<Self, Self::Err> {
        Species::from_name(name).ok_or_else(|| UnknownSpecies { name: name.to_owned() })
    }
}

/// How to generate a tree.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash, Serialize, Deserialize)]
pub struct GenerateOptions {
    /// Seed of the tree's random stream: the same seed gives the same tree.
    pub seed: u64,
    /// Needle count to aim for (the result lands within a fraction of a per
    /// cent for counts from a few thousand up): the needle density on the
    /// shoots is scaled, the tree's shape and size kept. `None`: the
    /// species' own count (young trees: tens of thousands, ±8 % by seed;
    /// mature trees: what their shoots carry, at most a record's worth).
    ///
    /// A mature tree given fewer needles than it naturally carries widens
    /// them, keeping their summed area, so its crown stays as dense: up to
    /// 6× and as wide as the shortest is long, then both ways, up to twice
    /// as long (needle elements standing for several needles); past that it
    /// thins.
    pub target_needles: Option<usize>,
    /// How old the tree is.
    pub age: Age,
}

/// Grows one tree of `species`.
pub fn generate(species: Species, options: &GenerateOptions) -> TreeInput {
    let params = species.params(options.age);
    if params.branching.twig_order > 0 {
        // Its twigs are prototypes however it is grown: flattened.
        return generate_prototypes(species, options).to_tree();
    }
    let skeleton = skeleton::grow_skeleton(&params, &mut TreeRng::new(options.seed, Stream::Skeleton));
    let budget = needle_budget(&params, &skeleton, options);
    let needles = foliage::grow_needles(
        &skeleton.sites,
        &params.foliage,
        budget,
        &mut TreeRng::new(options.seed, Stream::Foliage),
    );
    TreeInput {
        name: format!("{}-{}-s{}", species.name(), options.age, options.seed),
        needles,
        material: params.material_for(tree_height(&skeleton.wood)),
        wood: skeleton.wood,
        wood_mesh: Default::default(),
    }
}

/// Grows one tree of `species` as shared shoot prototypes placed on its
/// foliage sites: the same skeleton and about the same needles as
/// [`generate`], but each shoot's needles are one of a few dozen prototypes
/// (by needle count, vigour and variant) placed, rotated and scaled onto the
/// shoot, so the record and the GPU hold them once.
pub fn generate_prototypes(species: Species, options: &GenerateOptions) -> PrototypeInput {
    let params = species.params(options.age);
    let skeleton = skeleton::grow_skeleton(&params, &mut TreeRng::new(options.seed, Stream::Skeleton));
    let budget = needle_budget(&params, &skeleton, options);
    let (prototypes, placements) = foliage::grow_shoot_prototypes(
        &skeleton,
        &params.foliage,
        budget,
        &mut TreeRng::new(options.seed, Stream::Foliage),
    );
    PrototypeInput {
        name: format!("{}-{}-s{}", species.name(), options.age, options.seed),
        prototypes,
        placements,
        material: params.material_for(tree_height(&skeleton.wood)),
        wood: skeleton.wood,
        wood_mesh: Default::default(),
    }
}

/// Height of a tree's wood above its foot (the trunk's top), metres.
fn tree_height(wood: &[WoodSegment]) -> f32 {
    wood.iter().map(|w| w.start.y.max(w.end.y)).fold(0.0, f32::max)
}

/// Most a mature tree's needles widen before they also lengthen.
const MAX_WIDENING: f32 = 6.0;

/// How many needles the tree gets, and how much they widen: the species'
/// count with the tree's vigour (±8 %, by seed), or the options' count.
fn needle_budget(params: &SpeciesParams, skeleton: &skeleton::Skeleton, options: &GenerateOptions) -> NeedleBudget {
    let vigor = TreeRng::new(options.seed, Stream::Tree).jitter(1.0, 0.08);
    let foliage = &params.foliage;
    let (natural, most) = match foliage.count {
        NeedleCount::Total(count) => ((count as f32 * vigor).round() as usize, usize::MAX),
        NeedleCount::PerMetre { per_metre, most, .. } => {
            let twig_metres: f32 = skeleton
                .twig_placements
                .iter()
                .map(|p| skeleton.twigs[p.twig as usize].weight() * p.scale)
                .sum();
            let shoot_metres = skeleton.site_weight() + twig_metres;
            ((per_metre * shoot_metres * vigor).round() as usize, most)
        }
    };
    let target = options.target_needles.unwrap_or(natural.min(most));
    let keep_area = natural as f32 / target.max(1) as f32;
    let (widening, lengthening) = match (foliage.count, foliage.phyllotaxy) {
        (NeedleCount::Total(_), _) => (1.0, 1.0),
        // Scale leaves grow both ways, keeping their shape, up to `growth`
        // times (scale elements standing for a piece of spray).
        (NeedleCount::PerMetre { growth, .. }, params::Phyllotaxy::Scales) => {
            let both = keep_area.sqrt().clamp(1.0, growth.max(1.0));
            (both, both)
        }
        // Needles widen up to 6× (a needle element standing for a row of
        // needles) and no wider than the shortest is long; past that they
        // grow both ways, up to `growth` times as long.
        (NeedleCount::PerMetre { growth, .. }, _) => {
            let widest = (0.5 * foliage.length.0 / foliage.radius.1).clamp(1.0, MAX_WIDENING);
            let widening = keep_area.clamp(1.0, widest);
            let both = (keep_area / widening).sqrt().clamp(1.0, growth.max(1.0));
            (widening * both, both)
        }
    };
    NeedleBudget {
        target,
        natural,
        widening,
        lengthening,
    }
}

#[cfg(test)]
mod tests;
