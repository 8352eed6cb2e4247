//! The render path (compact storage buffers, GPU culling, indirect draws),
//! rendered on Mesa's lavapipe: it covers what the needles cover at every
//! distance (prisms, original lines, merged lines, wood), its GPU memory is
//! what it allocated, a species' buffers hold about 32 bytes a needle, and
//! its per-tree and per-view buffers grow and shrink with the trees and
//! views.
//! Pictures go to `target/test-output/render/`.
#![cfg(feature = "plugin")]

mod common;

use bevy::prelude::*;
use bevy_conifer_lod::generate::{GenerateOptions, Species, generate};
use bevy_conifer_lod::model::compact::CompactSpecies;
use bevy_conifer_lod::model::{BakeOptions, bake, write_record};
use bevy_conifer_lod::plugin::CompactGpuMemory;
use bevy_conifer_lod::plugin::headless::HeadlessRenderer;
use bevy_conifer_lod::prelude::*;
use common::{BACKGROUND, background_camera, covered_count, covered_grey, grey, look_at_crown, mean_difference};
use std::path::PathBuf;

const SIZE: u32 = 192;

/// The 12,000-needle Scots pine (with wood segments) the tests draw.
fn pine() -> bevy_conifer_lod::model::LodRecord {
    let tree = generate(
        Species::ScotsPine,
        &GenerateOptions {
            seed: 2,
            target_needles: Some(12_000),
            age: bevy_conifer_lod::generate::Age::Young,
        },
    );
    bake(&tree, &BakeOptions::default(), &()).unwrap()
}

struct Scene {
    renderer: HeadlessRenderer,
    species: Handle<ConiferSpecies>,
    target: Handle<Image>,
    camera: Entity,
    crown: Vec3,
    needles: usize,
    out: PathBuf,
    dir: tempfile::TempDir,
}

impl Scene {
    /// A 12,000-needle Scots pine (with wood segments) at the origin.
    fn new() -> Self {
        Self::with_trees(&[])
    }

    /// The same, with trees at `early` spawned before the species has
    /// loaded, as a game does on its first frame.
    fn with_trees(early: &[Transform]) -> Self {
        let dir = tempfile::tempdir().unwrap();
        let out = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("target/test-output/render");
        std::fs::create_dir_all(&out).unwrap();
        let record = pine();
        let crown = record.crown_center();
        let needles = record.needle_count();
        write_record(&record, &dir.path().join("pine.conifer")).unwrap();
        let mut renderer = HeadlessRenderer::new(&dir.path().to_string_lossy());
        let species: Handle<ConiferSpecies> = renderer.world().resource::<AssetServer>().load("pine.conifer");
        for &transform in early {
            renderer.world_mut().spawn((ConiferFoliage(species.clone()), transform));
        }
        HeadlessRenderer::spawn_lights(renderer.world_mut());
        renderer.load(&[species.clone().untyped()], 600).unwrap();
        let target = renderer.render_target(SIZE, SIZE);
        let camera = background_camera(renderer.world_mut(), &target);
        Self {
            renderer,
            species,
            target,
            camera,
            crown,
            needles,
            out,
            dir,
        }
    }

    /// A tree of the scene's species at `transform`.
    fn spawn_tree(&mut self, transform: Transform) -> Entity {
        let species = self.species.clone();
        self.renderer
            .world_mut()
            .spawn((ConiferFoliage(species), transform))
            .id()
    }

    fn look_from(&mut self, distance: f32, fov_deg: f32) {
        look_at_crown(self.renderer.world_mut(), self.camera, self.crown, distance, fov_deg);
    }

    fn shot(&mut self, name: &str) -> image::RgbaImage {
        // Buffers fill and pipelines compile over a few frames.
        for _ in 0..3 {
            self.renderer.update().unwrap();
        }
        let image = self.renderer.capture(&self.target, 20).unwrap();
        image.save(self.out.join(format!("compact_{name}.png"))).unwrap();
        image
    }

    fn memory(&self) -> CompactGpuMemory {
        self.renderer.world().resource::<CompactGpuMemory>().clone()
    }
}

/// The plugin covers what the needles cover: at 2 m (prisms), 6 m
/// (original lines), 30 m (merged lines) and 90 m (a far tree) the coverage
/// of its picture is within a few percent of the supersampled reference's
/// (every needle a prism, 4×4 samples a pixel), as `conifer eval` measures.
#[test]
fn the_plugin_covers_what_the_needles_cover() {
    let _turn = common::gpu_turn();
    use bevy_conifer_lod::eval::measure::{coverage_error, mean_coverage};
    use bevy_conifer_lod::eval::scene::{EvalScene, EvalView, Method};
    let record = pine();
    let view = EvalView::square(SIZE, 45.0);
    let mut scene = EvalScene::new(record, &[Method::Ours], view).unwrap();
    // Each representation of the line path (the impostor has its own test,
    // `tests/render_impostor.rs`).
    let world = scene.world_mut();
    let mut overrides = world.query::<&mut ConiferLodOverride>();
    for mut over in overrides.iter_mut(world) {
        over.far_impostor = Some(false);
    }
    let out = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("target/test-output/render");
    std::fs::create_dir_all(&out).unwrap();
    // (distance, name, coverage error bound, mean coverage bound relative
    // to the reference's: the far tree is 8 pixels tall).
    for (distance, what, bound, relative) in [
        (2.0, "prisms", 0.06, 0.15),
        (6.0, "lines", 0.03, 0.1),
        (30.0, "merged", 0.03, 0.1),
        (90.0, "far", 0.04, 0.35),
    ] {
        scene.set_distance(distance);
        let frame = scene.capture().unwrap();
        let ours = &frame.methods[0].1;
        ours.save(out.join(format!("compact_{what}.png"))).unwrap();
        frame
            .reference
            .save(out.join(format!("compact_{what}_reference.png")))
            .unwrap();
        let rect = scene.screen_rect(distance);
        let error = coverage_error(&frame.reference, ours, &rect).unwrap();
        let (mine, reference) = (mean_coverage(ours, &rect), mean_coverage(&frame.reference, &rect));
        println!("{what}: coverage error {error:.4}, mean coverage {mine:.3} (reference {reference:.3})");
        assert!(reference > 0.02, "{what}: the reference shows the tree");
        assert!(error < bound, "{what}: coverage error {error}");
        assert!(
            (mine - reference).abs() < relative * reference,
            "{what}: mean coverage {mine} vs {reference}"
        );
    }
}

#[test]
fn a_hidden_tree_is_not_drawn() {
    let _turn = common::gpu_turn();
    let mut scene = Scene::new();
    let tree = scene.spawn_tree(Transform::IDENTITY);
    scene.look_from(6.0, 45.0);
    assert!(covered_count(&scene.shot("shown")) > 1000);
    scene.renderer.world_mut().entity_mut(tree).insert(Visibility::Hidden);
    let hidden = scene.shot("hidden");
    assert_eq!(covered_count(&hidden), 0);
}

