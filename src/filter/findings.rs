//! What a scenario's filter does before any network is trained ([`findings`]): CBFs that no
//! input acts on, where on `C ∩ S` the QP is infeasible, and where a CBF's `‖L_g h‖` vanishes
//! while its row needs the input (`v` steep or jumping there). A user's first scenario often
//! has a CBF of relative degree two (a position bound on a double integrator): its row
//! `−L_g h·θ ≤ L_f̃ h + αh` has no `θ` in it, so the filter cannot enforce it and the QP is
//! infeasible wherever `L_f̃ h + αh < 0`. Without this the only sign was a count of skipped
//! training samples. It may import what the filter module may.

use super::SafetyFilter;
use super::{interval_rows, row_expressions, ConstraintRows, FilterStatus, Infeasibility};
use crate::expressions::Expr;
use crate::intervals::Interval;
use crate::scenario::Scenario;

/// About this many cell centres of `C` are solved (per axis the same count, at least 2).
pub const SAMPLE_POINTS: usize = 4096;

/// How far from 0 an inert row's enclosure may reach: interval products with an exact 0 are
/// rounded out to the smallest subnormals.
pub const INERT: f64 = 1e-300;

/// What [`findings`] found.
#[derive(Clone, Debug, PartialEq)]
pub struct FilterFindings {
    /// The CBFs whose row `−L_g h` is 0 on all of `C`, proven by interval evaluation: their
    /// relative degree is above one.
    pub inert: Vec<Inert>,
    /// The points of `C ∩ S` solved: the centres of an equal partition of `C` that lie in `S`.
    pub sampled: usize,
    /// Those where the QP is infeasible.
    pub infeasible: usize,
    /// The first such point and why.
    pub example: Option<(Vec<f64>, Infeasibility)>,
    /// CBFs whose `‖L_g h‖` falls below [`VANISHING`] of its largest on `C ∩ S` at a point
    /// where the row needs the input (`L_f̃ h + αh < 0`): `v` divides by `‖L_g h‖²`, so it is
    /// steep there or jumps (scenario 2's obstacle at (1, 0) and (3, 0)).
    pub vanishing: Vec<Vanishing>,
    /// Where the filtered flow leaves `C` through its sides (none where it leaves nowhere
    /// sampled): sets from boxes whose flow meets those sides end there, whatever the network.
    pub leaves_c: Option<LeavesC>,
}

/// Where the filtered flow leaves `C` ([`FilterFindings::leaves_c`]): `C` is not invariant,
/// and `verify` over all of `C` loses the cells along those sides.
#[derive(Clone, Debug, PartialEq)]
pub struct LeavesC {
    /// Points of `C`'s sides sampled in `S` where the filter is defined.
    pub sampled: usize,
    /// Those where the filtered field points out of `C`.
    pub leaving: usize,
    /// The first such point.
    pub at: Vec<f64>,
    /// Its side: the state's index, and whether it is the upper side.
    pub side: (usize, bool),
}

/// Where a CBF's `‖L_g h‖` nearly vanishes while its row needs the input ([`FilterFindings`]).
#[derive(Clone, Debug, PartialEq)]
pub struct Vanishing {
    /// The CBF's name.
    pub cbf: String,
    /// The smallest `‖L_g h‖` at such a point over the largest on the sampled `C ∩ S`.
    pub ratio: f64,
    /// That point.
    pub at: Vec<f64>,
}

/// A row whose `‖L_g h‖` falls below this share of its largest where it needs the input is
/// reported ([`FilterFindings::vanishing`]). The grid alone finds a few per cent near a zero
/// (the unicycle's `‖L_g h‖ ≥ 2lr` is 5.5 % of its largest, and never 0): [`descend`] follows
/// the smallest sample down to the zero, or stops at the true minimum.
pub const VANISHING: f64 = 1e-3;

/// The descents per CBF, from its smallest samples.
const DESCENTS: usize = 8;

