//! Prototypes and placements (record format 3): the direct cut equals the
//! flattened record's cut at every probe error, every needle is stood for
//! exactly once, placed errors scale with their placement, flat records
//! convert losslessly both ways, and the file round-trips. Seen from any
//! camera, view-dependent cuts stay exact partitions.

use bevy_conifer_lod::model::Cut;
use bevy_conifer_lod::model::compact::{CompactSpecies, shader_threshold_code, threshold_code};
use bevy_conifer_lod::model::record::CutStrategy;
use bevy_conifer_lod::model::record::NO_PARENT;
use bevy_conifer_lod::model::{
    BakeOptions, LodRecord, Needle, Placement, PrototypeInput, PrototypeRecord, TreeInput, ViewPoint, bake,
    bake_prototypes, decode_prototype_record, decode_record, encode_prototype_record, encode_record,
};
use glam::{Quat, Vec3};
use proptest::prelude::*;

/// A random prototype tree: 1–4 prototypes of 1–9 fanning needles, placed
/// 1–60 times with random rotations, translations and scales 0.5–2.
fn prototype_tree() -> impl Strategy<Value = PrototypeInput> {
    let needle = (
        prop::array::uniform3(-0.03f32..0.03),
        prop::array::uniform3(-1.0f32..1.0),
        0.01f32..0.1,
        0.0002f32..0.0015,
    );
    let prototype = prop::collection::vec(needle, 1..10);
    let placement = (
        0u32..4,
        prop::array::uniform4(-1.0f32..1.0),
        prop::array::uniform3(-2.0f32..2.0),
        0.5f32..2.0,
    );
    (
        prop::collection::vec(prototype, 1..5),
        prop::collection::vec(placement, 1..60),
    )
        .prop_map(|(prototypes, placements)| {
            let prototypes: Vec<Vec<Needle>> = prototypes
                .into_iter()
                .map(|needles| {
                    needles
                        .into_iter()
                        .map(|(offset, direction, length, radius)| {
                            let direction = Vec3::from(direction).try_normalize().unwrap_or(Vec3::Y);
                            let base = Vec3::from(offset);
                            Needle {
                                base,
                                tip: base + direction * length,
                                radius,
                                normal: direction.any_orthonormal_vector(),
                                group: 0,
                            }
                        })
                        .collect()
                })
                .collect();
            let count = prototypes.len() as u32;
            let placements = placements
                .into_iter()
                .map(|(k, q, t, scale)| Placement {
                    prototype: k % count,
                    rotation: {
                        let q = Quat::from_array(q);
                        if q.length() > 0.1 {
                            q.normalize()
                        } else {
                            Quat::IDENTITY
                        }
                    },
                    translation: Vec3::from(t),
                    scale,
                    needle_age: (k % 3) as u8,
                })
                .collect();
            PrototypeInput {
                name: "random prototypes".into(),
                prototypes,
                placements,
                ..Default::default()
            }
        })
}

