//! The XYZ tile grid of web maps ("slippy map" tiles) in Web Mercator
//! (EPSG:3857): at zoom `z` the world between latitudes +-85.0511 is
//! `2^z` x `2^z` tiles, `x` from the antimeridian eastwards and `y` from
//! the north southwards, each `TILE_SIZE` x `TILE_SIZE` pixels. The tile
//! exporter ([`super::xyz_tiles`]) uses this to say which tiles cover an
//! area and where each tile lies in metres of EPSG:3857.

/// Pixels along a tile's side.
pub const TILE_SIZE: usize = 256;

/// Half the side of the Web Mercator square, metres (pi times the WGS84
/// semi-major axis).
pub const HALF_WORLD_M: f64 = std::f64::consts::PI * 6_378_137.0;

/// The latitude where the Web Mercator square ends, degrees.
pub const MAX_LAT: f64 = 85.051_128_779_806_59;

/// Deepest zoom accepted (about 2 cm per pixel at the equator).
pub const MAX_ZOOM: u8 = 24;

/// One tile of the XYZ grid.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct TileId {
    pub z: u8,
    pub x: u32,
    pub y: u32,
}

impl TileId {
    /// `[xmin, ymin, xmax, ymax]` of the tile in EPSG:3857 metres.
    pub fn bounds_3857(&self) -> [f64; 4] {
        let size = tile_span_m(self.z);
        let xmin = -HALF_WORLD_M + self.x as f64 * size;
        let ymax = HALF_WORLD_M - self.y as f64 * size;
        [xmin, ymax - size, xmin + size, ymax]
    }

    /// The tile's path below the tree's root: `z/x/y.png`.
    pub fn relative_path(&self) -> std::path::PathBuf {
        std::path::PathBuf::from(format!("{}/{}/{}.png", self.z, self.x, self.y))
    }
}

/// Side of a tile at zoom `z`, metres of EPSG:3857.
pub fn tile_span_m(z: u8) -> f64 {
    2.0 * HALF_WORLD_M / (1u64 << z) as f64
}

/// Side of a tile's pixel at zoom `z`, metres of EPSG:3857.
pub fn pixel_span_m(z: u8) -> f64 {
    tile_span_m(z) / TILE_SIZE as f64
}

/// Longitude/latitude (degrees) to EPSG:3857 metres (the spherical
/// formula EPSG:3857 defines); latitudes are clamped to +-[`MAX_LAT`].
pub fn lonlat_to_3857(lon: f64, lat: f64) -> (f64, f64) {
    let lat = lat.clamp(-MAX_LAT, MAX_LAT).to_radians();
    let x = lon.to_radians() * 6_378_137.0;
    let y = (std::f64::consts::FRAC_PI_4 + lat / 2.0).tan().ln() * 6_378_137.0;
    (x, y)
}

/// EPSG:3857 metres to longitude/latitude, degrees.
pub fn epsg3857_to_lonlat(x: f64, y: f64) -> (f64, f64) {
    let lon = (x / 6_378_137.0).to_degrees();
    let lat = (2.0 * (y / 6_378_137.0).exp().atan() - std::f64::consts::FRAC_PI_2).to_degrees();
    (lon, lat)
}

/// The tiles at zoom `z` that intersect `[xmin, ymin, xmax, ymax]` (EPSG:3857
/// metres), as inclusive ranges `(x0, x1, y0, y1)`; `None` when the box is
/// empty or outside the world.
pub fn tile_range(z: u8, b: [f64; 4]) -> Option<(u32, u32, u32, u32)> {
    if !(b[0] < b[2] && b[1] < b[3]) || b.iter().any(|v| !v.is_finite()) {
        return None;
    }
    let n = 1u64 << z;
    let span = tile_span_m(z);
    // In tile units; a box edge on a tile edge (to 1e-9 of a tile) does
    // not reach into the next tile.
    const EPS: f64 = 1e-9;
    let tx = |x: f64| (x + HALF_WORLD_M) / span;
    let ty = |y: f64| (HALF_WORLD_M - y) / span;
    let (x0, x1) = ((tx(b[0]) + EPS).floor(), (tx(b[2]) - EPS).ceil() - 1.0);
    let (y0, y1) = ((ty(b[3]) + EPS).floor(), (ty(b[1]) - EPS).ceil() - 1.0);
    let last = (n - 1) as f64;
    if x1 < 0.0 || y1 < 0.0 || x0 > last || y0 > last {
        return None;
    }
    let c = |v: f64| v.clamp(0.0, last) as u32;
    (x0 <= x1 && y0 <= y1).then(|| (c(x0), c(x1), c(y0), c(y1)))
}

/// Parse a zoom range written `Z` or `Z0-Z1` (`8-12`), `Z0 <= Z1 <= 24`.
pub fn parse_zoom_range(s: &str) -> Result<(u8, u8), String> {
    let bad =
        || format!("--zoom '{s}' must be a zoom level or a range like 8-12 (0 to {MAX_ZOOM})");
    let (a, b) = match s.split_once('-') {
        Some((a, b)) => (a.trim(), b.trim()),
        None => (s.trim(), s.trim()),
    };
    let z0: u8 = a.parse().map_err(|_| bad())?;
    let z1: u8 = b.parse().map_err(|_| bad())?;
    if z0 > z1 || z1 > MAX_ZOOM {
        return Err(bad());
    }
    Ok((z0, z1))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn tile_zero_is_the_world() {
        let b = TileId { z: 0, x: 0, y: 0 }.bounds_3857();
        assert!((b[0] + HALF_WORLD_M).abs() < 1e-6 && (b[3] - HALF_WORLD_M).abs() < 1e-6);
        let (_, y) = lonlat_to_3857(0.0, MAX_LAT);
        assert!((y - HALF_WORLD_M).abs() < 1e-3);
    }

    #[test]
    fn known_tile_of_a_point() {
        // Zion (-113.0 E, 37.25 N) at zoom 10 is tile 190/397 (the usual
        // slippy-map formula).
        let (x, y) = lonlat_to_3857(-113.0, 37.25);
        let r = tile_range(10, [x, y, x + 1.0, y + 1.0]).expect("in the world");
        let n = 1024.0f64;
        let tx = ((-113.0 + 180.0) / 360.0 * n).floor() as u32;
        let lat = 37.25f64.to_radians();
        let ty = ((1.0 - (lat.tan() + 1.0 / lat.cos()).ln() / std::f64::consts::PI) / 2.0 * n)
            .floor() as u32;
        assert_eq!((r.0, r.2), (tx, ty));
        let (lon, la) = epsg3857_to_lonlat(x, y);
        assert!((lon + 113.0).abs() < 1e-9 && (la - 37.25).abs() < 1e-9);
    }

    #[test]
    fn a_box_on_tile_edges_covers_only_its_tiles() {
        let t = TileId { z: 5, x: 3, y: 7 }.bounds_3857();
        assert_eq!(tile_range(5, t), Some((3, 3, 7, 7)));
    }

    #[test]
    fn zoom_ranges() {
        assert_eq!(parse_zoom_range("8-12"), Ok((8, 12)));
        assert_eq!(parse_zoom_range("10"), Ok((10, 10)));
        assert!(parse_zoom_range("12-8").is_err());
        assert!(parse_zoom_range("25").is_err());
        assert!(parse_zoom_range("a-3").is_err());
    }
}
