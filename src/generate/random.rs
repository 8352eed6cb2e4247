//! The seeded random stream of one tree.

use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64Mcg;

/// Independent streams drawn from one seed, so that changing how many
/// numbers one stage draws does not reshuffle the other.
#[derive(Clone, Copy, Debug)]
pub(crate) enum Stream {
    /// Trunk, branches, shoots and sprays.
    Skeleton = 1,
    /// Needle placement on the shoots.
    Foliage = 2,
    /// Tree-level choices (the default needle count's vigour factor).
    Tree = 3,
}

/// A PCG generator with the handful of draws the grower needs.
pub(crate) struct TreeRng {
    inner: Pcg64Mcg,
}

impl TreeRng {
    /// The stream `stream` of the tree with seed `seed`.
    pub(crate) fn new(seed: u64, stream: Stream) -> Self {
        let mixed = seed ^ (stream as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15);
        Self {
            inner: Pcg64Mcg::seed_from_u64(mixed),
        }
    }

    /// Uniform in `[0, 1)`.
    pub(crate) fn unit(&mut self) -> f32 {
        (self.inner.next_u32() >> 8) as f32 * (1.0 / 16_777_216.0)
    }

    /// Uniform in `[lo, hi)`.
    pub(crate) fn range(&mut self, (lo, hi): (f32, f32)) -> f32 {
        lo + (hi - lo) * self.unit()
    }

    /// Uniform in `[-1, 1)`.
    pub(crate) fn signed(&mut self) -> f32 {
        2.0 * self.unit() - 1.0
    }

    /// `value` scaled by a random factor in `[1 - fraction, 1 + fraction)`.
    pub(crate) fn jitter(&mut self, value: f32, fraction: f32) -> f32 {
        value * (1.0 + fraction * self.signed())
    }

    /// `true` with probability `p`.
    pub(crate) fn chance(&mut self, p: f32) -> bool {
        self.unit() < p
    }

    /// Uniform integer in `lo..=hi`.
    pub(crate) fn count(&mut self, (lo, hi): (u32, u32)) -> u32 {
        if hi <= lo {
            return lo;
        }
        lo + self.inner.next_u32() % (hi - lo + 1)
    }

    /// `x` rounded up or down at random, so that the mean is `x`.
    pub(crate) fn round(&mut self, x: f32) -> u32 {
        let floor = x.max(0.0).floor();
        floor as u32 + u32::from(self.unit() < x - floor)
    }
}
