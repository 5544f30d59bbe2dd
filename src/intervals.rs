//! Closed intervals of `f64` with outward rounding (docs/design.md §3).
//! Imports only [`crate::rounding`], whose primitives round every end outward.
//!
//! An [`Interval`] `X = [x̲, x̄]` stands for the set `{x ∈ ℝ : x̲ ≤ x ≤ x̄}`; infinite ends are
//! allowed ([`Interval::ENTIRE`] is `ℝ`), and a slice `&[Interval]` is a box. Every operation `∘`
//! returns an interval containing `{x ∘ y : x ∈ X, y ∈ Y}` (the inclusion property), floating-point
//! error included (the rounding model is [`crate::rounding`]'s):
//!
//! - `+ − × ÷ √` are correctly rounded (IEEE 754), so the exact end lies within one ulp of the
//!   computed one: each end moves one step outward with [`round_down`] / [`round_up`] (sums keep
//!   an end that TwoSum shows exact).
//! - `exp ln sin cos tanh` come from the platform libm, which is *not* correctly rounded (glibc
//!   states ≤ 1–2 ulp); their ends move outward by a relative `2⁻⁵⁰` (≥ 4 ulp) plus the smallest
//!   normal number, then one more step. `sin cos tanh` are then clamped to `[−1, 1]`.
//! - `[a, b]·[c, d] = [min P, max P]`, `P = {ac, ad, bc, bd}`, with `0·∞ = 0` (an infinite end means
//!   "unbounded"; the real 0 times any real is 0).
//! - Division by an interval that contains 0 gives [`Interval::ENTIRE`], as does an odd negative
//!   power of one. Even powers are tight: `[−1, 2]² = [0, 4]`, `[−1, 2]⁻² = [1/4, +∞]`. Integer
//!   powers multiply by repeated squaring, rounding every product outward;
//!   [`crate::rounding::pow_int`] is the same sequence rounded to nearest, so it always lies in
//!   [`Interval::powi`] of a point.
//! - `sin`/`cos`: monotone between extrema, so the range is the hull of the end values, with the
//!   upper end 1 if `X` holds a maximiser (`π/2 + 2kπ` for sin, `2kπ` for cos) and the lower end −1
//!   if it holds a minimiser; the test errs towards "holds". Width ≥ 2π gives `[−1, 1]`.
//! - `sqrt` and `ln` clip the part of the argument below their domain; an argument entirely outside
//!   gives the *NaN interval* (both ends NaN, [`Interval::NAN`]), which callers detect with
//!   [`Interval::is_nan`]. NaN ends propagate through every operation.

use crate::rounding::{
    add_down_tight, add_up_tight, pow_down, pow_up, round_down, round_up, widen_down, widen_up,
};
use serde::{Deserialize, Serialize};
use std::f64::consts::{FRAC_PI_2, PI, TAU};
use std::fmt;
use std::ops::{Add, Div, Mul, Neg, Sub};

/// A closed interval `[lower, upper]` (possibly unbounded, or NaN; see the module docs).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Interval {
    /// Lower end.
    pub lower: f64,
    /// Upper end.
    pub upper: f64,
}

/// `a·b` with `0·∞ = 0`.
fn mul_ends(a: f64, b: f64) -> f64 {
    if a == 0.0 || b == 0.0 {
        0.0
    } else {
        a * b
    }
}

/// The hull of four end candidates, rounded outward.
fn outward_hull(p: [f64; 4]) -> Interval {
    let lo = p.iter().fold(f64::INFINITY, |m, &v| m.min(v));
    let hi = p.iter().fold(f64::NEG_INFINITY, |m, &v| m.max(v));
    Interval {
        lower: round_down(lo),
        upper: round_up(hi),
    }
}

/// The box `[lower, upper]` as one interval a coordinate (exact: the ends are taken as they are).
pub fn box_of(lower: &[f64], upper: &[f64]) -> Vec<Interval> {
    debug_assert_eq!(lower.len(), upper.len());
    lower
        .iter()
        .zip(upper)
        .map(|(&l, &u)| Interval::new(l, u))
        .collect()
}

/// Is there an integer `k` with `x̲ ≤ phase + 2πk ≤ x̄`? Near misses count as hits (looser, never
/// unsound): the slack covers the rounding of the quotient and of the constants `π/2`, `π`, `2π`.
fn holds_lattice_point(x: Interval, phase: f64) -> bool {
    let t_lo = (x.lower - phase) / TAU;
    let t_hi = (x.upper - phase) / TAU;
    let slack = 1e-9 + 1e-12 * t_lo.abs().max(t_hi.abs());
    (t_lo - slack).ceil() <= (t_hi + slack).floor()
}

