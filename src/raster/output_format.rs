//! Output formats as GDAL's utilities choose them: `-of FORMAT` names a
//! GDAL driver; without it the format follows the output's extension
//! (`.tif`/`.tiff` GeoTIFF, `.asc` Arc/Info ASCII grid, `.img` Erdas
//! Imagine, ... whatever GDAL registers for the extension), and a name
//! without extension is a GeoTIFF, as `gdal_translate` does. A format GDAL
//! cannot write, a VRT (which would only point at files), or an extension
//! no writable format claims is refused in one line before anything is
//! computed. `-co NAME=VALUE` creation options pass to the driver; for a
//! GeoTIFF they override the options that reproduce the input's layout.
//!
//! Drivers that write several files (`.asc` with its `.prj`) write into a
//! private staging directory beside the output, whose files are moved into
//! place together once the write succeeded.

use std::path::{Path, PathBuf};

use gdal::raster::RasterCreationOptions;
use gdal::{Dataset, DriverManager, DriverType, Metadata};

use super::provenance::ProvenanceRecord;
use super::RasterError;

/// How write-back writes its output, beyond the edit itself.
#[derive(Debug, Clone, Default)]
pub struct WriteOptions {
    /// `--overview-resampling` (a GDAL resampling name); `None`: the one
    /// the file records, else AVERAGE.
    pub overview_resampling: Option<String>,
    /// `-of`: the GDAL driver of `--out`; `None`: from its extension (a
    /// GeoTIFF input's own flavour, COG or not, for a GeoTIFF output).
    pub format: Option<String>,
    /// `-co NAME=VALUE` creation options.
    pub creation_options: Vec<String>,
    /// What the provenance entry records besides the edit id.
    pub record: ProvenanceRecord,
    /// Hard-link the unchanged tiles of a tile-directory output to the
    /// input's instead of copying them (`--link`): faster and free of
    /// space, but a tool that later modifies an output tile in place then
    /// modifies the input too.
    pub link_unchanged: bool,
    /// `--pyramid-resampling`: the resampling of a tile directory's
    /// `gdal_retile.py -levels` pyramid, refreshed after an in-place write
    /// ([`super::pyramid`]); `None`: near, `gdal_retile.py`'s default.
    pub pyramid_resampling: Option<String>,
    /// Leave a tile directory's `gdal_retile.py -levels` pyramid as it is:
    /// the caller refreshes it itself, over the union of several writes
    /// (a batch, once at its end: [`crate::batch::pyramid`]).
    pub defer_pyramid: bool,
}

impl WriteOptions {
    /// True when the output is a GeoTIFF written like its input (no `-co`,
    /// no `-of` other than GTiff/COG): the case [`super::block_patch`]
    /// covers.
    pub fn keeps_geotiff(&self, out: Option<&Path>) -> bool {
        if !self.creation_options.is_empty() {
            return false;
        }
        match out {
            None => true,
            Some(p) => {
                matches!(
                    output_driver(p, self.format.as_deref()).as_deref(),
                    Ok("GTiff") | Ok("COG")
                ) && self
                    .format
                    .as_deref()
                    .is_none_or(|f| f.eq_ignore_ascii_case("GTiff"))
            }
        }
    }
}

/// The GDAL driver that writes `out`: `format` (checked), else the one its
/// extension names (GeoTIFF without an extension). Errors are one line
/// naming `out`.
pub fn output_driver(out: &Path, format: Option<&str>) -> Result<String, String> {
    let name = out.display();
    if let Some(f) = format {
        let d = DriverManager::get_driver_by_name(f)
            .map_err(|_| format!("{name}: -of {f}: GDAL has no such format"))?;
        let short = d.short_name();
        if short.eq_ignore_ascii_case("VRT") {
            return Err(format!(
                "{name}: -of VRT is not supported (a VRT only points at other files); write a GeoTIFF"
            ));
        }
        if d.metadata_item("DCAP_RASTER", "").is_none()
            || (d.metadata_item("DCAP_CREATE", "").is_none()
                && d.metadata_item("DCAP_CREATECOPY", "").is_none())
        {
            return Err(format!(
                "{name}: -of {short}: GDAL cannot write rasters in this format"
            ));
        }
        return Ok(short);
    }
    let ext = out
        .extension()
        .map(|e| e.to_string_lossy().to_ascii_lowercase())
        .unwrap_or_default();
    match ext.as_str() {
        "" | "tif" | "tiff" | "gtiff" => return Ok("GTiff".into()),
        "vrt" => {
            return Err(format!(
            "{name}: VRT output is not supported (a VRT only points at other files); give a .tif"
        ))
        }
        _ => {}
    }
    match DriverManager::get_output_driver_for_dataset_name(out, DriverType::Raster) {
        Some(d) if !d.short_name().eq_ignore_ascii_case("VRT") => Ok(d.short_name()),
        _ => Err(format!(
            "{name}: no raster format GDAL can write has the extension '.{ext}'; give -of FORMAT or a .tif"
        )),
    }
}

