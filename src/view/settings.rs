//! The rule for a view's reach and refraction, one place for every caller:
//! the command line's `--max-distance` and `--refraction` (`view`,
//! `locate`, `edit`, `batch`, `serve`), the library's
//! [`crate::edit::EditOptions`] and a batch plan's settings.
//!
//! ```
//! use demsketch::view::{check_view_settings, SettingNames};
//! assert!(check_view_settings(Some(50_000.0), 1.0 / 7.0, SettingNames::Flags).is_ok());
//! assert!(check_view_settings(None, 0.0, SettingNames::Options).is_ok());
//! let e = check_view_settings(Some(0.0), 0.13, SettingNames::Flags).unwrap_err();
//! assert_eq!(e.to_string(), "--max-distance 0 must be a finite positive number of metres");
//! let e = check_view_settings(None, f64::NAN, SettingNames::Options).unwrap_err();
//! assert_eq!(e.to_string(), "refraction NaN must be a finite number");
//! ```

use crate::num::Num;

/// How a message names the two settings: the command line's flags, a
/// file's fields (a batch plan's `settings`), or the library's
/// [`crate::edit::EditOptions`] fields (whose `max_distance_m` may be
/// `None`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SettingNames {
    /// `--max-distance`, `--refraction`.
    Flags,
    /// `max_distance_m`, `refraction`.
    Fields,
    /// `max_distance_m` (`None`: the whole DEM), `refraction`.
    Options,
}

impl SettingNames {
    fn max_distance(self) -> &'static str {
        match self {
            SettingNames::Flags => "--max-distance",
            SettingNames::Fields | SettingNames::Options => "max_distance_m",
        }
    }

    fn max_distance_hint(self) -> &'static str {
        match self {
            SettingNames::Options => " (None: the whole DEM)",
            SettingNames::Flags | SettingNames::Fields => "",
        }
    }

    fn refraction(self) -> &'static str {
        match self {
            SettingNames::Flags => "--refraction",
            SettingNames::Fields | SettingNames::Options => "refraction",
        }
    }

    fn refraction_hint(self) -> &'static str {
        match self {
            SettingNames::Flags => " (the coefficient k, 1/7 by default)",
            SettingNames::Fields | SettingNames::Options => "",
        }
    }
}

/// A view distance or refraction coefficient out of its range (one line).
#[derive(Debug, Clone, Copy, PartialEq, thiserror::Error)]
pub enum ViewSettingError {
    #[error(
        "{} {} must be a finite positive number of metres{}",
        names.max_distance(),
        Num(*value),
        names.max_distance_hint()
    )]
    MaxDistance { value: f64, names: SettingNames },
    #[error(
        "{} {} must be a finite number{}",
        names.refraction(),
        Num(*value),
        names.refraction_hint()
    )]
    Refraction { value: f64, names: SettingNames },
}

/// A view distance is a finite positive number of metres (`None`: no
/// limit, the whole DEM), the refraction coefficient k a finite number.
/// Checked before any work: the library reads a view distance that is not
/// finite and positive as "no limit" (a typo such as `--max-distance 0`
/// would read the whole DEM, and a NaN or infinite distance cannot be
/// written into a batch's records), and a k that is not finite drops every
/// ray of the view into empty sky. `names` says how the message names
/// them.
pub fn check_view_settings(
    max_distance_m: Option<f64>,
    refraction: f64,
    names: SettingNames,
) -> Result<(), ViewSettingError> {
    if let Some(d) = max_distance_m {
        if !(d.is_finite() && d > 0.0) {
            return Err(ViewSettingError::MaxDistance { value: d, names });
        }
    }
    if !refraction.is_finite() {
        return Err(ViewSettingError::Refraction {
            value: refraction,
            names,
        });
    }
    Ok(())
}
