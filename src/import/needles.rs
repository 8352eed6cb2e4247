//! Splitting needle geometry into needles, and fitting each needle's
//! cylinder (the paper's input: centerline, radius, normal).
//!
//! ## Splitting
//!
//! A needle is a set of triangles connected through shared *edges*, where
//! two vertices count as the same when their indices or their positions are
//! equal (so needles written with their own unshared vertices, and quads
//! split into two triangles with duplicated corners, both come out whole).
//! Triangles touching at a single vertex only — fascicle needles sharing
//! their base point — stay separate needles.
//!
//! ## Fitting
//!
//! * normal: the area-weighted mean of the triangles' normals, each turned
//!   to agree with the largest triangle (so double-sided needles, written
//!   twice with opposite windings, do not cancel out);
//! * centerline: for a single triangle, from the mid-point of its shortest
//!   edge (the base) to the opposite corner (the apex); for four corners (a
//!   quad), between the mid-points of its two short edges (the pairing of
//!   the corners with the smallest summed distance); otherwise along the
//!   principal axis of the corners in the needle's plane, between the means
//!   of the corners within a fifth of the length of either end;
//! * radius: half the width: the extent of the corners across the
//!   centerline in the needle's plane;
//! * which end is the base: a triangle's apex is its tip; otherwise the end
//!   whose three nearest ends of other needles are clearly nearer (summed
//!   distance less than half the other end's: bases crowd on their shoot,
//!   tips fan out); otherwise the end nearer a wood vertex, when one end is
//!   within half a needle length of the wood and the other twice as far;
//!   otherwise the end with the nearer neighbours; otherwise the wider end;
//!   otherwise the end written first.
//!
//! Pieces that cannot be a needle are counted and skipped: non-finite
//! coordinates, zero area, a zero-length centerline or zero width, and
//! pieces as wide as they are long.

use super::SkipCounts;
use crate::model::Needle;
use glam::Vec3;
use rstar::{RTree, primitives::GeomWithData};
use std::collections::HashMap;

/// A fitted needle before its base/tip order and group are settled.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Fitted {
    /// The two centerline ends.
    pub ends: [Vec3; 2],
    /// Width across the centerline at each end (for the taper vote).
    pub end_widths: [f32; 2],
    /// `Some(0 or 1)` when the geometry says which end is the base.
    pub base_known: Option<usize>,
    /// Half the width.
    pub radius: f32,
    /// Unit normal.
    pub normal: Vec3,
    /// Group id of the vertices, when the file has them.
    pub group_value: Option<i64>,
}

/// Union-find with path halving.
pub(crate) struct UnionFind {
    parent: Vec<u32>,
}

impl UnionFind {
    /// `n` singletons.
    pub fn new(n: usize) -> Self {
        Self {
            parent: (0..n as u32).collect(),
        }
    }

    /// The representative of `x`.
    pub fn find(&mut self, mut x: u32) -> u32 {
        while self.parent[x as usize] != x {
            let grand = self.parent[self.parent[x as usize] as usize];
            self.parent[x as usize] = grand;
            x = grand;
        }
        x
    }

    /// Joins the sets of `a` and `b`.
    pub fn union(&mut self, a: u32, b: u32) {
        let (ra, rb) = (self.find(a), self.find(b));
        if ra != rb {
            let (lo, hi) = if ra < rb { (ra, rb) } else { (rb, ra) };
            self.parent[hi as usize] = lo;
        }
    }
}

