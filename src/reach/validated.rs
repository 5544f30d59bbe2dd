//! The validated step of the embedding system in continuous time (issue 36, DESIGN §3 Time):
//! an a-priori enclosure of the step by Picard–Lindelöf, then the comparison principle on slabs.
//! Imports the embedding's field terms ([`super::embedding`]), intervals and boxes only.
//!
//! Why it is sound (for one coordinate frame; z = Tx is the same in z):
//!
//! 1. *Enclosure.* Let `F(A) = [F̲, F̄]` bound the filtered field on `A ∩ S` and
//!    `B = X + [0, h]·F(A)` (per coordinate `[x̲ᵢ + h·min(0, F̲ᵢ), x̄ᵢ + h·max(0, F̄ᵢ)]`). If `B`
//!    lies in the interior of `A`, every trajectory from `X` stays in `B` over `[t, t + h]`: let
//!    `t₁` be the last time up to which it stayed in `A`; up to `t₁` its derivative lies in
//!    `F(A)` (it stays in `S`, where the filter keeps it), so `x(t₁) ∈ B ⊂ int A`, and by
//!    continuity it stays in `A` a while longer — so `t₁ = t + h`, and `x([t, t + h]) ⊆ B`.
//!    *1b. Within `C`.* With `F(A ∩ C)` in place of `F(A)` the same holds where, in every
//!    coordinate, `B` lies strictly inside `A` or `A`'s side is `C`'s and the field points
//!    strictly into `C` on it: at `t₁` the state is then inside `A ∩ C` or on such a side, moving
//!    inward, and stays in `A ∩ C` a while longer. Bounds over `A ∩ S` may be taken as the hull
//!    of bounds over parts of `A`, dropping parts proven outside `S`.
//!    *1c.* A side of `A` that is `C`'s may be shown inward by the field's bound on `A`'s face
//!    there alone (the argument of 1b looks at the field on that face only); the trajectories
//!    then keep to `C`'s side of it, so `B`'s end there is clipped to it.
//!    *1d. Halving.* Where no candidate closes over `h` (or one meets no sound field), the first half is enclosed from `X`
//!    (`B₁ ⊇ x([t, t + h/2])`), then the second from `B₁` (which holds every state at
//!    `t + h/2`): `B₂ ⊇ x([t + h/2, t + h])`. Every trajectory then stays in `B₁ ∪ B₂` with its
//!    derivative in the hull of both halves' `F`, which is all items 2–4 use of `B` and `F(A)`.
//! 2. *Slabs.* Take `sᵢ ≥ sup{Fᵢ(x) : x ∈ B, xᵢ ∈ Iᵢ}` with the slab
//!    `Iᵢ = [x̄ᵢ + h·min(0, F̲ᵢ), x̄ᵢ + h·max(0, F̄ᵢ)]`, and `u(τ) = x̄ᵢ + τ(sᵢ + ε)`. A trajectory
//!    that first reaches `u` at `τ* ∈ [0, h]` does so at a state `x(τ*) ∈ B` whose `i`-th
//!    coordinate is at most `x̄ᵢ + τ*·F̄ᵢ` (it started below `x̄ᵢ` and moved at rate ≤ `F̄ᵢ`) and
//!    at least `x̄ᵢ + h·min(0, sᵢ) ≥ x̄ᵢ + h·min(0, F̲ᵢ)` (`sᵢ ≥ F̲ᵢ`: the slab meets `B` at
//!    `xᵢ = x̄ᵢ`): `x(τ*)` lies in the slab, so `ẋᵢ(τ*) ≤ sᵢ < u'`, and it cannot cross. With
//!    `ε → 0`, `xᵢ ≤ x̄ᵢ + τ·sᵢ` on the whole step; mirrored for `x̲ᵢ`. The embedding's face
//!    bounds (mean-value form, interaction-aware network forms, face-local network bounds, the
//!    filter's pieces and enclosures) apply unchanged with the slab `{x ∈ B, xᵢ ∈ Iᵢ}` in
//!    place of the face `{x ∈ X, xᵢ = x̄ᵢ}`, and every bound over a whole set with `B` in
//!    place of `X`. Slabs have width `O(h)`, so the loss per step is `O(h²)`.

use super::embedding::{input_enclosure, interaction_row, Dynamics, NetworkBoundsRef};
use super::safe_set::{clip_to_safe_set, SafeHalfspace};
use crate::boxes::IntervalBox;
use crate::intervals::Interval;

