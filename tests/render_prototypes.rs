//! Shared prototypes on the render path, rendered on Mesa's
//! lavapipe: a tree of prototypes drawn with its prototypes shared (placed
//! by the GPU, expanded per view) looks like the same tree flattened, at
//! every distance, with LOD off, and past the expansion capacity; and its
//! species' GPU buffers hold each prototype once.
//! Pictures go to `target/test-output/render/`.
#![cfg(feature = "plugin")]

mod common;

use bevy::prelude::*;
use bevy_conifer_lod::generate::{GenerateOptions, Species, generate_prototypes};
use bevy_conifer_lod::model::compact::{
    CompactSpecies, PLACED_BANDS, PlacedDraw, budget_error, budget_expands, depth_bucket, shader_threshold_code,
};
use bevy_conifer_lod::model::{BakeOptions, PrototypeRecord, bake_prototypes};
use bevy_conifer_lod::plugin::headless::HeadlessRenderer;
use bevy_conifer_lod::plugin::{CompactGpuMemory, CompactReadback, PartKind, ViewReadback};
use bevy_conifer_lod::prelude::*;
use common::{background_camera, covered_count, look_at_crown, mean_difference, spawn_ground};
use std::path::PathBuf;

const SIZE: u32 = 160;

struct Scene {
    renderer: HeadlessRenderer,
    /// The tree with its prototypes shared.
    placed: Handle<ConiferSpecies>,
    /// The same tree flattened (every needle stored).
    flat: Handle<ConiferSpecies>,
    target: Handle<Image>,
    camera: Entity,
    crown: Vec3,
    out: PathBuf,
}

impl Scene {
    /// A 15,000-needle Scots pine grown as shoot prototypes, both ways.
    fn new() -> Self {
        let out = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("target/test-output/render");
        std::fs::create_dir_all(&out).unwrap();
        let input = generate_prototypes(
            Species::ScotsPine,
            &GenerateOptions {
                seed: 3,
                target_needles: Some(15_000),
                age: bevy_conifer_lod::generate::Age::Young,
            },
        );
        let record: PrototypeRecord = bake_prototypes(&input, &BakeOptions::default(), &())
            .unwrap()
            .quantized()
            .unwrap();
        assert!(
            record.prototypes.len() < record.placements.len() / 4,
            "prototypes are shared"
        );
        let flat_record = record.flatten().unwrap();
        let crown = flat_record.crown_center();
        let mut renderer = HeadlessRenderer::new(".");
        let placed = ConiferSpecies::from_prototype_record(&record).unwrap();
        let flat = ConiferSpecies::from_record(flat_record).unwrap();
        let compact = &placed.compact;
        assert_eq!(compact.prototypes.len(), record.prototypes.len());
        let mut species = renderer.world_mut().resource_mut::<Assets<ConiferSpecies>>();
        let (placed, flat) = (species.add(placed), species.add(flat));
        HeadlessRenderer::spawn_lights(renderer.world_mut());
        let target = renderer.render_target(SIZE, SIZE);
        let camera = background_camera(renderer.world_mut(), &target);
        Self {
            renderer,
            placed,
            flat,
            target,
            camera,
            crown,
            out,
        }
    }

    fn look_from(&mut self, distance: f32, fov_deg: f32) {
        look_at_crown(self.renderer.world_mut(), self.camera, self.crown, distance, fov_deg);
    }

    /// A picture of one tree of `species` at the origin.
    fn shot(&mut self, species: &Handle<ConiferSpecies>, name: &str) -> image::RgbaImage {
        self.shot_of(species, &[Transform::IDENTITY], name)
    }

    /// A picture of trees of `species` standing at `transforms`.
    fn shot_of(&mut self, species: &Handle<ConiferSpecies>, transforms: &[Transform], name: &str) -> image::RgbaImage {
        let trees: Vec<Entity> = transforms
            .iter()
            .map(|&transform| {
                let world = self.renderer.world_mut();
                world.spawn((ConiferFoliage(species.clone()), transform)).id()
            })
            .collect();
        // Buffers fill and pipelines compile over a few frames.
        for _ in 0..3 {
            self.renderer.update().unwrap();
        }
        let image = self.renderer.capture(&self.target, 20).unwrap();
        image.save(self.out.join(format!("prototypes_{name}.png"))).unwrap();
        for tree in trees {
            self.renderer.world_mut().despawn(tree);
        }
        image
    }

    /// Where the camera stands.
    fn camera_position(&self) -> Vec3 {
        self.renderer.world().get::<Transform>(self.camera).unwrap().translation
    }

