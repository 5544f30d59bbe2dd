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
//! boxes (tighter network bounds, narrower sets). Unsafe-start cells are not refined, so the
//! *safe area* — the area of the cells that start safe — is the same before and after, and the
//! **verified share** is `area(converges ∪ trapped) / safe area`. With `refine_feasibility` it
//! also bisects verified leaves whose QP feasibility is not proven (after the undecided ones):
//! a half keeps its parent's verdict, which holds for every start in the parent, unless its own
//! sets prove one, and only its own sets can prove the QP feasible.
//!
//! **Shards**: `K/N` takes the K-th (1-based) of N contiguous slices of the grid's cells (axis 0
//! fastest), so a job array can split a large region; [`merge`] checks that the shards come from
//! the same run and tile the grid exactly, and joins them. The refinement budget applies per
//! shard.

use crate::reach::ExactField;
use rayon::prelude::*;
use std::collections::BTreeMap;
use std::ops::Range;
use std::str::FromStr;
use std::time::Instant;

use serde::{Deserialize, Serialize};

use crate::boxes::IntervalBox;
use crate::equilibria::{Equilibrium, Stability};
use crate::intervals::Interval;
use crate::reach::{Backend, ReachError, ReachProblem, ReachSettings, Tube};
use crate::scenario::Scenario;

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
    pub const ALL: [Verdict; 7] = [
        Verdict::Converges,
        Verdict::Trapped,
        Verdict::Unknown,
        Verdict::Invalid,
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

    /// Refinement may decide it.
    pub fn is_refinable(self) -> bool {
        matches!(self, Verdict::Unknown | Verdict::Invalid)
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
    /// Bad settings (region, grid, shard, budget).
    #[error("{0}")]
    Settings(String),
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
}

/// The K-th (1-based) of N contiguous slices of a grid's cells.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct Shard {
    /// K, in `1..=count`.
    pub index: usize,
    /// N ≥ 1.
    pub count: usize,
}

impl Shard {
    /// The cell indices of this shard among `total` cells: `[⌊(K−1)·total/N⌋, ⌊K·total/N⌋)`.
    pub fn range(&self, total: usize) -> Range<usize> {
        let at = |k: usize| (k as u128 * total as u128 / self.count as u128) as usize;
        at(self.index - 1)..at(self.index)
    }
}

impl FromStr for Shard {
    type Err = VerifyError;

    /// Parses `K/N` with `1 ≤ K ≤ N`.
    fn from_str(s: &str) -> Result<Shard, VerifyError> {
        let bad = |why: &str| {
            VerifyError::Settings(format!(
                "--shard {s}: {why} (expected K/N with 1 ≤ K ≤ N, e.g. 2/8 for the second of 8 slices)"
            ))
        };
        let (k, n) = s.split_once('/').ok_or_else(|| bad("no `/`"))?;
        let k: usize = k
            .trim()
            .parse()
            .map_err(|_| bad("K is not a whole number"))?;
        let n: usize = n
            .trim()
            .parse()
            .map_err(|_| bad("N is not a whole number"))?;
        if n == 0 {
            return Err(bad("N must be at least 1"));
        }
        if k == 0 || k > n {
            return Err(bad("K is out of range (shards are numbered from 1)"));
        }
        Ok(Shard { index: k, count: n })
    }
}

impl std::fmt::Display for Shard {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{}/{}", self.index, self.count)
    }
}

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

/// The verdict of one box.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct BoxVerdict {
    /// Index of the grid cell it comes from (axis 0 fastest).
    pub cell: usize,
    /// Bisections from that cell (0 for the cell itself).
    pub depth: usize,
    /// The initial box.
    pub initial: IntervalBox,
    /// The verdict.
    pub verdict: Verdict,
    /// The filtered-system set at the last recorded time (absent for skipped boxes).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub final_set: Option<IntervalBox>,
    /// The last recorded time.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub t_end: Option<f64>,
    /// Index into the report's traps, for `trapped`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub trap: Option<usize>,
    /// Why (`unsafe`: when and which CBF; `invalid`: when it left `C`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub note: Option<String>,
    /// For verified boxes: whether the filter's QP is proven feasible on every set of the tube
    /// ([`crate::reach::pieces::FilterPieces::proves_feasible`]). Where it is not, some
    /// trajectories may meet an infeasible QP and stop existing; the verdict speaks of those
    /// that exist.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub feasible: Option<bool>,
}

impl BoxVerdict {
    /// Verified, but the QP's feasibility along its sets is not proven.
    pub fn lacks_feasibility_proof(&self) -> bool {
        self.verdict.is_verified() && self.feasible == Some(false)
    }

