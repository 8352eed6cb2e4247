//! CPU cost of the plugin per frame, no rendering: `MinimalPlugins` plus the
//! plugin, trees of 4 species (5,000 needles each) on a grid, a camera
//! flying through. Prints one JSON object per instance count (see
//! `bevy_conifer_lod::bench::runtime`); `conifer bench` runs the same code.
//!
//! ```text
//! cargo bench --bench plugin_runtime [-- 100 1000 10000 100000]
//! ```

fn main() {
    let counts: Vec<usize> = std::env::args().skip(1).filter_map(|a| a.parse().ok()).collect();
    let counts = if counts.is_empty() {
        vec![100, 1_000, 10_000, 100_000]
    } else {
        counts
    };
    let records = bevy_conifer_lod::bench::species_records(5_000);
    for instances in counts {
        let figures = bevy_conifer_lod::bench::runtime::runtime(&records, instances, 60);
        println!("{}", serde_json::to_string(&figures).expect("serializes"));
    }
}
