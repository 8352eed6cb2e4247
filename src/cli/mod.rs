//! The `conifer` command line: argument parsing and the subcommands.
//!
//! Kept in the library (behind the `cli` feature) so integration tests can
//! run the same code paths the binary runs.

#[cfg(feature = "eval")]
mod bench;
mod commands;
#[cfg(feature = "eval")]
mod eval;
pub mod heap;
#[cfg(feature = "plugin")]
mod render;

use clap::{Parser, Subcommand};
use std::ffi::OsString;
use std::path::PathBuf;

pub use commands::{CutReport, InspectReport, MinMedianMax};

/// Continuous-LOD records for coniferous trees: bake, inspect, cut, preview, export.
#[derive(Debug, Parser)]
#[command(name = "conifer", version, about, long_about = None)]
pub struct Cli {
    /// What to do.
    #[command(subcommand)]
    pub command: Command,
}

/// The subcommands.
#[derive(Debug, Subcommand)]
pub enum Command {
    /// Bake a tree (a procedural preset or a glTF file) into a `.conifer` LOD record.
    Bake(BakeArgs),
    /// Print what a record holds.
    Inspect(InspectArgs),
    /// Rewrite records of an older format version in the current one, in place
    /// (older versions are read and converted; a record gains its crown impostor,
    /// baked with the default options, unless --no-impostor; nothing else changes).
    Upgrade(UpgradeArgs),
    /// Print the cut (what is drawn) of a record at a viewing distance.
    Cut(CutArgs),
    /// Render the cut at a viewing distance to a PNG with the CPU preview rasterizer.
    Preview(PreviewArgs),
    /// Write the cut at a spatial error as a glTF binary (prisms as triangles, lines as LINES).
    Export(ExportArgs),
    /// Render a record through the Bevy plugin, headless, to a PNG.
    #[cfg(feature = "plugin")]
    Render(render::RenderArgs),
    /// Measure image quality, popping, primitives and frame time of the plugin
    /// against the paper's configuration and the peers (raw, bevy-lod,
    /// sampling), headless, against a supersampled reference.
    #[cfg(feature = "eval")]
    Eval(Box<eval::EvalArgs>),
    /// Benchmarks: bake scaling, record sizes, cut time, plugin CPU time per
    /// instance, and a rendered forest against raw meshes and Bevy LODs.
    #[cfg(feature = "eval")]
    Bench(bench::BenchArgs),
}

/// `--age`: a name of [`crate::generate::Age`].
fn parse_age(text: &str) -> Result<crate::generate::Age, String> {
    crate::generate::Age::from_name(text).ok_or_else(|| format!("unknown age `{text}` (expected `young` or `mature`)"))
}

/// `--merge-error`: a name of [`crate::model::MergeErrorBound`].
pub(crate) fn parse_merge_error(text: &str) -> Result<crate::model::MergeErrorBound, String> {
    crate::model::MergeErrorBound::from_name(text)
        .ok_or_else(|| format!("unknown merge error `{text}` (expected `needles` or `nested`)"))
}

/// `--merge-cost`: a name of [`crate::model::MergeCostRule`].
fn parse_merge_cost(text: &str) -> Result<crate::model::MergeCostRule, String> {
    crate::model::MergeCostRule::from_name(text)
        .ok_or_else(|| format!("unknown merge cost `{text}` (expected `error` or `weighted`)"))
}

