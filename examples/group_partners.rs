//! Which phyllotaxy groups can merge with another at a view's error at
//! all: a bound on the line counts of the README's "Table 1, reproduced"
//! that no merge order beats.
//!
//! Grows a young preset (the eastern white pine by default), merges each
//! group (a fascicle) down to its line as the bake does (level 1, errors
//! the needles' capsule), and for every group finds, over every other
//! group, the smallest error a merge of the two lines can have: the line
//! through the farthest pair of their four ends (as every merge takes
//! it), its error the thinnest capsule around it that holds their ten
//! needles, and no less than either group's own error
//! ([`needle_reach`], as `MergeErrorBound::Needles` tightens it). A pair
//! whose two lines lie farther apart than that error merges across a gap
//! (the README's `merge_gaps`). Printed for the paper's four views
//! (45°, 1536 px, ε = 1): how many groups have a partner at or under the
//! view's spatial error, with and without merging across a gap, and the
//! least number of lines the view can then draw.
//!
//! The bound: the errors of a merge forest grow up it, so a line of the
//! cut with error at most `e` that stands for several groups has, below
//! it, a merge of two group lines with error at most `e`. The groups with
//! no partner at `e` are lines of their own at that view; if every group
//! with a partner went into one single line the cut would still draw
//! `groups − partnered + 1` lines. That holds where every group's own
//! error is under the view's (the cut draws no group split into its
//! needles); where some are over, the tool prints no bound.
//!
//! ```text
//! cargo run --release --no-default-features --example group_partners -- [SPECIES]
//! ```

use bevy_conifer_lod::generate::{Age, GenerateOptions, Species, generate};
use bevy_conifer_lod::model::merge::{
    CostContext, MergeOptions, endpoint_position, merge_group, needle_reach, point_segment_distance, segment_distance,
    tighten_group_errors,
};
use bevy_conifer_lod::model::{Needle, PixelError, ViewParams};
use glam::Vec3;
use rayon::prelude::*;
use std::collections::BTreeMap;

const DISTANCES: [f32; 4] = [12.22, 26.71, 56.15, 118.40];

/// One group's root line and its needles.
struct GroupLine {
    a: Vec3,
    b: Vec3,
    error: f32,
    needles: Vec<Needle>,
}

/// The smallest error a merge of `x` and `y` can have (their line through
/// the farthest pair of their ends), if under `limit`; whether the two
/// lines lie farther apart than it.
fn pair_error(x: &GroupLine, y: &GroupLine, limit: f32) -> Option<(f32, bool)> {
    let ends = [x.a, x.b, y.a, y.b];
    let mut farthest = (0, 1, -1.0f32);
    for i in 0..4 {
        for j in i + 1..4 {
            let d = ends[i].distance(ends[j]);
            if d > farthest.2 {
                farthest = (i, j, d);
            }
        }
    }
    let (a, b) = (ends[farthest.0], ends[farthest.1]);
    // The four ends are needle ends: a cheap floor of the needles' reach.
    let floor = 2.0
        * ends
            .iter()
            .map(|&p| point_segment_distance(p, a, b))
            .fold(0.0f32, f32::max);
    let floor = floor.max(x.error).max(y.error);
    if floor > limit {
        return None;
    }
    let error = x
        .needles
        .iter()
        .chain(&y.needles)
        .map(|n| needle_reach(n, a, b))
        .fold(floor, f32::max);
    (error <= limit).then(|| (error, segment_distance(x.a, x.b, y.a, y.b) > error))
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let species: Species = std::env::args()
        .nth(1)
        .as_deref()
        .unwrap_or("eastern-white-pine")
        .parse()?;
    let tree = generate(
        species,
        &GenerateOptions {
            age: Age::Young,
            ..GenerateOptions::default()
        },
    );
    let mut groups: BTreeMap<u32, Vec<Needle>> = BTreeMap::new();
    for needle in tree.needles.iter().filter(|n| n.is_valid()) {
        groups.entry(needle.group).or_default().push(*needle);
    }
    let options = MergeOptions::default();
    let context = CostContext::for_options(&options, 1.0, tree.needles.len());
    let lines: Vec<GroupLine> = groups
        .into_values()
        .par_bridge()
        .map(|needles| {
            if needles.len() == 1 {
                let n = needles[0];
                let error = needle_reach(&n, n.base, n.tip);
                return GroupLine {
                    a: n.base,
                    b: n.tip,
                    error,
                    needles,
                };
            }
            let mut merged = merge_group(&needles, &context, &options);
            tighten_group_errors(&needles, &mut merged);
            let root = merged.last().expect("a group of several needles merges");
            GroupLine {
                a: endpoint_position(&needles, root.ends[0]),
                b: endpoint_position(&needles, root.ends[1]),
                error: root.error,
                needles,
            }
        })
        .collect();
    let view = ViewParams {
        vertical_fov: 45f32.to_radians(),
        viewport_height_px: 1536.0,
        pixel_error: PixelError(1.0),
    };
    let errors = DISTANCES.map(|d| view.spatial_error(d));
    let largest = errors.iter().copied().fold(0.0f32, f32::max);
    // Per group: its best partner's error, over all partners and over
    // those it does not reach across a gap.
    let best: Vec<(f32, f32)> = (0..lines.len())
        .into_par_iter()
        .map(|i| {
            let (mut any, mut no_gap) = (f32::INFINITY, f32::INFINITY);
            for (j, other) in lines.iter().enumerate() {
                if i == j {
                    continue;
                }
                if let Some((error, gap)) = pair_error(&lines[i], other, no_gap.min(largest)) {
                    any = any.min(error);
                    if !gap {
                        no_gap = no_gap.min(error);
                    }
                }
            }
            (any, no_gap)
        })
        .collect();
    let groups = lines.len();
    println!("{species} (young): {} needles in {groups} groups", tree.needles.len());
    println!(
        "| distance | spatial error | groups over it | with a partner, no gap | least lines, no gap | with a partner | least lines |"
    );
    println!("|---:|---:|---:|---:|---:|---:|---:|");
    for (distance, e) in DISTANCES.into_iter().zip(errors) {
        let over = lines.iter().filter(|l| l.error > e).count();
        let no_gap = best.iter().filter(|b| b.1 <= e).count();
        let any = best.iter().filter(|b| b.0 <= e).count();
        // Where a group's own error is over the view's, the cut splits it
        // into needles and the bound does not apply.
        let least = |partnered: usize| match over {
            0 => (groups - partnered + usize::from(partnered > 0)).to_string(),
            _ => "–".to_owned(),
        };
        println!(
            "| {distance:.2} m | {:.1} mm | {over} | {no_gap} | {} | {any} | {} |",
            e * 1e3,
            least(no_gap),
            least(any)
        );
    }
    Ok(())
}
