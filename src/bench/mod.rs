//! `conifer bench`: how cost grows with needles, instances and views,
//! measured and printed as figures (feature `eval`).
//!
//! * Bake: a child `conifer bake --json` per size (so each peak memory is
//!   its own), split into generate, merge level 1, level 2, record and write,
//!   and the growth exponent of a log-log fit; the flat generator (every
//!   needle grown and stored on its own) and the shoot prototypes.
//! * Record: bytes per needle on disk and in GPU buffers, load time.
//! * Cut: the paper's CPU traversal, with and without the three-part start.
//! * [`runtime`]: the plugin's CPU time per frame, no rendering.
//! * [`forest`]: a rendered forest, the plugin against raw meshes and
//!   meshoptimizer LODs under `VisibilityRange`.

pub mod forest;
pub mod presets;
pub mod runtime;

use crate::generate::{GenerateOptions, Species, generate};
use crate::model::record::CutStrategy;
use crate::model::{BakeOptions, LodRecord, PixelError, ViewParams, bake, decode_record};
use forest::{ForestMethod, forest_frame_ms};
use runtime::RuntimeFigures;
use serde::Serialize;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::time::Instant;

/// One record per procedural species at about `needles` needles (seed 0).
pub fn species_records(needles: usize) -> Vec<LodRecord> {
    Species::ALL
        .into_iter()
        .map(|species| {
            let tree = generate(
                species,
                &GenerateOptions {
                    seed: 0,
                    target_needles: Some(needles),
                    age: crate::generate::Age::Young,
                },
            );
            bake(&tree, &BakeOptions::default(), &()).expect("procedural trees bake")
        })
        .collect()
}

/// What [`run`] measures.
#[derive(Clone, Debug)]
pub struct BenchOptions {
    /// The `conifer` executable that runs the bakes.
    pub conifer: PathBuf,
    /// Needle counts baked (the Scots pine preset scaled).
    pub bake_needles: Vec<usize>,
    /// Directory of the shipped `.conifer` records (bytes per needle, load time).
    pub records_dir: PathBuf,
    /// Needles of the tree whose cut is timed.
    pub cut_needles: usize,
    /// Instance counts of the run-time benchmark.
    pub instances: Vec<usize>,
    /// Frames per run-time measurement.
    pub runtime_frames: usize,
    /// Trees of the rendered forest.
    pub forest_instances: usize,
    /// Needles per tree of the rendered forest.
    pub forest_needles: usize,
    /// Picture of the rendered forest.
    pub forest_size: (u32, u32),
    /// Frames timed per forest method.
    pub forest_frames: usize,
    /// Where plots and pictures go.
    pub out_dir: PathBuf,
    /// Needles of the procedural prototype trees whose GPU bytes are
    /// measured (one per species).
    pub prototype_needles: usize,
    /// Needles of each preset baked while frames are timed (`presets`);
    /// `None`: each species' own count, what the examples load.
    pub preset_needles: Option<usize>,
    /// Parts to run (`bake`, `records`, `prototypes`, `cuts`, `runtime`,
    /// `presets`, `forest`); empty runs them all.
    pub only: Vec<String>,
}

impl BenchOptions {
    fn runs(&self, part: &str) -> bool {
        self.only.is_empty() || self.only.iter().any(|p| p == part)
    }
}

impl BenchOptions {
    /// The full run (BENCHMARKS.md's figures).
    pub fn full(conifer: PathBuf, records_dir: PathBuf, out_dir: PathBuf) -> Self {
        Self {
            conifer,
            bake_needles: vec![10_000, 30_000, 100_000, 300_000, 1_000_000],
            records_dir,
            cut_needles: 50_000,
            instances: vec![100, 1_000, 10_000, 100_000],
            runtime_frames: 60,
            forest_instances: 1_000,
            forest_needles: 5_000,
            forest_size: (640, 360),
            forest_frames: 5,
            prototype_needles: 1_000_000,
            preset_needles: None,
            out_dir,
            only: Vec::new(),
        }
    }

