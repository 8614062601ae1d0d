//! The picture of a first-person view: terrain coloured by height, lit like
//! a hillshade (Lambert from a sun direction plus sky light), faded into
//! distance haze (aerial perspective, which is what makes successive ridges
//! readable), over a sky gradient. Written as 8-bit RGB PNG with the `png`
//! crate; the depth buffer itself can be written as a Float32 TIFF.

use super::atomic::write_atomically;
use super::depth_buffer::{DepthBuffer, SKY};
use super::terrain::LocalTerrain;
use super::RenderError;
use std::path::Path;

/// Lighting and haze parameters.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ShadeOptions {
    /// Sun azimuth, degrees clockwise from true north.
    pub sun_azimuth_deg: f64,
    /// Sun altitude above the horizon, degrees.
    pub sun_altitude_deg: f64,
    /// Distance at which haze covers 54% of the terrain colour (85% of
    /// 1 - 1/e); `None`: half the farthest visible distance.
    pub haze_distance_m: Option<f64>,
}

impl Default for ShadeOptions {
    fn default() -> Self {
        ShadeOptions {
            sun_azimuth_deg: 225.0,
            sun_altitude_deg: 35.0,
            haze_distance_m: None,
        }
    }
}

fn lerp(a: [f64; 3], b: [f64; 3], t: f64) -> [f64; 3] {
    let t = t.clamp(0.0, 1.0);
    [
        a[0] + (b[0] - a[0]) * t,
        a[1] + (b[1] - a[1]) * t,
        a[2] + (b[2] - a[2]) * t,
    ]
}

/// Colour ramp by relative height `s` in [0, 1].
fn ramp(s: f64) -> [f64; 3] {
    const STOPS: [(f64, [f64; 3]); 5] = [
        (0.0, [92.0, 118.0, 66.0]),
        (0.3, [128.0, 132.0, 84.0]),
        (0.55, [156.0, 138.0, 106.0]),
        (0.8, [150.0, 146.0, 140.0]),
        (1.0, [214.0, 212.0, 208.0]),
    ];
    let s = s.clamp(0.0, 1.0);
    for w in STOPS.windows(2) {
        if s <= w[1].0 {
            return lerp(w[0].1, w[1].1, (s - w[0].0) / (w[1].0 - w[0].0));
        }
    }
    STOPS[4].1
}

/// Shade a rendered view: returns RGB bytes, row-major.
pub fn shade(depth: &DepthBuffer, terrain: &LocalTerrain, opts: &ShadeOptions) -> Vec<u8> {
    let mut out = Vec::new();
    shade_into(depth, terrain, opts, &mut out);
    out
}

/// [`shade`] into `out` (resized to `3 * width * height`), so that a caller
/// rendering view after view (the browser app) reuses one buffer. Rows are
/// shaded in parallel; per pixel: the ray, the hit point, the colour ramp,
/// the smooth normal (interpolated vertex gradients, read straight from the
/// height grid inside it) and the haze; the sky from a table of its
/// gradient.
pub fn shade_into(
    depth: &DepthBuffer,
    terrain: &LocalTerrain,
    opts: &ShadeOptions,
    out: &mut Vec<u8>,
) {
    use rayon::prelude::*;
    let (w, h) = (depth.width, depth.height);
    let shader = Shader::new(depth, terrain, opts);
    out.resize(w * h * 3, 0);
    out.par_chunks_mut(w * 3)
        .enumerate()
        .for_each(|(j, row)| shader.row(j, row));
}

/// Entries of the sky gradient's table over ray heights 0 to [`SKY_TOP`].
const SKY_STEPS: usize = 2048;
/// Ray height (z of the unit ray) above which the sky is the zenith colour.
const SKY_TOP: f64 = 0.25;

/// What the shading of every pixel of one view shares.
struct Shader<'a> {
    depth: &'a DepthBuffer,
    terrain: &'a LocalTerrain,
    sun: [f64; 3],
    haze_d: f64,
    hmin_abs: f64,
    hspan: f64,
    /// Apparent drop per square metre of horizontal distance.
    drop_per_m2: f64,
    /// Local (east, north) -> vertex coordinates: origin and matrix.
    v0: (f64, f64),
    m: [[f64; 2]; 2],
    /// Sky colour by ray height, `SKY_STEPS + 1` entries.
    sky: Vec<[f64; 3]>,
}

