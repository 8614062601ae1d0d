//! An edit round's re-render that takes from the round before what the
//! terrain's change cannot reach (`RenderedView::rerender_terrain_region`)
//! gives the render a fresh one gives, to the bit: depths, triangles and
//! silhouettes, for a change of one vertex, of none, and of many.

mod common;

use common::fixture;
use demsketch::edit::rendered_view::{RenderedView, StrokeRegion};
use demsketch::raster::Dem;
use demsketch::render::{LocalTerrain, Scene};
use demsketch::view::{Camera, Georef, Viewpoint};

/// The region of a view down to two thirds of its height, silhouettes
/// wanted at any depth.
fn region(cam: &Camera) -> StrokeRegion {
    let (w, h) = (cam.width, cam.height);
    StrokeRegion {
        last_row: vec![(2 * h / 3) as i32; w],
        depth_limit: vec![f32::INFINITY; w],
        stroke_rows: vec![Vec::new(); w],
    }
}

/// The two renders are the same to the bit.
fn assert_same_render(got: &RenderedView, want: &RenderedView, what: &str) {
    let bits = |v: &RenderedView| {
        v.depth
            .depth
            .iter()
            .map(|d| d.to_bits())
            .collect::<Vec<_>>()
    };
    assert!(bits(got) == bits(want), "{what}: depths");
    assert!(
        got.depth.triangle == want.depth.triangle,
        "{what}: triangles"
    );
    assert_eq!(
        format!("{:?}", got.silhouettes),
        format!("{:?}", want.silhouettes),
        "{what}: silhouettes"
    );
    assert_eq!(got.skyline_row, want.skyline_row, "{what}: skyline");
    assert_eq!(got.by_column, want.by_column, "{what}: samples by column");
}

/// How far the Zion view of these tests reaches, metres.
const ZION_VIEW_M: f64 = 20_000.0;

/// A camera 1.7 m above cell (210, 103) of the Zion fixture, looking at
/// 200 degrees, and the wedge of the DEM it sees within [`ZION_VIEW_M`].
fn zion_view() -> (Camera, Scene) {
    let dem = Dem::open(&fixture("zion_srtm_utm12n.tif")).unwrap();
    let (x, y) = dem.geotransform.pixel_to_crs(210.5, 103.5);
    let georef = Georef::for_crs(&dem.crs, "zion").unwrap();
    let (lon, lat) = georef.crs_to_lonlat(x, y).unwrap();
    let vp = Viewpoint::above_surface(lon, lat, 1.7);
    let cam = Camera::new(480, 240, 200.0, -1.0, 0.0, 60.0).unwrap();
    let scene = Scene::open_wedge(&dem, &vp, Some(ZION_VIEW_M), 1.0 / 7.0, &cam).unwrap();
    (cam, scene)
}

#[test]
fn a_re_render_after_a_change_is_the_fresh_render() {
    let (cam, scene) = zion_view();
    let (w, h) = (scene.window.width, scene.window.height);
    // The view before the edit, as the edit renders it (index and ranges
    // built, which the patched terrains patch).
    let before = RenderedView::from_terrain(scene.terrain.clone(), &cam).unwrap();
    let base: &LocalTerrain = &before.terrain;
    let region = region(&cam);
    // A round's terrain: the whole window raised a little.
    let rect = (0, 0, w, h);
    let raise = |k: f32| {
        let map = &scene.window;
        move |c: usize, r: usize| -> Option<f32> {
            let v = map.get(c, r)?;
            Some(v + k * ((c + 3 * r) % 11) as f32)
        }
    };
    let first = raise(3.0);
    let t1 = base.with_heights(rect, &first);
    let r1 = RenderedView::render_terrain_region(t1, &cam, &region).unwrap();
    let fresh = |t: &LocalTerrain| RenderedView::render_terrain_region(t.clone(), &cam, &region);

    // One vertex changed since: where silhouettes of the view lie (the
    // longest ones', at their middle), so that some strips render and
    // some columns refine again, the others taken as they were.
    let one_at = |at: (usize, usize)| {
        let first = &first;
        move |c: usize, r: usize| -> Option<f32> {
            let v = first(c, r)?;
            Some(if (c, r) == at { v + 0.7 } else { v })
        }
    };
    let mut curves: Vec<_> = before.silhouettes.curves.iter().collect();
    curves.sort_by_key(|c| std::cmp::Reverse(c.samples.len()));
    let mut reached = 0;
    for c in curves.iter().take(8) {
        let s = &c.samples[c.samples.len() / 2];
        let at = (
            base.col0 + s.cell[0] as usize,
            base.row0 + s.cell[1] as usize,
        );
        let t2 = base.with_heights(rect, &one_at(at));
        let want = fresh(&t2).unwrap();
        let got = RenderedView::rerender_terrain_region(t2, &cam, &region, &r1).unwrap();
        assert_same_render(&got, &want, &format!("one vertex at {at:?}"));
        reached += usize::from(got.depth.triangle != r1.depth.triangle);
    }
    assert!(reached > 0, "no change reached the depth buffer");

    // Nothing changed since.
    let t3 = base.with_heights(rect, &first);
    let want = fresh(&t3).unwrap();
    let got = RenderedView::rerender_terrain_region(t3, &cam, &region, &r1).unwrap();
    assert_same_render(&got, &want, "no change");

    // Everything in the rectangle changed since.
    let second = raise(-2.0);
    let t4 = base.with_heights(rect, &second);
    let want = fresh(&t4).unwrap();
    let got = RenderedView::rerender_terrain_region(t4, &cam, &region, &r1).unwrap();
    assert_same_render(&got, &want, "the whole rectangle");

    // Another region: rendered afresh.
    let mut other = region.clone();
    other.last_row[0] -= 1;
    let t5 = base.with_heights(rect, &one_at((rect.0 + 1, rect.1 + 1)));
    let want = RenderedView::render_terrain_region(t5.clone(), &cam, &other).unwrap();
    let got = RenderedView::rerender_terrain_region(t5, &cam, &other, &r1).unwrap();
    assert_same_render(&got, &want, "another region");
}

