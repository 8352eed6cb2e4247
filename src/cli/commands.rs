//! The subcommands of `conifer`.

use super::{BakeArgs, CutArgs, ExportArgs, InspectArgs, PreviewArgs, ViewArgs};
use crate::export::write_cut_glb;
use crate::generate::{GenerateOptions, Species, generate, generate_prototypes};
use crate::import::{ImportOptions, ImportReport, import_gltf_prototypes};
use crate::model::calibration::CalibrationOptions;
use crate::model::compact::{CompactSpecies, threshold_code};
use crate::model::file::FORMAT_VERSION;
use crate::model::merge::PartnerSearch;
use crate::model::metric::{PixelError, ViewParams, line_opacity, relative_error};
use crate::model::record::{ErrorRange, LodRecord};
use crate::model::{
    BakeOptions, BakeProgress, BakeStage, MergeWeights, PrototypeInput, PrototypeRecord, read_record,
    write_prototype_record,
};
use crate::preview::{PreviewCamera, PreviewOptions, cut_primitives, mesh_triangles, render_preview_scene};
use anyhow::{Context, bail};
use glam::Vec3;
use indicatif::{MultiProgress, ProgressBar, ProgressStyle};
use serde::Serialize;
use std::collections::BTreeMap;
use std::path::Path;
use std::time::{Duration, Instant};

/// Progress bars for a bake, drawn on stderr only when it is a terminal.
struct BakeBars {
    groups: ProgressBar,
    tree: ProgressBar,
    impostor: ProgressBar,
    calibration: ProgressBar,
}

impl BakeBars {
    fn new() -> Self {
        let multi = MultiProgress::new();
        let style = ProgressStyle::with_template("{prefix:>14} [{bar:40}] {pos}/{len} merges ({elapsed})")
            .expect("valid template")
            .progress_chars("=> ");
        let bar = |prefix: &'static str| {
            let bar = multi.add(ProgressBar::new(0).with_style(style.clone()).with_prefix(prefix));
            bar.enable_steady_tick(Duration::from_millis(200));
            bar
        };
        // A stage of one step (0 when it starts, 1 when it ends).
        let one_step = |prefix: &'static str, what: &str| {
            let template = format!("{{prefix:>14}} [{{bar:40}}] {{pos}}/{{len}} {what} ({{elapsed}})");
            multi.add(
                ProgressBar::new(1)
                    .with_style(
                        ProgressStyle::with_template(&template)
                            .expect("valid template")
                            .progress_chars("=> "),
                    )
                    .with_prefix(prefix),
            )
        };
        // Added in this order, as before: the one-step bars above the merges'.
        let impostor = one_step("far", "impostor");
        let calibration = one_step("calibration", "line opacity");
        Self {
            groups: bar("groups"),
            tree: bar("whole tree"),
            impostor,
            calibration,
        }
    }
}

impl BakeProgress for BakeBars {
    fn progress(&self, stage: BakeStage, done: usize, total: usize) {
        let bar = match stage {
            BakeStage::MergeGroups => &self.groups,
            BakeStage::MergeTree => &self.tree,
            BakeStage::Impostor => &self.impostor,
            BakeStage::LineCalibration => &self.calibration,
        };
        bar.set_length(total as u64);
        bar.set_position(done as u64);
    }
}

/// Summary printed by `conifer bake --json`.
#[derive(Serialize)]
struct BakeReport<'a> {
    output: &'a Path,
    /// Needles once placed.
    needles: usize,
    /// Phyllotaxy groups: placed prototypes.
    groups: usize,
    /// Shared prototypes.
    prototypes: usize,
    /// Needles stored in the prototypes.
    prototype_needles: usize,
    lines_merged: usize,
    bytes: u64,
    bytes_per_needle: f64,
    generate_seconds: f64,
    bake_seconds: f64,
    /// The bake split into merge level 1, level 2 and the record.
    stages: crate::model::StageSeconds,
    write_seconds: f64,
    /// Peak resident memory of the process (Linux `VmHWM`), if known.
    peak_bytes: Option<u64>,
    /// What the glTF import found (glTF input only).
    #[serde(skip_serializing_if = "Option::is_none")]
    import: Option<&'a ImportReport>,
}

