//! Criterion benchmarks of the Bevy-free model: bake, cut (with and without
//! the three-part start), cut counts, record encode and decode.
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

criterion_group!(benches, bake_scaling, cuts, record_io);
criterion_main!(benches);
