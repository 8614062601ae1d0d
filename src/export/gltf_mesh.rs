//! `export gltf`: a triangle mesh of an area of the DEM as binary glTF 2.0
//! (`.glb`) for 3D viewers (three.js, Blender, Cesium, any glTF viewer).
//!
//! One vertex per valid cell centre of the area (every `step`-th cell),
//! two triangles per square of four valid vertices (a nodata cell leaves a
//! hole), per-vertex normals (area-weighted face normals), 32-bit indices.
//!
//! Frame: local east-north-up (ENU) metres on the WGS84 ellipsoid,
//! origin at the centre of the area (its longitude and latitude, height 0);
//! each vertex is its cell centre's lon/lat (through PROJ) with the DEM's
//! height taken as height above the ellipsoid (no geoid applied: over an
//! area a few tens of km across this shifts the whole mesh by a near
//! constant). glTF is y-up, so glTF `x` = east, `y` = up, `z` = south
//! (= -north). The origin, the frame and the area are recorded in
//! `asset.extras.demsketch` of the file.

use std::path::Path;

use serde::Serialize;
use serde_json::json;

use super::ExportError;
use crate::raster::atomic_file::{write_bytes_verified, StagedOutputs};
use crate::raster::{Dem, Window};

/// `--bounds` that is not an area in longitude and latitude (one line).
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum BoundsError {
    #[error("--bounds '{0}' must be four numbers WEST,SOUTH,EAST,NORTH (degrees)")]
    NotFourNumbers(String),
    #[error(
        "--bounds {}: need west < east and south < north, longitudes in [-180, 180] and latitudes in [-90, 90] degrees",
        show_bounds(.0)
    )]
    OutOfRange([f64; 4]),
}

fn show_bounds(b: &[f64; 4]) -> String {
    b.map(|v| crate::num::Num(v).to_string()).join(",")
}

/// `--bounds W,S,E,N` as four numbers, held to [`check_bounds`].
///
/// ```
/// use demsketch::export::gltf_mesh::parse_bounds;
/// assert_eq!(parse_bounds("-113.1,37.2,-112.9,37.4").unwrap(), [-113.1, 37.2, -112.9, 37.4]);
/// assert!(parse_bounds("1,2,3").is_err());
/// assert!(parse_bounds("170,0,190,1").is_err());
/// ```
pub fn parse_bounds(s: &str) -> Result<[f64; 4], BoundsError> {
    let v: Vec<f64> = s
        .split(',')
        .map(|p| p.trim().parse::<f64>())
        .collect::<Result<_, _>>()
        .map_err(|_| BoundsError::NotFourNumbers(s.to_string()))?;
    let b: [f64; 4] = v
        .try_into()
        .map_err(|_| BoundsError::NotFourNumbers(s.to_string()))?;
    check_bounds(b)?;
    Ok(b)
}

/// An area `[west, south, east, north]` in WGS84 degrees: west < east and
/// south < north (an area across the antimeridian is not supported),
/// longitudes in [-180, 180], latitudes in [-90, 90]. [`export_gltf`]
/// checks it before any work.
pub fn check_bounds(b: [f64; 4]) -> Result<(), BoundsError> {
    let [w, s, e, n] = b;
    let lon = |x: f64| (-180.0..=180.0).contains(&x);
    let lat = |y: f64| (-90.0..=90.0).contains(&y);
    if w < e && s < n && lon(w) && lon(e) && lat(s) && lat(n) {
        Ok(())
    } else {
        Err(BoundsError::OutOfRange(b))
    }
}

/// What to mesh.
#[derive(Debug, Clone)]
pub struct MeshOptions {
    /// Area as lon/lat `[west, south, east, north]` (default: the whole
    /// DEM), held to [`check_bounds`].
    pub bounds_lonlat: Option<[f64; 4]>,
    /// Take every `step`-th cell in each direction.
    pub step: usize,
    /// Refuse meshes with more vertices than this.
    pub max_vertices: usize,
}

