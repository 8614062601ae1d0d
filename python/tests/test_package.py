"""`import demsketch`: open a DEM and read a window (against GDAL's own
reading), view (against `demsketch view`), edit (against `demsketch edit`),
and errors as one-line exceptions."""

import shutil

import numpy as np
import pytest
from osgeo import gdal

import demsketch
from conftest import FIXTURES, FLAGS, OPTIONS, cli, digests, sketch, tile_set

gdal.UseExceptions()
TEXAS = FIXTURES / "texas_srtm90m_tiled_int16.tif"


def gdal_window(path, col, row, w, h):
    ds = gdal.Open(str(path))
    b = ds.GetRasterBand(1)
    a = b.ReadAsArray(col, row, w, h).astype(np.float32)
    nd = b.GetNoDataValue()
    if nd is not None:
        a[a == np.float32(nd)] = np.nan
    return a


def test_open_and_read_window_equal_gdal():
    d = demsketch.open(TEXAS)
    ds = gdal.Open(str(TEXAS))
    assert (d.width, d.height) == (ds.RasterXSize, ds.RasterYSize)
    assert d.kind == "geotiff" and d.tiles == 1
    assert d.geotransform == pytest.approx(ds.GetGeoTransform(), abs=1e-12)
    assert d.nodata == ds.GetRasterBand(1).GetNoDataValue()
    a = d.read_window(40, 30, 100, 70)
    assert a.dtype == np.float32 and a.shape == (70, 100)
    np.testing.assert_array_equal(a, gdal_window(TEXAS, 40, 30, 100, 70))
    whole = d.read_window()
    assert whole.shape == (d.height, d.width)
    np.testing.assert_array_equal(whole, gdal_window(TEXAS, 0, 0, d.width, d.height))


def test_a_window_across_tiles_is_seamless(tmp_path):
    dem = tile_set(tmp_path)
    d = demsketch.Dem(str(dem))
    assert d.kind == "tiles" and d.tiles == 16 and (d.width, d.height) == (192, 192)
    # Across four tiles' corners: the source file's cells at offset 64.
    a = d.read_window(30, 40, 60, 50)
    np.testing.assert_array_equal(a, gdal_window(TEXAS, 94, 104, 60, 50))


def test_view_equals_the_command(tmp_path):
    zion = FIXTURES / "zion_srtm_utm12n.tif"
    flags = dict(heading=10.0, pitch=4.0, width=320, height=180, max_distance=20000.0)
    png = tmp_path / "cli.png"
    cli("view", zion, "--lon", "-112.998", "--lat", "37.188", "--heading", "10", "--pitch", "4",
        "--size", "320x180", "--max-distance", "20000", "--out", png)
    mine = tmp_path / "py.png"
    rgb = demsketch.open(zion).view(-112.998, 37.188, out=mine, **flags)
    assert rgb.dtype == np.uint8 and rgb.shape == (180, 320, 3)
    assert mine.read_bytes() == png.read_bytes()
    np.testing.assert_array_equal(rgb, gdal.Open(str(png)).ReadAsArray().transpose(1, 2, 0))


def test_a_long_view_equals_the_command(tmp_path):
    # 160 px over 90 degrees: the view reaches beyond the full-resolution
    # reach (20 km) and is drawn from coarser rings there, as the command
    # draws it; full_resolution=True reads the whole wedge exactly.
    zion = FIXTURES / "zion_srtm_utm12n.tif"
    flags = dict(heading=0.0, pitch=-2.0, hfov=90.0, width=160, height=90, eye_height=1500.0)
    png = tmp_path / "cli.png"
    cli("view", zion, "--lon", "-112.998", "--lat", "37.15", "--heading", "0", "--pitch", "-2",
        "--hfov", "90", "--size", "160x90", "--eye-height", "1500", "--out", png)
    mine = tmp_path / "py.png"
    demsketch.open(zion).view(-112.998, 37.15, out=mine, **flags)
    assert mine.read_bytes() == png.read_bytes()
    full = tmp_path / "full.png"
    demsketch.open(zion).view(-112.998, 37.15, out=full, full_resolution=True, **flags)
    assert full.read_bytes() != png.read_bytes()


def test_edit_equals_the_command(tmp_path):
    dem = tile_set(tmp_path)
    s = tmp_path / "s.json"
    s.write_text(sketch(20.0, 20.0, 0.0, 1.5))
    out = tmp_path / "out"
    cli("edit", dem, "--sketch", s, "--out", out, *FLAGS, "--quiet")
    want = digests(out)
    shutil.rmtree(out)
    report = demsketch.edit(dem, s, out, **OPTIONS)
    assert report["written"] and report["changed_cells"] > 0
    assert digests(out) == want
    assert want != digests(dem)


def test_in_place_and_below_min_fit(tmp_path):
    dem = tile_set(tmp_path)
    before = digests(dem)
    s = tmp_path / "s.json"
    s.write_text(sketch(172.0, 172.0, 270.0, 1.5))
    # A fit no stroke can reach: nothing written, the report is.
    report = tmp_path / "r.json"
    with pytest.raises(demsketch.BelowMinFitError, match="min.fit|nothing written"):
        demsketch.edit(dem, s, in_place=True, report=report, max_distance=1000.0, min_fit=1.5)
    assert digests(dem) == before and report.is_file()
    r = demsketch.edit(dem, s, in_place=True, **OPTIONS)
    assert r["written"] and digests(dem) != before
    with pytest.raises(demsketch.DemsketchError, match="not both"):
        demsketch.edit(dem, s, tmp_path / "o", in_place=True)


def test_errors_are_one_line_exceptions(tmp_path):
    with pytest.raises(demsketch.DemsketchError) as e:
        demsketch.open(tmp_path / "missing.tif")
    assert "missing.tif" in str(e.value) and "\n" not in str(e.value)
    bad = tmp_path / "bad.json"
    bad.write_text("{not json")
    with pytest.raises(demsketch.DemsketchError) as e:
        demsketch.edit(TEXAS, bad, tmp_path / "o.tif")
    assert "bad.json" in str(e.value) and "\n" not in str(e.value)
    assert not (tmp_path / "o.tif").exists()
    with pytest.raises(demsketch.DemsketchError) as e:
        demsketch.open(TEXAS).view(0.0, 0.0, width=10, height=10)
    assert "\n" not in str(e.value)
