//! Agreement of the sweep ([`viewshed`]) with one exact line of sight per
//! cell ([`viewshed_exact`]) from 1.7 m above the centre of cell (COL, ROW):
//! `cargo run --release --example viewshed_agree -- DEM COL ROW`.
use demsketch::raster::read_height_map;
use demsketch::render::{viewshed, viewshed_exact, LocalTerrain};
use demsketch::view::{Georef, Viewpoint};
use std::time::Instant;

fn main() -> anyhow::Result<()> {
    let a: Vec<String> = std::env::args().collect();
    anyhow::ensure!(a.len() == 4, "usage: viewshed_agree DEM COL ROW");
    let (col, row): (f64, f64) = (a[2].parse()?, a[3].parse()?);
    let map = read_height_map(std::path::Path::new(&a[1]))?;
    let (x, y) = map.geotransform.pixel_to_crs(col + 0.5, row + 0.5);
    let georef = Georef::new(&map, "dem")?;
    let (lon, lat) = georef.crs_to_lonlat(x, y)?;
    let frame = georef.local_frame(&Viewpoint::above_surface(lon, lat, 1.7), &map, 1.0 / 7.0)?;
    let terrain = LocalTerrain::new(&map, &frame, None);
    let t = Instant::now();
    let sweep = viewshed(&terrain, &map, 0.0);
    let sweep_s = t.elapsed().as_secs_f64();
    let t = Instant::now();
    let exact = viewshed_exact(&terrain, &map, 0.0);
    let exact_s = t.elapsed().as_secs_f64();
    let (mut total, mut only_sweep, mut only_exact) = (0usize, 0usize, 0usize);
    for (i, (&s, &e)) in sweep.data.iter().zip(&exact.data).enumerate() {
        if map.data[i].is_nan() {
            continue;
        }
        total += 1;
        only_sweep += usize::from(s == 255 && e != 255);
        only_exact += usize::from(e == 255 && s != 255);
    }
    println!(
        "{}: agreement {:.4} % of {total} (only sweep {only_sweep}, only exact {only_exact}; visible {} / {}), sweep {sweep_s:.3} s, exact {exact_s:.3} s",
        a[1],
        100.0 * (total - only_sweep - only_exact) as f64 / total.max(1) as f64,
        sweep.visible_count(),
        exact.visible_count()
    );
    Ok(())
}