/// What was written.
#[derive(Debug, Clone, Serialize)]
pub struct MeshReport {
    pub out: String,
    /// `[col, row, width, height]` of the area on the DEM grid.
    pub window: [i64; 4],
    pub step: usize,
    pub vertices: usize,
    pub triangles: usize,
    /// Origin of the ENU frame: lon, lat (degrees), height 0.
    pub origin_lonlat: [f64; 2],
    /// glTF POSITION min and max (x east, y up, z south), metres.
    pub min: [f32; 3],
    pub max: [f32; 3],
    pub bytes: usize,
}

/// The mesh in memory.
pub struct Mesh {
    pub positions: Vec<[f32; 3]>,
    pub normals: Vec<[f32; 3]>,
    pub indices: Vec<u32>,
}

/// Mesh the area of `dem_path` and write it as `.glb` at `out`.
pub fn export_gltf(
    dem_path: &Path,
    out: &Path,
    opts: &MeshOptions,
) -> Result<MeshReport, ExportError> {
    if let Some(b) = opts.bounds_lonlat {
        check_bounds(b)?;
    }
    let dem = Dem::open(dem_path)?;
    let win = area_window(&dem, opts.bounds_lonlat)?;
    let step = opts.step.max(1);
    let (nc, nr) = (win.width.div_ceil(step), win.height.div_ceil(step));
    if nc * nr > opts.max_vertices {
        return Err(ExportError::Input {
            path: dem_path.display().to_string(),
            message: format!(
                "the area is {} x {} vertices at --step {step}, more than --max-vertices {} (raise --step or narrow --bounds)",
                nc, nr, opts.max_vertices
            ),
        });
    }
    if nc < 2 || nr < 2 {
        return Err(ExportError::Input {
            path: dem_path.display().to_string(),
            message: format!(
                "the area is {} x {} cells at --step {step}: too small for a mesh",
                nc, nr
            ),
        });
    }
    let map = dem.read_height_map(win)?;
    let (c0x, c0y) = map
        .geotransform
        .pixel_to_crs(win.width as f64 / 2.0, win.height as f64 / 2.0);
    let to_ll =
        proj::Proj::new_known_crs(&dem.crs.proj_definition(), "EPSG:4326", None).map_err(|e| {
            ExportError::Input {
                path: dem_path.display().to_string(),
                message: format!("its CRS is unknown to PROJ: {e}"),
            }
        })?;
    let (lon0, lat0) = to_ll.convert((c0x, c0y)).map_err(|e| ExportError::Input {
        path: dem_path.display().to_string(),
        message: format!("the area's centre does not convert to lon/lat: {e}"),
    })?;
    let enu = Enu::new(lon0, lat0);
    // Grid of vertex indices (u32::MAX: no vertex).
    let mut index = vec![u32::MAX; nc * nr];
    let mut positions = Vec::new();
    for j in 0..nr {
        for i in 0..nc {
            let (c, r) = (i * step, j * step);
            let h = map.data[r * win.width + c];
            if !h.is_finite() {
                continue;
            }
            let (x, y) = map
                .geotransform
                .pixel_to_crs(c as f64 + 0.5, r as f64 + 0.5);
            let Ok((lon, lat)) = to_ll.convert((x, y)) else {
                continue;
            };
            let [e, n, u] = enu.from_geodetic(lon, lat, h as f64);
            index[j * nc + i] = positions.len() as u32;
            positions.push([e as f32, u as f32, -n as f32]);
        }
    }
    let indices = triangles(&index, nc, nr);
    if indices.is_empty() {
        // (glTF has no empty accessor: every count is at least 1, and the
        // positions' min and max would be infinite)
        return Err(ExportError::Input {
            path: dem_path.display().to_string(),
            message: format!(
                "the area has no 2 x 2 block of cells with data at --step {step}: no mesh to write"
            ),
        });
    }
    let normals = vertex_normals(&positions, &indices);
    let mesh = Mesh {
        positions,
        normals,
        indices,
    };
    let (min, max) = bounds(&mesh.positions);
    let extras = json!({"demsketch": {
        "dem": dem_path.display().to_string(),
        "crs": dem.crs.proj_definition(),
        "window": [win.col, win.row, win.width, win.height],
        "step": step,
        "frame": "local east-north-up metres on WGS84; glTF x = east, y = up, z = south; DEM heights taken as ellipsoidal heights",
        "origin_lon": lon0,
        "origin_lat": lat0,
        "origin_height_m": 0.0,
    }});
    let glb = glb_bytes(&mesh, min, max, extras)?;
    let mut staged = StagedOutputs::default();
    let werr = |m: String| ExportError::Write {
        path: out.display().to_string(),
        message: m,
    };
    let tmp = staged.stage(out).map_err(werr)?;
    write_bytes_verified(&tmp, &glb).map_err(|e| werr(e.to_string()))?;
    staged.commit().map_err(werr)?;
    Ok(MeshReport {
        out: out.display().to_string(),
        window: [win.col, win.row, win.width as i64, win.height as i64],
        step,
        vertices: mesh.positions.len(),
        triangles: mesh.indices.len() / 3,
        origin_lonlat: [lon0, lat0],
        min,
        max,
        bytes: glb.len(),
    })
}