/// Splits one primitive's triangles into needles and fits them; skipped
/// pieces are counted in `skipped`.
pub(crate) fn fit_needles(
    positions: &[Vec3],
    triangles: &[[u32; 3]],
    groups: Option<&[i64]>,
    skipped: &mut SkipCounts,
) -> Vec<Fitted> {
    // Weld vertices by exact position.
    let mut welded = vec![0u32; positions.len()];
    let mut by_position: HashMap<[u32; 3], u32> = HashMap::with_capacity(positions.len());
    for (i, p) in positions.iter().enumerate() {
        let key = p.to_array().map(|x| if x == 0.0 { 0 } else { x.to_bits() });
        welded[i] = *by_position.entry(key).or_insert(i as u32);
    }
    // Triangles with finite corners, joined through shared welded edges.
    let mut kept: Vec<[u32; 3]> = Vec::with_capacity(triangles.len());
    for tri in triangles {
        if tri.iter().any(|&i| !positions[i as usize].is_finite()) {
            skipped.non_finite += 1;
            continue;
        }
        kept.push(*tri);
    }
    let mut sets = UnionFind::new(kept.len());
    let mut edge_owner: HashMap<(u32, u32), u32> = HashMap::with_capacity(kept.len() * 3);
    for (t, tri) in kept.iter().enumerate() {
        let w = tri.map(|i| welded[i as usize]);
        for (a, b) in [(w[0], w[1]), (w[1], w[2]), (w[2], w[0])] {
            if a == b {
                continue;
            }
            let key = (a.min(b), a.max(b));
            match edge_owner.get(&key) {
                Some(&other) => sets.union(other, t as u32),
                None => {
                    edge_owner.insert(key, t as u32);
                }
            }
        }
    }
    let mut members: HashMap<u32, Vec<u32>> = HashMap::new();
    let mut order = Vec::new();
    for t in 0..kept.len() as u32 {
        let root = sets.find(t);
        let list = members.entry(root).or_insert_with(|| {
            order.push(root);
            Vec::new()
        });
        list.push(t);
    }
    let mut fitted = Vec::with_capacity(order.len());
    for root in order {
        let tris: Vec<[u32; 3]> = members[&root].iter().map(|&t| kept[t as usize]).collect();
        match fit_component(positions, &welded, &tris) {
            Ok(mut needle) => {
                needle.group_value = groups.map(|g| g[tris[0][0] as usize]);
                fitted.push(needle);
            }
            Err(reason) => reason.count(skipped),
        }
    }
    fitted
}

/// Why a piece was skipped.
enum Skip {
    ZeroArea,
    Degenerate,
    NotElongated,
}

impl Skip {
    fn count(self, skipped: &mut SkipCounts) {
        match self {
            Skip::ZeroArea => skipped.zero_area += 1,
            Skip::Degenerate => skipped.degenerate += 1,
            Skip::NotElongated => skipped.not_elongated += 1,
        }
    }
}

