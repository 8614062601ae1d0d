//! Terrarium (Mapzen/AWS terrain tiles): a height in the red, green and
//! blue bytes of a pixel, `height = R * 256 + G + B / 256 - 32768` metres,
//! so heights from -32768 m to about 32768 m in steps of 1/256 m. Used by
//! [`super::tile_encoding`] for `export tiles --encoding terrarium`.

/// Lowest height Terrarium stores, metres.
pub const MIN_HEIGHT: f64 = -32_768.0;

/// The RGB bytes of `height` (metres), rounded to the nearest 1/256 m
/// and clamped to what the encoding holds.
pub fn encode(height: f64) -> [u8; 3] {
    let v = ((height - MIN_HEIGHT) * 256.0)
        .round()
        .clamp(0.0, 16_777_215.0) as u32;
    [(v >> 16) as u8, (v >> 8) as u8, v as u8]
}

/// The height (metres) of the RGB bytes.
pub fn decode(rgb: [u8; 3]) -> f64 {
    rgb[0] as f64 * 256.0 + rgb[1] as f64 + rgb[2] as f64 / 256.0 + MIN_HEIGHT
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn round_trip_within_half_a_step() {
        for h in [-32_768.0, -432.17, 0.0, 0.001, 1234.56, 8848.86] {
            assert!((decode(encode(h)) - h).abs() <= 0.5 / 256.0 + 1e-9, "{h}");
        }
        // 0 m is (128, 0, 0).
        assert_eq!(encode(0.0), [128, 0, 0]);
        // A fraction that rounds up carries into green.
        assert_eq!(encode(0.999_999), [128, 1, 0]);
    }
}