/// Every node error of the flattened tree, the midpoints between them, the
/// prism side boundaries, 0 and far beyond.
fn probe_errors(flat: &LodRecord) -> Vec<f32> {
    let mut errors: Vec<f32> = (0..flat.node_count() as u32).map(|k| flat.node_error(k)).collect();
    for needle in &flat.needles {
        errors.push(needle.radius * 0.05);
        errors.push(needle.radius * 0.5);
    }
    errors.sort_by(f32::total_cmp);
    errors.dedup();
    let mids: Vec<f32> = errors.windows(2).map(|w| 0.5 * (w[0] + w[1])).collect();
    errors.extend(mids);
    errors.extend([0.0, 1e3, f32::INFINITY]);
    errors
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 48, ..ProptestConfig::default() })]

    #[test]
    fn direct_cut_equals_the_flattened_cut(input in prototype_tree()) {
        let record = bake_prototypes(&input, &BakeOptions::default(), &()).unwrap();
        let flat = record.flatten().unwrap();
        prop_assert_eq!(flat.needle_count() as u64, record.needle_count());
        prop_assert_eq!(record.needle_count(), input.placed_needle_count());
        for e in probe_errors(&flat) {
            let direct = record.cut(e).sorted();
            prop_assert_eq!(&direct, &flat.cut(e).sorted(), "e = {}", e);
            prop_assert_eq!(&direct, &flat.cut_with(e, CutStrategy::Intervals).sorted(), "e = {}", e);
            prop_assert!(flat.coverage(&direct).iter().all(|&c| c == 1), "e = {}: a needle not stood for once", e);
        }
    }

    #[test]
    fn gpu_placed_layout_draws_every_needle_once(input in prototype_tree()) {
        // The compact layout's placed draws (CPU reference of the compute
        // passes and vertex shaders): at every probe error each needle is
        // stood for once, and the cut is the record's but for nodes whose
        // interval ends within 0.2 % of the error (code rounding).
        let record = bake_prototypes(&input, &BakeOptions::default(), &()).unwrap().quantized().unwrap();
        let flat = record.flatten().unwrap();
        let compact = CompactSpecies::build_placed(&record).unwrap();
        for e in probe_errors(&flat) {
            for threshold in [threshold_code as fn(f32) -> u16, shader_threshold_code] {
                let (drawn, _) = compact.placed_drawn(&record, threshold(e), e, threshold, None);
                prop_assert!(flat.coverage(&drawn).iter().all(|&c| c == 1), "e = {}: a needle not stood for once", e);
                let direct = record.cut(e);
                let lines = |cut: &bevy_conifer_lod::model::Cut| -> std::collections::BTreeSet<u32> {
                    cut.original_lines.iter().chain(&cut.merged_lines).copied().chain(cut.prisms.iter().map(|p| p.0 | 1 << 31)).collect()
                };
                for node in lines(&drawn).symmetric_difference(&lines(&direct)) {
                    let node = node & !(1 << 31);
                    let near = |x: f32| (x / e - 1.0).abs() < 2e-3;
                    prop_assert!(near(flat.node_error(node)) || near(flat.parent_error(node)), "e = {}: node {}", e, node);
                }
            }
        }
    }

    #[test]
    fn view_dependent_cuts_are_exact_partitions_wherever_the_camera_is(
        input in prototype_tree(),
        cameras in prop::collection::vec(prop::array::uniform3(-5.0f32..5.0), 3),
        inside in 0usize..1000,
    ) {
        // Each placement and level-2 line takes the error of its own
        // sphere's nearest point. Cameras: random ones in and around the
        // tree, one at the centre of a node's sphere (inside it and its
        // ancestors'), one at the tree sphere's centre, one beyond range.
        let record = bake_prototypes(&input, &BakeOptions::default(), &()).unwrap().quantized().unwrap();
        let flat = record.flatten().unwrap();
        let compact = CompactSpecies::build_placed(&record).unwrap();
        let level2 = (record.placements.len() + record.tree_merged.len()) as u32;
        // Each sphere holds its children's (with room to spare for
        // rounding), and the tree's holds them all.
        let holds = |outer: bevy_conifer_lod::model::Sphere, inner: bevy_conifer_lod::model::Sphere| {
            outer.center.distance(inner.center) + inner.radius < outer.radius
        };
        for node in 0..level2 {
            let parent = record.tree_parent(node);
            if parent != NO_PARENT {
                prop_assert!(holds(record.node_sphere(parent), record.node_sphere(node)), "node {}", node);
            }
            prop_assert!(holds(record.tree_sphere(), record.node_sphere(node)), "node {}", node);
        }
        let mut points: Vec<Vec3> = cameras.into_iter().map(Vec3::from).collect();
        points.push(record.node_sphere(inside as u32 % level2).center);
        points.push(record.tree_sphere().center);
        points.push(record.tree_sphere().center + Vec3::new(3e4, 1e3, -2e4));
        for camera in points {
            for slope in [1e-4f32, 2e-3, 3e-2, 0.4] {
                let view = ViewPoint::new(camera, slope);
                // Errors are monotone up the hierarchy: each parent's is at
                // most its child's, so a child of an accepted node is accepted.
                for node in 0..level2 {
                    let parent = record.tree_parent(node);
                    if parent != NO_PARENT {
                        prop_assert!(
                            record.node_error_seen_from(&view, parent) <= record.node_error_seen_from(&view, node),
                            "camera {camera}, node {node}"
                        );
                    }
                }
                let cut = record.cut_seen_from(&view);
                prop_assert!(flat.coverage(&cut).iter().all(|&c| c == 1), "camera {camera}: a needle not stood for once");
                if compact.placements.is_empty() {
                    continue;
                }
                // The GPU's per-node test (CPU reference): also exact, and
                // the walk's cut but for code rounding.
                for threshold in [threshold_code as fn(f32) -> u16, shader_threshold_code] {
                    let e = compact.sphere_error(&view, &compact.tree_sphere);
                    let (drawn, _) = compact.placed_drawn(&record, threshold(e), e, threshold, Some(&view));
                    prop_assert!(flat.coverage(&drawn).iter().all(|&c| c == 1), "camera {camera}: a needle not drawn once");
                    let lines = |cut: &bevy_conifer_lod::model::Cut| -> std::collections::BTreeSet<u32> {
                        cut.original_lines.iter().chain(&cut.merged_lines).copied().chain(cut.prisms.iter().map(|p| p.0 | 1 << 31)).collect()
                    };
                    let (a, b) = (lines(&drawn), lines(&cut));
                    // Codes round errors (a placed error is compared as
                    // `code(error) ≤ threshold(e / scale)`, a prism by its
                    // line code): at a boundary a line and its two
                    // children swap, or a prism and its line.
                    let differing = a.symmetric_difference(&b).count();
                    prop_assert!(differing <= 3 + a.len() / 30, "camera {camera}: {differing} of {} nodes differ", a.len());
                }
            }
        }
    }

    #[test]
    fn placed_errors_scale_with_their_placement(input in prototype_tree()) {
        let record = bake_prototypes(&input, &BakeOptions::default(), &()).unwrap();
        let flat = record.flatten().unwrap();
        for (p, placement) in record.placements.iter().enumerate() {
            let prototype = &record.prototypes[placement.prototype as usize];
            let root_error = prototype.node_error(prototype.root());
            prop_assert_eq!(record.placed_root_error(p), root_error * placement.scale);
            // The placed needles are the prototype's, moved and scaled.
            let first = record.needle_offset(p) as usize;
            for (i, needle) in prototype.needles.iter().enumerate() {
                let placed = &flat.needles[first + i];
                prop_assert_eq!(placed.radius, needle.radius * placement.scale);
                prop_assert!(placed.base.distance(placement.place_point(needle.base)) == 0.0);
                let expected_length = needle.length() * placement.scale;
                prop_assert!((placed.length() - expected_length).abs() <= 1e-5 * (1.0 + expected_length));
            }
        }
        // Parent error ≥ child error across both levels (checked by the
        // flat record's own invariants, asserted here node by node).
        for node in 0..flat.node_count() as u32 {
            prop_assert!(flat.parent_error(node) >= flat.node_error(node));
        }
    }

    #[test]
    fn prototype_files_round_trip_exactly(input in prototype_tree()) {
        let record = bake_prototypes(&input, &BakeOptions::default(), &()).unwrap();
        let bytes = encode_prototype_record(&record).unwrap();
        prop_assert_eq!(&decode_prototype_record(&bytes).unwrap(), &record);
        prop_assert_eq!(decode_record(&bytes).unwrap(), record.flatten().unwrap());
        // A bake is already what the file stores: quantizing changes nothing.
        prop_assert_eq!(&record.quantized().unwrap(), &record);
    }

    #[test]
    fn quantizing_moves_needles_by_micrometres_and_keeps_errors_monotone(input in prototype_tree()) {
        let record = bake_prototypes(&input, &BakeOptions::default(), &()).unwrap();
        // The placed needles of the bake against the unquantized input's.
        for (placement, p) in record.placements.iter().zip(&input.placements) {
            let (baked, given) = (&record.prototypes[placement.prototype as usize], &input.prototypes[p.prototype as usize]);
            for (b, g) in baked.needles.iter().zip(given) {
                prop_assert!(b.base.distance(g.base) < 1e-5 && b.tip.distance(g.tip) < 1e-5, "{:?} vs {:?}", b, g);
                prop_assert!((b.radius / g.radius - 1.0).abs() < 2.5e-4);
                // Placed: the placement's rotation and translation on their
                // codes move a needle end by a few micrometres more.
                for (end, given_end) in [(b.base, g.base), (b.tip, g.tip)] {
                    let (placed, wanted) = (placement.place_point(end), p.place_point(given_end));
                    prop_assert!(placed.distance(wanted) < 2e-5, "{} vs {}", placed, wanted);
                }
            }
            prop_assert_eq!(placement.scale, p.scale);
        }
        let flat = record.flatten().unwrap();
        for node in 0..flat.node_count() as u32 {
            prop_assert!(flat.parent_error(node) >= flat.node_error(node));
        }
    }
}

