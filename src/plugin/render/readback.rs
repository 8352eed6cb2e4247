//! Reading back what the compact path's compute passes wrote, for tests and
//! benchmarks: per view and species, each tree's LOD, its per-tree draws,
//! the placed draws and the sorted expanded placements. Opt-in
//! ([`CompactReadback::enabled`]) and blocking (the render world waits for
//! the copies each frame), so never on in a game.

use super::{CompactViews, ConiferSpecies};
use bevy::prelude::*;
use bevy::render::render_resource::{Buffer, BufferDescriptor, BufferUsages, CommandEncoder};
use bevy::render::renderer::RenderDevice;

/// Main world: set `enabled` to have every frame's compute results read
/// back; `views` then holds the last frame's (one frame late).
#[derive(Resource, Clone, Debug, Default)]
pub struct CompactReadback {
    /// Read back every frame while `true`.
    pub enabled: bool,
    /// What the compute passes wrote for each view and species.
    pub views: Vec<ViewReadback>,
}

/// What one view's compute passes wrote for one species.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct ViewReadback {
    /// The species.
    pub species: AssetId<ConiferSpecies>,
    /// Whether the view is a perspective one (cameras, point and spot
    /// lights; directional cascades are not).
    pub perspective: bool,
    /// Vertices a line takes in the view's draws: 6 where it draws lines as
    /// quads ([`crate::plugin::LineRaster::Area`] in cameras, shadow views
    /// with [`crate::plugin::ConiferLodSettings::shadow_line_quads`]), 2 as
    /// hardware lines.
    pub line_vertices: u32,
    /// Per tree (instance slot): threshold code and flags, spatial error,
    /// pixel error and transition, then the view point (the camera in the
    /// tree's frame and the error per metre of distance, 0 without one) as
    /// bits (`InstanceLod`).
    pub lods: Vec<[u32; 8]>,
    /// Per-tree indirect draws, one block of `trees` per tree part
    /// (`PartKind::index`): vertex count, instance count, first vertex,
    /// first instance.
    pub tree_draws: Vec<[u32; 4]>,
    /// Placed indirect draws, one block of `prototypes × PLACED_BANDS` per
    /// placed part.
    pub placed_draws: Vec<[u32; 4]>,
    /// The expanded placements in draw order: tree (31 bits) and the
    /// original-lines-from-needles flag (bit 31), then placement (16 bits)
    /// and the threshold code.
    pub entries: Vec<[u32; 2]>,
    /// A camera's draws of each expanded placement's lines, back to front,
    /// its merged lines then its original lines (each draw's first
    /// instance is its entry's index in `entries`; a placement without
    /// lines and every rank past the last entry draw nothing). Empty for
    /// other views.
    pub ordered_draws: Vec<[u32; 4]>,
    /// Per entry of `entries` (by index), the split of its draw in
    /// `ordered_draws`: the line its merged lines end at (in the merged
    /// lines' order) and its first original line (in the original lines'
    /// order; `model::compact::EntryLines`). Empty for other views.
    pub ordered_splits: Vec<[u32; 2]>,
}

impl ViewReadback {
    /// Tree `tree`'s threshold code and spatial error (tree metres).
    pub fn tree_lod(&self, tree: usize) -> (u16, f32) {
        let [code, e, ..] = self.lods[tree];
        ((code & 0xffff) as u16, f32::from_bits(e))
    }

    /// How far tree `tree` has faded into its crown impostor, in `[0, 1]`
    /// (the cull pass's 8 bits; `model::impostor::impostor_fade`).
    pub fn impostor_fade(&self, tree: usize) -> f32 {
        f32::from((self.lods[tree][0] >> 24) as u8) / 255.0
    }

    /// Tree `tree`'s indirect draw of part `kind`.
    pub fn tree_draw(&self, kind: super::gpu::PartKind, tree: usize) -> [u32; 4] {
        self.tree_draws[kind.index() * self.lods.len() + tree]
    }

    /// Tree `tree`'s view point (view-dependent detail: the camera in the
    /// tree's frame and the error per metre), if the cull pass wrote one.
    pub fn view_point(&self, tree: usize) -> Option<crate::model::ViewPoint> {
        let [.., x, y, z, slope] = self.lods[tree].map(f32::from_bits);
        (slope > 0.0).then(|| crate::model::ViewPoint::new(Vec3::new(x, y, z), slope))
    }

    /// Prisms and needle lines the vertex shaders process for this view,
    /// counted from the indirect draws the compute passes wrote: the
    /// per-tree draws of prisms, original and merged lines, and every
    /// placed draw (vertices over vertices a primitive, times instances).
    pub fn processed_primitives(&self, max_sides: u8) -> u64 {
        let prism_vertices = u64::from(crate::model::prism::prism_slot_vertices(max_sides));
        let line_vertices = u64::from(self.line_vertices.max(1));
        let per_primitive = |part: usize| if part == 0 { prism_vertices } else { line_vertices };
        let count = |draw: &[u32; 4], part: usize| u64::from(draw[0]) / per_primitive(part) * u64::from(draw[1]);
        // The first three blocks (prisms, original lines, merged lines) of
        // `block` draws each.
        let needle_parts = |draws: &[[u32; 4]], block: usize| -> u64 {
            draws
                .chunks(block.max(1))
                .take(3)
                .enumerate()
                .flat_map(|(part, block)| block.iter().map(move |d| count(d, part)))
                .sum()
        };
        let tree = needle_parts(&self.tree_draws, self.lods.len());
        let placed = needle_parts(&self.placed_draws, self.placed_draws.len() / super::PLACED_PART_KINDS);
        tree + placed
    }
}