/// The enclosure of one step in one frame.
#[derive(Clone, Debug, PartialEq)]
pub struct Flowpipe {
    /// `B ⊇ x([t, t + h])` for every trajectory from the set.
    pub set: IntervalBox,
    /// `F̲(A)`: lower bounds of the field over the enclosure the closure was proven on.
    pub f_lower: Vec<f64>,
    /// `F̄(A)`.
    pub f_upper: Vec<f64>,
    /// Where the step checks a moving box ([`moving`]): its face rates and slab depths; then
    /// `set` is the moving box's hull, and the slabs are the moving faces' ([`slab`]).
    pub faces: Option<MovingFaces>,
    /// Whether Picard–Lindelöf proved an enclosure holding `set` with the field within
    /// `[f_lower, f_upper]` on it. False for a moving box guessed without one ([`guessed`]):
    /// its `f_*` are its face rates, and only [`verified`]'s strict check on its slabs proves it.
    pub enclosed: bool,
    /// The other frames' sets over the step, as half-spaces of this frame's coordinates
    /// (`ReachSettings::meet_slabs`; empty otherwise): every trajectory lies in them over the
    /// whole step, so each slab is clipped by them ([`slab`]; item 7 in docs/design.md §7.1).
    pub others: Vec<SafeHalfspace>,
}

/// The moving box `X(τ) = [x̲ + τ·s̲, x̄ + τ·s̄]`, `τ ∈ [0, h]`, of a step (item 3 of the module's
/// argument), with the depths of its slabs: `F̲ ≤ s̲ ≤ ρ̲` and `ρ̄ ≤ s̄ ≤ F̄` per coordinate.
#[derive(Clone, Debug, PartialEq)]
pub struct MovingFaces {
    /// `s̲`: the lower faces' rates.
    pub lower: Vec<f64>,
    /// `s̄`: the upper faces' rates.
    pub upper: Vec<f64>,
    /// `ρ̲`: the lower slabs reach up to `x̲ᵢ + h·max(0, ρ̲ᵢ)`.
    pub depth_lower: Vec<f64>,
    /// `ρ̄`: the upper slabs reach down to `x̄ᵢ + h·min(0, ρ̄ᵢ)`.
    pub depth_upper: Vec<f64>,
}

/// What [`enclose_step`] found.
// One a frame and step, moved at once into the box's state: boxing would allocate every step.
#[allow(clippy::large_enum_variant)]
#[derive(Clone, Debug)]
pub enum Enclosure {
    /// A flowpipe.
    Closed(Flowpipe),
    /// No sound field on a candidate (e.g. the error map has no finite bound there).
    NoField,
    /// Picard–Lindelöf did not close in its tries (`enclose::TRIES`), for the reason given.
    Open(OpenCause),
}

/// Why a step's a-priori enclosure did not close: what a user can do about it differs.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum OpenCause {
    /// The candidates grew faster than they closed, within `C`: the field's bounds over them
    /// are too wide for the step (a shorter step, or substeps, may close it).
    Grows,
    /// The candidates' sweep reached past a side of `C` where the field is not proven to point
    /// into `C`: states of the set may leave `C` within the step, or the field's bounds are too
    /// wide to rule it out (smaller boxes may; a shorter step does not help).
    PastC,
    /// A trajectory from the set provably leaves `C` within the step (design §7.1 item 1e).
    Exits,
    /// [`OpenCause::Exits`] on the first step in x, whose set is the initial box (met with
    /// `S`): trajectories from the initial box leave `C`. Set by the engine, which knows the
    /// frame (a set in `z = Tx` holds more than the box).
    ExitsFromStart,
}

pub(super) fn point(x: f64) -> Interval {
    Interval::point(x)
}

/// `X + [0, h]·[F̲, F̄]`, rounded outward (a side that does not move stays exactly where it
/// is: a side of `C` a candidate may close on).
fn sweep(set: &IntervalBox, h: f64, f_lower: &[f64], f_upper: &[f64]) -> IntervalBox {
    let lower = (0..set.dim())
        .map(|i| match f_lower[i] >= 0.0 {
            true => set.lower[i],
            false => (point(set.lower[i]) + point(h) * point(f_lower[i])).lower,
        })
        .collect();
    let upper = (0..set.dim())
        .map(|i| match f_upper[i] <= 0.0 {
            true => set.upper[i],
            false => (point(set.upper[i]) + point(h) * point(f_upper[i])).upper,
        })
        .collect();
    IntervalBox { lower, upper }
}