/// The DEM window of a lon/lat area (edges densified through PROJ), or
/// the whole DEM.
fn area_window(dem: &Dem, b: Option<[f64; 4]>) -> Result<Window, ExportError> {
    let Some(b) = b else {
        return Ok(dem.full_window());
    };
    let bad = |m: String| ExportError::Input {
        path: dem.path.display().to_string(),
        message: m,
    };
    let from_ll = proj::Proj::new_known_crs("EPSG:4326", &dem.crs.proj_definition(), None)
        .map_err(|e| bad(format!("its CRS is unknown to PROJ: {e}")))?;
    let mut c = [
        f64::INFINITY,
        f64::INFINITY,
        f64::NEG_INFINITY,
        f64::NEG_INFINITY,
    ];
    let n = 16;
    for k in 0..=n {
        let t = k as f64 / n as f64;
        for (lon, lat) in [
            (b[0] + (b[2] - b[0]) * t, b[1]),
            (b[0] + (b[2] - b[0]) * t, b[3]),
            (b[0], b[1] + (b[3] - b[1]) * t),
            (b[2], b[1] + (b[3] - b[1]) * t),
        ] {
            if let Ok((x, y)) = from_ll.convert((lon, lat)) {
                c = [c[0].min(x), c[1].min(y), c[2].max(x), c[3].max(y)];
            }
        }
    }
    dem.window_for_bounds(c)
        .filter(|w| !w.is_empty())
        .ok_or_else(|| {
            bad(format!(
                "--bounds {} does not overlap the DEM",
                show_bounds(&b)
            ))
        })
}

/// Two counter-clockwise (seen from above) triangles per grid square whose
/// four corners all have a vertex.
fn triangles(index: &[u32], nc: usize, nr: usize) -> Vec<u32> {
    let mut out = Vec::new();
    for j in 0..nr - 1 {
        for i in 0..nc - 1 {
            let a = index[j * nc + i];
            let b = index[j * nc + i + 1];
            let c = index[(j + 1) * nc + i];
            let d = index[(j + 1) * nc + i + 1];
            if [a, b, c, d].contains(&u32::MAX) {
                continue;
            }
            out.extend_from_slice(&[a, c, b, b, c, d]);
        }
    }
    out
}