#[test]
fn compact_memory_is_what_was_allocated_and_follows_the_trees() {
    let _turn = common::gpu_turn();
    let mut scene = Scene::new();
    scene.look_from(60.0, 45.0);
    let mut trees = Vec::new();
    for i in 0..3000 {
        let (x, z) = ((i % 60) as f32 * 5.0 - 150.0, -((i / 60) as f32) * 5.0);
        trees.push(scene.spawn_tree(Transform::from_xyz(x, 0.0, z)));
    }
    let forest = scene.shot("forest");
    assert!(covered_count(&forest) > 1000);
    let memory = scene.memory();
    let id = scene.species.id();
    let species_bytes = memory.species_bytes[&id];
    let record = scene
        .renderer
        .world()
        .resource::<Assets<ConiferSpecies>>()
        .get(id)
        .unwrap()
        .record()
        .clone();
    let compact = CompactSpecies::build(&record).unwrap();
    let per_needle = species_bytes as f64 / scene.needles as f64;
    println!(
        "species {species_bytes} B ({per_needle:.1} B/needle), instances {} B, views {} B, {} buffers",
        memory.instance_bytes[&id], memory.view_bytes, memory.buffers
    );
    // The buffers hold the arrays (each at least 128 bytes; a flat species'
    // placement and prototype tables are empty).
    assert!(species_bytes >= compact.bytes().total() && species_bytes <= compact.bytes().total() + 9 * 128);
    assert!(per_needle <= 36.0, "{per_needle} B/needle");
    // 3,000 trees: a 4,096-slot instance buffer (64 B each) and the
    // species' 5,152-byte parameters, and per view its 144-byte culling
    // inputs, 4,096 LOD slots (32 B)
    // and 7 × 4,096 indirect draws (16 B), and six 16-byte stand-ins for
    // the placement buffers a flat species leaves empty and its counters'
    // header (136 words: the expansion budget's).
    let placed_stand_ins = 6 * 16 + 4 * 136;
    assert_eq!(memory.instance_bytes[&id], 4096 * 64 + 5152);
    // The impostor's texture: every mip level of every view, as uploaded.
    let impostor = record_species_impostor_bytes(&scene, id);
    assert_eq!(memory.impostor_bytes[&id], impostor);
    assert_eq!(memory.view_bytes, 144 + 4096 * 32 + 7 * 4096 * 16 + placed_stand_ins);
    let buffers = memory.buffers;
    // Frames with nothing replaced make no bind groups.
    let made = memory.bind_group_sets_made;
    scene.shot("forest_again");
    assert_eq!(
        scene.memory().bind_group_sets_made,
        made,
        "bind groups made again without a new buffer"
    );
    // Most trees go: the buffers shrink back, none leak.
    for &tree in &trees[100..] {
        scene.renderer.world_mut().despawn(tree);
    }
    scene.shot("forest_thinned");
    let memory = scene.memory();
    assert_eq!(memory.instance_bytes[&id], 128 * 64 + 5152);
    assert_eq!(memory.view_bytes, 144 + 128 * 32 + 7 * 128 * 16 + placed_stand_ins);
    assert_eq!(memory.buffers, buffers);
    // All go: nothing is left.
    for &tree in &trees[..100] {
        scene.renderer.world_mut().despawn(tree);
    }
    scene.shot("forest_gone");
    let memory = scene.memory();
    assert_eq!(memory.total(), 0, "{memory:?}");
    assert!(memory.impostor_bytes.is_empty());
    assert_eq!(memory.buffers, 0);
}

/// Bytes of the mip chain of `id`'s crown impostor.
fn record_species_impostor_bytes(scene: &Scene, id: AssetId<ConiferSpecies>) -> u64 {
    let species = scene.renderer.world().resource::<Assets<ConiferSpecies>>();
    species.get(id).unwrap().impostor.as_ref().unwrap().byte_size()
}

#[test]
fn trees_spawned_before_their_species_loads_are_drawn() {
    let _turn = common::gpu_turn();
    let mut scene = Scene::with_trees(&[Transform::from_xyz(0.0, 0.0, 500.0), Transform::IDENTITY]);
    scene.look_from(6.0, 45.0);
    let image = scene.shot("early_trees");
    let pixels = covered_count(&image);
    assert!(pixels > 1000, "the second tree covers {pixels} pixels");
}

#[test]
fn a_tree_after_a_culled_tree_is_drawn() {
    let _turn = common::gpu_turn();
    let mut scene = Scene::new();
    scene.look_from(6.0, 45.0);
    // Instance 0 far behind the camera (culled), instance 1 in view.
    scene.spawn_tree(Transform::from_xyz(0.0, 0.0, 500.0));
    scene.spawn_tree(Transform::IDENTITY);
    let image = scene.shot("second_instance");
    let pixels = covered_count(&image);
    assert!(pixels > 1000, "the second tree covers {pixels} pixels");
}

/// A camera rendering into its own target (or a viewport of one).
fn extra_camera(scene: &mut Scene, target: &Handle<Image>, distance: f32, viewport: Option<bevy::camera::Viewport>) {
    let eye = scene.crown + Vec3::Z * distance;
    scene.renderer.world_mut().spawn((
        HeadlessRenderer::camera_bundle(
            target,
            Transform::from_translation(eye).looking_at(scene.crown, Vec3::Y),
            45f32.to_radians(),
        ),
        Camera {
            clear_color: ClearColorConfig::Custom(Color::srgb_u8(BACKGROUND[0], BACKGROUND[1], BACKGROUND[2])),
            viewport,
            order: 1 + distance as isize,
            ..default()
        },
    ));
}