#[path = "validated_enclose.rs"]
mod enclose;
pub use enclose::{enclose_step, enclose_within, first_candidate, parts};

/// The field's bounds on a candidate, as [`enclose_step`] asks for them.
type FieldOn<'f, E> = dyn FnMut(&IntervalBox, bool) -> Result<Option<(Vec<f64>, Vec<f64>)>, E> + 'f;

#[path = "validated_exit.rs"]
mod exit;

/// The slab of coordinate `i` at the set's upper (`on_upper`) or lower end: the flowpipe with
/// `xᵢ` in `[e + h·min(0, F̲ᵢ), e + h·max(0, F̄ᵢ)]`, `e` that end, met with the flowpipe; for a
/// moving box ([`Flowpipe::faces`]) `xᵢ` in `[e + h·min(0, ρ̄ᵢ), e + h·max(0, s̄ᵢ)]` at the
/// upper end (`[e + h·min(0, s̲ᵢ), e + h·max(0, ρ̲ᵢ)]` at the lower), met with its hull.
pub fn slab(
    set: &IntervalBox,
    pipe: &Flowpipe,
    h: f64,
    i: usize,
    on_upper: bool,
) -> (Vec<f64>, Vec<f64>) {
    let end = if on_upper { set.upper[i] } else { set.lower[i] };
    let (down, up) = match (&pipe.faces, on_upper) {
        (None, _) => (pipe.f_lower[i], pipe.f_upper[i]),
        (Some(m), true) => (m.depth_upper[i], m.upper[i]),
        (Some(m), false) => (m.lower[i], m.depth_lower[i]),
    };
    let lo = (point(end) + point(h) * point(down.min(0.0))).lower;
    let hi = (point(end) + point(h) * point(up.max(0.0))).upper;
    let (mut lower, mut upper) = (pipe.set.lower.clone(), pipe.set.upper.clone());
    lower[i] = lo.max(pipe.set.lower[i]);
    upper[i] = hi.min(pipe.set.upper[i]);
    if lower[i] > upper[i] {
        // Only rounding can get here (the slab holds `e ∈ B`): keep the end itself.
        (lower[i], upper[i]) = (end, end);
    }
    // A state of the slab that a trajectory reaches lies in the other frames' sets too. An
    // empty meet (no trajectory reaches the slab) leaves the slab whole: any bound is sound.
    if !pipe.others.is_empty() {
        clip_to_safe_set(&mut lower, &mut upper, &pipe.others);
    }
    (lower, upper)
}

/// The lowest upper rate (`on_upper`) or highest lower rate the slab of coordinate `i` was
/// built for: `F̲ᵢ` (`F̄ᵢ`) for the whole enclosure's slabs, `ρ̄ᵢ` (`ρ̲ᵢ`) for a moving box's.
/// A rate past it reaches a state outside the slab, so rates are clamped to it.
pub(super) fn depth(pipe: &Flowpipe, i: usize, on_upper: bool) -> f64 {
    match (&pipe.faces, on_upper) {
        (None, true) => pipe.f_lower[i],
        (None, false) => pipe.f_upper[i],
        (Some(m), true) => m.depth_upper[i],
        (Some(m), false) => m.depth_lower[i],
    }
}

/// The moving box of a step from `set` (item 3 of the module's argument), its face rates
/// guessed from `rates`, last step's rates `(r̲, r̄)`: `s̄ = r̄ + δ`, `ρ̄ = r̄ − δ` with `δ` a tenth
/// of `F(A)`'s width, all within `pipe`'s `F(A)` (so the moving box's hull and slabs lie in
/// the enclosure `B` and every fact proven on `B` holds on them). `None` where the guess
/// turns the box inside out or is not finite. The step must then pass [`verified`].
pub fn moving(
    set: &IntervalBox,
    pipe: &Flowpipe,
    h: f64,
    (r_lower, r_upper): (&[f64], &[f64]),
) -> Option<Flowpipe> {
    let n = set.dim();
    let mut m = MovingFaces {
        lower: Vec::with_capacity(n),
        upper: Vec::with_capacity(n),
        depth_lower: Vec::with_capacity(n),
        depth_upper: Vec::with_capacity(n),
    };
    for i in 0..n {
        let (fl, fu) = (pipe.f_lower[i], pipe.f_upper[i]);
        let delta = 0.1 * (fu - fl);
        let s_lower = (r_lower[i] - delta).max(fl);
        let s_upper = (r_upper[i] + delta).min(fu);
        m.depth_lower
            .push((r_lower[i] + delta).min(fu).max(s_lower));
        m.depth_upper
            .push((r_upper[i] - delta).max(fl).min(s_upper));
        m.lower.push(s_lower);
        m.upper.push(s_upper);
    }
    let hull = moving_hull(set, h, &m)?;
    Some(Flowpipe {
        set: hull,
        f_lower: pipe.f_lower.clone(),
        f_upper: pipe.f_upper.clone(),
        faces: Some(m),
        enclosed: true,
        others: Vec::new(),
    })
}