pub(super) fn bake(args: &BakeArgs) -> anyhow::Result<()> {
    let started = Instant::now();
    let mut import_report = None;
    let input = match (&args.preset, &args.input) {
        (Some(name), _) => {
            let species: Species = name.parse().map_err(|e| anyhow::anyhow!("--preset {name}: {e}"))?;
            let target_needles = match &args.needles[..] {
                [] => None,
                [count] => Some(
                    count
                        .parse::<usize>()
                        .map_err(|_| anyhow::anyhow!("--needles with --preset takes a needle count, got {count:?}"))?,
                ),
                _ => bail!("--needles with --preset takes one needle count"),
            };
            if target_needles == Some(0) {
                bail!("--needles with --preset takes a needle count above 0");
            }
            let options = GenerateOptions {
                seed: args.seed,
                target_needles,
                age: args.age,
            };
            let mut input = if args.flat {
                PrototypeInput::from_tree(&generate(species, &options))
            } else {
                generate_prototypes(species, &options)
            };
            input.name = species.name().to_string();
            input
        }
        (None, Some(path)) => {
            let options = ImportOptions {
                needle_names: args.needles.clone(),
                scale: args.scale,
                ..Default::default()
            };
            let (input, report) = import_gltf_prototypes(path, &options)
                .with_context(|| format!("{}: cannot import glTF", path.display()))?;
            if !args.json {
                print_import(path, &report);
            }
            import_report = Some(report);
            input
        }
        (None, None) => bail!("give an input file or --preset NAME"),
    };
    let generate_seconds = started.elapsed().as_secs_f64();
    let [direction, distance, needle_count] = args.weights[..] else {
        bail!("--weights takes three numbers k1,k2,k3");
    };
    let impostor_valid = args.impostor_texel > 0.0 && args.impostor_texel.is_finite() && args.impostor_views > 0;
    if !(args.no_impostor || impostor_valid) {
        bail!("--impostor-texel takes a positive number of metres and --impostor-views a positive count");
    }
    let calibration = calibration_options(args.calibration_elevation)?;
    let mut options = BakeOptions {
        max_sides: args.max_sides,
        impostor: (!args.no_impostor).then_some(crate::model::impostor::ImpostorOptions {
            views: args.impostor_views,
            texel: args.impostor_texel,
        }),
        line_calibration: (!args.no_line_calibration).then_some(calibration),
        ..Default::default()
    };
    options.merge.weights = MergeWeights {
        direction,
        distance,
        needle_count,
    };
    options.merge.error_bound = args.merge_error;
    options.merge.cost_rule = args.merge_cost;
    options.merge.tree_search = if args.exhaustive {
        PartnerSearch::Exhaustive
    } else {
        PartnerSearch::Nearest {
            neighbours: args.neighbours.max(1),
        }
    };
    let bars = BakeBars::new();
    let timer = crate::model::StageTimer::new(&bars);
    let bake_started = Instant::now();
    let mut record =
        crate::model::bake_prototypes(&input, &options, &timer).with_context(|| format!("baking {}", input.name))?;
    let stages = timer.seconds(bake_started.elapsed().as_secs_f64());
    bars.groups.finish_and_clear();
    bars.tree.finish_and_clear();
    bars.impostor.finish_and_clear();
    record.bake.source = match (&args.preset, &args.input) {
        (Some(name), _) => format!("preset {name} seed {}", args.seed),
        (None, Some(path)) => path.display().to_string(),
        (None, None) => String::new(),
    };
    let write_started = Instant::now();
    let bytes = write_prototype_record(&record, &args.output)
        .with_context(|| format!("{}: cannot write record", args.output.display()))?;
    let needles = record.needle_count() as usize;
    let report = BakeReport {
        output: &args.output,
        needles,
        groups: record.placements.len(),
        prototypes: record.prototypes.len(),
        prototype_needles: record.prototype_needle_count() as usize,
        lines_merged: needles - record.placements.len() + record.tree_merged.len(),
        bytes,
        bytes_per_needle: bytes as f64 / needles as f64,
        generate_seconds,
        bake_seconds: record.bake.bake_seconds.unwrap_or(0.0),
        stages,
        write_seconds: write_started.elapsed().as_secs_f64(),
        peak_bytes: peak_resident_bytes(),
        import: import_report.as_ref(),
    };
    if args.json {
        println!("{}", serde_json::to_string_pretty(&report)?);
    } else {
        eprintln!(
            "baked {} needles in {} groups ({} prototypes of {} needles) ({} merged lines) in {:.2} s → {} ({} bytes, {:.1} bytes/needle)",
            report.needles,
            report.groups,
            report.prototypes,
            report.prototype_needles,
            report.lines_merged,
            report.bake_seconds,
            args.output.display(),
            bytes,
            report.bytes_per_needle
        );
    }
    Ok(())
}

