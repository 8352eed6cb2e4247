//! The bake: from a [`TreeInput`] to a [`LodRecord`] (paper, §4–5.1).

use super::calibration::{CalibrationOptions, LineCalibration, calibrate_lines};
use super::impostor::{CrownImpostor, ImpostorOptions};
use super::merge::{
    CostContext, GroupLine, MergeCostRule, MergeErrorBound, MergeOptions, merge_group_lines, merge_nested_group,
    tighten_group_errors,
};
use super::metric::{MAX_PRISM_SIDES, MIN_PRISM_SIDES};
use super::needle::{Needle, TreeInput, bounds};
use super::prototype::{MAX_PLACED_NEEDLES, Placement, Prototype, PrototypeInput, PrototypeRecord};
use super::quantize::{prototype_grid, quantize_needle};
use super::record::{BakeInfo, LodRecord, RecordInvalid};
use glam::Quat;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use std::sync::Arc;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::time::Instant;

/// Options of a bake.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct BakeOptions {
    /// `Lmax`: most sides of a needle's prism, in `[3, 64]` (default 8).
    pub max_sides: u8,
    /// Line-merging options.
    pub merge: MergeOptions,
    /// The crown impostor baked into the record (the far representation,
    /// [`super::impostor`]), or `None` for none (the plugin then bakes one
    /// each time it loads the record).
    #[serde(default = "default_impostor")]
    pub impostor: Option<ImpostorOptions>,
    /// How the lines' opacity is calibrated against the needles' coverage
    /// ([`super::calibration`]), or `None` for no calibration (every line
    /// keeps its opacity).
    #[serde(default = "default_line_calibration")]
    pub line_calibration: Option<CalibrationOptions>,
}

fn default_impostor() -> Option<ImpostorOptions> {
    Some(ImpostorOptions::default())
}

fn default_line_calibration() -> Option<CalibrationOptions> {
    Some(CalibrationOptions::default())
}

impl Default for BakeOptions {
    fn default() -> Self {
        Self {
            max_sides: 8,
            merge: MergeOptions::default(),
            impostor: default_impostor(),
            line_calibration: default_line_calibration(),
        }
    }
}

/// Why a bake failed.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum BakeError {
    /// The input has no needles.
    #[error("the tree has no needles")]
    NoNeedles,
    /// A needle has a NaN, a radius ≤ 0 or a zero-length centerline.
    #[error("needle {index} is invalid (non-finite, radius ≤ 0 or zero length)")]
    InvalidNeedle {
        /// Index of the needle in the input.
        index: usize,
    },
    /// The wood mesh has an index out of range, a partial triangle, a
    /// normal count unlike its position count, or a non-finite number.
    #[error("the wood mesh is inconsistent (index out of range, partial triangle or non-finite number)")]
    InvalidWoodMesh,
    /// `max_sides` is outside `[3, 64]`.
    #[error("max sides {0} is outside [3, 64]")]
    MaxSides(u8),
    /// Merge weights negative, non-finite or all zero.
    #[error("merge weights must be finite, non-negative and not all zero")]
    Weights,
    /// More needles than a record can hold.
    #[error("{0} needles: a record holds at most 2^24")]
    TooManyNeedles(usize),
    /// A prototype's needle has a NaN, a radius ≤ 0 or a zero-length centerline.
    #[error("needle {needle} of prototype {prototype} is invalid (non-finite, radius ≤ 0 or zero length)")]
    InvalidPrototypeNeedle {
        /// Index of the prototype.
        prototype: usize,
        /// Index of the needle in the prototype.
        needle: usize,
    },
    /// A placement names a missing prototype, or has a non-finite number,
    /// a scale ≤ 0 or a rotation that is not a unit quaternion.
    #[error("placement {index} is invalid (unknown prototype, non-finite number, scale ≤ 0 or zero rotation)")]
    InvalidPlacement {
        /// Index of the placement.
        index: usize,
    },
    /// The result failed the record's own checks (a bug, reported, not a panic).
    #[error("internal: the baked record is inconsistent: {0}")]
    Inconsistent(#[from] RecordInvalid),
}

