// Scratch (not committed): the bench forest, ours only.
use bevy_conifer_lod::bench::forest::{ForestMethod, forest_frame_ms};
fn main() {
    let args: Vec<String> = std::env::args().collect();
    let n: usize = args.get(1).and_then(|a| a.parse().ok()).unwrap_or(1000);
    let msaa = args.get(2).map_or(true, |a| a != "nomsaa");
    let records = bevy_conifer_lod::bench::species_records(5000);
    let pic = std::path::PathBuf::from("/tmp/forest_ours.png");
    let ms = forest_frame_ms(&records, ForestMethod::Ours, n, (640, 360), 3, msaa, Some(&pic)).unwrap();
    println!("ours {n} trees msaa {msaa}: {ms:.0} ms");
}
