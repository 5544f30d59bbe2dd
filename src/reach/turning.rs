//! Closed loops that turn sets faster than they shrink them: the limit of box coordinates
//! (docs/design.md §2b).
//!
//! A complex pair `α ± iβ` of the closed loop's linearisation rotates a set by `|β|` radians a
//! second while shrinking it at `|α|`. In any one frame of box coordinates the pair's best ℓ∞
//! rate is `α + |β|` ([`super::Transform::contracting`] attains it), so where `α + |β| ≥ 0`
//! boxes cannot shrink near the goal whatever the coordinates: the sets of a lightly damped
//! loop wrap and grow, and tubes do not reach the goal. Continuous time's slabs clipped by the
//! other frame's sets (§7.1 item 7) recover part of the rotation, and only part. Said before
//! any run, so that a verified share of 0 % has its cause named.

use nalgebra::DMatrix;

use crate::filter::SafetyFilter;
use crate::scenario::Scenario;

/// The eigenvalues `α ± iβ` (`α < 0 ≤ α + |β|`) of a stable closed loop at the goal that turn
/// sets at least as fast as they shrink them.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Turning {
    /// The pair's real part (< 0).
    pub alpha: f64,
    /// Its imaginary part (> 0, at least `|α|`).
    pub beta: f64,
}

impl Turning {
    /// The pair of `A` (n×n, row-major) with the largest `α + |β|`, where that is `≥ 0` and
    /// every eigenvalue's real part is negative (an unstable loop is another matter).
    pub fn of(a: &[f64], n: usize) -> Option<Turning> {
        if n == 0 || a.len() != n * n || a.iter().any(|v| !v.is_finite()) {
            return None;
        }
        let eigenvalues = DMatrix::from_row_slice(n, n, a).complex_eigenvalues();
        if eigenvalues.iter().any(|z| z.re >= 0.0) {
            return None;
        }
        let scale = a.iter().fold(f64::MIN_POSITIVE, |m, v| m.max(v.abs()));
        eigenvalues
            .iter()
            .filter(|z| z.im > 1e-9 * scale)
            .map(|z| Turning {
                alpha: z.re,
                beta: z.im,
            })
            .max_by(|p, q| p.box_rate().total_cmp(&q.box_rate()))
            .filter(|p| p.box_rate() >= 0.0)
    }

    /// The pair of the filtered closed loop's Jacobian at the goal's centre, if any.
    pub fn at_goal(scenario: &Scenario) -> Option<Turning> {
        let goal = scenario.reach.goal.center();
        let a = SafetyFilter::new(scenario)
            .closed_loop_jacobian(&goal)
            .ok()?;
        Turning::of(&a, scenario.n())
    }

    /// `α + |β|`: the best rate of boxes in one frame of coordinates.
    pub fn box_rate(&self) -> f64 {
        self.alpha + self.beta.abs()
    }
}

impl std::fmt::Display for Turning {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "the closed loop at the goal turns sets at least as fast as it shrinks them \
             (eigenvalues {a:.3} ± {b:.3}i): in any one frame of coordinates boxes cannot shrink \
             there (at best α + |β| = {r:.3} ≥ 0), so tubes reach the goal only where continuous \
             time's slabs clipped by the other frame's sets win, and hardly ever in `euler` or \
             `sampled`; more damping in the nominal controller (|α| > |β|) lets boxes shrink",
            a = self.alpha,
            b = self.beta,
            r = self.box_rate(),
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// `ẍ = −kx − cẋ`: complex pairs `−c/2 ± i√(k − c²/4)`.
    fn oscillator(k: f64, c: f64) -> Vec<f64> {
        vec![0.0, 1.0, -k, -c]
    }

    #[test]
    fn lightly_damped_loops_turn_and_damped_ones_do_not() {
        // −0.25 ± 0.968i: turns.
        let p = Turning::of(&oscillator(1.0, 0.5), 2).unwrap();
        assert!((p.alpha + 0.25).abs() < 1e-12 && (p.beta - 0.9375_f64.sqrt()).abs() < 1e-12);
        assert!((p.box_rate() - (0.9375_f64.sqrt() - 0.25)).abs() < 1e-12);
        // −1.5 ± 0.866i, real −1 and −2, and an unstable loop: none.
        assert_eq!(Turning::of(&oscillator(3.0, 3.0), 2), None);
        assert_eq!(Turning::of(&oscillator(2.0, 3.0), 2), None);
        assert_eq!(Turning::of(&oscillator(1.0, -0.5), 2), None);
        // The worse of two pairs, in a block-diagonal 4 × 4 loop.
        let mut a = vec![0.0; 16];
        for (block, (k, c)) in [(3.0, 3.0), (1.0, 0.2)].into_iter().enumerate() {
            let o = oscillator(k, c);
            for (i, j) in [(0, 0), (0, 1), (1, 0), (1, 1)] {
                a[(2 * block + i) * 4 + 2 * block + j] = o[i * 2 + j];
            }
        }
        let p = Turning::of(&a, 4).unwrap();
        assert!((p.alpha + 0.1).abs() < 1e-9, "{p:?}");
    }
}