/// Lines lit as cylinders: with the sun behind the camera a line shows the
/// cylinder's front-lit half (π/4 of a strip facing the sun), with the sun
/// across the view half of it is lit where a strip facing the viewer gets
/// the light edge-on, and with the sun behind the tree both see its shade.
#[test]
fn lines_are_lit_as_the_cylinders_they_stand_for() {
    let _turn = common::gpu_turn();
    let mut scene = Scene::new();
    scene.spawn_tree(Transform::IDENTITY);
    // 30 m: every needle is a line (original or merged).
    scene.look_from(30.0, 12.0);
    let eye = scene.crown + Vec3::Z * 30.0;
    let grey = |scene: &mut Scene, from: Vec3, lighting: LineLighting, name: &str| {
        let world = scene.renderer.world_mut();
        let mut suns = world.query_filtered::<&mut Transform, With<DirectionalLight>>();
        for mut sun in suns.iter_mut(world) {
            *sun = Transform::from_translation(scene.crown + from).looking_at(scene.crown, Vec3::Y);
        }
        world.resource_mut::<ConiferLodSettings>().line_lighting = lighting;
        covered_grey(&scene.shot(&format!("lighting_{name}")))
    };
    let front = eye - scene.crown;
    let side = Vec3::new(30.0, 0.0, 0.0);
    let back = -front;
    let cylinder = [front, side, back].map(|from| grey(&mut scene, from, LineLighting::Cylinder, "cylinder"));
    let strip = [front, side, back].map(|from| grey(&mut scene, from, LineLighting::FacingStrip, "strip"));
    // Grey levels of covered pixels, most of them partly background: the
    // differences are a few levels (189.9 / 183.0 / 174.9 against 192.3 /
    // 181.7 / 174.9 when written).
    println!("mean grey, sun front / side / back: cylinder {cylinder:?}, facing strip {strip:?}");
    assert!(
        cylinder[0] < strip[0] - 0.5,
        "front-lit cylinders are darker than strips facing the sun"
    );
    assert!(cylinder[1] > strip[1] + 0.5, "side-lit cylinders show their lit half");
    assert!(
        (cylinder[2] - strip[2]).abs() < 2.0,
        "from behind, both are in their own shade"
    );
    assert!(cylinder[2] < cylinder[1] && cylinder[1] < cylinder[0]);
}

/// Merged lines lit as their bundles (`LineLighting::Bundle`): the same
/// tree drawn with every merged line's stored alignment set to 1 (needles
/// along the chord: its cylinder) and to 0 (needles across it: `1 − β` of
/// the cylinder, the rest a sphere) sends the light the CPU reference
/// (`model::shading::bundle_cylinder_share` of the chord's cylinder, the
/// rest a sphere, lit by Bevy's Burley diffuse at the shader's four
/// normals across the cylinder and by the sphere's table,
/// `model::shading::SphereLight`) gives the lines the GPU drew, to within
/// 0.06 of the ratio (black background, no wood, ambient light, specular
/// or tonemapping; the reference weighs each line by its width and
/// projected length, where the pictures blend lines over each other),
/// under suns from the camera (drawn 0.980, reference 1.005), the side
/// (1.003, 0.990), above (1.000, 0.978) and high behind (1.026, 0.988).
/// With seven normals over the sphere's disk both had read 0.76 above and
/// 1.11–1.16 high behind: that rule was 17 % dark for a sun across the
/// view and bright from behind, and the sphere share moved the light by
/// its error. `LineLighting::Cylinder` ignores the alignment: it draws
/// alignment 0 as the bundle draws 1.
#[test]
fn merged_lines_are_lit_as_their_bundles() {
    use bevy::core_pipeline::tonemapping::Tonemapping;
    use bevy_conifer_lod::model::shading::{SphereLight, across_average, bundle_cylinder_share};
    use bevy_conifer_lod::plugin::CompactReadback;
    use std::sync::Arc;
    let _turn = common::gpu_turn();
    // The pine without its wood, which both pictures would share.
    let mut tree = generate(
        Species::ScotsPine,
        &GenerateOptions {
            seed: 2,
            target_needles: Some(12_000),
            age: bevy_conifer_lod::generate::Age::Young,
        },
    );
    tree.wood.clear();
    let record = bake(&tree, &BakeOptions::default(), &()).unwrap();
    let crown = record.crown_center();
    let base = ConiferSpecies::from_record(record.clone()).unwrap();
    let (mut renderer, target, sun) = common::sun_lit_renderer(SIZE);
    let world = renderer.world_mut();
    let camera = world
        .spawn((
            HeadlessRenderer::camera_bundle(&target, Transform::IDENTITY, 12f32.to_radians()),
            Camera {
                clear_color: ClearColorConfig::Custom(Color::BLACK),
                ..default()
            },
            Tonemapping::None,
        ))
        .id();
    // 60 m through a telephoto: merged lines carry most of the crown.
    let distance = 60.0;
    look_at_crown(world, camera, crown, distance, 12.0);
    let eye = crown + Vec3::Z * distance;
    world.resource_mut::<ConiferLodSettings>().far_impostor = false;
    world.resource_mut::<CompactReadback>().enabled = true;
    // The tree with every merged line's alignment code set to `code`.
    let variant = |code: u32| {
        let mut species = base.clone();
        let mut compact = (*species.compact).clone();
        for line in &mut compact.merged_lines {
            line[1] = (line[1] & 0x0fff_ffff) | code << 28;
        }
        species.compact = Arc::new(compact);
        species.material.reflectance = 0.0;
        species
    };
    // Summed linear RGB of the picture, and the cut the GPU drew.
    let draw = |renderer: &mut HeadlessRenderer, code: u32, lighting: LineLighting, from: Vec3, name: &str| {
        let world = renderer.world_mut();
        world.resource_mut::<ConiferLodSettings>().line_lighting = lighting;
        *world.get_mut::<Transform>(sun).unwrap() =
            Transform::from_translation(crown + from * 100.0).looking_at(crown, Vec3::Y);
        let handle = world.resource_mut::<Assets<ConiferSpecies>>().add(variant(code));
        let tree = world.spawn((ConiferFoliage(handle.clone()), Transform::IDENTITY)).id();
        for _ in 0..HeadlessRenderer::SETTLE_FRAMES + 2 {
            renderer.update().unwrap();
        }
        let picture = renderer.capture(&target, 8).unwrap();
        picture
            .save(
                PathBuf::from(env!("CARGO_MANIFEST_DIR"))
                    .join(format!("target/test-output/render/compact_bundle_{name}.png")),
            )
            .unwrap();
        let light: f32 = picture
            .pixels()
            .map(|p| common::linear(p.0[0]) + common::linear(p.0[1]) + common::linear(p.0[2]))
            .sum();
        let lod = common::camera_readback(renderer.world(), handle.id()).tree_lod(0);
        renderer.world_mut().despawn(tree);
        (light, lod)
    };
    // Bevy's `Fd_Burley` times `n·L` (the constant albedo / π left out).
    let roughness = {
        let perceptual = base.material.roughness.clamp(0.089, 1.0);
        perceptual * perceptual
    };
    let burley = |n: Vec3, v: Vec3, l: Vec3| {
        let n_dot_l = n.dot(l).max(0.0);
        let n_dot_v = n.dot(v).clamp(0.0001, 1.0);
        let l_dot_h = l.dot((l + v).normalize_or_zero());
        let f90 = 0.5 + 2.0 * roughness * l_dot_h * l_dot_h;
        let schlick = |x: f32| 1.0 + (f90 - 1.0) * (1.0 - x).powi(5);
        n_dot_l * schlick(n_dot_l) * schlick(n_dot_v)
    };
    let sphere_table = SphereLight::new(base.material.roughness, 0.0);
    let compact = &base.compact;
    let merged_slot: std::collections::HashMap<u32, usize> = compact
        .merged_source
        .iter()
        .enumerate()
        .map(|(m, &node)| (node, m))
        .collect();
    for (name, from) in [
        ("front", Vec3::Z),
        ("side", Vec3::X),
        ("top", Vec3::Y),
        ("high", Vec3::new(0.5, 0.8, -0.3).normalize()),
    ] {
        let (along, (code, e)) = draw(&mut renderer, 15, LineLighting::Bundle, from, &format!("along_{name}"));
        let (across, lod) = draw(&mut renderer, 0, LineLighting::Bundle, from, &format!("across_{name}"));
        let (cylinder, _) = draw(
            &mut renderer,
            0,
            LineLighting::Cylinder,
            from,
            &format!("cylinder_{name}"),
        );
        assert_eq!(lod, (code, e), "the same cut");
        // The light the CPU reference gives the cut the GPU drew: each line
        // weighted by its width times its length seen across the view.
        let cut = compact.drawn(code, e);
        assert!(cut.prisms.is_empty(), "{} prisms", cut.prisms.len());
        assert!(cut.merged_lines.len() > 500, "{} merged lines", cut.merged_lines.len());
        let (mut expected_along, mut expected_across) = (0.0f64, 0.0f64);
        let mut add = |a: Vec3, b: Vec3, width: f32, merged: bool| {
            let v = (eye - 0.5 * (a + b)).normalize();
            let chord = b - a;
            // A line one pixel wide, of opacity `min(width / pixel, 1)` (pixel error 1).
            let weight = f64::from(width.min(e) * chord.cross(v).length());
            // Bevy's diffuse (Burley's, with the species' roughness) at the
            // shader's four normals across the cylinder, and the sphere's
            // table (its mean diffuse, with the 1/π `burley` leaves out).
            let lambert = |n: Vec3| burley(n, v, from);
            let cylinder = f64::from(across_average(chord, v, from, lambert));
            let sphere = f64::from(sphere_table.at(v, from).0 * std::f32::consts::PI);
            let share = f64::from(bundle_cylinder_share(0.0));
            expected_along += weight * cylinder;
            expected_across += weight
                * if merged {
                    (share * cylinder + (1.0 - share) * sphere).max(0.0)
                } else {
                    cylinder
                };
        };
        for &needle in &cut.original_lines {
            let x = &record.needles[needle as usize];
            add(x.base, x.tip, 2.0 * x.radius, false);
        }
        for &node in &cut.merged_lines {
            let m = merged_slot[&node];
            let [(a, _), (b, _)] = record.node_ends(node);
            add(a, b, compact.merged_width(m), true);
        }
        let (ratio, expected) = (across / along, (expected_across / expected_along) as f32);
        println!(
            "sun {name}: {} original and {} merged lines; light across/along drawn {ratio:.4}, reference {expected:.4}; cylinder lighting {:.4}",
            cut.original_lines.len(),
            cut.merged_lines.len(),
            cylinder / along
        );
        assert!(along > 1.0, "the tree is lit: {along}");
        assert!((ratio - expected).abs() < 0.06, "sun {name}: {ratio} vs {expected}");
        assert!((cylinder / along - 1.0).abs() < 1e-3, "Cylinder ignores the alignment");
    }
}

