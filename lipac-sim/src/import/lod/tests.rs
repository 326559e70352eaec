use super::*;

/// A flat `n` x `n` grid of quads.
fn grid(n: u32) -> (Vec<[f32; 3]>, Vec<u32>) {
    let mut p = Vec::new();
    for j in 0..=n {
        for i in 0..=n {
            p.push([i as f32, 0.0, j as f32]);
        }
    }
    let mut ix = Vec::new();
    for j in 0..n {
        for i in 0..n {
            let a = j * (n + 1) + i;
            ix.extend([a, a + n + 1, a + 1, a + 1, a + n + 1, a + n + 2]);
        }
    }
    (p, ix)
}

#[test]
fn a_flat_grid_simplifies_and_stays_in_range() {
    let (p, ix) = grid(16);
    let [l1, l2] = generate_lods(&p, &ix).unwrap();
    assert!(l1.len() < ix.len(), "{} vs {}", l1.len(), ix.len());
    assert!(l2.len() <= l1.len());
    assert!(!l2.is_empty() && l2.len() % 3 == 0);
    assert!(l1.iter().chain(&l2).all(|&i| (i as usize) < p.len()));
}

#[test]
fn bad_input_is_an_error() {
    assert!(simplify(&[[0.0; 3]], &[0, 1, 2], 0.5, 0.01).is_err());
    assert!(simplify(&[[0.0; 3]; 3], &[0, 1, 2], 0.0, 0.01).is_err());
}