/// Unit normals: the sum of the adjacent faces' area-weighted normals.
fn vertex_normals(p: &[[f32; 3]], idx: &[u32]) -> Vec<[f32; 3]> {
    let mut acc = vec![[0.0f64; 3]; p.len()];
    for t in idx.chunks_exact(3) {
        let [a, b, c] = [t[0] as usize, t[1] as usize, t[2] as usize];
        let v = |k: usize| [p[k][0] as f64, p[k][1] as f64, p[k][2] as f64];
        let (pa, pb, pc) = (v(a), v(b), v(c));
        let u = [pb[0] - pa[0], pb[1] - pa[1], pb[2] - pa[2]];
        let w = [pc[0] - pa[0], pc[1] - pa[1], pc[2] - pa[2]];
        let n = [
            u[1] * w[2] - u[2] * w[1],
            u[2] * w[0] - u[0] * w[2],
            u[0] * w[1] - u[1] * w[0],
        ];
        for k in [a, b, c] {
            for d in 0..3 {
                acc[k][d] += n[d];
            }
        }
    }
    acc.into_iter()
        .map(|n| {
            let l = (n[0] * n[0] + n[1] * n[1] + n[2] * n[2]).sqrt();
            if l > 0.0 {
                [(n[0] / l) as f32, (n[1] / l) as f32, (n[2] / l) as f32]
            } else {
                [0.0, 1.0, 0.0]
            }
        })
        .collect()
}

/// Component-wise min and max of the positions.
fn bounds(p: &[[f32; 3]]) -> ([f32; 3], [f32; 3]) {
    let mut min = [f32::INFINITY; 3];
    let mut max = [f32::NEG_INFINITY; 3];
    for v in p {
        for d in 0..3 {
            min[d] = min[d].min(v[d]);
            max[d] = max[d].max(v[d]);
        }
    }
    (min, max)
}

/// The mesh as a GLB file: a 12-byte header, the JSON chunk (padded with
/// spaces) and the binary chunk (positions, normals, indices; padded with
/// zeros), each 4-byte aligned as the glTF 2.0 specification requires.
pub fn glb_bytes(
    mesh: &Mesh,
    min: [f32; 3],
    max: [f32; 3],
    extras: serde_json::Value,
) -> Result<Vec<u8>, ExportError> {
    let mut bin = Vec::new();
    for v in &mesh.positions {
        for c in v {
            bin.extend_from_slice(&c.to_le_bytes());
        }
    }
    let pos_len = bin.len();
    for v in &mesh.normals {
        for c in v {
            bin.extend_from_slice(&c.to_le_bytes());
        }
    }
    let nrm_len = bin.len() - pos_len;
    for i in &mesh.indices {
        bin.extend_from_slice(&i.to_le_bytes());
    }
    let idx_len = bin.len() - pos_len - nrm_len;
    while bin.len() % 4 != 0 {
        bin.push(0);
    }
    let n = mesh.positions.len();
    let doc = json!({
        "asset": {"version": "2.0", "generator": format!("demsketch {}", env!("CARGO_PKG_VERSION")), "extras": extras},
        "scene": 0,
        "scenes": [{"nodes": [0]}],
        "nodes": [{"mesh": 0, "name": "terrain"}],
        "meshes": [{"name": "terrain", "primitives": [{
            "attributes": {"POSITION": 0, "NORMAL": 1},
            "indices": 2,
            "mode": 4,
        }]}],
        "buffers": [{"byteLength": bin.len()}],
        "bufferViews": [
            {"buffer": 0, "byteOffset": 0, "byteLength": pos_len, "target": 34962},
            {"buffer": 0, "byteOffset": pos_len, "byteLength": nrm_len, "target": 34962},
            {"buffer": 0, "byteOffset": pos_len + nrm_len, "byteLength": idx_len, "target": 34963},
        ],
        "accessors": [
            {"bufferView": 0, "componentType": 5126, "count": n, "type": "VEC3", "min": min, "max": max},
            {"bufferView": 1, "componentType": 5126, "count": n, "type": "VEC3"},
            {"bufferView": 2, "componentType": 5125, "count": mesh.indices.len(), "type": "SCALAR"},
        ],
    });
    let mut text = serde_json::to_vec(&doc).map_err(|e| ExportError::Internal(e.to_string()))?;
    while text.len() % 4 != 0 {
        text.push(b' ');
    }
    let total = 12 + 8 + text.len() + 8 + bin.len();
    let total = u32::try_from(total).map_err(|_| {
        ExportError::Internal("the mesh is larger than a GLB file can be (4 GiB)".into())
    })?;
    let mut out = Vec::with_capacity(total as usize);
    out.extend_from_slice(b"glTF");
    out.extend_from_slice(&2u32.to_le_bytes());
    out.extend_from_slice(&total.to_le_bytes());
    out.extend_from_slice(&(text.len() as u32).to_le_bytes());
    out.extend_from_slice(&0x4E4F_534Au32.to_le_bytes());
    out.extend_from_slice(&text);
    out.extend_from_slice(&(bin.len() as u32).to_le_bytes());
    out.extend_from_slice(&0x004E_4942u32.to_le_bytes());
    out.extend_from_slice(&bin);
    Ok(out)
}