    /// This half's verdict given the verdict of the box it was bisected from. A verified box's
    /// verdict holds for every start in it, so a half whose own sets prove nothing (`unknown`,
    /// `invalid`) keeps its parent's verdict and final set; only a feasibility proof must come
    /// from the half's own sets. (`unsafe` is kept: it flags a bug, never a property.)
    fn within(self, parent: &BoxVerdict) -> BoxVerdict {
        if !parent.verdict.is_verified() || !self.verdict.is_refinable() {
            return self;
        }
        BoxVerdict {
            cell: self.cell,
            depth: self.depth,
            initial: self.initial,
            note: Some(format!(
                "the verdict of the box it was bisected from (its own sets: {})",
                self.verdict.name()
            )),
            feasible: Some(false),
            ..parent.clone()
        }
    }
}

/// What a run was: everything two shards must share to be merged.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct RunInfo {
    /// Scenario name.
    pub scenario: String,
    /// Scenario file.
    pub scenario_file: String,
    /// The partitioned region.
    pub region: IntervalBox,
    /// Cells per axis.
    pub grid: Vec<usize>,
    /// The goal box.
    pub goal: IntervalBox,
    /// Reach method (`disturbance`, `minkowski`).
    pub method: String,
    /// Bound method.
    pub bounds: String,
    /// `M_C`.
    pub m_c: f64,
    /// The disturbance came from the local bounds of a certified error map, not from `m_c`.
    #[serde(default)]
    pub local_margin: bool,
    /// Face-local network bounds.
    #[serde(default)]
    pub face_local: bool,
    /// Where the filtered system's own field replaced the network (`ReachSettings::exact`).
    #[serde(default)]
    pub exact: ExactField,
    /// Whether the sets were the meet of a box in x and the parallelotope
    /// (`ReachSettings::intersect_x`).
    #[serde(default)]
    pub intersect_x: bool,
    /// Euler step.
    pub dt: f64,
    /// Euler steps.
    pub steps: usize,
    /// What the sets bound (`reach::TimeModel`): `continuous`, `sampled (T_s = …)`, `euler`
    /// (files from before the setting existed: empty, and their sets bound the Euler map).
    #[serde(default)]
    pub time: String,
    /// Whether the embedding ran in transformed coordinates.
    pub transformed: bool,
    /// The CBFs whose half-spaces bounded the sets (`reach::safe_set`; empty with
    /// `--no-safe-set` or none affine).
    #[serde(default)]
    pub safe_set: Vec<String>,
    /// Refinement depth.
    pub refine_depth: usize,
    /// Refinement budget (extra boxes, per shard).
    pub budget: usize,
    /// Refinement also bisected verified leaves whose QP feasibility was not proven.
    #[serde(default)]
    pub refine_feasibility: bool,
}

/// Wall times and work of a run.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct VerifyTiming {
    /// Seconds in the reach engine.
    pub reach_s: f64,
    /// Seconds in all.
    pub total_s: f64,
    /// Boxes run through the engine (cells and refined halves).
    pub boxes_run: usize,
    /// Euler box-steps.
    pub box_steps: usize,
}

/// Area per verdict of a set of boxes.
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct Shares {
    /// Area of the boxes with each verdict.
    pub area: BTreeMap<Verdict, f64>,
    /// Number of boxes with each verdict.
    pub count: BTreeMap<Verdict, usize>,
    /// Area of every box.
    pub total_area: f64,
    /// Area of the boxes that start safe.
    pub safe_area: f64,
    /// `area(converges ∪ trapped) / safe_area` (0 when nothing starts safe).
    pub verified_share: f64,
    /// The same for the verified boxes whose filter is proven feasible on every set.
    pub verified_feasible_share: f64,
}

impl Shares {
    /// Tallies the boxes.
    pub fn of(boxes: &[BoxVerdict]) -> Shares {
        let mut s = Shares::default();
        for b in boxes {
            let a = b.initial.volume();
            *s.area.entry(b.verdict).or_insert(0.0) += a;
            *s.count.entry(b.verdict).or_insert(0) += 1;
            s.total_area += a;
            if b.verdict.starts_safe() {
                s.safe_area += a;
            }
        }
        let verified: f64 = s
            .area
            .iter()
            .filter(|(v, _)| v.is_verified())
            .map(|(_, a)| a)
            .fold(0.0, |x, y| x + y);
        let feasible: f64 = boxes
            .iter()
            .filter(|b| b.verdict.is_verified() && b.feasible == Some(true))
            .map(|b| b.initial.volume())
            .fold(0.0, |x, y| x + y);
        if s.safe_area > 0.0 {
            s.verified_share = verified / s.safe_area;
            s.verified_feasible_share = feasible / s.safe_area;
        }
        s
    }

