//! Dense linear algebra on top of nalgebra: the few factorizations the randomized
//! algorithms need, all on thin or small matrices (the large work is matrix products).
//!
//! * [`orthonormalize`]: modified Gram–Schmidt applied twice ("twice is enough",
//!   Giraud et al. 2005); a column that loses all but $10^{-10}$ of its norm to the previous
//!   ones is set to zero, so the result has orthonormal or zero columns and rank-deficient
//!   input never divides by zero.
//! * [`sorted_eigen`]: eigenpairs of a symmetric positive semi-definite Gram matrix,
//!   descending.
//! * [`factored_svd`]: the truncated SVD of $B = A C^\top$ given only the factors
//!   ($A$: $m \times r$, $C$: $n \times r$, $r \ll m, n$): with $A^\top A = V_a \Lambda_a V_a^\top$,
//!   $A = Q_a R_a$ where $Q_a = A V_a \Lambda_a^{-1/2}$ and $R_a = \Lambda_a^{1/2} V_a^\top$ (the same for
//!   $C$); the SVD $R_a R_c^\top = W \Sigma Z^\top$ gives $B = (Q_a W)\,\Sigma\,(Q_c Z)^\top$. Exact up to
//!   the Gram matrices' squared conditioning: components below $10^{-7}$ of the largest singular
//!   value lose relative accuracy, which a truncation never keeps anyway.
//! * [`select_rows`]: a well-conditioned subset of the rows of an orthonormal basis
//!   (pivoted QR, then greedy volume growth), see [`crate::sparse`].
//! * [`ridge_solve`]: $c = (A^\top A + \operatorname{diag}(\lambda))^{-1} A^\top b$ by Cholesky.

use nalgebra::DMatrix;

/// Orthonormalizes the columns of `m` in place (two passes of modified Gram–Schmidt).
/// Returns the number of non-zero columns left (the numerical rank).
pub fn orthonormalize(m: &mut DMatrix<f64>) -> usize {
    let (rows, cols) = m.shape();
    let mut norms0: Vec<f64> = (0..cols).map(|j| m.column(j).norm()).collect();
    let scale = norms0.iter().cloned().fold(0.0, f64::max);
    let mut rank = 0;
    for j in 0..cols {
        for _pass in 0..2 {
            for i in 0..j {
                let d = m.column(i).dot(&m.column(j));
                if d != 0.0 {
                    let (ci, mut cj) = m.columns_range_pair_mut(i, j);
                    cj.axpy(-d, &ci, 1.0);
                }
            }
        }
        let n = m.column(j).norm();
        // Relative to the column's own norm and to the largest input column: a zero column
        // or one inside the span of the previous ones becomes zero.
        if n > 1e-10 * norms0[j] && n > 1e-14 * scale && n > 0.0 {
            m.column_mut(j).scale_mut(1.0 / n);
            rank += 1;
        } else {
            m.column_mut(j).fill(0.0);
            norms0[j] = 0.0;
        }
    }
    let _ = rows;
    rank
}

/// Eigenvalues (descending, clipped at 0) and eigenvectors (columns, same order) of the
/// symmetric positive semi-definite matrix `g`.
pub fn sorted_eigen(g: DMatrix<f64>) -> (Vec<f64>, DMatrix<f64>) {
    let n = g.nrows();
    if n == 0 {
        return (Vec::new(), DMatrix::zeros(0, 0));
    }
    let sym = (&g + g.transpose()) * 0.5;
    let e = nalgebra::SymmetricEigen::new(sym);
    let mut order: Vec<usize> = (0..n).collect();
    order.sort_by(|&a, &b| e.eigenvalues[b].total_cmp(&e.eigenvalues[a]));
    let vals = order.iter().map(|&i| e.eigenvalues[i].max(0.0)).collect();
    let vecs = DMatrix::from_fn(n, n, |r, c| e.eigenvectors[(r, order[c])]);
    (vals, vecs)
}