impl Interval {
    /// The whole real line `[−∞, +∞]`.
    pub const ENTIRE: Interval = Interval {
        lower: f64::NEG_INFINITY,
        upper: f64::INFINITY,
    };

    /// The NaN interval: the result of an operation entirely outside its domain.
    pub const NAN: Interval = Interval {
        lower: f64::NAN,
        upper: f64::NAN,
    };

    /// `[lower, upper]`; debug builds check `lower ≤ upper` (NaN ends are let through).
    pub fn new(lower: f64, upper: f64) -> Interval {
        debug_assert!(
            lower <= upper || lower.is_nan() || upper.is_nan(),
            "Interval::new({lower}, {upper}): lower > upper"
        );
        Interval { lower, upper }
    }

    /// The degenerate interval `[x, x]`.
    pub fn point(x: f64) -> Interval {
        Interval { lower: x, upper: x }
    }

    /// Whether either end is NaN (see [`Interval::NAN`]).
    pub fn is_nan(&self) -> bool {
        self.lower.is_nan() || self.upper.is_nan()
    }

    /// `x̄ − x̲`, rounded up (0 exactly for a point).
    pub fn width(&self) -> f64 {
        if self.lower == self.upper {
            0.0
        } else {
            round_up(self.upper - self.lower)
        }
    }

    /// The midpoint (approximately; 0 for [`Interval::ENTIRE`]).
    pub fn center(&self) -> f64 {
        if self.lower == self.upper {
            self.lower
        } else if self.lower == f64::NEG_INFINITY && self.upper == f64::INFINITY {
            0.0
        } else {
            0.5 * self.lower + 0.5 * self.upper
        }
    }

    /// A radius `r` with `[c − r, c + r] ⊇ X` for `c = self.center()`, rounded up.
    pub fn radius(&self) -> f64 {
        if self.lower == self.upper {
            return 0.0;
        }
        let c = self.center();
        round_up(self.upper - c).max(round_up(c - self.lower))
    }

    /// Whether `x ∈ X`.
    pub fn contains(&self, x: f64) -> bool {
        self.lower <= x && x <= self.upper
    }

    /// Whether `X ⊆ other`.
    pub fn is_subset_of(&self, other: &Interval) -> bool {
        other.lower <= self.lower && self.upper <= other.upper
    }

    /// The smallest interval containing both.
    pub fn hull(&self, other: &Interval) -> Interval {
        if self.is_nan() || other.is_nan() {
            return Interval::NAN;
        }
        Interval {
            lower: self.lower.min(other.lower),
            upper: self.upper.max(other.upper),
        }
    }

    /// `X ∩ Y`, or `None` when they are disjoint (or either is NaN).
    pub fn intersection(&self, other: &Interval) -> Option<Interval> {
        let lower = self.lower.max(other.lower);
        let upper = self.upper.min(other.upper);
        (lower <= upper && !self.is_nan() && !other.is_nan()).then_some(Interval { lower, upper })
    }

    /// The magnitude `max{|x| : x ∈ X}`.
    pub fn mag(&self) -> f64 {
        self.lower.abs().max(self.upper.abs())
    }

    /// `X^n`, tight for even `n` (`[−1, 2]² = [0, 4]`); negative powers take the reciprocal (an
    /// odd negative power of an interval holding 0 is [`Interval::ENTIRE`]); `X⁰ = [1, 1]`.
    pub fn powi(self, n: i32) -> Interval {
        if n == 0 {
            return Interval::point(1.0);
        }
        if self.is_nan() {
            return Interval::NAN;
        }
        let m = n.unsigned_abs();
        let (l, u) = (self.lower, self.upper);
        let p = if m & 1 == 0 {
            let mig = if self.contains(0.0) {
                0.0
            } else {
                l.abs().min(u.abs())
            };
            Interval {
                lower: pow_down(mig, m),
                upper: pow_up(self.mag(), m),
            }
        } else {
            Interval {
                lower: if l >= 0.0 {
                    pow_down(l, m)
                } else {
                    -pow_up(-l, m)
                },
                upper: if u >= 0.0 {
                    pow_up(u, m)
                } else {
                    -pow_down(-u, m)
                },
            }
        };
        if n > 0 {
            p
        } else if m & 1 == 0 && p.lower == 0.0 {
            Interval {
                lower: round_down(1.0 / p.upper).max(0.0),
                upper: f64::INFINITY,
            }
        } else {
            Interval::point(1.0) / p
        }
    }

