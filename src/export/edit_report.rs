//! The parts of an edit report (`demsketch edit --report`, see DESIGN.md
//! "Report") that the exports read: what was edited and written, the
//! deformation window, the strokes with their fit and, where the report
//! has them, their placed 3D curves (`placed_curve`: points in the DEM's
//! CRS with absolute heights). Read leniently: fields the exports do not
//! use are ignored, so reports of newer versions still export.

use std::path::Path;

use serde_json::Value;

use super::ExportError;

/// What the exports use of an edit report.
#[derive(Debug, Clone, Default)]
pub struct EditReportSummary {
    pub dem: String,
    pub sketch: String,
    pub output: String,
    pub written: bool,
    pub dry_run: bool,
    pub changed_cells: u64,
    pub max_abs_displacement_m: f64,
    /// `[col, row, width, height]` of the deformation on the DEM grid.
    pub window: Option<[i64; 4]>,
    pub strokes: Vec<StrokeSummary>,
    /// The whole report, for provenance.
    pub raw: Value,
}

/// One stroke of one view.
#[derive(Debug, Clone)]
pub struct StrokeSummary {
    pub view: String,
    pub id: String,
    pub source_id: String,
    pub match_kind: String,
    pub status: String,
    pub fitted_fraction: f64,
    pub depth_m: [f64; 2],
    /// Placed curve in the DEM's CRS, `[x, y, z]`; empty when the report
    /// has none.
    pub placed_curve: Vec<[f64; 3]>,
}

/// Read and check an edit report.
pub fn read(path: &Path) -> Result<EditReportSummary, ExportError> {
    let bad = |m: String| ExportError::Input {
        path: path.display().to_string(),
        message: m,
    };
    let text = std::fs::read_to_string(path).map_err(|e| bad(e.to_string()))?;
    let raw: Value = serde_json::from_str(&text).map_err(|e| bad(format!("not JSON: {e}")))?;
    if !raw.is_object() || raw.get("views").is_none() || raw.get("deformation").is_none() {
        return Err(bad(
            "not an edit report (no \"views\" and \"deformation\"; write one with demsketch edit --report)".into(),
        ));
    }
    let s = |v: &Value, k: &str| v.get(k).and_then(Value::as_str).unwrap_or("").to_string();
    let window = raw["deformation"]["window"].as_array().and_then(|a| {
        let v: Vec<i64> = a.iter().filter_map(Value::as_i64).collect();
        (v.len() == 4).then(|| [v[0], v[1], v[2], v[3]])
    });
    let mut strokes = Vec::new();
    for view in raw["views"].as_array().into_iter().flatten() {
        for st in view["strokes"].as_array().into_iter().flatten() {
            let depth = st["match"]["depth_m"]
                .as_array()
                .map(|a| {
                    [
                        a.first().and_then(Value::as_f64).unwrap_or(0.0),
                        a.get(1).and_then(Value::as_f64).unwrap_or(0.0),
                    ]
                })
                .unwrap_or([0.0, 0.0]);
            let placed_curve = st["placed_curve"]
                .as_array()
                .into_iter()
                .flatten()
                .filter_map(|p| {
                    let a = p.as_array()?;
                    let f = |i: usize| a.get(i).and_then(Value::as_f64);
                    Some([f(0)?, f(1)?, f(2)?])
                })
                .filter(|p| p.iter().all(|v| v.is_finite()))
                .collect();
            strokes.push(StrokeSummary {
                view: s(view, "name"),
                id: s(st, "id"),
                source_id: s(st, "source_id"),
                match_kind: s(&st["match"], "kind"),
                status: s(st, "status"),
                fitted_fraction: st["fit"]["fitted_fraction"].as_f64().unwrap_or(0.0),
                depth_m: depth,
                placed_curve,
            });
        }
    }
    Ok(EditReportSummary {
        dem: s(&raw, "dem"),
        sketch: s(&raw, "sketch"),
        output: s(&raw, "output"),
        written: raw["written"].as_bool().unwrap_or(false),
        dry_run: raw["dry_run"].as_bool().unwrap_or(false),
        changed_cells: raw["changed_cells"].as_u64().unwrap_or(0),
        max_abs_displacement_m: raw["max_abs_displacement_m"].as_f64().unwrap_or(0.0),
        window,
        strokes,
        raw,
    })
}
