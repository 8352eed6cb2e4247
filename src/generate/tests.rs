use super::*;
use crate::model::Needle;

fn tree(species: Species, seed: u64) -> TreeInput {
    generate(
        species,
        &GenerateOptions {
            seed,
            target_needles: None,
        },
    )
}

fn group_sizes(needles: &[Needle]) -> Vec<usize> {
    let mut counts = std::collections::BTreeMap::new();
    for needle in needles {
        *counts.entry(needle.group).or_insert(0_usize) += 1;
    }
    counts.into_values().collect()
}

/// Default needle count range per species.
fn count_range(species: Species) -> (usize, usize) {
    match species {
        Species::EasternWhitePine => (50_000, 70_000),
        _ => (30_000, 80_000),
    }
}

/// Height range per species, metres.
fn height_range(species: Species) -> (f32, f32) {
    match species {
        Species::ScotsPine => (3.0, 5.0),
        Species::NorwaySpruce => (2.5, 3.5),
        Species::EasternWhitePine => (3.5, 5.0),
        Species::LawsonCypress => (1.7, 2.6),
    }
}

#[test]
fn same_seed_gives_identical_trees() {
    for species in Species::ALL {
        let options = GenerateOptions {
            seed: 42,
            target_needles: Some(8_000),
        };
        assert_eq!(generate(species, &options), generate(species, &options), "{species}");
    }
}

#[test]
fn different_seeds_give_different_trees() {
    for species in Species::ALL {
        let a = generate(
            species,
            &GenerateOptions {
                seed: 1,
                target_needles: Some(8_000),
            },
        );
        let b = generate(
            species,
            &GenerateOptions {
                seed: 2,
                target_needles: Some(8_000),
            },
        );
        assert_ne!(a.needles, b.needles, "{species}");
        assert_ne!(a.wood, b.wood, "{species}");
    }
}

#[test]
fn default_needle_counts_are_in_range() {
    for species in Species::ALL {
        for seed in 0..3 {
            let count = tree(species, seed).needles.len();
            let (lo, hi) = count_range(species);
            assert!((lo..=hi).contains(&count), "{species} seed {seed}: {count} needles");
        }
    }
}

#[test]
fn groups_follow_the_phyllotaxy() {
    for species in Species::ALL {
        let sizes = group_sizes(&tree(species, 3).needles);
        let (lo, hi) = match species {
            Species::ScotsPine => (2, 2),
            Species::EasternWhitePine => (5, 5),
            Species::NorwaySpruce => (10, 60),
            Species::LawsonCypress => (1, 600),
        };
        let bad = sizes.iter().filter(|&&s| s < lo || s > hi).count();
        assert_eq!(bad, 0, "{species}: {bad} of {} groups outside {lo}..={hi}", sizes.len());
    }
}

#[test]
fn cypress_sprays_hold_many_scales() {
    let sizes = group_sizes(&tree(Species::LawsonCypress, 0).needles);
    let mean = sizes.iter().sum::<usize>() as f32 / sizes.len() as f32;
    assert!(mean >= 20.0, "mean spray size {mean}");
}

#[test]
fn needle_sizes_match_the_species() {
    for species in Species::ALL {
        let params = species.params();
        let (short, long) = params.foliage.length;
        let (thin, thick) = params.foliage.radius;
        for needle in &tree(species, 5).needles {
            let length = needle.length();
            assert!(
                length >= short * 0.999 && length <= long * 1.001,
                "{species}: length {length}"
            );
            assert!(
                needle.radius >= thin && needle.radius <= thick,
                "{species}: radius {}",
                needle.radius
            );
        }
    }
}

#[test]
fn needles_and_wood_are_valid() {
    for species in Species::ALL {
        let tree = tree(species, 6);
        assert!(!tree.wood.is_empty());
        assert!(tree.wood.iter().all(|w| w.is_valid()), "{species}: wood");
        for needle in &tree.needles {
            assert!(needle.is_valid(), "{species}: {needle:?}");
            let axis = (needle.tip - needle.base).normalize();
            assert!(
                (needle.normal.length() - 1.0).abs() < 1e-3,
                "{species}: normal not unit"
            );
            assert!(
                needle.normal.dot(axis).abs() < 1e-3,
                "{species}: normal not perpendicular"
            );
        }
    }
}

#[test]
fn target_needles_is_met_within_15_percent() {
    for species in Species::ALL {
        for target in [10_000, 200_000] {
            let count = generate(
                species,
                &GenerateOptions {
                    seed: 9,
                    target_needles: Some(target),
                },
            )
            .needles
            .len();
            let error = (count as f64 / target as f64 - 1.0).abs();
            assert!(error <= 0.15, "{species}: {count} needles for {target}");
        }
    }
}

