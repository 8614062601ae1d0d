//! Matching has a budget (issue 11, item 7): branch-and-bound stops at its
//! node budget with the best solution found and says so; 1,000 strokes and
//! a zig-zag stroke (split into many pieces) finish. These tests assert
//! termination and the early-stop report, never a timing
//! (`benches/matching.rs` measures).

use demsketch::sketch::{
    branch_and_bound, branch_and_bound_with_budget, match_view, prepare_stroke, valid, Bound,
    Choice, FeatureKind, FoldBackPolicy, SimplePinhole, SketchOptions, Stroke, ViewFeature,
    ViewInput, ViewProjection, DEFAULT_NODE_BUDGET,
};
use std::sync::Arc;

struct Rng(u64);
impl Rng {
    fn next(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E3779B97F4A7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58476D1CE4E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D049BB133111EB);
        z ^ (z >> 31)
    }
    fn unit(&mut self) -> f64 {
        (self.next() >> 11) as f64 / (1u64 << 53) as f64
    }
    fn range(&mut self, a: f64, b: f64) -> f64 {
        a + (b - a) * self.unit()
    }
}

fn hash(i: usize, a: usize, j: usize, b: usize) -> f64 {
    let mut r = Rng(((i as u64) << 40) ^ ((a as u64) << 28) ^ ((j as u64) << 8) ^ b as u64);
    r.unit()
}

/// 1,000 strokes, 8 candidates each from a pool of 400 shared features,
/// neighbouring strokes in conflict at random.
#[test]
fn thousand_strokes_stop_at_the_budget_with_a_valid_solution() {
    let mut rng = Rng(11);
    let lists: Vec<Vec<Choice>> = (0..1000)
        .map(|_| {
            (0..8)
                .map(|_| Choice {
                    feature: (rng.next() % 400) as usize,
                    cost: rng.range(0.0, 10.0),
                })
                .collect()
        })
        .collect();
    let conflicts = |i: usize, a: usize, j: usize, b: usize| j - i < 4 && hash(i, a, j, b) < 0.3;
    for bound in [Bound::ForwardChecking, Bound::LowerBound] {
        let sol = branch_and_bound(&lists, &conflicts, bound);
        assert!(
            sol.stopped_early,
            "{bound:?}: the exact search cannot end in budget"
        );
        assert!(sol.cost.is_finite(), "{bound:?}: a solution is kept");
        assert!(valid(&lists, &conflicts, &sol.choice), "{bound:?}: valid");
        assert!(
            sol.nodes <= DEFAULT_NODE_BUDGET + 1,
            "{bound:?}: {} nodes",
            sol.nodes
        );
    }
    // A budget smaller than the strokes still completes the first descent.
    let sol = branch_and_bound_with_budget(&lists, &conflicts, Bound::ForwardChecking, 1);
    assert!(sol.stopped_early && sol.cost.is_finite());
    assert!(valid(&lists, &conflicts, &sol.choice));
    // A small instance is solved exactly: no early stop reported.
    let small = &lists[..3];
    let sol = branch_and_bound(small, &conflicts, Bound::ForwardChecking);
    assert!(!sol.stopped_early);
}

/// A feature along pixel columns `xa..xb` at screen height `y(x)` and
/// distance `d`.
fn feature(
    id: usize,
    cam: &SimplePinhole,
    xa: f64,
    xb: f64,
    y: impl Fn(f64) -> f64,
    d: f64,
) -> ViewFeature {
    let n = (((xb - xa) / 4.0).ceil() as usize).max(1);
    let pts: Vec<[f64; 3]> = (0..=n)
        .map(|i| {
            let x = xa + (xb - xa) * i as f64 / n as f64;
            cam.unproject([x, y(x)], d)
        })
        .collect();
    ViewFeature::from_world(id, FeatureKind::Ridge, &pts, cam)
}

fn camera() -> SimplePinhole {
    SimplePinhole::new([0.0, 0.0, 10.0], 0.0, 0.0, 60.0, 1600, 900)
        .with_terrain(Arc::new(|_, _| Some(0.0)))
}

/// 200 short strokes (10 rows of 20) over 300 features: matching ends with
/// a placement for every stroke and reports the early stop. (Not 1,000: the
/// depth ordering before matching makes a cue for every pair of strokes
/// the sweep has met, quadratic in strokes; the 1,000-stroke search itself
/// is the test above.)
#[test]
fn many_strokes_in_a_view_finish_and_report_the_early_stop() {
    let cam = camera();
    let mut rng = Rng(7);
    let features: Vec<ViewFeature> = (0..300)
        .map(|id| {
            let xa = rng.range(0.0, 1400.0);
            let w = rng.range(20.0, 200.0);
            let base = rng.range(250.0, 650.0);
            let d = rng.range(500.0, 20_000.0);
            feature(
                id,
                &cam,
                xa,
                xa + w,
                move |x| base - 5.0 * (x / 50.0).sin(),
                d,
            )
        })
        .collect();
    let mut strokes: Vec<Stroke> = Vec::new();
    for row in 0..10 {
        for k in 0..20 {
            let x0 = 4.0 + 78.0 * k as f64;
            let y = 300.0 + 30.0 * row as f64;
            let pts = [[x0, y], [x0 + 30.0, y - 6.0], [x0 + 60.0, y]];
            let i = strokes.len();
            strokes.extend(
                prepare_stroke(&format!("s{i}"), i, &pts, 2.0, 3.0, FoldBackPolicy::Reject)
                    .expect("stroke"),
            );
        }
    }
    let view = ViewInput {
        name: "many".into(),
        strokes,
        features: &features,
        projection: &cam,
    };
    let opts = SketchOptions {
        node_budget: 2_000,
        feature_completion: false,
        ..SketchOptions::default()
    };
    let m = match_view(&view, &opts).expect("match");
    assert_eq!(m.strokes.len(), 200);
    assert!(m.strokes.iter().all(|s| !s.points.is_empty()));
    let whole = demsketch::sketch::match_sketch(std::slice::from_ref(&view), &opts).unwrap();
    assert!(whole.stopped_early, "200 strokes: early stop reported");
    assert_eq!(whole.node_budget, 2_000);
}

/// A zig-zag stroke (folding back in x 40 times) is split into pieces that
/// all overlap each other: matching finishes.
#[test]
fn zig_zag_stroke_finishes() {
    let cam = camera();
    let features: Vec<ViewFeature> = (0..200)
        .map(|id| {
            let xa = 100.0 + 3.0 * id as f64;
            let base = 300.0 + (id % 17) as f64 * 10.0;
            feature(
                id,
                &cam,
                xa,
                xa + 400.0,
                move |_| base,
                1000.0 + 50.0 * id as f64,
            )
        })
        .collect();
    let pts: Vec<[f64; 2]> = (0..=80)
        .map(|k| {
            let x = if k % 2 == 0 { 300.0 } else { 700.0 };
            [x + k as f64, 300.0 + 4.0 * k as f64]
        })
        .collect();
    let strokes = prepare_stroke("zig", 0, &pts, 2.0, 3.0, FoldBackPolicy::Split).expect("zig-zag");
    assert!(strokes.len() > 40, "{} pieces", strokes.len());
    let view = ViewInput {
        name: "zig".into(),
        strokes,
        features: &features,
        projection: &cam,
    };
    let m = match_view(&view, &SketchOptions::default()).expect("match");
    assert_eq!(m.strokes.len(), view.strokes.len());
}