    /// Area with verdict `v` as a share of the safe area (of the total area for skipped
    /// verdicts).
    pub fn share(&self, v: Verdict) -> f64 {
        let a = self.area.get(&v).copied().unwrap_or(0.0);
        let whole = if v.starts_safe() {
            self.safe_area
        } else {
            self.total_area
        };
        if whole > 0.0 {
            a / whole
        } else {
            0.0
        }
    }
}

/// The verdicts of a run (or of a shard), as written to JSON.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct VerifyReport {
    /// [`FORMAT`].
    pub format: String,
    /// What was run.
    pub run: RunInfo,
    /// The shard, if this is one.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub shard: Option<Shard>,
    /// The grid cells covered: `[start, end)`.
    pub cells: [usize; 2],
    /// Trap boxes of stable undesirable equilibria.
    pub traps: Vec<Trap>,
    /// Verdicts of the grid cells, before refinement.
    pub before: Vec<BoxVerdict>,
    /// Verdicts of the leaves after refinement (equal to `before` without refinement).
    pub after: Vec<BoxVerdict>,
    /// Times.
    pub timing: VerifyTiming,
}

impl VerifyReport {
    /// Shares before refinement.
    pub fn shares_before(&self) -> Shares {
        Shares::of(&self.before)
    }

    /// Shares after refinement.
    pub fn shares_after(&self) -> Shares {
        Shares::of(&self.after)
    }

    /// Boxes whose sets met the unsafe set (should be none).
    pub fn unsafe_boxes(&self) -> Vec<&BoxVerdict> {
        self.after
            .iter()
            .chain(&self.before)
            .filter(|b| b.verdict == Verdict::Unsafe)
            .collect()
    }

    /// The report as JSON.
    pub fn to_json(&self) -> String {
        // Plain data with string keys: serialisation cannot fail.
        serde_json::to_string(self).unwrap_or_default()
    }

    /// Reads a report; `file` names it in errors.
    pub fn from_json(text: &str, file: &str) -> Result<VerifyReport, VerifyError> {
        let r: VerifyReport = serde_json::from_str(text).map_err(|e| VerifyError::Format {
            file: file.to_string(),
            message: format!("not a verdict file of cbfreach verify: {e}"),
        })?;
        if r.format != FORMAT {
            return Err(VerifyError::Format {
                file: file.to_string(),
                message: format!("format `{}`, expected `{FORMAT}`", r.format),
            });
        }
        Ok(r)
    }
}

/// Settings of a verification run.
#[derive(Clone, Debug)]
pub struct VerifySettings {
    /// The region to partition (inside `C`).
    pub region: IntervalBox,
    /// Cells per axis.
    pub grid: Vec<usize>,
    /// Bisection rounds of `unknown`/`invalid` leaves.
    pub refine_depth: usize,
    /// Most extra boxes refinement may run (per shard).
    pub budget: usize,
    /// Refinement also bisects verified leaves whose QP feasibility is not proven (after the
    /// unverified ones, within the same budget): their halves keep the verdict and may prove
    /// feasibility on their own sets.
    pub refine_feasibility: bool,
    /// Run only this slice of the cells.
    pub shard: Option<Shard>,
    /// Boxes per call of the engine (bounds memory; tubes are judged and dropped per chunk).
    pub chunk: usize,
}

impl VerifySettings {
    /// Checks the settings against the scenario; errors name the option.
    pub fn validate(&self, scenario: &Scenario) -> Result<(), VerifyError> {
        let n = scenario.n();
        let c = &scenario.reach.region;
        if self.region.dim() != n {
            return Err(VerifyError::Settings(format!(
                "--region: has {} coordinates, the system has {n} states",
                self.region.dim()
            )));
        }
        if !self.region.is_subset_of(c) {
            return Err(VerifyError::Settings(format!(
                "--region: {:?}…{:?} does not lie in the region C = {:?}…{:?} of {}",
                self.region.lower, self.region.upper, c.lower, c.upper, scenario.file
            )));
        }
        if self.region.widths().iter().any(|&w| w <= 0.0) {
            return Err(VerifyError::Settings(
                "--region: every side must have positive width".into(),
            ));
        }
        if self.grid.len() != n || self.grid.contains(&0) {
            return Err(VerifyError::Settings(format!(
                "--grid: expected {n} positive cell counts (e.g. 64,64), found {:?}",
                self.grid
            )));
        }
        let total = self.grid.iter().try_fold(1usize, |a, &k| a.checked_mul(k));
        match total {
            Some(t) if t <= 50_000_000 => {}
            _ => {
                return Err(VerifyError::Settings(format!(
                    "--grid: {:?} has too many cells (at most 50,000,000; use --shard)",
                    self.grid
                )))
            }
        }
        if let Some(s) = self.shard {
            let total = total.unwrap_or(0);
            if s.count > total {
                return Err(VerifyError::Settings(format!(
                    "--shard {s}: more shards than the {total} cells of the grid"
                )));
            }
        }
        Ok(())
    }
}

