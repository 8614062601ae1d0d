//! Stage 6 of the edit pipeline, `write`: pictures and report staged
//! first, then the honest-outcome gate (`--min-fit`, `--dry-run`), the
//! atomic write-back of the affected tiles, and last the pictures and the
//! report moved into place.

use std::path::{Path, PathBuf};
use std::time::Instant;

use super::pipeline::{render_edited, secs, Edit, ViewState};
use super::rendered_view::RenderedView;
use super::renders::{encode_png, height_change_map, view_picture, Picture};
use super::report::{
    DeformationReport, EditReport, MatchingReport, StagedFile, StrokeStatus, Timings, ViewReport,
};
use super::EditError;
use crate::deform::Deformation;
use crate::raster::provenance::sha256_hex;
use crate::raster::{Dem, Destination, Provenance, ProvenanceRecord, WriteReport};
use crate::sketch::SketchFile;

/// The inputs of the edit, as loaded.
pub(super) struct Sources<'a> {
    pub(super) dem_path: &'a Path,
    pub(super) sketch_path: &'a Path,
    pub(super) dem: &'a Dem,
    pub(super) sketch: &'a SketchFile,
}

/// What the edit computed, ready to be written and reported.
pub(super) struct Outcome {
    /// The final deformation.
    pub(super) deformation: Deformation,
    /// Per view: its strokes' fit and visibility, and its rounds.
    pub(super) views: Vec<ViewReport>,
    pub(super) notes: Vec<String>,
    /// Curve constraints from the strokes, and those the lowering added.
    pub(super) curve_constraints: usize,
    pub(super) lowering_constraints: usize,
    pub(super) matching: MatchingReport,
    /// What the sketch's map-view corrections did.
    pub(super) corrections: Vec<crate::correct::FeatureReport>,
    /// Per view, the rounds' last render (of its stroke region, on the
    /// final terrain): a later pass's whole render of that terrain takes
    /// the silhouettes it refined already
    /// ([`super::rendered_view::RenderedView::from_terrain_after`]).
    pub(super) renders: Vec<super::rendered_view::RenderedView>,
    /// The ridges a later pass may take as they are: those of the terrain
    /// this outcome's last pass read, where that pass was not kept (the
    /// next reads the same terrain; see [`super::pipeline`]'s `Seen`).
    pub(super) ridges: Option<super::pipeline::RidgesOf>,
}

impl Outcome {
    /// A copy without the renders (which only a later pass reads).
    pub(super) fn without_renders(&self) -> Outcome {
        Outcome {
            deformation: self.deformation.clone(),
            views: self.views.clone(),
            notes: self.notes.clone(),
            curve_constraints: self.curve_constraints,
            lowering_constraints: self.lowering_constraints,
            matching: self.matching,
            corrections: self.corrections.clone(),
            renders: Vec::new(),
            ridges: None,
        }
    }

    /// Makes `seen` (what a pass not kept rendered of the terrain it read)
    /// the renders and ridges the next pass takes from.
    pub(super) fn take_seen(&mut self, seen: Option<super::pipeline::Seen>) {
        if let Some(s) = seen {
            self.renders = s.renders;
            self.ridges = Some(s.ridges);
        }
    }
}

/// The worst stroke below the minimum fit, which stops the write.
struct BelowMinFit {
    view: String,
    stroke: String,
    fit: f64,
    reason: String,
}