/// Check `-co` items: each `NAME=VALUE`.
pub fn check_creation_options(items: &[String]) -> Result<(), String> {
    for i in items {
        match i.split_once('=') {
            Some((k, _)) if !k.trim().is_empty() => {}
            _ => return Err(format!("-co '{i}' must be written NAME=VALUE")),
        }
    }
    Ok(())
}

/// `base` with `user` options on top (same name: the user's wins; a user
/// option about the block layout replaces all of the base's, which
/// describe another layout).
pub fn merge_options(base: Vec<String>, user: &[String]) -> Vec<String> {
    let key = |s: &str| {
        s.split_once('=')
            .map(|(k, _)| k.trim().to_ascii_uppercase())
            .unwrap_or_default()
    };
    const LAYOUT: [&str; 4] = ["TILED", "BLOCKXSIZE", "BLOCKYSIZE", "BLOCKSIZE"];
    let user_layout = user.iter().any(|u| LAYOUT.contains(&key(u).as_str()));
    let mut out: Vec<String> = base
        .into_iter()
        .filter(|b| !user.iter().any(|u| key(u) == key(b)))
        .filter(|b| !(user_layout && LAYOUT.contains(&key(b).as_str())))
        .collect();
    out.extend(user.iter().cloned());
    out
}

/// True when the file at `path` is a BigTIFF.
pub fn is_bigtiff(path: &Path) -> bool {
    use std::io::Read;
    let mut b = [0u8; 4];
    std::fs::File::open(path)
        .and_then(|mut f| f.read_exact(&mut b))
        .map(|_| matches!(&b, b"II+\0" | b"MM\0+"))
        .unwrap_or(false)
}

/// Files written by a driver for an output, to move into place after the
/// main file: `(staged, final)`.
pub type StagedFiles = Vec<(PathBuf, PathBuf)>;

/// Write `src` with `driver` and `options` so that its main file ends up
/// at `tmp` (renamed to `target` by the caller) and any other file the
/// driver writes (a `.prj`, ...) is returned staged with its final path.
/// The driver writes under `target`'s name in a private staging directory,
/// so that sidecars get the names GDAL gives them.
pub fn write_copy(
    src: &Dataset,
    driver: &str,
    options: &[String],
    tmp: &Path,
    target: &Path,
) -> Result<StagedFiles, RasterError> {
    let werr = |m: String| RasterError::Write {
        path: target.to_path_buf(),
        message: m,
    };
    let d = DriverManager::get_driver_by_name(driver).map_err(|e| werr(e.to_string()))?;
    let opts = RasterCreationOptions::from_iter(options.iter().cloned());
    if driver == "GTiff" || driver == "COG" {
        // Written in memory, then to disk by demsketch: a full disk is a
        // plain write error (libtiff may hang on one).
        super::atomic_file::through_memory(tmp, None, |m| {
            let ds = src
                .create_copy(&d, m, &opts)
                .map_err(|e| werr(format!("GDAL could not write the file: {e}")))?;
            ds.close().map_err(|e| werr(e.to_string()))
        })
        .map_err(|m| {
            let t = format!("{}: ", target.display());
            werr(m.strip_prefix(&t).unwrap_or(&m).to_string())
        })?;
        return Ok(Vec::new());
    }
    let parent = target
        .parent()
        .filter(|p| !p.as_os_str().is_empty())
        .unwrap_or(Path::new("."));
    let stage = parent.join(format!(
        ".{}.demsketch-{}.d",
        target
            .file_name()
            .map(|n| n.to_string_lossy().into_owned())
            .unwrap_or_default(),
        std::process::id()
    ));
    let _ = std::fs::remove_dir_all(&stage);
    std::fs::create_dir(&stage).map_err(|e| RasterError::io(&stage, e))?;
    let run = || -> Result<StagedFiles, RasterError> {
        let name = target.file_name().unwrap_or_default();
        let main = stage.join(name);
        let ds = src
            .create_copy(&d, &main, &opts)
            .map_err(|e| werr(format!("GDAL could not write the {driver} file: {e}")))?;
        ds.close().map_err(|e| werr(e.to_string()))?;
        std::fs::rename(&main, tmp).map_err(|e| RasterError::io(target, e))?;
        let mut extra = Vec::new();
        for entry in std::fs::read_dir(&stage).map_err(|e| RasterError::io(&stage, e))? {
            let p = entry.map_err(|e| RasterError::io(&stage, e))?.path();
            let staged = parent.join(format!(
                ".{}.demsketch-{}.tmp",
                p.file_name().unwrap_or_default().to_string_lossy(),
                std::process::id()
            ));
            std::fs::rename(&p, &staged).map_err(|e| RasterError::io(target, e))?;
            extra.push((staged, parent.join(p.file_name().unwrap_or_default())));
        }
        Ok(extra)
    };
    let r = run();
    let _ = std::fs::remove_dir_all(&stage);
    r.map_err(|e| match e {
        RasterError::Write { path, message } => RasterError::Write {
            path,
            message: message.replace(
                stage
                    .join(target.file_name().unwrap_or_default())
                    .to_string_lossy()
                    .as_ref(),
                target.to_string_lossy().as_ref(),
            ),
        },
        other => other,
    })
}

