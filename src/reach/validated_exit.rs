//! Item 1e of [`super`]'s argument: a proof that some trajectory from a step's set leaves `C`
//! within a time `T`. Every enclosure within `C` of a step longer than `T` then fails (item 1b
//! would put that trajectory in `B ⊆ C` over the whole step), so [`super::enclose_within`]
//! skips their tries (a failing enclosure costs 100–230 network bounds, for the same "no
//! enclosure" at the same time).
//!
//! Why it is sound: let `x*` be a point of the set proven in `S`, on its end nearest a side of
//! `C` (say `xᵢ = C̄ᵢ`), and `R` the box from `x*` to that side in `xᵢ` and `x*ⱼ ± wⱼ` in every
//! other coordinate. Let `F(R)` bound the filtered field on `R ∩ S` with `F̲ᵢ(R) = L > 0`,
//! `Mⱼ = max|Fⱼ(R)|`, and `T ≥ (C̄ᵢ − x*ᵢ)/L` with `T·Mⱼ < wⱼ`. The trajectory from `x*` stays in
//! `S`; while it is in `R`, `xᵢ` grows at rate ≥ `L` and `|xⱼ − x*ⱼ| ≤ t·Mⱼ`, so it cannot leave `R`
//! through a side `j` before `T`, nor through `xᵢ = x*ᵢ`: it meets `xᵢ = C̄ᵢ` by time `T`, moving
//! out at rate ≥ `L`, and is outside `C` right after. The filtered system's trajectories from the
//! set are what an enclosure holds (item 1), so no enclosure within `C` of a step longer than
//! `T` closes. Mirrored for `x̲ᵢ`; outward rounding throughout.

use super::{point, sweep, FieldOn};
use crate::boxes::IntervalBox;
use crate::rounding::{round_down, round_up};

/// An upper bound on the time some trajectory from `set` takes to leave `region` (`C`), where
/// one is proven: for each side of `C` that the set's sweep over `h` by the field's estimate
/// (`guess`, else `field` on the set) crosses, but not at a wall of `S` (`walls`), [`side_exit`];
/// the least. `safe(x)`: whether the point `x` is proven in `S`.
pub(super) fn exit_time<E>(
    set: &IntervalBox,
    h: f64,
    guess: Option<(&[f64], &[f64])>,
    region: &IntervalBox,
    walls: Option<&IntervalBox>,
    safe: &dyn Fn(&[f64]) -> bool,
    field: &mut FieldOn<'_, E>,
) -> Result<Option<f64>, E> {
    let (lo, hi) = match guess {
        Some((l, u)) => (l.to_vec(), u.to_vec()),
        None => match field(set, false)? {
            Some(f) => f,
            None => return Ok(None),
        },
    };
    let reach = sweep(set, h, &lo, &hi);
    let mut least: Option<f64> = None;
    for i in 0..set.dim() {
        for up in [false, true] {
            let crosses = match up {
                true => reach.upper[i] > region.upper[i],
                false => reach.lower[i] < region.lower[i],
            };
            // No trajectory leaves through a side of `C` on or beyond a wall of `S` (item 1f).
            let walled = walls.is_some_and(|w| match up {
                true => region.upper[i] >= w.upper[i],
                false => region.lower[i] <= w.lower[i],
            });
            if !crosses || walled {
                continue;
            }
            let estimate = (&lo[..], &hi[..]);
            if let Some(t) = side_exit(set, h, estimate, region, (i, up), safe, field)? {
                least = Some(least.map_or(t, |l: f64| l.min(t)));
            }
        }
    }
    Ok(least)
}

/// The module's argument on one side `(i, up)` of `C`: `x*` the set's end there and, in the
/// other coordinates, its midpoint, lower or upper end (the first that proves it); `wⱼ` twice
/// the estimated motion over `h`. `T`, or `None` where the field on `R` does not prove it.
fn side_exit<E>(
    set: &IntervalBox,
    h: f64,
    estimate: (&[f64], &[f64]),
    region: &IntervalBox,
    (i, up): (usize, bool),
    safe: &dyn Fn(&[f64]) -> bool,
    field: &mut FieldOn<'_, E>,
) -> Result<Option<f64>, E> {
    let n = set.dim();
    let at = [
        |l: f64, u: f64| 0.5 * (l + u),
        |l: f64, _: f64| l,
        |_: f64, u: f64| u,
    ];
    for pick in at {
        let mut x: Vec<f64> = (0..n).map(|j| pick(set.lower[j], set.upper[j])).collect();
        x[i] = match up {
            true => set.upper[i],
            false => set.lower[i],
        };
        if let Some(t) = point_exit(&x, h, estimate, region, (i, up), safe, field)? {
            return Ok(Some(t));
        }
        if n == 1 {
            break;
        }
    }
    Ok(None)
}

/// [`side_exit`] from the point `x` of the set.
fn point_exit<E>(
    x: &[f64],
    h: f64,
    (lo, hi): (&[f64], &[f64]),
    region: &IntervalBox,
    (i, up): (usize, bool),
    safe: &dyn Fn(&[f64]) -> bool,
    field: &mut FieldOn<'_, E>,
) -> Result<Option<f64>, E> {
    let n = x.len();
    if !safe(x) {
        return Ok(None);
    }
    let mut w = vec![0.0; n];
    let mut r = IntervalBox {
        lower: x.to_vec(),
        upper: x.to_vec(),
    };
    for j in 0..n {
        if j == i {
            match up {
                true => r.upper[i] = region.upper[i],
                false => r.lower[i] = region.lower[i],
            }
            continue;
        }
        w[j] = 2.0 * h * lo[j].abs().max(hi[j].abs()) + 1e-9 * (1.0 + x[j].abs());
        // Rounded outward: `R`'s side `j` lies at least `wⱼ` from `x*`.
        r.lower[j] = round_down(x[j] - w[j]);
        r.upper[j] = round_up(x[j] + w[j]);
    }
    if r.lower[i] > r.upper[i] {
        return Ok(None);
    }
    let Some((fl, fu)) = field(&r, false)? else {
        return Ok(None);
    };
    // The least speed towards the side, and the distance to it (rounded up).
    let (rate, d) = match up {
        true => (fl[i], (point(region.upper[i]) - point(x[i])).upper),
        false => (-fu[i], (point(x[i]) - point(region.lower[i])).upper),
    };
    if !(rate > 0.0 && d >= 0.0) {
        return Ok(None);
    }
    let t = (point(d) / point(rate)).upper;
    let stays = (0..n).filter(|&j| j != i).all(|j| {
        let m = fl[j].abs().max(fu[j].abs());
        (point(t) * point(m)).upper < w[j]
    });
    Ok((stays && t.is_finite()).then_some(t))
}