/// Write everything the edit produced, or nothing of the DEM: renders the
/// whole views for the pictures (when `--renders`), stages the pictures
/// and the report (proving their directories writable), then writes the
/// deformation back atomically unless a stroke's fit is below
/// `--min-fit` (without `--allow-partial`) or it is a dry run, in which
/// case it only checks what a real write would change. The pictures and
/// the report are moved into place last, whatever the gate said; a stroke
/// below the minimum fit then ends the edit with
/// [`EditError::BelowMinFit`], carrying the report. `timings` gets the
/// write and total times (`t_all`: the start of the edit).
pub(super) fn write_outputs(
    edit: Edit,
    src: &Sources,
    views: &[ViewState],
    outcome: Outcome,
    mut timings: Timings,
    t_all: Instant,
) -> Result<EditReport, EditError> {
    let opts = edit.opts;
    let Outcome {
        deformation,
        views: view_reports,
        mut notes,
        curve_constraints,
        lowering_constraints,
        matching,
        corrections,
        renders,
        ridges,
    } = outcome;
    drop((renders, ridges));
    edit.pb.set_message("writing corrected tiles");
    let t = Instant::now();
    let pictures = if opts.renders.is_some() {
        // The rounds rendered only around the strokes: the pictures show
        // the whole view.
        let whole = views
            .iter()
            .map(|v| render_edited(v, &deformation, None))
            .collect::<Result<Vec<_>, _>>()?;
        pictures(views, &whole, &deformation)?
    } else {
        Vec::new()
    };
    let staged_report = match &opts.report {
        Some(p) => Some(stage_report(p, src, &view_reports)?),
        None => None,
    };
    let staged_renders = match &opts.renders {
        Some(dir) => Some(StagedDir::create(dir, &pictures)?),
        None => None,
    };
    let below = (!opts.allow_partial)
        .then(|| worst_below_min_fit(&view_reports))
        .flatten();
    let write = below.is_none() && !opts.dry_run;
    let written = if write {
        write_back(src, &deformation, opts)?
    } else {
        check_write_back(src, &deformation, below.is_some(), &mut notes)?
    };
    if let Some(b) = &below {
        notes.push(format!(
            "nothing written: view \"{}\" stroke \"{}\" fitted {:.2}, below --min-fit {} (--allow-partial writes anyway)",
            b.view, b.stroke, b.fit, opts.min_fit
        ));
    } else if opts.dry_run {
        notes.push("dry run: nothing written".into());
    }
    if let Some(s) = staged_renders {
        s.commit()?;
    }
    if let Some(p) = &opts.dz {
        write_dz(p, src.dem, &deformation).map_err(EditError::from)?;
    }
    timings.write = secs(t);
    timings.total = secs(t_all);

    let max_abs = deformation.stats.max_abs_displacement_m;
    let w = deformation.window;
    let report = EditReport {
        dem: src.dem_path.display().to_string(),
        sketch: edit.sketch_name,
        output: match &opts.destination {
            Destination::InPlace => src.dem_path.display().to_string(),
            Destination::Path(p) => p.display().to_string(),
        },
        views: view_reports,
        tiles_written: written
            .tiles_written
            .iter()
            .map(|p| p.display().to_string())
            .collect(),
        tiles_unchanged: written
            .tiles_unchanged
            .iter()
            .map(|p| p.display().to_string())
            .collect(),
        changed_cells: written.changed_cells,
        max_abs_displacement_m: max_abs,
        deformation: DeformationReport {
            window: [w.col, w.row, w.width as i64, w.height as i64],
            curve_constraints,
            lowering_constraints,
            influence_m: deformation.stats.influence_m,
            solver: serde_json::to_value(&deformation.stats).unwrap_or_default(),
        },
        timings_s: timings,
        notes,
        written: write,
        dry_run: opts.dry_run,
        min_fit: opts.min_fit,
        matching,
        corrections,
    };
    if let (Some(staged), Some(path)) = (staged_report, &opts.report) {
        commit_report(staged, path, &report)?;
    }
    edit.pb.finish_and_clear();
    if let Some(b) = below {
        return Err(EditError::BelowMinFit {
            sketch: report.sketch.clone(),
            view: b.view,
            stroke: b.stroke,
            fit: b.fit,
            min_fit: opts.min_fit,
            reason: b.reason,
            report: Box::new(report),
        });
    }
    Ok(report)
}

/// The report's staged file at `p`, its space claimed before the DEM is
/// written (a generous bound: the fixed part, each tile's path, each
/// stroke).
fn stage_report(
    p: &Path,
    src: &Sources,
    view_reports: &[ViewReport],
) -> Result<StagedFile, EditError> {
    let werr = |e: std::io::Error| EditError::Write {
        path: p.display().to_string(),
        message: e.to_string(),
    };
    let mut f = StagedFile::create(p).map_err(werr)?;
    let strokes: usize = view_reports.iter().map(|v| v.strokes.len()).sum();
    let curve_points: usize = view_reports
        .iter()
        .flat_map(|v| &v.strokes)
        .map(|s| s.placed_curve.len())
        .sum();
    let estimate = 64 * 1024 + 1024 * src.dem.tiles.len() + 8 * 1024 * strokes + 96 * curve_points;
    f.reserve(estimate as u64).map_err(werr)?;
    Ok(f)
}

