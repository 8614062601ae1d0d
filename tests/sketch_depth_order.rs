//! Depth ordering of strokes (section 4 of Tassé et al.): the paper's
//! Figure 3 and hand-made configurations (nesting, overlapping heights,
//! chains of junctions, no junctions, contradictions).

use demsketch::sketch::{
    order_strokes, prepare_stroke, CueKind, FoldBackPolicy, JunctionLabel, Stroke,
};

const T: f64 = 6.0;

fn strokes(defs: &[&[[f64; 2]]]) -> Vec<Stroke> {
    defs.iter()
        .enumerate()
        .map(|(i, p)| {
            prepare_stroke(
                &format!("{}", i + 1),
                i,
                p,
                2.0,
                3.0,
                FoldBackPolicy::Reject,
            )
            .unwrap()
            .remove(0)
        })
        .collect()
}

fn order(defs: &[&[[f64; 2]]]) -> Vec<usize> {
    order_strokes(&strokes(defs), T).order
}

/// Figure 3: three strokes, two T-junctions; stroke 3 in front of stroke 2,
/// itself in front of stroke 1 (strokes 2 and 3 overlap in height).
fn figure3() -> Vec<Vec<[f64; 2]>> {
    let y2 = |x: f64| 250.0 + 50.0 * (x - 500.0) / 300.0;
    vec![
        vec![[0.0, 300.0], [200.0, 200.0], [400.0, 350.0]],
        vec![
            [300.0, 450.0],
            [500.0, 250.0],
            [800.0, 300.0],
            [1000.0, 450.0],
        ],
        vec![[600.0, y2(600.0)], [675.0, 350.0], [750.0, y2(750.0)]],
    ]
}

#[test]
fn figure3_order_and_sweep() {
    let f = figure3();
    let defs: Vec<&[[f64; 2]]> = f.iter().map(|v| v.as_slice()).collect();
    let o = order_strokes(&strokes(&defs), T);
    assert_eq!(o.order, vec![2, 1, 0], "{o:#?}");
    assert!(o.conflicts.is_empty());
    // Two T-junctions... counted per extremity: stroke 1's end (occluded by
    // 2), stroke 3's start and end (in front of 2).
    let labels: Vec<(usize, bool, usize, JunctionLabel)> = o
        .junctions
        .iter()
        .map(|j| (j.stroke, j.at_end, j.other, j.label))
        .collect();
    assert!(labels.contains(&(0, true, 1, JunctionLabel::OccludedBy)));
    assert!(labels.contains(&(2, false, 1, JunctionLabel::InFrontOf)));
    assert!(labels.contains(&(2, true, 1, JunctionLabel::InFrontOf)));
    assert_eq!(labels.len(), 3);
    // The sweep of Figure 3 (bottom).
    let trace: Vec<(usize, bool, String)> = o
        .steps
        .iter()
        .map(|s| (s.stroke, s.close, s.relations[0].1.clone()))
        .collect();
    assert_eq!(trace[0], (0, false, "no relation".to_string()));
    assert_eq!(trace[1], (1, false, "in front of 1".to_string()));
    assert_eq!(trace[2], (0, true, "occluded by 2".to_string()));
    assert_eq!(trace[3], (2, false, "in front of 2".to_string()));
    assert_eq!(trace[4], (2, true, "in front of 2".to_string()));
}

#[test]
fn height_cue_without_junction() {
    // Far ridge above, near ridge below, overlapping in x, no containment.
    assert_eq!(
        order(&[
            &[[0.0, 200.0], [600.0, 150.0]],
            &[[300.0, 450.0], [900.0, 400.0]]
        ]),
        vec![1, 0]
    );
}

#[test]
fn containment_beats_height() {
    // The wide stroke contains the narrow one in x: it is behind, although
    // the narrow one's endpoints are higher on screen.
    assert_eq!(
        order(&[
            &[[0.0, 400.0], [500.0, 100.0], [1000.0, 400.0]],
            &[[400.0, 300.0], [500.0, 280.0], [600.0, 300.0]]
        ]),
        vec![1, 0]
    );
}

#[test]
fn nested_ranges() {
    // Four ranges, each containing the nearer one in x.
    assert_eq!(
        order(&[
            &[[0.0, 200.0], [500.0, 100.0], [1000.0, 200.0]],
            &[[400.0, 500.0], [500.0, 450.0], [600.0, 500.0]],
            &[[200.0, 300.0], [500.0, 250.0], [800.0, 300.0]],
            &[[300.0, 400.0], [500.0, 350.0], [700.0, 400.0]],
        ]),
        vec![1, 3, 2, 0]
    );
}

#[test]
fn chain_of_junctions() {
    // A ends on B, B ends on C: C in front of B in front of A.
    assert_eq!(
        order(&[
            &[[0.0, 200.0], [200.0, 300.0]],
            &[[100.0, 400.0], [200.0, 300.0], [500.0, 380.0]],
            &[[400.0, 550.0], [500.0, 380.0], [800.0, 300.0]],
        ]),
        vec![2, 1, 0]
    );
}

#[test]
fn chain_is_independent_of_drawing_direction() {
    let a: Vec<[f64; 2]> = vec![[200.0, 300.0], [0.0, 200.0]];
    let b: Vec<[f64; 2]> = vec![[500.0, 380.0], [200.0, 300.0], [100.0, 400.0]];
    let c: Vec<[f64; 2]> = vec![[800.0, 300.0], [500.0, 380.0], [400.0, 550.0]];
    assert_eq!(order(&[&c, &a, &b]), vec![0, 2, 1]);
}