/// WGS84 geodetic coordinates to a local east-north-up frame at an origin
/// (height 0): through earth-centred earth-fixed coordinates.
pub struct Enu {
    origin: [f64; 3],
    lon0: f64,
    lat0: f64,
}

const WGS84_A: f64 = 6_378_137.0;
const WGS84_F: f64 = 1.0 / 298.257_223_563;

impl Enu {
    pub fn new(lon0_deg: f64, lat0_deg: f64) -> Enu {
        Enu {
            origin: ecef(lon0_deg, lat0_deg, 0.0),
            lon0: lon0_deg.to_radians(),
            lat0: lat0_deg.to_radians(),
        }
    }

    /// `[east, north, up]` metres of a point (degrees, metres).
    pub fn from_geodetic(&self, lon_deg: f64, lat_deg: f64, h: f64) -> [f64; 3] {
        let p = ecef(lon_deg, lat_deg, h);
        let d = [
            p[0] - self.origin[0],
            p[1] - self.origin[1],
            p[2] - self.origin[2],
        ];
        let (sl, cl) = self.lon0.sin_cos();
        let (sp, cp) = self.lat0.sin_cos();
        [
            -sl * d[0] + cl * d[1],
            -sp * cl * d[0] - sp * sl * d[1] + cp * d[2],
            cp * cl * d[0] + cp * sl * d[1] + sp * d[2],
        ]
    }
}

/// Earth-centred earth-fixed coordinates of a WGS84 point.
fn ecef(lon_deg: f64, lat_deg: f64, h: f64) -> [f64; 3] {
    let e2 = WGS84_F * (2.0 - WGS84_F);
    let (lon, lat) = (lon_deg.to_radians(), lat_deg.to_radians());
    let n = WGS84_A / (1.0 - e2 * lat.sin().powi(2)).sqrt();
    [
        (n + h) * lat.cos() * lon.cos(),
        (n + h) * lat.cos() * lon.sin(),
        (n * (1.0 - e2) + h) * lat.sin(),
    ]
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn enu_axes() {
        let enu = Enu::new(10.0, 46.0);
        let up = enu.from_geodetic(10.0, 46.0, 100.0);
        assert!(up[0].abs() < 1e-6 && up[1].abs() < 1e-6 && (up[2] - 100.0).abs() < 1e-6);
        let east = enu.from_geodetic(10.001, 46.0, 0.0);
        assert!(east[0] > 70.0 && east[1].abs() < 0.01);
        let north = enu.from_geodetic(10.0, 46.001, 0.0);
        assert!(north[1] > 110.0 && north[0].abs() < 1e-6);
    }

    #[test]
    fn quads_are_counter_clockwise_from_above() {
        // A flat 2 x 2 grid: the normals point up (+y).
        let p = vec![
            [0.0, 0.0, 0.0],
            [1.0, 0.0, 0.0],
            [0.0, 0.0, 1.0],
            [1.0, 0.0, 1.0],
        ];
        let idx = triangles(&[0, 1, 2, 3], 2, 2);
        assert_eq!(idx.len(), 6);
        for n in vertex_normals(&p, &idx) {
            assert!((n[1] - 1.0).abs() < 1e-6, "{n:?}");
        }
    }
}
