//! Wind, rendered on Mesa's lavapipe and compared with the CPU reference
//! (`model::wind`): each part of a tree moves where the field says, its
//! surfaces turn as it bends them, and culling and errors grow by the
//! wind's reach.
//! Pictures go to `target/test-output/render/`.
#![cfg(feature = "plugin")]

mod common;

use bevy::prelude::*;
use bevy_conifer_lod::model::WoodSegment;
use bevy_conifer_lod::model::wind::{TreeWindPhase, WindClock, turn_normal, wind_offset, wind_reach};
use bevy_conifer_lod::plugin::headless::HeadlessRenderer;
use bevy_conifer_lod::plugin::{CompactReadback, PartKind};
use bevy_conifer_lod::prelude::*;
use common::{BACKGROUND, background_camera, covered, shoot, trunk_with_shoots};
use std::path::PathBuf;

const SIZE: u32 = 200;
const FOV_DEG: f32 = 50.0;

/// A 10 m trunk with a shoot at its top and one at a branch's tip, 2.5 m
/// out at 5 m up.
fn tree() -> ConiferSpecies {
    trunk_with_shoots(&[Vec3::new(-0.17, 9.7, 0.0), Vec3::new(2.3, 4.85, 0.0)], |k| {
        0.15 - 0.011 * k as f32
    })
}

/// A strong wind blowing to +x (to the right of the pictures), its clock
/// stopped at `seconds`.
fn wind(seconds: f64) -> ConiferWind {
    ConiferWind {
        direction: Vec2::X,
        strength: 4.0,
        gustiness: 0.3,
        turbulence: 0.6,
        time: Some(seconds),
    }
}

/// The picture of `target` a few frames into `wind`, saved as
/// `target/test-output/render/NAME.png`.
fn shot_in(renderer: &mut HeadlessRenderer, target: &Handle<Image>, wind: ConiferWind, name: &str) -> image::RgbaImage {
    renderer.world_mut().insert_resource(wind);
    for _ in 0..3 {
        renderer.update().unwrap();
    }
    let image = renderer.capture(target, 20).unwrap();
    let out = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("target/test-output/render");
    std::fs::create_dir_all(&out).unwrap();
    image.save(out.join(format!("{name}.png"))).unwrap();
    image
}

/// The centroid (pixels) of the covered pixels of `image` in columns
/// `columns` and rows `rows` that pass `keep` (their colour), and how
/// many there were.
fn centroid(
    image: &image::RgbaImage,
    columns: std::ops::Range<u32>,
    rows: std::ops::Range<u32>,
    keep: fn(&image::Rgba<u8>) -> bool,
) -> (Vec2, usize) {
    let mask = covered(image);
    let (mut sum, mut n) = (Vec2::ZERO, 0usize);
    for y in rows {
        for x in columns.clone() {
            if mask[(y * SIZE + x) as usize] && keep(image.get_pixel(x, y)) {
                sum += Vec2::new(x as f32 + 0.5, y as f32 + 0.5);
                n += 1;
            }
        }
    }
    (sum / n.max(1) as f32, n)
}