/// A stage of the bake, for progress reports.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum BakeStage {
    /// Merging inside phyllotaxy groups.
    MergeGroups,
    /// Merging across the tree.
    MergeTree,
    /// Baking the crown impostor (`done` 0 when it starts, 1 when it ends).
    Impostor,
    /// Calibrating the lines' opacity (`done` 0 when it starts, 1 when it
    /// ends).
    LineCalibration,
}

/// Receives progress of a bake.
pub trait BakeProgress: Sync {
    /// `done` of `total` steps of `stage` are finished.
    fn progress(&self, stage: BakeStage, done: usize, total: usize);
}

impl BakeProgress for () {
    fn progress(&self, _: BakeStage, _: usize, _: usize) {}
}

/// A [`BakeProgress`] that passes reports on to another and notes when each
/// stage last reported, so a bake's time splits into merge level 1 (groups),
/// level 2 (whole tree) and the rest (validation, record assembly).
pub struct StageTimer<'a> {
    inner: &'a dyn BakeProgress,
    start: Instant,
    last: std::sync::Mutex<[Option<f64>; 2]>,
    /// When the impostor's bake started and ended.
    impostor: std::sync::Mutex<[Option<f64>; 2]>,
    /// When the line calibration started and ended.
    line_calibration: std::sync::Mutex<[Option<f64>; 2]>,
}

/// Seconds of a bake's stages, from a [`StageTimer`].
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct StageSeconds {
    /// Level 1: merging inside phyllotaxy groups (with the needle sort before it).
    pub merge_groups: f64,
    /// Level 2: merging across the tree.
    pub merge_tree: f64,
    /// The rest of the bake: validation and building the record.
    pub record: f64,
    /// Baking the crown impostor.
    #[serde(default)]
    pub impostor: f64,
    /// Calibrating the lines' opacity.
    #[serde(default)]
    pub line_calibration: f64,
}

impl<'a> StageTimer<'a> {
    /// Starts the clock now; reports go on to `inner`.
    pub fn new(inner: &'a dyn BakeProgress) -> Self {
        Self {
            inner,
            start: Instant::now(),
            last: std::sync::Mutex::new([None, None]),
            impostor: std::sync::Mutex::new([None, None]),
            line_calibration: std::sync::Mutex::new([None, None]),
        }
    }

    /// The split of `total` seconds (the whole bake, timed by the caller
    /// from [`StageTimer::new`]): each stage ends at its last report. A
    /// stage that never reported (no groups, one line) takes no time.
    pub fn seconds(&self, total: f64) -> StageSeconds {
        let last = *self.last.lock().unwrap_or_else(|e| e.into_inner());
        let groups_end = last[0].unwrap_or(0.0);
        let tree_end = last[1].unwrap_or(groups_end).max(groups_end);
        let span = |span: &std::sync::Mutex<[Option<f64>; 2]>| match *span.lock().unwrap_or_else(|e| e.into_inner()) {
            [Some(start), Some(end)] => (end - start).max(0.0),
            _ => 0.0,
        };
        let (impostor, line_calibration) = (span(&self.impostor), span(&self.line_calibration));
        StageSeconds {
            merge_groups: groups_end,
            merge_tree: tree_end - groups_end,
            record: (total - tree_end - impostor - line_calibration).max(0.0),
            impostor,
            line_calibration,
        }
    }
}

impl BakeProgress for StageTimer<'_> {
    fn progress(&self, stage: BakeStage, done: usize, total: usize) {
        let now = self.start.elapsed().as_secs_f64();
        let slot = match stage {
            BakeStage::MergeGroups => 0,
            BakeStage::MergeTree => 1,
            BakeStage::Impostor | BakeStage::LineCalibration => {
                let span = if stage == BakeStage::Impostor {
                    &self.impostor
                } else {
                    &self.line_calibration
                };
                if let Ok(mut span) = span.lock() {
                    span[done.min(1)] = Some(now);
                }
                self.inner.progress(stage, done, total);
                return;
            }
        };
        if let Ok(mut last) = self.last.lock() {
            last[slot] = Some(last[slot].map_or(now, |t: f64| t.max(now)));
        }
        self.inner.progress(stage, done, total);
    }
}