/// A flat tree: 30 fascicles of 3 needles on a helix, 2 single needles.
fn flat_tree() -> TreeInput {
    let mut needles = Vec::new();
    for g in 0..32u32 {
        let t = g as f32 * 0.41;
        let base = Vec3::new(t.cos() * 0.4, g as f32 * 0.03, t.sin() * 0.4);
        for k in 0..if g < 30 { 3 } else { 1 } {
            let direction = Vec3::new(t.cos(), 0.3 + 0.1 * k as f32, t.sin() + 0.15 * k as f32).normalize();
            needles.push(Needle {
                base,
                tip: base + direction * 0.06,
                radius: 0.0008,
                normal: direction.any_orthonormal_vector(),
                group: 100 - g,
            });
        }
    }
    TreeInput {
        name: "helix".into(),
        needles,
        ..Default::default()
    }
}

#[test]
fn flat_records_convert_to_prototypes_and_back_exactly() {
    let flat = bake(&flat_tree(), &BakeOptions::default(), &()).unwrap();
    let prototypes = PrototypeRecord::from_flat(&flat).unwrap();
    assert_eq!(prototypes.prototypes.len(), 32);
    assert!(prototypes.placements.iter().all(Placement::is_identity));
    assert_eq!(prototypes.tree_merged.len(), 31);
    assert_eq!(prototypes.flatten().unwrap(), flat);
    // Written as format 3 and read back, either view.
    let bytes = encode_record(&flat).unwrap();
    assert_eq!(decode_record(&bytes).unwrap(), flat);
    assert_eq!(decode_prototype_record(&bytes).unwrap(), prototypes);
}