/// Writes the deformation back to the DEM's tiles (atomically, verified),
/// with the edit's provenance: the sketch's name and content hash, the
/// input, the sketch file's SHA-256 and the edit's parameters.
fn write_back(
    src: &Sources,
    deformation: &Deformation,
    opts: &super::EditOptions,
) -> Result<WriteReport, EditError> {
    let provenance = Provenance {
        edit_id: format!(
            "{}:{}",
            src.sketch_path
                .file_name()
                .map(|n| n.to_string_lossy().into_owned())
                .unwrap_or_default(),
            content_hash(src.sketch)
        ),
    };
    let mut write_opts = opts.write.clone();
    write_opts.record = ProvenanceRecord {
        input: Some(src.dem_path.display().to_string()),
        sketch_sha256: std::fs::read(src.sketch_path).ok().map(|b| sha256_hex(&b)),
        parameters: Some(opts.parameters()),
    };
    Ok(src.dem.write_back_with(
        deformation.window,
        &deformation.write_values(),
        &opts.destination,
        &provenance,
        &write_opts,
    )?)
}

/// Not written: what a real run would change (a dry run fails as the real
/// run would on heights the DEM cannot store; when a stroke is `below`
/// the minimum fit, that failure is a note instead).
fn check_write_back(
    src: &Sources,
    deformation: &Deformation,
    below: bool,
    notes: &mut Vec<String>,
) -> Result<WriteReport, EditError> {
    let changed = match src
        .dem
        .check_write_back(deformation.window, &deformation.write_values())
    {
        Ok(n) => n,
        Err(e) if !below => return Err(e.into()),
        Err(e) => {
            notes.push(format!("the write-back would also fail: {e}"));
            0
        }
    };
    Ok(WriteReport {
        tiles_written: Vec::new(),
        tiles_unchanged: Vec::new(),
        changed_cells: changed,
    })
}

/// Moves the report into place at `path`.
fn commit_report(staged: StagedFile, path: &Path, report: &EditReport) -> Result<(), EditError> {
    let mut text = serde_json::to_string_pretty(report)
        .map_err(|e| EditError::Internal(format!("report: {e}")))?;
    text.push('\n');
    staged
        .commit(text.as_bytes())
        .map_err(|e| EditError::Write {
            path: path.display().to_string(),
            message: e.to_string(),
        })
}

/// Nodata of the height-change GeoTIFF (`--dz`).
pub const DZ_NODATA: f64 = -9999.0;

/// The height change `M` over the deformation's window as a Float32
/// GeoTIFF on the DEM's grid (nodata where the DEM has none).
fn write_dz(path: &Path, dem: &Dem, d: &Deformation) -> Result<(), crate::raster::RasterError> {
    let w = d.window;
    let g = dem.geotransform.0;
    let (c, r) = (w.col as f64, w.row as f64);
    let gt = [
        g[0] + c * g[1] + r * g[2],
        g[1],
        g[2],
        g[3] + c * g[4] + r * g[5],
        g[4],
        g[5],
    ];
    let data: Vec<f32> = d
        .displacement
        .iter()
        .zip(&d.base.data)
        .map(|(&m, &h)| {
            if m.is_nan() || h.is_nan() {
                DZ_NODATA as f32
            } else {
                m
            }
        })
        .collect();
    let spec = crate::raster::output_format::RasterSpec {
        width: w.width,
        height: w.height,
        geotransform: Some(gt),
        crs: dem.crs.gdal_definition(),
        nodata: Some(DZ_NODATA),
        description: Some("height change (new - old)".into()),
        ..Default::default()
    };
    crate::raster::output_format::write_raster(path, &spec, vec![data])
}

/// Honest outcome: the stroke with the lowest fit among those not fitted
/// (below `--min-fit`), if any; it stops the write (the report and
/// pictures still come, to show why).
fn worst_below_min_fit(views: &[ViewReport]) -> Option<BelowMinFit> {
    views
        .iter()
        .flat_map(|v| v.strokes.iter().map(move |s| (v, s)))
        .filter(|(_, s)| s.status != StrokeStatus::Fitted)
        .min_by(|a, b| a.1.fit.fitted_fraction.total_cmp(&b.1.fit.fitted_fraction))
        .map(|(v, s)| BelowMinFit {
            view: v.name.clone(),
            stroke: s.id.clone(),
            fit: s.fit.fitted_fraction,
            reason: s.reason.clone().unwrap_or_default(),
        })
}

