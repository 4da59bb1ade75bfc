//! The dynamic-stitching plan: every branch of the published algorithm, the paper's worked
//! examples, and that no image is lost or duplicated.

use grounder::stitch::{grid_starts, plan, GridSpec};

fn layouts(specs: &[GridSpec]) -> Vec<(u32, u32, u32)> {
    specs.iter().map(|s| (s.rows, s.cols, s.frames)).collect()
}

fn total(specs: &[GridSpec]) -> usize {
    specs.iter().map(|s| s.frames as usize).sum()
}

#[test]
fn empty_input_gives_no_grids() {
    assert!(plan(0, 6).is_empty());
}

#[test]
fn branch_4l_only_4x1() {
    // n <= 4L: (4, 1) grids only; 7 images -> 4 + 3.
    assert_eq!(layouts(&plan(7, 6)), vec![(4, 1, 4), (4, 1, 3)]);
    assert_eq!(layouts(&plan(24, 6)), vec![(4, 1, 4); 6]);
    assert_eq!(layouts(&plan(1, 6)), vec![(4, 1, 1)]);
}

#[test]
fn branch_8l_paper_example_n40() {
    // Paper: n = 40, L = 6 -> two (4, 1) and four (2, 4).
    let p = plan(40, 6);
    assert_eq!(
        layouts(&p),
        vec![
            (4, 1, 4),
            (4, 1, 4),
            (2, 4, 8),
            (2, 4, 8),
            (2, 4, 8),
            (2, 4, 8)
        ]
    );
}

#[test]
fn branch_8l_partial_last_grid() {
    // n = 25, L = 6: n8 = ceil(1/4) = 1, n4 = 5 -> five (4, 1) full, one (2, 4) with 5.
    assert_eq!(
        layouts(&plan(25, 6)),
        vec![
            (4, 1, 4),
            (4, 1, 4),
            (4, 1, 4),
            (4, 1, 4),
            (4, 1, 4),
            (2, 4, 5)
        ]
    );
}

#[test]
fn branch_16l_paper_example_n84() {
    // Paper: n = 84, L = 6 -> one (4, 1) and five (8, 2).
    let p = plan(84, 6);
    let mut want = vec![(4, 1, 4)];
    want.extend(vec![(8, 2, 16); 5]);
    assert_eq!(layouts(&p), want);
}

#[test]
fn branch_16l_mixed() {
    // n = 60, L = 6: n16 = ceil(12/8) = 2, rest 28, n48 = 4, n8 = ceil(12/4) = 3, n4 = 1.
    let p = plan(60, 6);
    assert_eq!(
        layouts(&p),
        vec![
            (4, 1, 4),
            (2, 4, 8),
            (2, 4, 8),
            (2, 4, 8),
            (8, 2, 16),
            (8, 2, 16)
        ]
    );
}

#[test]
fn branch_27l_mixed() {
    // n = 120, L = 6: n27 = ceil(24/11) = 3, n4816 = 3, rest 39, n16 = ceil(15/8) = 2,
    // n48 = 1, rest 7, n8 = ceil(3/4) = 1, n4 = 0 -> one (2,4), two (8,2), rest in (9,3).
    let p = plan(120, 6);
    assert_eq!(
        layouts(&p),
        vec![
            (2, 4, 8),
            (8, 2, 16),
            (8, 2, 16),
            (9, 3, 27),
            (9, 3, 27),
            (9, 3, 26)
        ]
    );
}

#[test]
fn branch_27l_full() {
    assert_eq!(layouts(&plan(162, 6)), vec![(9, 3, 27); 6]);
}

#[test]
fn branch_above_27l_recurses_with_limit_one() {
    // n = 170, L = 6: six full (9, 3) grids (162), then 8 images with L = 1:
    // 8 <= 8 -> n8 = 1, n4 = 0 -> one (2, 4).
    let p = plan(170, 6);
    let mut want = vec![(9, 3, 27); 6];
    want.push((2, 4, 8));
    assert_eq!(layouts(&p), want);
    // n = 200, L = 6: seven (9, 3) = 189, then 11 with L = 1 -> one (8, 2) with 11.
    let p = plan(200, 6);
    let mut want = vec![(9, 3, 27); 7];
    want.push((8, 2, 11));
    assert_eq!(layouts(&p), want);
}

#[test]
fn no_image_lost_or_duplicated_and_limit_respected() {
    for l in 1..=12usize {
        for n in 0..=400usize {
            let p = plan(n, l);
            assert_eq!(total(&p), n, "n={n} L={l}: {p:?}");
            for s in &p {
                assert!(
                    s.frames >= 1 && s.frames <= s.capacity(),
                    "n={n} L={l}: {p:?}"
                );
                assert!(
                    [(4, 1), (2, 4), (8, 2), (9, 3)].contains(&(s.rows, s.cols)),
                    "n={n} L={l}: {p:?}"
                );
            }
            // Starts are consecutive and cover 0..n exactly once.
            let starts = grid_starts(&p);
            let mut seen = vec![0u8; n];
            for (s, start) in p.iter().zip(starts) {
                for c in &mut seen[start..start + s.frames as usize] {
                    *c += 1;
                }
            }
            assert!(seen.iter().all(|&c| c == 1), "n={n} L={l}");
            if n <= 27 * l {
                assert!(p.len() <= l, "n={n} L={l} uses {} grids: {p:?}", p.len());
                // Within the limit, layouts appear in ascending size.
                let caps: Vec<u32> = p.iter().map(|s| s.capacity()).collect();
                assert!(caps.windows(2).all(|w| w[0] <= w[1]), "n={n} L={l}: {p:?}");
            }
        }
    }
}