/// `a^T * b` as one matrix product (nalgebra's `tr_mul` runs column by column and is up to
/// 10x slower on large operands).
pub fn at_b(a: &DMatrix<f64>, b: &DMatrix<f64>) -> DMatrix<f64> {
    a.transpose() * b
}

/// Thin "Q" of `a` (m x r) from its Gram matrix: `(Q, R)` with `a = Q R`, `Q` m x r_eff with
/// orthonormal columns, `R` r_eff x r; columns of `a` with no weight (eigenvalues below
/// `1e-14` of the largest) are dropped.
fn gram_qr(a: &DMatrix<f64>) -> (DMatrix<f64>, DMatrix<f64>) {
    let (lam, v) = sorted_eigen(at_b(a, a));
    let top = lam.first().copied().unwrap_or(0.0);
    let keep = lam.iter().take_while(|&&l| l > 1e-14 * top && l > 0.0).count();
    let mut t = DMatrix::zeros(a.ncols(), keep);
    let mut r = DMatrix::zeros(keep, a.ncols());
    for j in 0..keep {
        let s = lam[j].sqrt();
        for i in 0..a.ncols() {
            t[(i, j)] = v[(i, j)] / s;
            r[(j, i)] = v[(i, j)] * s;
        }
    }
    (a * t, r)
}

/// The rank-`k` truncated SVD `(U, S, V)` of `B = A C^T` from its factors (see the module
/// documentation). `U`: m x k', `V`: n x k' with k' = min(k, rank B); `S` descending.
pub fn factored_svd(a: &DMatrix<f64>, c: &DMatrix<f64>, k: usize) -> (DMatrix<f64>, Vec<f64>, DMatrix<f64>) {
    assert_eq!(a.ncols(), c.ncols(), "factored_svd: A and C need the same number of columns");
    let (qa, ra) = gram_qr(a);
    let (qc, rc) = gram_qr(c);
    let core = &ra * rc.transpose();
    if core.nrows() == 0 || core.ncols() == 0 {
        return (DMatrix::zeros(a.nrows(), 0), Vec::new(), DMatrix::zeros(c.nrows(), 0));
    }
    let svd = nalgebra::SVD::new(core, true, true);
    let (w, zt) = (svd.u.expect("u requested"), svd.v_t.expect("v requested"));
    let mut order: Vec<usize> = (0..svd.singular_values.len()).collect();
    order.sort_by(|&x, &y| svd.singular_values[y].total_cmp(&svd.singular_values[x]));
    let k = k.min(order.len());
    let s: Vec<f64> = order[..k].iter().map(|&i| svd.singular_values[i]).collect();
    let wk = DMatrix::from_fn(w.nrows(), k, |r, j| w[(r, order[j])]);
    let zk = DMatrix::from_fn(zt.ncols(), k, |r, j| zt[(order[j], r)]);
    (qa * wk, s, qc * zk)
}

/// Singular values of a small dense matrix, descending.
pub fn singular_values(a: &DMatrix<f64>) -> Vec<f64> {
    if a.nrows() == 0 || a.ncols() == 0 {
        return Vec::new();
    }
    let mut s: Vec<f64> = nalgebra::SVD::new(a.clone(), false, false).singular_values.iter().copied().collect();
    s.sort_by(|x, y| y.total_cmp(x));
    s
}

/// 2-norm condition number `sigma_max / sigma_min` of a (rows >= cols) matrix; infinite
/// when it is rank-deficient.
pub fn condition_number(a: &DMatrix<f64>) -> f64 {
    let s = singular_values(a);
    match (s.first(), s.get(a.ncols().min(a.nrows()).saturating_sub(1))) {
        (Some(&hi), Some(&lo)) if lo > 0.0 => hi / lo,
        _ => f64::INFINITY,
    }
}