#[test]
fn one_prototype_placed_many_times_is_stored_once() {
    let tree = flat_tree();
    let shoot: Vec<Needle> = tree.needles.iter().filter(|n| n.group == 100).copied().collect();
    assert_eq!(shoot.len(), 3);
    let placements: Vec<Placement> = (0..2000)
        .map(|i| {
            let angle = i as f32 * 2.399_963;
            Placement {
                prototype: 0,
                rotation: Quat::from_rotation_y(angle) * Quat::from_rotation_x(0.3 * (i % 7) as f32),
                translation: Vec3::new(angle.cos(), i as f32 * 0.002, angle.sin()) * (1.0 + (i % 13) as f32 * 0.1),
                scale: 0.8 + 0.4 * ((i * 37) % 100) as f32 / 100.0,
                needle_age: (i / 500) as u8,
            }
        })
        .collect();
    let input = PrototypeInput {
        name: "one shoot".into(),
        prototypes: vec![shoot],
        placements,
        ..Default::default()
    };
    // What the lines and placements cost (the crown impostor, the same
    // bytes in both files, is measured in `model::file`).
    let no_impostor = BakeOptions {
        impostor: None,
        line_calibration: None,
        ..BakeOptions::default()
    };
    let record = bake_prototypes(&input, &no_impostor, &()).unwrap();
    assert_eq!(record.needle_count(), 6000);
    assert_eq!(record.prototype_needle_count(), 3);
    assert_eq!(record.tree_merged.len(), 1999);
    let flat = record.flatten().unwrap();
    let proto_bytes = encode_prototype_record(&record).unwrap().len();
    // The same tree written flat: every group its own prototype.
    let flat_bytes = encode_record(&flat).unwrap().len();
    // The shoot is stored once: what remains is each placement (a
    // similarity on codes, 23 bytes) and its level-2 merged line (about
    // 7); the needle ages are four runs.
    assert!(
        proto_bytes < 2000 * 31 && proto_bytes * 3 < flat_bytes * 2,
        "prototypes {proto_bytes} bytes, flat {flat_bytes} bytes"
    );
    // The cut is the flat cut at every distance band.
    for e in [0.0, 1e-4, 5e-4, 2e-3, 1e-2, 0.05, 0.2, 1.0, 10.0] {
        assert_eq!(record.cut(e).sorted(), flat.cut(e).sorted(), "e = {e}");
    }
}