fn fit_component(positions: &[Vec3], welded: &[u32], tris: &[[u32; 3]]) -> Result<Fitted, Skip> {
    // Normal: area-weighted, oriented like the largest triangle.
    let faces: Vec<Vec3> = tris
        .iter()
        .map(|t| {
            let [a, b, c] = t.map(|i| positions[i as usize].as_dvec3());
            ((b - a).cross(c - a) * 0.5).as_vec3()
        })
        .collect();
    let largest = faces
        .iter()
        .copied()
        .max_by(|x, y| x.length_squared().total_cmp(&y.length_squared()))
        .unwrap_or(Vec3::ZERO);
    let area_vector = faces.iter().fold(
        Vec3::ZERO,
        |acc, &f| {
            if f.dot(largest) < 0.0 { acc - f } else { acc + f }
        },
    );
    let area: f32 = faces.iter().map(|f| f.length()).sum();
    let Some(normal) = area_vector.try_normalize().filter(|_| area > 0.0 && area.is_finite()) else {
        return Err(Skip::ZeroArea);
    };

    // The distinct corners.
    let mut corners: Vec<Vec3> = Vec::with_capacity(4);
    let mut seen: Vec<u32> = Vec::with_capacity(4);
    for &i in tris.iter().flatten() {
        let w = welded[i as usize];
        if !seen.contains(&w) {
            seen.push(w);
            corners.push(positions[w as usize]);
        }
    }

    let (ends, base_known) = match corners.len() {
        3 => {
            // One triangle (maybe written twice): base = shortest edge.
            let [a, b, c] = [corners[0], corners[1], corners[2]];
            let edges = [
                (b.distance(c), a, (b + c) * 0.5),
                (c.distance(a), b, (c + a) * 0.5),
                (a.distance(b), c, (a + b) * 0.5),
            ];
            let (_, apex, base) = edges
                .iter()
                .copied()
                .min_by(|x, y| x.0.total_cmp(&y.0))
                .expect("three edges");
            ([base, apex], Some(0))
        }
        4 => {
            // A quad: the pairing of corners with the smallest summed
            // distance gives its two short edges.
            let c = &corners;
            let pairings = [((0, 1), (2, 3)), ((0, 2), (1, 3)), ((0, 3), (1, 2))];
            let ((a, b), (d, e)) = pairings
                .iter()
                .copied()
                .min_by(|&((a, b), (d, e)), &((f, g), (h, k))| {
                    (c[a].distance(c[b]) + c[d].distance(c[e])).total_cmp(&(c[f].distance(c[g]) + c[h].distance(c[k])))
                })
                .expect("three pairings");
            ([(c[a] + c[b]) * 0.5, (c[d] + c[e]) * 0.5], None)
        }
        _ => (principal_ends(&corners, normal), None),
    };
    let axis_vector = ends[1] - ends[0];
    let length = axis_vector.length();
    let Some(axis) = axis_vector.try_normalize() else {
        return Err(Skip::Degenerate);
    };
    let across = normal.cross(axis).normalize_or_zero();
    let (lo, hi) = corners.iter().fold((f32::INFINITY, f32::NEG_INFINITY), |(lo, hi), &p| {
        let x = (p - ends[0]).dot(across);
        (lo.min(x), hi.max(x))
    });
    let width = hi - lo;
    if !(width > 0.0 && width.is_finite() && length.is_finite()) {
        return Err(Skip::Degenerate);
    }
    if width >= length {
        return Err(Skip::NotElongated);
    }
    // Width near each end, for the taper vote.
    let end_widths = [0.0f32, 1.0].map(|t| {
        let (lo, hi) = corners
            .iter()
            .filter(|&&p| ((p - ends[0]).dot(axis) / length - t).abs() < 0.25)
            .fold((f32::INFINITY, f32::NEG_INFINITY), |(lo, hi), &p| {
                let x = (p - ends[0]).dot(across);
                (lo.min(x), hi.max(x))
            });
        (hi - lo).max(0.0)
    });
    Ok(Fitted {
        ends,
        end_widths,
        base_known,
        radius: 0.5 * width,
        normal,
        group_value: None,
    })
}

/// Ends of the principal axis (in the plane of `normal`) of `corners`: the
/// means of the corners within a fifth of the extent of either end.
fn principal_ends(corners: &[Vec3], normal: Vec3) -> [Vec3; 2] {
    let n = corners.len() as f32;
    let centre = corners.iter().copied().sum::<Vec3>() / n;
    let flat: Vec<Vec3> = corners
        .iter()
        .map(|&p| {
            let d = p - centre;
            d - normal * d.dot(normal)
        })
        .collect();
    // Power iteration on the in-plane covariance, started on the farthest corner.
    let mut axis = flat
        .iter()
        .copied()
        .max_by(|a, b| a.length_squared().total_cmp(&b.length_squared()))
        .and_then(Vec3::try_normalize)
        .unwrap_or(Vec3::X);
    for _ in 0..16 {
        let next = flat.iter().fold(Vec3::ZERO, |acc, &d| acc + d * d.dot(axis));
        match next.try_normalize() {
            Some(a) => axis = a,
            None => break,
        }
    }
    let t: Vec<f32> = corners.iter().map(|&p| (p - centre).dot(axis)).collect();
    let (lo, hi) = t.iter().fold((f32::INFINITY, f32::NEG_INFINITY), |(lo, hi), &x| {
        (lo.min(x), hi.max(x))
    });
    let band = 0.2 * (hi - lo);
    let mean_near = |target: f32| {
        let (sum, count) = corners
            .iter()
            .zip(&t)
            .filter(|&(_, &x)| (x - target).abs() <= band)
            .fold((Vec3::ZERO, 0.0f32), |(s, c), (&p, _)| (s + p, c + 1.0));
        let mid = sum / count.max(1.0);
        // Keep the end on the axis through the needle's middle.
        centre + axis * target + (mid - centre - axis * (mid - centre).dot(axis))
    };
    [mean_near(lo), mean_near(hi)]
}