    /// `X²` (tight).
    pub fn sqr(self) -> Interval {
        self.powi(2)
    }

    /// `√X` over `X ∩ [0, ∞)`; NaN interval if `X < 0`.
    pub fn sqrt(self) -> Interval {
        if self.is_nan() || self.upper < 0.0 {
            return Interval::NAN;
        }
        Interval {
            lower: round_down(self.lower.max(0.0).sqrt()).max(0.0),
            upper: round_up(self.upper.sqrt()),
        }
    }

    /// `exp X`.
    pub fn exp(self) -> Interval {
        Interval {
            lower: widen_down(self.lower.exp()).max(0.0),
            upper: widen_up(self.upper.exp()),
        }
    }

    /// `ln X` over `X ∩ [0, ∞)` (`ln 0 = −∞`); NaN interval if `X < 0`.
    pub fn ln(self) -> Interval {
        if self.is_nan() || self.upper < 0.0 {
            return Interval::NAN;
        }
        Interval {
            lower: if self.lower <= 0.0 {
                f64::NEG_INFINITY
            } else {
                widen_down(self.lower.ln())
            },
            upper: widen_up(self.upper.ln()),
        }
    }

    /// Range of a `2π`-periodic `f` with maximisers `peak + 2kπ` and minimisers `trough + 2kπ`.
    fn periodic(self, f: fn(f64) -> f64, peak: f64, trough: f64) -> Interval {
        if self.is_nan() {
            return Interval::NAN;
        }
        let (l, u) = (self.lower, self.upper);
        if !(l.is_finite() && u.is_finite()) || u - l >= TAU {
            return Interval::new(-1.0, 1.0);
        }
        let (fl, fu) = (f(l), f(u));
        Interval {
            lower: if holds_lattice_point(self, trough) {
                -1.0
            } else {
                widen_down(fl.min(fu)).max(-1.0)
            },
            upper: if holds_lattice_point(self, peak) {
                1.0
            } else {
                widen_up(fl.max(fu)).min(1.0)
            },
        }
    }

    /// `sin X`.
    pub fn sin(self) -> Interval {
        self.periodic(f64::sin, FRAC_PI_2, -FRAC_PI_2)
    }

    /// `cos X`.
    pub fn cos(self) -> Interval {
        self.periodic(f64::cos, 0.0, PI)
    }

    /// `tanh X`.
    pub fn tanh(self) -> Interval {
        Interval {
            lower: widen_down(self.lower.tanh()).max(-1.0),
            upper: widen_up(self.upper.tanh()).min(1.0),
        }
    }

    /// `atan X` (increasing).
    pub fn atan(self) -> Interval {
        if self.is_nan() {
            return Interval::NAN;
        }
        Interval::new(widen_down(self.lower.atan()), widen_up(self.upper.atan()))
    }

    /// `atan2(Y, X)` for `self = Y` and `other = X`. Off the cut `{x ≤ 0, y = 0}` it is
    /// continuous with no critical point (its gradient `(x, −y)/r²` vanishes nowhere) and
    /// monotone along every edge of the box, so its range is the corners'; a box meeting the
    /// cut (the origin included) gets `[−π, π]`.
    pub fn atan2(self, other: Interval) -> Interval {
        let (y, x) = (self, other);
        if y.is_nan() || x.is_nan() {
            return Interval::NAN;
        }
        if x.lower <= 0.0 && y.lower <= 0.0 && 0.0 <= y.upper {
            return Interval::new(widen_down(-PI), widen_up(PI));
        }
        let corners = [
            y.lower.atan2(x.lower),
            y.lower.atan2(x.upper),
            y.upper.atan2(x.lower),
            y.upper.atan2(x.upper),
        ];
        let lo = corners.iter().fold(f64::INFINITY, |m, &v| m.min(v));
        let hi = corners.iter().fold(f64::NEG_INFINITY, |m, &v| m.max(v));
        Interval::new(widen_down(lo), widen_up(hi))
    }

    /// `|X|` (exact).
    pub fn abs(self) -> Interval {
        if self.is_nan() {
            Interval::NAN
        } else if self.lower >= 0.0 {
            self
        } else if self.upper <= 0.0 {
            -self
        } else {
            Interval::new(0.0, self.mag())
        }
    }