const HAZE: [f64; 3] = [198.0, 212.0, 228.0];
const ZENITH: [f64; 3] = [88.0, 136.0, 196.0];

impl<'a> Shader<'a> {
    fn new(depth: &'a DepthBuffer, terrain: &'a LocalTerrain, opts: &ShadeOptions) -> Self {
        use rayon::prelude::*;
        let max_depth = depth
            .depth
            .par_iter()
            .copied()
            .filter(|d| d.is_finite())
            .reduce(|| 0.0f32, f32::max) as f64;
        let haze_d = opts.haze_distance_m.unwrap_or((max_depth / 2.0).max(500.0));
        let (az, alt) = (
            opts.sun_azimuth_deg.to_radians(),
            opts.sun_altitude_deg.to_radians(),
        );
        // Height range of the visible terrain for the colour ramp (its far
        // layers included).
        let (hmin, hmax) = terrain.height_range_with_far();
        let frame = terrain.frame;
        let v0 = terrain.en_to_v(0.0, 0.0);
        let (ve, vn) = (terrain.en_to_v(1.0, 0.0), terrain.en_to_v(0.0, 1.0));
        let m = [[ve.0 - v0.0, vn.0 - v0.0], [ve.1 - v0.1, vn.1 - v0.1]];
        let sky = (0..=SKY_STEPS)
            .map(|k| {
                let z = k as f64 / SKY_STEPS as f64 * SKY_TOP;
                lerp(HAZE, ZENITH, (z * 4.0).powf(0.7))
            })
            .collect();
        Shader {
            depth,
            terrain,
            sun: [az.sin() * alt.cos(), az.cos() * alt.cos(), alt.sin()],
            haze_d,
            hmin_abs: hmin + frame.eye_alt,
            hspan: (hmax - hmin).max(1.0),
            drop_per_m2: frame.curvature.drop(1.0),
            v0,
            m,
            sky,
        }
    }

    /// Shade image row `j` into `row` (RGB bytes).
    fn row(&self, j: usize, row: &mut [u8]) {
        let cam = &self.depth.camera;
        // The pixel-centre ray of `Camera::ray`, stepped along the row.
        let v = cam.height as f64 / 2.0 - (j as f64 + 0.5);
        let f = cam.focal_px;
        let base = [
            f * cam.forward[0] + v * cam.up[0],
            f * cam.forward[1] + v * cam.up[1],
            f * cam.forward[2] + v * cam.up[2],
        ];
        let half_w = cam.width as f64 / 2.0;
        let k0 = j * self.depth.width;
        for (i, px) in row.chunks_exact_mut(3).enumerate() {
            let u = i as f64 + 0.5 - half_w;
            let d = [
                base[0] + u * cam.right[0],
                base[1] + u * cam.right[1],
                base[2] + u * cam.right[2],
            ];
            let len = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
            let ray = [d[0] / len, d[1] / len, d[2] / len];
            let c = self.pixel(k0 + i, ray);
            // Non-negative: rounding half up is `round`; `as` saturates.
            px[0] = (c[0] + 0.5) as u8;
            px[1] = (c[1] + 0.5) as u8;
            px[2] = (c[2] + 0.5) as u8;
        }
    }

    /// The colour of pixel `k` (row-major index) seen along the unit `ray`,
    /// each channel in 0..=255.
    #[inline]
    fn pixel(&self, k: usize, ray: [f64; 3]) -> [f64; 3] {
        let id = self.depth.triangle[k];
        if id == SKY {
            return self.sky_colour(ray[2]);
        }
        let t = self.depth.depth[k] as f64;
        let p = [ray[0] * t, ray[1] * t, ray[2] * t];
        let habs =
            p[2] + self.terrain.frame.eye_alt + self.drop_per_m2 * (p[0] * p[0] + p[1] * p[1]);
        let base = ramp((habs - self.hmin_abs) / self.hspan);
        let n = self
            .normal(p, id)
            .or_else(|| self.terrain.shading_normal(p, id))
            .unwrap_or([0.0, 0.0, 1.0]);
        let sun = self.sun;
        let lambert = (n[0] * sun[0] + n[1] * sun[1] + n[2] * sun[2]).max(0.0);
        let sky = 0.5 + 0.5 * n[2];
        let light = 0.22 * sky + 0.95 * lambert;
        let lit = [base[0] * light, base[1] * light, base[2] * light];
        let f = 1.0 - (-t / self.haze_d).exp();
        lerp(lit, HAZE, 0.85 * f)
    }