type EndPoint = GeomWithData<[f32; 3], u32>;

/// Orders every needle base → tip (see the module docs) and returns them as
/// [`Needle`]s with group 0.
pub(crate) fn orient(fitted: &[Fitted], wood: &[Vec3]) -> (Vec<Needle>, OrientStats) {
    let mut stats = OrientStats::default();
    let median_length = super::groups::median(fitted.iter().map(|f| f.ends[0].distance(f.ends[1])).collect());
    let ends_tree = RTree::bulk_load(
        fitted
            .iter()
            .enumerate()
            .flat_map(|(i, f)| f.ends.map(|e| EndPoint::new(e.to_array(), i as u32)))
            .collect(),
    );
    let wood_tree = RTree::bulk_load(wood.iter().map(|p| p.to_array()).collect::<Vec<[f32; 3]>>());
    let needles = fitted
        .iter()
        .enumerate()
        .map(|(i, f)| {
            // Summed distance to the three nearest ends of other needles.
            let spread = f.ends.map(|e| {
                ends_tree
                    .nearest_neighbor_iter(e.to_array())
                    .filter(|p| p.data != i as u32)
                    .take(3)
                    .map(|p| Vec3::from(*p.geom()).distance(e))
                    .sum::<f32>()
            });
            let (more, fewer) = if spread[0] <= spread[1] { (0, 1) } else { (1, 0) };
            let base = if let Some(b) = f.base_known {
                stats.by_shape += 1;
                b
            } else if 2.0 * spread[more] + 1e-3 * median_length < spread[fewer] {
                stats.by_crowding += 1;
                more
            } else if let Some(b) = wood_vote(f, &wood_tree) {
                stats.by_wood += 1;
                b
            } else if spread[0] != spread[1] {
                stats.by_crowding += 1;
                more
            } else if (f.end_widths[0] - f.end_widths[1]).abs() > 0.05 * f.end_widths[0].max(f.end_widths[1]) {
                stats.by_taper += 1;
                usize::from(f.end_widths[1] > f.end_widths[0])
            } else {
                stats.by_order += 1;
                0
            };
            Needle {
                base: f.ends[base],
                tip: f.ends[1 - base],
                radius: f.radius,
                normal: f.normal,
                group: 0,
            }
        })
        .collect();
    (needles, stats)
}

/// The end nearer the wood, when one end is within half a needle length of
/// the wood and the other at least twice as far.
fn wood_vote(f: &Fitted, wood: &RTree<[f32; 3]>) -> Option<usize> {
    let length = f.ends[0].distance(f.ends[1]);
    let d = f.ends.map(|e| {
        wood.nearest_neighbor(e.to_array())
            .map_or(f32::INFINITY, |p| Vec3::from(*p).distance(e))
    });
    let (near, far) = if d[0] <= d[1] { (0, 1) } else { (1, 0) };
    (d[near] <= 0.5 * length && d[far] >= 2.0 * d[near] && d[far] > 0.0).then_some(near)
}

/// How the base end of the needles was decided.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize)]
pub struct OrientStats {
    /// By shape (a triangle's apex is its tip).
    pub by_shape: usize,
    /// By the nearer wood.
    pub by_wood: usize,
    /// By the end with more needle ends nearby.
    pub by_crowding: usize,
    /// By the wider end.
    pub by_taper: usize,
    /// By the order of the file's vertices.
    pub by_order: usize,
}

#[cfg(test)]
mod tests {
    use super::*;

    fn quad(base: Vec3, dir: Vec3, side: Vec3, length: f32, width: f32) -> [Vec3; 4] {
        let h = side * (0.5 * width);
        [base - h, base + dir * length - h, base + dir * length + h, base + h]
    }