    /// The compact arrays of `species`.
    fn compact(&self, species: &Handle<ConiferSpecies>) -> std::sync::Arc<CompactSpecies> {
        let assets = self.renderer.world().resource::<Assets<ConiferSpecies>>();
        assets.get(species).unwrap().compact.clone()
    }

    /// Trees of `species` standing at `transforms`, pictured as `name`,
    /// and what the compute passes wrote for its camera (`perspective`)
    /// or its directional cascade.
    fn read_back(
        &mut self,
        species: &Handle<ConiferSpecies>,
        transforms: &[Transform],
        name: &str,
        perspective: bool,
    ) -> ViewReadback {
        self.shot_of(species, transforms, name);
        let readback = self.renderer.world().resource::<CompactReadback>();
        readback
            .views
            .iter()
            .find(|v| v.species == species.id() && v.perspective == perspective)
            .expect("the view's results were read back")
            .clone()
    }

    fn memory(&self) -> CompactGpuMemory {
        self.renderer.world().resource::<CompactGpuMemory>().clone()
    }
}

/// The trees (instance slots) with expanded placements in `view`, sorted.
fn expanded_trees(view: &ViewReadback) -> Vec<u32> {
    let mut trees: Vec<u32> = view.entries.iter().map(|&[tree, _]| tree & 0x3fff_ffff).collect();
    trees.sort_unstable();
    trees.dedup();
    trees
}

/// Three trees 50, 20 and 6 m from a camera 6 m from the crown on `+z`,
/// farthest first.
fn three_trees() -> [Transform; 3] {
    [-44.0f32, -14.0, 0.0].map(|z| Transform::from_xyz(0.0, 0.0, z))
}

/// The scene read back, its camera 6 m from the crown, no impostor, and
/// the placed species, its compact arrays and [`three_trees`].
fn three_trees_scene() -> (
    Scene,
    Handle<ConiferSpecies>,
    std::sync::Arc<CompactSpecies>,
    [Transform; 3],
) {
    let mut scene = Scene::new();
    let world = scene.renderer.world_mut();
    world.resource_mut::<CompactReadback>().enabled = true;
    world.resource_mut::<ConiferLodSettings>().far_impostor = false;
    scene.look_from(6.0, 45.0);
    let placed = scene.placed.clone();
    let compact = scene.compact(&placed);
    (scene, placed, compact, three_trees())
}

fn assert_alike(what: &str, placed: &image::RgbaImage, flat: &image::RgbaImage) {
    let (pp, pf) = (covered_count(placed), covered_count(flat));
    let diff = mean_difference(placed, flat);
    println!("{what}: covered pixels placed {pp}, flat {pf}; mean grey |Δ| {diff:.2}");
    assert!(pf > 40, "{what}: the flat tree is drawn");
    assert!(
        (pp as f32 - pf as f32).abs() <= 0.08 * pf as f32,
        "{what}: placed covers {pp} pixels, flat {pf}"
    );
    assert!(diff < 8.0, "{what}: mean grey difference {diff}");
}

#[test]
fn placed_prototypes_draw_what_the_flattened_tree_draws() {
    let _turn = common::gpu_turn();
    let mut scene = Scene::new();
    // One error per tree, as a flat species has: the same cut both ways.
    scene
        .renderer
        .world_mut()
        .resource_mut::<ConiferLodSettings>()
        .error_scope = ErrorScope::Tree;
    let (placed, flat) = (scene.placed.clone(), scene.flat.clone());
    // Prisms close up, original lines, level-1 and level-2 merged lines.
    for (distance, fov, what) in [
        (1.5, 30.0, "prisms"),
        (6.0, 45.0, "lines"),
        (25.0, 25.0, "merged"),
        (80.0, 12.0, "far"),
    ] {
        scene.look_from(distance, fov);
        let a = scene.shot(&placed, &format!("{what}_placed"));
        let b = scene.shot(&flat, &format!("{what}_flat"));
        assert_alike(what, &a, &b);
    }
    // LOD off: every needle a prism, every placement expanded.
    scene.renderer.world_mut().resource_mut::<ConiferLodSettings>().enabled = false;
    scene.look_from(6.0, 45.0);
    let a = scene.shot(&placed, "lod_off_placed");
    let b = scene.shot(&flat, "lod_off_flat");
    assert_alike("LOD off", &a, &b);
}

