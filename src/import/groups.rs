//! Inferring phyllotaxy groups (shoots, fascicles) when a file has none.
//!
//! ## The rule
//!
//! Needles of one fascicle start at one point; needles spiralling round one
//! shoot start along one line, each a step `s` from the next; different
//! shoots are farther apart than that step. So:
//!
//! 1. The tree's base spacing `s` is the median, over the needles, of the
//!    distance from a needle's base to the nearest other needle's base.
//! 2. Two needles are linked when their bases are within
//!    `τ = link_factor · s` (default 2.5 steps), with `τ` at least a quarter
//!    of the median needle width (so fascicles whose bases coincide, where
//!    `s ≈ 0`, still join their own members only) and at most half the median
//!    needle length.
//! 3. Groups are the connected pieces of the links (single linkage): a
//!    fascicle, or a run of needles along a shoot.
//! 4. A piece larger than `max_group` needles (a long twig, or shoots
//!    joined where they touch) is cut into even runs, each at most
//!    `max_group`, of a depth-first walk over its links (from its outermost
//!    needle, nearest neighbour first): the walk follows one shoot to its
//!    end before turning into the next, so the runs are shoot segments and
//!    the first merge level stays local.
//!
//! Where shoots touch (a side shoot starting within `τ` of a needle of its
//! parent) single linkage joins them; the accuracy of the rule on trees
//! with known groups is measured in `tests/import.rs` and the README.

use super::needles::UnionFind;
use crate::model::Needle;
use glam::Vec3;
use rstar::{RTree, primitives::GeomWithData};

/// Parameters of the group rule (see the module docs).
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct GroupRule {
    /// Link distance in base spacings.
    pub link_factor: f32,
    /// Largest group; larger pieces are cut into runs along their axis.
    pub max_group: usize,
}

impl Default for GroupRule {
    fn default() -> Self {
        Self {
            link_factor: 2.5,
            max_group: 128,
        }
    }
}

/// What the rule measured on a tree.
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize)]
pub struct GroupInferenceInfo {
    /// Median distance from a base to the nearest other base, metres.
    pub base_spacing: f32,
    /// Link distance used, metres.
    pub link_distance: f32,
    /// Pieces cut because they exceeded `max_group`.
    pub pieces_cut: usize,
}

type Base = GeomWithData<[f32; 3], u32>;

/// The median (the upper one for an even count) of `values`; 0 when empty.
pub(crate) fn median(mut values: Vec<f32>) -> f32 {
    if values.is_empty() {
        return 0.0;
    }
    let mid = values.len() / 2;
    *values.select_nth_unstable_by(mid, f32::total_cmp).1
}

