//! A procedural tree named by a short string: species, seed and needle
//! count, baked with the default options.

use std::fmt;
use std::str::FromStr;

use super::{Age, GenerateOptions, Species, UnknownSpecies, generate_prototypes};
use crate::model::{BakeError, BakeOptions, PrototypeRecord, bake_prototypes};

/// A preset tree: one of the [`Species`] at an [`Age`] (mature unless
/// asked), grown from a seed, optionally with a needle count, as shared
/// shoot prototypes baked with [`BakeOptions::default`] (what `conifer bake
/// --preset` writes).
///
/// Its text form is `species[?seed=S][&needles=N][&age=young]`, e.g.
/// `norway-spruce?seed=3`; [`Preset`]'s `Display` writes it back.
///
/// ```
/// use bevy_conifer_lod::generate::{Preset, Species};
///
/// let preset: Preset = "norway-spruce?seed=3".parse().unwrap();
/// assert_eq!(preset, Preset::new(Species::NorwaySpruce).with_seed(3));
/// assert_eq!(preset.to_string(), "norway-spruce?seed=3");
/// ```
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct Preset {
    /// The species.
    pub species: Species,
    /// Seed of the tree's random stream (same seed, same tree).
    pub seed: u64,
    /// Needle count to aim for; `None` is the species' own.
    pub target_needles: Option<usize>,
    /// How old the tree is.
    pub age: Age,
}

impl Preset {
    /// The species' mature tree of seed 0 with its own needle count.
    pub fn new(species: Species) -> Self {
        Self {
            species,
            seed: 0,
            target_needles: None,
            age: Age::Mature,
        }
    }

    /// The same preset at another age.
    pub fn with_age(self, age: Age) -> Self {
        Self { age, ..self }
    }

    /// What [`generate_prototypes`](super::generate_prototypes) grows it from.
    pub fn options(&self) -> GenerateOptions {
        GenerateOptions {
            seed: self.seed,
            target_needles: self.target_needles,
            age: self.age,
        }
    }

    /// The same preset with another seed.
    pub fn with_seed(self, seed: u64) -> Self {
        Self { seed, ..self }
    }

    /// The same preset aiming at `needles` needles.
    pub fn with_needles(self, needles: usize) -> Self {
        Self {
            target_needles: Some(needles),
            ..self
        }
    }

    /// Grows and bakes the tree with [`BakeOptions::default`], the line
    /// calibration and crown impostor included (tens of milliseconds for
    /// young trees; 6.7–9.2 s for the 2 M-needle mature ones in a release
    /// build on two cores, half of it the calibration: `BENCHMARKS.md`;
    /// merges run on the current rayon pool).
    pub fn bake(&self) -> Result<PrototypeRecord, BakeError> {
        let input = generate_prototypes(self.species, &self.options());
        bake_prototypes(&input, &BakeOptions::default(), &())
    }

    /// A 64-bit fingerprint of everything the baked record depends on
    /// besides the preset's own fields: the species' generator parameters,
    /// the default bake options, the record format and this crate's
    /// version. A cache keyed by it goes stale when any of them changes.
    pub fn fingerprint(&self) -> u64 {
        let inputs = format!(
            "{:?}|{:?}|{}|{}",
            self.species.params(self.age),
            BakeOptions::default(),
            crate::model::file::FORMAT_VERSION,
            env!("CARGO_PKG_VERSION")
        );
        // FNV-1a: stable across runs and platforms, unlike `DefaultHasher`.
        inputs.bytes().fold(0xcbf2_9ce4_8422_2325_u64, |hash, byte| {
            (hash ^ u64::from(byte)).wrapping_mul(0x0100_0000_01b3)
        })
    }

    /// A file stem that names this preset uniquely (`norway-spruce-s3`,
    /// `norway-spruce-young-s3-n20000`).
    pub fn file_stem(&self) -> String {
        let age = match self.age {
            Age::Mature => String::new(),
            age => format!("-{age}"),
        };
        match self.target_needles {
            Some(needles) => format!("{}{age}-s{}-n{needles}", self.species.name(), self.seed),
            None => format!("{}{age}-s{}", self.species.name(), self.seed),
        }
    }
}

impl From<Species> for Preset {
    fn from(species: Species) -> Self {
        Preset::new(species)
    }
}

impl fmt::Display for Preset {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.species.name())?;
        let mut separator = '?';
        if self.seed != 0 {
            write!(f, "{separator}seed={}", self.seed)?;
            separator = '&';
        }
        if let Some(needles) = self.target_needles {
            write!(f, "{separator}needles={needles}")?;
            separator = '&';
        }
        if self.age != Age::Mature {
            write!(f, "{separator}age={}", self.age)?;
        }
        Ok(())
    }
}