#[test]
fn inside_the_crown_errors_per_placement_keep_the_full_detail_picture() {
    let _turn = common::gpu_turn();
    // The camera 1.5 m from the crown's centre, inside the tree's sphere:
    // with one error for the tree (from that centre) the needles beside
    // the camera get the far side's error; with each placement's own, the
    // picture stays nearer the full-detail one (LOD off).
    let mut scene = Scene::new();
    let placed = scene.placed.clone();
    let shot = |scene: &mut Scene, scope: ErrorScope, enabled: bool, name: &str| {
        let mut settings = scene.renderer.world_mut().resource_mut::<ConiferLodSettings>();
        settings.error_scope = scope;
        settings.enabled = enabled;
        scene.shot(&placed, name)
    };
    for (distance, fov) in [(1.5f32, 30.0f32), (0.6, 60.0)] {
        scene.look_from(distance, fov);
        let full = shot(
            &mut scene,
            ErrorScope::Placement,
            false,
            &format!("inside_{distance}m_full"),
        );
        let tree = shot(&mut scene, ErrorScope::Tree, true, &format!("inside_{distance}m_tree"));
        let own = shot(
            &mut scene,
            ErrorScope::Placement,
            true,
            &format!("inside_{distance}m_placement"),
        );
        let (d_tree, d_own) = (mean_difference(&tree, &full), mean_difference(&own, &full));
        println!(
            "{distance} m from the crown centre: mean grey |Δ| to full detail: one error per tree {d_tree:.2}, \
             per placement {d_own:.2}; covered pixels full {}, tree {}, placement {}",
            covered_count(&full),
            covered_count(&tree),
            covered_count(&own)
        );
        assert!(d_own < d_tree, "{distance} m: per placement {d_own}, per tree {d_tree}");
    }
}

#[test]
fn placed_species_hold_each_prototype_once() {
    let _turn = common::gpu_turn();
    let mut scene = Scene::new();
    scene.look_from(6.0, 45.0);
    let (placed, flat) = (scene.placed.clone(), scene.flat.clone());
    scene.shot(&placed, "memory_placed");
    let placed_bytes = scene.memory().species_bytes[&placed.id()];
    scene.shot(&flat, "memory_flat");
    let flat_bytes = scene.memory().species_bytes[&flat.id()];
    println!("species buffers: placed {placed_bytes} B, flat {flat_bytes} B");
    // A sapling's shoots are small (7 needles a placement here): its
    // placements and level-2 lines (with their bounding spheres, 20 bytes
    // a line) weigh most; a mature tree's shoots hold hundreds (`conifer
    // bench`: `prototype_gpu_bytes`).
    assert!(
        placed_bytes * 5 < flat_bytes * 2,
        "placed {placed_bytes} B is not a fraction of flat {flat_bytes} B"
    );
}

#[test]
fn trees_past_the_expansion_capacity_keep_their_coarser_cut() {
    let _turn = common::gpu_turn();
    let mut scene = Scene::new();
    // The coarser cut is what is compared (no impostor).
    scene
        .renderer
        .world_mut()
        .resource_mut::<ConiferLodSettings>()
        .far_impostor = false;
    scene.look_from(6.0, 45.0);
    let placed = scene.placed.clone();
    let full = scene.shot(&placed, "capacity_full");
    // Room for one placement: the tree falls back to its level-2 lines.
    scene
        .renderer
        .world_mut()
        .resource_mut::<ConiferLodSettings>()
        .max_expanded_placements = 1;
    let coarse = scene.shot(&placed, "capacity_one");
    let (f, c) = (covered_count(&full), covered_count(&coarse));
    println!("covered pixels: full {f}, past capacity {c}");
    assert!(c > f / 4, "the tree past capacity is still drawn ({c} of {f} pixels)");
    assert!(mean_difference(&full, &coarse) > 0.5, "and coarser than the full cut");
}