#[test]
fn needles_and_wood_move_where_the_cpu_field_says() {
    let _turn = common::gpu_turn();
    let species = tree();
    let shape = species.wind_shape;
    let (mut renderer, target, camera) = common::one_tree_scene(species, SIZE);
    // 12 m in front of the tree's middle: a metre is 9.4 pixels, every
    // needle a prism.
    let look = Vec3::new(1.1, 5.2, 0.0);
    let distance = 12.0f32;
    common::look_at_crown(renderer.world_mut(), camera, look, distance, FOV_DEG);
    let pixels_per_metre = SIZE as f32 / (2.0 * distance * (FOV_DEG.to_radians() / 2.0).tan());
    let to_pixel = |p: Vec3| {
        // Perspective: what lies off the look point's plane scales by depth.
        let depth = distance - p.z;
        let s = pixels_per_metre * distance / depth;
        Vec2::new(
            SIZE as f32 / 2.0 + (p.x - look.x) * s,
            SIZE as f32 / 2.0 - (p.y - look.y) * s,
        )
    };
    let mut shot = |wind: ConiferWind, name: &str| shot_in(&mut renderer, &target, wind, &format!("wind_{name}"));
    let calm = shot(ConiferWind::CALM, "calm");
    // Regions: the top shoot, the branch shoot, the trunk at 3–4 m (its
    // foot barely moves; higher up the shoots hide it).
    let top = to_pixel(Vec3::new(0.0, 9.85, 0.0));
    let branch = to_pixel(Vec3::new(2.47, 5.0, 0.0));
    let around = |c: Vec2, half: f32| {
        let lo = (c - half).max(Vec2::ZERO).as_uvec2();
        let hi = (c + half).min(Vec2::splat(SIZE as f32)).as_uvec2();
        (lo.x..hi.x, lo.y..hi.y)
    };
    let trunk_rows = to_pixel(Vec3::new(0.0, 4.0, 0.0)).y as u32..to_pixel(Vec3::new(0.0, 3.0, 0.0)).y as u32;
    let trunk_columns = 0..(to_pixel(Vec3::new(1.0, 0.0, 0.0)).x as u32);
    // Points along every needle of a shoot placed at `origin`.
    let shoot_points = |origin: Vec3| -> Vec<Vec3> {
        shoot()
            .iter()
            .flat_map(|n| (0..6).map(move |i| origin + n.base.lerp(n.tip, (i as f32 + 0.5) / 6.0)))
            .collect()
    };
    // A shoot's pixels are its needles' green, not the bark of the trunk
    // whose top its box holds: under a pixel wide there, the trunk covers
    // a varying count of pixel centres as it leans.
    let foliage: fn(&image::Rgba<u8>) -> bool = |p| p[1] > p[0];
    let anything: fn(&image::Rgba<u8>) -> bool = |_| true;
    let regions = [
        (
            "top shoot",
            around(top, 16.0),
            shoot_points(Vec3::new(-0.17, 9.7, 0.0)),
            foliage,
        ),
        (
            "branch shoot",
            around(branch, 16.0),
            shoot_points(Vec3::new(2.3, 4.85, 0.0)),
            foliage,
        ),
        (
            "trunk",
            (trunk_columns, trunk_rows),
            vec![Vec3::new(0.0, 3.5, 0.0)],
            anything,
        ),
    ];
    let mut moved = 0.0f32;
    for seconds in [0.8, 2.3, 3.9] {
        let w = wind(seconds);
        let windy = shot(w, &format!("{seconds}s"));
        let clock = WindClock::at(seconds, &shape);
        let phase = TreeWindPhase::of_root(Vec2::ZERO, &w.model());
        for (what, (columns, rows), points, keep) in regions.clone() {
            let (before, n_before) = centroid(&calm, columns.clone(), rows.clone(), keep);
            let (after, n_after) = centroid(&windy, columns, rows, keep);
            assert!(n_before > 20 && n_after > 20, "{what}: {n_before}, {n_after} pixels");
            // The field varies across a shoot: the mean of its points' moves.
            let expected = points
                .iter()
                .map(|&at| {
                    let offset = wind_offset(&w.model(), &shape, &clock, &phase, at).world(Vec2::X, 1.0);
                    to_pixel(at + offset) - to_pixel(at)
                })
                .sum::<Vec2>()
                / points.len() as f32;
            let measured = after - before;
            moved = moved.max(measured.length());
            assert!(
                (measured - expected).length() < 0.6,
                "{what} at {seconds} s: moved {measured} px, the field says {expected} px"
            );
        }
    }
    // The pictures did change: the top moved by pixels, not by nothing.
    assert!(moved > 3.0, "{moved}");
    assert_eq!(calm.get_pixel(0, 0).0[..3], BACKGROUND);
}