/// `LineOpacity::Coverage` against the summed-area rule, both drawn by the
/// shader: merged lines cover `1 − exp(−Σa/A)` of their footprint
/// (`model::metric::merged_line_coverage`), never more than `Σa/A` and,
/// where `Σa/A ≤ 1`, at least `1 − 1/e` of it.
#[test]
fn merged_lines_cover_at_most_their_summed_area_under_the_coverage_rule() {
    let _turn = common::gpu_turn();
    let mut scene = Scene::new();
    // 60 m through a telephoto: merged lines carry most of the crown (the
    // lines are what is measured: no impostor).
    scene.look_from(60.0, 12.0);
    scene
        .renderer
        .world_mut()
        .resource_mut::<ConiferLodSettings>()
        .far_impostor = false;
    let empty = scene.shot("opacity_empty");
    scene.spawn_tree(Transform::IDENTITY);
    let darkness = |scene: &mut Scene, rule: LineOpacity, name: &str| -> f32 {
        scene
            .renderer
            .world_mut()
            .resource_mut::<ConiferLodSettings>()
            .line_opacity = rule;
        let picture = scene.shot(name);
        picture
            .pixels()
            .zip(empty.pixels())
            .map(|(p, e)| (grey(e) - grey(p)).abs())
            .sum()
    };
    let area = darkness(&mut scene, LineOpacity::AreaPreserving, "opacity_area");
    let coverage = darkness(&mut scene, LineOpacity::Coverage, "opacity_coverage");
    println!("summed grey change from the empty picture: area rule {area:.0}, coverage rule {coverage:.0}");
    assert!(area > 500.0, "the tree is drawn");
    assert!(coverage < area, "coverage {coverage} under the summed area {area}");
    assert!(
        coverage > (1.0 - (-1.0f32).exp()) * area,
        "coverage {coverage} at least 1 − 1/e of the summed area {area}"
    );
}

#[test]
fn two_cameras_and_a_split_screen_each_get_their_own_cut() {
    let _turn = common::gpu_turn();
    let mut scene = Scene::new();
    scene.spawn_tree(Transform::IDENTITY);
    // The scene's camera at 1.5 m, a second one at 40 m into its own target.
    scene.look_from(1.5, 45.0);
    let far_target = scene.renderer.render_target(SIZE, SIZE);
    extra_camera(&mut scene, &far_target, 40.0, None);
    for _ in 0..3 {
        scene.renderer.update().unwrap();
    }
    let mut images = scene
        .renderer
        .capture_all(&[scene.target.clone(), far_target], 20)
        .unwrap();
    let far = images.pop().unwrap();
    let near = images.pop().unwrap();
    near.save(scene.out.join("compact_two_cameras_near.png")).unwrap();
    far.save(scene.out.join("compact_two_cameras_far.png")).unwrap();
    let (pn, pf) = (covered_count(&near), covered_count(&far));
    println!("two cameras: near {pn}, far {pf} covered pixels");
    assert!(pn > 4 * pf && pf > 30, "near {pn}, far {pf}");

    // Split screen: two viewports of one target, each its own view.
    let split = scene.renderer.render_target(2 * SIZE, SIZE);
    let half = |x: u32| bevy::camera::Viewport {
        physical_position: UVec2::new(x, 0),
        physical_size: UVec2::new(SIZE, SIZE),
        ..default()
    };
    extra_camera(&mut scene, &split, 1.5, Some(half(0)));
    extra_camera(&mut scene, &split, 40.0, Some(half(SIZE)));
    for _ in 0..3 {
        scene.renderer.update().unwrap();
    }
    let image = scene.renderer.capture(&split, 20).unwrap();
    image.save(scene.out.join("compact_split_screen.png")).unwrap();
    let left = image::imageops::crop_imm(&image, 0, 0, SIZE, SIZE).to_image();
    let right = image::imageops::crop_imm(&image, SIZE, 0, SIZE, SIZE).to_image();
    let (left_diff, right_diff) = (mean_difference(&left, &near), mean_difference(&right, &far));
    println!(
        "split screen: left |Δ| {left_diff:.2} against the near camera, right {right_diff:.2} against the far one"
    );
    assert!(left_diff < 3.0 && right_diff < 3.0);
}

