//! A whole `edit` (load, features, matching, deformation, lowering, write)
//! on a 512 x 512 DEM with 10 strokes. Target (issue 5): at most 0.1 s.
//!
//! The DEM is the Zion fixture resampled to 512 x 512 with `gdal_translate
//! -outsize` (real terrain, about 70 x 84 m cells); the sketch has 10
//! strokes traced from the view's longest silhouettes, each lifted by up to
//! 5 px in its middle (a small change, as a user correcting a skyline
//! would draw). The corrected GeoTIFF is written on every iteration.
//!
//!     cargo bench --bench edit

use criterion::{criterion_group, criterion_main, Criterion};
#[path = "support/edit_case.rs"]
mod edit_case;

use demsketch::edit::{run, EditOptions};
use demsketch::raster::Destination;

// The allocator of the `demsketch` binary (see `src/main.rs`), so that the
// figures are those of the command line.
#[global_allocator]
static GLOBAL: mimalloc::MiMalloc = mimalloc::MiMalloc;

fn bench(c: &mut Criterion) {
    let tmp = tempfile::tempdir().unwrap();
    let (dem, sketch) = edit_case::setup(tmp.path());
    let mut opts = EditOptions::new(Destination::Path(tmp.path().join("out.tif")));
    // The figures are those of a whole edit, written whatever its fit.
    opts.allow_partial = true;
    // One run outside the timer: print the report's stage timings.
    let rep = run(&dem, &sketch, &opts).unwrap();
    let strokes: usize = rep.views.iter().map(|v| v.strokes.len()).sum();
    eprintln!(
        "edit 512 x 512, {strokes} strokes: {:?}, lowering iterations {}",
        rep.timings_s, rep.views[0].lowering_iterations
    );
    let mut g = c.benchmark_group("edit");
    g.sample_size(10);
    g.bench_function("edit_512x512_10_strokes", |b| {
        b.iter(|| run(&dem, &sketch, &opts).unwrap())
    });
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