/// Arguments of `conifer bake`.
#[derive(Debug, clap::Args)]
pub struct BakeArgs {
    /// Input glTF/GLB file (alternative to --preset).
    #[arg(conflicts_with = "preset", required_unless_present = "preset")]
    pub input: Option<PathBuf>,
    /// Procedural species preset: scots-pine, norway-spruce, eastern-white-pine,
    /// lawson-cypress, douglas-fir, silver-fir.
    #[arg(long)]
    pub preset: Option<String>,
    /// With --preset: how old the tree is: `mature` (15–50 m, a million needles or more) or
    /// `young` (2–5 m saplings, tens of thousands).
    #[arg(long, requires = "preset", default_value = "mature", value_parser = parse_age)]
    pub age: crate::generate::Age,
    /// Seed of the procedural tree.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// With --preset: grow every needle on its own (the flat generator) instead of
    /// placing a few dozen shared shoot prototypes.
    #[arg(long, requires = "preset")]
    pub flat: bool,
    /// With --preset: the approximate needle count N of the procedural tree (default: the
    /// preset's own). With a glTF input: a node, mesh or material NAME holding needle geometry
    /// (repeatable; any case; `*` wildcards); default: names containing leaf/leaves/needle/foliage.
    #[arg(long, value_name = "N|NAME")]
    pub needles: Vec<String>,
    /// glTF input: metres per file unit (glTF is in metres).
    #[arg(long, default_value_t = 1.0)]
    pub scale: f32,
    /// Output record path.
    #[arg(short, long)]
    pub output: PathBuf,
    /// Lmax: most sides of a needle prism (3..=64).
    #[arg(long, default_value_t = 8)]
    pub max_sides: u8,
    /// Which pair of lines merges first: `error` (the pair whose merged line is thinnest)
    /// or `weighted` (the paper's weighted cost of direction, distance and needle count,
    /// with --weights).
    #[arg(long, default_value = "error", value_parser = parse_merge_cost)]
    pub merge_cost: crate::model::MergeCostRule,
    /// Merge cost weights k1,k2,k3 (direction, distance, needle count) of `--merge-cost weighted`.
    #[arg(long, value_name = "K1,K2,K3", value_delimiter = ',', default_values_t = [0.25f32, 0.25, 0.5])]
    pub weights: Vec<f32>,
    /// Partner candidates per line in the whole-tree merge (nearest neighbours).
    #[arg(long, default_value_t = 12)]
    pub neighbours: usize,
    /// Search every live line for the whole-tree merge (exact, quadratic: small trees only).
    #[arg(long)]
    pub exhaustive: bool,
    /// How a merged line's error is bounded: `needles` (the thinnest capsule around the line
    /// holding its needles) or `nested` (the paper's: a capsule holding its two children's
    /// capsules, which grows with every level, so merged lines are drawn later).
    #[arg(long, default_value = "needles", value_parser = parse_merge_error)]
    pub merge_error: crate::model::MergeErrorBound,
    /// Side of a crown impostor texel, metres: the far representation baked into the
    /// record (the tree turns into it where the pixel error spans 0.8–1.6 texels).
    #[arg(long, default_value_t = 0.10, value_name = "METRES")]
    pub impostor_texel: f32,
    /// Views of the crown impostor around the trunk.
    #[arg(long, default_value_t = 8)]
    pub impostor_views: u32,
    /// Bake no crown impostor into the record (the plugin then bakes one each time it loads it).
    #[arg(long)]
    pub no_impostor: bool,
    /// Do not calibrate the lines' opacity against the needles' coverage (every line keeps
    /// its area-preserving opacity; see `model::calibration`).
    #[arg(long)]
    pub no_line_calibration: bool,
    /// Also calibrate the lines from this many degrees above and below the horizontal
    /// (`CalibrationOptions::elevation_degrees`; 0, the default, calibrates level views
    /// only): for trees mostly seen from below or above, whose tiers a level view sees
    /// edge on.
    #[arg(long, default_value_t = 0.0)]
    pub calibration_elevation: f32,
    /// Print a JSON summary of the bake on stdout.
    #[arg(long)]
    pub json: bool,
}

/// Arguments of `conifer inspect`.
#[derive(Debug, clap::Args)]
pub struct InspectArgs {
    /// The record.
    pub file: PathBuf,
    /// Print one JSON object.
    #[arg(long)]
    pub json: bool,
}

/// Arguments of `conifer upgrade`.
#[derive(Debug, clap::Args)]
pub struct UpgradeArgs {
    /// The records to rewrite.
    #[arg(required = true)]
    pub files: Vec<PathBuf>,
    /// Leave a record's crown impostor as it is (by default, one older than format 12
    /// gets its impostor baked again with the default options: format 7's lit its
    /// texels along one mean axis, formats 8 and 9 lack its wood visibility, and
    /// formats up to 11 left the needles' end caps out of its coverage).
    #[arg(long)]
    pub no_impostor: bool,
    /// Leave a record's line calibration as it is (by default, one older than format 12 is
    /// calibrated again with the default options: format 9 added the table of line opacity
    /// scales, format 11 the wood lines' scales in it, format 12 counts the needles' end
    /// caps in what the lines must cover).
    #[arg(long)]
    pub no_line_calibration: bool,
    /// Calibrate the lines again, whatever the record's format, from level views and from
    /// this many degrees above and below them (`conifer bake --calibration-elevation`; 0
    /// calibrates level views only, as a bake does by default).
    #[arg(long)]
    pub calibration_elevation: Option<f32>,
}