/// Peak resident memory of this process so far (`VmHWM` of
/// `/proc/self/status`); `None` where that is not available.
pub fn peak_resident_bytes() -> Option<u64> {
    let status = std::fs::read_to_string("/proc/self/status").ok()?;
    let line = status.lines().find(|l| l.starts_with("VmHWM:"))?;
    let kib: u64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kib * 1024)
}

/// The import summary, on stderr.
fn print_import(path: &Path, report: &ImportReport) {
    let source = match &report.group_source {
        crate::import::GroupSource::Attribute(name) => format!("from the {name} attribute"),
        crate::import::GroupSource::Primitives => "one per needle primitive".to_string(),
        crate::import::GroupSource::Inferred(info) => format!(
            "inferred (base spacing {:.1} mm, link distance {:.1} mm, {} long pieces cut)",
            info.base_spacing * 1e3,
            info.link_distance * 1e3,
            info.pieces_cut
        ),
    };
    eprintln!(
        "{}: {} needles from {}; {} wood triangles from {} primitive(s)",
        path.display(),
        report.needles,
        report.needle_primitives.join(", "),
        report.wood_triangles,
        report.wood_primitives
    );
    eprintln!(
        "  radius {:.2} / {:.2} / {:.2} mm, length {:.1} / {:.1} / {:.1} mm (min / median / max)",
        report.radius.min * 1e3,
        report.radius.median * 1e3,
        report.radius.max * 1e3,
        report.length.min * 1e3,
        report.length.median * 1e3,
        report.length.max * 1e3
    );
    eprintln!(
        "  {} groups {source}, {} / {} / {} needles each",
        report.groups, report.group_size.min, report.group_size.median, report.group_size.max
    );
    if report.prototypes < report.groups {
        eprintln!(
            "  instanced needle meshes kept: {} groups are {} shared prototypes",
            report.groups, report.prototypes
        );
    }
    for warning in &report.warnings {
        eprintln!("  warning: {warning}");
    }
}

/// The line calibration's options for `--calibration-elevation` (degrees,
/// from 0 to under 90; 0 is level views only, the default).
fn calibration_options(elevation_degrees: f32) -> anyhow::Result<CalibrationOptions> {
    if !(0.0..90.0).contains(&elevation_degrees) {
        bail!("--calibration-elevation takes degrees from 0 to under 90");
    }
    Ok(CalibrationOptions {
        elevation_degrees,
        ..Default::default()
    })
}

fn load(path: &Path) -> anyhow::Result<LodRecord> {
    read_record(path).with_context(|| format!("{}: cannot load record", path.display()))
}

