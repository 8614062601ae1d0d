//! Pictures of an edit (`edit --renders DIR`): for every view the shaded
//! first-person view before and after the edit with the strokes drawn over
//! it, and a map of the height change `M` on the DEM grid with a diverging
//! colour scale (blue down, red up) and a labelled colour bar. Pictures are
//! encoded in memory and written by the pipeline only once the DEM has been
//! written.

use crate::render::{draw_polyline, shade, ShadeOptions};

use super::rendered_view::RenderedView;

/// An encoded PNG and its file name.
pub struct Picture {
    pub name: String,
    pub png: Vec<u8>,
}

/// Encode RGB bytes as PNG.
pub fn encode_png(width: usize, height: usize, rgb: &[u8]) -> Result<Vec<u8>, String> {
    let mut out = Vec::new();
    {
        let mut enc = png::Encoder::new(&mut out, width as u32, height as u32);
        enc.set_color(png::ColorType::Rgb);
        enc.set_depth(png::BitDepth::Eight);
        let mut wr = enc.write_header().map_err(|e| e.to_string())?;
        wr.write_image_data(rgb).map_err(|e| e.to_string())?;
        wr.finish().map_err(|e| e.to_string())?;
    }
    Ok(out)
}

/// The shaded view with `strokes` drawn in red.
pub fn view_picture(view: &RenderedView, strokes: &[Vec<[f64; 2]>]) -> Vec<u8> {
    let (w, h) = (view.camera.width, view.camera.height);
    let mut rgb = shade(&view.depth, &view.terrain, &ShadeOptions::default());
    let thick = (w as f64 / 600.0).clamp(2.0, 4.0);
    for s in strokes {
        draw_polyline(&mut rgb, w, h, s, [230, 30, 30], thick);
    }
    rgb
}

/// Diverging colour of `t` in [-1, 1]: blue, white, red.
fn diverging(t: f64) -> [u8; 3] {
    let t = t.clamp(-1.0, 1.0);
    let (a, b) = if t < 0.0 {
        ([247.0, 247.0, 247.0], [33.0, 102.0, 172.0])
    } else {
        ([247.0, 247.0, 247.0], [178.0, 24.0, 43.0])
    };
    let s = t.abs().powf(0.7);
    [
        (a[0] + (b[0] - a[0]) * s) as u8,
        (a[1] + (b[1] - a[1]) * s) as u8,
        (a[2] + (b[2] - a[2]) * s) as u8,
    ]
}