/// `CBF k`'s `‖L_g h‖` over the points of `C ∩ S` where its row needs the input, and the point,
/// by a pattern search from `start` (steps of a cell `cell`, halved where no neighbour is
/// lower; every neighbour in 3 states or fewer, the axes beyond).
fn descend(s: &Scenario, k: usize, start: &[f64], cell: &[f64]) -> (f64, Vec<f64>) {
    let (n, m) = (s.n(), s.m());
    let filter = SafetyFilter::new(s);
    let cost = |x: &[f64]| -> Option<f64> {
        if !s.reach.region.contains(x) || !s.is_safe(x) {
            return None;
        }
        let rows = filter.constraint_rows(x).ok()?;
        (rows.q[k] < 0.0).then(|| leverage(&rows, k, m))
    };
    let moves: Vec<Vec<f64>> = match n <= 3 {
        true => (0..3usize.pow(n as u32))
            .map(|mut d| {
                (0..n)
                    .map(|_| {
                        let step = d % 3;
                        d /= 3;
                        step as f64 - 1.0
                    })
                    .collect()
            })
            .filter(|d: &Vec<f64>| d.iter().any(|&v| v != 0.0))
            .collect(),
        false => (0..2 * n)
            .map(|j| {
                let mut d = vec![0.0; n];
                d[j / 2] = if j % 2 == 0 { -1.0 } else { 1.0 };
                d
            })
            .collect(),
    };
    let (mut x, mut best) = (start.to_vec(), cost(start).unwrap_or(f64::INFINITY));
    let mut step = 0.5;
    for _ in 0..200 {
        let next = moves
            .iter()
            .map(|d| {
                (0..n)
                    .map(|i| x[i] + d[i] * step * cell[i])
                    .collect::<Vec<f64>>()
            })
            .filter_map(|y| cost(&y).map(|c| (c, y)))
            .min_by(|a, b| a.0.total_cmp(&b.0));
        match next {
            Some((c, y)) if c < best => (best, x) = (c, y),
            _ => step *= 0.5,
        }
        if step < 1e-12 {
            break;
        }
    }
    (best, x)
}

/// `‖L_g h‖` of CBF `k` (its row's `a`, `m` inputs).
fn leverage(rows: &ConstraintRows, k: usize, m: usize) -> f64 {
    rows.g[k * m..(k + 1) * m]
        .iter()
        .map(|a| a * a)
        .sum::<f64>()
        .sqrt()
}

/// A CBF no input acts on ([`inert_cbfs`]), what its row asks of the state, and whether
/// another of the scenario's CBFs asks the same.
#[derive(Clone, Debug, PartialEq)]
pub struct Inert {
    /// The CBF's index in the scenario's CBFs.
    pub index: usize,
    /// The CBF's name.
    pub cbf: String,
    /// `ψ = L_f̃h + α(h)`: the row reads `0·θ ≤ ψ(x)`, so the QP is feasible only where
    /// `ψ ≥ 0`. For a position bound on a double integrator `ψ` counts the velocity, and the
    /// input acts on its own row: the next level of a high-order CBF.
    pub next: Expr,
    /// The CBF whose `h` is a positive multiple of `ψ` (at the nodes of a grid over `C`), if
    /// one is: where it holds, so does the inert row (a high-order CBF written out).
    pub kept_by: Option<String>,
}

/// The CBFs whose row `−L_g h` encloses to 0 over `C` (within [`INERT`], the width outward
/// rounding gives a product with 0): no input acts on them anywhere in `C`.
pub fn inert_cbfs(s: &Scenario) -> Vec<Inert> {
    let (a, _) = interval_rows(s, &s.reach.region);
    let m = s.m();
    let zero = |i: &Interval| i.lower.abs() <= INERT && i.upper.abs() <= INERT;
    let inert: Vec<usize> = (0..s.cbfs.len())
        .filter(|k| a[k * m..(k + 1) * m].iter().all(zero))
        .collect();
    if inert.is_empty() {
        return Vec::new();
    }
    // The CBFs' rows come first, in order.
    let (_, b) = row_expressions(s, false);
    let region = &s.reach.region;
    let n = region.dim();
    let k = crate::boxes::per_axis_within(n, 1024, 32);
    let nodes = crate::boxes::grid_points(region, &vec![k + 1; n]);
    inert
        .into_iter()
        .map(|k| {
            let next = b[k].collected();
            let kept_by = (0..s.cbfs.len())
                .filter(|&j| j != k)
                .find(|&j| positive_multiple(&s.cbfs[j].h, &next, &nodes))
                .map(|j| s.cbfs[j].name.clone());
            Inert {
                index: k,
                cbf: s.cbfs[k].name.clone(),
                next,
                kept_by,
            }
        })
        .collect()
}