/// The hull over the step of the box whose faces move from `set` at the rates `m`; `None`
/// where a rate or depth is not finite or the box turns inside out on the step (it is linear
/// in τ: its end decides).
fn moving_hull(set: &IntervalBox, h: f64, m: &MovingFaces) -> Option<IntervalBox> {
    let values = m.lower.iter().chain(&m.upper);
    if !values
        .chain(&m.depth_lower)
        .chain(&m.depth_upper)
        .all(|v| v.is_finite())
    {
        return None;
    }
    let ends = |i: usize| {
        let lo = point(set.lower[i]) + point(h) * point(m.lower[i]);
        let hi = point(set.upper[i]) + point(h) * point(m.upper[i]);
        (lo, hi)
    };
    if (0..set.dim()).any(|i| ends(i).0.upper > ends(i).1.lower) {
        return None;
    }
    Some(sweep(set, h, &m.lower, &m.upper))
}

/// A moving box of a step from `set` with no a-priori enclosure (docs/design.md §7.1, item
/// 3b): face rates guessed from last step's slab rates `(r̲, r̄)` and those of the step before
/// (`before`), `s̄ = max(r̄, r̂) + δ`, `ρ̄ = min(r̄, r̂) − δ` with `r̂ = 2r̄ − r̄_before` the
/// trend and `δ` a margin (`GUESS_MARGIN`; mirrored below). `None` where the box turns
/// inside out or a value is not finite. Nothing is known of it until [`verified`] passes on
/// every frame's rates, with the facts (piece, local `M`) taken on its hull. `guessed` in
/// `shaders/validated.wgsl` mirrors it (and [`slab`], [`verified`] of such a box).
pub fn guessed(
    set: &IntervalBox,
    h: f64,
    (r_lower, r_upper): (&[f64], &[f64]),
    before: Option<(&[f64], &[f64])>,
) -> Option<Flowpipe> {
    let n = set.dim();
    let mut m = MovingFaces {
        lower: Vec::with_capacity(n),
        upper: Vec::with_capacity(n),
        depth_lower: Vec::with_capacity(n),
        depth_upper: Vec::with_capacity(n),
    };
    for i in 0..n {
        let (rl, ru) = (r_lower[i], r_upper[i]);
        let (tl, tu) = match before {
            Some((bl, bu)) => (2.0 * rl - bl[i], 2.0 * ru - bu[i]),
            None => (rl, ru),
        };
        let delta = GUESS_MARGIN * ((ru - rl).abs() + rl.abs().max(ru.abs())) + 1e-9;
        m.lower.push(rl.min(tl) - delta);
        m.depth_lower.push(rl.max(tl) + delta);
        m.upper.push(ru.max(tu) + delta);
        m.depth_upper.push(ru.min(tu) - delta);
    }
    let hull = moving_hull(set, h, &m)?;
    Some(Flowpipe {
        set: hull,
        f_lower: m.lower.clone(),
        f_upper: m.upper.clone(),
        faces: Some(m),
        enclosed: false,
        others: Vec::new(),
    })
}

/// [`guessed`]'s margin around the guessed rates, as a share of their spread and size.
const GUESS_MARGIN: f64 = 0.05;