/// Map of the height change over a grid of `nx x ny` cells of `cell_m`
/// metres (`base` heights for a faint hillshade, NaN = nodata drawn grey)
/// with a colour bar labelled in metres. Returns `(width, height, rgb)`.
pub fn height_change_map(
    nx: usize,
    ny: usize,
    cell_m: (f64, f64),
    base: &[f32],
    change: &[f32],
) -> (usize, usize, Vec<u8>) {
    // Scale so that the picture is at least ~500 px wide when the grid is small.
    let scale = (500 / nx.max(1)).clamp(1, 8);
    let (mw, mh) = (nx * scale, ny * scale);
    let h = mh.max(220);
    // Labels about 1/25 of the picture's height, so that they stay
    // readable when a tall picture is shown scaled down (the app shows
    // it 320 px high); the bar is as wide as its longest label needs.
    let text_scale = (h / 125).max(2);
    let bar_w = 46 + 9 * 4 * text_scale + 8;
    let w = mw + bar_w;
    let mut rgb = vec![255u8; w * h * 3];
    let m = change
        .iter()
        .filter(|v| v.is_finite())
        .fold(0.0f32, |a, v| a.max(v.abs()))
        .max(1e-3) as f64;
    for j in 0..ny {
        for i in 0..nx {
            let k = j * nx + i;
            let c = if base[k].is_nan() {
                [160, 160, 160]
            } else {
                // Faint hillshade from the base heights (light from the NW).
                let hz = |a: usize, b: usize| (base[b * nx + a] + change[b * nx + a]) as f64;
                let (i0, i1) = (i.saturating_sub(1), (i + 1).min(nx - 1));
                let (j0, j1) = (j.saturating_sub(1), (j + 1).min(ny - 1));
                let gx = (hz(i1, j) - hz(i0, j)) / (cell_m.0 * (i1 - i0).max(1) as f64);
                let gy = (hz(i, j1) - hz(i, j0)) / (cell_m.1 * (j1 - j0).max(1) as f64);
                let shade = if gx.is_finite() && gy.is_finite() {
                    // Normal (-gx, gy, 1) in (east, north, up); light from NW, 45 deg up.
                    let n = (gx * gx + gy * gy + 1.0).sqrt();
                    let l = (0.5f64).sqrt();
                    let lambert = ((gx * 0.5 - gy * 0.5) * l + l) / n;
                    (0.82 + 0.25 * lambert).clamp(0.8, 1.05)
                } else {
                    1.0
                };
                let d = diverging(change[k] as f64 / m);
                [
                    (d[0] as f64 * shade).min(255.0) as u8,
                    (d[1] as f64 * shade).min(255.0) as u8,
                    (d[2] as f64 * shade).min(255.0) as u8,
                ]
            };
            for dj in 0..scale {
                for di in 0..scale {
                    let p = ((j * scale + dj) * w + i * scale + di) * 3;
                    rgb[p..p + 3].copy_from_slice(&c);
                }
            }
        }
    }
    // Colour bar: from +m at the top to -m at the bottom.
    let (bx0, bx1) = (mw + 16, mw + 40);
    let (by0, by1) = (20usize, h - 20);
    for y in by0..by1 {
        let t = 1.0 - 2.0 * (y - by0) as f64 / (by1 - by0 - 1) as f64;
        let c = diverging(t);
        for x in bx0..bx1 {
            let p = (y * w + x) * 3;
            rgb[p..p + 3].copy_from_slice(&c);
        }
    }
    for (t, y) in [(1.0, by0), (0.0, (by0 + by1) / 2), (-1.0, by1 - 1)] {
        let label = format!("{:+.1} m", t * m);
        let label = if t == 0.0 { "0 m".to_string() } else { label };
        for x in bx1..bx1 + 4 {
            let p = (y * w + x) * 3;
            rgb[p..p + 3].copy_from_slice(&[0, 0, 0]);
        }
        let y_text = (y + 1)
            .saturating_sub(5 * text_scale / 2)
            .min(h - 5 * text_scale);
        draw_text(&mut rgb, w, h, bx1 + 6, y_text, &label, text_scale);
    }
    (w, h, rgb)
}

/// 3 x 5 glyphs for labels: digits, sign, point, 'm'.
fn glyph(c: char) -> [u8; 5] {
    match c {
        '0' => [0b111, 0b101, 0b101, 0b101, 0b111],
        '1' => [0b010, 0b110, 0b010, 0b010, 0b111],
        '2' => [0b111, 0b001, 0b111, 0b100, 0b111],
        '3' => [0b111, 0b001, 0b111, 0b001, 0b111],
        '4' => [0b101, 0b101, 0b111, 0b001, 0b001],
        '5' => [0b111, 0b100, 0b111, 0b001, 0b111],
        '6' => [0b111, 0b100, 0b111, 0b101, 0b111],
        '7' => [0b111, 0b001, 0b010, 0b010, 0b010],
        '8' => [0b111, 0b101, 0b111, 0b101, 0b111],
        '9' => [0b111, 0b101, 0b111, 0b001, 0b111],
        '-' => [0b000, 0b000, 0b111, 0b000, 0b000],
        '+' => [0b000, 0b010, 0b111, 0b010, 0b000],
        '.' => [0b000, 0b000, 0b000, 0b000, 0b010],
        'm' => [0b000, 0b000, 0b110, 0b111, 0b101],
        _ => [0; 5],
    }
}

/// Draw `text` in black with the 3 x 5 font scaled by `s`.
fn draw_text(rgb: &mut [u8], w: usize, h: usize, x0: usize, y0: usize, text: &str, s: usize) {
    for (n, c) in text.chars().enumerate() {
        let g = glyph(c);
        for (r, bits) in g.iter().enumerate() {
            for col in 0..3 {
                if bits & (0b100 >> col) == 0 {
                    continue;
                }
                for dy in 0..s {
                    for dx in 0..s {
                        let x = x0 + (n * 4 + col) * s + dx;
                        let y = y0 + r * s + dy;
                        if x < w && y < h {
                            let p = (y * w + x) * 3;
                            rgb[p..p + 3].copy_from_slice(&[0, 0, 0]);
                        }
                    }
                }
            }
        }
    }
}
