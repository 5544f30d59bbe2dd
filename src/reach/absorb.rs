//! Absorbing boxes: where a tube may stop before the horizon because what follows is already
//! proven (docs/design.md §2.12, "Absorbing boxes").
//!
//! An [`Absorber`] is a box `B` with a time `τ` and a target `G` (the goal, or a trap's box):
//! every trajectory of the problem's time model from `B` lies in `G` at every sample time from
//! `τ` on. `verify` proves two kinds: boxes `I ⊆ G` whose tubes come back into `I` after a few
//! steps (`τ = 0`; [`crate::verify::absorbing_boxes`]), and verified boxes of its own earlier
//! rounds whose tubes stopped in such an `I` at `τ`. A tube whose set lies in `B` at a sample
//! time `t` with `t + τ ≤ T` is decided there, and its remaining steps are skipped. The check is
//! one containment at the recorded samples, the same for both engines: the CPU engine stops the
//! tube there ([`absorber`] in `ChunkRun::advance`), the GPU engine's tubes are cut at the same
//! sample afterwards ([`cut`]).

use crate::boxes::IntervalBox;

use super::{ReachProblem, Tube, TubeEnd};

/// A box whose trajectories are all in a target from a time on (module documentation).
#[derive(Clone, Debug, PartialEq)]
pub struct Absorber {
    /// The box `B`.
    pub set: IntervalBox,
    /// `τ`: from this long after a state is in `B`, it is in the target at every sample time.
    pub within: f64,
    /// The target: `None` the goal, `Some(k)` trap `k`.
    pub trap: Option<usize>,
}

/// Most buckets of [`Absorbers`]' index.
const BUCKETS: f64 = 65_536.0;

/// A problem's absorbers, indexed for containment: each is listed in every bucket of a uniform
/// grid over `C` that it meets, so a set lies in one only if that one is listed in the bucket of
/// the set's lower corner.
#[derive(Clone, Debug, Default)]
pub struct Absorbers {
    list: Vec<Absorber>,
    region: Option<IntervalBox>,
    per_axis: usize,
    buckets: Vec<Vec<u32>>,
}

impl Absorbers {
    /// `list` indexed over `region` (`C`).
    pub fn new(list: Vec<Absorber>, region: &IntervalBox) -> Absorbers {
        let n = region.dim();
        let per_axis = (BUCKETS.powf(1.0 / n as f64).floor() as usize).max(1);
        let mut a = Absorbers {
            list: Vec::new(),
            region: Some(region.clone()),
            per_axis,
            buckets: vec![Vec::new(); per_axis.pow(n as u32)],
        };
        for b in list {
            a.push(b);
        }
        a
    }

    /// Adds one (indexed only where `new` gave a region).
    fn push(&mut self, b: Absorber) {
        let k = self.list.len() as u32;
        if let Some(region) = &self.region {
            let axis = |v: &[f64]| -> Vec<usize> {
                (0..v.len()).map(|i| self.axis(region, i, v[i])).collect()
            };
            let (lo, hi) = (axis(&b.set.lower), axis(&b.set.upper));
            let mut at = lo.clone();
            loop {
                let flat = self.flat(at.iter().copied());
                self.buckets[flat].push(k);
                // The next bucket of the product `lo..=hi`.
                let Some(d) = (0..at.len()).find(|&d| at[d] < hi[d]) else {
                    break;
                };
                at[d] += 1;
                at[..d].copy_from_slice(&lo[..d]);
            }
        }
        self.list.push(b);
    }

    /// The bucket of coordinate `v` along axis `i` (clamped to the grid).
    fn axis(&self, region: &IntervalBox, i: usize, v: f64) -> usize {
        let w = region.upper[i] - region.lower[i];
        let f = ((v - region.lower[i]) / w * self.per_axis as f64).floor();
        (f.max(0.0) as usize).min(self.per_axis - 1)
    }

    /// The bucket of per-axis indices `at` (axis 0 varies fastest).
    fn flat(&self, at: impl DoubleEndedIterator<Item = usize>) -> usize {
        at.rev().fold(0, |acc, i| acc * self.per_axis + i)
    }

    /// None to stop in.
    pub fn is_empty(&self) -> bool {
        self.list.is_empty()
    }

    /// The absorbers that hold `set`: those listed in the bucket of its lower corner (a lookup
    /// at every recorded sample of every tube, so it allocates nothing).
    fn holding<'a, 's>(
        &'a self,
        set: &'s IntervalBox,
    ) -> impl Iterator<Item = &'a Absorber> + use<'a, 's> {
        let listed: &[u32] = match &self.region {
            Some(region) => {
                let x = &set.lower;
                &self.buckets[self.flat((0..x.len()).map(|i| self.axis(region, i, x[i])))]
            }
            None => &[],
        };
        listed
            .iter()
            .map(|&k| &self.list[k as usize])
            .filter(move |a| set.is_subset_of(&a.set))
    }
}

/// The absorber that decides a tube whose set at `t` is `set`: one holding `set` whose `τ` fits
/// in the time left (`t + τ ≤ T`), at a time at which that decides the rest — a whole number of
/// steps of `dt` after the start (not a substep, not the start), a multiple of the control
/// period in sampled data.
pub fn absorber<'p>(problem: &'p ReachProblem, t: f64, set: &IntervalBox) -> Option<&'p Absorber> {
    if problem.absorbing.is_empty() {
        return None;
    }
    let dt = problem.dt;
    let steps = (t / dt).round();
    let period = problem.period_steps().unwrap_or(1).max(1);
    let at_sample = (t - steps * dt).abs() <= 1e-9 * dt.max(t)
        && steps >= 1.0
        && (steps as usize).is_multiple_of(period);
    if !at_sample {
        return None;
    }
    let left = (problem.steps as f64 - steps) * dt;
    problem
        .absorbing
        .holding(set)
        .find(|a| a.within <= left + 1e-9 * dt)
}

/// Cuts `tube` at its first recorded sample (after the start, at a sample time, before its end)
/// that an absorber decides, as the CPU engine stops it there. Does nothing where none does.
pub fn cut(problem: &ReachProblem, tube: &mut Tube) {
    if problem.absorbing.is_empty() {
        return;
    }
    let at = tube
        .model_samples()
        .iter()
        .position(|s| absorber(problem, s.t, &s.set).is_some());
    if let Some(k) = at {
        tube.end = TubeEnd::Absorbed { t: tube.tube[k].t };
        tube.tube.truncate(k + 1);
    }
}
