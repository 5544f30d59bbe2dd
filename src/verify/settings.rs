//! How a verification run goes: [`VerifySettings`] (the one source of `cbfreach verify`'s
//! defaults, and of a scenario's `[settings.verify]` table). May import `verify`'s shards.

use serde::{Deserialize, Serialize};

use super::{Shard, VerifyError};
use crate::boxes::IntervalBox;
use crate::scenario::Scenario;

/// Settings of a verification run. `VerifySettings::default()` is what `cbfreach verify` runs
/// with no options; a scenario's `[settings.verify]` table sets `region`, `grid`,
/// `refine_depth`, `budget` and `refine_feasibility` by name, and command-line options
/// override both.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct VerifySettings {
    /// The region to partition (inside `C`). Default: `None`, the region `C` itself.
    pub region: Option<IntervalBox>,
    /// Cells per axis, one count per state. Default: `[64, 64]`.
    pub grid: Vec<usize>,
    /// Bisection rounds of `unknown`/`invalid` leaves. Default: 0.
    pub refine_depth: usize,
    /// Most extra boxes refinement may run (per shard). Default: 8192.
    pub budget: usize,
    /// Refinement also bisects verified leaves whose QP feasibility is not proven (after the
    /// unverified ones, within the same budget): their halves keep the verdict and may prove
    /// feasibility on their own sets. Default: false.
    pub refine_feasibility: bool,
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
            grid: vec![64, 64],
            refine_depth: 0,
            budget: 8192,
            refine_feasibility: false,
            shard: None,
            chunk: None,
        }
    }
}

/// Most grid cells one verification run (or shard) may hold in memory.
pub const MAX_CELLS_PER_RUN: usize = 50_000_000;

impl VerifySettings {
    /// The region partitioned for `scenario`: `region`, else `C`.
    pub fn region_in(&self, scenario: &Scenario) -> IntervalBox {
        self.region
            .clone()
            .unwrap_or_else(|| scenario.reach.region.clone())
    }

    /// Checks the settings against the scenario; errors name the field.
    pub fn validate(&self, scenario: &Scenario) -> Result<(), VerifyError> {
        let n = scenario.n();
        let c = &scenario.reach.region;
        let region = self.region_in(scenario);
        let bad = |field: &'static str, message: String| VerifyError::Settings { field, message };
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
        if self.grid.len() != n || self.grid.contains(&0) {
            return Err(bad(
                "grid",
                format!(
                    "expected {n} positive cell counts (e.g. 64,64), found {:?}",
                    self.grid
                ),
            ));
        }
        // The cap is per run: a shard runs only its slice of the grid.
        let total = self.grid.iter().try_fold(1usize, |a, &k| a.checked_mul(k));
        let Some(total) = total else {
            return Err(bad(
                "grid",
                format!("{:?}: the number of cells overflows", self.grid),
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
                    "{:?} gives {here} cells to this run, more than {MAX_CELLS_PER_RUN} \
                     (use --shard K/N with N ≥ {})",
                    self.grid,
                    total.div_ceil(MAX_CELLS_PER_RUN)
                ),
            ));
        }
        Ok(())
    }
}
