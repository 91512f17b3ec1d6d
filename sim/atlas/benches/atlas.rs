//! Atlas generation and loading, each beside a baseline measured in the same run: loading an
//! atlas (decompress, validate, thresholds, body mask, two distance maps, hash) vs only
//! decompressing its two NIfTI files; generating a phantom vs writing it.

use std::hint::black_box;
use std::io::Read;

use criterion::{Criterion, criterion_group, criterion_main};
use stylet_atlas::phantom::{PhantomConfig, generate};

fn atlas(c: &mut Criterion) {
    let config = PhantomConfig {
        dims: [128, 128, 100],
        spacing_mm: [3.0; 3],
        ..PhantomConfig::default()
    };
    let dir = tempfile::tempdir().unwrap();
    let p = generate(&config).unwrap();
    stylet_atlas::write(dir.path(), &p.manifest, &p.ct, &p.partial).unwrap();

    let mut group = c.benchmark_group("atlas_128x128x100");
    group.sample_size(10);
    group.bench_function("baseline_gunzip_volumes", |b| {
        b.iter(|| {
            let mut n = 0;
            for f in ["ct.nii.gz", "labels.nii.gz"] {
                let mut buf = Vec::new();
                flate2::read::MultiGzDecoder::new(std::fs::File::open(dir.path().join(f)).unwrap())
                    .read_to_end(&mut buf)
                    .unwrap();
                n += buf.len();
            }
            black_box(n)
        })
    });
    group.bench_function("load_and_validate", |b| {
        b.iter(|| black_box(stylet_atlas::load(dir.path()).unwrap()))
    });
    group.bench_function("generate_phantom", |b| b.iter(|| black_box(generate(&config).unwrap())));
    group.bench_function("write_atlas", |b| {
        let out = tempfile::tempdir().unwrap();
        b.iter(|| stylet_atlas::write(out.path(), &p.manifest, &p.ct, &p.partial).unwrap())
    });
    group.finish();
}

criterion_group!(benches, atlas);
criterion_main!(benches);
