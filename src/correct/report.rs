//! The report of `demsketch correct` (JSON): the run's window, what was
//! written, and per feature its kind, the cells it changed, the largest
//! height change and what it used (lake level, river surface, influence
//! distance) or reached (control-curve error), and for breaklines whether
//! they are hard and how many cells they re-interpolated.

use serde::Serialize;

use super::Correction;

/// What one feature did.
#[derive(Debug, Clone, Serialize)]
pub struct FeatureReport {
    /// Index in the FeatureCollection.
    pub index: usize,
    /// The feature's id or name.
    pub id: Option<String>,
    /// `lake`, `river`, `control_curve`, `breakline`, `landform` or
    /// `noise_region`.
    pub kind: &'static str,
    /// Cells whose height this feature changed.
    pub cells_changed: usize,
    /// Largest `|new - old|`, metres.
    pub max_abs_dz_m: f64,
    /// Water cells set to the surface (lakes, rivers).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub water_cells: Option<usize>,
    /// The blend width used (lakes, rivers), metres.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub blend_m: Option<f64>,
    /// The level used (lakes), metres.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub level_m: Option<f64>,
    /// True when the level is the lowest shoreline height.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub level_from_shoreline: Option<bool>,
    /// Water surface at the source and the outlet (rivers), metres.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub surface_start_m: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub surface_end_m: Option<f64>,
    /// Rivers: `[arc length from the source, surface]` in metres where the
    /// surface profile bends; linear (so flat across) in between.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub surface_knots_m: Option<Vec<[f64; 2]>>,
    /// True when the centreline was reversed (by the heights or `downstream`).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub reversed: Option<bool>,
    /// Influence distance (control curves), metres.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub influence_m: Option<f64>,
    /// Largest `|DEM - z|` along the curve afterwards (control curves).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub max_curve_error_m: Option<f64>,
    /// Cross-sections attached to the curve (control curves with some).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub cross_sections: Option<usize>,
    /// Largest `|DEM - z|` along the cross-sections afterwards (moved to
    /// meet the curve), metres.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub max_section_error_m: Option<f64>,
    /// Breaklines: true for a hard one, false for a soft one.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub hard: Option<bool>,
    /// Hard breaklines: the valid cells within the influence distance,
    /// re-interpolated from the triangulation.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub band_cells: Option<usize>,
    /// Landforms: where the silhouette went and the footprint used.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub landform: Option<LandformReport>,
    /// Landforms and noise regions: the stroke's noise and what was added.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub noise: Option<NoiseReport>,
}

/// The placement of a landform's silhouette.
#[derive(Debug, Clone, Serialize)]
pub struct LandformReport {
    /// Points of the placed silhouette (one per image pixel).
    pub silhouette_points: usize,
    /// True: placed on the vertical surface through the terrain under both
    /// stroke ends; false: on the drawing plane through one; absent: on
    /// the surface through the given shadow.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub both_ends_on_terrain: Option<bool>,
    /// True when the boundary is the default capsule.
    pub default_boundary: bool,
    /// The default capsule's shoulder base lengths `[d1, d2]`, metres.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub shoulders_m: Option<[f64; 2]>,
    /// Highest point of the placed silhouette, metres.
    pub peak_m: f64,
    /// The boundary as a GeoJSON geometry in the DEM's CRS (edit it and
    /// give it back as the feature's geometry).
    pub boundary: serde_json::Value,
    /// The shadow as a GeoJSON LineString in the DEM's CRS (give it back
    /// as the `shadow` property).
    pub shadow: serde_json::Value,
}

/// The noise of a stroke (wavelet analysis) and the noise added.
#[derive(Debug, Clone, Serialize)]
pub struct NoiseReport {
    /// The stroke's detail bands, finest first.
    pub bands: Vec<super::wavelet_noise::Band>,
    /// Energy of the stroke's detail bands over that of its smoothest
    /// level (the wavelet energy ratio).
    pub detail_energy_ratio: f64,
    /// Deviation of the noise field from the bands the DEM can carry, m.
    pub noise_sigma_m: f64,
    /// Root mean square of the noise added over the footprint, metres.
    pub noise_rms_m: f64,
}

impl FeatureReport {
    /// An empty report for `c`.
    pub fn new(c: &Correction) -> Self {
        FeatureReport {
            index: c.index,
            id: c.id.clone(),
            kind: c.kind.name(),
            cells_changed: 0,
            max_abs_dz_m: 0.0,
            water_cells: None,
            blend_m: None,
            level_m: None,
            level_from_shoreline: None,
            surface_start_m: None,
            surface_end_m: None,
            surface_knots_m: None,
            reversed: None,
            influence_m: None,
            max_curve_error_m: None,
            cross_sections: None,
            max_section_error_m: None,
            hard: None,
            band_cells: None,
            landform: None,
            noise: None,
        }
    }
}

/// Seconds per stage.
#[derive(Debug, Clone, Serialize)]
pub struct Timings {
    pub plan: f64,
    pub solve: f64,
    pub write: f64,
    pub total: f64,
}

/// The report of one run.
#[derive(Debug, Clone, Serialize)]
pub struct CorrectReport {
    pub dem: String,
    pub features: String,
    pub output: String,
    /// False on a dry run.
    pub written: bool,
    /// `[col, row, width, height]` of the window read and solved.
    pub window: [i64; 4],
    pub cell_size_m: [f64; 2],
    /// Cells whose stored value changed (would change, on a dry run).
    pub changed_cells: usize,
    pub tiles_written: Vec<String>,
    pub corrections: Vec<FeatureReport>,
    pub timings_s: Timings,
}
