//! The files GDAL keeps beside a raster, kept true after an edit: the
//! external overviews `NAME.ovr` (staged as `TMP.ovr` beside the temporary
//! file, so that GDAL finds and updates them with it, and renamed with it)
//! and the PAM sidecar `NAME.aux.xml`, whose statistics and histograms an
//! edit makes stale: they are removed (the rest of the sidecar, e.g. user
//! metadata, is kept), as are the STATISTICS_* items GDAL stores inside a
//! GeoTIFF. `gdalinfo -stats` recomputes them on demand.

use std::ffi::OsString;
use std::path::{Path, PathBuf};

use super::RasterError;

/// `path` with `suffix` appended to its file name (`x.tif` -> `x.tif.ovr`).
pub fn with_suffix(path: &Path, suffix: &str) -> PathBuf {
    let mut s: OsString = path.as_os_str().to_owned();
    s.push(suffix);
    PathBuf::from(s)
}

/// The external overview file GDAL would use for `path`, if there is one.
pub fn external_overviews(path: &Path) -> Option<PathBuf> {
    [".ovr", ".OVR"]
        .iter()
        .map(|s| with_suffix(path, s))
        .find(|p| p.is_file())
}

/// The band metadata items GDAL uses for cached statistics.
pub const STATISTICS_ITEMS: [&str; 6] = [
    "STATISTICS_MINIMUM",
    "STATISTICS_MAXIMUM",
    "STATISTICS_MEAN",
    "STATISTICS_STDDEV",
    "STATISTICS_VALID_PERCENT",
    "STATISTICS_APPROXIMATE",
];

/// Remove the cached statistics of band 1 of `ds` (open for update).
pub fn clear_statistics(ds: &gdal::Dataset) {
    let Ok(band) = ds.rasterband(1) else { return };
    for key in STATISTICS_ITEMS {
        let Ok(k) = std::ffi::CString::new(key) else {
            continue;
        };
        // SAFETY: a valid band handle of a live dataset; a NULL value
        // removes the item (GDALSetMetadataItem's documented behaviour).
        unsafe {
            gdal_sys::GDALSetMetadataItem(
                band.c_rasterband() as gdal_sys::GDALMajorObjectH,
                k.as_ptr(),
                std::ptr::null(),
                c"".as_ptr(),
            );
        }
    }
}

/// A PAM sidecar's XML without statistics items and histograms.
pub fn strip_statistics(xml: &str) -> String {
    let mut out = String::with_capacity(xml.len());
    let mut in_histograms = false;
    for line in xml.split_inclusive('\n') {
        let t = line.trim_start();
        if in_histograms {
            if t.starts_with("</Histograms>") {
                in_histograms = false;
            }
            continue;
        }
        if t.starts_with("<Histograms>") {
            in_histograms = !t.contains("</Histograms>");
            continue;
        }
        if t.starts_with("<MDI key=\"STATISTICS_") {
            continue;
        }
        out.push_str(line);
    }
    // An element left empty by the removal is dropped (GDAL writes none).
    let mut s = out;
    for empty in ["<Metadata>\n", "<Metadata />\n"] {
        while let Some(i) = s.find(empty) {
            let after = &s[i + empty.len()..];
            let trimmed = after.trim_start();
            if let Some(rest) = trimmed.strip_prefix("</Metadata>") {
                let line_start = s[..i].rfind('\n').map(|p| p + 1).unwrap_or(0);
                let end = s.len() - rest.len();
                let end = end + rest.find('\n').map(|p| p + 1).unwrap_or(rest.len());
                s.replace_range(line_start..end, "");
            } else {
                break;
            }
        }
    }
    s
}

/// True when a PAM document holds anything beyond its empty wrappers.
fn has_content(xml: &str) -> bool {
    let mut rest = xml;
    while let Some(i) = rest.find('<') {
        let Some(j) = rest[i..].find('>') else {
            return true;
        };
        let tag = rest[i + 1..i + j].trim_start_matches('/');
        let name = tag.split_whitespace().next().unwrap_or("");
        if !matches!(name, "PAMDataset" | "PAMRasterBand") {
            return true;
        }
        rest = &rest[i + j + 1..];
    }
    false
}

/// The sidecars to put beside an output once it is in place.
#[derive(Debug, Default)]
pub struct Sidecars {
    /// Staged `.ovr` and its final name.
    pub overviews: Option<(PathBuf, PathBuf)>,
    /// The new `.aux.xml` contents and its final name (`None` contents:
    /// remove a stale one).
    pub aux: Option<(Option<String>, PathBuf)>,
    /// Other files the output's driver wrote (a `.prj`), staged, with
    /// their final names.
    pub extra: Vec<(PathBuf, PathBuf)>,
}

