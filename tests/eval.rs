//! `conifer eval`'s harness on a small tree, headless (lavapipe): every
//! method renders, the counts follow each method's rule, and the measures
//! see what they should.
#![cfg(feature = "eval")]

mod common;

use bevy_conifer_lod::eval::scene::{EvalView, Method};
use bevy_conifer_lod::eval::{EvalOptions, evaluate};
use bevy_conifer_lod::generate::{GenerateOptions, Species, generate};
use bevy_conifer_lod::model::{BakeOptions, bake};

/// A young tree of 6,000 needles, baked flat.
fn young_record(species: Species, seed: u64) -> bevy_conifer_lod::model::LodRecord {
    let tree = generate(
        species,
        &GenerateOptions {
            seed,
            target_needles: Some(6000),
            age: bevy_conifer_lod::generate::Age::Young,
        },
    );
    bake(&tree, &BakeOptions::default(), &()).unwrap()
}

#[test]
fn every_method_renders_and_is_measured() {
    let _turn = common::gpu_turn();
    let record = young_record(Species::ScotsPine, 4);
    let needles = record.needle_count() as u64;
    let out = std::path::PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("target/test-output/eval");
    let options = EvalOptions {
        methods: Method::ALL.to_vec(),
        distances: vec![20.0, 4.0],
        view: EvalView {
            transition: 0.5,
            ..EvalView::square(96, 45.0)
        },
        dolly_steps: 4,
        timed_frames: 1,
        out_dir: Some(out.clone()),
        wind: None,
        flicker_distances: vec![20.0],
        orbit_steps: 6,
        pan_steps: 4,
    };
    let report = evaluate(record, &options, &mut |_| {}).unwrap();
    assert!(report.blank.is_empty(), "{:?}", report.blank);
    assert_eq!(report.methods.len(), 5);
    assert_eq!(report.dolly_distances.len(), 4);
    for (name, method) in &report.methods {
        // Distances come out sorted.
        let d: Vec<f32> = method.distances.iter().map(|d| d.distance).collect();
        assert_eq!(d, [4.0, 20.0], "{name}");
        assert_eq!(method.dolly_change.len(), 3);
        for at in &method.distances {
            assert!((0.0..=1.0).contains(&at.coverage_error), "{name}: {at:?}");
            assert!((0.0..=255.0).contains(&at.color_error), "{name}: {at:?}");
            assert!((0.0..=1.0).contains(&at.perceptual), "{name}: {at:?}");
            assert_eq!(at.primitives, at.triangles + at.lines);
            assert!(at.frame_ms > 0.0);
        }
    }
    // Shimmer: an orbit and a pan at 20 m for every method, measured over
    // changes the reference sees too (the tree turns and crosses the view).
    assert_eq!(report.reference.flicker.len(), 2);
    for f in &report.reference.flicker {
        assert!(f.mean_change > 0.0, "{f:?}");
    }
    for (name, method) in &report.methods {
        let paths: Vec<&str> = method.flicker.iter().map(|f| f.path.name()).collect();
        assert_eq!(paths, ["orbit", "pan"], "{name}");
        for f in &method.flicker {
            assert!(
                f.flicker_mean.is_finite() && f.flicker_p99 >= f.flicker_mean - 1e-9,
                "{name}: {f:?}"
            );
            assert!((0.0..=255.0).contains(&f.mean_change), "{name}: {f:?}");
        }
    }
    let m = |name: &str| &report.methods[name];
    // Raw draws every needle's Lmax prism at every distance, no lines.
    let raw = &m("raw").distances[0];
    assert_eq!(raw.needle_primitives, needles * 28);
    assert_eq!(raw.lines, 0);
    // Ours and the paper draw the same cut, except that ours turns into
    // its crown impostor (two triangles) far away, and draws both while it
    // fades; this small tree in a small picture is its impostor at 20 m.
    for (o, p) in m("ours").distances.iter().zip(&m("paper").distances) {
        let (ours, paper) = ((o.triangles, o.lines), (p.triangles, p.lines));
        assert!(
            ours == paper || ours == (paper.0 + 2, paper.1) || ours == (2, 0),
            "{o:?} vs {p:?}"
        );
    }
    assert_eq!((m("ours").distances[1].triangles, m("ours").distances[1].lines), (2, 0));
    assert!(m("ours").distances[1].primitives * 10 < raw.primitives);
    // Sampling spends the paper's cut's budget: same triangles, no more
    // needle lines; ours no more than the cut and its quad.
    for ((o, p), s) in m("ours")
        .distances
        .iter()
        .zip(&m("paper").distances)
        .zip(&m("sampling").distances)
    {
        assert_eq!(p.triangles, s.triangles);
        assert!(s.needle_primitives <= p.needle_primitives + 1, "{s:?} vs {p:?}");
        assert!(o.needle_primitives <= p.needle_primitives + 2, "{o:?} vs {p:?}");
    }
    // bevy-lod's chain shrinks and its levels enter in order.
    let levels = &report.bevy_lod_levels;
    assert_eq!(levels.len(), 5);
    assert!(
        levels
            .windows(2)
            .all(|w| w[1].triangles < w[0].triangles && w[1].enters_at >= w[0].enters_at)
    );
    // The paper's opacity over-covers (the reason ours differs) ...
    assert!(m("ours").distances[1].coverage_error < m("paper").distances[1].coverage_error);
    assert!(report.check().is_empty(), "{:?}", report.check());
    // ... and the files are there.
    for file in [
        "ref_4m.png",
        "ours_20m.png",
        "bevy-lod_4m.png",
        "contact_sheet.png",
        "popping.png",
        "primitives.png",
    ] {
        assert!(out.join(file).is_file(), "{file}");
    }
    assert_eq!(image::open(out.join("ref_20m.png")).unwrap().width(), 96);
}