    /// `{min(x, y)}` (exact).
    pub fn min(self, other: Interval) -> Interval {
        if self.is_nan() || other.is_nan() {
            return Interval::NAN;
        }
        Interval::new(self.lower.min(other.lower), self.upper.min(other.upper))
    }

    /// `{max(x, y)}` (exact).
    pub fn max(self, other: Interval) -> Interval {
        if self.is_nan() || other.is_nan() {
            return Interval::NAN;
        }
        Interval::new(self.lower.max(other.lower), self.upper.max(other.upper))
    }
}

impl From<f64> for Interval {
    fn from(x: f64) -> Interval {
        Interval::point(x)
    }
}

impl fmt::Display for Interval {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "[{}, {}]", self.lower, self.upper)
    }
}

impl Neg for Interval {
    type Output = Interval;
    fn neg(self) -> Interval {
        Interval {
            lower: -self.upper,
            upper: -self.lower,
        }
    }
}

impl Add for Interval {
    type Output = Interval;
    fn add(self, rhs: Interval) -> Interval {
        Interval {
            lower: add_down_tight(self.lower, rhs.lower),
            upper: add_up_tight(self.upper, rhs.upper),
        }
    }
}

impl Sub for Interval {
    type Output = Interval;
    fn sub(self, rhs: Interval) -> Interval {
        Interval {
            lower: add_down_tight(self.lower, -rhs.upper),
            upper: add_up_tight(self.upper, -rhs.lower),
        }
    }
}

impl Mul for Interval {
    type Output = Interval;
    fn mul(self, rhs: Interval) -> Interval {
        if self.is_nan() || rhs.is_nan() {
            return Interval::NAN;
        }
        let (a, b, c, d) = (self.lower, self.upper, rhs.lower, rhs.upper);
        outward_hull([
            mul_ends(a, c),
            mul_ends(a, d),
            mul_ends(b, c),
            mul_ends(b, d),
        ])
    }
}

impl Div for Interval {
    type Output = Interval;
    /// `X / Y`; [`Interval::ENTIRE`] when `0 ∈ Y`.
    fn div(self, rhs: Interval) -> Interval {
        if self.is_nan() || rhs.is_nan() {
            return Interval::NAN;
        }
        if rhs.contains(0.0) {
            return Interval::ENTIRE;
        }
        let (a, b, c, d) = (self.lower, self.upper, rhs.lower, rhs.upper);
        let q = [a / c, a / d, b / c, b / d];
        if q.iter().any(|v| v.is_nan()) {
            // ∞/∞: both unbounded; give up rather than guess.
            return Interval::ENTIRE;
        }
        outward_hull(q)
    }
}

