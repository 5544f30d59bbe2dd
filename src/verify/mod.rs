//! Verification at scale: a verdict per box of a partitioned region, adaptive refinement,
//! shards and their merge (issue 4).
//!
//! A region `R ⊆ C` is cut into a grid of cells. Each cell `X₀` is first checked against the
//! CBFs by interval evaluation of every `hᵢ` over it:
//!
//! - `max hᵢ(X₀) < 0` for some i: the whole cell is unsafe, [`Verdict::UnsafeStart`];
//! - `min hᵢ(X₀) < 0` for some i: the cell may hold unsafe points, [`Verdict::PartlyUnsafe`];
//!
//! both are skipped (the filter promises nothing for unsafe starts). Every other cell is run
//! through the reach engine and judged by its filtered-system sets `X(t)` (the `set` boxes of
//! the tube, recorded at every Euler step):
//!
//! - [`Verdict::Unsafe`] if at some recorded `t` some `hᵢ < 0` on all of `X(t)` (interval
//!   evaluation) while the QP is proven feasible on every earlier set: the filter keeps `S`
//!   forward invariant while it has a solution, so this reveals a bug and is reported loudly.
//!   Where the QP may be infeasible on an earlier set, the trajectories may stop existing
//!   there (conflicting CBFs), and the box is [`Verdict::Unknown`] with a note;
//! - [`Verdict::UnsafeBetweenSamples`] (sampled-data only, checked first) if a set, or the
//!   enclosure of the motion between two steps, is not proven inside `S`: a digital filter does
//!   not keep `S` invariant, so this is a finding about the system, with its time;
//! - [`Verdict::Invalid`] if `X(t)` left `C` (the theorem's hypothesis and `M_C` fail there);
//! - [`Verdict::Converges`] if `X(T) ⊆ G`, the scenario's goal box;
//! - [`Verdict::Trapped`] if `X(T)` lies in the [`Trap`] box of an undesirable equilibrium that
//!   the equilibria finder reports as stable. The trap box is centred on the equilibrium with
//!   the goal box's half-widths, so "trapped" and "converges" mean the same closeness to their
//!   equilibrium;
//! - [`Verdict::Unknown`] otherwise.
//!
//! **Refinement** bisects `unknown` and `invalid` leaves across their widest axis and re-runs the
//! halves, up to a depth and a budget of extra boxes; both can become decidable on smaller
//! boxes (tighter network bounds, narrower sets). Cells that may start unsafe are not refined
//! (but see `refine_boundary` below), so the *safe area* — the area of the cells that start
//! safe — is the same before and after, and the **verified share** is
//! `area(converges ∪ trapped) / safe area`. With `refine_feasibility` it
//! also bisects verified leaves whose QP feasibility is not proven (after the undecided ones):
//! a half keeps its parent's verdict, which holds for every start in the parent, unless its own
//! sets prove one, and only its own sets can prove the QP feasible. With `refine_boundary` it
//! also bisects `partly-unsafe` leaves (last): their halves that start safe are run and join
//! the safe area, which then grows from the cells' (docs/design.md §2.9).
//!
//! **Shards**: `K/N` takes the K-th (1-based) of N contiguous slices of the grid's cells (axis 0
//! fastest), so a job array can split a large region; [`merge`] checks that the shards come from
//! the same run and tile the grid exactly, and joins them. The refinement budget applies per
//! shard.
//!
//! Submodules by concern: `run` (the verifier and [`judge`]), `report` (what a run reports),
//! `settings`, `shard` (shards and [`merge`]), `traps`, `pieces` ([`verify_by_pieces`]) and
//! `check` (checks against the ground-truth filter). May import `reach`, `scenario`,
//! `equilibria`, `filter` and `simulate`.

mod absorb;
mod check;
pub mod checkpoint;
mod pieces;
mod report;
mod run;
mod settings;
mod shard;
mod traps;
mod what_stops;

