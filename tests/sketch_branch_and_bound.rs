//! Branch-and-bound against brute force (section 5.2.2 of Tassé et al.):
//! 500 random instances with up to 6 strokes and up to 8 candidates each,
//! shared features and random occlusion conflicts. The optimum must be the
//! brute-force optimum and fewer nodes must be visited; the node ratio is
//! printed (run with `--nocapture`).

use demsketch::sketch::{branch_and_bound, brute_force, valid, Bound, Choice, EMPTY_LIST_COST};

struct Rng(u64);
impl Rng {
    fn next(&mut self) -> u64 {
        // splitmix64
        self.0 = self.0.wrapping_add(0x9E3779B97F4A7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58476D1CE4E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D049BB133111EB);
        z ^ (z >> 31)
    }
    fn below(&mut self, n: u64) -> u64 {
        self.next() % n
    }
    fn unit(&mut self) -> f64 {
        (self.next() >> 11) as f64 / (1u64 << 53) as f64
    }
}

fn hash4(seed: u64, i: usize, a: usize, j: usize, b: usize) -> f64 {
    let mut r = Rng(seed ^ ((i as u64) << 48) ^ ((a as u64) << 32) ^ ((j as u64) << 16) ^ b as u64);
    r.next();
    r.unit()
}

#[test]
fn branch_and_bound_equals_brute_force_on_500_instances() {
    let mut rng = Rng(0x5EED);
    let (mut bb_nodes, mut bf_nodes, mut paper_nodes, mut exhaustive_nodes, mut fc_nodes) =
        (0u64, 0u64, 0u64, 0u64, 0u64);
    let mut with_empty = 0;
    for inst in 0..500 {
        let n = 1 + rng.below(6) as usize;
        let pool = 2 + rng.below(12) as usize;
        let lists: Vec<Vec<Choice>> = (0..n)
            .map(|_| {
                let m = rng.below(9) as usize; // 0..=8 candidates
                (0..m)
                    .map(|_| Choice {
                        feature: rng.below(pool as u64) as usize,
                        cost: (rng.unit() * 10.0 * 1000.0).round() / 1000.0 + rng.unit() * 1e-6,
                    })
                    .collect()
            })
            .collect();
        let p = rng.unit() * 0.6;
        let seed = rng.next();
        let conflicts = move |i: usize, a: usize, j: usize, b: usize| hash4(seed, i, a, j, b) < p;

        let bf = brute_force(&lists, &conflicts);
        let bb = branch_and_bound(&lists, &conflicts, Bound::LowerBound);
        let paper = branch_and_bound(&lists, &conflicts, Bound::PartialCost);
        let ex = branch_and_bound(&lists, &conflicts, Bound::None);
        let fc = branch_and_bound(&lists, &conflicts, Bound::ForwardChecking);
        for s in [&bb, &paper, &ex, &fc] {
            assert!(
                (s.cost - bf.cost).abs() <= 1e-9 * bf.cost.max(1.0),
                "instance {inst}: {} vs brute force {}",
                s.cost,
                bf.cost
            );
            assert!(
                valid(&lists, &conflicts, &s.choice),
                "instance {inst}: invalid"
            );
            assert!(s.nodes <= bf.nodes);
        }
        if bf.empty > 0 {
            with_empty += 1;
            assert!(bf.cost >= EMPTY_LIST_COST);
        }
        bb_nodes += bb.nodes;
        paper_nodes += paper.nodes;
        exhaustive_nodes += ex.nodes;
        fc_nodes += fc.nodes;
        bf_nodes += bf.nodes;
    }
    assert!(bb_nodes < bf_nodes);
    assert!(paper_nodes < bf_nodes);
    assert!(fc_nodes < bf_nodes && fc_nodes <= bb_nodes);
    println!(
        "500 instances ({with_empty} with an emptied list): nodes visited: brute force {bf_nodes}, \
         exhaustive feasible tree {exhaustive_nodes}, B&B paper bound {paper_nodes} ({:.4} of brute force), \
         B&B with lower bound {bb_nodes} ({:.4} of brute force), \
         B&B with forward checking (default) {fc_nodes} ({:.4} of brute force, {:.3} of the feasible tree)",
        paper_nodes as f64 / bf_nodes as f64,
        bb_nodes as f64 / bf_nodes as f64,
        fc_nodes as f64 / bf_nodes as f64,
        fc_nodes as f64 / exhaustive_nodes as f64
    );
}

#[test]
fn a_feature_is_used_once() {
    let lists = vec![
        vec![Choice {
            feature: 7,
            cost: 1.0,
        }],
        vec![
            Choice {
                feature: 7,
                cost: 1.0,
            },
            Choice {
                feature: 8,
                cost: 3.0,
            },
        ],
    ];
    let none = |_: usize, _: usize, _: usize, _: usize| false;
    let s = branch_and_bound(&lists, &none, Bound::LowerBound);
    assert_eq!(s.choice, vec![Some(0), Some(1)]);
    assert_eq!(s.cost, 4.0);
}

#[test]
fn emptied_list_costs_infinity_unless_unavoidable() {
    // Choosing feature 1 for stroke 0 (cheapest) empties stroke 1's list;
    // the solver prefers the dearer feature 2 for stroke 0.
    let lists = vec![
        vec![
            Choice {
                feature: 1,
                cost: 0.1,
            },
            Choice {
                feature: 2,
                cost: 5.0,
            },
        ],
        vec![Choice {
            feature: 1,
            cost: 0.1,
        }],
    ];
    let none = |_: usize, _: usize, _: usize, _: usize| false;
    let s = branch_and_bound(&lists, &none, Bound::PartialCost);
    assert_eq!(s.choice, vec![Some(1), Some(0)]);
    // Unavoidable: both strokes only have feature 1.
    let lists = vec![
        vec![Choice {
            feature: 1,
            cost: 0.1,
        }],
        vec![Choice {
            feature: 1,
            cost: 0.1,
        }],
    ];
    let s = branch_and_bound(&lists, &none, Bound::LowerBound);
    assert_eq!(s.choice, vec![Some(0), None]);
    assert_eq!(s.empty, 1);
}

#[test]
fn occlusion_constraint_is_respected() {
    // Stroke 1's cheap candidate would hide stroke 0's only candidate.
    let lists = vec![
        vec![Choice {
            feature: 0,
            cost: 1.0,
        }],
        vec![
            Choice {
                feature: 1,
                cost: 0.5,
            },
            Choice {
                feature: 2,
                cost: 2.0,
            },
        ],
    ];
    let conflicts = |i: usize, a: usize, j: usize, b: usize| (i, a, j, b) == (0, 0, 1, 0);
    let s = branch_and_bound(&lists, &conflicts, Bound::LowerBound);
    assert_eq!(s.choice, vec![Some(0), Some(1)]);
}
