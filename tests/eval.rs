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

/// `--float-blending` end to end: `ours` drawn into `Rgba32Float` writes
/// linear light whose colour agrees with its alpha, and the report says
/// how it was drawn. The shipped young spruce at 12.22 m with a line for
/// nearly every needle puts a hundred blends on a crown pixel; in `Hdr`
/// on lavapipe 162 of its pixels came out darker in red than their alpha
/// allows by more than 0.01 of linear light (README, "Lavapipe rounds
/// 16-bit blends toward zero"). Here no pixel may be darker than that by
/// more than one 8-bit step of the sky and a half (a line fainter than
/// half a level of alpha still darkens the sky's red by a level): it
/// finds 1.00, and 4.92 with `hdr` in place of `float_blending`.
#[test]
fn float_blending_pictures_keep_colour_and_coverage_together() {
    let _turn = common::gpu_turn();
    let root = std::path::PathBuf::from(env!("CARGO_MANIFEST_DIR"));
    let bytes = std::fs::read(root.join("assets/trees/norway-spruce.conifer")).unwrap();
    let record = bevy_conifer_lod::model::file::decode_record(&bytes).unwrap();
    let out = root.join("target/test-output/eval-float");
    let options = EvalOptions {
        methods: vec![Method::Ours],
        distances: vec![12.22],
        view: EvalView {
            float_blending: true,
            tonemapping: false,
            pixel_error: 0.25,
            ..EvalView::square(160, 45.0)
        },
        dolly_steps: 2,
        timed_frames: 1,
        out_dir: Some(out.clone()),
        wind: None,
        flicker_distances: Vec::new(),
        orbit_steps: 0,
        pan_steps: 0,
    };
    let report = evaluate(record, &options, &mut |_| {}).unwrap();
    assert!(report.float_blending && !report.tonemapping);
    assert_eq!(report.line_raster, "Area");
    let picture = image::open(out.join("ours_12.22m.png")).unwrap().to_rgba8();
    let sky = picture.get_pixel(0, 0).0;
    assert_eq!(sky[3], 0, "the corner is sky");
    let (mut covered, mut worst) = (0.0f32, 0.0f32);
    for p in picture.pixels() {
        let alpha = f32::from(p.0[3]) / 255.0;
        covered += alpha;
        for (&light, &sky) in p.0.iter().zip(&sky).take(3) {
            // Linear light at least what the sky keeps through the
            // pixel's alpha, in 8-bit steps of the sky.
            let floor = (1.0 - alpha) * common::linear(sky);
            let step = common::linear(sky) - common::linear(sky - 1);
            worst = worst.max((floor - common::linear(light)) / step);
        }
    }
    println!("covered {covered:.1} pixels; darkest below the floor by {worst:.2} sky steps");
    assert!(covered > 100.0, "{covered}");
    assert!(worst <= 1.5, "a pixel {worst} steps darker than its alpha allows");
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

/// The reference's material (`eval::reference::ReferenceMaterial`) shades a
/// needle thinner than a sample with the normals of its own surface: a row
/// of parallel needles (cylinders 2 mm thick) lit from high behind shows
/// the same mean colour over its covered samples 15 m away (0.13 of a pixel
/// wide) as 0.6 m away (4.5 pixels wide): 1.00× when written. Bevy's
/// `StandardMaterial` on the same meshes shades a far needle at the pixel's
/// centre, its normal extrapolated sideways onto the lit rim, and shines
/// 1.53× brighter far than near (with the sun low behind, 5–8×).
#[test]
fn the_reference_shades_sub_pixel_needles_where_they_are() {
    use bevy::camera::visibility::RenderLayers;
    use bevy::core_pipeline::tonemapping::Tonemapping;
    use bevy::prelude::*;
    use bevy_conifer_lod::eval::reference::{ReferenceMaterial, ReferenceMaterialPlugin};
    use bevy_conifer_lod::plugin::headless::HeadlessRenderer;
    let _turn = common::gpu_turn();
    let mut renderer = HeadlessRenderer::with_setup(".", |app| {
        app.add_plugins(ReferenceMaterialPlugin);
    });
    let size = 96;
    let target = renderer.render_target(size, size);
    let world = renderer.world_mut();
    let sun = HeadlessRenderer::spawn_lights(world);
    world.insert_resource(GlobalAmbientLight {
        brightness: 0.0,
        ..default()
    });
    // High behind the needles (the camera looks down −Z from +Z): the
    // upper third of each needle's visible width is lit.
    world.entity_mut(sun).insert((
        Transform::from_xyz(0.0, 1.0, -0.35).looking_at(Vec3::ZERO, Vec3::Y),
        RenderLayers::from_layers(&[1, 2]),
    ));
    let albedo = LinearRgba::new(0.3, 0.3, 0.3, 1.0);
    let standard = world.resource_mut::<Assets<StandardMaterial>>().add(StandardMaterial {
        base_color: albedo.into(),
        perceptual_roughness: 0.5,
        ..default()
    });
    let plain = ReferenceMaterial::new(
        &mut world.resource_mut::<Assets<bevy::render::storage::ShaderBuffer>>(),
        albedo,
        0.5,
        0.5,
    );
    let reference = world.resource_mut::<Assets<ReferenceMaterial>>().add(plain);
    // 41 needles across the view, 3 mm apart in a vertical plane, tilted
    // 7° so each crosses rows of samples (level, a needle a tenth of a
    // pixel thick covers a whole row of samples or none).
    let needle = world
        .resource_mut::<Assets<Mesh>>()
        .add(Mesh::from(Cylinder::new(0.001, 0.2)));
    for k in -20..=20 {
        let transform =
            Transform::from_xyz(0.0, k as f32 * 0.003, 0.0).with_rotation(Quat::from_rotation_z(97f32.to_radians()));
        world.spawn((
            Mesh3d(needle.clone()),
            MeshMaterial3d(standard.clone()),
            transform,
            RenderLayers::layer(1),
        ));
        world.spawn((
            Mesh3d(needle.clone()),
            MeshMaterial3d(reference.clone()),
            transform,
            RenderLayers::layer(2),
        ));
    }
    let camera = world
        .spawn((
            HeadlessRenderer::camera_bundle(&target, Transform::IDENTITY, 4f32.to_radians()),
            Camera {
                clear_color: ClearColorConfig::Custom(Color::NONE),
                ..default()
            },
            Tonemapping::None,
            RenderLayers::layer(1),
        ))
        .id();
    // The mean linear colour of the covered samples: Σ colour / Σ coverage
    // over a black background.
    let mut mean_colour = |layer: usize, distance: f32, name: &str| {
        let world = renderer.world_mut();
        world.entity_mut(camera).insert((
            Transform::from_xyz(0.0, 0.0, distance).looking_at(Vec3::ZERO, Vec3::Y),
            RenderLayers::layer(layer),
        ));
        for _ in 0..HeadlessRenderer::SETTLE_FRAMES {
            renderer.update().unwrap();
        }
        let picture = renderer.capture(&target, 8).unwrap();
        let out = std::path::PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("target/test-output/eval");
        std::fs::create_dir_all(&out).unwrap();
        picture.save(out.join(format!("reference_needles_{name}.png"))).unwrap();
        let (mut light, mut coverage) = (0.0f64, 0.0f64);
        for p in picture.pixels() {
            light += f64::from(common::linear(p.0[1]));
            coverage += f64::from(p.0[3]) / 255.0;
        }
        assert!(coverage > 20.0, "{name}: the needles cover {coverage} pixels");
        light / coverage
    };
    let standard_near = mean_colour(1, 0.6, "standard_near");
    let standard_far = mean_colour(1, 15.0, "standard_far");
    let reference_near = mean_colour(2, 0.6, "reference_near");
    let reference_far = mean_colour(2, 15.0, "reference_far");
    println!(
        "mean colour near / far: StandardMaterial {standard_near:.4} / {standard_far:.4} ({:.2}×), reference {reference_near:.4} / {reference_far:.4} ({:.2}×)",
        standard_far / standard_near,
        reference_far / reference_near
    );
    assert!((reference_far / reference_near - 1.0).abs() < 0.05);
    assert!(standard_far / standard_near > 1.3);
}

/// The reference takes the tree's colours as the plugin gives them
/// (`model::color`): three flat shoots side by side, this year's, a
/// 4-year-old one and one turned on its back, each needle coloured by its
/// shoot (`eval::reference::spawn_reference_tree`), and a branch whose
/// bark turns from one colour to another with height. Lit by a sun behind
/// the camera with no ambient light and no specular (reflectance 0),
/// every pixel's linear colour is its albedo times a grey factor: each
/// patch's mean colour has its albedo's proportions.
#[test]
fn the_reference_colours_needles_by_their_shoot_and_bark_by_height() {
    use bevy::camera::visibility::RenderLayers;
    use bevy::core_pipeline::tonemapping::Tonemapping;
    use bevy::prelude::*;
    use bevy_conifer_lod::eval::reference::{ReferenceMaterialPlugin, spawn_reference_tree};
    use bevy_conifer_lod::model::color::shoot_colors;
    use bevy_conifer_lod::model::{FoliageMaterial, Needle, Placement, PrototypeInput, WoodSegment, bake_prototypes};
    use bevy_conifer_lod::plugin::headless::HeadlessRenderer;
    let _turn = common::gpu_turn();

    let (young, mature, underside) = ([0.40, 0.08, 0.08], [0.08, 0.40, 0.08], [0.08, 0.08, 0.40]);
    let (lower_bark, upper_bark) = ([0.30, 0.30, 0.05], [0.05, 0.30, 0.30]);
    let rgba = |[r, g, b]: [f32; 3]| [r, g, b, 1.0];
    // A flat shoot 3 cm wide and 6 cm tall, its needles' normals +Z.
    let shoot: Vec<Needle> = (0..15)
        .map(|k| Needle {
            base: Vec3::new(-0.014 + 0.002 * k as f32, -0.03, 0.0),
            tip: Vec3::new(-0.014 + 0.002 * k as f32, 0.03, 0.0),
            radius: 0.001,
            normal: Vec3::Z,
            group: 0,
        })
        .collect();
    let at = |x: f32, needle_age: u8, rotation: Quat| Placement {
        translation: Vec3::new(x, 0.0, 0.0),
        rotation,
        needle_age,
        ..Placement::identity(0)
    };
    let input = PrototypeInput {
        name: "three shoots and a branch".into(),
        prototypes: vec![shoot],
        placements: vec![
            at(-0.06, 0, Quat::IDENTITY),
            at(0.0, 4, Quat::IDENTITY),
            at(0.06, 4, Quat::from_rotation_y(std::f32::consts::PI)),
        ],
        // Bark turning between 0 and 6 cm up.
        wood: vec![WoodSegment {
            start: Vec3::new(0.12, -0.04, 0.0),
            end: Vec3::new(0.12, 0.10, 0.0),
            start_radius: 0.01,
            end_radius: 0.01,
        }],
        material: FoliageMaterial {
            young_needle_color: rgba(young),
            needle_underside_color: rgba(underside),
            upper_wood_color: rgba(upper_bark),
            upper_wood_heights: [0.0, 0.06],
            ..FoliageMaterial::uniform(rgba(mature), rgba(lower_bark), 0.6, 0.0)
        },
        ..Default::default()
    };
    let record = bake_prototypes(&input, &bevy_conifer_lod::model::BakeOptions::default(), &()).unwrap();
    let flat = record.flatten().unwrap();

    let mut renderer = HeadlessRenderer::with_setup(".", |app| {
        app.add_plugins(ReferenceMaterialPlugin);
    });
    let size = 128;
    let target = renderer.render_target(size, size);
    let world = renderer.world_mut();
    world.insert_resource(GlobalAmbientLight {
        brightness: 0.0,
        ..default()
    });
    // 2,000 lux: the brightest albedo (0.4) stays under white.
    world.spawn((
        DirectionalLight {
            illuminance: 2_000.0,
            shadow_maps_enabled: false,
            ..default()
        },
        Transform::from_xyz(0.03, 0.03, 1.0).looking_at(Vec3::new(0.03, 0.03, 0.0), Vec3::Y),
        RenderLayers::layer(1),
    ));
    let shoots = shoot_colors(&record);
    spawn_reference_tree(world, &flat, Some(&shoots), RenderLayers::layer(1));
    // 0.2 m across at 1 m: a pixel is 1.6 mm.
    let fov = 2.0 * (0.1f32).atan();
    let centre = Vec3::new(0.03, 0.03, 0.0);
    world.spawn((
        HeadlessRenderer::camera_bundle(
            &target,
            Transform::from_xyz(0.03, 0.03, 1.0).looking_at(centre, Vec3::Y),
            fov,
        ),
        Camera {
            clear_color: ClearColorConfig::Custom(Color::NONE),
            ..default()
        },
        Tonemapping::None,
        RenderLayers::layer(1),
    ));
    for _ in 0..HeadlessRenderer::SETTLE_FRAMES {
        renderer.update().unwrap();
    }
    let picture = renderer.capture(&target, 8).unwrap();
    let out = std::path::PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("target/test-output/eval");
    std::fs::create_dir_all(&out).unwrap();
    picture.save(out.join("reference_shoot_colours.png")).unwrap();

    // The mean linear colour over the covered pixels of the box
    // [x0, x1] × [y0, y1] (metres in the plane z = 0), normalised to sum 1.
    let pixel = |x: f32, y: f32| {
        let scale = size as f32 / 0.2;
        (
            ((x - centre.x) * scale + size as f32 / 2.0) as u32,
            ((centre.y - y) * scale + size as f32 / 2.0) as u32,
        )
    };
    let proportions = |x0: f32, x1: f32, y0: f32, y1: f32, name: &str| {
        let ((px0, py0), (px1, py1)) = (pixel(x0, y1), pixel(x1, y0));
        let (mut sum, mut covered) = ([0.0f64; 3], 0u32);
        for py in py0..py1 {
            for px in px0..px1 {
                let p = picture.get_pixel(px, py).0;
                if p[3] == 255 {
                    for c in 0..3 {
                        sum[c] += f64::from(common::linear(p[c]));
                    }
                    covered += 1;
                }
            }
        }
        assert!(covered > 40, "{name}: {covered} covered pixels");
        let total: f64 = sum.iter().sum();
        sum.map(|c| (c / total) as f32)
    };
    let expect = |seen: [f32; 3], albedo: [f32; 3], name: &str| {
        let total: f32 = albedo.iter().sum();
        for c in 0..3 {
            assert!(
                (seen[c] - albedo[c] / total).abs() < 0.03,
                "{name}: proportions {seen:?}, albedo {albedo:?}"
            );
        }
    };
    // Inside each shoot, clear of its edges.
    expect(
        proportions(-0.07, -0.05, -0.02, 0.02, "young"),
        young,
        "this year's shoot",
    );
    expect(
        proportions(-0.01, 0.01, -0.02, 0.02, "mature"),
        mature,
        "the 4-year-old shoot",
    );
    expect(
        proportions(0.05, 0.07, -0.02, 0.02, "underside"),
        underside,
        "the shoot on its back",
    );
    // The bark below its turn and above it.
    expect(
        proportions(0.115, 0.125, -0.035, -0.005, "lower bark"),
        lower_bark,
        "the lower bark",
    );
    expect(
        proportions(0.115, 0.125, 0.065, 0.095, "upper bark"),
        upper_bark,
        "the upper bark",
    );
}

/// The reference's CPU tone map against Bevy's own pass: cameras with
/// `Hdr` and TonyMcMapface clear to linear colours from a dark needle's to
/// brighter than white, and each pixel is within one level of
/// `ToneMap::map` of its colour.
#[test]
fn the_cpu_tone_map_is_bevys() {
    use bevy::camera::{Hdr, RenderTarget};
    use bevy::core_pipeline::tonemapping::DebandDither;
    use bevy::prelude::*;
    use bevy_conifer_lod::eval::tonemap::ToneMap;
    use bevy_conifer_lod::plugin::headless::HeadlessRenderer;

    let colours: [[f32; 3]; 6] = [
        [0.83, 0.85, 0.89],
        [0.02, 0.04, 0.015],
        [0.1, 0.3, 0.05],
        [0.5, 0.2, 0.9],
        [1.0, 1.0, 1.0],
        [2.5, 0.7, 0.3],
    ];
    let mut renderer = HeadlessRenderer::new(concat!(env!("CARGO_MANIFEST_DIR"), "/assets"));
    let mut targets = Vec::new();
    for (k, [r, g, b]) in colours.into_iter().enumerate() {
        let target = renderer.render_target(4, 4);
        renderer.world_mut().spawn((
            Camera3d::default(),
            RenderTarget::from(target.clone()),
            Camera {
                clear_color: ClearColorConfig::Custom(Color::linear_rgb(r, g, b)),
                order: k as isize,
                ..default()
            },
            Hdr,
            DebandDither::Disabled,
        ));
        targets.push(target);
    }
    for _ in 0..HeadlessRenderer::SETTLE_FRAMES {
        renderer.update().unwrap();
    }
    let pictures = renderer.capture_all(&targets, 10).unwrap();
    let tone = ToneMap::from_world(renderer.world_mut()).expect("Bevy's TonyMcMapface LUT");
    for (colour, picture) in colours.iter().zip(&pictures) {
        let gpu = picture.get_pixel(2, 2).0;
        let cpu = tone.map(*colour).map(common::srgb_level);
        println!("{colour:?}: GPU {gpu:?}, CPU {cpu:?}");
        for k in 0..3 {
            assert!(
                (f32::from(gpu[k]) - cpu[k]).abs() <= 1.0,
                "{colour:?}: GPU {gpu:?}, CPU {cpu:?}"
            );
        }
    }
}

/// `conifer eval --float-blending`'s targets: a hundred translucent layers
/// over the eval's grey sky, blended into an `Rgba32Float` target and read
/// back as 8-bit sRGB, come out within a level of the exact composite
/// (colour and alpha). The same layers in `Hdr`'s `Rgba16Float` are
/// printed beside: lavapipe rounds each blend into a 16-bit float toward
/// zero, so they come out darker than their coverage allows.
#[test]
fn float_blending_composites_many_layers_exactly() {
    use bevy::camera::{Hdr, RenderTarget};
    use bevy::core_pipeline::tonemapping::{DebandDither, Tonemapping};
    use bevy::prelude::*;
    use bevy::render::render_resource::TextureFormat;
    use bevy_conifer_lod::plugin::headless::HeadlessRenderer;
    let _turn = common::gpu_turn();

    const LAYERS: usize = 100;
    const ALPHA: f32 = 0.01;
    let sky = [0.83f32, 0.85, 0.89];
    let needle = [0.02f32, 0.06, 0.02];
    let mut renderer = HeadlessRenderer::new(concat!(env!("CARGO_MANIFEST_DIR"), "/assets"));
    let float_target = renderer.render_target_with_format(8, 8, TextureFormat::Rgba32Float);
    let half_target = renderer.render_target(8, 8);
    let world = renderer.world_mut();
    let quad = world
        .resource_mut::<Assets<Mesh>>()
        .add(Mesh::from(Rectangle::new(4.0, 4.0)));
    let layer = world.resource_mut::<Assets<StandardMaterial>>().add(StandardMaterial {
        base_color: Color::linear_rgba(needle[0], needle[1], needle[2], ALPHA),
        alpha_mode: AlphaMode::Blend,
        unlit: true,
        ..default()
    });
    for k in 0..LAYERS {
        world.spawn((
            Mesh3d(quad.clone()),
            MeshMaterial3d(layer.clone()),
            Transform::from_xyz(0.0, 0.0, -1.0 - 0.01 * k as f32),
        ));
    }
    let [r, g, b] = sky;
    for (k, (target, hdr)) in [(&float_target, false), (&half_target, true)].into_iter().enumerate() {
        let mut camera = world.spawn((
            Camera3d::default(),
            RenderTarget::from(target.clone()),
            Camera {
                clear_color: ClearColorConfig::Custom(Color::linear_rgba(r, g, b, 0.0)),
                order: k as isize,
                ..default()
            },
            Tonemapping::None,
            DebandDither::Disabled,
        ));
        if hdr {
            camera.insert(Hdr);
        }
    }
    for _ in 0..HeadlessRenderer::SETTLE_FRAMES {
        renderer.update().unwrap();
    }
    let pictures = renderer.capture_all(&[float_target, half_target], 10).unwrap();
    let through = (1.0 - ALPHA).powi(LAYERS as i32);
    let expected: Vec<f32> = (0..3)
        .map(|k| common::srgb_level(sky[k] * through + needle[k] * (1.0 - through)))
        .chain([(1.0 - through) * 255.0])
        .collect();
    let float = pictures[0].get_pixel(4, 4).0;
    let half = pictures[1].get_pixel(4, 4).0;
    println!("{LAYERS} layers of alpha {ALPHA}: exact {expected:?}, Rgba32Float {float:?}, Hdr (Rgba16Float) {half:?}");
    for k in 0..4 {
        assert!(
            (f32::from(float[k]) - expected[k]).abs() <= 1.0,
            "channel {k}: Rgba32Float {float:?} against {expected:?}"
        );
    }
}