#[test]
fn a_reloaded_record_and_a_removed_override_are_drawn_anew() {
    let _turn = common::gpu_turn();
    let mut scene = Scene::new();
    // The cut is what changes (no impostor).
    scene
        .renderer
        .world_mut()
        .resource_mut::<ConiferLodSettings>()
        .far_impostor = false;
    scene.look_from(8.0, 45.0);
    let tree = scene
        .renderer
        .world_mut()
        .spawn((
            ConiferFoliage(scene.species.clone()),
            Transform::IDENTITY,
            ConiferLodOverride {
                pixel_error: Some(12.0),
                ..default()
            },
        ))
        .id();
    let coarse = scene.shot("override_coarse");
    scene
        .renderer
        .world_mut()
        .entity_mut(tree)
        .remove::<ConiferLodOverride>();
    let restored = scene.shot("override_removed");
    let (coarse_px, restored_px) = (covered_count(&coarse), covered_count(&restored));
    println!("override: {coarse_px} covered pixels at ε = 12, {restored_px} after removal");
    assert!(
        mean_difference(&coarse, &restored) > 1.0,
        "removing the override changes the cut"
    );

    // The same file rewritten with a different tree, reloaded.
    let other = generate(
        Species::NorwaySpruce,
        &GenerateOptions {
            seed: 9,
            target_needles: Some(6_000),
            age: bevy_conifer_lod::generate::Age::Young,
        },
    );
    let record = bake(&other, &BakeOptions::default(), &()).unwrap();
    write_record(&record, &scene.dir.path().join("pine.conifer")).unwrap();
    scene.renderer.world().resource::<AssetServer>().reload("pine.conifer");
    let mut reloaded = None;
    for _ in 0..200 {
        scene.renderer.update().unwrap();
        let species = scene.renderer.world().resource::<Assets<ConiferSpecies>>();
        if species
            .get(&scene.species)
            .is_some_and(|s| s.needle_count == record.needle_count() as u64)
        {
            reloaded = Some(());
            break;
        }
    }
    assert!(reloaded.is_some(), "the record reloaded");
    let after = scene.shot("reloaded");
    // What a fresh scene draws of the new record.
    let fresh = {
        let mut fresh = Scene::new();
        fresh
            .renderer
            .world_mut()
            .resource_mut::<ConiferLodSettings>()
            .far_impostor = false;
        write_record(&record, &fresh.dir.path().join("spruce.conifer")).unwrap();
        let handle: Handle<ConiferSpecies> = fresh.renderer.world().resource::<AssetServer>().load("spruce.conifer");
        fresh.renderer.load(&[handle.clone().untyped()], 600).unwrap();
        fresh.crown = scene.crown;
        fresh.look_from(8.0, 45.0);
        fresh
            .renderer
            .world_mut()
            .spawn((ConiferFoliage(handle), Transform::IDENTITY));
        fresh.shot("reloaded_fresh")
    };
    let (diff_old, diff_fresh) = (mean_difference(&after, &restored), mean_difference(&after, &fresh));
    println!("reloaded: |Δ| {diff_old:.2} from the old tree, {diff_fresh:.2} from a fresh load of the new one");
    assert!(diff_fresh < 1.0 && diff_old > 3.0 * diff_fresh.max(0.3));
}

/// Five needles 0.6 m long at 0°, 30°, 45°, 71° and 90° from the
/// vertical, far enough apart that no two touch a pixel, seen from 20 m
/// by a 128² camera onto a transparent background, sun-lit, without tone
/// mapping; the species without a line calibration, the impostor off
/// (lines only), the compute pass read back.
struct FiveNeedles {
    renderer: HeadlessRenderer,
    target: Handle<Image>,
    camera: Entity,
    handle: Handle<ConiferSpecies>,
    /// Each needle's ends in pixels (the camera's projection).
    ends: Vec<[[f32; 2]; 2]>,
    _sun: Entity,
}

impl FiveNeedles {
    fn new(radius: f32) -> Self {
        use bevy_conifer_lod::model::{FoliageMaterial, Needle, TreeInput};
        let needles: Vec<Needle> = [0.0f32, 30.0, 45.0, 71.0, 90.0]
            .iter()
            .enumerate()
            .map(|(k, degrees)| {
                let (sin, cos) = degrees.to_radians().sin_cos();
                let half = 0.3 * Vec3::new(sin, cos, 0.0);
                let centre = Vec3::new(-3.0 + 1.5 * k as f32, 0.17 * k as f32 - 0.3, 0.0);
                Needle {
                    base: centre - half,
                    tip: centre + half,
                    radius,
                    normal: Vec3::Z,
                    group: k as u32,
                }
            })
            .collect();
        let input = TreeInput {
            name: "five needles".into(),
            needles: needles.clone(),
            wood: Vec::new(),
            wood_mesh: Default::default(),
            material: FoliageMaterial::default(),
        };
        let record = bake(&input, &BakeOptions::default(), &()).unwrap();
        let mut species = ConiferSpecies::from_record(record).unwrap();
        // Without a calibration (the five needles' own is about 1).
        species.line_calibration = None;
        let scene = LineScene::new(species);
        let ends = needles
            .iter()
            .map(|n| [scene.pixel(n.base), scene.pixel(n.tip)])
            .collect();
        let LineScene {
            renderer,
            target,
            camera,
            handle,
            sun,
            ..
        } = scene;
        Self {
            renderer,
            target,
            camera,
            handle,
            ends,
            _sun: sun,
        }
    }
}

/// A species seen from 20 m by a 128² camera looking along −Z at the
/// origin onto a transparent background, sun-lit, without tone mapping;
/// the impostor off (lines only), the compute pass read back.
struct LineScene {
    renderer: HeadlessRenderer,
    target: Handle<Image>,
    camera: Entity,
    handle: Handle<ConiferSpecies>,
    sun: Entity,
    /// The camera's projection (Bevy's reversed infinite perspective, near
    /// 0.1 m) and view.
    clip_from_world: Mat4,
}

