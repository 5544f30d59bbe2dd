//! The a-priori enclosure of a step (item 1 of [`super`]'s argument, items 1b–1f of the
//! design's §7.1): Picard–Lindelöf candidates from a guess or the set's own field, inflated and
//! retried, clipped to `C` and `S`'s walls, bounded whole or by parts, halved where they do not
//! close. A child of `reach::validated`.

use super::{exit, sweep, Enclosure, FieldOn, Flowpipe, OpenCause};
use crate::boxes::IntervalBox;
use crate::rounding::{round_down, round_up};

/// Tries of the a-priori enclosure before a step gives up (then halving, item 1d). A
/// candidate that has not closed by the third try has almost always started to grow without
/// end: on scenario 1 (16 × 12 cells, two rounds of refinement) 18 of 6,729 closures came at
/// the third try or later, none after the fifth, while the enclosures that finally fail spent
/// most of a continuous run's network bounds on tries 4–8. Three tries change no verdict there
/// nor on scenario 2 (20 × 8) and cut scenario 1's CPU time by a third.
const TRIES: usize = 3;

/// The first candidate [`enclose_step`] tries from a guess of the field `(lo, hi)`: the sweep
/// of `set` over `h`, inflated, within `region` (`None` where it misses `region`). The engine
/// bounds the network over every box's first candidate in one batch.
pub fn first_candidate(
    set: &IntervalBox,
    h: f64,
    (lo, hi): (&[f64], &[f64]),
    region: Option<&IntervalBox>,
) -> Option<IntervalBox> {
    let a = inflate(&sweep(set, h, lo, hi));
    match region {
        Some(r) => a.intersection(r),
        None => Some(a),
    }
}

/// `b` grown by 10 % of its width and a little more on every side.
fn inflate(b: &IntervalBox) -> IntervalBox {
    let grow = |l: f64, u: f64| 0.1 * (u - l) + 1e-9 * (1.0 + l.abs().max(u.abs()));
    IntervalBox {
        lower: (0..b.dim())
            .map(|i| round_down(b.lower[i] - grow(b.lower[i], b.upper[i])))
            .collect(),
        upper: (0..b.dim())
            .map(|i| round_up(b.upper[i] + grow(b.lower[i], b.upper[i])))
            .collect(),
    }
}

/// The a-priori enclosure of a step of length `h` from `set` (Picard–Lindelöf, item 1 of the
/// module's argument): candidates `A` from `guess` (last step's field bounds, else the field on
/// the set itself), inflated and retried; `field(A, parts)` must bound the filtered field on
/// `A ∩ S` — over `A` whole (`parts = false`), or as the hull of bounds over parts of `A`
/// (`true`, tried where the whole's bounds do not close: a candidate that reaches into an
/// obstacle or across the filter's pieces has loose bounds as a whole). With `region` (`C`, in
/// the frame's coordinates) candidates are clipped to it (item 1b).
pub fn enclose_step<E>(
    set: &IntervalBox,
    h: f64,
    guess: Option<(&[f64], &[f64])>,
    region: Option<&IntervalBox>,
    field: impl FnMut(&IntervalBox, bool) -> Result<Option<(Vec<f64>, Vec<f64>)>, E>,
) -> Result<Enclosure, E> {
    enclose_within(set, h, guess, region, None, &|_| false, field)
}

/// [`enclose_step`] for the filtered system, whose trajectories stay in `S`: `walls` are `S`'s
/// bounds on single coordinates ([`crate::reach::safe_set::SafeSet::walls`]), which no
/// trajectory crosses (item 1f), and `safe(x)` proves points in `S`: with `region`, a step from
/// which some trajectory provably leaves `C` within a time `T` (item 1e, `exit::exit_time`)
/// has no enclosure within `C` over any step longer than `T`, and those steps are not tried.
pub fn enclose_within<E>(
    set: &IntervalBox,
    h: f64,
    guess: Option<(&[f64], &[f64])>,
    region: Option<&IntervalBox>,
    walls: Option<&IntervalBox>,
    safe: &dyn Fn(&[f64]) -> bool,
    mut field: impl FnMut(&IntervalBox, bool) -> Result<Option<(Vec<f64>, Vec<f64>)>, E>,
) -> Result<Enclosure, E> {
    let exit = match region {
        Some(r) => exit::exit_time(set, h, guess, r, walls, safe, &mut field)?,
        None => None,
    };
    let confines = Confines { region, walls };
    enclose_halving(set, h, guess, confines, &mut field, HALVINGS, exit)
}