/// The expansion budget goes to the nearest tree, whatever order the
/// trees were spawned in: three trees 6, 20 and 50 m from the camera,
/// spawned farthest first, with room for the nearest one's placements
/// alone. The nearest keeps its cut and its placements; the other two fall
/// back to their level-2 lines (`model::compact::budget_expands`), or,
/// with the far impostor on, the one still in lines (20 m, fading into its
/// impostor) is drawn as its impostor alone. Before the budget went by
/// distance, the first trees the GPU reached (the far ones) took the room
/// and the nearest lost its needles.
#[test]
fn the_expansion_budget_goes_to_the_nearest_tree() {
    let _turn = common::gpu_turn();
    let (mut scene, placed, compact, transforms) = three_trees_scene();
    // Each tree's threshold code and spatial error, by instance slot, and
    // the trees with expanded placements.
    let lods = |scene: &mut Scene, name: &str| {
        let view = scene.read_back(&placed, &transforms, name, true);
        let trees: Vec<(u16, f32, bool)> = (0..view.lods.len())
            .map(|t| {
                let (code, e) = view.tree_lod(t);
                (code, e, view.view_point(t).is_some())
            })
            .collect();
        let expanded = expanded_trees(&view);
        let impostor_alone: Vec<bool> = (0..view.lods.len())
            .map(|t| {
                let lines = [PartKind::OriginalLines, PartKind::MergedLines, PartKind::Prisms]
                    .map(|kind| view.tree_draw(kind, t)[0])
                    .iter()
                    .sum::<u32>();
                view.impostor_fade(t) == 1.0 && view.tree_draw(PartKind::Impostor, t)[0] == 6 && lines == 0
            })
            .collect();
        (trees, expanded, impostor_alone)
    };
    let (roomy, roomy_expanded, _) = lods(&mut scene, "budget_roomy");
    assert_eq!(roomy.len(), 3);
    assert_eq!(roomy_expanded.len(), 3, "with room, every tree expands");
    let nearest = (0..3).min_by(|&a, &b| roomy[a].1.total_cmp(&roomy[b].1)).unwrap();
    let demand = |t: usize| compact.expanded_placements(roomy[t].0);
    println!(
        "codes {:?}, demands {:?}, nearest slot {nearest}",
        roomy.iter().map(|t| t.0).collect::<Vec<_>>(),
        (0..3).map(demand).collect::<Vec<_>>()
    );
    scene
        .renderer
        .world_mut()
        .resource_mut::<ConiferLodSettings>()
        .max_expanded_placements = demand(nearest);
    let (tight, tight_expanded, _) = lods(&mut scene, "budget_nearest");
    assert_eq!(tight_expanded, vec![nearest as u32], "only the nearest tree expands");
    for t in 0..3 {
        if t == nearest {
            assert_eq!(tight[t], roomy[t], "the nearest tree keeps its cut");
        } else {
            assert!(
                tight[t].0 > roomy[t].0 && !tight[t].2,
                "tree {t} falls back to its level-2 lines: {:?} from {:?}",
                tight[t],
                roomy[t]
            );
        }
    }
    // With the impostor: the tree at 20 m fades into it with room, and
    // past the budget it is its impostor alone.
    scene
        .renderer
        .world_mut()
        .resource_mut::<ConiferLodSettings>()
        .far_impostor = true;
    let (with_impostor, expanded, impostor_alone) = lods(&mut scene, "budget_impostor");
    let middle = (0..3)
        .filter(|&t| t != nearest)
        .min_by(|&a, &b| with_impostor[a].1.total_cmp(&with_impostor[b].1))
        .unwrap();
    println!("with the impostor: expanded {expanded:?}, impostor alone {impostor_alone:?}, middle slot {middle}");
    assert_eq!(expanded, vec![nearest as u32]);
    assert!(!impostor_alone[nearest], "the nearest tree keeps its lines");
    assert!(impostor_alone[middle], "the tree past the budget is its impostor");
}