#[test]
fn occluded_at_start() {
    // A starts on B's descending flank and rises away: A behind B.
    let o = order_strokes(
        &strokes(&[
            &[[0.0, 400.0], [300.0, 300.0], [600.0, 450.0]],
            &[[450.0, 375.0], [700.0, 200.0], [900.0, 250.0]],
        ]),
        T,
    );
    assert_eq!(o.order, vec![0, 1]);
    assert_eq!(o.junctions.len(), 1);
    assert_eq!(o.junctions[0].label, JunctionLabel::OccludedBy);
    assert!(!o.junctions[0].at_end);
}

#[test]
fn in_front_at_end_from_below() {
    // A rises from below and ends on the far ridge B: A in front.
    assert_eq!(
        order(&[
            &[[100.0, 500.0], [300.0, 300.0]],
            &[[0.0, 250.0], [300.0, 300.0], [600.0, 250.0]]
        ]),
        vec![0, 1]
    );
}

#[test]
fn junction_beats_height() {
    // B starts low on the left but descends into A's flank: B is behind A
    // although its lowest endpoint is lower than A's.
    let o = order_strokes(
        &strokes(&[
            &[[300.0, 200.0], [500.0, 100.0], [700.0, 200.0]],
            &[[0.0, 450.0], [200.0, 50.0], [400.0, 150.0]],
        ]),
        T,
    );
    assert_eq!(o.order, vec![0, 1]);
    assert!(o.conflicts.is_empty());
    // The height cue is not even consulted: where the strokes share
    // columns (300 to 400 px) B is drawn above A, which agrees with the
    // junction.
    let opening_a = o.steps.iter().find(|s| s.stroke == 0 && !s.close).unwrap();
    assert_eq!(
        opening_a.relations,
        vec![(CueKind::Above, "in front of 2".to_string())]
    );
    assert!(o.accepted.iter().all(|c| c.kind != CueKind::Height));
}

#[test]
fn above_beats_containment() {
    // A short far ridge drawn above a wide near one, inside its x interval:
    // the paper's containment cue alone would put the wide stroke behind,
    // but it is drawn below the short one on every shared column, so it is
    // in front (a configuration met when tracing real views).
    let o = order_strokes(
        &strokes(&[
            &[[0.0, 300.0], [400.0, 420.0], [800.0, 500.0]],
            &[[100.0, 150.0], [200.0, 140.0], [300.0, 160.0]],
        ]),
        T,
    );
    assert_eq!(o.order, vec![0, 1], "{o:#?}");
    assert!(o.conflicts.is_empty());
}

#[test]
fn end_to_end_contact_is_not_a_junction() {
    // One silhouette continuing another (the second starts where the first
    // ends): no T-junction at either extremity.
    let o = order_strokes(
        &strokes(&[
            &[[0.0, 300.0], [200.0, 250.0]],
            &[[201.0, 250.5], [400.0, 180.0]],
        ]),
        T,
    );
    assert!(o.junctions.is_empty(), "{:?}", o.junctions);
    assert!(o.conflicts.is_empty());
}

#[test]
fn disjoint_strokes_by_height() {
    assert_eq!(
        order(&[
            &[[0.0, 450.0], [200.0, 500.0]],
            &[[300.0, 250.0], [500.0, 300.0]],
            &[[600.0, 350.0], [800.0, 400.0]],
        ]),
        vec![0, 2, 1]
    );
}

#[test]
fn no_cue_keeps_sweep_order() {
    assert_eq!(
        order(&[
            &[[600.0, 300.0], [800.0, 300.0]],
            &[[0.0, 300.0], [200.0, 300.0]]
        ]),
        vec![1, 0]
    );
}

#[test]
fn contradictory_junctions_are_reported() {
    // A starts on B going down (in front of B) and ends on B from above
    // (occluded by B): the first cue of the sweep wins, the other is reported.
    let o = order_strokes(
        &strokes(&[
            &[
                [200.0, 300.0],
                [300.0, 400.0],
                [400.0, 200.0],
                [600.0, 300.0],
            ],
            &[[0.0, 300.0], [1000.0, 300.0]],
        ]),
        T,
    );
    assert_eq!(o.order, vec![0, 1]);
    assert_eq!(o.conflicts.len(), 1, "{o:#?}");
    assert!(o.conflicts[0].message.contains("contradictory"));
    // Deterministic.
    let again = order_strokes(
        &strokes(&[
            &[
                [200.0, 300.0],
                [300.0, 400.0],
                [400.0, 200.0],
                [600.0, 300.0],
            ],
            &[[0.0, 300.0], [1000.0, 300.0]],
        ]),
        T,
    );
    assert_eq!(again.order, o.order);
}

#[test]
fn figure3_with_far_background() {
    // Figure 3 plus a wide background range above everything, no junction.
    let mut f = figure3();
    f.push(vec![[0.0, 120.0], [500.0, 60.0], [1000.0, 120.0]]);
    let defs: Vec<&[[f64; 2]]> = f.iter().map(|v| v.as_slice()).collect();
    assert_eq!(order(&defs), vec![2, 1, 0, 3]);
}

#[test]
fn split_pieces_do_not_make_junctions_with_each_other() {
    let pieces = prepare_stroke(
        "z",
        0,
        &[[0.0, 300.0], [300.0, 250.0], [200.0, 200.0], [500.0, 150.0]],
        2.0,
        3.0,
        FoldBackPolicy::Split,
    )
    .unwrap();
    assert_eq!(pieces.len(), 3);
    let o = order_strokes(&pieces, T);
    assert!(o.junctions.is_empty());
    assert_eq!(o.order.len(), 3);
}