/// Where a step's candidates are kept: `C` (item 1b), and `S`'s walls (item 1f).
#[derive(Clone, Copy)]
struct Confines<'a> {
    region: Option<&'a IntervalBox>,
    walls: Option<&'a IntervalBox>,
}

impl Confines<'_> {
    /// `b` within `C` and the walls (`None` where it misses them).
    fn clip(&self, b: IntervalBox) -> Option<IntervalBox> {
        let b = match self.walls {
            Some(w) => b.intersection(w)?,
            None => b,
        };
        match self.region {
            Some(r) => b.intersection(r),
            None => Some(b),
        }
    }
}

/// The sweep `b` met with the walls: every state of a trajectory lies within them.
fn within_walls(b: &mut IntervalBox, walls: Option<&IntervalBox>) {
    let Some(w) = walls else { return };
    for i in 0..b.dim() {
        b.lower[i] = b.lower[i].max(w.lower[i]).min(b.upper[i]);
        b.upper[i] = b.upper[i].min(w.upper[i]).max(b.lower[i]);
    }
}

/// Halvings of a step whose enclosure does not close ([`enclose_halving`]).
const HALVINGS: usize = 2;

/// [`enclose_step`]; where the step's enclosure does not close (or meets no sound field), the
/// step's halves are enclosed one after the other (item 1d), up to `halvings` times. `exit`:
/// a time within which a trajectory from `set` leaves `C` (item 1e), if one is proven.
fn enclose_halving<E>(
    set: &IntervalBox,
    h: f64,
    guess: Option<(&[f64], &[f64])>,
    confines: Confines,
    field: &mut FieldOn<'_, E>,
    halvings: usize,
    exit: Option<f64>,
) -> Result<Enclosure, E> {
    // Item 1e: a trajectory from `set` leaves `C` within the step; no candidate closes.
    // The last halving's tries tighten no field over parts (nine bounds each): that was a
    // quarter of the enclosures' network bounds on scenario 1 (32 × 24 `--refine 3`) and only
    // kept 6 of its 1,493 leaves one step longer before their tubes ended anyway (every
    // verdict the same), while a stiff field's quarter steps close without it.
    let parts = halvings > 0;
    let whole = match exit {
        Some(t) if t < h => Enclosure::Open(OpenCause::Exits),
        _ => enclose_once(set, h, guess, confines, field, parts)?,
    };
    // A candidate without a sound field (it grew into cells with no finite margin) may be
    // avoided by a shorter step's too.
    if matches!(whole, Enclosure::Closed(_)) || halvings == 0 {
        return Ok(whole);
    }
    let half = 0.5 * h;
    let first = match enclose_halving(set, half, guess, confines, field, halvings - 1, exit)? {
        Enclosure::Closed(pipe) => pipe,
        other => return Ok(other),
    };
    let rates = Some((&first.f_lower[..], &first.f_upper[..]));
    let second =
        match enclose_halving(&first.set, half, rates, confines, field, halvings - 1, None)? {
            Enclosure::Closed(pipe) => pipe,
            other => return Ok(other),
        };
    let n = set.dim();
    Ok(Enclosure::Closed(Flowpipe {
        set: IntervalBox {
            lower: (0..n)
                .map(|i| first.set.lower[i].min(second.set.lower[i]))
                .collect(),
            upper: (0..n)
                .map(|i| first.set.upper[i].max(second.set.upper[i]))
                .collect(),
        },
        f_lower: (0..n)
            .map(|i| first.f_lower[i].min(second.f_lower[i]))
            .collect(),
        f_upper: (0..n)
            .map(|i| first.f_upper[i].max(second.f_upper[i]))
            .collect(),
        faces: None,
        enclosed: true,
        others: Vec::new(),
    }))
}