#[test]
fn inside_a_crown_each_placement_is_nearer_the_reference_than_one_error() {
    let _turn = common::gpu_turn();
    // `conifer eval --inside` on a small tree of shared prototypes: the
    // camera 2 m from the trunk at 40 % of the height, both error scopes
    // against the supersampled reference.
    use bevy_conifer_lod::eval::inside::{InsideOptions, evaluate_inside};
    use bevy_conifer_lod::generate::{Age, generate_prototypes};
    use bevy_conifer_lod::model::bake_prototypes;
    let input = generate_prototypes(
        Species::NorwaySpruce,
        &GenerateOptions {
            seed: 2,
            target_needles: Some(20_000),
            age: Age::Young,
        },
    );
    let record = bake_prototypes(&input, &BakeOptions::default(), &())
        .unwrap()
        .quantized()
        .unwrap();
    let view = EvalView::square(96, 60.0);
    let options = InsideOptions {
        from_trunk: 0.6,
        ..InsideOptions::new(view)
    };
    let report = evaluate_inside(&record, &options, &mut |_| {}).unwrap();
    let [tree, placement] = [&report.methods[0], &report.methods[1]];
    println!("{report:#?}");
    assert_eq!((tree.error_scope, placement.error_scope), ("tree", "placement"));
    assert!(report.near_needles > 0);
    for m in [tree, placement] {
        assert_eq!(m.primitives, m.triangles + m.lines);
        assert!((0.0..=1.0).contains(&m.coverage_error));
    }
    // Beside the camera, each placement's own error keeps needles full
    // prisms; one error for the tree thins them.
    assert!(placement.coarse_near_needles < tree.coarse_near_needles);
    assert!(placement.color_error < tree.color_error, "{placement:?} {tree:?}");
}

/// In wind, the reference (CPU field) and ours (GPU field) sway together:
/// the reference's pictures move, ours keeps its calm coverage error.
#[test]
fn in_wind_ours_sways_with_the_reference() {
    let _turn = common::gpu_turn();
    let record = young_record(Species::NorwaySpruce, 2);
    let run = |wind: Option<f32>| {
        let options = EvalOptions {
            methods: vec![Method::Ours],
            distances: vec![3.0, 12.0],
            // Lines (the swaying impostor is measured in render_impostor).
            view: EvalView {
                ours_impostor: false,
                ..EvalView::square(96, 45.0)
            },
            dolly_steps: 4,
            timed_frames: 1,
            out_dir: None,
            wind,
            flicker_distances: Vec::new(),
            orbit_steps: 0,
            pan_steps: 0,
        };
        evaluate(record.clone(), &options, &mut |_| {}).unwrap()
    };
    let calm = run(None);
    let windy = run(Some(4.0));
    assert_eq!((calm.wind, windy.wind), (0.0, 4.0));
    // The reference swayed: its dolly pictures change more step to step.
    let change = |r: &bevy_conifer_lod::eval::EvalReport| r.reference.dolly_change.iter().sum::<f64>();
    assert!(
        change(&windy) > change(&calm) + 0.05,
        "{} vs {}",
        change(&windy),
        change(&calm)
    );
    let ours = |r: &bevy_conifer_lod::eval::EvalReport| r.methods["ours"].distances.clone();
    for (c, w) in ours(&calm).iter().zip(ours(&windy)) {
        assert!(
            w.coverage_error <= c.coverage_error + 0.01,
            "at {} m: {} in wind, {} calm",
            c.distance,
            w.coverage_error,
            c.coverage_error
        );
    }
    assert!(windy.methods["ours"].popping_max <= 1.0 + calm.methods["ours"].popping_max);
    // The shadow scene sways too (ours on the GPU, the exact shadow by the
    // CPU field): ours' shadow error stays near its calm one.
    for (c, w) in ours(&calm).iter().zip(ours(&windy)) {
        let (Some(c_error), Some(w_error)) = (c.shadow_coverage_error, w.shadow_coverage_error) else {
            panic!("at {} m: no shadow error", c.distance);
        };
        assert!(
            w_error <= c_error + 0.02,
            "at {} m: shadow error {w_error} in wind, {c_error} calm",
            c.distance
        );
    }
}
