//! The embedding field of one box-step on the CPU engine: the filter's own field on a proven
//! piece, its enclosures on the faces of a set, and the network's bounds plus the error margin
//! (with the Minkowski method's radius), and the small helpers they share with the step loop
//! in `cpu.rs` and the validated step in `cpu_time.rs`.

use std::time::Instant;

use super::super::closeness::{closeness_step, log_norm};
use super::super::embedding::{
    embedding_field, embedding_field_by_face, euler_turn, widen_by, NetworkBoundsRef,
};
use super::super::validated;
use super::super::{ReachMethod, ReachProblem};
use super::{ChunkBuffers, ChunkRun, Frame, Live, Rates, StepInput};
use crate::bounds::AffineBoundsBatch;
use crate::boxes::IntervalBox;
use crate::filter::FilterPiece;
use crate::intervals::Interval;

impl ChunkRun<'_> {
    /// The filtered system's own field on a piece over a set, widened by the transform's slack,
    /// as rates of the Euler map over `h` ([`euler_turn`]).
    pub(super) fn piece_field(
        problem: &ReachProblem,
        set: &IntervalBox,
        (piece, slack): (FilterPiece, f64),
        zeros: &[f64],
        h: f64,
    ) -> (Vec<f64>, Vec<f64>) {
        let (n, m) = (problem.dynamics.n, problem.dynamics.m);
        let dynamics = piece_dynamics(problem, piece);
        let zero = zero_bounds(zeros, n, m);
        let (mut dl, mut du) =
            embedding_field(dynamics, &set.lower, &set.upper, zero, zero.b_lower);
        let whole = Some((zero, zero.b_lower));
        euler_turn(dynamics, &set.lower, &set.upper, h, whole, &mut dl, &mut du);
        widen_by(&mut dl, &mut du, slack);
        (dl, du)
    }

    /// The filtered system's field with `v` enclosed by its closed form on each face of the set
    /// ([`super::pieces::FilterPieces::enclosure`]; each face's x-box met with `known` where
    /// frames are met), widened by the transform's slack; `None` where an enclosure is
    /// unbounded (near a jump of `v`).
    pub(super) fn enclosure_field(
        &self,
        frame: &Frame,
        set: &IntervalBox,
        known: &IntervalBox,
        faces: &mut Vec<f64>,
        zeros: &[f64],
    ) -> Option<(Vec<f64>, Vec<f64>)> {
        let problem = frame.problem;
        let (n, m) = (problem.dynamics.n, problem.dynamics.m);
        let (lower, upper) = (&set.lower, &set.upper);
        faces.clear();
        let mut slack = 0.0_f64;
        // Per face, in the order (0, lower), (0, upper), (1, lower), …: `v`'s lower ends, then
        // its upper ends.
        for i in 0..n {
            for at in [lower[i], upper[i]] {
                let face_lo: Vec<f64> = pinned(lower, i, at).collect();
                let face_hi: Vec<f64> = pinned(upper, i, at).collect();
                let mut x_box = problem.x_box_in_safe_set(&face_lo, &face_hi, frame.safe);
                if self.frames.len() > 1 {
                    x_box = x_box.intersection(known).unwrap_or(x_box);
                }
                let v = problem.pieces.enclosure(&x_box)?;
                if !v.iter().all(|e| e.lower.is_finite() && e.upper.is_finite()) {
                    return None;
                }
                slack = slack.max(problem.pieces.field_slack(&x_box, &v));
                faces.extend(v.iter().map(|e| e.lower));
                faces.extend(v.iter().map(|e| e.upper));
            }
        }
        let faces = &faces[..];
        let face = |i: usize, up: bool| {
            let k = (2 * i + usize::from(up)) * 2 * m;
            constant_bounds(zeros, &faces[k..k + m], &faces[k + m..k + 2 * m], n)
        };
        let (mut dl, mut du) =
            embedding_field_by_face(&problem.dynamics, lower, upper, face, &zeros[..m]);
        euler_turn(
            &problem.dynamics,
            lower,
            upper,
            self.h,
            None,
            &mut dl,
            &mut du,
        );
        widen_by(&mut dl, &mut du, slack);
        Some((dl, du))
    }

    /// The fields of one frame's box-step from this step's batch (`slot`: the box's rows, where
    /// the network was bounded): the filter's piece, its enclosures, the network (its margin
    /// put in `buf.margin`). Returns them and the time spent on the closeness radius.
    pub(super) fn first_fields(
        &self,
        frame: &Frame,
        state: &mut Live,
        f: usize,
        input: StepInput,
        slot: Option<usize>,
        buf: &mut ChunkBuffers,
    ) -> ([Option<Rates>; 3], f64) {
        let p = frame.problem;
        let set = &state.sets[f];
        let pipe = state.pipes.get(f).and_then(Option::as_ref);
        let exact = input.piece.map(|piece| match pipe {
            Some(pipe) => self.piece_slab_field(p, set, pipe, piece, &buf.zeros),
            None => Self::piece_field(p, set, piece, &buf.zeros, self.h),
        });
        let enclosed = match (pipe, input.piece.is_none() && self.encloses) {
            (_, false) => None,
            (Some(pipe), true) => {
                let known = state.pipe_known.as_ref().unwrap_or(&state.known);
                self.enclosure_slab_field(frame, set, pipe, known, &buf.zeros)
            }
            (None, true) => {
                self.enclosure_field(frame, set, &state.known, &mut buf.faces, &buf.zeros)
            }
        };
        if f == 0 {
            state.tube.exact_steps += usize::from(exact.is_some());
            state.tube.enclosed_steps += usize::from(enclosed.is_some());
        }
        buf.margin.clear();
        buf.margin.resize(p.dynamics.m, input.margin.unwrap_or(0.0));
        let mut minkowski_s = 0.0;
        let network = slot.map(|slot| {
            let batch = &buf.frames[f].batch;
            let (field, s) = self.network_field(p, state, f, batch, slot, &buf.margin);
            minkowski_s += s;
            field
        });
        ([exact, enclosed, network], minkowski_s)
    }

    /// The embedding field from the network's bounds of this box-step (`slot`: the box's rows
    /// in the frame's batch) plus the error margin `bound`; the Minkowski method also advances
    /// the closeness radius. Returns the field and the time spent on the radius.
    pub(super) fn network_field(
        &self,
        problem: &ReachProblem,
        state: &mut Live,
        frame: usize,
        batch: &AffineBoundsBatch,
        slot: usize,
        margin: &[f64],
    ) -> ((Vec<f64>, Vec<f64>), f64) {
        let (n, m) = (problem.dynamics.n, problem.dynamics.m);
        let set = &state.sets[frame];
        let pipe = state.pipes.get(frame).and_then(Option::as_ref);
        let face =
            |i: usize, up: bool| bounds_of(batch, slot * 2 * n + 2 * i + usize::from(up), n, m);
        let nn = bounds_of(batch, slot, n, m);
        let dynamics = &problem.dynamics;
        let (mut dl, mut du) = match (pipe, self.settings.face_local) {
            (Some(pipe), true) => validated::slab_field(dynamics, set, pipe, self.h, face, margin),
            (Some(pipe), false) => {
                validated::slab_field(dynamics, set, pipe, self.h, |_, _| nn, margin)
            }
            (None, true) => {
                let (mut dl, mut du) =
                    embedding_field_by_face(dynamics, &set.lower, &set.upper, face, margin);
                euler_turn(
                    dynamics, &set.lower, &set.upper, self.h, None, &mut dl, &mut du,
                );
                (dl, du)
            }
            (None, false) => {
                let (mut dl, mut du) =
                    embedding_field(dynamics, &set.lower, &set.upper, nn, margin);
                let whole = Some((nn, margin));
                euler_turn(
                    dynamics, &set.lower, &set.upper, self.h, whole, &mut dl, &mut du,
                );
                (dl, du)
            }
        };
        // The Minkowski method's radius (refused with face-local bounds: its rate needs one C).
        let mut minkowski_s = 0.0;
        if self.settings.method == ReachMethod::Minkowski && !self.settings.face_local {
            let clock = Instant::now();
            let c = closeness_rate(problem, nn);
            state.radius = closeness_step(state.radius, c, problem.input_gain, problem.m_c, self.h);
            minkowski_s = clock.elapsed().as_secs_f64();
        }
        widen_by(&mut dl, &mut du, problem.field_slack);
        ((dl, du), minkowski_s)
    }
}