/// Which phase a progress report is about.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Stage {
    /// The grid cells.
    Cells,
    /// Refinement round `d` (1-based).
    Refine(usize),
}

/// `Some(UnsafeStart)`, `Some(PartlyUnsafe)` or `None` (the box starts safe), by interval
/// evaluation of every CBF over the box.
pub fn start_verdict(scenario: &Scenario, b: &IntervalBox) -> Option<Verdict> {
    let x = as_intervals(b);
    let hs: Vec<Interval> = scenario
        .cbfs
        .iter()
        .map(|c| c.h.eval_interval(&x))
        .collect();
    // NaN bounds (an expression undefined somewhere on the box) count as "maybe unsafe".
    if hs.iter().any(|h| h.upper < 0.0) {
        Some(Verdict::UnsafeStart)
    } else if !hs.iter().all(|h| h.lower >= 0.0) {
        Some(Verdict::PartlyUnsafe)
    } else {
        None
    }
}

fn as_intervals(b: &IntervalBox) -> Vec<Interval> {
    b.lower
        .iter()
        .zip(&b.upper)
        .map(|(&l, &u)| Interval::new(l, u))
        .collect()
}

/// Judges one tube (see the module docs for the order of the checks).
pub fn judge(
    problem: &ReachProblem,
    scenario: &Scenario,
    traps: &[Trap],
    tube: &Tube,
) -> (Verdict, Option<usize>, Option<String>) {
    for (k, s) in tube.tube.iter().enumerate() {
        let x = as_intervals(&s.set);
        for cbf in &scenario.cbfs {
            if cbf.h.eval_interval(&x).upper < 0.0 {
                let outside = format!(
                    "t = {:.3}: {} < 0 on the whole set {:?}…{:?}",
                    s.t, cbf.name, s.set.lower, s.set.upper
                );
                // `S` is forward invariant only while the QP has a solution: where it may have
                // none on an earlier set, every trajectory may have stopped there (the
                // scenario's CBFs may conflict), and a set outside `S` proves nothing.
                if !problem.proves_feasible_on(&tube.tube[..k]) {
                    return (
                        Verdict::Unknown,
                        None,
                        Some(format!(
                            "{outside}, after sets on which the QP is not proven feasible: \
                             the trajectories may have met an infeasible QP before"
                        )),
                    );
                }
                return (Verdict::Unsafe, None, Some(outside));
            }
        }
    }
    if !tube.valid {
        return (Verdict::Invalid, None, tube.note.clone());
    }
    let Some(last) = tube.last() else {
        return (Verdict::Unknown, None, Some("empty tube".into()));
    };
    if last.set.is_subset_of(&scenario.reach.goal) {
        return (Verdict::Converges, None, None);
    }
    if let Some(k) = traps.iter().position(|t| last.set.is_subset_of(&t.region)) {
        return (Verdict::Trapped, Some(k), None);
    }
    (Verdict::Unknown, None, None)
}

/// Runs the grid cells of one verification (or shard) and refines.
pub struct Verifier<'a> {
    /// The scenario (CBFs, goal).
    pub scenario: &'a Scenario,
    /// The compiled reach problem.
    pub problem: &'a ReachProblem,
    /// The engine.
    pub backend: &'a dyn Backend,
    /// Reach settings (`every` is forced to 1: the unsafe check looks at every step).
    pub reach: ReachSettings,
    /// Trap boxes.
    pub traps: Vec<Trap>,
}