/// `conifer upgrade`: rewrites records in the current format, in place.
pub(super) fn upgrade(args: &super::UpgradeArgs) -> anyhow::Result<()> {
    let elevation = args.calibration_elevation;
    let calibration = calibration_options(elevation.unwrap_or(0.0))?;
    if elevation.is_some() && args.no_line_calibration {
        bail!("--calibration-elevation calibrates the lines again; --no-line-calibration leaves them");
    }
    for path in &args.files {
        let bytes = std::fs::read(path).with_context(|| format!("{}: cannot read", path.display()))?;
        let version = bytes
            .get(8..12)
            .map(|v| u32::from_le_bytes(v.try_into().expect("4 bytes")));
        let mut record: PrototypeRecord = crate::model::decode_prototype_record(&bytes)
            .with_context(|| format!("{}: cannot load record", path.display()))?;
        if version == Some(FORMAT_VERSION) && elevation.is_none() {
            eprintln!("{}: already format {FORMAT_VERSION}", path.display());
            continue;
        }
        // Format 12 measures the impostor and the line calibration against
        // the needles' capped silhouettes: older ones are baked again.
        let measured_without_caps = version.is_none_or(|v| v < 12);
        let rebake = (record.impostor.is_none() || measured_without_caps) && !args.no_impostor;
        if rebake {
            record.impostor = crate::model::bake_impostor(&record, Default::default());
        }
        // Format 13 stores how densely the needles fill the impostor's
        // crown, format 14 the ages and sides of the needles its views
        // see, format 15 how bright those needles are lit against its
        // texels: an older impostor's are measured from the needles (a
        // fresh bake measured them already).
        let measure_scale = !rebake && version.is_none_or(|v| v < 15);
        let measure_seen = measure_scale && version.is_none_or(|v| v < 14);
        let measure_density = measure_seen && version.is_none_or(|v| v < 13);
        if let Some(impostor) = record.impostor.as_deref().filter(|_| measure_scale) {
            let needles = record.placed_needles();
            let density = measure_density.then(|| crate::model::impostor::CrownDensity::measure(&needles, impostor));
            let seen = measure_seen.then(|| crate::model::color::NeedleMix::seen(&record, &needles, impostor));
            let scale = impostor.view_light_scale(&record.wood, &needles);
            if let Some(impostor) = record.impostor.as_mut().map(std::sync::Arc::make_mut) {
                if let Some(density) = density {
                    impostor.crown_density = density;
                }
                if let Some(seen) = seen {
                    impostor.seen_needles = seen;
                }
                impostor.view_light_scale = Some(scale);
            }
        }
        if (record.line_calibration.is_none() || measured_without_caps || elevation.is_some())
            && !args.no_line_calibration
        {
            record.line_calibration = crate::model::bake::calibrate_record_lines(&record, &calibration)
                .with_context(|| format!("{}: cannot calibrate its lines", path.display()))?;
        }
        let written = write_prototype_record(&record, path)
            .with_context(|| format!("{}: cannot write record", path.display()))?;
        eprintln!(
            "{}: format {} → {FORMAT_VERSION}, {} → {written} bytes",
            path.display(),
            version.unwrap_or(0),
            bytes.len()
        );
    }
    Ok(())
}

/// Smallest, median and largest of a set of numbers.
pub type MinMedianMax = crate::import::Spread;

/// What `conifer inspect --json` prints.
#[derive(Debug, Serialize)]
pub struct InspectReport {
    /// Tree name.
    pub name: String,
    /// Where the tree came from.
    pub source: String,
    /// Record format version of the file (older ones are converted on load).
    pub format_version: u32,
    /// Needle count (once the prototypes are placed).
    pub needles: usize,
    /// Phyllotaxy groups (placed prototypes).
    pub groups: usize,
    /// Shared prototypes.
    pub prototypes: usize,
    /// Needles stored in the prototypes.
    pub prototype_needles: u64,
    /// Original lines (one per needle).
    pub lines_original: usize,
    /// Merged lines.
    pub lines_merged: usize,
    /// Roots of the merge forest.
    pub roots: usize,
    /// Lmax.
    pub max_sides: u8,
    /// Wood segments.
    pub wood_segments: usize,
    /// Triangles of the wood mesh (imported trees).
    pub wood_triangles: usize,
    /// `[min, max]` error of each part, metres.
    pub error_ranges: BTreeMap<&'static str, [f32; 2]>,
    /// Needle radius, metres.
    pub radius: MinMedianMax,
    /// Needle length, metres.
    pub length: MinMedianMax,
    /// Needles per group.
    pub group_size: MinMedianMax,
    /// Tree height (bounding box), metres.
    pub height: f32,
    /// File size.
    pub bytes: u64,
    /// File size per needle.
    pub bytes_per_needle: f64,
    /// Bake time, if recorded.
    pub bake_seconds: Option<f64>,
    /// Merge weights k1, k2, k3.
    pub weights: [f32; 3],
    /// The crown impostor stored in the record, if any.
    pub impostor: Option<ImpostorSummary>,
    /// Linear RGB the far representations (the tree's merged lines, the
    /// impostor) colour its needles with
    /// ([`crate::model::color::far_needle_color`]).
    pub far_needle_color: [f32; 3],
    /// The line opacity scales by pixel size stored in the record, if any
    /// ([`crate::model::calibration::LineCalibration`]).
    pub line_calibration: Option<crate::model::calibration::LineCalibration>,
}

