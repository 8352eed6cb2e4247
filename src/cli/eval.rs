//! `conifer eval`: every method against the supersampled reference, headless.

use super::parse_merge_error;
use crate::eval::inside::{InsideOptions, InsideReport, evaluate_inside};
use crate::eval::scene::{EvalLights, EvalSun, EvalTree, EvalView, Method};
use crate::eval::{EvalOptions, EvalReport, evaluate};
use crate::model::{read_prototype_record, read_record};
use crate::plugin::{LineLighting, LineOpacity, LineOrder, LineRaster, WoodLineOrder};
use anyhow::{Context, bail};
use std::path::PathBuf;

/// Arguments of `conifer eval`.
#[derive(Debug, clap::Args)]
pub struct EvalArgs {
    /// The record.
    pub file: PathBuf,
    /// Methods compared with the reference (paper, ours, raw, bevy-lod, sampling).
    #[arg(long, value_delimiter = ',', default_value = "paper,ours,raw,bevy-lod,sampling")]
    pub methods: Vec<String>,
    /// Distances from the crown centre, metres (default: the paper's Table 1
    /// distances; with --quick 12.22,56.15).
    #[arg(long, value_delimiter = ',')]
    pub distances: Vec<f32>,
    /// Picture size, `WIDTHxHEIGHT` (default 512x512; with --quick 160x160).
    #[arg(long)]
    pub size: Option<String>,
    /// Vertical field of view, degrees.
    #[arg(long, default_value_t = 45.0)]
    pub fov_deg: f32,
    /// Pixel error ε.
    #[arg(long, default_value_t = 1.0)]
    pub pixel_error: f32,
    /// Transition coefficient δ.
    #[arg(long, default_value_t = crate::plugin::ConiferLodSettings::default().transition)]
    pub transition: f32,
    /// Reference samples per pixel along each axis, at least 4 (default 8;
    /// with --quick 4). The reference also keeps 4× MSAA: at 8 the coverage
    /// error of `ours` is within 0.002 of its value at 12.
    #[arg(long)]
    pub supersampling: Option<u32>,
    /// Pictures along the near-to-far dolly (default 150; with --quick 16).
    #[arg(long)]
    pub dolly_steps: Option<usize>,
    /// Frames timed per method and distance (default 5; with --quick 2).
    #[arg(long)]
    pub frames: Option<usize>,
    /// Directory for the pictures, contact sheet and plots.
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// A CI-sized run: small pictures, two distances, a short dolly.
    #[arg(long)]
    pub quick: bool,
    /// `ours` keeps its lines at every distance (no crown impostor).
    #[arg(long)]
    pub ours_no_impostor: bool,
    /// Recompute the record's merged-line errors under this bound before
    /// measuring (`needles` or `nested`, the paper's; default: the record's
    /// own). The `paper` method always draws the record's needles merged again
    /// with the paper's weighted cost and `nested` error.
    #[arg(long, value_name = "BOUND", value_parser = parse_merge_error)]
    pub merge_error: Option<crate::model::MergeErrorBound>,
    /// Every camera renders into Bevy's 16-bit float main texture (`Hdr`)
    /// instead of the default 8-bit sRGB one.
    #[arg(long)]
    pub hdr: bool,
    /// The cameras write linear light clamped to [0, 1] instead of
    /// tone-mapping it (Bevy's default, TonyMcMapface): the background stays
    /// the clear colour with `--hdr` too.
    #[arg(long)]
    pub no_tonemapping: bool,
    /// The methods' cameras blend in 32-bit float: each renders linear
    /// light into an `Rgba32Float` target and is tone-mapped on the CPU as
    /// the reference is. Lavapipe rounds each blend into `--hdr`'s 16-bit
    /// float toward zero, which darkens a pixel under many translucent
    /// lines; a GPU rounding to nearest does not. Needs a device that
    /// multisamples `Rgba32Float` (lavapipe does).
    #[arg(long)]
    pub float_blending: bool,
    /// Shimmer under camera motion: an orbit (the camera circles the
    /// crown) and a lateral pan at each of these distances, metres (e.g.
    /// 12,56,250); reports each method's flicker_mean and flicker_p99.
    #[arg(long, value_delimiter = ',')]
    pub flicker_distances: Vec<f32>,
    /// Steps of each orbit (a full circle).
    #[arg(long, default_value_t = 120)]
    pub orbit_steps: usize,
    /// Steps of each pan (0.37 pixels at the crown a step).
    #[arg(long, default_value_t = 60)]
    pub pan_steps: usize,
    /// Wind strength (0 calm, 1 a light breeze, 3 strong), blowing across
    /// the view: the plugin's trees sway on the GPU, the reference and the
    /// peers by the CPU reference of the same field; the dolly's clock runs
    /// 1/30 s a step.
    #[arg(long)]
    pub wind: Option<f32>,
    /// Exit non-zero if `ours` is worse than `paper` on coverage error or
    /// popping, or if any method's render is blank (what CI runs).
    #[arg(long)]
    pub check: bool,
    /// Degrees the cameras stand above the crown centre's level, looking
    /// at it (negative: below; 0, level, as the paper's views): how the
    /// methods hold up seen from a hillside.
    #[arg(long, default_value_t = 0.0, allow_negative_numbers = true)]
    pub elevation: f32,
    /// The camera elevations over the crown, `START,END` degrees, across
    /// which `ours`'s impostor gives way to its lines
    /// (`ConiferLodSettings::impostor_steep_degrees`; default 30,45).
    #[arg(long, value_name = "START,END", value_parser = crate::model::impostor::parse_degree_band)]
    pub impostor_steep: Option<[f32; 2]>,
    /// Print the report as one JSON object on stdout (otherwise a table).
    #[arg(long)]
    pub json: bool,
    /// Where the sun stands: `front` (high, behind the camera), `side` (low,
    /// across the view) or `back` (low, behind the tree: back light).
    #[arg(long, default_value = "front")]
    pub sun: String,
    /// Which lights shine: `both` (the sun and the ambient light, as a
    /// game has them), `sun` or `ambient` alone (to tell which of them a
    /// method lights differently from the reference).
    #[arg(long, default_value = "both")]
    pub lights: String,
    /// How the plugin lights lines: `cylinder` (the default: every line as
    /// the cylinder along its chord), `bundle` (a merged line as its
    /// needles spread about its chord) or `facing-strip` (a strip turned
    /// toward the viewer).
    #[arg(long, default_value = "cylinder")]
    pub line_lighting: String,
    /// How the plugin rasterizes lines: `auto` (the default: `area` with
    /// `--hdr`, `hardware` without), `hardware` (one-pixel hardware lines,
    /// the paper's) or `area` (each pixel covered by the line's strip's
    /// area in it).
    #[arg(long, default_value = "auto")]
    pub line_raster: String,
    /// Where the plugin draws each tree's wood lines among its foliage
    /// lines: `layered` (the default: before and after them, split by the
    /// share of the wood the needles leave in sight) or `under-foliage`
    /// (once, before them).
    #[arg(long, default_value = "layered")]
    pub wood_lines: String,
    /// The order in which the plugin blends the lines of trees of shared
    /// prototypes: `back-to-front` (the default: each placement's lines on
    /// their own, the farthest first) or `by-prototype` (one instanced
    /// draw per prototype and band, in a fixed order).
    #[arg(long, default_value = "back-to-front")]
    pub line_order: String,
    /// The merged-line opacity `ours` draws with: `area` (the needles'
    /// summed area over the line's pixel area) or `coverage`
    /// (`1 − exp(−Σa/A)`).
    #[arg(long, default_value = "area")]
    pub ours_opacity: String,
    /// Instead of the distances: the camera in the crown, 2 m from the
    /// trunk at 40 % of the tree's height, the tree drawn as its shared
    /// prototypes with one error for the tree and with each placement's
    /// own, against the reference (`--methods`, `--distances`,
    /// `--elevation` and the dolly do not apply).
    #[arg(long)]
    pub inside: bool,
}

