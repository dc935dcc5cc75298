//! Frictionless contact as a linear complementarity problem: forces `f >= 0` on the candidate
//! nodes, the surface's sink `G f` at least the interference `delta` everywhere, equal to it
//! where a node carries force. `G` (displacement per unit force) is symmetric positive definite,
//! so block principal pivoting (Judice and Pires, 1994) finds the one solution in a few dense
//! solves; each solve is faer's Cholesky factorisation (blocked and vectorised: on a few
//! hundred nodes it is the label's largest cost).

use faer::linalg::solvers::Solve;
use faer::{Col, Mat, Side};

use super::MechanicsError;

/// Most exchanges of the whole infeasible set before Murty's one-at-a-time rule takes over when
/// they stop shrinking it.
const FULL_EXCHANGES: usize = 3;

/// The forces (N) solving `0 <= f`, `G f - delta >= 0`, `f . (G f - delta) = 0`, and how many
/// pivoting steps it took, starting from the nodes `start` says are in contact (any guess is
/// safe; a good one saves steps and makes the first factorisation smaller).
pub(crate) fn solve(g: &Mat<f64>, delta_mm: &[f64], start: &[bool]) -> Result<(Vec<f64>, usize), MechanicsError> {
    let n = delta_mm.len();
    assert_eq!((g.nrows(), g.ncols()), (n, n), "one row and column per candidate node");
    if n == 0 {
        return Ok((Vec::new(), 0));
    }
    let scale = delta_mm.iter().fold(0f64, |m, d| m.max(d.abs()));
    // A node is out of contact if it would carry a pull beyond this, or penetrates beyond it.
    let tol_mm = 1e-10 * scale.max(1e-12);
    let mut free = start.to_vec();
    assert_eq!(free.len(), n, "one guess per candidate");
    let mut best = usize::MAX;
    let mut exchanges = FULL_EXCHANGES;
    let limit = 20 * n + 100;
    for step in 1..=limit {
        let idx: Vec<usize> = (0..n).filter(|&i| free[i]).collect();
        let mut f = vec![0.0; n];
        if !idx.is_empty() {
            let sub = Mat::from_fn(idx.len(), idx.len(), |a, b| g[(idx[a], idx[b])]);
            let rhs = Col::from_fn(idx.len(), |a| delta_mm[idx[a]]);
            let x =
                sub.llt(Side::Lower).map_err(|_| MechanicsError::NotPositiveDefinite { nodes: idx.len() })?.solve(&rhs);
            if !x.iter().all(|v| v.is_finite()) {
                return Err(MechanicsError::NotPositiveDefinite { nodes: idx.len() });
            }
            for (a, &i) in idx.iter().enumerate() {
                f[i] = x[a];
            }
        }
        // Infeasible: a node in contact that pulls, or one out of contact that the indenter
        // still penetrates.
        let force_tol = tol_mm / g[(0, 0)].abs().max(f64::MIN_POSITIVE);
        let infeasible: Vec<usize> = (0..n)
            .filter(|&i| {
                if free[i] {
                    f[i] < -force_tol
                } else {
                    let sink: f64 = idx.iter().map(|&j| g[(i, j)] * f[j]).sum();
                    sink - delta_mm[i] < -tol_mm
                }
            })
            .collect();
        if infeasible.is_empty() {
            for v in &mut f {
                *v = v.max(0.0);
            }
            return Ok((f, step));
        }
        if infeasible.len() < best {
            best = infeasible.len();
            exchanges = FULL_EXCHANGES;
            infeasible.iter().for_each(|&i| free[i] = !free[i]);
        } else if exchanges > 0 {
            exchanges -= 1;
            infeasible.iter().for_each(|&i| free[i] = !free[i]);
        } else {
            let last = *infeasible.last().expect("not empty");
            free[last] = !free[last];
        }
    }
    Err(MechanicsError::NoConvergence { nodes: n, steps: limit })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Checks the complementarity conditions of a solution.
    fn assert_complementary(g: &Mat<f64>, delta: &[f64], f: &[f64]) {
        let sink: Vec<f64> = (0..delta.len()).map(|i| (0..delta.len()).map(|j| g[(i, j)] * f[j]).sum()).collect();
        for i in 0..delta.len() {
            assert!(f[i] >= 0.0, "node {i} pulls: {}", f[i]);
            let slack = sink[i] - delta[i];
            assert!(slack >= -1e-9, "node {i} penetrated by {}", -slack);
            assert!(f[i] * slack.abs() <= 1e-9, "node {i} carries {} with slack {slack}", f[i]);
        }
    }

    #[test]
    fn a_two_node_case_by_hand() {
        // Two coupled nodes: both pressed, one pressed much further. Solving both in contact
        // pulls on the shallow one; the solution leaves it free and carries the other alone.
        let g = Mat::from_fn(2, 2, |i, j| if i == j { 1.0 } else { 0.5 });
        let delta = [1.0, 0.2];
        let (f, _) = solve(&g, &delta, &[true, true]).unwrap();
        assert!((f[0] - 1.0).abs() < 1e-12 && f[1] == 0.0, "{f:?}");
        assert_complementary(&g, &delta, &f);
        // Both in contact when the second is pressed far enough: f = G^-1 delta.
        let delta = [1.0, 0.8];
        let (f, _) = solve(&g, &delta, &[false, false]).unwrap();
        assert!((f[0] - 0.8).abs() < 1e-12 && (f[1] - 0.4).abs() < 1e-12, "{f:?}");
    }

    #[test]
    fn random_positive_definite_problems_satisfy_complementarity() {
        let mut state = 0x2545_f491_4f6c_dd1du64;
        let mut next = || {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            (state >> 11) as f64 / (1u64 << 53) as f64
        };
        for n in [1, 3, 10, 40] {
            // A kernel like the half-space's: positive, falling with distance along a line.
            let pos: Vec<f64> = (0..n).map(|_| next() * 10.0).collect();
            let g = Mat::from_fn(n, n, |i, j| 1.0 / (0.5 + (pos[i] - pos[j]).abs()));
            let delta: Vec<f64> = (0..n).map(|_| next() * 2.0 - 0.5).collect();
            // Whatever the first guess, the same solution.
            let (f, steps) = solve(&g, &delta, &vec![true; n]).unwrap();
            assert!(steps <= 2 * n + 5, "{steps} steps for {n} nodes");
            assert_complementary(&g, &delta, &f);
            let guess: Vec<bool> = (0..n).map(|i| i % 2 == 0).collect();
            let (again, _) = solve(&g, &delta, &guess).unwrap();
            assert!(
                f.iter().zip(&again).all(|(a, b)| (a - b).abs() <= 1e-9 * (1.0 + a.abs())),
                "{f:?} against {again:?}"
            );
        }
    }
}