/// A record's crown impostor in `conifer inspect`.
#[derive(Debug, Serialize)]
pub struct ImpostorSummary {
    /// Views around the trunk.
    pub views: u32,
    /// Texels across.
    pub columns: u32,
    /// Texels up.
    pub rows: u32,
    /// Side of a texel, metres.
    pub texel: f32,
    /// Bytes of its texels and mip levels on the GPU.
    pub gpu_bytes: u64,
    /// The needles its views see first by age class (this year's, last
    /// year's, mature), each `[share, share × underside shown]`
    /// ([`crate::model::color::NeedleMix`]); `None` in an older record or
    /// a tree without ages.
    pub seen_needles: Option<[[f32; 2]; crate::model::color::NEEDLE_AGE_CLASSES]>,
    /// How its direct light is scaled by the light's direction in the
    /// view's frame (`[angle][roll]`,
    /// [`crate::model::impostor::ViewLightScale`]); `None` in an older
    /// record.
    pub view_light_scale:
        Option<[[f32; crate::model::impostor::VIEW_LIGHT_ROLLS]; crate::model::impostor::VIEW_LIGHT_ANGLES]>,
}

pub(super) fn inspect(args: &InspectArgs) -> anyhow::Result<()> {
    let path = &args.file;
    let file = std::fs::read(path).with_context(|| format!("{}: cannot load record", path.display()))?;
    let prototypes = crate::model::decode_prototype_record(&file)
        .with_context(|| format!("{}: cannot load record", path.display()))?;
    let record = prototypes
        .flatten()
        .with_context(|| format!("{}: cannot load record", path.display()))?;
    let bytes = file.len() as u64;
    let ranges = record.part_ranges();
    let pair = |r: ErrorRange| [r.min, r.max];
    let mut error_ranges = BTreeMap::new();
    error_ranges.insert("cylinders", pair(ranges.cylinders));
    error_ranges.insert("original_lines", pair(ranges.original_lines));
    if let Some(merged) = ranges.merged_lines {
        error_ranges.insert("merged_lines", pair(merged));
    }
    let mut group_sizes = vec![0f64; record.group_count()];
    for needle in &record.needles {
        group_sizes[needle.group as usize] += 1.0;
    }
    let (lo, hi) = record.bounds();
    let w = record.bake.weights;
    let report = InspectReport {
        name: record.name.clone(),
        source: record.bake.source.clone(),
        format_version: u32::from_le_bytes(file[8..12].try_into().expect("a decoded record has a header")),
        needles: record.needle_count(),
        groups: record.group_count(),
        prototypes: prototypes.prototypes.len(),
        prototype_needles: prototypes.prototype_needle_count(),
        lines_original: record.needle_count(),
        lines_merged: record.merged.len(),
        roots: record.roots().len(),
        max_sides: record.max_sides,
        wood_segments: record.wood.len(),
        wood_triangles: record.wood_mesh.triangle_count(),
        error_ranges,
        radius: MinMedianMax::of(record.needles.iter().map(|n| n.radius as f64).collect()),
        length: MinMedianMax::of(record.needles.iter().map(|n| n.length() as f64).collect()),
        group_size: MinMedianMax::of(group_sizes),
        height: hi.y - lo.y,
        bytes,
        bytes_per_needle: bytes as f64 / record.needle_count() as f64,
        bake_seconds: record.bake.bake_seconds,
        weights: [w.direction, w.distance, w.needle_count],
        impostor: prototypes.impostor.as_deref().map(|i| ImpostorSummary {
            views: i.views,
            columns: i.columns,
            rows: i.rows,
            texel: i.texel,
            gpu_bytes: i.byte_size(),
            seen_needles: i.seen_needles.map(|mix| mix.by_age),
            view_light_scale: i.view_light_scale.map(|scale| scale.scales),
        }),
        far_needle_color: crate::model::color::far_needle_color(&prototypes).to_array(),
        line_calibration: prototypes.line_calibration,
    };
    if args.json {
        println!("{}", serde_json::to_string_pretty(&report)?);
    } else {
        println!("{} ({})", report.name, report.source);
        println!(
            "  needles {} in {} groups ({} prototypes of {} needles), {} merged lines, {} roots",
            report.needles,
            report.groups,
            report.prototypes,
            report.prototype_needles,
            report.lines_merged,
            report.roots
        );
        println!("  format version {}", report.format_version);
        for (part, [min, max]) in &report.error_ranges {
            println!("  {part:>15}: error {min:.6} .. {max:.6} m");
        }
        match &report.impostor {
            Some(i) => println!(
                "  crown impostor: {} views of {} × {} texels of {:.3} m ({} bytes on the GPU)",
                i.views, i.columns, i.rows, i.texel, i.gpu_bytes
            ),
            None => println!("  no crown impostor (the plugin bakes one at load)"),
        }
        if let Some(scales) = report.impostor.as_ref().and_then(|i| i.view_light_scale) {
            let scale = crate::model::impostor::ViewLightScale { scales };
            let at = |x: f32, y: f32, z: f32| scale.at(glam::Vec3::new(x, y, z));
            println!(
                "  impostor light scale: sun behind the camera {:.3}, above {:.3}, beside {:.3}, behind the tree {:.3}",
                at(0.0, 0.0, 1.0),
                at(0.0, 1.0, 0.0),
                at(1.0, 0.0, 0.0),
                at(0.0, 0.0, -1.0)
            );
        }
        let [r, g, b] = report.far_needle_color;
        println!(
            "  far needle colour {r:.4} {g:.4} {b:.4} (linear){}",
            if report.impostor.as_ref().is_some_and(|i| i.seen_needles.is_some()) {
                ", of the needles the impostor sees"
            } else {
                ", the needles' area mean"
            }
        );
        match &report.line_calibration {
            Some(c) => println!(
                "  line opacity scales {} at pixels of {:.4} .. {:.4} m; wood lines' by size at opacities 1/64, 1/16, 1/4, 1: {}",
                c.scales.map(|s| format!("{s:.3}")).join(" "),
                c.first_pixel,
                c.last_pixel,
                c.wood_scales
                    .map(|row| row.map(|s| format!("{s:.2}")).join(" "))
                    .join(" | "),
            ),
            None => println!("  no line calibration (every line keeps its opacity)"),
        }
        println!("  {} bytes ({:.1} per needle)", report.bytes, report.bytes_per_needle);
    }
    Ok(())
}