impl Verifier<'_> {
    /// Verifies the cells of `settings.region` (of the shard, if any); `progress` gets the
    /// stage, boxes done and boxes in the stage.
    pub fn run(
        &self,
        settings: &VerifySettings,
        progress: &(dyn Fn(Stage, usize, usize) + Sync),
    ) -> Result<VerifyReport, VerifyError> {
        settings.validate(self.scenario)?;
        let clock = Instant::now();
        let all = settings.region.partition(&settings.grid);
        let range = settings.shard.map_or(0..all.len(), |s| s.range(all.len()));
        let mut timing = VerifyTiming::default();
        let cells: Vec<(usize, usize, IntervalBox)> =
            range.clone().map(|k| (k, 0, all[k].clone())).collect();
        let before = self.run_boxes(&cells, settings.chunk, &mut timing, &|d, t| {
            progress(Stage::Cells, d, t)
        })?;

        let mut leaves = before.clone();
        let mut left = settings.budget;
        for depth in 1..=settings.refine_depth {
            let latest = |i: &usize| leaves[*i].depth + 1 == depth;
            let undecided =
                (0..leaves.len()).filter(|i| latest(i) && leaves[*i].verdict.is_refinable());
            let unproven_feasible = (0..leaves.len()).filter(|i| {
                settings.refine_feasibility && latest(i) && leaves[*i].lacks_feasibility_proof()
            });
            // The undecided leaves take the budget first; the halves replace their parents in
            // place, so the parents go in leaf order.
            let mut parents: Vec<usize> =
                undecided.chain(unproven_feasible).take(left / 2).collect();
            parents.sort_unstable();
            if parents.is_empty() {
                break;
            }
            left -= 2 * parents.len();
            let children: Vec<(usize, usize, IntervalBox)> = parents
                .iter()
                .flat_map(|&i| {
                    let (l, r) = leaves[i].initial.bisect();
                    [(leaves[i].cell, depth, l), (leaves[i].cell, depth, r)]
                })
                .collect();
            let judged = self.run_boxes(&children, settings.chunk, &mut timing, &|d, t| {
                progress(Stage::Refine(depth), d, t)
            })?;
            // Replace each parent by its two halves, in place.
            let mut next = Vec::with_capacity(leaves.len() + parents.len());
            let mut halves = judged.into_iter();
            let mut p = parents.iter().peekable();
            for (i, b) in leaves.into_iter().enumerate() {
                if p.peek() == Some(&&i) {
                    p.next();
                    next.extend(halves.by_ref().take(2).map(|h| h.within(&b)));
                } else {
                    next.push(b);
                }
            }
            leaves = next;
        }
        timing.total_s = clock.elapsed().as_secs_f64();
        Ok(VerifyReport {
            format: FORMAT.into(),
            run: RunInfo {
                scenario: self.scenario.name.clone(),
                scenario_file: self.scenario.file.clone(),
                region: settings.region.clone(),
                grid: settings.grid.clone(),
                goal: self.scenario.reach.goal.clone(),
                method: serde_name(&self.reach.method),
                bounds: self.reach.bounds.name().to_string(),
                m_c: self.problem.m_c,
                local_margin: self.problem.error_map.is_some(),
                face_local: self.reach.face_local,
                exact: self.reach.exact_field(),
                intersect_x: self.problem.frames(&self.reach).len() > 1,
                dt: self.problem.dt,
                steps: self.problem.steps,
                time: self.problem.time.to_string(),
                transformed: self.problem.transform.is_some(),
                safe_set: (self.problem.safe_set_for(self.reach.method).names())
                    .into_iter()
                    .map(String::from)
                    .collect(),
                refine_depth: settings.refine_depth,
                budget: settings.budget,
                refine_feasibility: settings.refine_feasibility,
            },
            shard: settings.shard,
            cells: [range.start, range.end],
            traps: self.traps.clone(),
            before,
            after: leaves,
            timing,
        })
    }

    /// Start check, then the engine in chunks, then [`judge`]; keeps the input order.
    fn run_boxes(
        &self,
        boxes: &[(usize, usize, IntervalBox)],
        chunk: usize,
        timing: &mut VerifyTiming,
        progress: &(dyn Fn(usize, usize) + Sync),
    ) -> Result<Vec<BoxVerdict>, VerifyError> {
        let mut out: Vec<BoxVerdict> = boxes
            .iter()
            .map(|(cell, depth, b)| BoxVerdict {
                cell: *cell,
                depth: *depth,
                initial: b.clone(),
                verdict: start_verdict(self.scenario, b).unwrap_or(Verdict::Unknown),
                final_set: None,
                t_end: None,
                trap: None,
                note: None,
                feasible: None,
            })
            .collect();
        let to_run: Vec<usize> = (0..out.len())
            .filter(|&i| out[i].verdict.starts_safe())
            .collect();
        let total = to_run.len();
        let settings = ReachSettings {
            every: 1,
            ..self.reach.clone()
        };
        let chunk = chunk.max(1);
        progress(0, total);
        for (c, idx) in to_run.chunks(chunk).enumerate() {
            let initial: Vec<IntervalBox> = idx.iter().map(|&i| out[i].initial.clone()).collect();
            let done = c * chunk;
            let clock = Instant::now();
            let result = self
                .backend
                .reach(self.problem, &initial, &settings, &|s, all| {
                    progress(done + idx.len() * s / all.max(1), total)
                })?;
            timing.reach_s += clock.elapsed().as_secs_f64();
            timing.boxes_run += idx.len();
            // Judging (and the feasibility proof along each verified tube, an interval
            // evaluation of the QP's rows at every step) is per tube: in parallel, or it takes
            // longer than a GPU's reach.
            let (scenario, traps, problem) = (self.scenario, &self.traps, self.problem);
            let judged: Vec<_> = result
                .boxes
                .par_iter()
                .map(|tube| {
                    let (verdict, trap, note) = judge(problem, scenario, traps, tube);
                    let feasible = verdict
                        .is_verified()
                        .then(|| problem.proves_feasible_along(tube));
                    (verdict, trap, note, feasible)
                })
                .collect();
            for ((&i, tube), (verdict, trap, note, feasible)) in
                idx.iter().zip(&result.boxes).zip(judged)
            {
                let last = tube.last();
                timing.box_steps += tube.steps_run(self.problem.dt);
                let b = &mut out[i];
                b.verdict = verdict;
                b.trap = trap;
                b.note = note;
                b.final_set = last.map(|s| s.set.clone());
                b.t_end = last.map(|s| s.t);
                b.feasible = feasible;
            }
            progress((done + idx.len()).min(total), total);
        }
        Ok(out)
    }
}