#[test]
fn small_and_zero_targets_do_not_break() {
    for species in Species::ALL {
        let five_k = generate(
            species,
            &GenerateOptions {
                seed: 0,
                target_needles: Some(5_000),
            },
        );
        let error = (five_k.needles.len() as f64 / 5_000.0 - 1.0).abs();
        assert!(error <= 0.15, "{species}: {}", five_k.needles.len());
        let none = generate(
            species,
            &GenerateOptions {
                seed: 0,
                target_needles: Some(0),
            },
        );
        assert!(none.needles.is_empty());
    }
}

#[test]
fn heights_and_footprint_are_in_range() {
    for species in Species::ALL {
        for seed in 0..3 {
            let tree = tree(species, seed);
            let (min, max) = tree.needle_bounds().unwrap();
            let (lo, hi) = height_range(species);
            assert!(max.y >= lo && max.y <= hi, "{species} seed {seed}: height {}", max.y);
            assert!(min.y >= -0.05, "{species}: needles below ground ({})", min.y);
            let width = (max.x - min.x).max(max.z - min.z);
            assert!(width > 0.5 && width < max.y * 1.2, "{species}: width {width}");
        }
    }
}

#[test]
fn trees_stand_at_the_origin() {
    for species in Species::ALL {
        let tree = tree(species, 0);
        let base = tree
            .wood
            .iter()
            .map(|w| w.start)
            .min_by(|a, b| a.y.total_cmp(&b.y))
            .unwrap();
        assert!(base.length() < 1e-4, "{species}: base at {base}");
    }
}

#[test]
fn species_names_round_trip() {
    for species in Species::ALL {
        assert_eq!(Species::from_name(species.name()), Some(species));
        assert_eq!(species.name().parse::<Species>(), Ok(species));
        assert_eq!(species.to_string(), species.name());
    }
    assert_eq!(Species::from_name("Scots_Pine"), Some(Species::ScotsPine));
    let error = "larch".parse::<Species>().unwrap_err().to_string();
    assert!(error.contains("larch") && error.contains("norway-spruce"), "{error}");
}

#[test]
fn shoot_prototypes_grow_the_same_tree_from_a_few_dozen_shoots() {
    use crate::model::needle::bounds;
    for species in Species::ALL {
        for target in [20_000usize, 200_000] {
            let options = GenerateOptions {
                seed: 5,
                target_needles: Some(target),
            };
            let input = generate_prototypes(species, &options);
            assert_eq!(
                input,
                generate_prototypes(species, &options),
                "{species}: deterministic"
            );
            let placed = input.placed_needle_count() as f64;
            let stored: usize = input.prototypes.iter().map(Vec::len).sum();
            eprintln!(
                "{species} {target}: {} prototypes ({stored} needles) placed {} times = {placed} needles",
                input.prototypes.len(),
                input.placements.len()
            );
            assert!(
                (placed / target as f64 - 1.0).abs() < 0.03,
                "{species}: {placed} placed needles for {target}"
            );
            assert!(
                input.prototypes.len() <= 120,
                "{species}: {} prototypes",
                input.prototypes.len()
            );
            assert!(
                stored * 10 < placed as usize,
                "{species}: {stored} stored for {placed} placed"
            );
            assert!(input.placements.iter().all(|p| p.is_valid()));
            // The same crown as the flat generator's, within a few centimetres.
            let flat = generate(species, &options);
            let tree = input.to_tree();
            assert!(tree.needles.iter().all(Needle::is_valid));
            let (lo, hi) = bounds(tree.needles.iter().flat_map(|n| [n.base, n.tip])).unwrap();
            let (flat_lo, flat_hi) = flat.needle_bounds().unwrap();
            let size = (flat_hi - flat_lo).length();
            assert!(
                (lo - flat_lo).length() < 0.05 * size && (hi - flat_hi).length() < 0.05 * size,
                "{species}: bounds {lo}..{hi} against {flat_lo}..{flat_hi}"
            );
            // Needle lengths keep the species' range (scales stay near 1).
            let mut lengths: Vec<f32> = tree.needles.iter().map(Needle::length).collect();
            let mut flat_lengths: Vec<f32> = flat.needles.iter().map(Needle::length).collect();
            lengths.sort_by(f32::total_cmp);
            flat_lengths.sort_by(f32::total_cmp);
            let median = lengths[lengths.len() / 2];
            let flat_median = flat_lengths[flat_lengths.len() / 2];
            assert!(
                (median / flat_median - 1.0).abs() < 0.15,
                "{species}: median needle {median} against {flat_median}"
            );
        }
    }
}
