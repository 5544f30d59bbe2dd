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
use crate::boxes::IntervalBox;
use crate::filter::SafetyFilter;
use crate::scenario::{Scenario, TransformChoice};

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

/// How far boxes at the goal grow before they shrink, in the scenario's coordinates: the box
/// embedding of the closed loop's linearisation `Λ = T A T⁻¹` (widths `ẇ = M w`, `Mᵢᵢ = Λᵢᵢ`,
/// `Mᵢⱼ = |Λᵢⱼ|`) from the z-image of an x-box of unit widths, read back in x (`|S| w`) against
/// its start. Where
/// `A` is far from normal (eigenvalues close together, strongly coupled modes: a cart-pole under
/// pole placement) the coordinates that contract in ℓ∞ pass the widest coordinate's width to the
/// others first, and the sets peak at several times their start before they shrink: the
/// nonlinear terms over those wider sets may then stop them. Said before any run.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Transient {
    /// The largest x-width over its start (at least 1).
    pub growth: f64,
    /// When it peaks.
    pub at: f64,
}

impl Transient {
    /// The transient of `A` (n×n, row-major) in the coordinates of `t` (x itself when `None`);
    /// `None` where the box embedding does not shrink the box to half its start within
    /// `10⁵` steps, or its widths grow past `10⁶` (boxes do not contract there: other diagnoses
    /// say why).
    pub fn of(a: &[f64], t: Option<&Transform>, n: usize) -> Option<Transient> {
        if n == 0 || a.len() != n * n || a.iter().any(|v| !v.is_finite()) {
            return None;
        }
        let lambda = t.map_or_else(|| a.to_vec(), |t| t.conjugate(a));
        let m: Vec<f64> = (0..n * n)
            .map(|k| match k / n == k % n {
                true => lambda[k],
                false => lambda[k].abs(),
            })
            .collect();
        // The z-widths of the unit x-box (centred: widths are all that matter), and the
        // x-width of a z-box of widths `w`, by the transform's own maps.
        let half =
            |w: &[f64], sign: f64| -> Vec<f64> { w.iter().map(|v| sign * 0.5 * v).collect() };
        let unit = IntervalBox {
            lower: vec![-0.5; n],
            upper: vec![0.5; n],
        };
        let mut w = t.map_or_else(|| vec![1.0; n], |t| t.to_z_box(&unit).widths());
        let x_width = |w: &[f64]| -> f64 {
            let xs = match t {
                Some(t) => t.to_x_box(&half(w, -1.0), &half(w, 1.0)).widths(),
                None => w.to_vec(),
            };
            xs.into_iter().fold(0.0, f64::max)
        };
        let norm = (0..n)
            .map(|i| (0..n).map(|j| m[i * n + j].abs()).sum::<f64>())
            .fold(f64::MIN_POSITIVE, f64::max);
        let h = 0.05 / norm;
        let field = |w: &[f64]| -> Result<Vec<f64>, std::convert::Infallible> {
            Ok((0..n)
                .map(|i| (0..n).map(|j| m[i * n + j] * w[j]).sum())
                .collect())
        };
        // Against the z-image's own x-width: the wrap of a box into z and back is another
        // matter (with the meet with x-boxes, §2.11, the sets do not pay it).
        let start = x_width(&w);
        let mut peak = Transient {
            growth: 1.0,
            at: 0.0,
        };
        for step in 1..=100_000 {
            // RK4: the widths' linear ODE, to well within the figure's two digits.
            let Ok(next) = crate::simulate::rk4(&field, &w, h);
            w = next;
            let xw = x_width(&w) / start;
            // Widths that grow without end: boxes do not contract here at all.
            if !xw.is_finite() || xw > 1e6 {
                return None;
            }
            if xw > peak.growth {
                peak = Transient {
                    growth: xw,
                    at: step as f64 * h,
                };
            }
            if xw <= 0.5 {
                return Some(peak);
            }
        }
        None
    }

    /// Growth worth saying (`check` and every run say it from here).
    pub const NOTABLE: f64 = 2.0;

    /// The transient of the filtered closed loop's Jacobian at the goal's centre, in the
    /// coordinates `choice` gives (the scenario's `transform`, or a flag's), where it is
    /// [`Transient::NOTABLE`].
    pub fn at_goal(scenario: &Scenario, choice: &TransformChoice) -> Option<Transient> {
        let goal = scenario.reach.goal.center();
        let a = SafetyFilter::new(scenario)
            .closed_loop_jacobian(&goal)
            .ok()?;
        let t = Transform::for_scenario(scenario, choice).ok()?;
        Transient::of(&a, t.as_ref(), scenario.n()).filter(|t| t.growth >= Self::NOTABLE)
    }
}

impl std::fmt::Display for Transient {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "boxes at the goal grow to {g:.1}× their width (in x, at t = {t:.2}) before they \
             shrink, in the coordinates chosen: the closed loop's linearisation there is far \
             from normal, so sets must start small, and its nonlinear terms over the grown sets \
             may stop them (verify the goal's neighbourhood with small cells; modes of the \
             nominal controller farther apart shrink the transient)",
            g = self.growth,
            t = self.at,
        )
    }
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

    /// A cart-pole under pole placement (poles −2, −2.5, −3, −3.5; results.md) is far from
    /// normal: in the coordinates chosen for it boxes grow about tenfold before they shrink,
    /// while a loop with the same eigenvalues and uncoupled modes never grows, and an unstable
    /// one has no transient to speak of.
    #[test]
    fn a_far_from_normal_loop_grows_boxes_before_it_shrinks_them() {
        let (k1, k2, k3, k4) = (
            2.6758409785932717,
            34.503920489296654,
            4.064729867482161,
            7.532364933741073,
        );
        let cart_pole = [
            [0.0, 0.0, 1.0, 0.0],
            [0.0, 0.0, 0.0, 1.0],
            [k1, k2 - 0.981, k3, k4],
            [-2.0 * k1, 21.582 - 2.0 * k2, -2.0 * k3, -2.0 * k4],
        ]
        .concat();
        let t = Transform::contracting(&cart_pole, 4).unwrap();
        let grown = Transient::of(&cart_pole, Some(&t), 4).unwrap();
        assert!(grown.growth > 5.0 && grown.at > 0.1, "{grown:?}");
        let mut normal = vec![0.0; 16];
        for (i, l) in [-2.0, -2.5, -3.0, -3.5].into_iter().enumerate() {
            normal[i * 5] = l;
        }
        let flat = Transient::of(&normal, None, 4).unwrap();
        assert_eq!((flat.growth, flat.at), (1.0, 0.0));
        assert_eq!(Transient::of(&[0.5, 0.0, 0.0, -1.0], None, 2), None);
    }

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