fn serde_name<T: Serialize>(v: &T) -> String {
    match serde_json::to_value(v) {
        Ok(serde_json::Value::String(s)) => s,
        _ => String::new(),
    }
}

/// Joins shard reports (`(file name, report)`, any order) into one report over the whole grid.
/// They must come from the same run (scenario, region, grid, settings), have the same shard
/// count, and tile the grid's cells without gap or overlap.
pub fn merge(parts: Vec<(String, VerifyReport)>) -> Result<VerifyReport, VerifyError> {
    let Some((first_name, first)) = parts.first().cloned() else {
        return Err(VerifyError::Merge("no files given".into()));
    };
    let total: usize = first.run.grid.iter().product();
    for (name, r) in &parts[1..] {
        if r.run != first.run {
            let (a, b) = (
                serde_json::to_value(&first.run).unwrap_or_default(),
                serde_json::to_value(&r.run).unwrap_or_default(),
            );
            let differs: Vec<String> = match (a, b) {
                (serde_json::Value::Object(a), serde_json::Value::Object(b)) => a
                    .iter()
                    .filter(|(k, v)| b.get(*k) != Some(v))
                    .map(|(k, v)| {
                        format!(
                            "{k}: {v} in {first_name} but {} in {name}",
                            b.get(k).cloned().unwrap_or_default()
                        )
                    })
                    .collect(),
                _ => vec![],
            };
            return Err(VerifyError::Merge(format!(
                "{first_name} and {name} come from different runs ({})",
                differs.join("; ")
            )));
        }
        let count = |r: &VerifyReport| r.shard.map(|s| s.count);
        if count(r) != count(&first) {
            return Err(VerifyError::Merge(format!(
                "{first_name} is shard {} but {name} is shard {} (different shard counts)",
                first.shard.map_or("none".into(), |s| s.to_string()),
                r.shard.map_or("none".into(), |s| s.to_string())
            )));
        }
    }
    let mut parts = parts;
    parts.sort_by_key(|(_, r)| (r.cells[0], r.cells[1]));
    let mut at = 0;
    for (name, r) in &parts {
        if r.cells[1] > total || r.cells[0] > r.cells[1] {
            return Err(VerifyError::Merge(format!(
                "{name}: cells {}..{} do not fit the {total} cells of the grid",
                r.cells[0], r.cells[1]
            )));
        }
        if r.cells[0] < at {
            return Err(VerifyError::Merge(format!(
                "{name} overlaps another file: its cells {}..{} start before {at} (the same shard twice?)",
                r.cells[0], r.cells[1]
            )));
        }
        if r.cells[0] > at {
            return Err(VerifyError::Merge(format!(
                "cells {at}..{} are missing (a shard file not given?)",
                r.cells[0]
            )));
        }
        at = r.cells[1];
    }
    if at != total {
        return Err(VerifyError::Merge(format!(
            "cells {at}..{total} are missing (a shard file not given?)"
        )));
    }
    let mut merged = VerifyReport {
        format: FORMAT.into(),
        run: first.run.clone(),
        shard: None,
        cells: [0, total],
        traps: first.traps.clone(),
        before: Vec::new(),
        after: Vec::new(),
        timing: VerifyTiming::default(),
    };
    for (_, r) in parts {
        merged.before.extend(r.before);
        merged.after.extend(r.after);
        merged.timing.reach_s += r.timing.reach_s;
        merged.timing.total_s += r.timing.total_s;
        merged.timing.boxes_run += r.timing.boxes_run;
        merged.timing.box_steps += r.timing.box_steps;
    }
    Ok(merged)
}

/// What simulating starts in the verified boxes with the ground-truth filter found
/// ([`simulation_check`]).
#[derive(Clone, Debug, Default)]
pub struct SimulationCheck {
    /// Verified leaves simulated.
    pub boxes: usize,
    /// Starts simulated.
    pub starts: usize,
    /// Starts whose trajectory stopped early (an infeasible QP) in boxes whose feasibility was
    /// not proven: the filtered system is not defined there, so they neither confirm nor refute
    /// the verdict (in boxes proven feasible they count as disagreements).
    pub stopped: usize,
    /// Starts that end elsewhere than their box's verdict says, or stop at an infeasible QP in
    /// a box proven feasible: `(start, verdict, end)`.
    pub disagreements: Vec<(Vec<f64>, Verdict, Vec<f64>)>,
}