/// Why a string is not a [`Preset`].
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
pub enum PresetParseError {
    /// The species is not one of [`Species::ALL`].
    #[error(
        "{0}; a tree of your own loads from a `.conifer` record baked by `conifer bake` (a glTF file or a preset with other options)"
    )]
    UnknownSpecies(#[from] UnknownSpecies),
    /// An option that is not `seed`, `needles` or `age`, a seed or count
    /// that is not a whole number, a count of 0 or an unknown age.
    #[error(
        "bad preset option `{option}` in `{text}` (expected `seed=S` and `needles=N`, whole numbers with N > 0, and `age=young` or `age=mature`, joined by `&`)"
    )]
    BadOption {
        /// The whole text.
        text: String,
        /// The option that did not parse.
        option: String,
    },
}

impl FromStr for Preset {
    type Err = PresetParseError;

    fn from_str(text: &str) -> Result<Self, Self::Err> {
        let (name, options) = text.split_once('?').unwrap_or((text, ""));
        let mut preset = Preset::new(name.parse::<Species>()?);
        for option in options.split('&').filter(|o| !o.is_empty()) {
            let bad = || PresetParseError::BadOption {
                text: text.to_owned(),
                option: option.to_owned(),
            };
            let (key, value) = option.split_once('=').ok_or_else(bad)?;
            match key.trim() {
                "seed" => preset.seed = value.trim().parse().map_err(|_| bad())?,
                "needles" => match value.trim().parse() {
                    Ok(0) | Err(_) => return Err(bad()),
                    Ok(needles) => preset.target_needles = Some(needles),
                },
                "age" => preset.age = Age::from_name(value).ok_or_else(bad)?,
                _ => return Err(bad()),
            }
        }
        Ok(preset)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    #[test]
    fn bad_names_and_options_are_errors_that_say_what_to_do() {
        let unknown = "norwy-spruce".parse::<Preset>().unwrap_err();
        let message = unknown.to_string();
        assert!(
            message.contains("norwy-spruce") && message.contains("norway-spruce"),
            "{message}"
        );
        assert!(message.contains("conifer bake"), "{message}");
        for bad in [
            "scots-pine?seed=x",
            "scots-pine?colour=red",
            "scots-pine?seed",
            "scots-pine?needles=-3",
            "scots-pine?needles=0",
            "scots-pine?age=0",
            "scots-pine?age=old",
        ] {
            assert!(
                matches!(bad.parse::<Preset>(), Err(PresetParseError::BadOption { .. })),
                "{bad}"
            );
        }
    }

    #[test]
    fn a_preset_bakes_the_tree_conifer_bake_writes() {
        let preset = Preset::new(Species::ScotsPine)
            .with_seed(2)
            .with_needles(3_000)
            .with_age(Age::Young);
        let record = preset.bake().unwrap();
        let flat = record.flatten().unwrap();
        let needles = flat.needles.len();
        assert!((2_700..=3_300).contains(&needles), "{needles} needles");
        assert!(record.prototypes.len() < record.placements.len());
        let again = preset.bake().unwrap();
        assert_eq!(
            (&again.prototypes, &again.placements, &again.tree_merged),
            (&record.prototypes, &record.placements, &record.tree_merged),
            "a preset is deterministic"
        );
        assert_eq!(preset.file_stem(), "scots-pine-young-s2-n3000");
        assert_eq!(preset.to_string(), "scots-pine?seed=2&needles=3000&age=young");
        assert_eq!(preset.fingerprint(), preset.with_seed(9).fingerprint());
        assert_ne!(
            preset.fingerprint(),
            Preset::new(Species::NorwaySpruce).fingerprint(),
            "species' parameters differ"
        );
        assert_ne!(
            preset.fingerprint(),
            preset.with_age(Age::Mature).fingerprint(),
            "ages' parameters differ"
        );
    }

    proptest! {
        #[test]
        fn text_form_round_trips(species in 0..Species::ALL.len(), seed in any::<u64>(), needles in proptest::option::of(1usize..10_000_000), young in any::<bool>()) {
            let age = if young { Age::Young } else { Age::Mature };
            let preset = Preset { species: Species::ALL[species], seed, target_needles: needles, age };
            prop_assert_eq!(preset.to_string().parse::<Preset>(), Ok(preset));
        }
    }
}
