//! The coordinates in which a closed loop's linear part contracts in ℓ∞
//! ([`super::Transform::contracting`]): a real Schur form, complex pairs in their own rotation
//! coordinates, the coupling between blocks scaled down; parts of the state that do not act
//! on each other each get their own.

use nalgebra::DMatrix;

use super::{log_norm_inf, TransformError};

/// The parts of the state that do not act on each other through `A` (n×n, row-major): the
/// connected components of `i ~ j` where `A[i][j] ≠ 0` or `A[j][i] ≠ 0`, each sorted, in the
/// order of their first state.
pub(super) fn decoupled_parts(a: &[f64], n: usize) -> Vec<Vec<usize>> {
    fn root(part: &mut [usize], mut i: usize) -> usize {
        while part[i] != i {
            part[i] = part[part[i]];
            i = part[i];
        }
        i
    }
    let mut part: Vec<usize> = (0..n).collect();
    for i in 0..n {
        for j in 0..n {
            if i != j && a[i * n + j] != 0.0 {
                let (ri, rj) = (root(&mut part, i), root(&mut part, j));
                part[ri.max(rj)] = ri.min(rj);
            }
        }
    }
    let mut parts: Vec<Vec<usize>> = Vec::new();
    let mut index_of = vec![usize::MAX; n];
    for i in 0..n {
        let r = root(&mut part, i);
        if index_of[r] == usize::MAX {
            index_of[r] = parts.len();
            parts.push(Vec::new());
        }
        parts[index_of[r]].push(i);
    }
    parts
}

/// `T` (row-major) of [`super::Transform::contracting`] for one part: `A = Q U Qᵀ`; each 2 × 2
/// block of a complex pair `α ± iβ` is brought to `[[α, β], [−β, α]]` by its own `P`; then
/// `T = D⁻¹ W⁻¹ Qᵀ`, `W = diag(P, 1, …)` and `D = diag(δ⁰, δ¹, …)` (one power a block)
/// shrinking the coupling between blocks until `μ∞(TAT⁻¹)` is within half of the slowest
/// block's rate, or the smallest `μ∞` the halvings of `δ` found.
pub(super) fn contracting_matrix(a: &[f64], n: usize) -> Result<Vec<f64>, TransformError> {
    let am = DMatrix::from_row_slice(n, n, a);
    let (mut q, mut u) = am.clone().schur().unpack();
    split_real_pairs(&mut q, &mut u);
    let blocks = schur_blocks(&u);
    // `W`: the blocks' own coordinates; the identity where every eigenvalue is real, so
    // that those systems get the bits they always had.
    let pairs: Vec<usize> = blocks
        .iter()
        .filter(|&&(_, size)| size == 2)
        .map(|&(i, _)| i)
        .collect();
    let w = (!pairs.is_empty()).then(|| {
        let mut w = DMatrix::identity(n, n);
        for &i in &pairs {
            w.view_mut((i, i), (2, 2)).copy_from(&rotation_basis(&u, i));
        }
        w
    });
    let (w_inv, u) = match &w {
        Some(w) => {
            let w_inv = w.clone().try_inverse().ok_or(TransformError::Singular)?;
            let u = &w_inv * &u * w;
            (Some(w_inv), u)
        }
        None => (None, u),
    };
    // The power of `δ` of each coordinate: its block's index.
    let power: Vec<i32> = blocks
        .iter()
        .enumerate()
        .flat_map(|(k, &(_, size))| std::iter::repeat_n(k as i32, size))
        .collect();
    // Each block's own rate `μ∞` (its diagonal part), the slowest of which sets the goal.
    let slowest = blocks
        .iter()
        .map(|&(i, size)| log_norm_inf_of(&u.view((i, i), (size, size)).clone_owned()))
        .fold(f64::NEG_INFINITY, f64::max);
    // Where the slowest block does not contract (a pair that turns sets faster than it
    // shrinks them), its own rate is only approached as `δ → 0`: within 1 % of it is as
    // good, where halving on would scale `T` by `2⁴⁰` (a 3-state loop with a pair driving
    // a real mode got entries of 10¹¹, and no enclosure closed).
    let target = if slowest < 0.0 {
        0.5 * slowest
    } else {
        slowest + 0.01 * slowest.max(1e-3)
    };
    let mut delta: f64 = 1.0;
    let mut best: Option<(f64, DMatrix<f64>)> = None;
    for _ in 0..40 {
        let d_inv = DMatrix::from_fn(n, n, |i, j| match i == j {
            true => delta.powi(-power[i]),
            false => 0.0,
        });
        let d = DMatrix::from_fn(n, n, |i, j| match i == j {
            true => delta.powi(power[i]),
            false => 0.0,
        });
        let t = match &w_inv {
            Some(w_inv) => &d_inv * w_inv * q.transpose(),
            None => &d_inv * q.transpose(),
        };
        let mu = log_norm_inf_of(&(&d_inv * &u * d));
        if best.as_ref().is_none_or(|(b, _)| mu < *b) {
            best = Some((mu, t));
        }
        if mu <= target {
            break;
        }
        delta *= 0.5;
    }
    let (_, t) = best.ok_or(TransformError::Empty)?;
    Ok((0..n * n).map(|k| t[(k / n, k % n)]).collect())
}