/// Group ids `0..groups` for `needles` by the rule.
pub fn infer_groups(needles: &[Needle], rule: &GroupRule) -> (Vec<u32>, GroupInferenceInfo) {
    let n = needles.len();
    if n == 0 {
        return (Vec::new(), GroupInferenceInfo::default());
    }
    let tree = RTree::bulk_load(
        needles
            .iter()
            .enumerate()
            .map(|(i, x)| Base::new(x.base.to_array(), i as u32))
            .collect(),
    );
    let nearest: Vec<f32> = needles
        .iter()
        .enumerate()
        .map(|(i, x)| {
            tree.nearest_neighbor_iter(x.base.to_array())
                .find(|p| p.data != i as u32)
                .map_or(f32::INFINITY, |p| Vec3::from(*p.geom()).distance(x.base))
        })
        .collect();
    let spacing = median(nearest);
    let width = median(needles.iter().map(|x| 2.0 * x.radius).collect());
    let length = median(needles.iter().map(Needle::length).collect());
    let link = (rule.link_factor * spacing).max(0.25 * width).min(2.0 * length);
    let link = if link.is_finite() { link } else { 0.0 };

    let mut sets = UnionFind::new(n);
    let mut neighbours: Vec<Vec<u32>> = vec![Vec::new(); n];
    for (i, x) in needles.iter().enumerate() {
        for p in tree.locate_within_distance(x.base.to_array(), link * link) {
            if p.data != i as u32 {
                neighbours[i].push(p.data);
                sets.union(i as u32, p.data);
            }
        }
        // Nearest last: the walk below pops it first.
        let base = x.base;
        neighbours[i].sort_by(|&a, &b| {
            let (da, db) = (
                needles[a as usize].base.distance(base),
                needles[b as usize].base.distance(base),
            );
            db.total_cmp(&da).then(b.cmp(&a))
        });
    }
    let mut pieces: std::collections::HashMap<u32, Vec<u32>> = std::collections::HashMap::new();
    let mut order = Vec::new();
    for i in 0..n as u32 {
        let root = sets.find(i);
        pieces
            .entry(root)
            .or_insert_with(|| {
                order.push(root);
                Vec::new()
            })
            .push(i);
    }
    let mut groups = vec![0u32; n];
    let mut next = 0u32;
    let mut info = GroupInferenceInfo {
        base_spacing: spacing,
        link_distance: link,
        pieces_cut: 0,
    };
    let max_group = rule.max_group.max(1);
    for root in order {
        let mut members = std::mem::take(pieces.get_mut(&root).expect("collected above"));
        if members.len() > max_group {
            info.pieces_cut += 1;
            members = walk_order(needles, &members, &neighbours);
            let runs = members.len().div_ceil(max_group);
            let run_length = members.len().div_ceil(runs);
            for run in members.chunks(run_length) {
                for &i in run {
                    groups[i as usize] = next;
                }
                next += 1;
            }
        } else {
            for &i in &members {
                groups[i as usize] = next;
            }
            next += 1;
        }
    }
    (groups, info)
}

/// The members of a linked piece in the order of a depth-first walk over
/// the links, from the member farthest from the piece's centre, nearest
/// neighbour first: the walk runs along one shoot to its end before it
/// turns into another, so even runs of it are pieces of shoots.
fn walk_order(needles: &[Needle], members: &[u32], neighbours: &[Vec<u32>]) -> Vec<u32> {
    let centre = members.iter().map(|&i| needles[i as usize].base).sum::<Vec3>() / members.len() as f32;
    let start = *members
        .iter()
        .max_by(|&&a, &&b| {
            let (da, db) = (
                needles[a as usize].base.distance(centre),
                needles[b as usize].base.distance(centre),
            );
            da.total_cmp(&db).then(b.cmp(&a))
        })
        .expect("a piece has members");
    let mut seen = std::collections::HashSet::with_capacity(members.len());
    let mut order = Vec::with_capacity(members.len());
    let mut stack = vec![start];
    while let Some(i) = stack.pop() {
        if !seen.insert(i) {
            continue;
        }
        order.push(i);
        stack.extend(neighbours[i as usize].iter().copied().filter(|j| !seen.contains(j)));
    }
    order
}

/// How well inferred groups match known ones.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct GroupAgreement {
    /// Fraction of needles in the majority true group of their inferred
    /// group (1 = no inferred group mixes true groups).
    pub purity: f64,
    /// Fraction of needles in the majority inferred group of their true
    /// group (1 = no true group is split).
    pub completeness: f64,
    /// Adjusted Rand index (1 = identical partitions, ≈ 0 = chance).
    pub adjusted_rand_index: f64,
}