/// A camera draws each expanded placement's lines on their own, the
/// farthest first (by depth bucket of its prototype's sphere centre,
/// `model::compact::back_to_front`): blended lines drawn a prototype at a
/// time mixed a crown's whole depth in a pixel. Three trees 6, 20 and 50 m
/// away: every entry with lines is drawn once, its merged lines then its
/// original lines in one draw, with the lines its own code takes from the
/// orders its draw's flags name and the split the vertex shader reads
/// (`CompactSpecies::entry_lines`), and no draw is in a nearer bucket than
/// one drawn after it (one bucket's slack for the GPU's rounding).
#[test]
fn a_camera_draws_each_placements_lines_back_to_front() {
    let _turn = common::gpu_turn();
    let (mut scene, placed, compact, transforms) = three_trees_scene();
    let view = scene.read_back(&placed, &transforms, "back_to_front", true);
    let camera = scene.camera_position();
    // Instance slots to trees: the spatial error grows with distance.
    let mut slots: Vec<usize> = (0..view.lods.len()).collect();
    slots.sort_by(|&a, &b| view.tree_lod(a).1.total_cmp(&view.tree_lod(b).1));
    let mut nearest_first = transforms;
    nearest_first.sort_by(|a, b| {
        a.translation
            .distance(camera)
            .total_cmp(&b.translation.distance(camera))
    });
    let mut tree_transform = [Transform::IDENTITY; 3];
    for (&slot, transform) in slots.iter().zip(nearest_first) {
        tree_transform[slot] = transform;
    }
    let entries = &view.entries;
    assert_eq!(expanded_trees(&view).len(), 3, "every tree expands");
    assert!(
        view.ordered_draws.len() >= entries.len(),
        "{} draws for {} entries",
        view.ordered_draws.len(),
        entries.len()
    );
    assert_eq!(view.ordered_splits.len(), entries.len());
    let line_vertices = view.line_vertices;
    // Entry `[tree, word]`'s lines: its draw's choices of order (bits 31
    // and 30 of `tree`) at its own code.
    let own_lines = |[tree, word]: [u32; 2]| {
        let placement = &compact.placements[(word & 0xffff) as usize];
        compact.entry_lines(
            placement.prototype as usize,
            (word >> 16) as u16,
            tree >> 31 == 1,
            tree >> 30 & 1 == 1,
        )
    };
    let mut drawn_lines = [0u64; 2];
    let mut seen = vec![false; entries.len()];
    let mut nearest_bucket = u32::MAX;
    let mut buckets = Vec::new();
    for draw in view.ordered_draws.iter().filter(|d| d[0] > 0) {
        let [vertices, instances, first_vertex, slot] = *draw;
        assert_eq!(instances, 1);
        let slot = slot as usize;
        assert!(slot < entries.len() && !seen[slot], "entry {slot} drawn once");
        seen[slot] = true;
        let [tree, word] = entries[slot];
        let placement = &compact.placements[(word & 0xffff) as usize];
        let prototype = &compact.prototypes[placement.prototype as usize];
        let lines = own_lines(entries[slot]);
        assert_eq!(
            [vertices, first_vertex],
            [lines.lines(), lines.first()].map(|n| n * line_vertices),
            "entry {slot}"
        );
        assert_eq!(view.ordered_splits[slot], lines.split(), "entry {slot}");
        drawn_lines[0] += u64::from(lines.original);
        drawn_lines[1] += u64::from(lines.merged);
        let center = prototype.sphere.placed(&placement.transform).center;
        let world = tree_transform[(tree & 0x3fff_ffff) as usize].transform_point(center);
        let bucket = depth_bucket(world.distance(camera));
        assert!(
            bucket <= nearest_bucket.saturating_add(1),
            "bucket {bucket} drawn after bucket {nearest_bucket}"
        );
        nearest_bucket = nearest_bucket.min(bucket);
        buckets.push(bucket);
    }
    // Every entry with lines is drawn.
    for (slot, &entry) in entries.iter().enumerate() {
        let lines = own_lines(entry).lines();
        assert_eq!(seen[slot], lines > 0, "entry {slot}: {lines} lines");
    }
    println!(
        "{} placements drawn back to front, buckets {:?} .. {:?}",
        buckets.len(),
        buckets.first(),
        buckets.last()
    );
    assert!(buckets.first() > buckets.last(), "the crowns span buckets");
    println!(
        "lines drawn one placement at a time: original {}, merged {}",
        drawn_lines[0], drawn_lines[1]
    );
    assert!(drawn_lines[0] > 0 && drawn_lines[1] > 0);
    // By prototype: the instanced draws alone, the same pixels covered.
    let back_to_front = scene.shot_of(&placed, &transforms, "back_to_front");
    scene
        .renderer
        .world_mut()
        .resource_mut::<ConiferLodSettings>()
        .line_order = LineOrder::ByPrototype;
    let view = scene.read_back(&placed, &transforms, "by_prototype", true);
    assert!(view.ordered_draws.is_empty() && view.ordered_splits.is_empty());
    assert_eq!(view.entries.len(), entries.len());
    let by_prototype = scene.shot_of(&placed, &transforms, "by_prototype");
    let (a, b) = (covered_count(&back_to_front), covered_count(&by_prototype));
    let diff = mean_difference(&back_to_front, &by_prototype);
    println!("covered back to front {a}, by prototype {b}; mean grey |Δ| {diff:.2}");
    assert!(a.abs_diff(b) <= a / 100, "{a} against {b}");
}

