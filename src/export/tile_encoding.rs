//! A tile of heights as an RGBA PNG in one of the two height encodings
//! web maps read (`raster-dem` sources of MapLibre/Mapbox, Cesium and
//! deck.gl terrain layers): [`Encoding::TerrainRgb`] ([`super::terrain_rgb`])
//! or [`Encoding::Terrarium`] ([`super::terrarium`]). Nodata pixels are
//! transparent (alpha 0) and carry the encoding of 0 m in their colour, so
//! a reader that ignores alpha sees sea level there rather than a spike to
//! the encoding's lowest height.

use super::{terrain_rgb, terrarium};

/// How heights become pixel colours.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum Encoding {
    /// Mapbox Terrain-RGB (MapLibre's `"encoding": "mapbox"`).
    TerrainRgb,
    /// Terrarium (MapLibre's `"encoding": "terrarium"`).
    Terrarium,
}

impl Encoding {
    /// Parse `terrain-rgb` (also `mapbox`) or `terrarium`.
    pub fn parse(s: &str) -> Result<Encoding, String> {
        match s.to_ascii_lowercase().as_str() {
            "terrain-rgb" | "terrainrgb" | "mapbox" => Ok(Encoding::TerrainRgb),
            "terrarium" => Ok(Encoding::Terrarium),
            _ => Err(format!(
                "--encoding '{s}': use terrain-rgb (Mapbox) or terrarium"
            )),
        }
    }

    /// The RGB bytes of a height in metres.
    pub fn encode(self, height: f64) -> [u8; 3] {
        match self {
            Encoding::TerrainRgb => terrain_rgb::encode(height),
            Encoding::Terrarium => terrarium::encode(height),
        }
    }

    /// The height in metres of RGB bytes.
    pub fn decode(self, rgb: [u8; 3]) -> f64 {
        match self {
            Encoding::TerrainRgb => terrain_rgb::decode(rgb),
            Encoding::Terrarium => terrarium::decode(rgb),
        }
    }

    /// The name MapLibre's `raster-dem` source gives the encoding.
    pub fn maplibre_name(self) -> &'static str {
        match self {
            Encoding::TerrainRgb => "mapbox",
            Encoding::Terrarium => "terrarium",
        }
    }
}

/// RGBA pixels of a tile of heights (metres, NaN = nodata), row-major.
pub fn rgba(heights: &[f32], encoding: Encoding) -> Vec<u8> {
    let zero = encoding.encode(0.0);
    let mut out = Vec::with_capacity(heights.len() * 4);
    for &h in heights {
        if h.is_finite() {
            let c = encoding.encode(h as f64);
            out.extend_from_slice(&[c[0], c[1], c[2], 255]);
        } else {
            out.extend_from_slice(&[zero[0], zero[1], zero[2], 0]);
        }
    }
    out
}

/// A `size` x `size` tile of heights as PNG bytes (RGBA, 8 bits). Fast
/// compression: tiles are many and small, and height bytes compress
/// poorly anyway.
pub fn encode_png(heights: &[f32], size: usize, encoding: Encoding) -> Result<Vec<u8>, String> {
    let pixels = rgba(heights, encoding);
    let mut bytes = Vec::new();
    {
        let mut enc = png::Encoder::new(&mut bytes, size as u32, size as u32);
        enc.set_color(png::ColorType::Rgba);
        enc.set_depth(png::BitDepth::Eight);
        enc.set_compression(png::Compression::Fast);
        let mut w = enc.write_header().map_err(|e| e.to_string())?;
        w.write_image_data(&pixels).map_err(|e| e.to_string())?;
        w.finish().map_err(|e| e.to_string())?;
    }
    Ok(bytes)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn nodata_is_transparent_sea_level() {
        let px = rgba(&[f32::NAN, 100.0], Encoding::Terrarium);
        assert_eq!(&px[..4], &[128, 0, 0, 0]);
        assert_eq!(px[7], 255);
        assert!((Encoding::Terrarium.decode([px[4], px[5], px[6]]) - 100.0).abs() < 0.01);
    }
}