/// Bakes a flat tree: every phyllotaxy group a prototype placed once
/// ([`PrototypeInput::from_tree`], groups in order of first appearance),
/// baked by [`bake_prototypes`] and flattened.
pub fn bake(input: &TreeInput, options: &BakeOptions, progress: &dyn BakeProgress) -> Result<LodRecord, BakeError> {
    if let Some(index) = input.needles.iter().position(|n| !n.is_valid()) {
        return Err(BakeError::InvalidNeedle { index });
    }
    let record = bake_prototypes(&PrototypeInput::from_tree(input), options, progress)?;
    let start = Instant::now();
    let mut flat = record.flatten()?;
    flat.bake.bake_seconds = record.bake.bake_seconds.map(|s| s + start.elapsed().as_secs_f64());
    Ok(flat)
}

/// The paper's model of a baked tree (§4): `record`'s needles merged again,
/// over the record's groups as [`bake`] merges a flat tree, with the
/// paper's weighted cost ([`MergeCostRule::Weighted`], the record's
/// weights) and nested error ([`MergeErrorBound::Nested`]); the wood,
/// material, crown impostor and line calibration are `record`'s.
/// `conifer eval` draws its `paper` method from it, beside ours from
/// `record` itself.
pub fn paper_model(record: &LodRecord) -> Result<LodRecord, BakeError> {
    let input = TreeInput {
        name: record.name.clone(),
        needles: record.needles.clone(),
        wood: record.wood.clone(),
        wood_mesh: record.wood_mesh.clone(),
        material: record.material,
    };
    let mut options = BakeOptions {
        max_sides: record.max_sides,
        impostor: None,
        line_calibration: None,
        ..BakeOptions::default()
    };
    options.merge.weights = record.bake.weights;
    options.merge.cost_rule = MergeCostRule::Weighted;
    options.merge.error_bound = MergeErrorBound::Nested;
    let mut paper = bake(&input, &options, &())?;
    paper.impostor = record.impostor.clone();
    paper.line_calibration = record.line_calibration;
    Ok(paper)
}

