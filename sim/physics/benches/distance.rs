//! Hot paths of the physics crate, each beside a baseline measured in the same run:
//! - exact distance transform of a 128³ mask vs a plain pass over the same mask (memory baseline),
//!   single-threaded and on all threads;
//! - labelling l(x, d) and parameter lookup vs a bare trilinear CT sample (1 kHz loop lookups).

use criterion::{Criterion, criterion_group, criterion_main};
use std::hint::black_box;
use stylet_physics::distance::{signed_distance_map, squared_edt};
use stylet_physics::glam::DVec3;
use stylet_physics::{Affine, Grid, Param, PunctureAtlas, Role, synthetic_atlas};

fn ball_mask(n: usize) -> (Grid, Vec<bool>) {
    let g = Grid::new([n; 3], Affine::from_spacing([1.5; 3], DVec3::splat(-(n as f64) * 0.75))).unwrap();
    let mask = (0..g.len())
        .map(|i| {
            let [a, b, c] = g.unlinear(i);
            let p = g.voxel_to_world(a, b, c);
            (p / DVec3::new(80.0, 60.0, 70.0)).length() < 1.0
        })
        .collect();
    (g, mask)
}

fn distance(c: &mut Criterion) {
    let (g, mask) = ball_mask(128);
    let mut group = c.benchmark_group("distance_128cubed");
    group.sample_size(10);
    group.bench_function("baseline_mask_to_f32_pass", |b| {
        b.iter(|| black_box(mask.iter().map(|&m| if m { 0.0f32 } else { 1.0 }).collect::<Vec<f32>>()))
    });
    let one = rayon::ThreadPoolBuilder::new().num_threads(1).build().unwrap();
    group.bench_function("squared_edt_1_thread", |b| {
        b.iter(|| one.install(|| black_box(squared_edt(&g, &mask))))
    });
    group.bench_function("squared_edt_all_threads", |b| {
        b.iter(|| black_box(squared_edt(&g, &mask)))
    });
    group.bench_function("signed_distance_map", |b| {
        b.iter(|| black_box(signed_distance_map(&g, &mask)))
    });
    group.finish();
}

fn small_atlas() -> PunctureAtlas {
    let g = Grid::new([64; 3], Affine::from_spacing([2.0; 3], DVec3::splat(-64.0))).unwrap();
    let ct: Vec<f32> = (0..g.len())
        .map(|i| {
            let [a, b, c] = g.unlinear(i);
            let r = g.voxel_to_world(a, b, c).length();
            if r < 40.0 {
                60.0
            } else if r < 55.0 {
                -100.0
            } else {
                -1000.0
            }
        })
        .collect();
    let labels: Vec<u16> = ct.iter().map(|&v| if v == 60.0 { 10 } else { 0 }).collect();
    synthetic_atlas::atlas_with(
        g,
        ct,
        labels,
        &[(10, "liver", Role::Organ)],
        synthetic_atlas::body_ramp(),
    )
    .unwrap()
}

fn lookups(c: &mut Criterion) {
    let atlas = small_atlas();
    let points: Vec<DVec3> = (0..100_000)
        .map(|i| {
            let f = i as f64;
            DVec3::new(
                (f * 0.37).sin() * 60.0,
                (f * 0.11).cos() * 60.0,
                (f * 0.07).sin() * 60.0,
            )
        })
        .collect();
    let mut group = c.benchmark_group("lookups_100k_points");
    group.sample_size(20);
    group.bench_function("baseline_trilinear_ct_sample", |b| {
        b.iter(|| points.iter().map(|&p| atlas.hu_at(p)).sum::<f64>())
    });
    group.bench_function("label_at", |b| {
        b.iter(|| points.iter().map(|&p| atlas.label_at(p, 20.0) as u64).sum::<u64>())
    });
    group.bench_function("param_at_cut_threshold", |b| {
        b.iter(|| {
            points
                .iter()
                .map(|&p| atlas.param_at(p, 20.0, Param::CutThresholdN))
                .sum::<f64>()
        })
    });
    group.finish();
}

criterion_group!(benches, distance, lookups);
criterion_main!(benches);