#[test]
fn bad_prototype_inputs_are_errors() {
    use bevy_conifer_lod::model::BakeError;
    let needle = Needle {
        base: Vec3::ZERO,
        tip: Vec3::Y * 0.05,
        radius: 0.001,
        normal: Vec3::X,
        group: 0,
    };
    let mut input = PrototypeInput {
        name: "bad".into(),
        prototypes: vec![vec![needle; 2]],
        placements: vec![Placement::identity(0), Placement::identity(1)],
        ..Default::default()
    };
    assert_eq!(
        bake_prototypes(&input, &BakeOptions::default(), &()),
        Err(BakeError::InvalidPlacement { index: 1 })
    );
    input.placements[1] = Placement {
        scale: f32::NAN,
        ..Placement::identity(0)
    };
    assert_eq!(
        bake_prototypes(&input, &BakeOptions::default(), &()),
        Err(BakeError::InvalidPlacement { index: 1 })
    );
    input.placements[1] = Placement {
        scale: 0.0,
        ..Placement::identity(0)
    };
    assert!(bake_prototypes(&input, &BakeOptions::default(), &()).is_err());
    input.placements[1] = Placement::identity(0);
    input.prototypes[0][1].radius = f32::NAN;
    assert_eq!(
        bake_prototypes(&input, &BakeOptions::default(), &()),
        Err(BakeError::InvalidPrototypeNeedle {
            prototype: 0,
            needle: 1
        })
    );
    input.prototypes[0].clear();
    assert_eq!(
        bake_prototypes(&input, &BakeOptions::default(), &()),
        Err(BakeError::NoNeedles)
    );
    // A file's placement that degenerates a valid prototype (found by the
    // fuzz target): a length that underflows, positions that overflow.
    let long = Needle {
        tip: Vec3::Y * 4.0,
        ..needle
    };
    input.prototypes[0] = vec![
        long,
        Needle {
            base: Vec3::X * 0.5,
            ..long
        },
    ];
    input.placements[1] = Placement::identity(0);
    let record = bake_prototypes(&input, &BakeOptions::default(), &()).unwrap();
    for scale in [1e-40f32, 3e38] {
        let placements = vec![Placement {
            scale,
            ..Placement::identity(0)
        }];
        let rebuilt = PrototypeRecord::from_parts(
            record.name.clone(),
            record.prototypes.clone(),
            placements,
            Vec::new(),
            Vec::new(),
            Default::default(),
            record.material,
            record.max_sides,
            record.bake.clone(),
        );
        assert!(
            matches!(
                rebuilt,
                Err(bevy_conifer_lod::model::record::RecordInvalid::BadPlacement(0))
            ),
            "scale {scale}: {rebuilt:?}"
        );
    }
    // More placed needles than a record holds: refused before any work.
    let input = PrototypeInput {
        name: "huge".into(),
        prototypes: vec![vec![needle; 1 << 12]],
        placements: vec![Placement::identity(0); (1 << 12) + 1],
        ..Default::default()
    };
    assert!(matches!(
        bake_prototypes(&input, &BakeOptions::default(), &()),
        Err(BakeError::TooManyNeedles(_))
    ));
}