/// Chooses `count` rows of `u` (m x k) that keep the selected submatrix well conditioned:
/// first column-pivoted QR of `u^T` (each step takes the row with the largest norm after
/// projecting out the rows taken, Businger–Golub), which picks up to `k` rows; then, while
/// more are wanted, the row with the largest leverage `u_r^T (A^T A)^{-1} u_r` against the
/// selection `A` (the row that grows `det(A^T A)` the most: greedy maximum volume), with
/// Sherman–Morrison updates. Returns the row indices in the order chosen.
pub fn select_rows(u: &DMatrix<f64>, count: usize) -> Vec<usize> {
    let (m, k) = u.shape();
    let count = count.min(m);
    let mut chosen = Vec::with_capacity(count);
    let mut taken = vec![false; m];
    // Phase 1: pivoted QR on the rows.
    let mut res = u.clone();
    let mut norms: Vec<f64> = (0..m).map(|r| res.row(r).norm_squared()).collect();
    let top = norms.iter().cloned().fold(0.0, f64::max);
    while chosen.len() < count.min(k) {
        let (best, &bn) =
            norms.iter().enumerate().filter(|(r, _)| !taken[*r]).max_by(|a, b| a.1.total_cmp(b.1)).expect("rows left");
        if bn <= 1e-20 * top.max(f64::MIN_POSITIVE) {
            break; // the remaining rows are in the span of the chosen ones
        }
        taken[best] = true;
        chosen.push(best);
        let q = res.row(best).transpose() / bn.sqrt();
        for r in 0..m {
            if !taken[r] {
                let d = res.row(r).dot(&q.transpose());
                for j in 0..k {
                    res[(r, j)] -= d * q[j];
                }
                norms[r] = res.row(r).norm_squared();
            }
        }
    }
    if chosen.len() >= count {
        return chosen;
    }
    // Phase 2: greedy volume growth. G = (A^T A + delta I)^{-1}.
    let mut ata = DMatrix::<f64>::zeros(k, k);
    for &r in &chosen {
        let row = u.row(r);
        ata += row.transpose() * row;
    }
    let delta = 1e-12 * (1.0 + ata.diagonal().max());
    for i in 0..k {
        ata[(i, i)] += delta;
    }
    let mut g = ata.try_inverse().unwrap_or_else(|| DMatrix::identity(k, k) / delta);
    let mut lev: Vec<f64> = (0..m).map(|r| (u.row(r) * &g * u.row(r).transpose())[(0, 0)]).collect();
    while chosen.len() < count {
        let (best, _) =
            lev.iter().enumerate().filter(|(r, _)| !taken[*r]).max_by(|a, b| a.1.total_cmp(b.1)).expect("rows left");
        taken[best] = true;
        chosen.push(best);
        let x = u.row(best).transpose();
        let gx = &g * &x;
        let denom = 1.0 + x.dot(&gx);
        g -= &gx * gx.transpose() / denom;
        for r in 0..m {
            if !taken[r] {
                let d = u.row(r).dot(&gx.transpose());
                lev[r] -= d * d / denom;
            }
        }
    }
    chosen
}