/// The paper's Table 1 distances (metres).
pub const TABLE1_DISTANCES: [f32; 4] = [12.22, 26.71, 56.15, 118.4];

pub(super) fn eval(args: &EvalArgs) -> anyhow::Result<()> {
    let methods = args
        .methods
        .iter()
        .map(|name| Method::from_name(name).with_context(|| format!("unknown method {name:?}")))
        .collect::<anyhow::Result<Vec<_>>>()?;
    let distances = if !args.distances.is_empty() {
        args.distances.clone()
    } else if args.quick {
        vec![12.22, 56.15]
    } else {
        TABLE1_DISTANCES.to_vec()
    };
    if distances.iter().any(|d| !d.is_finite() || *d <= 0.0) {
        bail!("distances must be positive metres, got {distances:?}");
    }
    let size = args
        .size
        .clone()
        .unwrap_or_else(|| if args.quick { "160x160" } else { "512x512" }.into());
    let (width, height) = super::commands::parse_size(&size)?;
    let supersampling = args.supersampling.unwrap_or(if args.quick { 4 } else { 8 });
    if supersampling < 4 {
        bail!("--supersampling must be at least 4 (the reference is 4x4 per pixel or finer)");
    }
    let sun = EvalSun::ALL
        .into_iter()
        .find(|s| s.name() == args.sun)
        .with_context(|| format!("--sun {:?}: the suns are front, side, back", args.sun))?;
    let lights = EvalLights::ALL
        .into_iter()
        .find(|l| l.name() == args.lights)
        .with_context(|| format!("--lights {:?}: both, sun or ambient", args.lights))?;
    let line_lighting = match args.line_lighting.as_str() {
        "bundle" => LineLighting::Bundle,
        "cylinder" => LineLighting::Cylinder,
        "facing-strip" => LineLighting::FacingStrip,
        other => bail!("--line-lighting {other:?}: bundle, cylinder or facing-strip"),
    };
    let line_raster = match args.line_raster.as_str() {
        "auto" => LineRaster::Auto,
        "area" => LineRaster::Area,
        "hardware" => LineRaster::Hardware,
        other => bail!("--line-raster {other:?}: auto, area or hardware"),
    };
    let wood_line_order = match args.wood_lines.as_str() {
        "layered" => WoodLineOrder::Layered,
        "under-foliage" => WoodLineOrder::UnderFoliage,
        other => bail!("--wood-lines {other:?}: layered or under-foliage"),
    };
    let line_order = match args.line_order.as_str() {
        "back-to-front" => LineOrder::BackToFront,
        "by-prototype" => LineOrder::ByPrototype,
        other => bail!("--line-order {other:?}: back-to-front or by-prototype"),
    };
    let ours_line_opacity = match args.ours_opacity.as_str() {
        "area" => LineOpacity::AreaPreserving,
        "coverage" => LineOpacity::Coverage,
        other => bail!("--ours-opacity {other:?}: area or coverage"),
    };
    let view = EvalView {
        width,
        height,
        fov_deg: args.fov_deg,
        pixel_error: args.pixel_error,
        transition: args.transition,
        supersampling,
        sun,
        lights,
        line_lighting,
        line_raster,
        wood_line_order,
        line_order,
        ours_line_opacity,
        ours_impostor: !args.ours_no_impostor,
        hdr: args.hdr,
        tonemapping: !args.no_tonemapping,
        float_blending: args.float_blending,
        elevation_deg: args.elevation,
        impostor_steep_degrees: args
            .impostor_steep
            .unwrap_or(crate::plugin::ConiferLodSettings::default().impostor_steep_degrees),
    };
    if args.inside {
        if let Some(bound) = args.merge_error {
            bail!(
                "--merge-error {} recomputes a flattened record's errors; --inside draws the record's own",
                bound.name()
            );
        }
        let record = read_prototype_record(&args.file)
            .with_context(|| format!("{}: cannot load record", args.file.display()))?;
        let options = InsideOptions {
            out_dir: args.out.clone(),
            ..InsideOptions::new(view)
        };
        let report = evaluate_inside(&record, &options, &mut |line| eprintln!("eval: {line}"))
            .with_context(|| format!("{}: evaluation failed", args.file.display()))?;
        if args.json {
            println!("{}", serde_json::to_string(&serde_json::json!({ "inside": report }))?);
        } else {
            print_inside(&report);
        }
        return Ok(());
    }
    // A tree of shared prototypes is drawn by its placements, as a game
    // loading the record draws it; recomputed merge errors are the
    // flattened record's.
    let tree: EvalTree = match args.merge_error {
        Some(bound) => read_record(&args.file)
            .with_context(|| format!("{}: cannot load record", args.file.display()))?
            .with_error_bound(bound)
            .with_context(|| format!("{}: cannot recompute its merge errors", args.file.display()))?
            .into(),
        None => read_prototype_record(&args.file)
            .with_context(|| format!("{}: cannot load record", args.file.display()))?
            .into(),
    };
    let options = EvalOptions {
        methods,
        distances,
        view,
        dolly_steps: args.dolly_steps.unwrap_or(if args.quick { 16 } else { 150 }),
        timed_frames: args.frames.unwrap_or(if args.quick { 2 } else { 5 }),
        out_dir: args.out.clone(),
        wind: args.wind,
        flicker_distances: args.flicker_distances.clone(),
        orbit_steps: args.orbit_steps,
        pan_steps: args.pan_steps,
    };
    let report = evaluate(tree, &options, &mut |line| eprintln!("eval: {line}"))
        .with_context(|| format!("{}: evaluation failed", args.file.display()))?;
    if args.json {
        println!("{}", serde_json::to_string(&report)?);
    } else {
        print_table(&report);
    }
    if args.check {
        let failures = report.check();
        if !failures.is_empty() {
            bail!("eval check failed:\n  {}", failures.join("\n  "));
        }
        eprintln!(
            "eval: check passed (ours no worse than paper on coverage and popping; ours' shadow error within {}; no blank render)",
            crate::eval::SHADOW_ERROR_LIMIT
        );
    }
    Ok(())
}