/// A whole render of a surface that a region render was made on (the
/// next pass of an edit starts from its last round's terrain) takes that
/// render's refined candidates (`RenderedView::from_terrain_after`) and is
/// the fresh whole render, to the bit; on another surface it renders
/// afresh.
#[test]
fn a_whole_render_after_a_region_render_of_its_surface_is_the_fresh_render() {
    let (cam, scene) = zion_view();
    let max_d = Some(ZION_VIEW_M);
    let (w, h) = (scene.window.width, scene.window.height);
    let before = RenderedView::from_terrain(scene.terrain.clone(), &cam).unwrap();
    let base: &LocalTerrain = &before.terrain;
    // The last round's terrain: the window changed a little (lowered,
    // the eye staying above the ground), patched over the view's terrain
    // as the rounds do ...
    let raised = |c: usize, r: usize| -> Option<f32> {
        let v = scene.window.get(c, r)?;
        Some(v - 2.0 * ((c + 3 * r) % 11) as f32)
    };
    let patched = base.with_heights((0, 0, w, h), &raised);
    // ... and the same surface built from the edited grid, as the next
    // pass builds it.
    let mut edited = scene.window.clone();
    for r in 0..h {
        for c in 0..w {
            if let Some(v) = raised(c, r) {
                edited.data[r * w + c] = v;
            }
        }
    }
    let grid = LocalTerrain::over(&edited, &scene.frame, max_d);
    assert!(grid.same_surface(&patched), "the two builds differ");

    // Regions as the edit's: rows down to a varying last row, and the
    // silhouettes near in depth or near a stroke's row (one at any depth,
    // as in `region` above).
    let mut strokes = region(&cam);
    let limit = before.depth.depth.iter().copied().filter(|d| d.is_finite());
    let far = limit.fold(0.0f32, f32::max);
    for x in 0..cam.width {
        strokes.last_row[x] = (cam.height / 2 + (x * 7) % 61) as i32;
        strokes.depth_limit[x] = if x % 3 == 0 { far / 4.0 } else { 0.0 };
        strokes.stroke_rows[x] = vec![(cam.height / 3 + x % 17) as f32];
    }
    let want = RenderedView::from_terrain(grid.clone(), &cam).unwrap();
    for (name, r) in [("any depth", region(&cam)), ("strokes", strokes)] {
        let last = RenderedView::render_terrain_region(patched.clone(), &cam, &r).unwrap();
        assert!(
            last.silhouettes.sample_count() > 0,
            "{name}: the region has silhouettes"
        );
        let got = RenderedView::from_terrain_after(grid.clone(), &cam, Some(&last)).unwrap();
        assert_same_render(&got, &want, name);
        assert_eq!(got.columns.samples, want.columns.samples, "{name}: columns");
        assert_eq!(
            got.columns.candidates, want.columns.candidates,
            "{name}: candidates"
        );
    }

    // Another surface: rendered afresh.
    let last = RenderedView::render_terrain_region(patched, &cam, &region(&cam)).unwrap();
    let lowered = base.with_heights((0, 0, w, h), &|c, r| Some(scene.window.get(c, r)? - 5.0));
    assert!(!lowered.same_surface(&last.terrain));
    let want = RenderedView::from_terrain(lowered.clone(), &cam).unwrap();
    let got = RenderedView::from_terrain_after(lowered, &cam, Some(&last)).unwrap();
    assert_same_render(&got, &want, "another surface");
}