/// A directional light's cascade sees every tree at the same error (its
/// texel), so the budget cannot go by it: it goes to the trees nearest the
/// camera the cascade serves (`model::compact::budget_error`). Three trees
/// 6, 20 and 50 m from the camera, spawned farthest first, one cascade over
/// all three and room for one tree's placements in it: the nearest casts
/// its lines, the other two their impostors, as the CPU reference
/// (`budget_expands` over the trees' `budget_error` codes) says. Before,
/// the first tree the GPU reached took the room (the farthest), and in the
/// forest a far tree's card cast a straight-edged band across the crowns
/// next to the camera.
#[test]
fn a_cascade_gives_its_budget_to_the_trees_nearest_its_camera() {
    let _turn = common::gpu_turn();
    let mut scene = Scene::new();
    let world = scene.renderer.world_mut();
    world.resource_mut::<CompactReadback>().enabled = true;
    let sun = world
        .query_filtered::<Entity, With<DirectionalLight>>()
        .single(world)
        .unwrap();
    world.get_mut::<DirectionalLight>(sun).unwrap().shadow_maps_enabled = true;
    world.entity_mut(sun).insert(
        bevy::light::CascadeShadowConfigBuilder {
            num_cascades: 1,
            maximum_distance: 80.0,
            first_cascade_far_bound: 80.0,
            ..default()
        }
        .build(),
    );
    scene.look_from(6.0, 45.0);
    let placed = scene.placed.clone();
    let compact = scene.compact(&placed);
    let transforms = three_trees();
    // The cascade's threshold code per tree and the trees it expanded.
    let cascade = |scene: &mut Scene, name: &str| {
        let view = scene.read_back(&placed, &transforms, name, false);
        let codes: Vec<u16> = (0..view.lods.len()).map(|t| view.tree_lod(t).0).collect();
        let expanded = expanded_trees(&view);
        let impostor: Vec<bool> = (0..view.lods.len())
            .map(|t| view.tree_draw(PartKind::Impostor, t)[0] == 6)
            .collect();
        (codes, expanded, impostor)
    };
    let (codes, roomy_expanded, _) = cascade(&mut scene, "cascade_roomy");
    assert_eq!(codes.len(), 3);
    assert!(
        codes.iter().all(|&c| c == codes[0]),
        "one error for the cascade: {codes:?}"
    );
    assert_eq!(roomy_expanded, vec![0, 1, 2], "with room, every tree casts its lines");
    let demand = compact.expanded_placements(codes[0]);
    assert!(demand > 0, "the cascade's cut expands placements");
    // The CPU reference: each tree ranked by the error its camera sees it
    // at (45°, 160 pixels high).
    let slope = 2.0 * (22.5f32).to_radians().tan() / SIZE as f32;
    let eye = scene.crown + Vec3::Z * 6.0;
    let trees: Vec<(u16, u32)> = transforms
        .iter()
        .map(|t| {
            let distance = eye.distance(scene.crown + t.translation);
            (
                shader_threshold_code(budget_error(distance, 0.0, slope, 1.0, 1.0)),
                demand,
            )
        })
        .collect();
    let reference = budget_expands(&trees, demand);
    scene
        .renderer
        .world_mut()
        .resource_mut::<ConiferLodSettings>()
        .max_expanded_placements = demand;
    let (_, expanded, impostor) = cascade(&mut scene, "cascade_nearest");
    println!(
        "cascade code {}, demand {demand}: expanded {expanded:?}, impostors {impostor:?}, reference {reference:?}",
        codes[0]
    );
    assert_eq!(
        reference,
        vec![false, false, true],
        "the reference gives the room to the nearest tree"
    );
    assert_eq!(expanded, vec![2], "the cascade expands the tree nearest its camera");
    assert_eq!(
        impostor,
        vec![true, true, false],
        "the trees past its budget cast their impostors"
    );
}

/// The per-tree draws the CPU reference (`CompactSpecies::prefixes`) gives
/// for a tree at threshold code `code` and spatial error `e`, as the compute
/// pass writes them: `[vertex count, first vertex]` of prisms, original
/// lines and merged lines.
fn reference_tree_draws(compact: &CompactSpecies, code: u16, e: f32) -> [[u32; 2]; 3] {
    let p = compact.prefixes(code, e);
    let prism_vertices = 12 * u32::from(compact.max_sides.max(3)) - 12;
    [
        [p.prisms * prism_vertices, 0],
        [
            2 * p.original_lines,
            if p.original_from_needles { 2 * p.prisms } else { 0 },
        ],
        [2 * p.merged_lines, 0],
    ]
}