/// In wind a wood segment bends along its length: drawn in
/// `WOOD_SECTIONS` sections, a 3 m branch's middle moves where the field
/// moves it, not where a branch straight between its moved ends would be
/// (CPU reference: `wood_offset` at points along it; `wood_bend_gap`).
#[test]
fn a_long_branch_bends_along_its_length() {
    let _turn = common::gpu_turn();
    // A branch 3 m long, 20 cm thick, straight out at 6 m up.
    let (root, tip) = (Vec3::new(0.12, 6.0, 0.0), Vec3::new(3.12, 6.0, 0.0));
    let branch = WoodSegment {
        start: root,
        end: tip,
        start_radius: 0.1,
        end_radius: 0.1,
    };
    let species = common::trunk_with_branches(&[Vec3::new(-0.17, 9.7, 0.0)], |k| 0.15 - 0.011 * k as f32, &[branch]);
    let shape = species.wind_shape;
    let (mut renderer, target, camera) = common::one_tree_scene(species, SIZE);
    // 6 m in front of the branch's middle: a metre is 36 pixels.
    let look = Vec3::new(1.62, 6.0, 0.0);
    let distance = 6.0f32;
    common::look_at_crown(renderer.world_mut(), camera, look, distance, FOV_DEG);
    let pixels_per_metre = SIZE as f32 / (2.0 * distance * (FOV_DEG.to_radians() / 2.0).tan());
    let row = |y: f32| SIZE as f32 / 2.0 - (y - look.y) * pixels_per_metre;
    let column = |x: f32| SIZE as f32 / 2.0 + (x - look.x) * pixels_per_metre;
    let mut shot = |wind: ConiferWind, name: &str| shot_in(&mut renderer, &target, wind, &format!("branch_{name}"));
    let calm = shot(ConiferWind::CALM, "calm");
    // The branch's middle third, and rows well beyond its sway.
    let (from, to) = (root.lerp(tip, 1.0 / 3.0), root.lerp(tip, 2.0 / 3.0));
    let columns = column(from.x) as u32..column(to.x) as u32;
    let rows = (row(6.0) - 30.0) as u32..(row(6.0) + 30.0) as u32;
    let (mut bent, mut straight_apart) = (0.0f32, 0.0f32);
    for seconds in [0.8, 2.3, 3.9] {
        let w = wind(seconds);
        let windy = shot(w, &format!("{seconds}s"));
        let clock = WindClock::at(seconds, &shape);
        let phase = TreeWindPhase::of_root(Vec2::ZERO, &w.model());
        let up = |p: Vec3| wind_offset(&w.model(), &shape, &clock, &phase, p).up;
        let (before, n_before) = centroid(&calm, columns.clone(), rows.clone(), |_| true);
        let (after, n_after) = centroid(&windy, columns.clone(), rows.clone(), |_| true);
        assert!(n_before > 100 && n_after > 100, "{n_before}, {n_after} pixels");
        // Down the picture is up the tree.
        let measured = (before.y - after.y) / pixels_per_metre;
        let points: Vec<f32> = (0..32).map(|i| (i as f32 + 0.5) / 32.0).collect();
        let field = points.iter().map(|&t| up(from.lerp(to, t))).sum::<f32>() / points.len() as f32;
        let straight = points
            .iter()
            .map(|&t| {
                let along = (from.x - root.x + t * (to.x - from.x)) / (tip.x - root.x);
                up(root) + (up(tip) - up(root)) * along
            })
            .sum::<f32>()
            / points.len() as f32;
        println!(
            "{seconds} s: the branch's middle rose {:.1} px; the field says {:.1} px, straight between its ends {:.1} px",
            measured * pixels_per_metre,
            field * pixels_per_metre,
            straight * pixels_per_metre
        );
        assert!(
            (measured - field).abs() * pixels_per_metre < 0.6,
            "{seconds} s: the middle rose {measured} m, the field says {field} m"
        );
        bent = bent.max(measured.abs());
        straight_apart = straight_apart.max((straight - field).abs() * pixels_per_metre);
    }
    // The wind moved the branch, and drawn straight it would have missed.
    assert!(bent * pixels_per_metre > 0.8, "{bent}");
    assert!(
        straight_apart > 1.5,
        "straight would be off by {straight_apart} px at most"
    );
}