#[test]
fn a_region_render_taken_from_a_whole_render_is_the_fresh_region_render() {
    let (cam, scene) = zion_view();
    let (w, h) = (scene.window.width, scene.window.height);
    let before = RenderedView::from_terrain(scene.terrain.clone(), &cam).unwrap();
    let unedited = || before.terrain.with_heights((0, 0, 0, 0), &|_, _| None);
    // Regions as the edit's (see the test above), one with columns left
    // out (last row -1) and columns down to the image's last row.
    let mut strokes = region(&cam);
    let limit = before.depth.depth.iter().copied().filter(|d| d.is_finite());
    let far = limit.fold(0.0f32, f32::max);
    for x in 0..cam.width {
        strokes.last_row[x] = match x % 97 {
            0..=4 => -1,
            5..=9 => cam.height as i32 - 1,
            _ => (cam.height / 2 + (x * 7) % 61) as i32,
        };
        strokes.depth_limit[x] = if x % 3 == 0 { far / 4.0 } else { 0.0 };
        strokes.stroke_rows[x] = vec![(cam.height / 3 + x % 17) as f32];
    }
    for (name, r) in [("any depth", region(&cam)), ("strokes", strokes)] {
        let want = RenderedView::render_terrain_region(scene.terrain.clone(), &cam, &r).unwrap();
        assert!(
            want.silhouettes.sample_count() > 0,
            "{name}: the region has silhouettes"
        );
        let got = before.region_of(unedited(), &r).expect("usable").unwrap();
        assert_same_render(&got, &want, name);
        assert_eq!(got.columns.samples, want.columns.samples, "{name}: columns");
        assert_eq!(
            got.columns.candidates, want.columns.candidates,
            "{name}: candidates"
        );
        assert_eq!(got.region.as_ref(), Some(&r), "{name}: region");
        // A re-render from it after a change of a few vertices is the
        // fresh one too.
        let (c0, r0) = (w / 2, h / 3);
        let changed = before
            .terrain
            .with_heights((c0, r0, c0 + 3, r0 + 3), &|c, r| {
                Some(scene.window.get(c, r)? + 7.0)
            });
        let want = RenderedView::render_terrain_region(changed.clone(), &cam, &r).unwrap();
        let again = RenderedView::rerender_terrain_region(changed, &cam, &r, &got).unwrap();
        assert_same_render(&again, &want, &format!("{name}, changed"));
        // Not from a region render, nor onto another surface.
        assert!(
            got.region_of(unedited(), &r).is_none(),
            "{name}: region render"
        );
        let lowered = before
            .terrain
            .with_heights((0, 0, w, h), &|c, r| Some(scene.window.get(c, r)? - 5.0));
        assert!(
            before.region_of(lowered, &r).is_none(),
            "{name}: another surface"
        );
    }
}

/// A later pass that reads the terrain a pass not kept (or dropped) read
/// takes that pass's whole renders as they are
/// (`RenderedView::is_whole_render_of`): the pass's whole render, taken
/// from the earlier pass's last region render, is the fresh render of the
/// same surface built again from the edited grid, to the bit; a region
/// render, another surface or another camera is not taken.
#[test]
fn a_whole_render_of_a_surface_is_taken_for_the_same_surface_only() {
    let (cam, scene) = zion_view();
    let max_d = Some(ZION_VIEW_M);
    let (w, h) = (scene.window.width, scene.window.height);
    let before = RenderedView::from_terrain(scene.terrain.clone(), &cam).unwrap();
    let base: &LocalTerrain = &before.terrain;
    let lowered_by = |c: usize, r: usize| -> Option<f32> {
        let v = scene.window.get(c, r)?;
        Some(v - 2.0 * ((c + 5 * r) % 7) as f32)
    };
    let patched = base.with_heights((0, 0, w, h), &lowered_by);
    let mut edited = scene.window.clone();
    for r in 0..h {
        for c in 0..w {
            if let Some(v) = lowered_by(c, r) {
                edited.data[r * w + c] = v;
            }
        }
    }
    // The pass not kept: its whole render, from the pass before's region
    // render of the same surface.
    let last = RenderedView::render_terrain_region(patched.clone(), &cam, &region(&cam)).unwrap();
    let read = LocalTerrain::over(&edited, &scene.frame, max_d);
    let whole = RenderedView::from_terrain_after(read, &cam, Some(&last)).unwrap();
    // The next pass reads the same terrain, built again.
    let again = LocalTerrain::over(&edited, &scene.frame, max_d);
    assert!(whole.is_whole_render_of(&again, &cam));
    let fresh = RenderedView::from_terrain(again, &cam).unwrap();
    assert_same_render(&whole, &fresh, "taken whole render");
    assert_eq!(whole.columns.samples, fresh.columns.samples, "columns");
    assert_eq!(
        whole.columns.candidates, fresh.columns.candidates,
        "candidates"
    );
    assert_eq!(whole.columns.confined, fresh.columns.confined, "confined");

    // Not taken: a region render, another surface, another camera.
    assert!(!last.is_whole_render_of(&patched, &cam));
    assert!(!before.is_whole_render_of(&patched, &cam));
    let other = Camera::new(480, 240, 200.0, -1.0, 5.0, 60.0).unwrap();
    assert!(!fresh.is_whole_render_of(&fresh.terrain, &other));
    assert!(fresh.is_whole_render_of(&fresh.terrain, &cam));
}
