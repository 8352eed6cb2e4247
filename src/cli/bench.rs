//! `conifer bench`: the whole-app figures of BENCHMARKS.md as one JSON object.

use crate::bench::{BenchOptions, run};
use anyhow::Context;
use std::path::PathBuf;

/// Arguments of `conifer bench`.
#[derive(Debug, clap::Args)]
pub struct BenchArgs {
    /// A CI-sized run (about 2 minutes): every part, small. A smoke test of
    /// the harness, not figures to quote.
    #[arg(long)]
    pub quick: bool,
    /// Directory of the shipped records (bytes per needle, load time).
    #[arg(long, default_value = "assets/trees")]
    pub records: PathBuf,
    /// Directory for plots and forest pictures.
    #[arg(long, default_value = "target/bench")]
    pub out: PathBuf,
    /// Run only these parts (bake, records, prototypes, cuts, runtime, presets, forest).
    #[arg(long, value_delimiter = ',')]
    pub only: Vec<String>,
    /// Needles of each preset of the `presets` part (default: each
    /// species' own count).
    #[arg(long)]
    pub preset_needles: Option<usize>,
    /// Needles of each mature preset of the `prototypes` part (default
    /// 1,000,000; 2,000,000 is what the shipped mature records hold).
    #[arg(long)]
    pub prototype_needles: Option<usize>,
    /// Print one JSON object on stdout (otherwise a summary).
    #[arg(long)]
    pub json: bool,
}

pub(super) fn bench(args: &BenchArgs) -> anyhow::Result<()> {
    let conifer = std::env::current_exe().context("cannot find the conifer executable for the bake runs")?;
    const PARTS: [&str; 7] = ["bake", "records", "prototypes", "cuts", "runtime", "presets", "forest"];
    if let Some(bad) = args.only.iter().find(|p| !PARTS.contains(&p.as_str())) {
        anyhow::bail!("--only {bad:?}: the parts are {}", PARTS.join(", "));
    }
    let mut options = if args.quick {
        BenchOptions::quick(conifer, args.records.clone(), args.out.clone())
    } else {
        BenchOptions::full(conifer, args.records.clone(), args.out.clone())
    };
    options.only = args.only.clone();
    if args.preset_needles.is_some() {
        options.preset_needles = args.preset_needles;
    }
    if let Some(needles) = args.prototype_needles {
        if needles == 0 {
            anyhow::bail!("--prototype-needles 0: a tree needs needles");
        }
        options.prototype_needles = needles;
    }
    let report = run(&options, &mut |line| eprintln!("bench: {line}")).context("benchmark failed")?;
    if args.json {
        println!("{}", serde_json::to_string(&report)?);
        return Ok(());
    }
    println!("machine: {} ({} build)", report.machine, report.profile);
    for (mode, bakes) in [("flat", &report.bake), ("shoot prototypes", &report.bake_prototypes)] {
        for b in bakes {
            println!(
                "bake {:>9} needles ({mode}, {} prototypes): {:8.3} s ({:.0} needles/s), peak {:.0} MB, {:.2} MB on disk",
                b.needles,
                b.prototypes,
                b.seconds,
                b.needles_per_second,
                b.peak_bytes.unwrap_or(0) as f64 / 1e6,
                b.file_bytes as f64 / 1e6
            );
        }
    }
    println!("bake exponent (log-log): {:.3}", report.bake_exponent);
    for (name, r) in &report.bytes_per_needle {
        println!(
            "{name}: {:.1} B/needle on disk, {:.1} B/needle on the GPU, decode {:.1} ms, build {:.1} ms",
            r.disk_bytes_per_needle, r.gpu_bytes_per_needle, r.decode_ms, r.build_ms
        );
        println!(
            "  processed / cut {}",
            processed_over_cut(&r.distances, &r.processed_over_cut)
        );
    }
    for (name, t) in &report.prototype_trees {
        println!(
            "{name}: {} needles as {} prototypes ({} needles) placed {} times: {:.2} MB on disk, {:.2} MB on the GPU",
            t.needles,
            t.prototypes,
            t.prototype_needles,
            t.placements,
            t.file_bytes as f64 / 1e6,
            t.gpu_bytes as f64 / 1e6
        );
        println!(
            "  processed / cut {}",
            processed_over_cut(&t.distances, &t.processed_over_cut)
        );
    }
    for r in &report.runtime {
        println!(
            "{:>7} trees: systems {:.3} ms ({:.0} ns/tree), whole {:.3} ms ({:.0} ns/tree)",
            r.instances, r.systems_ms_per_frame, r.systems_ns_per_instance, r.cpu_ms_per_frame, r.ns_per_instance
        );
    }
    if let Some(p) = &report.presets {
        println!(
            "{} presets ({} needles) baking under {} trees: longest frame {:.2} ms (p99 {:.2}, median {:.2}) over {} frames, \
             idle longest {:.2} ms (p99 {:.2}, median {:.2}); baked in {:.1} s, read from the cache in {:.0} ms",
            p.presets.len(),
            p.needles,
            p.trees,
            p.baking_frame_ms_max,
            p.baking_frame_ms_p99,
            p.baking_frame_ms_median,
            p.baking_frames,
            p.idle_frame_ms_max,
            p.idle_frame_ms_p99,
            p.idle_frame_ms_median,
            p.bake_seconds,
            p.cached_load_ms
        );
        println!(
            "  frames over the idle median + 2 ms: {} baking, {} idle",
            p.baking_frames_over_2ms, p.idle_frames_over_2ms
        );
        if let (Some(app), Some(flat)) = (p.cached_app_heap_bytes, p.flattened_heap_bytes) {
            println!(
                "  the cached app holds {:.0} MB of heap; the species' flattened records, once asked for, {:.0} MB more",
                app as f64 / 1e6,
                flat as f64 / 1e6
            );
        }
    }
    if let Some(c) = &report.cut_us {
        for (k, d) in c.distances.iter().enumerate() {
            println!(
                "cut at {d:>5} m ({} primitives): {:.1} us with the three-part start, {:.1} us from the roots, {:.2} us counts only",
                c.primitives[k], c.three_part_start[k], c.from_roots[k], c.counts_only[k]
            );
        }
    }
    if let Some(r) = &report.render_ratio {
        println!(
            "forest of {} trees: ours {:.0} ms, raw {:.0} ms ({:.1}x), bevy-lod {:.0} ms ({:.1}x); \
             without MSAA: ours {:.0} ms, bevy-lod {:.0} ms; ours in a light breeze {:.0} ms",
            r.instances,
            r.ours_ms,
            r.raw_ms,
            r.raw_over_ours,
            r.bevylod_ms,
            r.bevylod_over_ours,
            r.ours_no_msaa_ms,
            r.bevylod_no_msaa_ms,
            r.ours_in_wind_ms
        );
    }
    Ok(())
}

/// `at 5 m 1.27, at 20 m 1.37, …`.
fn processed_over_cut(distances: &[f32], ratios: &[f64]) -> String {
    distances
        .iter()
        .zip(ratios)
        .map(|(d, r)| format!("at {d} m {r:.2}"))
        .collect::<Vec<_>>()
        .join(", ")
}