/// An independent check of the verdicts: simulates a `per_axis`ⁿ grid of starts (corners
/// included) in every `converges` or `trapped` leaf of `report` with the ground-truth filter
/// (the system the sets bound over the scenario's horizon: RK4 at `dt/10` in continuous time,
/// the control held over `dt` when sampled, Euler at `dt` for the Euler map) and checks that
/// each trajectory ends in the goal set or in its trap box. The sets bound the filtered system,
/// so a disagreement means a bug, an unsound `M`, or Euler's error across a basin boundary.
pub fn simulation_check(s: &Scenario, report: &VerifyReport, per_axis: usize) -> SimulationCheck {
    use crate::filter::SafetyFilter;
    use crate::simulate::{simulate_filtered, Integrator};
    let filter = SafetyFilter::new(s);
    let steps = s.reach.steps();
    let k = per_axis.max(1);
    let fraction = |i: usize| {
        if k == 1 {
            0.5
        } else {
            i as f64 / (k - 1) as f64
        }
    };
    let leaves: Vec<&BoxVerdict> = report
        .after
        .iter()
        .filter(|b| b.verdict.is_verified())
        .collect();
    let per_box: Vec<SimulationCheck> = leaves
        .par_iter()
        .map(|b| {
            let mut out = SimulationCheck {
                boxes: 1,
                ..SimulationCheck::default()
            };
            let target = match (b.verdict, b.trap) {
                (Verdict::Trapped, Some(t)) => &report.traps[t].region,
                _ => &s.reach.goal,
            };
            for code in 0..k.pow(s.n() as u32) {
                let at: Vec<f64> = (0..s.n())
                    .map(|d| fraction(code / k.pow(d as u32) % k))
                    .collect();
                let x0 = b.initial.point_at(&at);
                // The system the sets bound (`RunInfo::time`): the ODE by RK4 at dt/10, the
                // held control, or the Euler map.
                let tr = match report.run.time.split(' ').next() {
                    Some("continuous") => simulate_filtered(
                        &filter,
                        &x0,
                        s.reach.dt / 10.0,
                        10 * steps,
                        Integrator::Rk4,
                    ),
                    Some("sampled") => {
                        simulate_filtered(&filter, &x0, s.reach.dt, steps, Integrator::Zoh)
                    }
                    _ => simulate_filtered(&filter, &x0, s.reach.dt, steps, Integrator::Euler),
                };
                out.starts += 1;
                if tr.stopped.is_some() && b.feasible == Some(true) {
                    // The QP was proven feasible on every set, and the sets hold the Euler
                    // trajectory at every step.
                    out.disagreements.push((x0, b.verdict, tr.last().to_vec()));
                } else if tr.stopped.is_some() {
                    out.stopped += 1;
                } else if !target.contains(tr.last()) {
                    out.disagreements.push((x0, b.verdict, tr.last().to_vec()));
                }
            }
            out
        })
        .collect();
    per_box
        .into_iter()
        .fold(SimulationCheck::default(), |mut all, one| {
            all.boxes += one.boxes;
            all.starts += one.starts;
            all.stopped += one.stopped;
            all.disagreements.extend(one.disagreements);
            all
        })
}

/// Where the ground-truth filtered system goes from the centre of each leaf that was not
/// verified (`unknown` or `invalid`), as shares of the leaves' safe area
/// ([`explain_unverified`]). A diagnostic, not a proof: it separates what no sound set can
/// show (the system itself leaves `C`, or the horizon ends elsewhere) from what the network's
/// error and the over-approximation left open.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct UnverifiedCauses {
    /// Not verified (the sum of the four below).
    pub unverified: f64,
    /// The centre's trajectory leaves `C`, where `M_C` no longer holds.
    pub leaves_region: f64,
    /// The centre's trajectory stops at an infeasible QP.
    pub infeasible: f64,
    /// The centre's trajectory ends at `T` in neither the goal nor a trap box.
    pub ends_elsewhere: f64,
    /// The centre's trajectory ends in the goal or a trap box: the sets were too loose.
    pub too_loose: f64,
}