    #[test]
    fn quads_with_own_vertices_are_split_and_fitted() {
        let mut positions = Vec::new();
        let mut triangles = Vec::new();
        for k in 0..10 {
            let base = Vec3::new(k as f32 * 0.01, 0.0, 0.0);
            let q = quad(base, Vec3::Y, Vec3::X, 0.1, 0.002);
            let first = positions.len() as u32;
            positions.extend_from_slice(&q);
            // Two triangles with duplicated corners (unindexed style).
            let dup = positions.len() as u32;
            positions.extend_from_slice(&[q[0], q[2]]);
            triangles.push([first, first + 1, first + 2]);
            triangles.push([dup, dup + 1, first + 3]);
        }
        let mut skipped = SkipCounts::default();
        let fitted = fit_needles(&positions, &triangles, None, &mut skipped);
        assert_eq!(fitted.len(), 10);
        assert_eq!(skipped, SkipCounts::default());
        for f in &fitted {
            assert!((f.radius - 0.001).abs() < 1e-6);
            assert!((f.ends[0].distance(f.ends[1]) - 0.1).abs() < 1e-5);
            assert!(f.normal.z.abs() > 0.999);
        }
    }

    #[test]
    fn triangles_sharing_a_base_vertex_stay_separate() {
        // Two triangle needles of a fascicle sharing one base corner.
        let mut skipped = SkipCounts::default();
        let triangles = [[0, 1, 2], [0, 3, 4]];
        let positions = vec![
            Vec3::ZERO,
            Vec3::new(0.001, 0.0, 0.0),
            Vec3::new(0.0, 0.1, 0.0),
            Vec3::new(0.0, 0.001, 0.0),
            Vec3::new(0.0, 0.0, 0.1),
        ];
        let fitted = fit_needles(&positions, &triangles, None, &mut skipped);
        assert_eq!(fitted.len(), 2);
        for f in &fitted {
            assert_eq!(f.base_known, Some(0));
            assert!(f.ends[0].length() < 0.001, "base is the short edge's mid-point");
        }
    }

    #[test]
    fn degenerate_pieces_are_counted() {
        let positions = vec![
            Vec3::ZERO,
            Vec3::X,
            Vec3::new(2.0, 0.0, 0.0), // collinear: zero area
            Vec3::new(0.0, 0.0, 5.0),
            Vec3::new(f32::NAN, 0.0, 0.0),
            Vec3::new(0.0, 5.0, 5.0),
            Vec3::new(0.0, 0.0, 10.0),
            Vec3::new(1.0, 0.0, 10.0),
            Vec3::new(0.5, 0.9, 10.0), // equilateral-ish: not elongated
        ];
        let triangles = [[0, 1, 2], [3, 4, 5], [6, 7, 8]];
        let mut skipped = SkipCounts::default();
        let fitted = fit_needles(&positions, &triangles, None, &mut skipped);
        assert!(fitted.is_empty());
        assert_eq!(skipped.zero_area, 1);
        assert_eq!(skipped.non_finite, 1);
        assert_eq!(skipped.not_elongated, 1);
    }

    #[test]
    fn strips_of_many_quads_fit_along_their_axis() {
        // A needle made of 4 quads in a row (10 corners), tapering.
        let mut positions = Vec::new();
        for k in 0..5 {
            let w = 0.002 * (1.0 - 0.15 * k as f32);
            positions.push(Vec3::new(-0.5 * w, 0.02 * k as f32, 0.0));
            positions.push(Vec3::new(0.5 * w, 0.02 * k as f32, 0.0));
        }
        let mut triangles = Vec::new();
        for k in 0..4u32 {
            let (a, b, c, d) = (2 * k, 2 * k + 1, 2 * k + 3, 2 * k + 2);
            triangles.push([a, b, c]);
            triangles.push([a, c, d]);
        }
        let mut skipped = SkipCounts::default();
        let fitted = fit_needles(&positions, &triangles, None, &mut skipped);
        assert_eq!(fitted.len(), 1);
        let f = fitted[0];
        let (lo, hi) = (f.ends[0].y.min(f.ends[1].y), f.ends[0].y.max(f.ends[1].y));
        assert!(lo < 0.005 && hi > 0.075, "{:?}", f.ends);
        assert!((f.radius - 0.001).abs() < 1e-5);
        let (needles, stats) = orient(&fitted, &[]);
        assert_eq!(stats.by_taper, 1);
        assert!(needles[0].base.y < needles[0].tip.y, "the wider end is the base");
    }
}