impl LineScene {
    /// The picture's side, pixels.
    const SIZE: u32 = 128;

    fn new(species: ConiferSpecies) -> Self {
        use bevy::core_pipeline::tonemapping::Tonemapping;
        use bevy_conifer_lod::plugin::CompactReadback;
        let (mut renderer, target, sun) = common::sun_lit_renderer(Self::SIZE);
        let world = renderer.world_mut();
        let handle = world.resource_mut::<Assets<ConiferSpecies>>().add(species);
        world.spawn((ConiferFoliage(handle.clone()), Transform::IDENTITY));
        let fov = 45f32.to_radians();
        let transform = Transform::from_translation(Vec3::new(0.0, 0.0, 20.0)).looking_at(Vec3::ZERO, Vec3::Y);
        let camera = world
            .spawn((
                HeadlessRenderer::camera_bundle(&target, transform, fov),
                Camera {
                    clear_color: ClearColorConfig::Custom(Color::srgba(0.0, 0.0, 0.0, 0.0)),
                    ..default()
                },
                Tonemapping::None,
            ))
            .id();
        world.resource_mut::<CompactReadback>().enabled = true;
        // Lines only: a small tree would fade into its crown impostor here.
        world.resource_mut::<ConiferLodSettings>().far_impostor = false;
        Self {
            renderer,
            target,
            camera,
            handle,
            sun,
            clip_from_world: Mat4::perspective_infinite_reverse_rh(fov, 1.0, 0.1) * transform.to_matrix().inverse(),
        }
    }

    /// Where the camera sees `p` (world metres), in pixels.
    fn pixel(&self, p: Vec3) -> [f32; 2] {
        let clip = self.clip_from_world * p.extend(1.0);
        let ndc = clip.truncate() / clip.w;
        let size = Self::SIZE as f32;
        [(0.5 + 0.5 * ndc.x) * size, (0.5 - 0.5 * ndc.y) * size]
    }
}

/// A picture's alpha against the CPU's: each pixel's `1 − Π(1 − c)` over
/// the lines between `ends` (pixels), `c` what `coverage(a, b, pixel)`
/// gives each ([`AlphaAgainstCpu::composed`]), or what `want` gives the
/// pixel ([`AlphaAgainstCpu::of`]).
#[derive(Clone, Copy)]
struct AlphaAgainstCpu {
    /// Mean |Δ| over the pixels either covers.
    mean: f32,
    /// Largest |Δ|.
    worst: f32,
    /// Pixels either covers.
    pixels: usize,
    /// Alpha summed over the picture.
    drawn: f32,
    /// The CPU's alpha summed.
    expected: f32,
    /// The least alpha drawn where the CPU covers a pixel wholly (1 where
    /// it covers none).
    least_inside: f32,
}

impl AlphaAgainstCpu {
    fn composed(
        picture: &image::RgbaImage,
        ends: &[[[f32; 2]; 2]],
        coverage: impl Fn([f32; 2], [f32; 2], [f32; 2]) -> f32,
    ) -> Self {
        Self::of(picture, |square| {
            1.0 - ends.iter().map(|&[a, b]| 1.0 - coverage(a, b, square)).product::<f32>()
        })
    }

    fn of(picture: &image::RgbaImage, want: impl Fn([f32; 2]) -> f32) -> Self {
        let mut result = Self {
            mean: 0.0,
            worst: 0.0,
            pixels: 0,
            drawn: 0.0,
            expected: 0.0,
            least_inside: 1.0,
        };
        for (x, y, pixel) in picture.enumerate_pixels() {
            let want = want([x as f32, y as f32]);
            let got = f32::from(pixel[3]) / 255.0;
            if want > 0.0 || got > 0.0 {
                result.mean += (got - want).abs();
                result.worst = result.worst.max((got - want).abs());
                result.pixels += 1;
            }
            if want > 0.999 {
                result.least_inside = result.least_inside.min(got);
            }
            result.drawn += got;
            result.expected += want;
        }
        result.mean /= result.pixels.max(1) as f32;
        result
    }

    /// The figures, for the log: alpha summed against the CPU's, the mean
    /// and largest |Δ|.
    fn summary(&self) -> String {
        format!(
            "alpha summed {:.2} (reference {:.2}); mean |Δ| {:.4} over {} pixels, largest {:.3}",
            self.drawn, self.expected, self.mean, self.pixels, self.worst
        )
    }

    /// Asserts that `what` is in the picture (the CPU's alpha summed over
    /// `at_least`), drawn in total within 2 % of the CPU's, and pixel by
    /// pixel within `mean_at_most` on average and `worst_at_most`.
    fn assert_near(&self, what: &str, at_least: f32, mean_at_most: f32, worst_at_most: f32) {
        let Self {
            mean,
            worst,
            drawn,
            expected,
            ..
        } = *self;
        assert!(expected > at_least, "{what} in the picture: {expected}");
        assert!(
            (drawn / expected - 1.0).abs() < 0.02,
            "alpha summed {drawn} against {expected}"
        );
        assert!(
            mean < mean_at_most && worst < worst_at_most,
            "mean {mean}, largest {worst}"
        );
    }
}

/// Lines wider than a pixel (`model::raster::line_pixel_coverage`): the
/// five needles of [`FiveNeedles`] 0.26 m thick at pixel error 3, so each
/// is an original line standing for a needle about two pixels wide. With
/// `LineRaster::Area` each pixel's alpha is the strip's exact area there
/// (a strip two pixels wide), as the CPU reference gives it; a one-pixel
/// line (what the area raster drew before, and what `Hardware` draws)
/// would cover half of it.
#[test]
fn wide_lines_cover_each_pixel_by_their_strips_area() {
    use bevy_conifer_lod::model::raster::line_pixel_coverage;
    let _turn = common::gpu_turn();
    let radius = 0.13;
    let FiveNeedles {
        mut renderer,
        target,
        handle,
        ends,
        ..
    } = FiveNeedles::new(radius);
    let pixel_error = 3.0;
    {
        let mut settings = renderer.world_mut().resource_mut::<ConiferLodSettings>();
        settings.line_raster = LineRaster::Area;
        settings.pixel_error = pixel_error;
    }
    for _ in 0..HeadlessRenderer::SETTLE_FRAMES + 2 {
        renderer.update().unwrap();
    }
    let picture = renderer.capture(&target, 8).unwrap();
    let out = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("target/test-output/render");
    std::fs::create_dir_all(&out).unwrap();
    picture.save(out.join("compact_wide_lines.png")).unwrap();
    let readback = common::camera_readback(renderer.world(), handle.id());
    let (_, spatial_error) = readback.tree_lod(0);
    // The needle's width in pixels: its `2R` over the pixel (the spatial
    // error over the pixel error).
    let width = 2.0 * radius * pixel_error / spatial_error;
    assert!(
        width > 1.5 && width < 2.5 && 2.0 * radius < spatial_error,
        "lines about two pixels wide: {width}"
    );
    let alpha = AlphaAgainstCpu::composed(&picture, &ends, |a, b, square| {
        line_pixel_coverage(a, b, 1.0, width, square)
    });
    println!("wide lines {width:.3} pixels: {}", alpha.summary());
    // Five strips 0.6 m long (4.6 pixels) and two pixels wide.
    alpha.assert_near("the needles", 30.0, 0.005, 0.02);
}