/// Simulates the centre of every `unknown` or `invalid` leaf of `report` with the ground-truth
/// filter (Euler at the scenario's `dt` over its horizon, as the engine integrates) and sorts
/// the leaves' area into [`UnverifiedCauses`].
pub fn explain_unverified(s: &Scenario, report: &VerifyReport) -> UnverifiedCauses {
    use crate::filter::SafetyFilter;
    use crate::simulate::{simulate_filtered, Integrator};
    let filter = SafetyFilter::new(s);
    let safe_area = Shares::of(&report.after).safe_area;
    if safe_area <= 0.0 {
        return UnverifiedCauses::default();
    }
    let ends_in_target =
        |x: &[f64]| s.reach.goal.contains(x) || report.traps.iter().any(|t| t.region.contains(x));
    report
        .after
        .par_iter()
        .filter(|b| b.verdict.is_refinable())
        .map(|b| {
            let share = b.initial.volume() / safe_area;
            let tr = simulate_filtered(
                &filter,
                &b.initial.center(),
                s.reach.dt,
                s.reach.steps(),
                Integrator::Euler,
            );
            let mut c = UnverifiedCauses {
                unverified: share,
                ..UnverifiedCauses::default()
            };
            if tr.x.iter().any(|x| !s.reach.region.contains(x)) {
                c.leaves_region = share;
            } else if tr.stopped.is_some() {
                c.infeasible = share;
            } else if ends_in_target(tr.last()) {
                c.too_loose = share;
            } else {
                c.ends_elsewhere = share;
            }
            c
        })
        .reduce(UnverifiedCauses::default, |a, b| UnverifiedCauses {
            unverified: a.unverified + b.unverified,
            leaves_region: a.leaves_region + b.leaves_region,
            infeasible: a.infeasible + b.infeasible,
            ends_elsewhere: a.ends_elsewhere + b.ends_elsewhere,
            too_loose: a.too_loose + b.too_loose,
        })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn shards_tile_the_cells() {
        for total in [1usize, 7, 100, 4096] {
            for n in 1..=total.min(9) {
                let mut at = 0;
                for k in 1..=n {
                    let r = Shard { index: k, count: n }.range(total);
                    assert_eq!(r.start, at);
                    at = r.end;
                }
                assert_eq!(at, total);
            }
        }
    }

    fn leaf(verdict: Verdict, lower: [f64; 2], upper: [f64; 2]) -> BoxVerdict {
        BoxVerdict {
            cell: 3,
            depth: 1,
            initial: IntervalBox {
                lower: lower.to_vec(),
                upper: upper.to_vec(),
            },
            verdict,
            final_set: None,
            t_end: Some(10.0),
            trap: None,
            note: None,
            feasible: None,
        }
    }

    #[test]
    fn a_half_of_a_verified_box_keeps_its_verdict() {
        let mut parent = leaf(Verdict::Trapped, [0.0, 0.0], [1.0, 1.0]);
        parent.depth = 0;
        parent.trap = Some(0);
        parent.feasible = Some(false);
        parent.final_set = Some(IntervalBox {
            lower: vec![2.9, -0.1],
            upper: vec![3.1, 0.1],
        });
        // The half's own sets prove nothing: the parent's verdict, trap and final set hold
        // for it, its own box and depth stay, and its QP feasibility is not proven.
        for own in [Verdict::Unknown, Verdict::Invalid] {
            let half = leaf(own, [0.0, 0.0], [0.5, 1.0]).within(&parent);
            assert_eq!(half.verdict, Verdict::Trapped);
            assert_eq!(half.trap, Some(0));
            assert_eq!(half.final_set, parent.final_set);
            assert_eq!(half.initial.upper, vec![0.5, 1.0]);
            assert_eq!(half.depth, 1);
            assert_eq!(half.feasible, Some(false));
            assert!(half.note.unwrap().contains(own.name()));
        }
        // A half verified on its own (here with the QP proven feasible) keeps its own proof;
        // `unsafe` (a bug) is never hidden.
        let mut proven = leaf(Verdict::Trapped, [0.5, 0.0], [1.0, 1.0]);
        proven.feasible = Some(true);
        assert_eq!(proven.clone().within(&parent), proven);
        let bug = leaf(Verdict::Unsafe, [0.5, 0.0], [1.0, 1.0]);
        assert_eq!(bug.clone().within(&parent), bug);
        // Halves of an unverified box are only their own.
        let unknown = leaf(Verdict::Unknown, [0.0, 0.0], [0.5, 1.0]);
        parent.verdict = Verdict::Unknown;
        assert_eq!(unknown.clone().within(&parent), unknown);
    }

    #[test]
    fn shard_parsing_explains_errors() {
        assert_eq!(
            "2/8".parse::<Shard>().unwrap(),
            Shard { index: 2, count: 8 }
        );
        for bad in ["0/4", "5/4", "1/0", "a/2", "3", "1/-2"] {
            let e = bad.parse::<Shard>().unwrap_err().to_string();
            assert!(e.contains("--shard"), "{e}");
        }
    }
}