    /// The sky's colour along a ray of height `z` (linear in the table).
    #[inline]
    fn sky_colour(&self, z: f64) -> [f64; 3] {
        let s = (z.max(0.0) / SKY_TOP * SKY_STEPS as f64).min(SKY_STEPS as f64);
        let k = (s as usize).min(SKY_STEPS - 1);
        let (a, b) = (self.sky[k], self.sky[k + 1]);
        let f = s - k as f64;
        [
            a[0] + (b[0] - a[0]) * f,
            a[1] + (b[1] - a[1]) * f,
            a[2] + (b[2] - a[2]) * f,
        ]
    }

    /// [`LocalTerrain::shading_normal`] at `p` on triangle `id` where the
    /// four corners' central differences lie inside the grid and are all
    /// data (`None` elsewhere, where the caller asks the terrain).
    #[inline]
    fn normal(&self, p: [f64; 3], id: u32) -> Option<[f64; 3]> {
        let tr = self.terrain;
        let (nx, ny) = (tr.nx, tr.ny);
        let cx = tr.cells_x().max(1);
        let cell = (id / 2) as usize;
        let (c, r) = (cell % cx, cell / cx);
        if c < 1 || r < 1 || c + 2 >= nx || r + 2 >= ny {
            return None;
        }
        let m = self.m;
        let vx = self.v0.0 + m[0][0] * p[0] + m[0][1] * p[1];
        let vy = self.v0.1 + m[1][0] * p[0] + m[1][1] * p[1];
        let fx = (vx - c as f64).clamp(0.0, 1.0);
        let fy = (vy - r as f64).clamp(0.0, 1.0);
        let z = &tr.z;
        let at = |c: usize, r: usize| z.at_cr(c, r) as f64;
        // Central differences at the cell's corners (c..=c+1, r..=r+1).
        let grad = |c: usize, r: usize| {
            (
                (at(c + 1, r) - at(c - 1, r)) / 2.0,
                (at(c, r + 1) - at(c, r - 1)) / 2.0,
            )
        };
        let (g00, g10, g01, g11) = (
            grad(c, r),
            grad(c + 1, r),
            grad(c, r + 1),
            grad(c + 1, r + 1),
        );
        let l = |a: f64, b: f64, t: f64| a + (b - a) * t;
        let gx = l(l(g00.0, g10.0, fx), l(g01.0, g11.0, fx), fy);
        let gy = l(l(g00.1, g10.1, fx), l(g01.1, g11.1, fx), fy);
        if gx.is_nan() || gy.is_nan() {
            return None;
        }
        let de = gx * m[0][0] + gy * m[1][0];
        let dn = gx * m[0][1] + gy * m[1][1];
        let len = (de * de + dn * dn + 1.0).sqrt();
        Some([-de / len, -dn / len, 1.0 / len])
    }
}

/// Write RGB bytes as an 8-bit PNG (atomically: temporary file, then rename).
pub fn write_png(path: &Path, width: usize, height: usize, rgb: &[u8]) -> Result<(), RenderError> {
    write_atomically(
        path,
        |tmp| {
            let werr = |m: String| RenderError::Write {
                path: path.display().to_string(),
                message: m,
            };
            let file = std::fs::File::create(tmp).map_err(|e| werr(e.to_string()))?;
            let mut enc =
                png::Encoder::new(std::io::BufWriter::new(file), width as u32, height as u32);
            enc.set_color(png::ColorType::Rgb);
            enc.set_depth(png::BitDepth::Eight);
            let mut wr = enc.write_header().map_err(|e| werr(e.to_string()))?;
            wr.write_image_data(rgb).map_err(|e| werr(e.to_string()))?;
            wr.finish().map_err(|e| werr(e.to_string()))?;
            Ok(())
        },
        |tmp| verify_png(tmp, width, height, rgb),
    )
}