/// What `conifer cut --json` prints.
#[derive(Debug, Serialize)]
pub struct CutReport {
    /// Viewing distance, metres.
    pub distance: f32,
    /// Spatial error e, metres.
    pub spatial_error: f32,
    /// Needles drawn as prisms.
    pub prisms: u64,
    /// Prisms by side count.
    pub prism_sides: BTreeMap<u8, u64>,
    /// Original lines drawn.
    pub lines_original: u64,
    /// Merged lines drawn.
    pub lines_merged: u64,
    /// Needles stood for by the cut.
    pub needles_covered: u64,
    /// Needles in the record.
    pub needles: usize,
    /// Prism triangles.
    pub triangles: u64,
    /// Line segments.
    pub line_segments: u64,
    /// Triangles plus line segments.
    pub primitives: u64,
    /// Mean opacity of the original lines drawn, `δ · 2/ρ` (paper), or null.
    pub mean_original_line_opacity: Option<f32>,
    /// Lines (original, merged and wood) in the prefixes the plugin's
    /// indirect draws cover at this error in the flat layout (a record made
    /// in code and handed to `ConiferSpecies::from_record`): what its vertex
    /// shaders run on (null when the record does not fit the GPU layout).
    pub gpu_lines_processed: Option<u64>,
    /// Primitives (prisms and needle lines) the plugin processes at this
    /// error in the layout its asset loader builds for this file (the
    /// record's prototypes placed, `CompactSpecies::build_placed`), every
    /// placement at the view's error: the level-2 prefix and each expanded
    /// placement's prototype prefixes (null when the record does not fit
    /// that layout, or for `conifer preview`).
    pub gpu_placed_primitives_processed: Option<u64>,
    /// All lines of the plugin's GPU arrays (null as above).
    pub gpu_lines_total: Option<u64>,
}

