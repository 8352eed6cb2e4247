//! Criterion benchmarks of the Bevy-free model: bake, cut (with and without
//! the three-part start), cut counts, record encode and decode, and the
//! bake's binary stamp of needles (a row run at a time against sample by
//! sample).
//!
//! ```text
//! cargo bench --bench model
//! ```

use bevy_conifer_lod::generate::{GenerateOptions, Species, generate};
use bevy_conifer_lod::model::record::CutStrategy;
use bevy_conifer_lod::model::{BakeOptions, CutCounter, PixelError, ViewParams, bake, decode_record, encode_record};
use criterion::{BenchmarkId, Criterion, Throughput, criterion_group, criterion_main};
use std::hint::black_box;

fn tree(needles: usize) -> bevy_conifer_lod::model::TreeInput {
    generate(
        Species::ScotsPine,
        &GenerateOptions {
            seed: 0,
            target_needles: Some(needles),
            age: bevy_conifer_lod::generate::Age::Young,
        },
    )
}

fn bake_scaling(c: &mut Criterion) {
    let mut group = c.benchmark_group("bake");
    group.sample_size(10);
    for needles in [5_000, 20_000, 50_000] {
        let input = tree(needles);
        group.throughput(Throughput::Elements(input.needles.len() as u64));
        group.bench_with_input(BenchmarkId::from_parameter(needles), &input, |b, input| {
            b.iter(|| bake(black_box(input), &BakeOptions::default(), &()).unwrap())
        });
    }
    group.finish();
}

fn cuts(c: &mut Criterion) {
    let record = bake(&tree(50_000), &BakeOptions::default(), &()).unwrap();
    let view = ViewParams {
        pixel_error: PixelError(1.0),
        ..ViewParams::default()
    };
    let counter = CutCounter::new(&record);
    let mut group = c.benchmark_group("cut");
    for distance in [5.0f32, 20.0, 50.0, 150.0, 400.0] {
        let e = view.spatial_error(distance);
        for (name, strategy) in [
            ("three_part_start", CutStrategy::Traversal { three_part_start: true }),
            (
                "from_roots",
                CutStrategy::Traversal {
                    three_part_start: false,
                },
            ),
        ] {
            group.bench_with_input(BenchmarkId::new(name, distance), &e, |b, &e| {
                b.iter(|| record.cut_with(black_box(e), strategy))
            });
        }
        group.bench_with_input(BenchmarkId::new("counts_only", distance), &e, |b, &e| {
            b.iter(|| counter.count(black_box(e)))
        });
    }
    group.finish();
}

fn record_io(c: &mut Criterion) {
    let record = bake(&tree(50_000), &BakeOptions::default(), &()).unwrap();
    let bytes = encode_record(&record).unwrap();
    let mut group = c.benchmark_group("record");
    group.throughput(Throughput::Bytes(bytes.len() as u64));
    group.bench_function("encode", |b| b.iter(|| encode_record(black_box(&record)).unwrap()));
    group.bench_function("decode", |b| b.iter(|| decode_record(black_box(&bytes)).unwrap()));
    group.finish();
}

/// 20,000 needle-like pieces over a 512 × 512 sample picture (sample
/// units, a deterministic scatter): `half_width` wide, about `length` long.
fn pieces(half_width: f32, length: f32) -> Vec<(glam::Vec2, glam::Vec2, f32)> {
    let mut state = 0x9E37_79B9_7F4A_7C15u64;
    let mut unit = move || {
        state ^= state << 13;
        state ^= state >> 7;
        state ^= state << 17;
        (state >> 40) as f32 / (1u64 << 24) as f32
    };
    (0..20_000)
        .map(|_| {
            let a = glam::Vec2::new(unit() * 512.0, unit() * 512.0);
            let angle = unit() * std::f32::consts::TAU;
            let b = a + glam::Vec2::new(angle.cos(), angle.sin()) * length * (0.5 + unit());
            (a, b, half_width)
        })
        .collect()
}

/// The bake's binary stamp (`SampleBits`) of needles as the impostor sees
/// them: a mature spruce's widened needles (half width 2 samples, 9
/// long) and a white pine's (a tenth of a sample, 16 long), with
/// `stamp` (a row run at a time, sample by sample under two samples wide)
/// and with `stamp_each` (every sample handed to a callback), and the
/// impostor's dense case: the same needles four deep, a needle whose box is
/// covered already skipped (`box_is_full`).
fn stamp(c: &mut Criterion) {
    use bevy_conifer_lod::model::look::{PieceEnds, SampleBits};
    let mut group = c.benchmark_group("stamp");
    group.sample_size(20);
    let ends = PieceEnds::Capped { slant: 0.3 };
    for (name, half_width, length) in [("wide", 2.0, 9.0), ("narrow", 0.1, 16.0)] {
        let pieces = pieces(half_width, length);
        group.throughput(Throughput::Elements(pieces.len() as u64));
        group.bench_function(BenchmarkId::new("runs", name), |b| {
            b.iter(|| {
                let mut bits = SampleBits::new(512, 512);
                for &(a, e, r) in &pieces {
                    bits.stamp(a, e, r, r, ends);
                }
                black_box(bits)
            })
        });
        group.bench_function(BenchmarkId::new("per_sample", name), |b| {
            b.iter(|| {
                let mut bits = SampleBits::new(512, 512);
                for &(a, e, r) in &pieces {
                    bits.stamp_each(a, e, r, r, ends, |_, _| {});
                }
                black_box(bits)
            })
        });
        group.bench_function(BenchmarkId::new("four_deep_skipping_full_boxes", name), |b| {
            b.iter(|| {
                let mut bits = SampleBits::new(512, 512);
                for _ in 0..4 {
                    for &(a, e, r) in &pieces {
                        if !bits.box_is_full(a, e, r) {
                            bits.stamp(a, e, r, r, ends);
                        }
                    }
                }
                black_box(bits)
            })
        });
    }
    group.finish();
}

criterion_group!(benches, bake_scaling, cuts, record_io, stamp);
criterion_main!(benches);