/// One try of [`enclose_step`] over the whole step `h`; `parts`: whether a candidate's field
/// may be bounded as the hull over its parts where the whole's does not close it (where the
/// whole has no field, its parts are asked whatever `parts`: those outside `S` drop out).
fn enclose_once<E>(
    set: &IntervalBox,
    h: f64,
    guess: Option<(&[f64], &[f64])>,
    confines: Confines,
    field: &mut FieldOn<'_, E>,
    parts: bool,
) -> Result<Enclosure, E> {
    let Confines { region, walls } = confines;
    let clip = |b: IntervalBox| confines.clip(b);
    // The sweep over the step, within the walls.
    let sweep = |lo: &[f64], hi: &[f64]| {
        let mut b = sweep(set, h, lo, hi);
        within_walls(&mut b, walls);
        b
    };
    let first = match guess {
        Some(guess) => {
            let Some(a) = first_candidate(set, h, guess, region) else {
                return Ok(Enclosure::Open(OpenCause::PastC));
            };
            a
        }
        None => match field(set, false)? {
            Some((lo, hi)) => inflate(&sweep(&lo, &hi)),
            None => match field(set, true)? {
                Some((lo, hi)) => inflate(&sweep(&lo, &hi)),
                None => return Ok(Enclosure::NoField),
            },
        },
    };
    let Some(mut a) = clip(first) else {
        return Ok(Enclosure::Open(OpenCause::PastC));
    };
    let mut cause = OpenCause::Grows;
    for _ in 0..TRIES {
        let whole = field(&a, false)?;
        let closes_with = |f: &(Vec<f64>, Vec<f64>)| {
            let b = sweep(&f.0, &f.1);
            closes(&b, &a, &c_inward(&a, f, confines))
        };
        let found = match whole {
            Some(w) if closes_with(&w) => Some(w),
            Some(w) if !parts => Some(w),
            whole => match (whole, field(&a, true)?) {
                (Some(w), Some(p)) => Some(meet(w, p)),
                (w, p) => w.or(p),
            },
        };
        let Some((lo, hi)) = found else {
            return Ok(Enclosure::NoField);
        };
        let mut b = sweep(&lo, &hi);
        let mut inward = c_inward(&a, &(lo.clone(), hi.clone()), confines);
        if let Some(r) = region.filter(|_| !closes(&b, &a, &inward)) {
            // Item 1c: a side of `C` the whole candidate's field does not prove inward may be
            // proven on the candidate's face there.
            for i in 0..a.dim() {
                for up in [false, true] {
                    let (side, c) = match up {
                        false => (a.lower[i], r.lower[i]),
                        true => (a.upper[i], r.upper[i]),
                    };
                    if side != c || inward[i][usize::from(up)] {
                        continue;
                    }
                    let mut face = a.clone();
                    (face.lower[i], face.upper[i]) = (side, side);
                    let Some((fl, fu)) = field(&face, false)? else {
                        continue;
                    };
                    if (!up && fl[i] > 0.0) || (up && fu[i] < 0.0) {
                        inward[i][usize::from(up)] = true;
                        match up {
                            false => b.lower[i] = b.lower[i].max(side),
                            true => b.upper[i] = b.upper[i].min(side),
                        }
                    }
                }
            }
        }
        if closes(&b, &a, &inward) {
            return Ok(Enclosure::Closed(Flowpipe {
                set: b,
                f_lower: lo,
                f_upper: hi,
                faces: None,
                enclosed: true,
                others: Vec::new(),
            }));
        }
        cause = match region.is_some_and(|r| reaches_past(&b, r, &inward)) {
            true => OpenCause::PastC,
            false => OpenCause::Grows,
        };
        let grown = IntervalBox {
            lower: (0..a.dim()).map(|i| a.lower[i].min(b.lower[i])).collect(),
            upper: (0..a.dim()).map(|i| a.upper[i].max(b.upper[i])).collect(),
        };
        match clip(inflate(&grown)) {
            Some(next) if next.lower.iter().chain(&next.upper).all(|v| v.is_finite()) => a = next,
            _ => break,
        }
    }
    Ok(Enclosure::Open(cause))
}

