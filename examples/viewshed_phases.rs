//! Times the phases of a viewshed (read, terrain, sweep) on one DEM:
//! `cargo run --release --example viewshed_phases -- DEM COL ROW`.
use demsketch::raster::read_height_map;
use demsketch::render::{viewshed, LocalTerrain};
use demsketch::view::{Georef, Viewpoint};
use std::time::Instant;

fn main() -> anyhow::Result<()> {
    let a: Vec<String> = std::env::args().collect();
    anyhow::ensure!(a.len() == 4, "usage: viewshed_phases DEM COL ROW");
    let (col, row): (f64, f64) = (a[2].parse()?, a[3].parse()?);
    let t = Instant::now();
    let map = read_height_map(std::path::Path::new(&a[1]))?;
    let read_s = t.elapsed().as_secs_f64();
    let (x, y) = map.geotransform.pixel_to_crs(col + 0.5, row + 0.5);
    let georef = Georef::new(&map, "dem")?;
    let (lon, lat) = georef.crs_to_lonlat(x, y)?;
    let t = Instant::now();
    let frame = georef.local_frame(&Viewpoint::above_surface(lon, lat, 1.7), &map, 1.0 / 7.0)?;
    let terrain = LocalTerrain::new(&map, &frame, None);
    let terrain_s = t.elapsed().as_secs_f64();
    let t = Instant::now();
    let vs = viewshed(&terrain, &map, 0.0);
    let sweep_s = t.elapsed().as_secs_f64();
    println!(
        "read {read_s:.3} s, terrain {terrain_s:.3} s, sweep {sweep_s:.3} s, visible {}",
        vs.visible_count()
    );
    Ok(())
}