#[test]
fn a_camera_in_a_tall_crown_sees_prisms_beside_it_and_lines_across_it() {
    // A mature Douglas fir (35–50 m) seen from 2 m beside its trunk at 40 %
    // of its height, 1080 pixels high at 45°: each placement at the error
    // of its own sphere's nearest point, against the paper's one error for
    // the tree (from the crown's centre).
    use bevy_conifer_lod::generate::{Age, GenerateOptions, Species, generate_prototypes};
    use bevy_conifer_lod::model::ViewParams;
    let input = generate_prototypes(
        Species::DouglasFir,
        &GenerateOptions {
            seed: 0,
            target_needles: None,
            age: Age::Mature,
        },
    );
    let record = bake_prototypes(&input, &BakeOptions::default(), &()).unwrap();
    let flat = record.flatten().unwrap();
    let (lo, hi) = flat.bounds();
    let height = hi.y - lo.y;
    assert!(height > 35.0, "{height} m");
    let camera = Vec3::new(2.0, lo.y + 0.4 * height, 0.0);
    let slope = ViewParams::default().error_per_distance();
    let seen = record.cut_seen_from(&ViewPoint::new(camera, slope));
    let per_tree = record.cut(slope * camera.distance(flat.crown_center()));
    for cut in [&seen, &per_tree] {
        assert!(flat.coverage(cut).iter().all(|&c| c == 1));
    }
    // Beside the camera (within 0.5 m) the paper's error, from the crown's
    // centre metres away, gives needles fewer sides than the view needs;
    // past 25 m it still draws prisms where a pixel holds the needle.
    let distance = |i: u32| {
        let n = &flat.needles[i as usize];
        n.base.distance(camera).min(n.tip.distance(camera))
    };
    let near_sides = |cut: &Cut| {
        let sides: Vec<f64> = cut
            .prisms
            .iter()
            .filter(|p| distance(p.0) < 0.5)
            .map(|p| f64::from(p.1))
            .collect();
        (sides.len(), sides.iter().sum::<f64>() / sides.len().max(1) as f64)
    };
    let far_lines =
        |cut: &Cut| cut.original_lines.iter().filter(|&&i| distance(i) > 25.0).count() + cut.merged_lines.len();
    let primitives = |s: &bevy_conifer_lod::model::CutStats| s.triangles + s.lines_original + s.lines_merged;
    let (seen_stats, tree_stats) = (flat.cut_stats(&seen), flat.cut_stats(&per_tree));
    let describe = |cut: &Cut, stats: &bevy_conifer_lod::model::CutStats| {
        format!(
            "{} prisms, {} original and {} merged lines, {} primitives; near: {:?} (needles, mean sides); \
             far lines {}",
            cut.prisms.len(),
            cut.original_lines.len(),
            cut.merged_lines.len(),
            primitives(stats),
            near_sides(cut),
            far_lines(cut)
        )
    };
    println!(
        "{height:.1} m fir, camera 2 m from the trunk at 40 % of its height, 1080 px at 45°:\n  \
         seen from the camera: {}\n  one error for the tree: {}",
        describe(&seen, &seen_stats),
        describe(&per_tree, &tree_stats)
    );
    let ((near, seen_sides), (_, tree_sides)) = (near_sides(&seen), near_sides(&per_tree));
    assert!(near > 0);
    assert_eq!(
        seen_sides,
        f64::from(flat.max_sides),
        "every needle beside the camera is a full prism"
    );
    assert!(tree_sides < seen_sides);
    assert!(
        far_lines(&seen) > 10 * far_lines(&per_tree).max(100),
        "the far crown is lines seen from the camera"
    );
}