/// Whether `h = c·ψ` with one `c > 0` at every node (to 1e-9 relative), `c` taken where `|ψ|`
/// is largest.
fn positive_multiple(h: &Expr, psi: &Expr, nodes: &[Vec<f64>]) -> bool {
    let pairs: Vec<(f64, f64)> = nodes.iter().map(|x| (h.eval(x), psi.eval(x))).collect();
    let Some(&(h0, p0)) = pairs.iter().max_by(|a, b| a.1.abs().total_cmp(&b.1.abs())) else {
        return false;
    };
    let c = h0 / p0;
    c.is_finite()
        && c > 0.0
        && pairs
            .iter()
            .all(|&(h, p)| (h - c * p).abs() <= 1e-9 * (1.0 + h.abs() + (c * p).abs()))
}

/// The scenario's filter checked on `C`: inert CBFs, and the QP solved at about
/// [`SAMPLE_POINTS`] points of `C ∩ S`.
pub fn findings(s: &Scenario) -> FilterFindings {
    let region = &s.reach.region;
    let n = s.n();
    let per_axis = ((SAMPLE_POINTS as f64).powf(1.0 / n as f64).floor() as usize).max(2);
    let counts = vec![per_axis; n];
    let filter = SafetyFilter::new(s);
    let m = s.m();
    let (mut sampled, mut infeasible, mut example) = (0, 0, None);
    // Per CBF: the largest ‖L_g h‖ sampled, and every sample where its row needs the input.
    let mut largest = vec![0.0_f64; s.cbfs.len()];
    let mut needing: Vec<Vec<(f64, Vec<f64>)>> = vec![Vec::new(); s.cbfs.len()];
    for k in 0..per_axis.pow(n as u32) {
        let x = region.partition_cell(&counts, k).center();
        if !s.is_safe(&x) {
            continue;
        }
        sampled += 1;
        // A point where v is not defined (a CBF's gradient) is not an infeasible QP.
        let Ok(rows) = filter.constraint_rows(&x) else {
            continue;
        };
        for (c, (big, need)) in largest.iter_mut().zip(&mut needing).enumerate() {
            let norm = leverage(&rows, c, m);
            *big = big.max(norm);
            if rows.q[c] < 0.0 {
                need.push((norm, x.clone()));
            }
        }
        if let Ok(FilterStatus::Infeasible(why)) = filter.solve_rows(&rows, &x) {
            infeasible += 1;
            example.get_or_insert((x, why));
        }
    }
    let cell = region.partition_cell(&counts, 0).widths();
    let inert = inert_cbfs(s);
    let vanishing = s
        .cbfs
        .iter()
        .zip(largest.iter().zip(needing))
        .enumerate()
        .filter(|(_, (c, _))| !inert.iter().any(|i| i.cbf == c.name))
        .filter_map(|(k, (c, (&big, mut need)))| {
            // From the smallest few: one may start at a corner of the region the row needs
            // the input in, where the search stalls (the lane keeper's at y = −1).
            need.sort_by(|a, b| a.0.total_cmp(&b.0));
            let (norm, at) = need
                .iter()
                .take(DESCENTS)
                .map(|(_, start)| descend(s, k, start, &cell))
                .min_by(|a, b| a.0.total_cmp(&b.0))?;
            let ratio = norm / big;
            (big > 0.0 && ratio < VANISHING).then(|| Vanishing {
                cbf: c.name.clone(),
                ratio,
                at,
            })
        })
        .collect();
    FilterFindings {
        inert,
        sampled,
        infeasible,
        example,
        vanishing,
        leaves_c: leaves_c(s, &filter),
    }
}