#[test]
fn gpu_draws_equal_the_cpu_reference() {
    let _turn = common::gpu_turn();
    let mut scene = Scene::new();
    scene.renderer.world_mut().resource_mut::<CompactReadback>().enabled = true;
    // The cut is what is compared: no impostor far away.
    scene
        .renderer
        .world_mut()
        .resource_mut::<ConiferLodSettings>()
        .far_impostor = false;
    let (placed, flat) = (scene.placed.clone(), scene.flat.clone());
    let species = scene.renderer.world().resource::<Assets<ConiferSpecies>>();
    let placed_compact = species.get(&placed).unwrap().compact.clone();
    let flat_compact = species.get(&flat).unwrap().compact.clone();
    let prototype_record = {
        let input = generate_prototypes(
            Species::ScotsPine,
            &GenerateOptions {
                seed: 3,
                target_needles: Some(15_000),
                age: bevy_conifer_lod::generate::Age::Young,
            },
        );
        bake_prototypes(&input, &BakeOptions::default(), &())
            .unwrap()
            .quantized()
            .unwrap()
    };
    let flat_record = prototype_record.flatten().unwrap();
    let mut view_dependent = 0;
    for distance in [1.5f32, 6.0, 25.0, 80.0] {
        scene.look_from(distance, 45.0);
        for (handle, compact) in [(&placed, &placed_compact), (&flat, &flat_compact)] {
            scene.shot(handle, &format!("readback_{distance}m"));
            let readback = scene.renderer.world().resource::<CompactReadback>().clone();
            let view = readback
                .views
                .iter()
                .find(|v| v.species == handle.id() && v.perspective)
                .expect("the camera's results were read back");
            let (code, e) = view.tree_lod(0);
            assert!(
                code.abs_diff(shader_threshold_code(e)) <= 1,
                "tree code {code} at e = {e}"
            );
            // View-dependent detail (the default scope) on the placed tree:
            // the camera in the tree's frame (the tree stands at the
            // origin) and the tree's error from its sphere's nearest point.
            let seen = view.view_point(0);
            if let Some(seen) = &seen {
                let camera = scene.camera_position();
                assert!(
                    seen.camera.distance(camera) < 1e-3,
                    "view point {seen:?}, camera {camera}"
                );
                let cpu = compact.sphere_error(seen, &compact.tree_sphere);
                assert!((e - cpu).abs() <= 1e-5 * cpu.max(1e-3), "tree error {e}, CPU {cpu}");
                view_dependent += 1;
            }
            // Per-tree draws: the GPU's binary searches are the CPU's.
            let trees = view.lods.len();
            for (kind, [vertices, first]) in reference_tree_draws(compact, code, e).into_iter().enumerate() {
                let draw = view.tree_draws[kind * trees];
                assert_eq!([draw[0], draw[2]], [vertices, first], "{distance} m, part {kind}");
            }
            // Placed draws: each entry's threshold code is the tree's error
            // over its placement's scale; each draw counts its entries and
            // holds the longest prefix they need.
            let mut expected = vec![PlacedDraw::default(); compact.prototypes.len() * PLACED_BANDS as usize];
            for &[tree, word] in &view.entries {
                assert_eq!(tree & 0x3fff_ffff, 0);
                let j = (word & 0xffff) as usize;
                let c = (word >> 16) as u16;
                let placement = &compact.placements[j];
                assert!(!compact.parent_accepted(j, seen.as_ref(), shader_threshold_code));
                let cpu =
                    shader_threshold_code(compact.placement_error(j, e, seen.as_ref()) / placement.transform.scale);
                assert!(c.abs_diff(cpu) <= 1, "entry code {c}, CPU {cpu}");
                let k = placement.prototype as usize;
                expected[compact.placed_draw_index(k, c)].add(compact.prototype_prefixes(k, c));
            }
            let cpu_view = compact.placed_view(code, e, shader_threshold_code, seen.as_ref());
            assert_eq!(view.entries.len(), cpu_view.expanded.len());
            let draws = expected.len();
            let prism_vertices = 12 * u32::from(compact.max_sides.max(3)) - 12;
            for (d, reference) in expected.iter().enumerate() {
                let [prisms, original, merged] = [0, 1, 2].map(|part| view.placed_draws[part * draws + d]);
                let count = |draw: [u32; 4]| if draw[0] == 0 { 0 } else { draw[1] };
                // A draw without placements needs no prefix: `longest` stays 0.
                let longest = reference.longest;
                let placements = if longest.total() > 0 { reference.placements } else { 0 };
                assert_eq!(count(prisms).max(count(original)).max(count(merged)), placements);
                assert_eq!(prisms[0], longest.prisms * prism_vertices);
                assert_eq!(original[0], 2 * longest.original_lines());
                assert_eq!(merged[0], 2 * longest.merged());
            }
            // Each entry says which order its draw takes lines from: the
            // needles after the prisms (bit 31), merged lines by own code
            // (bit 30).
            for &[tree, word] in &view.entries {
                let placement = &compact.placements[(word & 0xffff) as usize];
                let longest =
                    expected[compact.placed_draw_index(placement.prototype as usize, (word >> 16) as u16)].longest;
                assert_eq!(tree >> 31 == 1, longest.original_from_needles());
                assert_eq!(tree >> 30 & 1 == 1, longest.merged_from_own());
            }
            // What the vertex shaders process over what the cut holds.
            let cut = if compact.placements.is_empty() {
                flat_record.cut(e)
            } else {
                compact
                    .placed_drawn(&prototype_record, code, e, shader_threshold_code, seen.as_ref())
                    .0
            };
            let in_cut = (cut.prisms.len() + cut.original_lines.len() + cut.merged_lines.len()) as f64;
            let ratio = view.processed_primitives(compact.max_sides) as f64 / in_cut.max(1.0);
            println!(
                "{distance} m, {}: {} expanded placements, processed / cut = {ratio:.2}",
                if compact.placements.is_empty() {
                    "flat"
                } else {
                    "placed"
                },
                view.entries.len()
            );
            assert!(ratio <= 2.0, "{distance} m: {ratio}");
        }
    }
    assert_eq!(
        view_dependent, 4,
        "the placed tree is seen from a view point at every distance"
    );
}