    /// A CI-sized run: every part, small.
    pub fn quick(conifer: PathBuf, records_dir: PathBuf, out_dir: PathBuf) -> Self {
        Self {
            bake_needles: vec![5_000, 10_000, 20_000],
            cut_needles: 10_000,
            instances: vec![100, 1_000],
            runtime_frames: 10,
            forest_instances: 36,
            forest_needles: 2_000,
            forest_size: (256, 144),
            forest_frames: 1,
            prototype_needles: 50_000,
            preset_needles: Some(20_000),
            ..Self::full(conifer, records_dir, out_dir)
        }
    }
}

/// Seconds of one bake's stages.
#[derive(Clone, Copy, Debug, Default, Serialize, serde::Deserialize)]
pub struct BakeStages {
    /// Generating the procedural tree (or importing).
    pub generate: f64,
    /// Merge level 1 (inside groups).
    pub merge_groups: f64,
    /// Merge level 2 (across the tree).
    pub merge_tree: f64,
    /// Validation and record assembly.
    pub record: f64,
    /// Baking the crown impostor into the record.
    #[serde(default)]
    pub impostor: f64,
    /// Encoding and writing the file.
    pub write: f64,
}

/// One bake.
#[derive(Clone, Debug, Serialize)]
pub struct BakeFigures {
    /// Needles baked (once placed).
    pub needles: usize,
    /// Shared prototypes of the record (the flat generator: one per group).
    pub prototypes: usize,
    /// Needles stored in the prototypes.
    pub prototype_needles: usize,
    /// Bake seconds (merge levels and record; generation and writing are
    /// in `stages`).
    pub seconds: f64,
    /// Needles per bake second.
    pub needles_per_second: f64,
    /// Peak resident memory of the bake process, bytes.
    pub peak_bytes: Option<u64>,
    /// The split.
    pub stages: BakeStages,
    /// Record file bytes.
    pub file_bytes: u64,
}

/// One species' record.
#[derive(Clone, Debug, Serialize)]
pub struct RecordFigures {
    /// Needles.
    pub needles: usize,
    /// File bytes.
    pub file_bytes: u64,
    /// File bytes per needle.
    pub disk_bytes_per_needle: f64,
    /// GPU buffer bytes of the species: the sizes of the `wgpu` buffers the render world created for it
    /// (`CompactGpuMemory::species_bytes`), per-tree and per-view buffers
    /// not included.
    pub gpu_bytes: u64,
    /// GPU bytes per needle.
    pub gpu_bytes_per_needle: f64,
    /// Whether `gpu_bytes` was read from the allocated buffers (always).
    pub gpu_bytes_measured: bool,
    /// Median time to decode and validate the file from memory, ms.
    pub decode_ms: f64,
    /// Median time to build the compact GPU arrays from the record, ms.
    pub build_ms: f64,
    /// Camera distances of `processed_over_cut`, metres (64 px, 0.8 rad).
    pub distances: Vec<f32>,
    /// Lines and prisms the vertex shaders processed (the compute pass's
    /// draw arguments, read back) over those in the cut, per distance.
    pub processed_over_cut: Vec<f64>,
}

/// A procedural tree of shared shoot prototypes, drawn.
#[derive(Clone, Debug, Serialize)]
pub struct PrototypeTreeFigures {
    /// Needles once placed.
    pub needles: u64,
    /// Needles stored in its prototypes.
    pub prototype_needles: u64,
    /// Prototypes.
    pub prototypes: usize,
    /// Placements.
    pub placements: usize,
    /// Record file bytes (the current format).
    pub file_bytes: u64,
    /// GPU buffer bytes of the species, summed from the `wgpu` buffers the
    /// render world created for it (`CompactGpuMemory::species_bytes`).
    pub gpu_bytes: u64,
    /// Bytes of its crown impostor's texture, every mip level
    /// (`CompactGpuMemory::impostor_bytes`).
    pub impostor_bytes: u64,
    /// Per-view bytes of the one camera that drew it (culling, expanded
    /// placements, indirect draws).
    pub view_bytes: u64,
    /// Camera distances of `processed_over_cut`, metres (64 px, 0.8 rad).
    pub distances: Vec<f32>,
    /// Prisms and lines the vertex shaders process (counted from the
    /// indirect draws the GPU wrote, read back) over those in the cut (the
    /// CPU reference at the GPU's codes), at each distance.
    pub processed_over_cut: Vec<f64>,
}