/// Render world: whether to read back, and the copies under way.
#[derive(Resource, Default)]
pub(super) struct PendingReadbacks {
    pub(super) enabled: bool,
    staged: Vec<Staged>,
    done: Vec<ViewReadback>,
}

struct Staged {
    species: AssetId<ConiferSpecies>,
    perspective: bool,
    line_vertices: u32,
    buffer: Buffer,
    /// Byte lengths of the lods, tree draws, placed draws, counters,
    /// sorted entries, back-to-front line draws and their splits in
    /// `buffer`, in that order.
    lengths: [u64; 7],
    trees: usize,
    draws: usize,
    entry_capacity: usize,
    depth_ordered: bool,
}

pub(super) fn extract_request(
    request: bevy::render::Extract<Res<CompactReadback>>,
    mut pending: ResMut<PendingReadbacks>,
) {
    pending.enabled = request.enabled;
}

/// Encodes copies of every view's results into staging buffers (after the
/// compute pass).
pub(super) fn stage(
    encoder: &mut CommandEncoder,
    device: &RenderDevice,
    views: &CompactViews,
    pending: &mut PendingReadbacks,
) {
    if !pending.enabled {
        return;
    }
    for ((_, species), view) in &views.views {
        let p = &view.placed;
        let sources = [
            &view.lods,
            &view.args,
            &p.args,
            &p.counters,
            &p.sorted,
            &p.ordered,
            &p.ordered_splits,
        ];
        let lengths = sources.map(|b| b.size());
        let buffer = device.create_buffer(&BufferDescriptor {
            label: Some("conifer compact readback"),
            size: lengths.iter().sum(),
            usage: BufferUsages::MAP_READ | BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        let mut offset = 0;
        for (source, length) in sources.into_iter().zip(lengths) {
            encoder.copy_buffer_to_buffer(source, 0, &buffer, offset, length);
            offset += length;
        }
        pending.staged.push(Staged {
            species: *species,
            perspective: view.perspective,
            line_vertices: view.line_vertices,
            buffer,
            lengths,
            trees: view.instance_count as usize,
            draws: p.draws as usize,
            entry_capacity: p.entry_capacity as usize,
            depth_ordered: p.depth_ordered,
        });
    }
}

fn words(bytes: &[u8]) -> Vec<u32> {
    bytes
        .chunks_exact(4)
        .map(|w| u32::from_le_bytes([w[0], w[1], w[2], w[3]]))
        .collect()
}

/// After the frame is submitted: waits for the copies and decodes them.
pub(super) fn collect(device: Res<RenderDevice>, mut pending: ResMut<PendingReadbacks>) {
    let staged = std::mem::take(&mut pending.staged);
    if staged.is_empty() {
        return;
    }
    for s in &staged {
        s.buffer
            .slice(..)
            .map_async(bevy::render::render_resource::MapMode::Read, |_| {});
    }
    if device
        .poll(bevy::render::render_resource::PollType::wait_indefinitely())
        .is_err()
    {
        return;
    }
    let mut done = Vec::new();
    for s in staged {
        let bytes = s.buffer.slice(..).get_mapped_range().to_vec();
        s.buffer.unmap();
        let mut at = 0usize;
        let mut part = |k: usize| {
            let range = at..at + s.lengths[k] as usize;
            at += s.lengths[k] as usize;
            words(&bytes[range])
        };
        let (lods, tree, placed, counters, sorted, ordered, splits) =
            (part(0), part(1), part(2), part(3), part(4), part(5), part(6));
        let trees = s.trees;
        let quads = |w: &[u32], n: usize| w.chunks_exact(4).take(n).map(|c| [c[0], c[1], c[2], c[3]]).collect();
        // Entries kept (an entry whose parent line a view point reaches is
        // dropped): the draws' counts.
        let first_count = super::gpu::PLACED_COUNTER_HEADER as usize;
        let entry_count: usize = counters
            .iter()
            .skip(first_count)
            .take(s.draws)
            .map(|&c| c as usize)
            .sum();
        done.push(ViewReadback {
            species: s.species,
            perspective: s.perspective,
            line_vertices: s.line_vertices,
            lods: lods
                .chunks_exact(8)
                .take(trees)
                .map(|c| std::array::from_fn(|k| c[k]))
                .collect(),
            tree_draws: quads(&tree, trees * super::TREE_PART_KINDS),
            placed_draws: quads(&placed, s.draws * super::PLACED_PART_KINDS),
            entries: sorted
                .chunks_exact(2)
                .take(entry_count.min(s.entry_capacity))
                .map(|c| [c[0], c[1]])
                .collect(),
            ordered_draws: if s.depth_ordered {
                quads(&ordered, usize::MAX)
            } else {
                Vec::new()
            },
            ordered_splits: if s.depth_ordered {
                splits
                    .chunks_exact(2)
                    .take(entry_count.min(s.entry_capacity))
                    .map(|c| [c[0], c[1]])
                    .collect()
            } else {
                Vec::new()
            },
        });
    }
    pending.done = done;
}

/// Copies the last results to the main world.
pub(super) fn publish(mut pending: ResMut<PendingReadbacks>, mut main_world: ResMut<bevy::render::MainWorld>) {
    if pending.done.is_empty() {
        return;
    }
    if let Some(mut target) = main_world.get_resource_mut::<CompactReadback>() {
        target.views = std::mem::take(&mut pending.done);
    }
}
