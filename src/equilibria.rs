//! Equilibria of the filtered system `F(x) = f̃(x) + g(x) v(x) = 0` inside the region `C`.
//!
//! A CBF filter can create equilibria where the nominal loop has none: points on `∂S` where
//! `f̃(x*) ≠ 0` is cancelled by the filter (*undesirable* equilibria, Chen et al. 2024). We find
//! them by damped Newton iterations from a coarse set of starts over `C` (a grid in the plane, a
//! Halton set of the same size in 3 or more states, so that the cost does not grow with the
//! power of the dimension) and from the same starts projected onto each CBF's zero level set,
//! de-duplicate, and classify each by the eigenvalues
//! of `DF(x*)` (central differences: `F` is smooth on each side of an active-set switch, and an
//! equilibrium on `∂S` lies strictly inside the active side).
//!
//! Where equilibria form a curve or surface (the unicycle's look-ahead controller rests
//! wherever its look-ahead point is at the goal, whatever the heading), every start lands
//! somewhere on it; [`group_equilibria`] reports such a set once, as a [`Continuum`] with its
//! extent and sample count, instead of as hundreds of points.

use nalgebra::{DMatrix, DVector};
use rayon::prelude::*;
use serde::Serialize;

use crate::boxes::IntervalBox;
use crate::filter::SafetyFilter;

/// Stability type from the eigenvalues of the Jacobian.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum Stability {
    /// Every eigenvalue has a negative real part.
    Stable,
    /// Real parts of both signs, none zero.
    Saddle,
    /// Every eigenvalue has a positive real part.
    Unstable,
    /// Some real part is zero (within tolerance): linearisation decides nothing.
    NonHyperbolic,
}

impl std::fmt::Display for Stability {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            Stability::Stable => "stable",
            Stability::Saddle => "saddle",
            Stability::Unstable => "unstable",
            Stability::NonHyperbolic => "non-hyperbolic",
        })
    }
}

/// One equilibrium `x*` of the filtered system.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Equilibrium {
    /// `x*`.
    pub x: Vec<f64>,
    /// Its type.
    pub kind: Stability,
    /// Eigenvalues of `DF(x*)` as `[re, im]`, sorted by real part.
    pub eigenvalues: Vec<[f64; 2]>,
    /// `f̃(x*) ≠ 0`: an equilibrium created by the filter.
    pub undesirable: bool,
}

/// A connected set of non-hyperbolic equilibria found from many starts: a curve or surface
/// of equilibria (a zero eigenvalue along it), sampled where the search's starts landed.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Continuum {
    /// Lower corner of the samples' hull.
    pub lower: Vec<f64>,
    /// Upper corner of the samples' hull.
    pub upper: Vec<f64>,
    /// Equilibria found on it.
    pub samples: usize,
    /// `f̃(x*) ≠ 0` on it: created by the filter (a continuum holds equilibria of one kind).
    pub undesirable: bool,
    /// One sample (the first in position order).
    pub example: Vec<f64>,
}

/// What the search found, grouped: isolated equilibria and continua of equilibria.
#[derive(Clone, Debug, PartialEq, Serialize)]
#[serde(tag = "type", rename_all = "kebab-case")]
pub enum EquilibriumSet {
    /// An isolated equilibrium.
    Point(Equilibrium),
    /// A curve or surface of equilibria.
    Continuum(Continuum),
}

/// Search settings.
#[derive(Clone, Debug)]
pub struct EquilibriumSearch {
    /// Starting points per axis of the grid over `C` in the plane; in `n ≥ 3` states the
    /// same number of starts in all (`starts_per_axis²`, a Halton set over `C`).
    pub starts_per_axis: usize,
    /// Accept `x` when `‖F(x)‖∞` is below this.
    pub residual_tolerance: f64,
    /// Real parts within this of 0 count as zero.
    pub hyperbolicity_tolerance: f64,
    /// Newton iterations per start.
    pub max_iterations: usize,
}

impl Default for EquilibriumSearch {
    fn default() -> Self {
        EquilibriumSearch {
            starts_per_axis: 30,
            residual_tolerance: 1e-10,
            hyperbolicity_tolerance: 1e-6,
            max_iterations: 60,
        }
    }
}

