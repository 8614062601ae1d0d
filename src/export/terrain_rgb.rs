//! Mapbox Terrain-RGB: a height in the red, green and blue bytes of a
//! pixel, `height = -10000 + (R * 65536 + G * 256 + B) * 0.1` metres, so
//! heights from -10000 m to 1667721.5 m in steps of 0.1 m. Used by
//! [`super::tile_encoding`] for `export tiles --encoding terrain-rgb`.

/// Lowest height Terrain-RGB stores, metres.
pub const MIN_HEIGHT: f64 = -10_000.0;
/// Height step, metres.
pub const STEP: f64 = 0.1;

/// The RGB bytes of `height` (metres), rounded to the nearest 0.1 m and
/// clamped to what the encoding holds.
pub fn encode(height: f64) -> [u8; 3] {
    let v = ((height - MIN_HEIGHT) / STEP)
        .round()
        .clamp(0.0, 16_777_215.0) as u32;
    [(v >> 16) as u8, (v >> 8) as u8, v as u8]
}

/// The height (metres) of the RGB bytes.
pub fn decode(rgb: [u8; 3]) -> f64 {
    let v = rgb[0] as u32 * 65_536 + rgb[1] as u32 * 256 + rgb[2] as u32;
    MIN_HEIGHT + v as f64 * STEP
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn round_trip_within_half_a_step() {
        for h in [-10_000.0, -432.17, 0.0, 0.04, 1234.56, 8848.86] {
            assert!((decode(encode(h)) - h).abs() <= 0.05 + 1e-9, "{h}");
        }
        // Mapbox's example: 0 m is (1, 134, 160).
        assert_eq!(encode(0.0), [1, 134, 160]);
        assert_eq!(encode(-20_000.0), [0, 0, 0]);
    }
}