pub use absorb::{absorbing_boxes, leaf_absorbers, target_absorbers, Absorbing, SCALES};
pub use check::{
    centre_outcomes, explain_unverified, outcome_from, simulate_model, simulation_check, survey,
    CentreOutcome, SimulationCheck, Survey, UnverifiedCauses, LATER_HORIZONS,
};
pub use pieces::{
    no_journals, verify_by_pieces, PieceOutcome, PiecesJournals, PiecesSettings, PiecesVerdict,
    PIECES_CHUNK, REFINE_BUDGET, SPLIT,
};
pub use report::{BoxVerdict, Headline, RunInfo, Shares, VerifyReport, VerifyTiming};
pub use run::{
    in_safe_set, judge, judge_with_feasibility, split_outside_s, start_verdict, InSafeSet,
    Judgement, Reason, Stage, Verifier,
};
pub use settings::VerifySettings;
pub use shard::{merge, Shard};
pub use traps::{
    equilibrium_search_for, traps_for, traps_for_equilibria, traps_from_equilibria, Trap,
    MAX_EQUILIBRIUM_STARTS,
};
pub use what_stops::{
    rerun_stopped, Culprit, Reruns, StoppedRerun, WhatStops, SUBSTEP_FACTOR, WHAT_STOPS_LEAVES,
};

use serde::{Deserialize, Serialize};

use crate::reach::ReachError;

/// The `format` tag of verdict JSON files.
pub const FORMAT: &str = "cbfreach-verify-1";

/// What a box's reachable sets show.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Hash, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Verdict {
    /// The set at the final time lies in the goal box.
    Converges,
    /// The set at the final time lies in the trap box of a stable undesirable equilibrium.
    Trapped,
    /// Neither could be shown.
    Unknown,
    /// The set left the region `C`: the result says nothing.
    Invalid,
    /// Sampled-data: a set, or the enclosure of the motion between two steps, is not proven
    /// inside `S` — the held input may carry states out of `S` between samples (a finding, not
    /// a bug; [`crate::reach::UnsafeBetweenSamples`]).
    UnsafeBetweenSamples,
    /// The set lay entirely in the unsafe set at some time, after sets on which the QP is
    /// proven feasible: a bug (filter, network error bound or engine), never a property of a
    /// correct system.
    Unsafe,
    /// The box may contain unsafe points (some `hᵢ` may be negative on it); skipped.
    PartlyUnsafe,
    /// The box lies in the unsafe set (some `hᵢ < 0` on all of it); skipped.
    UnsafeStart,
}

impl Verdict {
    /// Every verdict, in report order.
    pub const ALL: [Verdict; 8] = [
        Verdict::Converges,
        Verdict::Trapped,
        Verdict::Unknown,
        Verdict::Invalid,
        Verdict::UnsafeBetweenSamples,
        Verdict::Unsafe,
        Verdict::PartlyUnsafe,
        Verdict::UnsafeStart,
    ];

    /// The kebab-case name used in JSON and tables.
    pub fn name(self) -> &'static str {
        match self {
            Verdict::Converges => "converges",
            Verdict::Trapped => "trapped",
            Verdict::Unknown => "unknown",
            Verdict::Invalid => "invalid",
            Verdict::UnsafeBetweenSamples => "unsafe-between-samples",
            Verdict::Unsafe => "unsafe",
            Verdict::PartlyUnsafe => "partly-unsafe",
            Verdict::UnsafeStart => "unsafe-start",
        }
    }

    /// `converges` or `trapped`: a proven outcome.
    pub fn is_verified(self) -> bool {
        matches!(self, Verdict::Converges | Verdict::Trapped)
    }

    /// The box started safe and was run.
    pub fn starts_safe(self) -> bool {
        !matches!(self, Verdict::PartlyUnsafe | Verdict::UnsafeStart)
    }

    /// Refinement may decide it (smaller boxes may also prove that the sets stay in `S`).
    pub fn is_refinable(self) -> bool {
        matches!(
            self,
            Verdict::Unknown | Verdict::Invalid | Verdict::UnsafeBetweenSamples
        )
    }
}

impl std::fmt::Display for Verdict {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

/// Why a verification could not run, or shard files could not be merged.
#[derive(Debug, thiserror::Error)]
pub enum VerifyError {
    /// Bad settings (region, grid, shard): the field and what is wrong.
    #[error("{field}: {message}")]
    Settings {
        /// The field of [`VerifySettings`] at fault.
        field: &'static str,
        /// What is wrong.
        message: String,
    },
    /// The reach engine failed.
    #[error(transparent)]
    Reach(#[from] ReachError),
    /// A verdict file is not valid JSON of this format.
    #[error("{file}: {message}")]
    Format {
        /// The file (or `<input>`).
        file: String,
        /// What is wrong.
        message: String,
    },
    /// Shard files do not fit together.
    #[error("cannot merge: {0}")]
    Merge(String),
    /// The run was asked to stop (an interrupt); its checkpoint holds the finished boxes.
    #[error("interrupted")]
    Interrupted,
}