/// A thick 10 m trunk (radius 0.5 m) and a shoot 4 m out: the trunk fills
/// 27 pixels across 8 m away.
fn thick_trunk() -> ConiferSpecies {
    trunk_with_shoots(&[Vec3::new(4.0, 1.0, -3.0)], |_| 0.5)
}

/// A pixel's linear brightness (the mean of its RGB channels, sRGB decoded).
fn linear(p: &image::Rgba<u8>) -> f32 {
    (common::linear(p[0]) + common::linear(p[1]) + common::linear(p[2])) / 3.0
}

#[test]
fn the_trunk_turns_its_normals_toward_the_light_as_it_leans() {
    let _turn = common::gpu_turn();
    let species = thick_trunk();
    let shape = species.wind_shape;
    let mut renderer = HeadlessRenderer::new(".");
    let handle = renderer
        .world_mut()
        .resource_mut::<Assets<ConiferSpecies>>()
        .add(species);
    renderer
        .world_mut()
        .spawn((ConiferFoliage(handle), Transform::IDENTITY));
    // The trunk itself, not the crown impostor (a 10 m tree seen 8 m away
    // in 200 pixels is past half a texel of it).
    renderer.world_mut().resource_mut::<ConiferLodSettings>().far_impostor = false;
    // The sun straight overhead and nothing else: in calm the trunk's
    // sides face it edge on (N·L = 0) and stay black; leaning away from
    // the wind, its upwind side turns up toward the sun and is lit, its
    // downwind side turns away and stays black. Drawn with the calm
    // normals, both sides would stay black.
    renderer.world_mut().insert_resource(GlobalAmbientLight {
        brightness: 0.0,
        ..default()
    });
    renderer.world_mut().spawn((
        DirectionalLight {
            illuminance: 40_000.0,
            shadow_maps_enabled: false,
            ..default()
        },
        Transform::from_rotation(Quat::from_rotation_x(-std::f32::consts::FRAC_PI_2)),
    ));
    let target = renderer.render_target(SIZE, SIZE);
    let camera = background_camera(renderer.world_mut(), &target);
    renderer
        .world_mut()
        .entity_mut(camera)
        .insert(bevy::core_pipeline::tonemapping::Tonemapping::None);
    let look = Vec3::new(0.0, 5.0, 0.0);
    let distance = 8.0f32;
    common::look_at_crown(renderer.world_mut(), camera, look, distance, FOV_DEG);
    let pixels_per_metre = SIZE as f32 / (2.0 * distance * (FOV_DEG.to_radians() / 2.0).tan());
    let row_of = |y: f32| (SIZE as f32 / 2.0 - (y - look.y) * pixels_per_metre) as u32;
    let column_of = |x: f32| (SIZE as f32 / 2.0 + x * pixels_per_metre) as u32;
    // No gusts or flutter: the trunk's bend alone, at the moment of the
    // first three seconds it bends most (the sway adds to the lean).
    let phase = TreeWindPhase::of_root(Vec2::ZERO, &ConiferWind::default().model());
    let seconds = (0..30)
        .map(|t| f64::from(t) * 0.1)
        .max_by(|&a, &b| {
            let bend = |t: f64| (WindClock::at(t, &shape).trunk + phase.sway).sin();
            bend(a).total_cmp(&bend(b))
        })
        .unwrap();
    let steady = |direction: Vec2, strength: f32| ConiferWind {
        direction,
        strength,
        gustiness: 0.0,
        turbulence: 0.0,
        time: Some(seconds),
    };
    let mut shot =
        |wind: ConiferWind, name: &str| shot_in(&mut renderer, &target, wind, &format!("wind_normals_{name}"));
    let calm = shot(steady(Vec2::X, 0.0), "calm");
    let right = [
        shot(steady(Vec2::X, 2.0), "right_2"),
        shot(steady(Vec2::X, 4.0), "right_4"),
    ];
    let left = shot(steady(-Vec2::X, 4.0), "left_4");
    // Mean brightness of the trunk's left and right quarters over segment
    // k's rows (a margin off its ends): of each row's covered run, three
    // pixels in from its edges (which blend with the background).
    let halves = |image: &image::RgbaImage, k: usize| {
        let covered = covered(image);
        let rows = row_of(0.97 * (k + 1) as f32 - 0.15)..row_of(0.97 * k as f32 + 0.15);
        let (mut left, mut right) = (Vec::new(), Vec::new());
        for y in rows {
            let run: Vec<u32> = (column_of(-1.5)..column_of(1.5))
                .filter(|&x| covered[(y * SIZE + x) as usize])
                .collect();
            let (Some(&first), Some(&last)) = (run.first(), run.last()) else {
                continue;
            };
            let (first, last) = (first + 3, last.saturating_sub(3));
            if last <= first + 8 {
                continue;
            }
            let quarter = (last - first) / 4;
            left.extend((first..first + quarter).map(|x| linear(image.get_pixel(x, y))));
            right.extend((last - quarter..last).map(|x| linear(image.get_pixel(x, y))));
        }
        assert!(left.len() > 40, "segment {k}: {} pixels a side", left.len());
        let mean = |v: &[f32]| v.iter().sum::<f32>() / v.len() as f32;
        (mean(&left), mean(&right))
    };
    // The CPU reference: how far the upwind side's normal turns up as the
    // wind turns the segment's chord (`turn_normal`, as the shader does).
    let upwind_rise = |strength: f32, k: usize| {
        let w = steady(Vec2::X, strength).model();
        let clock = WindClock::at(seconds, &shape);
        let phase = TreeWindPhase::of_root(Vec2::ZERO, &w);
        let end = |y: f32| {
            let at = Vec3::new(0.0, y, 0.0);
            at + wind_offset(&w, &shape, &clock, &phase, at).world(Vec2::X, 1.0)
        };
        let (a, b) = (0.97 * k as f32, 0.97 * (k + 1) as f32);
        turn_normal(-Vec3::X, Vec3::Y * (b - a), end(b) - end(a)).y
    };
    for k in 3..8 {
        let (calm_left, calm_right) = halves(&calm, k);
        let [(half_left, half_right), (full_left, full_right)] = [halves(&right[0], k), halves(&right[1], k)];
        let (against_left, against_right) = halves(&left, k);
        let (rise_half, rise_full) = (upwind_rise(2.0, k), upwind_rise(4.0, k));
        println!(
            "segment {k}: calm {calm_left:.4} | {calm_right:.4}; to +x, strength 2: {half_left:.4} | {half_right:.4}, 4: {full_left:.4} | {full_right:.4}; to −x, 4: {against_left:.4} | {against_right:.4} (CPU: upwind normal rises {rise_half:.4}, {rise_full:.4})"
        );
        assert!(
            rise_full > rise_half && rise_half > 0.0,
            "the CPU field bends the trunk downwind"
        );
        assert!(
            calm_left.max(calm_right) < 0.002,
            "segment {k} in calm: {calm_left} | {calm_right}"
        );
        // Blowing to +x the left (upwind) side is lit, more in a stronger
        // wind; blowing to −x, the right side.
        assert!(
            full_left > 0.01 && full_left > 3.0 * full_right,
            "segment {k}: {full_left} | {full_right}"
        );
        assert!(
            full_left > half_left && half_left > 2.0 * half_right,
            "segment {k}: {half_left} vs {full_left}"
        );
        assert!(
            against_right > 0.01 && against_right > 3.0 * against_left,
            "segment {k}: {against_left} | {against_right}"
        );
        // Lit in proportion to how far the normals rose (the faces, the
        // bark's colour and the sun are the same in both pictures).
        let (measured, expected) = (full_left / half_left, rise_full / rise_half);
        assert!(
            (measured / expected - 1.0).abs() < 0.1,
            "segment {k}: brightness grew {measured}×, the normals' rise {expected}×"
        );
    }
}

