//! The LOD levels of a preset at the paper's Table 1 distances, like the
//! paper's Fig. 6: bakes the tree, prints what the cut draws at 12.22,
//! 26.71, 56.15 and 118.40 m (45° vertical FOV, 1536 px, ε = 1) next to the
//! paper's counts, those of the paper's weighted merge cost
//! (`MergeCostRule::Weighted`) and those of its cost and nested merge error
//! together (`MergeErrorBound::Nested`), baked beside ours, and renders each of our
//! cuts framed at a common size, side by
//! side, with the CPU preview rasterizer (merged lines drawn at the width
//! that keeps their needles' area); the second row colours the same cuts by
//! representation: prisms blue, original lines green, merged lines orange.
//!
//! ```text
//! cargo run --release --example lod_levels [species] [output.png]
//! ```

use bevy_conifer_lod::generate::{Age, GenerateOptions, Species, generate};
use bevy_conifer_lod::model::{BakeOptions, MergeCostRule, MergeErrorBound, PixelError, ViewParams, bake};
use bevy_conifer_lod::preview::{PreviewCamera, PreviewOptions, cut_primitives, render_preview};
use std::path::PathBuf;

const DISTANCES: [f32; 4] = [12.22, 26.71, 56.15, 118.40];
const PAPER_LINES: [u64; 4] = [23_310, 14_391, 6_212, 2_022];
const TILE: u32 = 384;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let mut args = std::env::args().skip(1);
    let species: Species = args.next().as_deref().unwrap_or("eastern-white-pine").parse()?;
    let output = args.next().map(PathBuf::from).unwrap_or_else(|| {
        PathBuf::from(env!("CARGO_MANIFEST_DIR")).join(format!("target/preview/{species}-lod-levels.png"))
    });
    if let Some(dir) = output.parent() {
        std::fs::create_dir_all(dir)?;
    }
    let young = GenerateOptions {
        age: Age::Young,
        ..GenerateOptions::default()
    };
    let tree = generate(species, &young);
    let record = bake(&tree, &BakeOptions::default(), &())?;
    let mut weighted_options = BakeOptions::default();
    weighted_options.merge.cost_rule = MergeCostRule::Weighted;
    let weighted = bake(&tree, &weighted_options, &())?;
    let mut paper_options = weighted_options;
    paper_options.merge.error_bound = MergeErrorBound::Nested;
    let paper_record = bake(&tree, &paper_options, &())?;
    let view = ViewParams {
        vertical_fov: 45f32.to_radians(),
        viewport_height_px: 1536.0,
        pixel_error: PixelError(1.0),
    };
    let (lo, hi) = record.bounds();
    let camera = PreviewCamera::framing(lo, hi, TILE, TILE, 0.6);
    let mut strip = image::RgbaImage::new(TILE * DISTANCES.len() as u32, 2 * TILE);
    println!(
        "{species}: {} needles in {} groups",
        record.needle_count(),
        record.group_count()
    );
    println!(
        "| distance | spatial error | prisms | original lines | merged lines | lines | lines, weighted cost | lines, weighted cost and nested error | paper's lines |"
    );
    println!("|---:|---:|---:|---:|---:|---:|---:|---:|---:|");
    for (i, (distance, paper)) in DISTANCES.into_iter().zip(PAPER_LINES).enumerate() {
        let e = view.spatial_error(distance);
        let cut = record.cut(e);
        let stats = record.cut_stats(&cut);
        let weighted_lines = weighted.cut_stats(&weighted.cut(e)).line_segments;
        let paper_model_lines = paper_record.cut_stats(&paper_record.cut(e)).line_segments;
        println!(
            "| {distance:.2} m | {:.1} mm | {} | {} | {} | {} | {weighted_lines} | {paper_model_lines} | {paper} |",
            e * 1e3,
            stats.prisms,
            stats.lines_original,
            stats.lines_merged,
            stats.line_segments
        );
        // The framed camera shows the cut larger than at `distance`; the
        // lines keep the width and opacity they would have there.
        let mut primitives = cut_primitives(&record, &cut, 1.0);
        let tile = render_preview(&primitives, &camera, &PreviewOptions::default());
        image::imageops::replace(&mut strip, &tile, (i as u32 * TILE) as i64, 0);
        // Same order as `cut_primitives`: wood, prisms, original lines, merged lines.
        let ranges = [cut.prisms.len(), cut.original_lines.len(), cut.merged_lines.len()];
        let colors = [[0.05, 0.15, 0.9], [0.1, 0.6, 0.1], [0.95, 0.4, 0.02]];
        let mut at = record.wood.len();
        for (count, color) in ranges.into_iter().zip(colors) {
            for primitive in &mut primitives[at..at + count] {
                primitive.color = color;
            }
            at += count;
        }
        let tile = render_preview(&primitives, &camera, &PreviewOptions::default());
        image::imageops::replace(&mut strip, &tile, (i as u32 * TILE) as i64, TILE as i64);
    }
    strip.save(&output)?;
    println!("wrote {}", output.display());
    Ok(())
}