/// The PNG at `tmp` must decode to `width` x `height` RGB pixels equal to `rgb`.
fn verify_png(tmp: &Path, width: usize, height: usize, rgb: &[u8]) -> Result<(), String> {
    let file = std::fs::File::open(tmp).map_err(|e| e.to_string())?;
    let mut reader = png::Decoder::new(std::io::BufReader::new(file))
        .read_info()
        .map_err(|e| e.to_string())?;
    let mut buf = vec![0; reader.output_buffer_size().unwrap_or(0)];
    let info = reader.next_frame(&mut buf).map_err(|e| e.to_string())?;
    if (info.width as usize, info.height as usize) != (width, height)
        || buf[..info.buffer_size()] != *rgb
    {
        return Err("its pixels differ from those written".into());
    }
    Ok(())
}

/// Nodata of a written depth buffer: sky (never a bare infinity).
pub const DEPTH_NODATA: f64 = -9999.0;

/// The depth buffer as written: metres from the eye, sky [`DEPTH_NODATA`].
pub fn depth_for_file(depth: &DepthBuffer) -> Vec<f32> {
    depth
        .depth
        .iter()
        .map(|&d| {
            if d.is_finite() {
                d
            } else {
                DEPTH_NODATA as f32
            }
        })
        .collect()
}

/// Write the depth buffer as a Float32 TIFF in image space (no
/// georeference): metres from the eye, sky nodata ([`DEPTH_NODATA`]).
pub fn write_depth_tiff(depth: &DepthBuffer, path: &Path) -> Result<(), RenderError> {
    write_atomically(
        path,
        |tmp| {
            let werr = |e: gdal::errors::GdalError| RenderError::Write {
                path: path.display().to_string(),
                message: e.to_string().lines().next().unwrap_or("").to_string(),
            };
            crate::raster::atomic_file::through_memory(tmp, None, |tmp| {
                let driver = gdal::DriverManager::get_driver_by_name("GTiff").map_err(werr)?;
                let mut ds = driver
                    .create_with_band_type::<f32, _>(tmp, depth.width, depth.height, 1)
                    .map_err(werr)?;
                let data = depth_for_file(depth);
                let mut band = ds.rasterband(1).map_err(werr)?;
                band.set_no_data_value(Some(DEPTH_NODATA)).map_err(werr)?;
                let mut buf = gdal::raster::Buffer::new((depth.width, depth.height), data);
                band.write((0, 0), (depth.width, depth.height), &mut buf)
                    .map_err(werr)?;
                ds.flush_cache().map_err(werr)?;
                ds.close().map_err(werr)?;
                Ok::<(), RenderError>(())
            })
            .map_err(|message| RenderError::Write {
                path: path.display().to_string(),
                message,
            })
        },
        |tmp| {
            crate::raster::atomic_file::verify_band(
                tmp,
                depth.width,
                depth.height,
                &depth_for_file(depth),
            )
        },
    )
}

/// Draw a polyline of pixel coordinates (DESIGN.md convention: pixel `(i, j)`
/// covers `[i, i+1) x [j, j+1)`) into RGB bytes, `thickness` pixels wide.
/// For overlays: sketch strokes, silhouettes, ridges.
pub fn draw_polyline(
    rgb: &mut [u8],
    width: usize,
    height: usize,
    points: &[[f64; 2]],
    color: [u8; 3],
    thickness: f64,
) {
    let r = (thickness / 2.0).max(0.5);
    let mut plot = |x: f64, y: f64| {
        let (x0, x1) = ((x - r).floor() as i64, (x + r).ceil() as i64);
        let (y0, y1) = ((y - r).floor() as i64, (y + r).ceil() as i64);
        for j in y0.max(0)..y1.min(height as i64) {
            for i in x0.max(0)..x1.min(width as i64) {
                let (cx, cy) = (i as f64 + 0.5 - x, j as f64 + 0.5 - y);
                if cx * cx + cy * cy <= r * r {
                    let k = (j as usize * width + i as usize) * 3;
                    rgb[k..k + 3].copy_from_slice(&color);
                }
            }
        }
    };
    for w in points.windows(2) {
        let (a, b) = (w[0], w[1]);
        let n = ((b[0] - a[0]).abs().max((b[1] - a[1]).abs()) * 2.0)
            .ceil()
            .max(1.0) as usize;
        if n > 1_000_000 {
            continue;
        }
        for s in 0..=n {
            let t = s as f64 / n as f64;
            plot(a[0] + (b[0] - a[0]) * t, a[1] + (b[1] - a[1]) * t);
        }
    }
    if points.len() == 1 {
        plot(points[0][0], points[0][1]);
    }
}