/// `Interval ∘ f64` and `f64 ∘ Interval` through [`Interval::point`].
macro_rules! scalar_ops {
    ($($tr:ident $method:ident),*) => {$(
        impl $tr<f64> for Interval {
            type Output = Interval;
            fn $method(self, rhs: f64) -> Interval {
                self.$method(Interval::point(rhs))
            }
        }
        impl $tr<Interval> for f64 {
            type Output = Interval;
            fn $method(self, rhs: Interval) -> Interval {
                Interval::point(self).$method(rhs)
            }
        }
    )*};
}
scalar_ops!(Add add, Sub sub, Mul mul, Div div);

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rounding::pow_int;

    /// Sums are outward rounded only when inexact: checked against exact integer arithmetic
    /// (every f64 of magnitude ≥ 2⁵³ is an integer, so i128 holds the exact sums).
    #[test]
    fn sums_are_exact_when_exact_and_enclosing_otherwise() {
        let mut seed = 0x9E37_79B9_7F4A_7C15_u64;
        let mut next = || {
            seed ^= seed << 13;
            seed ^= seed >> 7;
            seed ^= seed << 17;
            seed
        };
        let (mut exact, mut widened) = (0, 0);
        for _ in 0..20_000 {
            let a = ((next() >> 2) | 1 << 61) as f64;
            let b = ((next() >> 3) | 1 << 60) as f64;
            let b = if next() % 2 == 0 { b } else { -b };
            let truth = a as i128 + b as i128;
            let x = Interval::point(a) + Interval::point(b);
            assert!(
                x.lower as i128 <= truth && truth <= x.upper as i128,
                "{a} + {b}"
            );
            let y = Interval::point(a) - Interval::point(-b);
            assert_eq!((x.lower, x.upper), (y.lower, y.upper));
            if x.lower == x.upper {
                assert_eq!(x.lower as i128, truth);
                exact += 1;
            } else {
                widened += 1;
            }
        }
        assert!(
            exact > 1000 && widened > 1000,
            "{exact} exact, {widened} widened"
        );
        let z = Interval::point(-2.0) - Interval::point(-2.0);
        assert_eq!((z.lower, z.upper), (0.0, 0.0));
    }
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    /// A random interval with lower end in `[−span, span]` and a width that is sometimes 0.
    fn random_interval(rng: &mut ChaCha8Rng, span: f64, max_width: f64) -> Interval {
        let lower = rng.random_range(-span..span);
        let width = match rng.random_range(0..4) {
            0 => 0.0,
            1 => rng.random_range(0.0..1e-6),
            _ => rng.random_range(0.0..max_width),
        };
        Interval::new(lower, lower + width)
    }

    /// Both ends and some random interior points.
    fn samples(rng: &mut ChaCha8Rng, x: Interval) -> Vec<f64> {
        let mut s = vec![x.lower, x.upper];
        s.extend((0..6).map(|_| x.lower + rng.random::<f64>() * (x.upper - x.lower)));
        s.retain(|v| x.contains(*v));
        s
    }

    fn assert_encloses(name: &str, result: Interval, value: f64, inputs: &[Interval]) {
        if value.is_nan() {
            return;
        }
        assert!(
            result.contains(value),
            "{name}{inputs:?} = {result:?} misses {value:e}"
        );
    }

    #[test]
    fn unary_operations_enclose_sampled_points() {
        type Unary = (&'static str, fn(Interval) -> Interval, fn(f64) -> f64);
        let ops: [Unary; 10] = [
            ("neg", |x| -x, |x| -x),
            ("sqr", Interval::sqr, |x| x * x),
            ("sqrt", Interval::sqrt, f64::sqrt),
            ("exp", Interval::exp, f64::exp),
            ("ln", Interval::ln, f64::ln),
            ("sin", Interval::sin, f64::sin),
            ("cos", Interval::cos, f64::cos),
            ("tanh", Interval::tanh, f64::tanh),
            ("abs", Interval::abs, f64::abs),
            ("recip", |x| 1.0 / x, |x| 1.0 / x),
        ];
        let mut rng = ChaCha8Rng::seed_from_u64(1);
        for _ in 0..3000 {
            let x = random_interval(&mut rng, 12.0, 8.0);
            for (name, op, f) in ops {
                let r = op(x);
                for p in samples(&mut rng, x) {
                    assert_encloses(name, r, f(p), &[x]);
                }
            }
            for n in -5..=6 {
                let r = x.powi(n);
                for p in samples(&mut rng, x) {
                    assert_encloses("powi", r, pow_int(p, n), &[x]);
                    let exact_ish = p.powi(n);
                    if exact_ish.is_finite() && r.lower.is_finite() && r.upper.is_finite() {
                        let slack = 1e-12 * exact_ish.abs();
                        assert!(r.lower - slack <= exact_ish && exact_ish <= r.upper + slack);
                    }
                }
            }
        }
    }

    #[test]
    fn binary_operations_enclose_sampled_points() {
        type Binary = (
            &'static str,
            fn(Interval, Interval) -> Interval,
            fn(f64, f64) -> f64,
        );
        let ops: [Binary; 6] = [
            ("add", |x, y| x + y, |x, y| x + y),
            ("sub", |x, y| x - y, |x, y| x - y),
            ("mul", |x, y| x * y, |x, y| x * y),
            ("div", |x, y| x / y, |x, y| x / y),
            ("min", Interval::min, f64::min),
            ("max", Interval::max, f64::max),
        ];
        let mut rng = ChaCha8Rng::seed_from_u64(2);
        for _ in 0..3000 {
            let x = random_interval(&mut rng, 5.0, 4.0);
            let y = random_interval(&mut rng, 5.0, 4.0);
            let c = rng.random_range(-3.0..3.0);
            for (name, op, f) in ops {
                let r = op(x, y);
                let xs = samples(&mut rng, x);
                for &p in &xs {
                    for q in samples(&mut rng, y) {
                        assert_encloses(name, r, f(p, q), &[x, y]);
                    }
                }
                for &p in &xs {
                    assert_encloses(name, op(x, Interval::point(c)), f(p, c), &[x]);
                }
            }
            for p in samples(&mut rng, x) {
                assert_encloses("x*c", x * c, p * c, &[x]);
                assert_encloses("c-x", c - x, c - p, &[x]);
                assert_encloses("c/x", c / x, c / p, &[x]);
                assert_encloses("x+c", x + c, p + c, &[x]);
            }
        }
    }

    #[test]
    fn even_powers_are_tight() {
        let x = Interval::new(-1.0, 2.0);
        let sq = x.sqr();
        assert_eq!(sq.lower, 0.0);
        assert!((sq.upper - 4.0).abs() < 1e-12);
        let x4 = Interval::new(-3.0, -2.0).powi(4);
        assert!((x4.lower - 16.0).abs() < 1e-12 && (x4.upper - 81.0).abs() < 1e-12);
        let inv = x.powi(-2);
        assert!((inv.lower - 0.25).abs() < 1e-12 && inv.upper == f64::INFINITY);
        assert_eq!(x.powi(-1), Interval::ENTIRE);
        let cube = x.powi(3);
        assert!((cube.lower + 1.0).abs() < 1e-12 && (cube.upper - 8.0).abs() < 1e-12);
    }

    #[test]
    fn sin_and_cos_reach_their_extrema() {
        let s = Interval::new(0.0, PI).sin();
        assert_eq!(s.upper, 1.0);
        assert!(s.lower <= 0.0 && s.lower > -1e-12);
        let s = Interval::new(1.0, 2.0).sin();
        assert_eq!(s.upper, 1.0);
        assert!((s.lower - 1f64.sin().min(2f64.sin())).abs() < 1e-12);
        assert_eq!(Interval::new(4.0, 5.0).sin().lower, -1.0);
        assert_eq!(Interval::new(3.0, 3.5).cos().lower, -1.0);
        assert_eq!(Interval::new(-0.5, 0.1).cos().upper, 1.0);
        let c = Interval::new(13.0, 14.0).cos(); // 4π ≈ 12.57: no extremum inside
        assert!((c.lower - 14f64.cos()).abs() < 1e-12 && (c.upper - 13f64.cos()).abs() < 1e-12);
        assert_eq!(Interval::new(-0.1, 7.0).sin(), Interval::new(-1.0, 1.0));
        assert!(Interval::new(0.1, 0.2).sin().upper < 0.2);
    }

    #[test]
    fn division_by_interval_holding_zero_is_entire() {
        let x = Interval::new(1.0, 2.0);
        assert_eq!(x / Interval::new(-1.0, 1.0), Interval::ENTIRE);
        assert_eq!(x / Interval::new(0.0, 1.0), Interval::ENTIRE);
        assert_eq!(x / Interval::point(0.0), Interval::ENTIRE);
        let q = x / Interval::new(2.0, 4.0);
        assert!(q.contains(0.25) && q.contains(1.0) && q.width() < 0.75 + 1e-12);
    }

    #[test]
    fn domains_and_nan_propagation() {
        assert!(Interval::new(-2.0, -1.0).sqrt().is_nan());
        assert!(Interval::new(-2.0, -1.0).ln().is_nan());
        assert_eq!(Interval::new(-1.0, 4.0).sqrt().lower, 0.0);
        assert_eq!(Interval::new(-1.0, 1.0).ln().lower, f64::NEG_INFINITY);
        let nan = Interval::NAN;
        for r in [
            nan + Interval::point(1.0),
            nan * Interval::point(0.0),
            nan.sin(),
            nan.abs(),
        ] {
            assert!(r.is_nan());
        }
        assert!((Interval::ENTIRE * 0.0).mag() < 1e-300);
    }

    #[test]
    fn set_helpers() {
        let a = Interval::new(-1.0, 3.0);
        let b = Interval::new(2.0, 5.0);
        assert_eq!(a.hull(&b), Interval::new(-1.0, 5.0));
        assert_eq!(a.intersection(&b), Some(Interval::new(2.0, 3.0)));
        assert_eq!(a.intersection(&Interval::new(4.0, 5.0)), None);
        assert!(Interval::new(0.0, 1.0).is_subset_of(&a) && !b.is_subset_of(&a));
        assert_eq!(
            (a.center(), a.mag(), Interval::point(2.0).width()),
            (1.0, 3.0, 0.0)
        );
        assert!(a.width() >= 4.0 && a.radius() >= 2.0 && a.radius() < 2.0 + 1e-12);
    }
}