/// Cut timings.
#[derive(Clone, Debug, Serialize)]
pub struct CutFigures {
    /// Needles of the tree.
    pub needles: usize,
    /// Viewing distances, metres (1080 px, 45°, ε = 1).
    pub distances: Vec<f32>,
    /// The cut's primitives at each distance.
    pub primitives: Vec<u64>,
    /// Median µs per cut, the paper's traversal with the three-part start.
    pub three_part_start: Vec<f64>,
    /// Median µs per cut, the traversal from the roots.
    pub from_roots: Vec<f64>,
    /// Median µs of `CutCounter::count` (counts only, what the overlay uses).
    pub counts_only: Vec<f64>,
}

/// Rendered forest frame times.
#[derive(Clone, Debug, Serialize)]
pub struct RenderRatio {
    /// `raw` frame time over `ours`.
    pub raw_over_ours: f64,
    /// `bevy-lod` frame time over `ours`.
    pub bevylod_over_ours: f64,
    /// Median frame ms, the plugin.
    pub ours_ms: f64,
    /// Median frame ms, raw meshes.
    pub raw_ms: f64,
    /// Median frame ms, meshoptimizer LODs with `VisibilityRange`.
    pub bevylod_ms: f64,
    /// The plugin without MSAA, ms: lavapipe rasterizes MSAA lines slowly,
    /// so this shows how much of `ours_ms` is that (raw meshes barely change).
    pub ours_no_msaa_ms: f64,
    /// `bevy-lod` without MSAA, ms.
    pub bevylod_no_msaa_ms: f64,
    /// The plugin in a light breeze (`ConiferWind::default()`), ms: what
    /// the wind costs the GPU (`ours_ms` is calm).
    pub ours_in_wind_ms: f64,
    /// Trees.
    pub instances: usize,
    /// Needles per tree.
    pub needles_per_tree: usize,
    /// Picture width.
    pub width: u32,
    /// Picture height.
    pub height: u32,
    /// The renderer (lavapipe: only ratios mean anything).
    pub adapter: String,
}

/// Everything `conifer bench --json` prints.
#[derive(Clone, Debug, Serialize)]
pub struct BenchReport {
    /// The machine: CPU, cores, memory.
    pub machine: String,
    /// Build profile of the measuring binary.
    pub profile: String,
    /// Bakes by size, the flat generator (`conifer bake --flat`).
    pub bake: Vec<BakeFigures>,
    /// Bakes by size, shoot prototypes (`conifer bake`'s default).
    pub bake_prototypes: Vec<BakeFigures>,
    /// Slope of log(bake seconds) over log(needles), least squares.
    pub bake_exponent: f64,
    /// Shipped records by species.
    pub bytes_per_needle: BTreeMap<String, RecordFigures>,
    /// Procedural prototype trees by species (`prototype_needles` needles).
    pub prototype_trees: BTreeMap<String, PrototypeTreeFigures>,
    /// CPU cut selection.
    pub cut_us: Option<CutFigures>,
    /// The plugin's CPU time per frame, no rendering.
    pub runtime: Vec<RuntimeFigures>,
    /// Presets baking while the app runs, and read back from the cache.
    pub presets: Option<presets::PresetFigures>,
    /// The rendered forest.
    pub render_ratio: Option<RenderRatio>,
    /// The GPU machine's figures, or why there are none.
    pub gpu: String,
    /// Files written (plots, forest pictures).
    pub files: Vec<PathBuf>,
}

