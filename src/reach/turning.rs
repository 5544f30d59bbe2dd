//! Closed loops that turn sets faster than they shrink them: the limit of box coordinates
//! (docs/design.md §2b).
//!
//! A complex pair `α ± iβ` of the closed loop's linearisation rotates a set by `|β|` radians a
//! second while shrinking it at `|α|`. In any one frame of box coordinates the pair's best ℓ∞
//! rate is `α + |β|` ([`super::Transform::contracting`] attains it), so where `α + |β| ≥ 0`
//! boxes cannot shrink near the goal whatever the coordinates: the sets of a lightly damped
//! loop wrap and grow, and tubes do not reach the goal. Said before any run, so that a
//! verified share of 0 % has its cause named.
//!
//! What continuous time does about it (§7.1 item 8): the sets are kept in `K` frames, the
//! pair's own coordinates `z` and copies of them turned by `jπ/(2K)`, whose slabs clip each
//! other (item 7). Their meet is a polygon of `4K` sides around the turning set, which shrinks
//! at about `α + |β|·tan(π/(4K))`: [`Turning::frames`] picks the `K` that leaves two thirds of
//! the pair's own rate `α`.

use nalgebra::DMatrix;

use super::transform::{schur_blocks, Transform, TransformError};
use crate::filter::SafetyFilter;
use crate::scenario::Scenario;

/// Most frames [`Turning::frames`] picks (each bounds the network on its own slabs).
pub const MAX_FRAMES: usize = 8;

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

    /// `α + |β|·tan(π/(4K))`: about the rate of the meet of `K` frames turned by `π/(2K)`.
    pub fn rate_in(&self, frames: usize) -> f64 {
        let k = frames.max(1) as f64;
        self.alpha + self.beta.abs() * (std::f64::consts::PI / (4.0 * k)).tan()
    }

    /// The fewest frames (at least 2, at most [`MAX_FRAMES`]) whose meet shrinks at two thirds
    /// of `|α|` or faster: the frames cost in proportion, the rate's gain falls off.
    pub fn frames(&self) -> usize {
        (2..=MAX_FRAMES)
            .find(|&k| self.rate_in(k) <= self.alpha / 3.0)
            .unwrap_or(MAX_FRAMES)
    }
}

/// The coordinates of the turned frames: `R_j·T` for `j = 1 … frames − 1`, `R_j` turning each
/// complex pair of `T A T⁻¹` (its 2 × 2 diagonal blocks with complex eigenvalues, as
/// [`Transform::contracting`] makes them) by `jπ/(2·frames)` and leaving the other coordinates.
/// A pair's block `[[α, β], [−β, α]]` commutes with turns: each frame is as good alone as `T`.
/// An error where `T A T⁻¹` has no such block (nothing turns).
pub fn turned(t: &Transform, a: &[f64], frames: usize) -> Result<Vec<Transform>, TransformError> {
    let n = t.n;
    // `T A T⁻¹` is block triangular in these coordinates: its pairs are the blocks the Schur
    // form's reading finds.
    let pairs: Vec<usize> = schur_blocks(&DMatrix::from_row_slice(n, n, &t.conjugate(a)))
        .into_iter()
        .filter(|&(_, size)| size == 2)
        .map(|(i, _)| i)
        .collect();
    if pairs.is_empty() {
        return Err(TransformError::NoPair);
    }
    (1..frames)
        .map(|j| {
            let phi = j as f64 * std::f64::consts::PI / (2.0 * frames as f64);
            let (c, s) = (phi.cos(), phi.sin());
            let mut rt = t.t.clone();
            for &p in &pairs {
                for col in 0..n {
                    let (u, v) = (t.t[p * n + col], t.t[(p + 1) * n + col]);
                    rt[p * n + col] = c * u - s * v;
                    rt[(p + 1) * n + col] = s * u + c * v;
                }
            }
            Transform::from_matrix(rt, n)
        })
        .collect()
}

impl std::fmt::Display for Turning {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "the closed loop at the goal turns sets at least as fast as it shrinks them \
             (eigenvalues {a:.3} ± {b:.3}i): in any one frame of coordinates boxes cannot shrink \
             there (at best α + |β| = {r:.3} ≥ 0); continuous time keeps the sets in frames \
             turned about the pair as well, whose meet can (reach.turned_frames), but in \
             `euler` and `sampled` tubes hardly reach the goal; more damping in the nominal \
             controller (|α| > |β|) lets boxes shrink in one frame",
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
    fn turned_frames_turn_the_pair_alone_and_keep_its_rate() {
        // A pair and a real eigenvalue: ẍ = −x − 0.7ẋ, ẏ = −2y.
        let a = vec![0.0, 1.0, 0.0, -1.0, -0.7, 0.0, 0.0, 0.0, -2.0];
        let t = Transform::contracting(&a, 3).unwrap();
        let turned = turned(&t, &a, 3).unwrap();
        assert_eq!(turned.len(), 2);
        let rate = |t: &Transform| super::super::log_norm_inf(&t.conjugate(&a), 3);
        for r in &turned {
            // As good as T alone, the real coordinate untouched.
            assert!(
                (rate(r) - rate(&t)).abs() < 1e-9,
                "{} {}",
                rate(r),
                rate(&t)
            );
            assert_eq!(r.t[6..], t.t[6..]);
        }
        // Nothing turns on a loop with real eigenvalues.
        let real = vec![-1.0, 0.5, 0.0, -2.0];
        let t = Transform::from_matrix(vec![1.0, 0.0, 0.0, 1.0], 2).unwrap();
        assert!(matches!(turned_err(&t, &real), TransformError::NoPair));
        // Frames picked: −0.5 ± 0.97i needs 3, −0.8 ± 0.97i 2, −0.05 ± i the most.
        let pick = |alpha: f64, beta: f64| Turning { alpha, beta }.frames();
        assert_eq!(
            (pick(-0.5, 0.968), pick(-0.8, 0.968), pick(-0.05, 1.0)),
            (3, 2, 8)
        );
    }

    /// A pair that turns, driving a real mode: the `auto` coordinates stop scaling within 1 %
    /// of the pair's own rate (they scaled by 2⁴⁰ before, and no enclosure closed in them).
    #[test]
    fn auto_coordinates_of_a_turning_pair_stay_well_scaled() {
        // θ̈ = −1.19θ − ω̇…: −0.5 ± 0.97i; ẏ = −2y + 0.5θ.
        let a = vec![0.0, 1.0, 0.0, -1.19, -1.0, 0.0, 0.5, 0.0, -2.0];
        let t = Transform::contracting(&a, 3).unwrap();
        let largest = t.t.iter().chain(&t.s).fold(0.0_f64, |m, v| m.max(v.abs()));
        assert!(largest < 1e3, "{:?}", t.t);
        let rate = super::super::log_norm_inf(&t.conjugate(&a), 3);
        let pair = Turning::of(&a, 3).unwrap().box_rate();
        assert!(
            rate <= pair * 1.0101 && rate >= pair - 1e-9,
            "{rate} against {pair}"
        );
    }

    fn turned_err(t: &Transform, a: &[f64]) -> TransformError {
        turned(t, a, 2).err().unwrap()
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
