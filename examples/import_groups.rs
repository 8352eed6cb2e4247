//! The glTF importer's phyllotaxy-group rule, measured and shown.
//!
//! 1. Imports `../shared/fixtures/small_pine_s0.glb` (or the file given as
//!    the first argument) and renders it with every group in its own colour
//!    to `target/preview/fixture-groups.png` (and a close-up).
//! 2. For each procedural preset: writes the tree as a GLB *without* its
//!    groups, imports it back, and compares the inferred groups with the
//!    true ones (purity, completeness, adjusted Rand index); renders the
//!    synthetic tree coloured by inferred group.
//!
//! `cargo run --release --example import_groups`

use bevy_conifer_lod::export::{TreeGlbOptions, encode_tree_glb};
use bevy_conifer_lod::generate::{GenerateOptions, Species, generate};
use bevy_conifer_lod::import::{ImportOptions, group_agreement, import_gltf, import_gltf_bytes};
use bevy_conifer_lod::model::TreeInput;
use bevy_conifer_lod::preview::{
    PreviewCamera, PreviewOptions, PreviewPrimitive, mesh_triangles, render_preview_scene,
};
use glam::Vec3;
use std::path::{Path, PathBuf};
use std::time::Instant;

/// A well-spread colour for group `g` (golden-ratio hues).
fn group_color(g: u32) -> [f32; 3] {
    let hue = (g as f32 * 0.618_034).fract() * 6.0;
    let x = 1.0 - (hue % 2.0 - 1.0).abs();
    let [r, gr, b] = match hue as u32 {
        0 => [1.0, x, 0.0],
        1 => [x, 1.0, 0.0],
        2 => [0.0, 1.0, x],
        3 => [0.0, x, 1.0],
        4 => [x, 0.0, 1.0],
        _ => [1.0, 0.0, x],
    };
    // Not too bright, not too dark (linear light).
    [r, gr, b].map(|c| 0.05 + 0.75 * c)
}

fn render_groups(tree: &TreeInput, path: &Path, size: (u32, u32), zoom: Option<(Vec3, f32)>) {
    let mut primitives: Vec<PreviewPrimitive> = tree
        .wood
        .iter()
        .map(|w| PreviewPrimitive::wood(w, [0.25, 0.17, 0.12]))
        .collect();
    primitives.extend(
        tree.needles
            .iter()
            .map(|n| PreviewPrimitive::needle(n, group_color(n.group))),
    );
    let triangles = mesh_triangles(&tree.wood_mesh, [0.25, 0.17, 0.12]);
    let camera = match zoom {
        Some((centre, half)) => PreviewCamera::framing(
            centre - Vec3::splat(half),
            centre + Vec3::splat(half),
            size.0,
            size.1,
            0.6,
        ),
        None => {
            let points = tree
                .needles
                .iter()
                .flat_map(|n| [n.base, n.tip])
                .chain(tree.wood_mesh.positions.iter().copied());
            let (lo, hi) = bevy_conifer_lod::model::bounds(points).expect("a tree");
            PreviewCamera::framing(lo, hi, size.0, size.1, 0.6)
        }
    };
    let options = PreviewOptions {
        samples_per_pixel_side: 3,
        ..Default::default()
    };
    let image = render_preview_scene(&primitives, &triangles, &camera, &options);
    image.save(path).expect("PNG written");
    println!("  wrote {}", path.display());
}