/// The report as a Markdown table (the README's form).
pub fn print_table(report: &EvalReport) {
    println!(
        "| method | distance (m) | coverage error | coverage bias, crown / fringe | colour error | crown colour error | crown shade error | FLIP | shadow error | triangles | lines | primitives | frame ms |"
    );
    println!("|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|");
    for (name, method) in &report.methods {
        for d in &method.distances {
            println!(
                "| {name} | {:.2} | {:.4} | {:+.4} / {:+.4} | {:.2} | {:.2} | {:.2} ({:.0} %) | {:.3} | {} | {} | {} | {} | {:.1} |",
                d.distance,
                d.coverage_error,
                d.coverage_bias.crown,
                d.coverage_bias.fringe,
                d.color_error,
                d.crown_color_error,
                d.crown_shade.error,
                100.0 * d.crown_shade.compared,
                d.perceptual,
                d.shadow_coverage_error.map_or("–".to_string(), |e| format!("{e:.4}")),
                d.triangles,
                d.lines,
                d.primitives,
                d.frame_ms
            );
        }
    }
    println!();
    println!("| reference | distance (m) | mean coverage | crown see-through |");
    println!("|---|---:|---:|---:|");
    for d in &report.reference.distances {
        println!(
            "| reference | {:.2} | {:.4} | {} |",
            d.distance,
            d.mean_coverage,
            d.crown_see_through.map_or("–".to_string(), |s| format!("{s:.3}"))
        );
    }
    println!();
    println!("| method | popping max | popping p99 |");
    println!("|---|---:|---:|");
    for (name, method) in &report.methods {
        println!("| {name} | {:.2} | {:.2} |", method.popping_max, method.popping_p99);
    }
    if report.methods.values().any(|m| !m.flicker.is_empty()) {
        println!();
        println!("| method | path | distance (m) | flicker mean | flicker p99 | mean change |");
        println!("|---|---|---:|---:|---:|---:|");
        for (name, method) in &report.methods {
            for f in &method.flicker {
                println!(
                    "| {name} | {} | {:.1} | {:.3} | {:.3} | {:.3} |",
                    f.path.name(),
                    f.distance,
                    f.flicker_mean,
                    f.flicker_p99,
                    f.mean_change
                );
            }
        }
        for f in &report.reference.flicker {
            println!(
                "| reference | {} | {:.1} | – | – | {:.3} |",
                f.path.name(),
                f.distance,
                f.mean_change
            );
        }
    }
}

fn print_inside(report: &InsideReport) {
    let [x, y, z] = report.camera;
    println!(
        "{:.1} m tree, {} needles; camera at ({x:.1}, {y:.1}, {z:.1}) m, {}x{} at {}°; {} needles within 1 m",
        report.tree_height, report.needles, report.width, report.height, report.fov_deg, report.near_needles
    );
    println!(
        "{:<10} {:>9} {:>8} {:>8} {:>10} {:>10} {:>10} {:>12} {:>12}",
        "errors", "coverage", "colour", "FLIP", "prisms", "lines", "merged", "primitives", "coarse near"
    );
    for m in &report.methods {
        println!(
            "{:<10} {:>9.4} {:>8.2} {:>8.4} {:>10} {:>10} {:>10} {:>12} {:>12}",
            format!("per {}", m.error_scope),
            m.coverage_error,
            m.color_error,
            m.perceptual,
            m.prisms,
            m.original_lines,
            m.merged_lines,
            m.primitives,
            m.coarse_near_needles
        );
    }
}