/// A branch drawn as wood lines wider than a pixel covers its pixels as
/// one strip (`model::raster::joined_line_pixel_coverage`): six straight
/// segments end to end, one 0.31 m (2.4 pixels) long, 0.324 m thick at
/// 20 m and pixel error 3 (lines about 2.5 pixels wide), tilted 17° so
/// that every joint falls inside pixels. Each pixel's alpha is the CPU's
/// joined composition within a few levels of 255; blended as six
/// separate strips (what the area raster drew before) the pixels at the
/// joints would be a quarter short, pale stripes across the branch. The
/// same with the wood's share in sight set to one half
/// (`WoodVisibility`): the camera draws it in two layers, and with
/// nothing between them each pixel still takes the strip's area, each
/// layer splitting that coverage (`model::impostor::wood_layer_opacities`
/// per pixel); split by the line's opacity of 1, a pixel at the strip's
/// edge half covered would take `½ + ¼`. On lavapipe: mean |Δ| alpha
/// 0.0008 over 140 pixels (largest 0.002), summed 86.15 against 86.14;
/// half in sight 0.0010 (0.003), 86.17. Against six separate strips the
/// pictures differ by 0.0100; with the layers split by the line's opacity
/// (the vertex stage's split, tried) the half-in-sight picture sums 93.44,
/// mean |Δ| 0.052.
#[test]
fn a_wide_branch_covers_its_pixels_as_one_strip() {
    use bevy_conifer_lod::model::impostor::{CROWN_PROFILE_STEPS, WOOD_NEARNESS_BINS, WoodVisibility};
    use bevy_conifer_lod::model::raster::{LineJoints, joined_line_pixel_coverage};
    use bevy_conifer_lod::model::{FoliageMaterial, Needle, Sphere, TreeInput, WoodSegment};
    let _turn = common::gpu_turn();
    let radius = 0.162;
    let (from, to) = (Vec3::new(-2.6, -1.0, 0.0), Vec3::new(2.6, 0.6, 0.0));
    let stops = [0.0f32, 0.13, 0.31, 0.52, 0.58, 0.8, 1.0];
    let wood: Vec<WoodSegment> = stops
        .windows(2)
        .map(|t| WoodSegment {
            start: from.lerp(to, t[0]),
            end: from.lerp(to, t[1]),
            start_radius: radius,
            end_radius: radius,
        })
        .collect();
    // One needle, out of the picture: a record has foliage.
    let input = TreeInput {
        name: "one branch".into(),
        needles: vec![Needle {
            base: Vec3::new(0.0, 14.0, 0.0),
            tip: Vec3::new(0.0, 14.05, 0.0),
            radius: 0.001,
            normal: Vec3::Z,
            group: 0,
        }],
        wood: wood.clone(),
        wood_mesh: Default::default(),
        material: FoliageMaterial::default(),
    };
    let out = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("target/test-output/render");
    std::fs::create_dir_all(&out).unwrap();
    for half_in_sight in [false, true] {
        let record = bake(&input, &BakeOptions::default(), &()).unwrap();
        let mut species = ConiferSpecies::from_record(record).unwrap();
        species.line_calibration = None;
        if half_in_sight {
            let mut impostor = (**species.impostor.as_ref().expect("an impostor: the wood is layered")).clone();
            impostor.wood_visibility = WoodVisibility {
                shares: [[0.5; WOOD_NEARNESS_BINS]; CROWN_PROFILE_STEPS],
            };
            species.impostor = Some(std::sync::Arc::new(impostor));
        }
        let pixel_error = 3.0;
        let mut scene = LineScene::new(species);
        {
            let mut settings = scene.renderer.world_mut().resource_mut::<ConiferLodSettings>();
            settings.line_raster = LineRaster::Area;
            settings.pixel_error = pixel_error;
        }
        for _ in 0..HeadlessRenderer::SETTLE_FRAMES + 2 {
            scene.renderer.update().unwrap();
        }
        let picture = scene.renderer.capture(&scene.target, 8).unwrap();
        let name = if half_in_sight {
            "compact_wide_branch_half_in_sight.png"
        } else {
            "compact_wide_branch.png"
        };
        picture.save(out.join(name)).unwrap();
        // Each segment's width in pixels at its own error (the nearest point of
        // its sphere, as the shader's `wood_segment_error`).
        let readback = common::camera_readback(scene.renderer.world(), scene.handle.id());
        let (_, tree_error) = readback.tree_lod(0);
        let view = readback.view_point(0);
        let strips: Vec<([f32; 2], [f32; 2], f32, LineJoints)> = wood
            .iter()
            .enumerate()
            .map(|(k, w)| {
                let error = view.map_or(tree_error, |v| v.spatial_error(&Sphere::around_wood(w)));
                let joints = LineJoints {
                    start: k > 0,
                    end: k + 1 < wood.len(),
                };
                (
                    scene.pixel(w.start),
                    scene.pixel(w.end),
                    2.0 * radius * pixel_error / error,
                    joints,
                )
            })
            .collect();
        assert!(
            strips.iter().all(|s| s.2 > 2.0 && s.2 < 3.0),
            "lines 2–3 pixels wide: {:?}",
            strips.iter().map(|s| s.2).collect::<Vec<_>>()
        );
        // Past two pixels wide a wood line's opacity is 1 and its
        // calibration's scale 1.
        let compose = |joined: bool, square: [f32; 2]| {
            1.0 - strips
                .iter()
                .map(|&(a, b, width, joints)| {
                    let joints = if joined { joints } else { LineJoints::NONE };
                    1.0 - joined_line_pixel_coverage(a, b, 1.0, width, joints, square)
                })
                .product::<f32>()
        };
        let alpha = AlphaAgainstCpu::of(&picture, |square| compose(true, square));
        let open_mean = AlphaAgainstCpu::of(&picture, |square| compose(false, square)).mean;
        println!(
            "wide branch (wood half in sight: {half_in_sight}): {}; against separate strips {open_mean:.4}; least alpha inside the strip {:.3}",
            alpha.summary(),
            alpha.least_inside
        );
        alpha.assert_near("the branch", 80.0, 0.006, 0.03);
        assert!(
            open_mean > 2.0 * alpha.mean,
            "separate strips: {open_mean} against {}",
            alpha.mean
        );
        assert!(
            alpha.least_inside > 0.97,
            "a pale stripe inside the branch: {}",
            alpha.least_inside
        );
    }
}