#[test]
fn placed_prototypes_cast_the_flattened_tree_shadow() {
    let _turn = common::gpu_turn();
    let mut scene = Scene::new();
    let world = scene.renderer.world_mut();
    let mut lights = world.query::<&mut DirectionalLight>();
    for mut light in lights.iter_mut(world) {
        light.shadow_maps_enabled = true;
    }
    spawn_ground(world);
    // Straight down from 14 m over the tree: the ground and its shadow.
    let camera = scene.camera;
    *world.get_mut::<Transform>(camera).unwrap() =
        Transform::from_translation(Vec3::Y * 14.0).looking_at(Vec3::ZERO, Vec3::X);
    for _ in 0..3 {
        scene.renderer.update().unwrap();
    }
    let bare = scene.renderer.capture(&scene.target, 20).unwrap();
    let (placed, flat) = (scene.placed.clone(), scene.flat.clone());
    let a = scene.shot(&placed, "shadow_placed");
    let b = scene.shot(&flat, "shadow_flat");
    // Darkening of the ground by the tree and its shadow, and how the two differ.
    let grey = |p: &image::Rgba<u8>| (p[0] as f32 + p[1] as f32 + p[2] as f32) / 3.0;
    let darkening = |image: &image::RgbaImage| -> f32 {
        image
            .pixels()
            .zip(bare.pixels())
            .map(|(p, q)| (grey(q) - grey(p)).max(0.0))
            .sum::<f32>()
            / image.pixels().len() as f32
    };
    let (da, db) = (darkening(&a), darkening(&b));
    let difference = a
        .pixels()
        .zip(b.pixels())
        .map(|(p, q)| (grey(p) - grey(q)).abs())
        .sum::<f32>()
        / a.pixels().len() as f32;
    println!("shadow: darkening placed {da:.2}, flat {db:.2}; mean |Δ| {difference:.2} of 255");
    assert!(db > 1.0, "the flat tree darkens the ground");
    assert!((da - db).abs() <= 0.05 * db, "placed {da}, flat {db}");
    assert!(difference < 1.0);
}

#[test]
fn with_lod_off_every_tree_of_a_forest_is_drawn() {
    let _turn = common::gpu_turn();
    let mut scene = Scene::new();
    scene.renderer.world_mut().resource_mut::<ConiferLodSettings>().enabled = false;
    scene.look_from(30.0, 45.0);
    let row: Vec<Transform> = (0..5)
        .map(|k| Transform::from_xyz((k as f32 - 2.0) * 6.0, 0.0, 0.0))
        .collect();
    let (placed, flat) = (scene.placed.clone(), scene.flat.clone());
    let a = scene.shot_of(&placed, &row, "lod_off_forest_placed");
    let b = scene.shot_of(&flat, &row, "lod_off_forest_flat");
    // Each tree's column of the picture.
    for k in 0..5u32 {
        let column =
            |image: &image::RgbaImage| image::imageops::crop_imm(image, k * SIZE / 5, 0, SIZE / 5, SIZE).to_image();
        assert_alike(&format!("LOD off, tree {k}"), &column(&a), &column(&b));
    }
}