/// Bakes a tree of prototypes: validates the needles and placements, snaps
/// normals to the record's storage precision, merges each prototype down to
/// one line once (level 1, prototypes in parallel), then the placed
/// prototype lines across the tree (level 2), and builds the record.
///
/// Level 1's cost is measured in tree units at the prototype's mean
/// placement scale (the crown diagonal over that scale, the tree's needle
/// count), so a flat tree (every scale 1) merges as the paper does.
pub fn bake_prototypes(
    input: &PrototypeInput,
    options: &BakeOptions,
    progress: &dyn BakeProgress,
) -> Result<PrototypeRecord, BakeError> {
    let start = Instant::now();
    if !(MIN_PRISM_SIDES..=MAX_PRISM_SIDES).contains(&options.max_sides) {
        return Err(BakeError::MaxSides(options.max_sides));
    }
    if !options.merge.weights.is_valid() {
        return Err(BakeError::Weights);
    }
    let placed = input.placed_needle_count();
    if placed == 0 {
        return Err(BakeError::NoNeedles);
    }
    if placed > MAX_PLACED_NEEDLES {
        return Err(BakeError::TooManyNeedles(placed as usize));
    }
    for (prototype, needles) in input.prototypes.iter().enumerate() {
        if let Some(needle) = needles.iter().position(|n| !n.is_valid()) {
            return Err(BakeError::InvalidPrototypeNeedle { prototype, needle });
        }
    }
    if let Some(index) = input
        .placements
        .iter()
        .position(|p| !(p.is_valid() && (p.prototype as usize) < input.prototypes.len()))
    {
        return Err(BakeError::InvalidPlacement { index });
    }
    if !input.wood_mesh.is_valid() {
        return Err(BakeError::InvalidWoodMesh);
    }
    let placements: Vec<Placement> = input
        .placements
        .iter()
        .map(|p| Placement {
            rotation: if p.rotation == Quat::IDENTITY {
                p.rotation
            } else {
                p.rotation.normalize()
            },
            ..*p
        })
        .collect();
    // Needles as the record stores them (format 4: ends on the prototype's
    // grid, radius and normal on their codes), before anything is measured
    // on them, so the merged lines' errors hold for the stored needles.
    let mut prototype_needles: Vec<Vec<Needle>> = Vec::with_capacity(input.prototypes.len());
    for (prototype, needles) in input.prototypes.iter().enumerate() {
        // Valid needles (checked above) have no grid only when one lies
        // beyond `quantize::MAX_GRID_COORDINATE`.
        let grid = prototype_grid(needles).ok_or(BakeError::InvalidPrototypeNeedle { prototype, needle: 0 })?;
        let quantized = needles
            .iter()
            .enumerate()
            .map(|(needle, n)| {
                quantize_needle(&Needle { group: 0, ..*n }, &grid)
                    .ok_or(BakeError::InvalidPrototypeNeedle { prototype, needle })
            })
            .collect::<Result<Vec<_>, _>>()?;
        prototype_needles.push(quantized);
    }

    // The cost context: the placed crown's diagonal and needle count.
    let placed_points = placements.iter().flat_map(|p| {
        prototype_needles[p.prototype as usize]
            .iter()
            .flat_map(move |n| [p.place_point(n.base), p.place_point(n.tip)])
    });
    let diagonal = bounds(placed_points).map_or(0.0, |(lo, hi)| lo.distance(hi));
    let total = placed as usize;
    let mut scale_sum = vec![(0.0f64, 0u32); prototype_needles.len()];
    for p in &placements {
        let entry = &mut scale_sum[p.prototype as usize];
        *entry = (entry.0 + p.scale as f64, entry.1 + 1);
    }

    // Level 1: each prototype once, in parallel.
    let group_total: usize = prototype_needles.iter().map(|n| n.len().saturating_sub(1)).sum();
    let done = AtomicUsize::new(0);
    let prototypes: Vec<Prototype> = prototype_needles
        .into_par_iter()
        .zip(scale_sum.par_iter())
        .zip(input.prototypes.par_iter())
        .map(|((needles, &(sum, count)), original)| {
            let mean_scale = if count == 0 { 1.0 } else { (sum / count as f64) as f32 };
            let context = CostContext::for_options(&options.merge, diagonal / mean_scale, total);
            // A twig's shoots and fascicles are merged first, then across it.
            let groups: Vec<u32> = original.iter().map(|n| n.group).collect();
            let mut merged = merge_nested_group(&needles, &groups, &context, &options.merge);
            if options.merge.error_bound == MergeErrorBound::Needles {
                tighten_group_errors(&needles, &mut merged);
            }
            let so_far = done.fetch_add(merged.len(), Ordering::Relaxed) + merged.len();
            progress.progress(BakeStage::MergeGroups, so_far, group_total);
            Prototype { needles, merged }
        })
        .collect();

    // Level 2: the placed prototype lines across the tree.
    let mut first_needle = 0u32;
    let group_lines: Vec<GroupLine> = placements
        .iter()
        .map(|p| {
            let prototype = &prototypes[p.prototype as usize];
            let root = prototype.root();
            let ends = prototype.node_ends(root);
            let line = GroupLine {
                a: p.place_point(prototype.endpoint(ends[0])),
                b: p.place_point(prototype.endpoint(ends[1])),
                ends: ends.map(|e| 2 * first_needle + e),
                error: prototype.node_error(root) * p.scale,
                needles: prototype.needles.len() as u32,
            };
            first_needle += prototype.needles.len() as u32;
            line
        })
        .collect();
    let tree_total = group_lines.len().saturating_sub(1);
    let context = CostContext::for_options(&options.merge, diagonal, total);
    let tree_merged = merge_group_lines(&group_lines, &context, options.merge.tree_search, |k| {
        if k % 1024 == 0 || k == tree_total {
            progress.progress(BakeStage::MergeTree, k, tree_total)
        }
    });

    let info = BakeInfo {
        weights: options.merge.weights,
        bake_seconds: None,
        source: input.name.clone(),
    };
    let mut record = PrototypeRecord::from_parts(
        input.name.clone(),
        prototypes,
        placements,
        tree_merged,
        input.wood.clone(),
        input.wood_mesh.clone(),
        input.material,
        options.max_sides,
        info,
    )?;
    if options.merge.error_bound == MergeErrorBound::Needles {
        record.tighten_tree_errors();
    }
    // What the record file stores (needles, errors and placements on their
    // codes): writing and reading the bake's record is exact.
    record = record.quantized()?;
    if let Some(impostor) = options.impostor {
        progress.progress(BakeStage::Impostor, 0, 1);
        record.impostor = bake_impostor(&record, impostor);
        progress.progress(BakeStage::Impostor, 1, 1);
    }
    if let Some(calibration) = options.line_calibration {
        progress.progress(BakeStage::LineCalibration, 0, 1);
        record.line_calibration = calibrate_record_lines(&record, &calibration)?;
        progress.progress(BakeStage::LineCalibration, 1, 1);
    }
    record.bake.bake_seconds = Some(start.elapsed().as_secs_f64());
    Ok(record)
}