/// Whether the Euler step of `[dl, du]` over `h` turns `set` inside out.
pub(super) fn inverts(set: &IntervalBox, dl: &[f64], du: &[f64], h: f64) -> bool {
    (0..dl.len()).any(|i| set.upper[i] + h * du[i] < set.lower[i] + h * dl[i])
}

/// The meet of two sound bounds `[dl, du]` of the same embedding field.
pub(super) fn meet_fields(
    (mut dl, mut du): (Vec<f64>, Vec<f64>),
    (dl2, du2): (Vec<f64>, Vec<f64>),
) -> (Vec<f64>, Vec<f64>) {
    for i in 0..dl.len() {
        dl[i] = dl[i].max(dl2[i]);
        du[i] = du[i].min(du2[i]);
    }
    (dl, du)
}

/// `x` with coordinate `i` set to `v` (a face of a box).
pub(super) fn pinned(x: &[f64], i: usize, v: f64) -> impl Iterator<Item = f64> + '_ {
    x.iter()
        .enumerate()
        .map(move |(j, &x_j)| if j == i { v } else { x_j })
}

/// The filtered system's dynamics on a proven piece of the filter.
pub(super) fn piece_dynamics(
    problem: &ReachProblem,
    piece: FilterPiece,
) -> &super::super::embedding::Dynamics {
    match piece {
        FilterPiece::Inactive => &problem.dynamics,
        FilterPiece::Binding(k) => &problem.pieces.binding_field(k).dynamics,
    }
}