pub(super) fn view_params(view: &ViewArgs) -> ViewParams {
    ViewParams {
        vertical_fov: view.fov_deg.to_radians(),
        viewport_height_px: view.height_px,
        pixel_error: PixelError(view.pixel_error),
    }
}

/// The cut report of `record` seen from `view`.
pub(crate) fn cut_report(record: &LodRecord, prototypes: Option<&PrototypeRecord>, view: &ViewArgs) -> CutReport {
    let e = view_params(view).spatial_error(view.distance);
    let placed_processed = prototypes.and_then(|prototypes| {
        let compact = CompactSpecies::build_placed(prototypes).ok()?;
        Some(
            compact
                .placed_drawn(prototypes, threshold_code(e), e, threshold_code, None)
                .1,
        )
    });
    let cut = record.cut(e);
    let stats = record.cut_stats(&cut);
    let compact = CompactSpecies::build(record).ok();
    let opacity_sum: f32 = cut
        .original_lines
        .iter()
        .map(|&i| line_opacity(relative_error(e, record.needles[i as usize].radius), view.transition))
        .sum();
    CutReport {
        distance: view.distance,
        spatial_error: e,
        prisms: stats.prisms,
        prism_sides: stats.prism_sides.clone(),
        lines_original: stats.lines_original,
        lines_merged: stats.lines_merged,
        needles_covered: stats.needles_covered,
        needles: record.needle_count(),
        triangles: stats.triangles,
        line_segments: stats.line_segments,
        primitives: stats.primitives(),
        mean_original_line_opacity: (!cut.original_lines.is_empty())
            .then(|| opacity_sum / cut.original_lines.len() as f32),
        gpu_lines_processed: compact.as_ref().map(|c| {
            let p = c.prefixes(threshold_code(e), e);
            u64::from(p.original_lines + p.merged_lines + p.wood_lines - p.wood_prisms)
        }),
        gpu_lines_total: compact
            .as_ref()
            .map(|c| (c.needles.len() + c.merged_lines.len() + c.wood_segments.len()) as u64),
        gpu_placed_primitives_processed: placed_processed,
    }
}

pub(super) fn cut(args: &CutArgs) -> anyhow::Result<()> {
    check_view(&args.view)?;
    let prototypes = crate::model::read_prototype_record(&args.file)
        .with_context(|| format!("{}: cannot load record", args.file.display()))?;
    let record = prototypes
        .flatten()
        .with_context(|| format!("{}: cannot load record", args.file.display()))?;
    let report = cut_report(&record, Some(&prototypes), &args.view);
    if args.json {
        println!("{}", serde_json::to_string_pretty(&report)?);
    } else {
        println!(
            "e = {:.6} m at {} m: {} prisms ({} triangles), {} original lines, {} merged lines; {} of {} needles covered",
            report.spatial_error,
            report.distance,
            report.prisms,
            report.triangles,
            report.lines_original,
            report.lines_merged,
            report.needles_covered,
            report.needles
        );
    }
    Ok(())
}