fn main() {
    let out = PathBuf::from("target/preview");
    std::fs::create_dir_all(&out).expect("target/preview");
    let fixture = std::env::args()
        .nth(1)
        .map(PathBuf::from)
        .unwrap_or_else(|| PathBuf::from("../shared/fixtures/small_pine_s0.glb"));

    println!("== {}", fixture.display());
    let started = Instant::now();
    let (tree, report) = import_gltf(&fixture, &ImportOptions::default()).expect("fixture imports");
    println!(
        "  {} needles, {} skipped, radius {:.2}/{:.2}/{:.2} mm, {} groups of {}/{}/{} ({:.2} s)",
        report.needles,
        report.skipped.total(),
        report.radius.min * 1e3,
        report.radius.median * 1e3,
        report.radius.max * 1e3,
        report.groups,
        report.group_size.min,
        report.group_size.median,
        report.group_size.max,
        started.elapsed().as_secs_f64()
    );
    println!("  groups: {:?}", report.group_source);
    // The fixture has no groups, but writes each twig's needles one after
    // another: a base more than 1 cm from the previous one starts a twig.
    let mut twig = 0u32;
    let twigs: Vec<u32> = tree
        .needles
        .iter()
        .enumerate()
        .map(|(i, n)| {
            if i > 0 && tree.needles[i - 1].base.distance(n.base) > 0.01 {
                twig += 1;
            }
            twig
        })
        .collect();
    let inferred: Vec<u32> = tree.needles.iter().map(|n| n.group).collect();
    let agreement = group_agreement(&twigs, &inferred);
    println!(
        "  against the file's {} twigs (needle order): purity {:.3}, completeness {:.3}, ARI {:.3}",
        twig + 1,
        agreement.purity,
        agreement.completeness,
        agreement.adjusted_rand_index
    );
    println!("  orientation: {:?}", report.orientation);
    render_groups(&tree, &out.join("fixture-groups.png"), (900, 1000), None);
    // A close-up of one twig-laden branch: around the needle at the median height.
    let mut heights: Vec<(f32, Vec3)> = tree.needles.iter().map(|n| (n.base.y, n.base)).collect();
    heights.sort_by(|a, b| a.0.total_cmp(&b.0));
    let centre = heights[heights.len() / 2].1;
    render_groups(
        &tree,
        &out.join("fixture-groups-closeup.png"),
        (800, 800),
        Some((centre, 0.45)),
    );

    for species in Species::ALL {
        println!("== {} (seed 1), written without groups, imported back", species.name());
        let truth_tree = generate(
            species,
            &GenerateOptions {
                seed: 1,
                target_needles: None,
                age: bevy_conifer_lod::generate::Age::Young,
            },
        );
        let glb = encode_tree_glb(&truth_tree, &TreeGlbOptions { groups: false });
        let (imported, report) =
            import_gltf_bytes(&glb, None, species.name(), &ImportOptions::default()).expect("preset imports");
        assert_eq!(imported.needles.len(), truth_tree.needles.len());
        // Match needles by centerline: the importer keeps the file's needle order.
        let truth: Vec<u32> = truth_tree.needles.iter().map(|n| n.group).collect();
        let inferred: Vec<u32> = imported.needles.iter().map(|n| n.group).collect();
        let agreement = group_agreement(&truth, &inferred);
        println!(
            "  {} needles, true groups {}, inferred {} (sizes {}/{}/{}); purity {:.3}, completeness {:.3}, ARI {:.3}",
            imported.needles.len(),
            truth_tree.group_count(),
            report.groups,
            report.group_size.min,
            report.group_size.median,
            report.group_size.max,
            agreement.purity,
            agreement.completeness,
            agreement.adjusted_rand_index
        );
        let flipped = truth_tree
            .needles
            .iter()
            .zip(&imported.needles)
            .filter(|(a, b)| a.base.distance(b.base) > a.base.distance(b.tip))
            .count();
        println!(
            "  base/tip recovered for {} of {} needles ({:?})",
            imported.needles.len() - flipped,
            imported.needles.len(),
            report.orientation
        );
        render_groups(
            &imported,
            &out.join(format!("{}-groups.png", species.name())),
            (700, 800),
            None,
        );
        // A close-up of the outer crown at mid height, where shoots are visible.
        let (lo, hi) = imported.needle_bounds().expect("needles");
        let mid_y = 0.5 * (lo.y + hi.y);
        let outer = imported
            .needles
            .iter()
            .filter(|n| (n.base.y - mid_y).abs() < 0.1 * (hi.y - lo.y))
            .max_by(|a, b| a.base.x.total_cmp(&b.base.x))
            .expect("needles at mid height");
        render_groups(
            &imported,
            &out.join(format!("{}-groups-closeup.png", species.name())),
            (600, 600),
            Some((outer.base - Vec3::X * 0.15, 0.2)),
        );
    }
}