/// Why the benchmark failed.
#[derive(Debug, thiserror::Error)]
pub enum BenchError {
    /// A bake child failed.
    #[error("bake of {needles} needles failed: {message}")]
    Bake {
        /// Needles.
        needles: usize,
        /// What went wrong.
        message: String,
    },
    /// A record could not be read.
    #[error("{0}: {1}")]
    Record(PathBuf, String),
    /// Rendering failed.
    #[error(transparent)]
    Render(#[from] crate::eval::scene::EvalError),
    /// A plot failed.
    #[error(transparent)]
    Plot(#[from] crate::eval::plot::PlotError),
    /// The output directory could not be made.
    #[error("{0}: {1}")]
    OutDir(PathBuf, std::io::Error),
}

/// Slope of the least-squares line through `(ln x, ln y)`; 0 with fewer than
/// two usable points.
pub fn log_log_slope(points: &[(f64, f64)]) -> f64 {
    let logs: Vec<(f64, f64)> = points
        .iter()
        .filter(|(x, y)| *x > 0.0 && *y > 0.0 && x.is_finite() && y.is_finite())
        .map(|(x, y)| (x.ln(), y.ln()))
        .collect();
    let n = logs.len() as f64;
    if logs.len() < 2 {
        return 0.0;
    }
    let (mx, my) = (
        logs.iter().map(|p| p.0).sum::<f64>() / n,
        logs.iter().map(|p| p.1).sum::<f64>() / n,
    );
    let sxx: f64 = logs.iter().map(|p| (p.0 - mx).powi(2)).sum();
    let sxy: f64 = logs.iter().map(|p| (p.0 - mx) * (p.1 - my)).sum();
    if sxx > 0.0 { sxy / sxx } else { 0.0 }
}

/// Median µs of `f` over at least 5 runs and at least 50 ms.
fn time_us(mut f: impl FnMut()) -> f64 {
    let mut times = Vec::new();
    let started = Instant::now();
    while times.len() < 5 || (started.elapsed().as_secs_f64() < 0.05 && times.len() < 10_000) {
        let t = Instant::now();
        f();
        times.push(t.elapsed().as_secs_f64() * 1e6);
    }
    crate::eval::measure::median(&times)
}

fn machine() -> String {
    let cpu = std::fs::read_to_string("/proc/cpuinfo")
        .ok()
        .and_then(|s| {
            s.lines()
                .find(|l| l.starts_with("model name"))
                .and_then(|l| l.split(':').nth(1))
                .map(|s| s.trim().to_string())
        })
        .unwrap_or_else(|| "unknown CPU".into());
    let cores = std::thread::available_parallelism().map_or(1, |n| n.get());
    let memory = std::fs::read_to_string("/proc/meminfo")
        .ok()
        .and_then(|s| {
            s.lines()
                .find(|l| l.starts_with("MemTotal"))
                .and_then(|l| l.split_whitespace().nth(1))
                .and_then(|kb| kb.parse::<f64>().ok())
        })
        .map_or_else(
            || "unknown memory".into(),
            |kb| format!("{:.0} GiB", kb / 1024.0 / 1024.0),
        );
    format!("{cpu}, {cores} cores, {memory}, no GPU (software Vulkan: Mesa lavapipe)")
}

fn bake_child(conifer: &Path, needles: usize, flat: bool, dir: &Path) -> Result<BakeFigures, BenchError> {
    let output_file = dir.join(format!("bench_{needles}.conifer"));
    let fail = |message: String| BenchError::Bake { needles, message };
    let output = std::process::Command::new(conifer)
        .args([
            "bake",
            "--preset",
            "scots-pine",
            "--needles",
            &needles.to_string(),
            "--json",
            "-o",
        ])
        .arg(&output_file)
        .args(flat.then_some("--flat"))
        .output()
        .map_err(|e| fail(format!("cannot run {}: {e}", conifer.display())))?;
    let _ = std::fs::remove_file(&output_file);
    if !output.status.success() {
        return Err(fail(String::from_utf8_lossy(&output.stderr).into_owned()));
    }
    let json: serde_json::Value =
        serde_json::from_slice(&output.stdout).map_err(|e| fail(format!("bad JSON from the bake: {e}")))?;
    let number = |key: &str| json.get(key).and_then(serde_json::Value::as_f64).unwrap_or(0.0);
    let stage = |key: &str| {
        json.get("stages")
            .and_then(|s| s.get(key))
            .and_then(serde_json::Value::as_f64)
            .unwrap_or(0.0)
    };
    let seconds = number("bake_seconds");
    let baked = number("needles") as usize;
    Ok(BakeFigures {
        needles: baked,
        prototypes: number("prototypes") as usize,
        prototype_needles: number("prototype_needles") as usize,
        seconds,
        needles_per_second: if seconds > 0.0 { baked as f64 / seconds } else { 0.0 },
        peak_bytes: json.get("peak_bytes").and_then(serde_json::Value::as_u64),
        stages: BakeStages {
            generate: number("generate_seconds"),
            merge_groups: stage("merge_groups"),
            merge_tree: stage("merge_tree"),
            record: stage("record"),
            impostor: stage("impostor"),
            write: number("write_seconds"),
        },
        file_bytes: number("bytes") as u64,
    })
}

fn record_figures(path: &Path) -> Result<RecordFigures, BenchError> {
    let bytes = std::fs::read(path).map_err(|e| BenchError::Record(path.to_path_buf(), e.to_string()))?;
    let record = decode_record(&bytes).map_err(|e| BenchError::Record(path.to_path_buf(), e.to_string()))?;
    let decode_ms = time_us(|| {
        std::hint::black_box(decode_record(std::hint::black_box(&bytes)).ok());
    }) / 1e3;
    let build_ms = time_us(|| {
        std::hint::black_box(crate::model::compact::CompactSpecies::build(&record).ok());
    }) / 1e3;
    let species = crate::plugin::ConiferSpecies::from_record(record.clone())
        .map_err(|e| BenchError::Record(record.name.clone().into(), e.to_string()))?;
    let compact = species.compact.clone();
    let distances = vec![2.0f32, 5.0, 20.0, 80.0, 400.0];
    let mut processed_over_cut = Vec::new();
    let gpu = compact_memory(species, &distances, |view| {
        let (code, e) = view.tree_lod(0);
        let cut = compact.drawn(code, e);
        let in_cut = (cut.prisms.len() + cut.original_lines.len() + cut.merged_lines.len()).max(1);
        processed_over_cut.push(view.processed_primitives(record.max_sides) as f64 / in_cut as f64);
    })?
    .species;
    let needles = record.needle_count().max(1);
    Ok(RecordFigures {
        needles: record.needle_count(),
        file_bytes: bytes.len() as u64,
        disk_bytes_per_needle: bytes.len() as f64 / needles as f64,
        gpu_bytes: gpu,
        gpu_bytes_per_needle: gpu as f64 / needles as f64,
        gpu_bytes_measured: true,
        decode_ms,
        build_ms,
        distances,
        processed_over_cut,
    })
}

/// A 1,000,000-needle (by default) procedural tree of `species` as shoot
/// prototypes: baked, loaded, drawn once by the compact path at 20 m, its
/// buffers read back.
fn prototype_tree_figures(species: Species, needles: usize) -> Result<PrototypeTreeFigures, BenchError> {
    let input = crate::generate::generate_prototypes(
        species,
        &GenerateOptions {
            seed: 0,
            target_needles: Some(needles),
            age: crate::generate::Age::Mature,
        },
    );
    let failed = |e: String| BenchError::Record(species.name().into(), e);
    let record =
        crate::model::bake_prototypes(&input, &BakeOptions::default(), &()).map_err(|e| failed(e.to_string()))?;
    let file_bytes = crate::model::encode_prototype_record(&record)
        .map_err(|e| failed(e.to_string()))?
        .len() as u64;
    let record = record.quantized().map_err(|e| failed(e.to_string()))?;
    let tree = crate::plugin::ConiferSpecies::from_prototype_record(&record).map_err(|e| failed(e.to_string()))?;
    let compact = tree.compact.clone();
    let distances = vec![5.0f32, 20.0, 80.0];
    let mut processed_over_cut = Vec::new();
    let memory = compact_memory(tree, &distances, |view| {
        let (code, e) = view.tree_lod(0);
        // The view point the cull pass wrote (view-dependent detail, the
        // default scope), if any.
        let seen = view.view_point(0);
        let (cut, _) = compact.placed_drawn(
            &record,
            code,
            e,
            crate::model::compact::shader_threshold_code,
            seen.as_ref(),
        );
        let in_cut = (cut.prisms.len() + cut.original_lines.len() + cut.merged_lines.len()).max(1);
        processed_over_cut.push(view.processed_primitives(record.max_sides) as f64 / in_cut as f64);
    })?;
    Ok(PrototypeTreeFigures {
        needles: record.needle_count(),
        prototype_needles: record.prototype_needle_count(),
        prototypes: record.prototypes.len(),
        placements: record.placements.len(),
        file_bytes,
        gpu_bytes: memory.species,
        impostor_bytes: memory.impostor,
        view_bytes: memory.view,
        distances,
        processed_over_cut,
    })
}

/// Bytes the render path allocated for one species and one view.
struct AllocatedBytes {
    /// The species' buffers.
    species: u64,
    /// Its impostor texture.
    impostor: u64,
    /// The view's buffers.
    view: u64,
}

/// One tree of `species` drawn headless at 20 m from its crown: the
/// species' buffer bytes, its impostor's and the view's; then at each of
/// `distances`, the camera's compute results read back and handed to
/// `read`. The line path is what is measured: the tree never turns into
/// its impostor.
fn compact_memory(
    species: crate::plugin::ConiferSpecies,
    distances: &[f32],
    mut read: impl FnMut(&crate::plugin::ViewReadback),
) -> Result<AllocatedBytes, BenchError> {
    use crate::plugin::headless::HeadlessRenderer;
    use crate::plugin::{CompactGpuMemory, CompactReadback, ConiferFoliage, ConiferSpecies};
    use bevy::prelude::*;
    let mut renderer = HeadlessRenderer::new(".");
    let target = renderer.render_target(64, 64);
    let world = renderer.world_mut();
    world.resource_mut::<crate::plugin::ConiferLodSettings>().far_impostor = false;
    let crown = species.crown_center;
    let handle = world.resource_mut::<Assets<ConiferSpecies>>().add(species);
    world.spawn((ConiferFoliage(handle.clone()), Transform::IDENTITY));
    let at = |distance: f32| Transform::from_translation(crown + Vec3::Z * distance).looking_at(crown, Vec3::Y);
    let camera = world
        .spawn(HeadlessRenderer::camera_bundle(&target, at(20.0), 0.8))
        .id();
    for _ in 0..HeadlessRenderer::SETTLE_FRAMES {
        renderer
            .update()
            .map_err(|e| BenchError::Render(crate::eval::scene::EvalError::from(e)))?;
    }
    let memory = renderer.world().resource::<CompactGpuMemory>().clone();
    renderer.world_mut().resource_mut::<CompactReadback>().enabled = true;
    for &distance in distances {
        *renderer.world_mut().get_mut::<Transform>(camera).expect("the camera") = at(distance);
        // The frame that culls, then the one that publishes its results.
        for _ in 0..2 {
            renderer
                .update()
                .map_err(|e| BenchError::Render(crate::eval::scene::EvalError::from(e)))?;
        }
        let readback = renderer.world().resource::<CompactReadback>();
        if let Some(view) = readback
            .views
            .iter()
            .find(|v| v.species == handle.id() && v.perspective)
        {
            read(view);
        }
    }
    Ok(AllocatedBytes {
        species: memory.species_bytes.get(&handle.id()).copied().unwrap_or(0),
        impostor: memory.impostor_bytes.get(&handle.id()).copied().unwrap_or(0),
        view: memory.view_bytes,
    })
}

/// Distances of the cut benchmark, metres.
pub const CUT_DISTANCES: [f32; 5] = [5.0, 20.0, 50.0, 150.0, 400.0];

fn cut_figures(needles: usize) -> CutFigures {
    let tree = generate(
        Species::ScotsPine,
        &GenerateOptions {
            seed: 0,
            target_needles: Some(needles),
            age: crate::generate::Age::Young,
        },
    );
    let record = bake(&tree, &BakeOptions::default(), &()).expect("the preset bakes");
    let view = ViewParams {
        pixel_error: PixelError(1.0),
        ..ViewParams::default()
    };
    let counter = crate::model::CutCounter::new(&record);
    let mut figures = CutFigures {
        needles: record.needle_count(),
        distances: CUT_DISTANCES.to_vec(),
        primitives: Vec::new(),
        three_part_start: Vec::new(),
        from_roots: Vec::new(),
        counts_only: Vec::new(),
    };
    for distance in CUT_DISTANCES {
        let e = view.spatial_error(distance);
        figures.primitives.push(counter.count(e).primitives());
        for (three_part_start, out) in [(true, &mut figures.three_part_start), (false, &mut figures.from_roots)] {
            let strategy = CutStrategy::Traversal { three_part_start };
            out.push(time_us(|| {
                std::hint::black_box(record.cut_with(std::hint::black_box(e), strategy));
            }));
        }
        figures.counts_only.push(time_us(|| {
            std::hint::black_box(counter.count(std::hint::black_box(e)));
        }));
    }
    figures
}

/// Runs every benchmark of `options`; `progress` hears a line per stage.
pub fn run(options: &BenchOptions, progress: &mut dyn FnMut(&str)) -> Result<BenchReport, BenchError> {
    std::fs::create_dir_all(&options.out_dir).map_err(|e| BenchError::OutDir(options.out_dir.clone(), e))?;
    let mut files = Vec::new();

    let (mut bakes, mut prototype_bakes) = (Vec::new(), Vec::new());
    for &needles in options.bake_needles.iter().filter(|_| options.runs("bake")) {
        progress(&format!("bake {needles} needles, flat and as shoot prototypes"));
        bakes.push(bake_child(&options.conifer, needles, true, &options.out_dir)?);
        prototype_bakes.push(bake_child(&options.conifer, needles, false, &options.out_dir)?);
    }
    let bake_exponent = log_log_slope(&bakes.iter().map(|b| (b.needles as f64, b.seconds)).collect::<Vec<_>>());

    progress("records");
    let mut records = BTreeMap::new();
    for species in Species::ALL.into_iter().filter(|_| options.runs("records")) {
        let path = options.records_dir.join(format!("{}.conifer", species.name()));
        if path.is_file() {
            records.insert(species.name().to_string(), record_figures(&path)?);
        }
    }

    let mut prototype_trees = BTreeMap::new();
    for species in Species::ALL.into_iter().filter(|_| options.runs("prototypes")) {
        progress(&format!(
            "{} as shoot prototypes, {} needles",
            species.name(),
            options.prototype_needles
        ));
        prototype_trees.insert(
            species.name().to_string(),
            prototype_tree_figures(species, options.prototype_needles)?,
        );
    }

    progress("cuts");
    let cut_us = options.runs("cuts").then(|| cut_figures(options.cut_needles));

    let mut runtime = Vec::new();
    let runtime_records = if options.runs("runtime") {
        species_records(5_000)
    } else {
        Vec::new()
    };
    for &instances in options.instances.iter().filter(|_| options.runs("runtime")) {
        progress(&format!("run time, {instances} trees"));
        runtime.push(runtime::runtime(&runtime_records, instances, options.runtime_frames));
    }

    let presets = options.runs("presets").then(|| {
        progress(&format!(
            "six presets ({:?} needles) baking in a running app",
            options.preset_needles
        ));
        presets::preset_figures(options.preset_needles, 1_000, &options.out_dir.join("preset-cache"))
    });

    let render_ratio = if options.runs("forest") {
        Some(forest_figures(options, &mut files, progress)?)
    } else {
        None
    };

    progress("plots");
    files.extend(write_plots(&options.out_dir, &bakes, &prototype_bakes, &runtime)?);

    Ok(BenchReport {
        machine: machine(),
        profile: if cfg!(debug_assertions) { "debug" } else { "release" }.into(),
        bake: bakes,
        bake_prototypes: prototype_bakes,
        bake_exponent,
        bytes_per_needle: records,
        prototype_trees,
        cut_us,
        runtime,
        presets,
        render_ratio,
        gpu: "no GPU machine was lent to this session (the device tool's status: not drawn); no absolute GPU figures"
            .into(),
        files,
    })
}

fn forest_figures(
    options: &BenchOptions,
    files: &mut Vec<PathBuf>,
    progress: &mut dyn FnMut(&str),
) -> Result<RenderRatio, BenchError> {
    let forest_records = species_records(options.forest_needles);
    let mut forest_ms = BTreeMap::new();
    for (name, method, msaa) in [
        ("ours", ForestMethod::Ours, true),
        ("raw", ForestMethod::Raw, true),
        ("bevy-lod", ForestMethod::BevyLod, true),
        ("ours-no-msaa", ForestMethod::Ours, false),
        ("ours-in-wind", ForestMethod::OursInWind, true),
        ("bevy-lod-no-msaa", ForestMethod::BevyLod, false),
    ] {
        progress(&format!("rendered forest, {name}, {} trees", options.forest_instances));
        let picture = options.out_dir.join(format!("forest_{name}.png"));
        let ms = forest_frame_ms(
            &forest_records,
            method,
            options.forest_instances,
            options.forest_size,
            options.forest_frames,
            msaa,
            msaa.then_some(picture.as_path()),
        )?;
        if msaa {
            files.push(picture);
        }
        forest_ms.insert(name, ms);
    }
    let ours = forest_ms["ours"].max(1e-9);
    Ok(RenderRatio {
        raw_over_ours: forest_ms["raw"] / ours,
        bevylod_over_ours: forest_ms["bevy-lod"] / ours,
        ours_ms: forest_ms["ours"],
        raw_ms: forest_ms["raw"],
        bevylod_ms: forest_ms["bevy-lod"],
        ours_no_msaa_ms: forest_ms["ours-no-msaa"],
        ours_in_wind_ms: forest_ms["ours-in-wind"],
        bevylod_no_msaa_ms: forest_ms["bevy-lod-no-msaa"],
        instances: options.forest_instances,
        needles_per_tree: forest_records.iter().map(LodRecord::needle_count).sum::<usize>() / forest_records.len(),
        width: options.forest_size.0,
        height: options.forest_size.1,
        adapter: "Mesa lavapipe (software Vulkan, CPU)".into(),
    })
}

fn write_plots(
    dir: &Path,
    bakes: &[BakeFigures],
    prototype_bakes: &[BakeFigures],
    runtime: &[RuntimeFigures],
) -> Result<Vec<PathBuf>, BenchError> {
    use crate::eval::plot::{Axes, Series, line_plot};
    let series = |name: &str, f: &dyn Fn(&BakeFigures) -> f64| Series {
        name: name.into(),
        points: bakes.iter().map(|b| (b.needles as f64, f(b))).collect(),
    };
    let prototypes = Series {
        name: "shoot prototypes: bake".into(),
        points: prototype_bakes.iter().map(|b| (b.needles as f64, b.seconds)).collect(),
    };
    let bake_path = dir.join("bake_time_vs_needles.png");
    line_plot(
        &bake_path,
        &Axes {
            title: "bake time vs needles (log-log)",
            x_label: "needles",
            y_label: "seconds",
            log_x: true,
            log_y: true,
        },
        &[
            series("flat: bake (both merge levels + record)", &|b| b.seconds),
            prototypes,
            series("merge level 1 (groups)", &|b| b.stages.merge_groups),
            series("merge level 2 (tree)", &|b| b.stages.merge_tree),
            series("crown impostor", &|b| b.stages.impostor),
            series("generate", &|b| b.stages.generate),
            series("write", &|b| b.stages.write),
        ],
        720,
        440,
    )?;
    let runtime_path = dir.join("runtime_vs_instances.png");
    line_plot(
        &runtime_path,
        &Axes {
            title: "plugin CPU time per instance per frame",
            x_label: "instances",
            y_label: "ns per instance",
            log_x: true,
            log_y: false,
        },
        &[
            Series {
                name: "plugin systems".into(),
                points: runtime
                    .iter()
                    .map(|r| (r.instances as f64, r.systems_ns_per_instance))
                    .collect(),
            },
            Series {
                name: "whole cost (with - without plugin)".into(),
                points: runtime
                    .iter()
                    .map(|r| (r.instances as f64, r.ns_per_instance))
                    .collect(),
            },
        ],
        720,
        440,
    )?;
    Ok(vec![bake_path, runtime_path])
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn log_log_slope_recovers_power_laws() {
        let linear: Vec<(f64, f64)> = [1e4, 1e5, 1e6].iter().map(|&n| (n, 3e-6 * n)).collect();
        assert!((log_log_slope(&linear) - 1.0).abs() < 1e-9);
        let quadratic: Vec<(f64, f64)> = [10.0, 20.0, 40.0].iter().map(|&n| (n, n * n)).collect();
        assert!((log_log_slope(&quadratic) - 2.0).abs() < 1e-9);
        assert_eq!(log_log_slope(&[(1.0, 1.0)]), 0.0);
        assert_eq!(log_log_slope(&[(0.0, 1.0), (-1.0, 2.0)]), 0.0);
    }
}
