//! Trap boxes: around the stable undesirable equilibria of the filtered system, sets that end
//! inside are `trapped`. May import `equilibria`, `filter` and `scenario`.

use serde::{Deserialize, Serialize};

use crate::boxes::IntervalBox;
use crate::equilibria::{find_equilibria, Equilibrium, EquilibriumSearch, Stability};
use crate::filter::SafetyFilter;
use crate::scenario::Scenario;

/// A box around a stable undesirable equilibrium: sets that end inside are `trapped`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Trap {
    /// The equilibrium `x*`.
    pub x: Vec<f64>,
    /// The trap box `x* ± half-widths`.
    pub region: IntervalBox,
}

/// Trap boxes `x* ± half_widths` around every equilibrium that is stable and undesirable.
pub fn traps_from_equilibria(found: &[Equilibrium], half_widths: &[f64]) -> Vec<Trap> {
    found
        .iter()
        .filter(|e| e.kind == Stability::Stable && e.undesirable)
        .map(|e| Trap {
            x: e.x.clone(),
            region: IntervalBox {
                lower: e.x.iter().zip(half_widths).map(|(c, h)| c - h).collect(),
                upper: e.x.iter().zip(half_widths).map(|(c, h)| c + h).collect(),
            },
        })
        .collect()
}

/// The traps of a scenario as `cbfreach verify` takes them: the stable undesirable equilibria
/// of the filtered system in `C` (found with the default search), each with a box of the goal
/// box's half-widths.
pub fn traps_for(s: &Scenario) -> Vec<Trap> {
    // Past the size of a dense search there are no traps: fewer `trapped` verdicts, never a
    // wrong one.
    let Some(search) = equilibrium_search_for(s.n()) else {
        return Vec::new();
    };
    let found = find_equilibria(&SafetyFilter::new(s), &s.reach.region, &search);
    traps_for_equilibria(s, &found)
}

/// Most starting points of the dense equilibrium search (its grid grows as `kⁿ`).
pub const MAX_EQUILIBRIUM_STARTS: usize = 100_000;

/// The default search for `n` states, with fewer starts per axis where `30ⁿ` would pass
/// [`MAX_EQUILIBRIUM_STARTS`]; `None` when even 2 per axis would.
pub fn equilibrium_search_for(n: usize) -> Option<EquilibriumSearch> {
    let mut search = EquilibriumSearch::default();
    search.starts_per_axis =
        crate::boxes::per_axis_within(n, MAX_EQUILIBRIUM_STARTS, search.starts_per_axis);
    (search.starts_per_axis >= 2).then_some(search)
}

/// [`traps_for`] with the equilibria already found.
pub fn traps_for_equilibria(s: &Scenario, found: &[Equilibrium]) -> Vec<Trap> {
    let half: Vec<f64> = s.reach.goal.widths().iter().map(|w| 0.5 * w).collect();
    traps_from_equilibria(found, &half)
}