/// Before/after views with the strokes, and the height-change map.
fn pictures(
    views: &[ViewState],
    after: &[RenderedView],
    d: &Deformation,
) -> Result<Vec<Picture>, EditError> {
    let enc = |w, h, rgb: &[u8]| encode_png(w, h, rgb).map_err(EditError::Internal);
    let mut out = Vec::new();
    for (v, a) in views.iter().zip(after) {
        let strokes: Vec<Vec<[f64; 2]>> = v.spec.strokes.iter().map(|s| s.points.clone()).collect();
        let (w, h) = (v.camera.width, v.camera.height);
        let name = picture_stem(&v.spec.name);
        out.push(Picture {
            name: format!("{name}_before.png"),
            png: enc(w, h, &view_picture(&v.before, &strokes))?,
        });
        out.push(Picture {
            name: format!("{name}_after.png"),
            png: enc(w, h, &view_picture(a, &strokes))?,
        });
    }
    let (gx, gy) = d.base.geotransform.pixel_size();
    let cell_m = if d.base.crs.geographic {
        let lat = d.base.geotransform.0[3].to_radians();
        (
            gx.abs() * 111_320.0 * lat.cos().max(0.01),
            gy.abs() * 110_540.0,
        )
    } else {
        (gx.abs(), gy.abs())
    };
    let (w, h, rgb) = height_change_map(
        d.window.width,
        d.window.height,
        cell_m,
        &d.base.data,
        &d.displacement,
    );
    out.push(Picture {
        name: "height_change.png".into(),
        png: enc(w, h, &rgb)?,
    });
    Ok(out)
}

/// A file-name-safe version of a view name: the stem of its pictures.
pub fn picture_stem(name: &str) -> String {
    let s: String = name
        .chars()
        .map(|c| {
            if c.is_ascii_alphanumeric() || c == '-' || c == '_' {
                c
            } else {
                '_'
            }
        })
        .collect();
    if s.is_empty() {
        "view".into()
    } else {
        s
    }
}

/// A short hash of the sketch content (FNV-1a of its JSON), for provenance.
fn content_hash(sketch: &SketchFile) -> String {
    let text = serde_json::to_string(sketch).unwrap_or_default();
    let mut h: u64 = 0xcbf2_9ce4_8422_2325;
    for b in text.bytes() {
        h ^= b as u64;
        h = h.wrapping_mul(0x0100_0000_01b3);
    }
    format!("{h:016x}")
}

/// Pictures written into a staging directory beside the target (exclusive,
/// unpredictable name), each read back, then moved into the target
/// directory on commit; removed if dropped uncommitted.
pub(crate) struct StagedDir {
    target: PathBuf,
    staging: Option<crate::raster::atomic_file::Staging>,
    names: Vec<String>,
}

impl StagedDir {
    pub(crate) fn create(target: &Path, pictures: &[Picture]) -> Result<StagedDir, EditError> {
        let werr = |m: String| EditError::Write {
            path: target.display().to_string(),
            message: m,
        };
        if target.exists() && !target.is_dir() {
            return Err(werr("exists and is not a directory".into()));
        }
        let parent = crate::raster::atomic_file::parent_dir(target);
        if !parent.is_dir() {
            return Err(werr("its parent directory does not exist".into()));
        }
        let staging = crate::raster::atomic_file::Staging::new_in(parent)
            .map_err(|e| werr(format!("cannot create a staging directory: {e}")))?;
        for p in pictures {
            crate::raster::atomic_file::write_bytes_verified(
                &staging.file(p.name.as_ref()),
                &p.png,
            )
            .map_err(|e| werr(format!("{}: {e}", p.name)))?;
        }
        Ok(StagedDir {
            target: target.to_path_buf(),
            staging: Some(staging),
            names: pictures.iter().map(|p| p.name.clone()).collect(),
        })
    }

    pub(crate) fn commit(mut self) -> Result<(), EditError> {
        let werr = |p: &Path, e: std::io::Error| EditError::Write {
            path: p.display().to_string(),
            message: e.to_string(),
        };
        let Some(staging) = self.staging.take() else {
            return Ok(());
        };
        let _commit = crate::raster::atomic_file::commit_guard();
        if !self.target.exists() {
            use std::os::unix::fs::PermissionsExt;
            // The staging directory is mode 700; the renders directory
            // gets an ordinary directory's mode.
            std::fs::set_permissions(staging.path(), std::fs::Permissions::from_mode(0o755))
                .map_err(|e| werr(&self.target, e))?;
            let kept = staging.keep();
            if let Err(e) = std::fs::rename(&kept, &self.target) {
                let _ = std::fs::remove_dir_all(&kept);
                return Err(werr(&self.target, e));
            }
        } else {
            for n in &self.names {
                let to = self.target.join(n);
                std::fs::rename(staging.file(n.as_ref()), &to).map_err(|e| werr(&to, e))?;
            }
        }
        Ok(())
    }
}