/// Every equilibrium of the filtered system found inside `region`, sorted by position.
pub fn find_equilibria(
    filter: &SafetyFilter,
    region: &IntervalBox,
    search: &EquilibriumSearch,
) -> Vec<Equilibrium> {
    let n = region.dim();
    let per_axis = search.starts_per_axis.max(2);
    let coarse: Vec<Vec<f64>> = if n <= 2 {
        region
            .partition(&vec![per_axis; n])
            .iter()
            .map(IntervalBox::center)
            .collect()
    } else {
        (1..=per_axis * per_axis)
            .map(|k| region.point_at(&halton(k, n)))
            .collect()
    };
    let mut starts = coarse.clone();
    for cbf in &filter.scenario().cbfs {
        starts.extend(coarse.iter().filter_map(|c| {
            let p = project_to_zero_level(c, |x| {
                let grad = cbf.gradient.iter().map(|e| e.eval(x)).collect();
                (cbf.h.eval(x), grad)
            })?;
            region.contains(&p).then_some(p)
        }));
    }
    let found: Vec<Vec<f64>> = starts
        .par_iter()
        .filter_map(|x0| newton(filter, x0, search))
        .filter(|x| region.contains(x))
        .collect();

    let scale = region.widths().iter().fold(0.0_f64, |a, &b| a.max(b));
    let periods = state_periods(filter.scenario());
    let mut unique: Vec<Vec<f64>> = Vec::new();
    for x in found {
        if !unique
            .iter()
            .any(|u| max_dist(u, &x, &periods) < 1e-6 * scale.max(1.0))
        {
            unique.push(x);
        }
    }
    unique.sort_by(|a, b| {
        a.iter()
            .zip(b)
            .fold(std::cmp::Ordering::Equal, |o, (p, q)| {
                o.then(p.total_cmp(q))
            })
    });
    unique
        .into_iter()
        .filter_map(|x| classify(filter, x, search))
        .collect()
}

/// Groups `found` ([`find_equilibria`] over `region` with `search`): non-hyperbolic
/// equilibria, all desirable or all undesirable, closer than two start spacings to one another
/// (in units of `region`'s widths; single linkage) form a [`Continuum`] when there are at least
/// [`CONTINUUM_SAMPLES`] of them; every other equilibrium is a point. Two continua of one kind
/// closer than that are reported as one.
pub fn group_equilibria(
    found: Vec<Equilibrium>,
    region: &IntervalBox,
    search: &EquilibriumSearch,
) -> Vec<EquilibriumSet> {
    let n = region.dim();
    let per_axis = search.starts_per_axis.max(2) as f64;
    // The starts' spacing: 1/k per axis on the k × k grid, (k²)^(−1/n) for the Halton set.
    let spacing = if n <= 2 {
        1.0 / per_axis
    } else {
        (per_axis * per_axis).powf(-1.0 / n as f64)
    };
    let link = 2.0 * spacing;
    let widths: Vec<f64> = region.widths().iter().map(|w| w.max(1e-300)).collect();
    let near = |a: &[f64], b: &[f64]| (0..n).all(|i| (a[i] - b[i]).abs() <= link * widths[i]);
    let flat: Vec<usize> = (0..found.len())
        .filter(|&k| found[k].kind == Stability::NonHyperbolic)
        .collect();
    // Single linkage by a flood fill over the non-hyperbolic ones.
    let mut group = vec![usize::MAX; found.len()];
    let mut groups: Vec<Vec<usize>> = Vec::new();
    for &k in &flat {
        if group[k] != usize::MAX {
            continue;
        }
        let id = groups.len();
        group[k] = id;
        let mut members = vec![k];
        let mut next = 0;
        while next < members.len() {
            let a = members[next];
            next += 1;
            for &b in &flat {
                if group[b] == usize::MAX
                    && found[b].undesirable == found[a].undesirable
                    && near(&found[a].x, &found[b].x)
                {
                    group[b] = id;
                    members.push(b);
                }
            }
        }
        groups.push(members);
    }
    let mut out = Vec::new();
    let mut grouped = vec![false; found.len()];
    for members in groups.iter().filter(|m| m.len() >= CONTINUUM_SAMPLES) {
        let mut lower = vec![f64::INFINITY; n];
        let mut upper = vec![f64::NEG_INFINITY; n];
        for &k in members {
            grouped[k] = true;
            for i in 0..n {
                lower[i] = lower[i].min(found[k].x[i]);
                upper[i] = upper[i].max(found[k].x[i]);
            }
        }
        let first = members.iter().copied().min().unwrap_or(0);
        out.push((
            first,
            EquilibriumSet::Continuum(Continuum {
                lower,
                upper,
                samples: members.len(),
                undesirable: found[first].undesirable,
                example: found[first].x.clone(),
            }),
        ));
    }
    for (k, e) in found.into_iter().enumerate() {
        if !grouped[k] {
            out.push((k, EquilibriumSet::Point(e)));
        }
    }
    // In the order of `found` (by position), each continuum at its first sample.
    out.sort_by_key(|(k, _)| *k);
    out.into_iter().map(|(_, e)| e).collect()
}

/// Fewest non-hyperbolic equilibria that [`group_equilibria`] reports as a continuum.
pub const CONTINUUM_SAMPLES: usize = 3;