impl Sidecars {
    /// Stage the sidecars of `source` for an output at `target` whose
    /// temporary file is `tmp`: its `.ovr` copied to `TMP.ovr` (when the
    /// file has no internal overviews, as GDAL would use it), its
    /// `.aux.xml` without statistics.
    pub fn stage(
        source: &Path,
        tmp: &Path,
        target: &Path,
        internal_overviews: bool,
    ) -> Result<Sidecars, RasterError> {
        let mut s = Sidecars::default();
        if !internal_overviews {
            if let Some(ovr) = external_overviews(source) {
                let staged = with_suffix(tmp, ".ovr");
                std::fs::copy(&ovr, &staged).map_err(|e| RasterError::io(&staged, e))?;
                s.overviews = Some((staged, with_suffix(target, ".ovr")));
            }
        }
        let aux = with_suffix(source, ".aux.xml");
        if aux.is_file() {
            let text = std::fs::read_to_string(&aux).map_err(|e| RasterError::io(&aux, e))?;
            let stripped = strip_statistics(&text);
            let keep = has_content(&stripped);
            s.aux = Some((keep.then_some(stripped), with_suffix(target, ".aux.xml")));
        }
        Ok(s)
    }

    /// Remove whatever was staged (on failure).
    pub fn discard(&self) {
        if let Some((staged, _)) = &self.overviews {
            let _ = std::fs::remove_file(staged);
        }
        for (staged, _) in &self.extra {
            let _ = std::fs::remove_file(staged);
        }
    }

    /// Remove what GDAL or [`Sidecars::stage`] may have put beside a
    /// temporary file `tmp` (on failure, when the staging record is lost).
    pub fn discard_beside(tmp: &Path) {
        for s in [".ovr", ".aux.xml"] {
            let _ = std::fs::remove_file(with_suffix(tmp, s));
        }
    }

    /// Move the staged sidecars into place (after the main file).
    pub fn commit(&self) -> Result<(), RasterError> {
        if let Some((staged, target)) = &self.overviews {
            std::fs::rename(staged, target).map_err(|e| RasterError::io(target, e))?;
        }
        for (staged, target) in &self.extra {
            std::fs::rename(staged, target).map_err(|e| RasterError::io(target, e))?;
        }
        if let Some((text, target)) = &self.aux {
            match text {
                Some(t) => {
                    let tmp =
                        with_suffix(target, &format!(".demsketch-{}.tmp", std::process::id()));
                    std::fs::write(&tmp, t)
                        .and_then(|_| std::fs::rename(&tmp, target))
                        .map_err(|e| {
                            let _ = std::fs::remove_file(&tmp);
                            RasterError::io(target, e)
                        })?;
                }
                None => match std::fs::remove_file(target) {
                    Ok(()) => {}
                    Err(e) if e.kind() == std::io::ErrorKind::NotFound => {}
                    Err(e) => return Err(RasterError::io(target, e)),
                },
            }
        }
        Ok(())
    }
}

/// Copy the sidecars of an unchanged tile `source` beside its copy
/// `target` (they are still true of it).
pub fn copy_unchanged(source: &Path, target: &Path) -> Result<(), RasterError> {
    for s in [".ovr", ".aux.xml"] {
        let from = with_suffix(source, s);
        if from.is_file() {
            let to = with_suffix(target, s);
            std::fs::copy(&from, &to).map_err(|e| RasterError::io(&to, e))?;
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn statistics_and_histograms_are_stripped() {
        let xml = "<PAMDataset>\n  <PAMRasterBand band=\"1\">\n    <Histograms>\n      <HistItem>\n      </HistItem>\n    </Histograms>\n    <Metadata>\n      <MDI key=\"STATISTICS_MAXIMUM\">3</MDI>\n      <MDI key=\"OTHER\">x</MDI>\n    </Metadata>\n  </PAMRasterBand>\n</PAMDataset>\n";
        let s = strip_statistics(xml);
        assert!(!s.contains("STATISTICS"), "{s}");
        assert!(!s.contains("Hist"), "{s}");
        assert!(s.contains("<MDI key=\"OTHER\">x</MDI>"), "{s}");
        let only = "<PAMDataset>\n  <PAMRasterBand band=\"1\">\n    <Metadata>\n      <MDI key=\"STATISTICS_MEAN\">3</MDI>\n    </Metadata>\n  </PAMRasterBand>\n</PAMDataset>\n";
        let s = strip_statistics(only);
        assert!(!s.contains("Metadata"), "{s}");
    }
}