/// Whether the rates `(dl, du)` found on a moving box's slabs prove it (item 3): every face
/// moves faster than the field on its slab (`s̄ᵢ > du_i`, `s̲ᵢ < dl_i`), or at least as fast as
/// the field anywhere in `A` (`s̄ᵢ ≥ F̄ᵢ`: no trajectory can cross it). True for the whole
/// enclosure's slabs (Picard–Lindelöf proved them).
pub fn verified(pipe: &Flowpipe, (dl, du): (&[f64], &[f64])) -> bool {
    let Some(m) = &pipe.faces else {
        return true;
    };
    (0..dl.len()).all(|i| {
        // Without an enclosure only the strict check proves the box (design §7.1 item 3b).
        let upper = du[i] < m.upper[i] || (pipe.enclosed && m.upper[i] >= pipe.f_upper[i]);
        let lower = dl[i] > m.lower[i] || (pipe.enclosed && m.lower[i] <= pipe.f_lower[i]);
        upper && lower
    })
}

/// Every slab, in the order of the faces: (0, lower), (0, upper), (1, lower), …
pub fn slabs<'a>(
    set: &'a IntervalBox,
    pipe: &'a Flowpipe,
    h: f64,
) -> impl Iterator<Item = (Vec<f64>, Vec<f64>)> + 'a {
    (0..set.dim()).flat_map(move |i| [false, true].map(|up| slab(set, pipe, h, i, up)))
}

/// A bound of `Fᵢ` over the region `[lower, upper]` for `F = f̃ + g(N + w)`, `w ∈ [−M, M]`:
/// the lower end for `on_upper = false`, the upper end otherwise (the embedding's face bound,
/// with the region's `i`-th coordinate an interval too).
pub fn bound_on(
    dynamics: &Dynamics,
    lower: &[f64],
    upper: &[f64],
    i: usize,
    on_upper: bool,
    nn: NetworkBoundsRef,
    margin: &[f64],
) -> Interval {
    let n = dynamics.n;
    let p: Vec<f64> = (0..n)
        .map(|j| lower[j] + 0.5 * (upper[j] - lower[j]))
        .collect();
    let (mut total, slopes) = form_on(dynamics, lower, upper, &p, i, on_upper, nn, margin);
    for (j, k) in slopes.into_iter().enumerate() {
        total = total + k * (Interval::new(lower[j], upper[j]) - point(p[j]));
    }
    total
}

/// The form `Fᵢ(x) ∈ c + Σⱼ kⱼ(xⱼ − pⱼ)` behind [`bound_on`], valid for `x` in the box
/// `[lower, upper]` (within `S`) with `p` a point of the box: `(c, k)`. For constant `g = B` the
/// interaction-aware side's row is in `k` (the lower side's for `on_upper = false`); otherwise
/// `g`'s input term is in `c`.
#[allow(clippy::too_many_arguments)]
pub(super) fn form_on(
    dynamics: &Dynamics,
    lower: &[f64],
    upper: &[f64],
    p: &[f64],
    i: usize,
    on_upper: bool,
    nn: NetworkBoundsRef,
    margin: &[f64],
) -> (Interval, Vec<Interval>) {
    let at = form_at(dynamics, lower, upper, p, i);
    form_side(dynamics, &at, p, i, on_upper, nn, margin)
}

/// What [`form_on`]'s two sides share on one box and point: the box, `Df̃ᵢ` over it, `f̃ᵢ(p)`.
struct FormAt {
    x: Vec<Interval>,
    jac: Vec<Interval>,
    f_p: Interval,
}

/// [`FormAt`] of coordinate `i` on the box `[lower, upper]` at `p`.
fn form_at(dynamics: &Dynamics, lower: &[f64], upper: &[f64], p: &[f64], i: usize) -> FormAt {
    let x = crate::intervals::box_of(lower, upper);
    let p_box: Vec<Interval> = p.iter().map(|&v| point(v)).collect();
    let jac = dynamics.f_tilde_jacobian[i]
        .iter()
        .map(|e| e.eval_interval(&x))
        .collect();
    let f_p = dynamics.f_tilde[i].eval_interval(&p_box);
    FormAt { x, jac, f_p }
}

/// [`form_on`] of one side from what both share.
fn form_side(
    dynamics: &Dynamics,
    at: &FormAt,
    p: &[f64],
    i: usize,
    on_upper: bool,
    nn: NetworkBoundsRef,
    margin: &[f64],
) -> (Interval, Vec<Interval>) {
    let n = dynamics.n;
    let mut total = at.f_p;
    match &dynamics.g_constant {
        Some(b) => {
            let (row, delta) = interaction_row(b, dynamics, nn, margin, i, on_upper);
            for j in 0..n {
                total = total + row[j] * point(p[j]);
            }
            let slopes = (0..n).map(|j| at.jac[j] + row[j]).collect();
            (total + delta, slopes)
        }
        None => {
            for (k, u) in input_enclosure(nn, margin).into_iter().enumerate() {
                total = total + dynamics.g[i][k].eval_interval(&at.x) * u;
            }
            (total, at.jac.clone())
        }
    }
}