/// Compares two partitions of the same needles.
pub fn group_agreement(truth: &[u32], inferred: &[u32]) -> GroupAgreement {
    use std::collections::HashMap;
    assert_eq!(truth.len(), inferred.len(), "one label per needle in both");
    let n = truth.len() as f64;
    let mut pairs: HashMap<(u32, u32), u64> = HashMap::new();
    let mut by_truth: HashMap<u32, u64> = HashMap::new();
    let mut by_inferred: HashMap<u32, u64> = HashMap::new();
    for (&t, &p) in truth.iter().zip(inferred) {
        *pairs.entry((p, t)).or_default() += 1;
        *by_truth.entry(t).or_default() += 1;
        *by_inferred.entry(p).or_default() += 1;
    }
    let mut best_p: HashMap<u32, u64> = HashMap::new();
    let mut best_t: HashMap<u32, u64> = HashMap::new();
    for (&(p, t), &c) in &pairs {
        let bp = best_p.entry(p).or_default();
        *bp = (*bp).max(c);
        let bt = best_t.entry(t).or_default();
        *bt = (*bt).max(c);
    }
    let choose2 = |x: u64| (x as f64) * (x as f64 - 1.0) / 2.0;
    let index: f64 = pairs.values().map(|&c| choose2(c)).sum();
    let a: f64 = by_inferred.values().map(|&c| choose2(c)).sum();
    let b: f64 = by_truth.values().map(|&c| choose2(c)).sum();
    let total = choose2(truth.len() as u64);
    let expected = if total > 0.0 { a * b / total } else { 0.0 };
    let max = 0.5 * (a + b);
    GroupAgreement {
        purity: best_p.values().sum::<u64>() as f64 / n,
        completeness: best_t.values().sum::<u64>() as f64 / n,
        adjusted_rand_index: if max - expected == 0.0 {
            1.0
        } else {
            (index - expected) / (max - expected)
        },
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn needle(base: Vec3, dir: Vec3) -> Needle {
        Needle {
            base,
            tip: base + dir * 0.1,
            radius: 0.0008,
            normal: dir.any_orthonormal_vector(),
            group: 0,
        }
    }

    #[test]
    fn fascicles_with_shared_bases_are_groups() {
        let mut needles = Vec::new();
        let mut truth = Vec::new();
        for f in 0..50u32 {
            let base = Vec3::new(0.0, f as f32 * 0.004, 0.0015 * (f as f32).sin());
            for k in 0..5 {
                let a = k as f32 * 1.2566 + f as f32;
                needles.push(needle(base, Vec3::new(a.cos(), 0.6, a.sin()).normalize()));
                truth.push(f);
            }
        }
        let (groups, info) = infer_groups(&needles, &GroupRule::default());
        let agreement = group_agreement(&truth, &groups);
        assert_eq!(agreement.adjusted_rand_index, 1.0, "{agreement:?} {info:?}");
    }

    #[test]
    fn shoots_are_groups_and_long_ones_are_cut() {
        let mut needles = Vec::new();
        let mut truth = Vec::new();
        for shoot in 0..6u32 {
            let start = Vec3::new(shoot as f32 * 0.3, 0.0, 0.0);
            for k in 0..100 {
                let a = k as f32 * 2.4;
                let base = start + Vec3::new(0.0015 * a.cos(), k as f32 * 0.003, 0.0015 * a.sin());
                needles.push(needle(base, Vec3::new(a.cos(), 0.8, a.sin()).normalize()));
                truth.push(shoot);
            }
        }
        let (groups, _) = infer_groups(&needles, &GroupRule::default());
        assert_eq!(group_agreement(&truth, &groups).adjusted_rand_index, 1.0);
        let rule = GroupRule {
            max_group: 40,
            ..GroupRule::default()
        };
        let (groups, info) = infer_groups(&needles, &rule);
        assert_eq!(info.pieces_cut, 6);
        let agreement = group_agreement(&truth, &groups);
        assert_eq!(agreement.purity, 1.0);
        let mut sizes = std::collections::HashMap::<u32, usize>::new();
        for g in groups {
            *sizes.entry(g).or_default() += 1;
        }
        assert!(sizes.values().all(|&s| (30..=40).contains(&s)), "{sizes:?}");
    }

    #[test]
    fn agreement_measures() {
        let same = group_agreement(&[0, 0, 1, 1], &[5, 5, 7, 7]);
        assert_eq!(
            (same.purity, same.completeness, same.adjusted_rand_index),
            (1.0, 1.0, 1.0)
        );
        let split = group_agreement(&[0, 0, 0, 0], &[0, 0, 1, 1]);
        assert_eq!((split.purity, split.completeness), (1.0, 0.5));
    }
}
