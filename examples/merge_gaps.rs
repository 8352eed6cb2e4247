//! Merges across gaps: of a record's merges with error at most `E` metres,
//! how many joined two lines lying farther apart than that error (the merge
//! error bounds how far the needles lie from the line, not how much of the
//! line they cover, so a line may bridge a gap between two collinear
//! lines). Used in the README's "Table 1, reproduced" to compare the
//! partner searches.
//!
//! ```text
//! cargo run --release --no-default-features --example merge_gaps -- E RECORD...
//! ```

use bevy_conifer_lod::model::merge::segment_distance;
use bevy_conifer_lod::model::read_record;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let mut args = std::env::args().skip(1);
    let error: f32 = args.next().ok_or("usage: merge_gaps E RECORD...")?.parse()?;
    for path in args {
        let record = read_record(std::path::Path::new(&path))?;
        let (mut merges, mut gaps) = (0u64, 0u64);
        for merged in record.merged.iter().filter(|m| m.error <= error) {
            merges += 1;
            let [(a1, b1), (a2, b2)] = merged.children.map(|child| {
                let ends = record.node_ends(child);
                (ends[0].0, ends[1].0)
            });
            if segment_distance(a1, b1, a2, b2) > merged.error {
                gaps += 1;
            }
        }
        println!("{path}: {merges} merges with error ≤ {error} m, {gaps} of them across a gap wider than their error");
    }
    Ok(())
}