pub(super) fn check_view(view: &ViewArgs) -> anyhow::Result<()> {
    if !(view.distance.is_finite() && view.distance >= 0.0) {
        bail!("--distance must be a finite number ≥ 0, got {}", view.distance);
    }
    if !(view.fov_deg > 0.0 && view.fov_deg < 180.0) {
        bail!("--fov-deg must be in (0, 180), got {}", view.fov_deg);
    }
    if !(view.height_px >= 1.0 && view.height_px.is_finite()) {
        bail!("--height-px must be at least 1, got {}", view.height_px);
    }
    if !(view.pixel_error > 0.0 && view.pixel_error.is_finite()) {
        bail!("--pixel-error must be > 0, got {}", view.pixel_error);
    }
    if !(view.transition > 0.0 && view.transition <= 1.0) {
        bail!("--transition must be in (0, 1], got {}", view.transition);
    }
    Ok(())
}

pub(super) fn parse_size(size: &str) -> anyhow::Result<(u32, u32)> {
    let parsed = size
        .split_once('x')
        .and_then(|(w, h)| Some((w.trim().parse().ok()?, h.trim().parse().ok()?)));
    match parsed {
        Some((w, h)) if (1..=8192).contains(&w) && (1..=8192).contains(&h) => Ok((w, h)),
        _ => bail!("--size must be WIDTHxHEIGHT with both in 1..=8192, got {size:?}"),
    }
}

/// Checks a picture's options; returns its size and view.
pub(super) fn picture_view(picture: &super::PictureArgs) -> anyhow::Result<(u32, u32, ViewArgs)> {
    let (width, height) = parse_size(&picture.size)?;
    let view = ViewArgs {
        distance: picture.distance,
        fov_deg: picture.fov_deg,
        height_px: height as f32,
        pixel_error: picture.pixel_error,
        transition: picture.transition,
    };
    check_view(&view)?;
    Ok((width, height, view))
}

pub(super) fn preview(args: &PreviewArgs) -> anyhow::Result<()> {
    let (width, height, view) = picture_view(&args.picture)?;
    let picture = &args.picture;
    let record = load(&args.file)?;
    let e = view_params(&view).spatial_error(picture.distance);
    let (lo, hi) = record.bounds();
    let centre = (lo + hi) * 0.5;
    let camera = PreviewCamera {
        eye: centre + Vec3::Z * picture.distance.max(1e-3),
        target: centre,
        vertical_fov: picture.fov_deg.to_radians(),
        width,
        height,
    };
    let started = Instant::now();
    let primitives = cut_primitives(&record, &record.cut(e), picture.transition);
    let [r, g, b, _] = record.material.wood_color;
    let wood = mesh_triangles(&record.wood_mesh, [r, g, b]);
    let image = render_preview_scene(&primitives, &wood, &camera, &PreviewOptions::default());
    let render_ms = started.elapsed().as_secs_f64() * 1e3;
    image
        .save(&args.output)
        .with_context(|| format!("{}: cannot write PNG", args.output.display()))?;
    let report = cut_report(&record, None, &view);
    println!(
        "{}",
        serde_json::json!({
            "output": args.output,
            "spatial_error": e,
            "prisms": report.prisms,
            "lines_original": report.lines_original,
            "lines_merged": report.lines_merged,
            "triangles": report.triangles,
            "lines": report.line_segments,
            "render_ms": render_ms,
        })
    );
    Ok(())
}

pub(super) fn export(args: &ExportArgs) -> anyhow::Result<()> {
    if !(args.error.is_finite() && args.error >= 0.0) {
        bail!("--error must be a finite number ≥ 0 (metres), got {}", args.error);
    }
    if !(args.transition > 0.0 && args.transition <= 1.0) {
        bail!("--transition must be in (0, 1], got {}", args.transition);
    }
    let record = load(&args.file)?;
    let report = write_cut_glb(&record, args.error, args.transition, &args.output)
        .with_context(|| format!("{}: cannot write glTF", args.output.display()))?;
    if args.json {
        println!("{}", serde_json::to_string_pretty(&report)?);
    } else {
        eprintln!(
            "e = {} m: {} prisms ({} triangles), {} original + {} merged lines, {} wood triangles → {} ({} bytes)",
            report.spatial_error,
            report.prisms,
            report.prism_triangles,
            report.lines_original,
            report.lines_merged,
            report.wood_triangles,
            args.output.display(),
            report.bytes
        );
    }
    Ok(())
}