/// A single-band raster to write: size, georeference and nodata.
#[derive(Debug, Clone, Default)]
pub struct RasterSpec {
    pub width: usize,
    pub height: usize,
    /// GDAL geotransform (`None`: image space, no georeference).
    pub geotransform: Option<[f64; 6]>,
    /// CRS as GDAL reads it (WKT or PROJ string; empty: none).
    pub crs: String,
    pub nodata: Option<f64>,
    /// Band description (`gdalinfo` "Description").
    pub description: Option<String>,
    /// `-of` (`None`: from the extension).
    pub format: Option<String>,
    /// `-co NAME=VALUE`.
    pub creation_options: Vec<String>,
}

/// Write `bands` (each row-major `width * height`) to `path` in the format
/// `-of` or its extension names, atomically (a temporary file beside it,
/// renamed; a driver's extra files moved after it).
pub fn write_raster<T: gdal::raster::GdalType + Copy>(
    path: &Path,
    spec: &RasterSpec,
    bands: Vec<Vec<T>>,
) -> Result<(), RasterError> {
    let werr = |m: String| RasterError::Write {
        path: path.to_path_buf(),
        message: m,
    };
    let gerr = |e: gdal::errors::GdalError| werr(e.to_string());
    let driver = output_driver(path, spec.format.as_deref()).map_err(|m| {
        werr(
            m.strip_prefix(&format!("{}: ", path.display()))
                .unwrap_or(&m)
                .to_string(),
        )
    })?;
    check_creation_options(&spec.creation_options).map_err(werr)?;
    let mem_driver = DriverManager::get_driver_by_name("MEM").map_err(gerr)?;
    let mut mem = mem_driver
        .create_with_band_type::<T, _>("", spec.width, spec.height, bands.len())
        .map_err(gerr)?;
    if let Some(gt) = spec.geotransform {
        mem.set_geo_transform(&gt).map_err(gerr)?;
    }
    if !spec.crs.is_empty() {
        if let Ok(sr) = gdal::spatial_ref::SpatialRef::from_definition(&spec.crs) {
            mem.set_spatial_ref(&sr).map_err(gerr)?;
        }
    }
    for (i, data) in bands.into_iter().enumerate() {
        let mut band = mem.rasterband(i + 1).map_err(gerr)?;
        if let Some(nd) = spec.nodata {
            band.set_no_data_value(Some(nd)).map_err(gerr)?;
        }
        if let Some(d) = &spec.description {
            band.set_description(d).map_err(gerr)?;
        }
        let size = (spec.width, spec.height);
        band.write((0, 0), size, &mut gdal::raster::Buffer::new(size, data))
            .map_err(gerr)?;
    }
    let base: Vec<String> = if driver == "GTiff" {
        vec!["TILED=YES".into(), "COMPRESS=DEFLATE".into()]
    } else {
        Vec::new()
    };
    let options = merge_options(base, &spec.creation_options);
    let tmp = path.with_file_name(format!(
        ".{}.demsketch-{}.tmp",
        path.file_name()
            .map(|n| n.to_string_lossy().into_owned())
            .unwrap_or_default(),
        std::process::id()
    ));
    let result = write_copy(&mem, &driver, &options, &tmp, path).and_then(|extra| {
        std::fs::File::open(&tmp)
            .and_then(|f| f.sync_all())
            .and_then(|_| std::fs::rename(&tmp, path))
            .map_err(|e| RasterError::io(path, e))?;
        for (staged, target) in &extra {
            std::fs::rename(staged, target).map_err(|e| RasterError::io(target, e))?;
        }
        Ok(())
    });
    if result.is_err() {
        let _ = std::fs::remove_file(&tmp);
    }
    result.map_err(|e| match e {
        RasterError::Write { message, .. } => RasterError::Write {
            path: path.to_path_buf(),
            message: message.replace(
                tmp.to_string_lossy().as_ref(),
                path.to_string_lossy().as_ref(),
            ),
        },
        other => other,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn formats_follow_the_extension_like_gdal_translate() {
        assert_eq!(output_driver(Path::new("a.tif"), None).unwrap(), "GTiff");
        assert_eq!(output_driver(Path::new("a.TIFF"), None).unwrap(), "GTiff");
        assert_eq!(output_driver(Path::new("a"), None).unwrap(), "GTiff");
        assert_eq!(output_driver(Path::new("a.asc"), None).unwrap(), "AAIGrid");
        assert!(output_driver(Path::new("a.vrt"), None).is_err());
        assert!(output_driver(Path::new("a.qqq"), None).is_err());
        assert_eq!(
            output_driver(Path::new("a.dat"), Some("gtiff")).unwrap(),
            "GTiff"
        );
        assert!(output_driver(Path::new("a.tif"), Some("VRT")).is_err());
        assert!(output_driver(Path::new("a.tif"), Some("NoSuch")).is_err());
    }

    #[test]
    fn user_options_override() {
        let m = merge_options(
            vec!["COMPRESS=LZW".into(), "TILED=YES".into()],
            &["compress=ZSTD".into()],
        );
        assert_eq!(
            m,
            vec!["TILED=YES".to_string(), "compress=ZSTD".to_string()]
        );
    }
}