/// Bounds `[F̲, F̄]` of the field over the whole box `[lower, upper]` (for [`enclose_step`]):
/// per coordinate [`bound_on`]'s lower end and its upper end, the box's Jacobian and `f̃ᵢ` at its
/// centre evaluated once for both (the same operations as two calls, so the same bits).
pub fn field_over(
    dynamics: &Dynamics,
    lower: &[f64],
    upper: &[f64],
    nn: NetworkBoundsRef,
    margin: &[f64],
) -> (Vec<f64>, Vec<f64>) {
    let n = dynamics.n;
    let p: Vec<f64> = (0..n)
        .map(|j| lower[j] + 0.5 * (upper[j] - lower[j]))
        .collect();
    let (mut lo, mut hi) = (Vec::with_capacity(n), Vec::with_capacity(n));
    for i in 0..n {
        let at = form_at(dynamics, lower, upper, &p, i);
        let end = |on_upper: bool| {
            let (mut total, slopes) = form_side(dynamics, &at, &p, i, on_upper, nn, margin);
            for (j, k) in slopes.into_iter().enumerate() {
                total = total + k * (Interval::new(lower[j], upper[j]) - point(p[j]));
            }
            total
        };
        // Without a constant `g` the form does not depend on the side.
        let (l, u) = match dynamics.g_constant {
            Some(_) => (end(false), end(true)),
            None => {
                let both = end(false);
                (both, both)
            }
        };
        lo.push(l.lower);
        hi.push(u.upper);
    }
    (lo, hi)
}

/// The slab step's rates `(s̲, s̄)`: `s̲ᵢ` bounds `Fᵢ` from below on the lower slab of `i`, `s̄ᵢ`
/// from above on its upper slab; `nn(i, on_upper)` bounds the network there (over the slab
/// itself, or over the whole flowpipe). `x ← x + h·s` is then the validated step.
pub fn slab_field<'a>(
    dynamics: &Dynamics,
    set: &IntervalBox,
    pipe: &Flowpipe,
    h: f64,
    nn: impl Fn(usize, bool) -> NetworkBoundsRef<'a>,
    margin: &[f64],
) -> (Vec<f64>, Vec<f64>) {
    let n = dynamics.n;
    let side = |i: usize, up: bool| {
        let (lo, hi) = slab(set, pipe, h, i, up);
        bound_on(dynamics, &lo, &hi, i, up, nn(i, up), margin)
    };
    let mut dl: Vec<f64> = (0..n).map(|i| side(i, false).lower).collect();
    let mut du: Vec<f64> = (0..n).map(|i| side(i, true).upper).collect();
    clamp_to_depths(pipe, &mut dl, &mut du);
    (dl, du)
}

/// Slab rates `(dl, du)` kept within the depths their slabs were built for: `s̄ᵢ ≥ F̲ᵢ` and
/// `s̲ᵢ ≤ F̄ᵢ` hold for exact bounds (the slabs meet the flowpipe); kept so for any rounding, as
/// the argument needs (for a moving box: `≥ ρ̄ᵢ`, `≤ ρ̲ᵢ`, item 3). [`slab_field`]'s last step;
/// `slab_step_end` in `shaders/validated.wgsl` mirrors it.
pub fn clamp_to_depths(pipe: &Flowpipe, dl: &mut [f64], du: &mut [f64]) {
    for i in 0..dl.len() {
        du[i] = du[i].max(depth(pipe, i, true));
        dl[i] = dl[i].min(depth(pipe, i, false));
    }
}

/// After the step: the new set lies in the flowpipe too.
pub fn meet_with_pipe(lower: &mut [f64], upper: &mut [f64], pipe: &Flowpipe) {
    for i in 0..lower.len() {
        lower[i] = lower[i].max(pipe.set.lower[i]);
        upper[i] = upper[i].min(pipe.set.upper[i]);
    }
}

#[cfg(test)]
#[path = "validated_tests.rs"]
mod tests;
