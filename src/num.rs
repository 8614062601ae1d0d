//! Numbers in messages: a value the user gave is echoed as written when it
//! is of everyday size, and in exponent form otherwise, so that `1e308`
//! does not print as a 309-digit number (Rust's `{}` of an `f64` never
//! uses an exponent).
//!
//! ```
//! use demsketch::num::Num;
//! assert_eq!(Num(250.5).to_string(), "250.5");
//! assert_eq!(Num(1e308).to_string(), "1e308");
//! assert_eq!(Num(-2.5e-300).to_string(), "-2.5e-300");
//! assert_eq!(Num(f64::NAN).to_string(), "NaN");
//! ```

use std::fmt;

/// An `f64` that displays compactly: `{}` from 1e-4 to below 1e9 in size
/// (and 0), `{:e}` beyond.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Num(pub f64);

impl fmt::Display for Num {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let a = self.0.abs();
        if self.0.is_finite() && a != 0.0 && !(1e-4..1e9).contains(&a) {
            write!(f, "{:e}", self.0)
        } else {
            write!(f, "{}", self.0)
        }
    }
}

#[cfg(test)]
mod tests {
    use super::Num;

    #[test]
    fn compact_beyond_everyday_sizes() {
        assert_eq!(Num(0.0).to_string(), "0");
        assert_eq!(Num(1.7).to_string(), "1.7");
        assert_eq!(Num(-123456789.0).to_string(), "-123456789");
        assert_eq!(Num(1e9).to_string(), "1e9");
        assert_eq!(Num(1e12).to_string(), "1e12");
        assert_eq!(Num(0.0001).to_string(), "0.0001");
        assert_eq!(Num(1e-5).to_string(), "1e-5");
        assert_eq!(Num(f64::INFINITY).to_string(), "inf");
        assert!(Num(f64::MAX).to_string().len() < 30);
    }
}