/// `(A^T A + diag(lambda))^{-1} A^T B` for `A` s x k, `B` s x n (`lambda`: k entries >= 0).
/// `None` if the regularised normal matrix is not positive definite.
pub fn ridge_solve(a: &DMatrix<f64>, b: &DMatrix<f64>, lambda: &[f64]) -> Option<DMatrix<f64>> {
    let at = a.transpose();
    let mut n = &at * a;
    for (i, l) in lambda.iter().enumerate() {
        n[(i, i)] += l;
    }
    let chol = nalgebra::Cholesky::new(n)?;
    Some(chol.solve(&(&at * b)))
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;
    use rand_chacha::ChaCha8Rng;
    use rand_distr::{Distribution, StandardNormal};

    fn gauss(rows: usize, cols: usize, seed: u64) -> DMatrix<f64> {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        DMatrix::from_fn(rows, cols, |_, _| StandardNormal.sample(&mut rng))
    }

    #[test]
    fn orthonormalize_handles_dependent_and_zero_columns() {
        for (rows, cols) in [(5, 3), (40, 12), (200, 30)] {
            let mut m = gauss(rows, cols, rows as u64);
            // Column 1 = 2 * column 0, the last column zero.
            let c0 = m.column(0).clone_owned();
            m.set_column(1, &(c0 * 2.0));
            m.column_mut(cols - 1).fill(0.0);
            let mut q = m.clone();
            let rank = orthonormalize(&mut q);
            assert_eq!(rank, cols - 2);
            let qtq = q.transpose() * &q;
            for i in 0..cols {
                for j in 0..cols {
                    let want = if i == j && q.column(i).norm() > 0.0 { 1.0 } else { 0.0 };
                    assert!((qtq[(i, j)] - want).abs() < 1e-12 * rows as f64, "{i} {j} {}", qtq[(i, j)]);
                }
            }
            // Same span: projecting m onto q leaves nothing.
            let resid = &m - &q * (q.transpose() * &m);
            assert!(resid.norm() < 1e-10 * m.norm());
        }
    }

    #[test]
    fn factored_svd_equals_the_svd_of_the_product() {
        for (m, n, r, seed) in [(30, 20, 4, 1u64), (80, 60, 10, 2), (50, 90, 7, 3)] {
            let a = gauss(m, r, seed);
            let c = gauss(n, r, seed + 100);
            let b = &a * c.transpose();
            let exact = singular_values(&b);
            let (u, s, v) = factored_svd(&a, &c, r);
            for j in 0..r {
                assert!((s[j] - exact[j]).abs() < 1e-9 * exact[0], "sigma {j}: {} vs {}", s[j], exact[j]);
            }
            let rebuilt = &u * DMatrix::from_diagonal(&nalgebra::DVector::from_vec(s.clone())) * v.transpose();
            assert!((&rebuilt - &b).norm() < 1e-9 * b.norm());
            // Truncated: the error is the discarded singular values.
            let (u2, s2, v2) = factored_svd(&a, &c, r / 2);
            let t = &u2 * DMatrix::from_diagonal(&nalgebra::DVector::from_vec(s2)) * v2.transpose();
            let tail: f64 = exact[r / 2..].iter().map(|x| x * x).sum::<f64>().sqrt();
            assert!(((&t - &b).norm() - tail).abs() < 1e-8 * b.norm());
        }
    }

    #[test]
    fn selected_rows_are_better_conditioned_than_the_first_rows() {
        // A basis whose first rows are nearly dependent: the selection must avoid them.
        for (m, k, count) in [(100, 5, 5), (300, 10, 25), (500, 20, 60)] {
            let mut u = gauss(m, k, m as u64);
            for r in 0..count {
                let base = u.row(0).clone_owned();
                u.set_row(r, &(base * (1.0 + 1e-6 * r as f64)));
            }
            orthonormalize(&mut u);
            let sel = select_rows(&u, count);
            assert_eq!(sel.len(), count);
            let mut uniq = sel.clone();
            uniq.sort_unstable();
            uniq.dedup();
            assert_eq!(uniq.len(), count, "no row twice");
            let pick = |rows: &[usize]| DMatrix::from_fn(rows.len(), k, |i, j| u[(rows[i], j)]);
            let kappa_sel = condition_number(&pick(&sel));
            let first: Vec<usize> = (0..count).collect();
            let kappa_first = condition_number(&pick(&first));
            assert!(kappa_sel < 50.0, "selected rows: kappa {kappa_sel}");
            assert!(kappa_first > 1e4, "first rows: kappa {kappa_first}");
        }
    }

    #[test]
    fn ridge_solve_recovers_exact_coefficients_without_regularisation() {
        let a = gauss(40, 6, 9);
        let x = gauss(6, 3, 10);
        let b = &a * &x;
        let got = ridge_solve(&a, &b, &[0.0; 6]).unwrap();
        assert!((&got - &x).norm() < 1e-10 * x.norm());
        // Regularisation shrinks.
        let shrunk = ridge_solve(&a, &b, &[1e3; 6]).unwrap();
        assert!(shrunk.norm() < 0.9 * x.norm());
    }
}
