//! How a verification run goes: [`VerifySettings`] (the one source of `cbfreach verify`'s
//! defaults, and of a scenario's `[settings.verify]` table). May import `verify`'s shards.

use serde::{Deserialize, Serialize};

use std::borrow::Cow;

use super::{Shard, VerifyError};
use crate::boxes::IntervalBox;
use crate::reach::{ReachProblem, TimeModel};
use crate::scenario::Scenario;

/// Settings of a verification run. `VerifySettings::default()` is what `cbfreach verify` runs
/// with no options; a scenario's `[settings.verify]` table sets `region`, `grid`,
/// `refine_depth`, `budget`, `refine_feasibility`, `refine_boundary` and `max_substeps` by name,
/// and command-line options override both.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct VerifySettings {
    /// The region to partition (inside `C`). Default: `None`, the region `C` itself.
    pub region: Option<IntervalBox>,
    /// Cells per axis, one count per state. Default: empty, the grid
    /// [`VerifySettings::default_grid`] gives for the scenario's state count (64 × 64 in two
    /// states).
    pub grid: Vec<usize>,
    /// Bisection rounds of `unknown`/`invalid` leaves. Default: 0.
    pub refine_depth: usize,
    /// Most extra boxes refinement may run (per shard). Default: 8192.
    pub budget: usize,
    /// Refinement also bisects verified leaves whose QP feasibility is not proven (after the
    /// unverified ones, within the same budget): their halves keep the verdict and may prove
    /// feasibility on their own sets. Default: false.
    pub refine_feasibility: bool,
    /// Refinement also bisects `partly-unsafe` leaves, the band along `∂S` (after the others,
    /// within the same budget): their halves that start in `S` are run, and join the safe area,
    /// which then grows from the cells' (the share before refinement keeps the cells'). Where
    /// the filter acts and its spurious equilibria lie, which cells straddling `∂S` leave out.
    /// Default: false (the shares stay those of the cells that start safe).
    pub refine_boundary: bool,
    /// In continuous time refinement cuts the step as it cuts the boxes: a box of depth `d`
    /// runs `2^⌈d/n⌉` times the problem's substeps (n states; [`VerifySettings::substeps_at`]),
    /// at most this many (never fewer than the problem's own). A validated step's excess over
    /// the flow is `O(h²)`, so `O(h)` over the horizon, whatever the box's width: bisection,
    /// which halves a box's widest side once every `n` rounds, gains little on boxes that
    /// small unless `h` shrinks with it (docs/design.md §7.3). Default: 4. 1: refinement keeps
    /// the step.
    pub max_substeps: usize,
    /// Stop each tube once its set lies in a box proven absorbing for the goal or a trap
    /// ([`super::absorbing_boxes`]; docs/design.md §2.12): every later state is then proven in
    /// that target, so the verdict is decided. Verdicts stay or improve (a set that would have
    /// outgrown the target later no longer matters), and converging tubes skip most of their
    /// steps. Default: true. false: every tube runs to the horizon.
    pub absorb: bool,
    /// Run only this slice of the cells. Default: `None`, every cell (not read from a
    /// scenario: shards split one run across jobs).
    #[serde(skip)]
    pub shard: Option<Shard>,
    /// Boxes per call of the engine (bounds memory; tubes are judged and dropped per chunk).
    /// Default: `None`, the engine's preferred batch (`Backend::preferred_batch`).
    #[serde(skip)]
    pub chunk: Option<usize>,
}

impl Default for VerifySettings {
    fn default() -> Self {
        VerifySettings {
            region: None,
            grid: Vec::new(),
            refine_depth: 0,
            budget: 8192,
            refine_feasibility: false,
            refine_boundary: false,
            max_substeps: 4,
            absorb: true,
            shard: None,
            chunk: None,
        }
    }
}

/// Most grid cells one verification run (or shard) may hold in memory.
pub const MAX_CELLS_PER_RUN: usize = 50_000_000;

impl VerifySettings {
    /// The grid where none is given: 64 cells per axis in one and two states, and in more the
    /// most per axis that keeps the grid within 4,096 cells (16³, 8⁴, 5⁵, 4⁶, …, at least 2).
    pub fn default_grid(n: usize) -> Vec<usize> {
        vec![crate::boxes::per_axis_within(n, 4096, 64).max(2); n]
    }

    /// The cells per axis of a run over `n` states: [`VerifySettings::grid`], or
    /// [`VerifySettings::default_grid`] where it is empty.
    pub fn grid_for(&self, n: usize) -> Vec<usize> {
        match self.grid.is_empty() {
            true => Self::default_grid(n),
            false => self.grid.clone(),
        }
    }

    /// The region partitioned for `scenario`: `region`, else `C`.
    pub fn region_in(&self, scenario: &Scenario) -> IntervalBox {
        self.region
            .clone()
            .unwrap_or_else(|| scenario.reach.region.clone())
    }

    /// Validated steps per `dt` for the boxes of refinement depth `depth`: in continuous time
    /// `2^⌈depth/n⌉` times the problem's substeps, at most `max_substeps` and never fewer than
    /// the problem's own; the problem's substeps in the other time models.
    pub fn substeps_at(&self, problem: &ReachProblem, depth: usize) -> usize {
        let base = problem.substeps.max(1);
        match problem.time {
            TimeModel::Continuous => cut_step(base, problem.dynamics.n, depth, self.max_substeps),
            _ => base,
        }
    }