/// Whether the sweep `b` reaches past a side of `region` (`C`) not proven inward: the
/// candidates, clipped to `C`, cannot close there however the step is tried.
fn reaches_past(b: &IntervalBox, region: &IntervalBox, inward: &[[bool; 2]]) -> bool {
    (0..b.dim()).any(|i| {
        (b.lower[i] < region.lower[i] && !inward[i][0])
            || (b.upper[i] > region.upper[i] && !inward[i][1])
    })
}

/// Per coordinate, whether no trajectory leaves through `a`'s lower and upper sides: those
/// that are `C`'s with the field `(lo, hi)` pointing strictly into `C` there (item 1b), and
/// those on or beyond a wall of `S` (item 1f).
fn c_inward(
    a: &IntervalBox,
    (lo, hi): &(Vec<f64>, Vec<f64>),
    Confines { region, walls }: Confines,
) -> Vec<[bool; 2]> {
    (0..a.dim())
        .map(|i| {
            let c = match region {
                Some(r) => [
                    a.lower[i] == r.lower[i] && lo[i] > 0.0,
                    a.upper[i] == r.upper[i] && hi[i] < 0.0,
                ],
                None => [false, false],
            };
            let wall = match walls {
                Some(w) => [a.lower[i] <= w.lower[i], a.upper[i] >= w.upper[i]],
                None => [false, false],
            };
            [c[0] || wall[0], c[1] || wall[1]]
        })
        .collect()
}

/// Whether `b = X + [0, h]·F(A ∩ C)` proves the enclosure (items 1, 1b and 1c): in every
/// coordinate `b` lies strictly inside `a`, or meets `a`'s side where that side is `C`'s and the
/// field points strictly inward there (`inward`, from [`c_inward`] or the side's face: a
/// trajectory on that face moves into `C`, so it cannot leave `A ∩ C` through it).
fn closes(b: &IntervalBox, a: &IntervalBox, inward: &[[bool; 2]]) -> bool {
    (0..a.dim()).all(|i| {
        let lower = a.lower[i] < b.lower[i] || (inward[i][0] && a.lower[i] <= b.lower[i]);
        let upper = b.upper[i] < a.upper[i] || (inward[i][1] && b.upper[i] <= a.upper[i]);
        lower && upper
    })
}

/// The meet of two sound bounds of the same field.
fn meet(
    (mut lo, mut hi): (Vec<f64>, Vec<f64>),
    (lo2, hi2): (Vec<f64>, Vec<f64>),
) -> (Vec<f64>, Vec<f64>) {
    for i in 0..lo.len() {
        lo[i] = lo[i].max(lo2[i]);
        hi[i] = hi[i].min(hi2[i]);
    }
    (lo, hi)
}

/// `a` cut into `k` equal parts along every axis (`kⁿ` boxes; the cuts rounded, the parts
/// cover `a`).
pub fn parts(a: &IntervalBox, k: usize) -> Vec<IntervalBox> {
    let n = a.dim();
    let k = k.max(1);
    let cut = |i: usize, j: usize| match j {
        0 => a.lower[i],
        j if j == k => a.upper[i],
        j => a.lower[i] + (a.upper[i] - a.lower[i]) * (j as f64 / k as f64),
    };
    let total = k.pow(n as u32);
    (0..total)
        .map(|mut idx| {
            let (mut lower, mut upper) = (Vec::with_capacity(n), Vec::with_capacity(n));
            for i in 0..n {
                let j = idx % k;
                idx /= k;
                lower.push(cut(i, j));
                upper.push(cut(i, j + 1));
            }
            IntervalBox { lower, upper }
        })
        .collect()
}