/// The filtered field on about [`SAMPLE_POINTS`] points of `C`'s sides in `S` (on each side the
/// centres of an equal partition of the face), and where it points out of `C`.
fn leaves_c(s: &Scenario, filter: &SafetyFilter) -> Option<LeavesC> {
    let region = &s.reach.region;
    let n = s.n();
    let per_side = SAMPLE_POINTS / (2 * n);
    let per_axis = match n {
        1 => 1,
        _ => ((per_side as f64).powf(1.0 / (n - 1) as f64).floor() as usize).max(2),
    };
    let (mut sampled, mut leaving, mut first) = (0, 0, None);
    for axis in 0..n {
        let mut counts = vec![per_axis; n];
        counts[axis] = 1;
        for upper in [false, true] {
            let side = match upper {
                true => region.upper[axis],
                false => region.lower[axis],
            };
            for k in 0..counts.iter().product::<usize>() {
                let mut x = region.partition_cell(&counts, k).center();
                x[axis] = side;
                if !s.is_safe(&x) {
                    continue;
                }
                let Ok(field) = filter.closed_loop(&x) else {
                    continue;
                };
                sampled += 1;
                if (upper && field[axis] > 0.0) || (!upper && field[axis] < 0.0) {
                    leaving += 1;
                    first.get_or_insert((x, (axis, upper)));
                }
            }
        }
    }
    first.map(|(at, side)| LeavesC {
        sampled,
        leaving,
        at,
        side,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// tests/fixtures/vdp.toml with its wall `h`.
    fn van_der_pol(h: &str) -> Scenario {
        let text = include_str!("../../tests/fixtures/vdp.toml").replacen(
            "h = \"1.5 - x1 - 0.5*x2\"",
            &format!("h = \"{h}\""),
            1,
        );
        Scenario::from_toml(&text, "vdp.toml", std::path::Path::new(".")).unwrap()
    }

    /// A position bound on a double integrator's position (relative degree two) is found inert,
    /// and the QP infeasible exactly where `L_f h + αh = −x₂ + 1.5 − x₁ < 0`; tilted by the
    /// velocity (relative degree one) it is neither.
    #[test]
    fn a_cbf_no_input_acts_on_is_named_with_where_the_qp_fails() {
        let s = van_der_pol("1.5 - x1");
        let f = findings(&s);
        assert_eq!(f.inert.len(), 1);
        let wall = &f.inert[0];
        assert_eq!((wall.cbf.as_str(), wall.kept_by.as_ref()), ("wall", None));
        // Its row asks ψ = L_f h + αh = −x₂ + 1.5 − x₁ ≥ 0 (α = 1).
        for x in [[0.3, -0.2], [-1.0, 0.7], [1.2, 1.1]] {
            assert!((wall.next.eval(&x) - (1.5 - x[0] - x[1])).abs() < 1e-12);
        }
        let counts = vec![64, 64];
        let expected = (0..64 * 64)
            .map(|k| s.reach.region.partition_cell(&counts, k).center())
            .filter(|x| s.is_safe(x) && 1.5 - x[0] - x[1] < 0.0)
            .count();
        assert!(expected > 200, "{expected}");
        assert_eq!(f.infeasible, expected);
        let (x, why) = f.example.expect("an infeasible point");
        assert!(1.5 - x[0] - x[1] < 0.0, "{x:?}");
        assert!(matches!(why, Infeasibility::NoInputOnRow { .. }), "{why:?}");
        // Written out as a high-order CBF (ψ as a CBF of its own, here scaled by 2), the inert
        // row is kept by it, and the QP is feasible on all of C ∩ S.
        let text = include_str!("../../tests/fixtures/vdp.toml").replacen(
            "h = \"1.5 - x1 - 0.5*x2\"",
            "h = \"1.5 - x1\"\n[[cbf]]\nname = \"next\"\nh = \"3 - 2*x1 - 2*x2\"",
            1,
        );
        let both =
            findings(&Scenario::from_toml(&text, "vdp.toml", std::path::Path::new(".")).unwrap());
        assert_eq!(both.inert[0].kept_by.as_deref(), Some("next"));
        assert_eq!(both.infeasible, 0);
        let tilted = findings(&van_der_pol("1.5 - x1 - 0.5*x2"));
        assert!(tilted.inert.is_empty() && tilted.vanishing.is_empty());
        assert_eq!(tilted.infeasible, 0);
        assert!(tilted.sampled > 3000, "{}", tilted.sampled);
    }

    /// Scenario 2's filtered flow leaves `C` on some of its sides (first through `x₁ = −4` at
    /// full reverse speed), not all; the found point is on its side, in `S`, with the field
    /// pointing out. `ẋ = u`, `κ = −x`, kept left of a wall, leaves its box nowhere (the
    /// wall's side lies outside `S`).
    #[test]
    fn where_the_filtered_flow_leaves_c_is_found_and_only_there() {
        let text = include_str!("../../scenarios/double-integrator.toml");
        let s = Scenario::from_toml(text, "di.toml", std::path::Path::new(".")).unwrap();
        let l = findings(&s).leaves_c.expect("scenario 2's flow leaves C");
        assert!(l.leaving > 0 && l.leaving < l.sampled, "{l:?}");
        let (axis, upper) = l.side;
        let f = SafetyFilter::new(&s).closed_loop(&l.at).unwrap();
        let side = [s.reach.region.lower[axis], s.reach.region.upper[axis]][usize::from(upper)];
        assert_eq!(l.at[axis], side);
        assert!(s.is_safe(&l.at));
        assert!(
            if upper { f[axis] > 0.0 } else { f[axis] < 0.0 },
            "{l:?}: {f:?}"
        );
        let text = include_str!("../../tests/fixtures/vdp.toml")
            .replacen(
                "f = [\"x2\", \"(1 - x1^2)*x2 - x1\"]",
                "f = [\"0\", \"0\"]",
                1,
            )
            .replacen(
                "g = [[\"0\"], [\"1\"]]",
                "g = [[\"1\", \"0\"], [\"0\", \"1\"]]",
                1,
            )
            .replacen("inputs = [\"u\"]", "inputs = [\"u1\", \"u2\"]", 1)
            .replacen(
                "kappa = [\"-x1 - 2*x2 - (1 - x1^2)*x2 + x1\"]",
                "kappa = [\"-x1\", \"-x2\"]",
                1,
            );
        let contracting = Scenario::from_toml(&text, "x.toml", std::path::Path::new(".")).unwrap();
        let f = findings(&contracting);
        assert_eq!(f.leaves_c, None, "{f:?}");
    }

    /// A lane keeper whose CBF `1 − y − sin ψ` has `L_g h = −cos ψ`: where the row needs the
    /// input, `‖L_g h‖` reaches 0 at `ψ = π/2` (the grid's nearest sample is at 5 % of the
    /// largest); the descent finds the zero (tests/fixtures/lane.toml).
    #[test]
    fn where_l_g_h_vanishes_with_the_row_needing_input_is_found() {
        let text = include_str!("../../tests/fixtures/lane.toml");
        let s = Scenario::from_toml(text, "lane.toml", std::path::Path::new(".")).unwrap();
        let f = findings(&s);
        assert_eq!(f.vanishing.len(), 1, "{f:?}");
        let v = &f.vanishing[0];
        assert!(v.ratio < 1e-6, "{v:?}");
        assert!(
            (v.at[1].abs() - std::f64::consts::FRAC_PI_2).abs() < 1e-5,
            "{v:?}"
        );
        // The point is one the row needs the input at, in S.
        let rows = SafetyFilter::new(&s).constraint_rows(&v.at).unwrap();
        assert!(rows.q[0] < 0.0 && s.is_safe(&v.at), "{v:?}");
    }
}