/// Lines cover each pixel by their strip's area in it
/// (`LineRaster::Area`, CPU reference `model::raster::strip_pixel_coverage`):
/// five needles 0.6 m long at 0°, 30°, 45°, 71° and 90° from the vertical,
/// 0.23 pixels wide at 20 m, far enough apart that no two touch a pixel,
/// drawn as original lines (the impostor off) with 4× MSAA onto a
/// transparent background. Each
/// pixel's alpha is the needle's opacity (`2R·ε/e`, `e` the spatial error
/// the compute pass wrote) times its strip's area there, within a few
/// levels of 255 (mean |Δ| 0.0011 over the 40 pixels either covers,
/// largest 0.002: 8-bit rounding; alpha summed 5.40 against 5.37). The
/// hardware lines of `LineRaster::Hardware` (one pixel wide; lavapipe's
/// are rectangles) keep the sum (5.42) but miss pixel by pixel: mean |Δ|
/// 0.034 over 48 pixels, largest 0.102. With a line calibration
/// ([`LineCalibration`]) the area lines' opacity is scaled by the table at
/// their pixel size, as its CPU reference `scale_at` interpolates it
/// (0.689 here: mean |Δ| 0.0010 over 34 pixels, largest 0.002; alpha
/// summed 3.73 against 3.70).
#[test]
fn lines_cover_each_pixel_by_their_strips_area() {
    use bevy_conifer_lod::model::calibration::LineCalibration;
    use bevy_conifer_lod::model::raster::strip_pixel_coverage;
    let _turn = common::gpu_turn();
    let radius = 0.015;
    let FiveNeedles {
        mut renderer,
        target,
        camera,
        handle,
        ends,
        ..
    } = FiveNeedles::new(radius);
    let out = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("target/test-output/render");
    std::fs::create_dir_all(&out).unwrap();
    // A table of line opacity scales whose pixel sizes bracket this view's
    // (13 cm): the shader interpolates it between its third and fourth
    // entries (`LineCalibration::scale_at`).
    let calibration = LineCalibration {
        first_pixel: 0.05,
        last_pixel: 0.5,
        scales: [0.5, 0.55, 0.6, 0.7, 0.75, 0.8, 0.9, 1.0],
        wood_scales: [[1.0; 4]; 8],
    };
    let mut errors = Vec::new();
    let mut alphas = Vec::new();
    // The last two: `LineRaster::Auto` draws hardware lines into the
    // camera's 8-bit main texture and quads into a 16-bit float one (`Hdr`).
    for (raster, calibrated, hdr) in [
        (LineRaster::Area, None, false),
        (LineRaster::Hardware, None, false),
        (LineRaster::Area, Some(calibration), false),
        (LineRaster::Auto, None, false),
        (LineRaster::Auto, None, true),
    ] {
        renderer.world_mut().resource_mut::<ConiferLodSettings>().line_raster = raster;
        let mut assets = renderer.world_mut().resource_mut::<Assets<ConiferSpecies>>();
        assets.get_mut(&handle).unwrap().line_calibration = calibrated;
        if hdr {
            renderer.world_mut().entity_mut(camera).insert(bevy::camera::Hdr);
        } else {
            renderer.world_mut().entity_mut(camera).remove::<bevy::camera::Hdr>();
        }
        for _ in 0..HeadlessRenderer::SETTLE_FRAMES + 2 {
            renderer.update().unwrap();
        }
        let picture = renderer.capture(&target, 8).unwrap();
        let name = match (calibrated.is_some(), hdr) {
            (true, _) => "_calibrated",
            (false, true) => "_hdr",
            (false, false) => "",
        };
        picture
            .save(out.join(format!("compact_line_raster_{raster:?}{name}.png")))
            .unwrap();
        alphas.push(picture.pixels().map(|p| p[3]).collect::<Vec<u8>>());
        let (_, spatial_error) = common::camera_readback(renderer.world(), handle.id()).tree_lod(0);
        let scale = calibrated.map_or(1.0, |c| c.scale_at(spatial_error));
        let opacity = 2.0 * radius / spatial_error * scale;
        assert!(
            opacity > 0.1 && opacity < 0.35,
            "the needles are lines 0.1–0.35 pixels wide: {opacity}"
        );
        let AlphaAgainstCpu {
            mean,
            worst,
            pixels,
            drawn,
            expected,
            ..
        } = AlphaAgainstCpu::composed(&picture, &ends, |a, b, square| {
            (opacity * strip_pixel_coverage(a, b, opacity, square)).min(1.0)
        });
        println!(
            "{raster:?}, scale {scale:.3}: opacity {opacity:.3}; alpha summed {drawn:.2} (reference {expected:.2}); \
             mean |Δ| {mean:.4} over {pixels} pixels, largest {worst:.3}"
        );
        assert!(expected > 3.0, "the needles are in the picture: {expected}");
        errors.push((mean, worst, drawn / expected));
    }
    let [
        (area_mean, area_worst, area_sum),
        (hardware_mean, _, _),
        (scaled_mean, scaled_worst, scaled_sum),
        _,
        (hdr_mean, hdr_worst, hdr_sum),
    ] = [errors[0], errors[1], errors[2], errors[3], errors[4]];
    assert_eq!(alphas[3], alphas[1], "auto draws hardware lines into an 8-bit texture");
    assert!(
        hdr_mean < 0.003 && hdr_worst < 0.01 && (hdr_sum - 1.0).abs() < 0.05,
        "auto draws quads into a float texture: mean {hdr_mean}, largest {hdr_worst}, summed {hdr_sum}"
    );
    assert!(
        (area_sum - 1.0).abs() < 0.05 && (scaled_sum - 1.0).abs() < 0.05,
        "coverage summed {area_sum} (calibrated: {scaled_sum}) of the reference's"
    );
    assert!(
        area_mean < 0.003 && area_worst < 0.01,
        "area raster: mean {area_mean}, largest {area_worst}"
    );
    assert!(
        scaled_mean < 0.003 && scaled_worst < 0.01,
        "area raster, calibrated: mean {scaled_mean}, largest {scaled_worst}"
    );
    assert!(
        hardware_mean > 5.0 * area_mean,
        "hardware lines miss more: {hardware_mean} vs {area_mean}"
    );
}