/// `μ∞` of a square matrix ([`log_norm_inf`]).
fn log_norm_inf_of(m: &DMatrix<f64>) -> f64 {
    let n = m.nrows();
    let row_major: Vec<f64> = (0..n * n).map(|k| m[(k / n, k % n)]).collect();
    log_norm_inf(&row_major, n)
}

/// The diagonal blocks of a real Schur form `U`: `(first row, 1 or 2)`, a 2 × 2 block where
/// the entry below the diagonal is not negligible (a complex pair).
pub(in crate::reach) fn schur_blocks(u: &DMatrix<f64>) -> Vec<(usize, usize)> {
    let n = u.nrows();
    let scale = u.amax().max(f64::MIN_POSITIVE);
    let mut blocks = Vec::new();
    let mut i = 0;
    while i < n {
        let pair = i + 1 < n && complex_pair(u, i, scale);
        blocks.push((i, if pair { 2 } else { 1 }));
        i += if pair { 2 } else { 1 };
    }
    blocks
}

/// Whether the entry below `U`'s diagonal at `i` is not negligible against `scale`.
fn coupled_below(u: &DMatrix<f64>, i: usize, scale: f64) -> bool {
    u[(i + 1, i)].abs() > 1e-12 * scale
}

/// Whether the 2 × 2 block at `i` is a complex pair. One whose imaginary part is negligible is
/// left to the scaling as two real eigenvalues: its basis `P` would be nearly singular.
fn complex_pair(u: &DMatrix<f64>, i: usize, scale: f64) -> bool {
    coupled_below(u, i, scale) && imaginary_part(u, i) > 1e-6 * scale
}

/// `(a − d)²/4 + bc` of the 2 × 2 block `[[a, b], [c, d]]` at `i`: its eigenvalues are
/// `(a + d)/2 ± √` of it.
fn discriminant(u: &DMatrix<f64>, i: usize) -> f64 {
    let (a, b, c, d) = (u[(i, i)], u[(i, i + 1)], u[(i + 1, i)], u[(i + 1, i + 1)]);
    0.25 * (a - d) * (a - d) + b * c
}

/// Makes triangular each 2 × 2 block of `U` whose eigenvalues are real but which nalgebra's
/// Schur form left unsplit (two double integrators' `−1, −1, −1, −1` leave one: the QR
/// iteration converges slowly on a defective eigenvalue), by the rotation to the block's
/// eigenvector, applied to `U` and `Q` alike. Unsplit, the block's entry below the diagonal
/// is what the scaling of [`Transform::contracting`] multiplies up (`μ∞ = 1` in z, as in x).
fn split_real_pairs(q: &mut DMatrix<f64>, u: &mut DMatrix<f64>) {
    let n = u.nrows();
    let scale = u.amax().max(f64::MIN_POSITIVE);
    for i in 0..n.saturating_sub(1) {
        if !coupled_below(u, i, scale) || complex_pair(u, i, scale) {
            continue;
        }
        let (a, b, c, d) = (u[(i, i)], u[(i, i + 1)], u[(i + 1, i)], u[(i + 1, i + 1)]);
        let lambda = 0.5 * (a + d) + discriminant(u, i).max(0.0).sqrt();
        // Two directions of the null space of `B − λI`; the longer is the better conditioned.
        let (p, r) = if b.hypot(lambda - a) >= (lambda - d).hypot(c) {
            (b, lambda - a)
        } else {
            (lambda - d, c)
        };
        let norm = p.hypot(r);
        if norm == 0.0 {
            continue;
        }
        let g = DMatrix::from_row_slice(2, 2, &[p / norm, -r / norm, r / norm, p / norm]);
        let rows = g.transpose() * u.rows(i, 2);
        u.rows_mut(i, 2).copy_from(&rows);
        let cols = u.columns(i, 2) * &g;
        u.columns_mut(i, 2).copy_from(&cols);
        let cols = q.columns(i, 2) * &g;
        q.columns_mut(i, 2).copy_from(&cols);
    }
}

/// `β ≥ 0` of the eigenvalues `α ± iβ` of the 2 × 2 block `U[i.., i..]` (0 where they are real).
fn imaginary_part(u: &DMatrix<f64>, i: usize) -> f64 {
    (-discriminant(u, i)).max(0.0).sqrt()
}

/// `P` with `P⁻¹BP = [[α, β], [−β, α]]` for the 2 × 2 block `B = U[i.., i..]` with eigenvalues
/// `α ± iβ`: the real and imaginary parts of `B`'s eigenvector `(b, λ − a)` of `λ = α + iβ`
/// (`Bp = αp − βq`, `Bq = βp + αq`). Where `B`'s eigenvalues are real after all (a block the
/// Schur form left unsplit), the identity.
fn rotation_basis(u: &DMatrix<f64>, i: usize) -> DMatrix<f64> {
    let (a, b) = (u[(i, i)], u[(i, i + 1)]);
    let alpha = 0.5 * (a + u[(i + 1, i + 1)]);
    let beta = imaginary_part(u, i);
    if beta == 0.0 || b == 0.0 {
        return DMatrix::identity(2, 2);
    }
    // Columns p = (b, α − a), q = (0, β), scaled to unit length of p.
    let norm = b.hypot(alpha - a);
    DMatrix::from_row_slice(2, 2, &[b / norm, 0.0, (alpha - a) / norm, beta / norm])
}