/// The line calibration of `record` ([`calibrate_lines`] on the record
/// flattened; `None` where it gives none).
pub fn calibrate_record_lines(
    record: &PrototypeRecord,
    options: &CalibrationOptions,
) -> Result<Option<LineCalibration>, RecordInvalid> {
    Ok(calibrate_lines(&record.flatten()?, options))
}

/// The crown impostor of `record`'s placed needles and wood, baked with
/// `options`, with the ages and sides of the needles its views see
/// ([`super::color::NeedleMix::seen`]) and how bright they are lit against
/// its texels ([`CrownImpostor::view_light_scale`]); `None` where
/// [`CrownImpostor::bake`] gives none (options out of range).
pub fn bake_impostor(record: &PrototypeRecord, options: ImpostorOptions) -> Option<Arc<CrownImpostor>> {
    let needles = record.placed_needles();
    let mut impostor = CrownImpostor::bake(&needles, &record.wood, &record.wood_mesh, options)?;
    impostor.seen_needles = super::color::NeedleMix::seen(record, &needles, &impostor);
    impostor.view_light_scale = Some(impostor.view_light_scale(&record.wood, &needles));
    Some(Arc::new(impostor))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::generate::{GenerateOptions, Species, generate};

    #[test]
    fn the_paper_model_is_the_papers_bake_of_the_same_needles() {
        let tree = generate(
            Species::ScotsPine,
            &GenerateOptions {
                seed: 5,
                target_needles: Some(3000),
                age: crate::generate::Age::Young,
            },
        );
        let bare = BakeOptions {
            impostor: None,
            line_calibration: None,
            ..BakeOptions::default()
        };
        let ours = bake(&tree, &bare, &()).unwrap();
        let paper = paper_model(&ours).unwrap();
        let mut options = bare;
        options.merge.cost_rule = MergeCostRule::Weighted;
        options.merge.error_bound = MergeErrorBound::Nested;
        let direct = bake(&tree, &options, &()).unwrap();
        assert_eq!(paper.needles, ours.needles);
        assert_eq!(paper.merged, direct.merged);
        assert_ne!(paper.merged, ours.merged, "the paper's cost builds another forest");
        assert_eq!(paper.wood, ours.wood);
    }

    #[test]
    fn stage_timer_splits_the_bake_in_order() {
        let tree = generate(
            Species::NorwaySpruce,
            &GenerateOptions {
                seed: 3,
                target_needles: Some(4000),
                age: crate::generate::Age::Young,
            },
        );
        let timer = StageTimer::new(&());
        let record = bake(&tree, &BakeOptions::default(), &timer).unwrap();
        let total = timer.start.elapsed().as_secs_f64();
        let s = timer.seconds(total);
        assert!(!record.merged.is_empty());
        assert!(record.impostor.is_some(), "the default bake holds the impostor");
        assert!(
            record.line_calibration.is_some(),
            "the default bake calibrates the lines"
        );
        assert!(
            s.merge_groups > 0.0
                && s.merge_tree > 0.0
                && s.record >= 0.0
                && s.impostor > 0.0
                && s.line_calibration > 0.0,
            "{s:?}"
        );
        assert!((s.merge_groups + s.merge_tree + s.record + s.impostor + s.line_calibration - total).abs() < 1e-9);
        // Nothing reported: everything is the record stage.
        let idle = StageTimer::new(&());
        assert_eq!(
            idle.seconds(2.0),
            StageSeconds {
                merge_groups: 0.0,
                merge_tree: 0.0,
                record: 2.0,
                impostor: 0.0,
                line_calibration: 0.0,
            }
        );
    }
}