    /// The problem the boxes of refinement depth `depth` run: `problem` with
    /// [`VerifySettings::substeps_at`] substeps (itself where that is its own).
    pub fn problem_at<'p>(&self, problem: &'p ReachProblem, depth: usize) -> Cow<'p, ReachProblem> {
        let substeps = self.substeps_at(problem, depth);
        match substeps == problem.substeps.max(1) {
            true => Cow::Borrowed(problem),
            false => Cow::Owned(problem.clone().with_time(problem.time, substeps)),
        }
    }

    /// Checks the settings against the scenario; errors name the field.
    pub fn validate(&self, scenario: &Scenario) -> Result<(), VerifyError> {
        let n = scenario.n();
        let c = &scenario.reach.region;
        let region = self.region_in(scenario);
        let bad = |field: &'static str, message: String| VerifyError::Settings { field, message };
        if self.max_substeps == 0 {
            return Err(bad(
                "max_substeps",
                "must be at least 1 (1: refinement keeps the step)".into(),
            ));
        }
        if region.dim() != n {
            return Err(bad(
                "region",
                format!(
                    "has {} coordinates, the system has {n} states",
                    region.dim()
                ),
            ));
        }
        if !region.is_subset_of(c) {
            return Err(bad(
                "region",
                format!(
                    "{:?}…{:?} does not lie in the region C = {:?}…{:?} of {}",
                    region.lower, region.upper, c.lower, c.upper, scenario.file
                ),
            ));
        }
        if region.widths().iter().any(|&w| w <= 0.0) {
            return Err(bad("region", "every side must have positive width".into()));
        }
        let grid = self.grid_for(n);
        if grid.len() != n || grid.contains(&0) {
            return Err(bad(
                "grid",
                format!("expected {n} positive cell counts (e.g. 64,64), found {grid:?}"),
            ));
        }
        // The cap is per run: a shard runs only its slice of the grid.
        let total = grid.iter().try_fold(1usize, |a, &k| a.checked_mul(k));
        let Some(total) = total else {
            return Err(bad(
                "grid",
                format!("{grid:?}: the number of cells overflows"),
            ));
        };
        if let Some(s) = self.shard {
            if s.count > total {
                return Err(bad(
                    "shard",
                    format!("{s}: more shards than the {total} cells of the grid"),
                ));
            }
        }
        let here = self.shard.map_or(total, |s| s.range(total).len());
        if here > MAX_CELLS_PER_RUN {
            return Err(bad(
                "grid",
                format!(
                    "{grid:?} gives {here} cells to this run, more than {MAX_CELLS_PER_RUN} \
                     (use --shard K/N with N ≥ {})",
                    total.div_ceil(MAX_CELLS_PER_RUN)
                ),
            ));
        }
        Ok(())
    }
}

/// `base · 2^⌈depth/n⌉` substeps, at most `max` and never fewer than `base`.
fn cut_step(base: usize, n: usize, depth: usize, max: usize) -> usize {
    let halvings = depth.div_ceil(n.max(1));
    let cut = u32::try_from(halvings)
        .ok()
        .and_then(|h| 1usize.checked_shl(h))
        .unwrap_or(usize::MAX);
    base.saturating_mul(cut).min(max).max(base)
}

#[cfg(test)]
mod tests {
    use super::{cut_step, VerifySettings};

    #[test]
    fn the_default_grid_follows_the_state_count() {
        let grid = VerifySettings::default_grid;
        assert_eq!(grid(1), [64]);
        assert_eq!(grid(2), [64, 64]);
        assert_eq!(grid(3), [16; 3]);
        assert_eq!(grid(4), [8; 4]);
        assert_eq!(grid(5), [5; 5]);
        assert_eq!(grid(6), [4; 6]);
        assert_eq!(grid(13), [2; 13]);
        // A given grid is kept.
        let given = VerifySettings {
            grid: vec![3, 4, 5],
            ..VerifySettings::default()
        };
        assert_eq!(given.grid_for(3), [3, 4, 5]);
        assert_eq!(VerifySettings::default().grid_for(3), [16; 3]);
    }

    #[test]
    fn the_step_halves_once_every_n_rounds_within_its_bounds() {
        // Two states: the widest side halves at depths 1, 3, 5, …; so does the step.
        let two: Vec<usize> = (0..8).map(|d| cut_step(1, 2, d, 8)).collect();
        assert_eq!(two, [1, 2, 2, 4, 4, 8, 8, 8]);
        let three: Vec<usize> = (0..8).map(|d| cut_step(1, 3, d, 64)).collect();
        assert_eq!(three, [1, 2, 2, 2, 4, 4, 4, 8]);
        // The cap, the scenario's own substeps kept when above it, 1 = off, no overflow.
        assert_eq!(cut_step(3, 2, 1, 4), 4);
        assert_eq!(cut_step(8, 2, 3, 4), 8);
        assert_eq!(cut_step(1, 2, 6, 1), 1);
        assert_eq!(cut_step(1, 1, 200, usize::MAX), usize::MAX);
    }
}
