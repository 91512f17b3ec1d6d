//! Atlas generation and loading, each beside a baseline measured in the same run: loading an
//! atlas (decompress, validate, thresholds, body mask, two distance maps, hash) vs only
//! decompressing its two NIfTI files; generating a phantom vs writing it. On the default phantom
//! (256 × 256 × 200): a load from the derived-data cache, a cold load (no cache: derive and write
//! it) and a load that does not use the cache, against the same decompression baseline (the
//! nibabel side of the comparison is `benches/atlas_load/nibabel_load.py`).

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
        b.iter(|| black_box(stylet_atlas::load_with(dir.path(), stylet_atlas::CacheMode::Off).unwrap()))
    });
    group.bench_function("generate_phantom", |b| b.iter(|| black_box(generate(&config).unwrap())));
    group.bench_function("write_atlas", |b| {
        let out = tempfile::tempdir().unwrap();
        b.iter(|| stylet_atlas::write(out.path(), &p.manifest, &p.ct, &p.partial).unwrap())
    });
    group.finish();
}

fn gunzip_volumes(dir: &std::path::Path) -> usize {
    let mut n = 0;
    for f in ["ct.nii.gz", "labels.nii.gz"] {
        let mut buf = Vec::new();
        flate2::read::MultiGzDecoder::new(std::fs::File::open(dir.join(f)).unwrap())
            .read_to_end(&mut buf)
            .unwrap();
        n += buf.len();
    }
    n
}

fn default_phantom_load(c: &mut Criterion) {
    use stylet_atlas::{CacheMode, CacheStatus};
    let dir = tempfile::tempdir().unwrap();
    let p = generate(&PhantomConfig::default()).unwrap();
    stylet_atlas::write(dir.path(), &p.manifest, &p.ct, &p.partial).unwrap();
    let cache = dir.path().join(stylet_atlas::cache::CACHE_DIR);

    // One timed pass of each first, printed as ratios to the baseline (criterion's means follow).
    let time = |f: &mut dyn FnMut()| {
        let mut best = f64::INFINITY;
        for _ in 0..3 {
            let t = std::time::Instant::now();
            f();
            best = best.min(t.elapsed().as_secs_f64());
        }
        best
    };
    let base = time(&mut || {
        black_box(gunzip_volumes(dir.path()));
    });
    let uncached = time(&mut || {
        black_box(stylet_atlas::load_with(dir.path(), CacheMode::Off).unwrap());
    });
    // A cold load returns while its cache is written on a thread of its own; the write's wait
    // (what dropping the atlas or asking its status costs right after the load) is timed apart.
    let (mut cold, mut cold_write) = (f64::INFINITY, 0.0);
    for _ in 0..3 {
        let _ = std::fs::remove_dir_all(&cache);
        let t = std::time::Instant::now();
        let a = stylet_atlas::load(dir.path()).unwrap();
        let returned = t.elapsed().as_secs_f64();
        assert_eq!(a.cache_status(), CacheStatus::Written);
        if returned < cold {
            cold = returned;
            cold_write = t.elapsed().as_secs_f64() - returned;
        }
    }
    let cached = time(&mut || {
        let a = stylet_atlas::load(dir.path()).unwrap();
        assert_eq!(a.cache_status(), CacheStatus::Hit);
    });
    println!(
        "default phantom: gunzip {:.3} s; load cached {:.3} s ({:.2}×), cold {:.3} s ({:.2}×; its cache written {:.3} s later), without cache {:.3} s ({:.2}×); cold / without cache {:.3}",
        base,
        cached,
        cached / base,
        cold,
        cold / base,
        cold_write,
        uncached,
        uncached / base,
        cold / uncached
    );

    let mut group = c.benchmark_group("atlas_default_phantom");
    group.sample_size(10);
    group.bench_function("baseline_gunzip_volumes", |b| {
        b.iter(|| black_box(gunzip_volumes(dir.path())))
    });
    group.bench_function("load_cached", |b| {
        b.iter(|| black_box(stylet_atlas::load(dir.path()).unwrap()))
    });
    group.bench_function("load_cold_writes_cache", |b| {
        b.iter(|| {
            let _ = std::fs::remove_dir_all(&cache);
            // Timed until the cache is on disk (the atlas is dropped inside the iteration).
            black_box(stylet_atlas::load(dir.path()).unwrap().cache_status())
        })
    });
    group.bench_function("load_without_cache", |b| {
        b.iter(|| black_box(stylet_atlas::load_with(dir.path(), CacheMode::Off).unwrap()))
    });
    group.finish();
}

criterion_group!(benches, atlas, default_phantom_load);
criterion_main!(benches);