/// How a view is described on the command line.
#[derive(Debug, Clone, clap::Args)]
pub struct ViewArgs {
    /// Distance from the viewer to the tree, metres.
    #[arg(long)]
    pub distance: f32,
    /// Vertical field of view, degrees.
    #[arg(long, default_value_t = 45.0)]
    pub fov_deg: f32,
    /// Viewport height, pixels.
    #[arg(long, default_value_t = 1080.0)]
    pub height_px: f32,
    /// Pixel error ε.
    #[arg(long, default_value_t = 1.0)]
    pub pixel_error: f32,
    /// Transition coefficient δ in (0, 1], scaling original lines' opacity.
    #[arg(long, default_value_t = 1.0)]
    pub transition: f32,
}

/// Arguments of `conifer cut`.
#[derive(Debug, clap::Args)]
pub struct CutArgs {
    /// The record.
    pub file: PathBuf,
    /// The view.
    #[command(flatten)]
    pub view: ViewArgs,
    /// Print one JSON object.
    #[arg(long)]
    pub json: bool,
}

/// Arguments of `conifer preview`.
#[derive(Debug, clap::Args)]
pub struct PreviewArgs {
    /// The record.
    pub file: PathBuf,
    /// The picture.
    #[command(flatten)]
    pub picture: PictureArgs,
    /// Output PNG.
    #[arg(short, long)]
    pub output: PathBuf,
}

/// How a picture of a record is taken (`conifer preview`, `conifer render`):
/// the camera looks at the crown's centre from `distance` metres along +Z.
#[derive(Debug, Clone, clap::Args)]
pub struct PictureArgs {
    /// Distance from the camera to the tree's centre, metres.
    #[arg(long)]
    pub distance: f32,
    /// Image size, WIDTHxHEIGHT pixels (the height is the viewport height of the error).
    #[arg(long, default_value = "512x512")]
    pub size: String,
    /// Vertical field of view, degrees.
    #[arg(long, default_value_t = 45.0)]
    pub fov_deg: f32,
    /// Pixel error ε.
    #[arg(long, default_value_t = 1.0)]
    pub pixel_error: f32,
    /// Transition coefficient δ in (0, 1].
    #[arg(long, default_value_t = 1.0)]
    pub transition: f32,
}

/// Arguments of `conifer export`.
#[derive(Debug, clap::Args)]
pub struct ExportArgs {
    /// The record.
    pub file: PathBuf,
    /// Spatial error e of the cut, metres (see `conifer cut --json` for the e of a view).
    #[arg(long)]
    pub error: f32,
    /// Transition coefficient δ in (0, 1], scaling the lines' opacity.
    #[arg(long, default_value_t = 1.0)]
    pub transition: f32,
    /// Output GLB.
    #[arg(short, long)]
    pub output: PathBuf,
    /// Print one JSON object.
    #[arg(long)]
    pub json: bool,
}

/// Parses `args` (program name first) and runs the command.
pub fn run<I, T>(args: I) -> anyhow::Result<()>
where
    I: IntoIterator<Item = T>,
    T: Into<OsString> + Clone,
{
    // Usage errors print clap's message and exit with status 2; --help exits 0.
    let cli = Cli::parse_from(args);
    match cli.command {
        Command::Bake(args) => commands::bake(&args),
        Command::Inspect(args) => commands::inspect(&args),
        Command::Upgrade(args) => commands::upgrade(&args),
        Command::Cut(args) => commands::cut(&args),
        Command::Preview(args) => commands::preview(&args),
        Command::Export(args) => commands::export(&args),
        #[cfg(feature = "plugin")]
        Command::Render(args) => render::render(&args),
        #[cfg(feature = "eval")]
        Command::Eval(args) => eval::eval(&args),
        #[cfg(feature = "eval")]
        Command::Bench(args) => bench::bench(&args),
    }
}