/// The network's stand-in where `v = 0` exactly: zero forms and bounds (`zeros` holds at least
/// `m·n` zeros).
pub(super) fn zero_bounds(zeros: &[f64], n: usize, m: usize) -> NetworkBoundsRef<'_> {
    constant_bounds(zeros, &zeros[..m], &zeros[..m], n)
}

/// Bounds `lo ≤ v ≤ hi` with zero slopes (an enclosure of `v` in the network's place).
pub(super) fn constant_bounds<'a>(
    zeros: &'a [f64],
    lo: &'a [f64],
    hi: &'a [f64],
    n: usize,
) -> NetworkBoundsRef<'a> {
    let m = lo.len();
    NetworkBoundsRef {
        a_lower: &zeros[..m * n],
        b_lower: lo,
        a_upper: &zeros[..m * n],
        b_upper: hi,
        lower: lo,
        upper: hi,
    }
}

pub(super) fn bounds_of(
    batch: &AffineBoundsBatch,
    k: usize,
    n: usize,
    m: usize,
) -> NetworkBoundsRef<'_> {
    NetworkBoundsRef {
        a_lower: &batch.a_lower[k * m * n..(k + 1) * m * n],
        b_lower: &batch.b_lower[k * m..(k + 1) * m],
        a_upper: &batch.a_upper[k * m * n..(k + 1) * m * n],
        b_upper: &batch.b_upper[k * m..(k + 1) * m],
        lower: &batch.lower[k * m..(k + 1) * m],
        upper: &batch.upper[k * m..(k + 1) * m],
    }
}

/// `c_k ≥ sup_{x∈C} μ(Df̃(x) + g(x) C_k)` with `C_k` the hull of the box's `C̲, C̄` (one
/// matrix for the same-slope relaxation, as the paper's theorem assumes).
pub(super) fn closeness_rate(problem: &ReachProblem, nn: NetworkBoundsRef) -> f64 {
    let (n, m) = (problem.dynamics.n, problem.dynamics.m);
    let c_hull: Vec<Interval> = nn
        .a_lower
        .iter()
        .zip(nn.a_upper)
        .map(|(&a, &b)| Interval::new(a.min(b), a.max(b)))
        .collect();
    let a: Vec<Interval> = (0..n * n)
        .map(|ij| {
            let (i, j) = (ij / n, ij % n);
            (0..m).fold(problem.jacobian_over_region[ij], |s, k| {
                s + problem.g_over_region[i * m + k] * c_hull[k * n + j]
            })
        })
        .collect();
    log_norm(&a, n, problem.norm)
}
