//! The rule for a view's reach and refraction, one place for every caller:
//! the command line's `--max-distance` and `--refraction` (`view`,
//! `locate`, `edit`, `batch`, `serve`), the library's
//! [`crate::edit::EditOptions`] and a batch plan's settings; how the
//! library reads a view distance ([`distance_limit`]); and the rule for an
//! edit's least fit ([`check_min_fit`], `--min-fit`, `min_fit`).
//!
//! ```
//! use demsketch::view::{check_view_settings, SettingNames};
//! assert!(check_view_settings(Some(50_000.0), 1.0 / 7.0, SettingNames::Flags).is_ok());
//! assert!(check_view_settings(None, 0.0, SettingNames::Options).is_ok());
//! let e = check_view_settings(Some(0.0), 0.13, SettingNames::Flags).unwrap_err();
//! assert_eq!(e.to_string(), "--max-distance 0 must be a finite positive number of metres");
//! let e = check_view_settings(None, f64::NAN, SettingNames::Options).unwrap_err();
//! assert_eq!(e.to_string(), "refraction NaN must be a finite number");
//! use demsketch::view::distance_limit;
//! assert_eq!(distance_limit(Some(20_000.0)), Some(20_000.0));
//! for no_limit in [None, Some(0.0), Some(-5.0), Some(f64::NAN), Some(f64::INFINITY)] {
//!     assert_eq!(distance_limit(no_limit), None);
//! }
//! let e = demsketch::view::check_min_fit(-1.0, SettingNames::Flags).unwrap_err();
//! assert_eq!(e.to_string(), "--min-fit -1 must be a number >= 0 (a share of a stroke's columns; above 1: never written)");
//! ```

use crate::num::Num;

/// How a message names a setting: the command line's flags, a file's
/// fields (a batch plan's `settings`), or the library's
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

    fn min_fit(self) -> &'static str {
        match self {
            SettingNames::Flags => "--min-fit",
            SettingNames::Fields | SettingNames::Options => "min_fit",
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

/// The view distance the library works to: `max_distance_m` when it is
/// finite and positive, else `None`, no limit (the whole DEM). Every
/// reader of a view distance (the scene, the terrain, the viewshed, the
/// edit, a batch's footprints) reads it so; [`check_view_settings`] keeps
/// a user's `0`, negative or non-finite distance from getting here.
pub fn distance_limit(max_distance_m: Option<f64>) -> Option<f64> {
    max_distance_m.filter(|d| d.is_finite() && *d > 0.0)
}

/// An edit's least fit out of its range (one line).
#[derive(Debug, Clone, Copy, PartialEq, thiserror::Error)]
#[error(
    "{} {} must be a number >= 0 (a share of a stroke's columns; above 1: never written)",
    names.min_fit(),
    Num(*value)
)]
pub struct MinFitError {
    pub value: f64,
    pub names: SettingNames,
}

/// An edit's least fit (`--min-fit`, a batch plan's or
/// [`crate::edit::EditOptions`]' `min_fit`) is a finite number >= 0: the
/// share of a stroke's pixel columns that must be fitted
/// (`fit.fitted_fraction`, in [0, 1]) for the edit to be written. Above 1
/// no stroke can reach it, so nothing is ever written (exit 3, the report
/// and pictures are): a documented way to see what an edit would do. A
/// negative or non-finite one is a typo. Checked before any work; `names`
/// says how the message names it.
pub fn check_min_fit(value: f64, names: SettingNames) -> Result<(), MinFitError> {
    if value.is_finite() && value >= 0.0 {
        Ok(())
    } else {
        Err(MinFitError { value, names })
    }
}