#[test]
fn culling_and_errors_grow_by_the_winds_reach() {
    let _turn = common::gpu_turn();
    let mut renderer = HeadlessRenderer::new(".");
    let species = tree();
    let shape = species.wind_shape;
    let crown = species.crown_center;
    let crown_radius = {
        let (lo, hi) = (Vec3::from(species.aabb.min()), Vec3::from(species.aabb.max()));
        (lo - crown).abs().max((hi - crown).abs()).length()
    };
    let handle = renderer
        .world_mut()
        .resource_mut::<Assets<ConiferSpecies>>()
        .add(species);
    HeadlessRenderer::spawn_lights(renderer.world_mut());
    renderer.world_mut().resource_mut::<CompactReadback>().enabled = true;
    // Lines, not the crown impostor (which has no view point).
    renderer.world_mut().resource_mut::<ConiferLodSettings>().far_impostor = false;
    let reach = wind_reach(&wind(0.0).model(), &shape);
    assert!(reach > 0.5, "{reach}");
    // Tree 0 in full view 40 m away; tree 1 off the right edge of the
    // frustum by half the reach (its crown sphere's, the cull test's).
    let depth = 40.0f32;
    let half_angle = (FOV_DEG / 2.0).to_radians();
    let edge_x = depth * half_angle.tan() + (crown_radius + 0.5 * reach) / half_angle.cos();
    let roots = [
        Vec3::new(0.0, -crown.y, -depth),
        Vec3::new(edge_x - crown.x, -crown.y, -depth),
    ];
    for root in roots {
        renderer
            .world_mut()
            .spawn((ConiferFoliage(handle.clone()), Transform::from_translation(root)));
    }
    let target = renderer.render_target(SIZE, SIZE);
    let camera = background_camera(renderer.world_mut(), &target);
    *renderer.world_mut().get_mut::<Projection>(camera).unwrap() = Projection::Perspective(PerspectiveProjection {
        fov: FOV_DEG.to_radians(),
        ..default()
    });
    let mut frame = |wind: ConiferWind| {
        renderer.world_mut().insert_resource(wind);
        for _ in 0..4 {
            renderer.update().unwrap();
        }
        renderer.capture(&target, 20).unwrap();
        let readback = renderer.world().resource::<CompactReadback>();
        readback
            .views
            .iter()
            .find(|v| v.perspective)
            .expect("the camera's readback")
            .clone()
    };
    let calm = frame(ConiferWind::CALM);
    let windy = frame(wind(1.0));
    // Instance slots need not follow the spawn order: the tree in view is
    // the one the calm frame gave a view point.
    let in_view = (0..2)
        .find(|&t| calm.view_point(t).is_some())
        .unwrap_or_else(|| panic!("a tree in view: {:?}", calm.lods));
    let edge = 1 - in_view;
    // Off screen by half the reach: culled in calm, kept in wind.
    let drawn = |view: &bevy_conifer_lod::plugin::ViewReadback| {
        let own = PartKind::ALL
            .iter()
            .filter(|k| k.placed_index().is_none())
            .any(|&k| view.tree_draw(k, edge)[0] > 0 && view.tree_draw(k, edge)[1] > 0);
        own || view.entries.iter().any(|e| (e[0] & 0x7fff_ffff) as usize == edge)
    };
    assert!(!drawn(&calm), "in calm the tree off screen is culled");
    assert!(drawn(&windy), "in wind the tree that may sway into view is kept");
    // In view: the error is measured from its sphere grown by the reach,
    // the slope times the reach smaller (tree metres).
    let (_, e_calm) = calm.tree_lod(in_view);
    let (_, e_windy) = windy.tree_lod(in_view);
    let slope = calm.view_point(in_view).map(|v| v.error_per_metre).unwrap_or(0.0);
    assert!(
        ((e_calm - e_windy) - slope * reach).abs() < 1e-3 * e_calm,
        "calm {e_calm}, windy {e_windy}, slope × reach {}",
        slope * reach
    );
}
