//! libFuzzer target (cargo-fuzz): bytes opened as a GeoTIFF, every block
//! decoded. Errors are fine; a panic, an abort or a memory blow-up is a bug.
#![no_main]

use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    // A small budget, so that "fits the budget" cases stay cheap too.
    std::env::set_var("DEMSKETCH_MEMORY_BUDGET_MB", "256");
    let _ = demsketch::raster::geotiff::fuzz::decode_all_blocks(data);
});