/// The `k`-th point of the Halton sequence in `[0, 1]ⁿ` (bases the first `n` primes).
fn halton(k: usize, n: usize) -> Vec<f64> {
    const PRIMES: [usize; 12] = [2, 3, 5, 7, 11, 13, 17, 19, 23, 29, 31, 37];
    (0..n)
        .map(|i| {
            let base = PRIMES[i % PRIMES.len()];
            let (mut f, mut r, mut j) = (1.0, 0.0, k);
            while j > 0 {
                f /= base as f64;
                r += f * (j % base) as f64;
                j /= base;
            }
            r
        })
        .collect()
}

/// Each state's period (`[system] periodic`), `None` for an ordinary state.
fn state_periods(s: &crate::scenario::Scenario) -> Vec<Option<f64>> {
    let mut periods = vec![None; s.n()];
    for p in &s.periodic {
        periods[p.state] = Some(p.period());
    }
    periods
}

/// The ℓ∞ distance, periodic states measured round their circle (`−π` and `π` are one angle).
fn max_dist(a: &[f64], b: &[f64], periods: &[Option<f64>]) -> f64 {
    a.iter()
        .zip(b)
        .zip(periods)
        .map(|((p, q), period)| match period {
            Some(t) => {
                let d = (p - q).abs().rem_euclid(*t);
                d.min(t - d)
            }
            None => (p - q).abs(),
        })
        .fold(0.0, f64::max)
}

/// Newton's method on a scalar `h` towards `h = 0` along `∇h` (a few steps; None if it fails).
fn project_to_zero_level(
    x0: &[f64],
    h_and_grad: impl Fn(&[f64]) -> (f64, Vec<f64>),
) -> Option<Vec<f64>> {
    let mut x = x0.to_vec();
    for _ in 0..30 {
        let (h, grad) = h_and_grad(&x);
        let norm2: f64 = grad.iter().map(|g| g * g).sum();
        if !h.is_finite() || !norm2.is_finite() || norm2 < 1e-300 {
            return None;
        }
        if h.abs() < 1e-13 {
            return Some(x);
        }
        x.iter_mut()
            .zip(&grad)
            .for_each(|(xi, gi)| *xi -= h * gi / norm2);
    }
    let (h, _) = h_and_grad(&x);
    (h.abs() < 1e-9).then_some(x)
}

fn residual(filter: &SafetyFilter, x: &[f64]) -> Option<(Vec<f64>, f64)> {
    let f = filter.closed_loop(x).ok()?;
    let r = f.iter().fold(0.0_f64, |a, v| a.max(v.abs()));
    r.is_finite().then_some((f, r))
}

/// Damped Newton on `F(x) = 0` with a backtracking line search on `‖F‖∞`.
fn newton(filter: &SafetyFilter, x0: &[f64], search: &EquilibriumSearch) -> Option<Vec<f64>> {
    let n = x0.len();
    let mut x = x0.to_vec();
    let (mut f, mut r) = residual(filter, &x)?;
    for _ in 0..search.max_iterations {
        if r < search.residual_tolerance {
            return Some(x);
        }
        let jac = filter.closed_loop_jacobian(&x).ok()?;
        let delta = DMatrix::from_row_slice(n, n, &jac)
            .lu()
            .solve(&(-DVector::from_vec(f.clone())))?;
        let mut alpha = 1.0;
        loop {
            let trial: Vec<f64> = (0..n).map(|i| x[i] + alpha * delta[i]).collect();
            if let Some((ft, rt)) = residual(filter, &trial) {
                if rt < r * (1.0 - 1e-4 * alpha) {
                    (x, f, r) = (trial, ft, rt);
                    break;
                }
            }
            alpha *= 0.5;
            if alpha < 1e-10 {
                return None;
            }
        }
    }
    (r < search.residual_tolerance).then_some(x)
}

fn classify(filter: &SafetyFilter, x: Vec<f64>, search: &EquilibriumSearch) -> Option<Equilibrium> {
    let n = x.len();
    let jac = filter.closed_loop_jacobian(&x).ok()?;
    let mut eigenvalues: Vec<[f64; 2]> = DMatrix::from_row_slice(n, n, &jac)
        .complex_eigenvalues()
        .iter()
        .map(|z| [z.re, z.im])
        .collect();
    eigenvalues.sort_by(|a, b| a[0].total_cmp(&b[0]).then(a[1].total_cmp(&b[1])));
    let tol = search.hyperbolicity_tolerance;
    let kind = if eigenvalues.iter().any(|z| z[0].abs() <= tol) {
        Stability::NonHyperbolic
    } else if eigenvalues.iter().all(|z| z[0] < 0.0) {
        Stability::Stable
    } else if eigenvalues.iter().all(|z| z[0] > 0.0) {
        Stability::Unstable
    } else {
        Stability::Saddle
    };
    let nominal = filter.scenario().f_tilde_at(&x);
    let undesirable = nominal.iter().any(|v| v.abs() > 1e-7);
    Some(Equilibrium {
        x,
        kind,
        eigenvalues,
        undesirable,
    })
}
