//! What a verification run reports: a verdict per box ([`BoxVerdict`]), the run's settings
//! ([`RunInfo`]), shares per verdict ([`Shares`]) and the JSON file ([`VerifyReport`]). May
//! import `verify`'s verdicts and shards.

use std::collections::BTreeMap;

use serde::{Deserialize, Serialize};

use super::{Shard, Trap, Verdict, VerifyError, FORMAT};
use crate::boxes::IntervalBox;
use crate::reach::ExactField;

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
    /// What ended its tube early, as data (the note says it in words).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub ended: Option<crate::reach::EndKind>,
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
    pub(super) fn within(self, parent: &BoxVerdict) -> BoxVerdict {
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

/// Serde's default of a count that was 1 before it was recorded.
fn one() -> usize {
    1
}

/// What a run was: everything two shards must share to be merged.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct RunInfo {
    /// Scenario name.
    pub scenario: String,
    /// Scenario file.
    pub scenario_file: String,
    /// The states' names, in the order of every box's coordinates (files from before them:
    /// none).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub states: Vec<String>,
    /// Units of states, inputs and time by name (`[system] units`; absent where none given).
    #[serde(default, skip_serializing_if = "BTreeMap::is_empty")]
    pub units: BTreeMap<String, String>,
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
    /// `ReachSettings::taylor3` (continuous time; files from before it: false).
    #[serde(default)]
    pub taylor3: bool,
    /// `ReachSettings::lattice` (continuous time; files from before it: false).
    #[serde(default)]
    pub lattice: bool,
    /// `ReachSettings::meet_slabs` where it applies (continuous time, several frames; files
    /// from before it: false).
    #[serde(default)]
    pub meet_slabs: bool,
    /// Frames turned about the closed loop's turn the sets were kept in besides x (continuous
    /// time, `reach.turned_frames`; 1: z alone; files from before it: 1).
    #[serde(default = "one")]
    pub turned_frames: usize,
    /// Euler step.
    pub dt: f64,
    /// Euler steps.
    pub steps: usize,
    /// What the sets bound (`reach::TimeModel`): `continuous`, `sampled (T_s = …)`, `euler`
    /// (files from before the setting existed: empty, and their sets bound the Euler map).
    #[serde(default)]
    pub time: String,
    /// Validated steps per `dt` of the grid's cells (1 outside continuous time).
    #[serde(default = "one")]
    pub substeps: usize,
    /// The most substeps refinement cut refined boxes' steps into
    /// (`VerifySettings::max_substeps`; files from before it: 1, refinement kept the step).
    #[serde(default = "one")]
    pub max_substeps: usize,
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
    /// Refinement also bisected `partly-unsafe` leaves (`VerifySettings::refine_boundary`):
    /// the safe area after refinement holds their halves that start in `S` (false in files
    /// from before it).
    #[serde(default)]
    pub refine_boundary: bool,
    /// The boxes proven absorbing, where tubes stopped (`VerifySettings::absorb`; none in
    /// files from before it: every tube ran to the horizon).
    #[serde(default)]
    pub absorbing: Vec<super::Absorbing>,
    /// Hash of the network file (`provenance::network_hash`), so that `merge` refuses shards
    /// run with different networks; empty when not recorded.
    #[serde(default, skip_serializing_if = "String::is_empty")]
    pub network_hash: String,
    /// Hash of the filter (`provenance::filter_hash`): shards of an edited scenario do not
    /// merge; empty when not recorded.
    #[serde(default, skip_serializing_if = "String::is_empty")]
    pub filter_hash: String,
}

/// Wall times and work of a run.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct VerifyTiming {
    /// Seconds in the reach engine.
    pub reach_s: f64,
    /// Seconds in all (the equilibria search included).
    pub total_s: f64,
    /// Seconds of the equilibria search (once per run, before the boxes).
    #[serde(default)]
    pub equilibria_s: f64,
    /// Boxes run through the engine (cells and refined halves).
    pub boxes_run: usize,
    /// Box-steps of the scenario's `dt` (as many as the Euler map takes over the same time).
    pub box_steps: usize,
    /// Steps of the integrator: box-steps times the substeps each was cut into (`--substeps`,
    /// and refinement's shorter steps under `continuous`: a refined box's box-step is two to
    /// four of them); `box_steps` where no step is cut.
    #[serde(default)]
    pub integration_steps: usize,
}

impl VerifyTiming {
    /// Counts a tube of `steps` box-steps, each cut into `per_dt` steps of the integrator.
    pub fn count_steps(&mut self, steps: usize, per_dt: usize) {
        self.box_steps += steps;
        self.integration_steps += steps * per_dt;
    }
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
    /// `area(converges ∪ trapped) / safe_area` (0 when nothing starts safe), boxes whose QP
    /// feasibility is not proven counted too: their verdicts cover only the trajectories that
    /// exist (do not meet an infeasible QP). Reported beside the headline, labelled.
    pub verified_share: f64,
    /// The same for the verified boxes whose filter is proven feasible on every set: the
    /// headline figure ([`Headline::verified`]).
    pub verified_feasible_share: f64,
}

/// The verified shares a report leads with, in the order they are printed: first the share
/// with the filter's QP proven feasible on every set, beside it the share that also counts
/// boxes whose verdict covers only the trajectories that exist. Written first in the JSON
/// (`headline`).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Headline {
    /// Share of the safe area verified with the QP proven feasible on every set (after
    /// refinement).
    pub verified: f64,
    /// Share verified counting boxes whose QP feasibility is not proven: their verdicts speak
    /// only of the trajectories that do not meet an infeasible QP.
    pub verified_existing_trajectories: f64,
    /// [`Headline::verified`] before refinement.
    pub verified_before_refinement: f64,
    /// [`Headline::verified_existing_trajectories`] before refinement.
    pub verified_existing_trajectories_before_refinement: f64,
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
    /// What stops the leaves whose sets were too loose (`verify` fills it after the run; a
    /// diagnosis, not a verdict).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub what_stops: Option<super::WhatStops>,
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

    /// The shares a report leads with (after refinement, and before).
    pub fn headline(&self) -> Headline {
        let (b, a) = (self.shares_before(), self.shares_after());
        Headline {
            verified: a.verified_feasible_share,
            verified_existing_trajectories: a.verified_share,
            verified_before_refinement: b.verified_feasible_share,
            verified_existing_trajectories_before_refinement: b.verified_share,
        }
    }

    /// Why the leaves that refinement could still decide (`unknown`, `invalid`,
    /// `unsafe-between-samples`) were not verified, by what ended their tubes: each cause's
    /// share of the safe area, largest first; `None` for tubes that ran to the horizon (or an
    /// absorbing box) and ended outside the goal and the traps.
    pub fn why_not_verified(&self) -> Vec<(Option<crate::reach::EndKind>, f64)> {
        let safe = self.shares_after().safe_area;
        let mut by: BTreeMap<Option<crate::reach::EndKind>, f64> = BTreeMap::new();
        for b in self.after.iter().filter(|b| b.verdict.is_refinable()) {
            *by.entry(b.ended).or_insert(0.0) += b.initial.volume();
        }
        let mut out: Vec<_> = match safe > 0.0 {
            true => by.into_iter().map(|(k, a)| (k, a / safe)).collect(),
            false => Vec::new(),
        };
        out.sort_by(|a, b| b.1.total_cmp(&a.1));
        out
    }

    /// Boxes whose sets met the unsafe set (should be none), each once: an unsafe box is not
    /// refined, so it is a leaf of `after` too (the same box is not counted twice).
    pub fn unsafe_boxes(&self) -> Vec<&BoxVerdict> {
        let after: Vec<&BoxVerdict> = self
            .after
            .iter()
            .filter(|b| b.verdict == Verdict::Unsafe)
            .collect();
        let before_only = self
            .before
            .iter()
            .filter(|b| b.verdict == Verdict::Unsafe && !after.contains(b));
        after.iter().copied().chain(before_only).collect()
    }

    /// The report as JSON, its [`Headline`] first (read back, the headline is recomputed
    /// from the boxes).
    pub fn to_json(&self) -> String {
        #[derive(Serialize)]
        struct Written<'a> {
            headline: Headline,
            #[serde(flatten)]
            report: &'a VerifyReport,
        }
        let written = Written {
            headline: self.headline(),
            report: self,
        };
        // Plain data with string keys: serialisation cannot fail.
        serde_json::to_string(&written).unwrap_or_default()
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

#[cfg(test)]
mod tests {
    use super::*;

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
            ended: None,
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

    /// The headline is the share proven feasible; the share of verdicts covering only the
    /// trajectories that exist comes beside it, and the JSON leads with both.
    #[test]
    fn the_headline_leads_with_the_share_proven_feasible() {
        let mut proven = leaf(Verdict::Converges, [0.0, 0.0], [1.0, 1.0]);
        proven.feasible = Some(true);
        let mut unproven = leaf(Verdict::Converges, [1.0, 0.0], [4.0, 1.0]);
        unproven.feasible = Some(false);
        let boxes = vec![proven, unproven];
        let report = VerifyReport {
            format: FORMAT.to_string(),
            run: RunInfo {
                scenario: "s".into(),
                scenario_file: "s.toml".into(),
                states: vec!["x1".into(), "x2".into()],
                units: BTreeMap::new(),
                region: IntervalBox::new(vec![0.0, 0.0], vec![4.0, 1.0]).unwrap(),
                grid: vec![2, 1],
                goal: IntervalBox::new(vec![0.0, 0.0], vec![0.1, 0.1]).unwrap(),
                method: "disturbance".into(),
                bounds: "forward-backward".into(),
                m_c: 0.1,
                local_margin: false,
                face_local: false,
                exact: ExactField::default(),
                intersect_x: false,
                taylor3: false,
                lattice: false,
                meet_slabs: false,
                turned_frames: 1,
                dt: 0.1,
                steps: 1,
                time: String::new(),
                substeps: 1,
                max_substeps: 1,
                transformed: false,
                safe_set: vec![],
                network_hash: String::new(),
                filter_hash: String::new(),
                refine_depth: 0,
                budget: 0,
                refine_feasibility: false,
                refine_boundary: false,
                absorbing: Vec::new(),
            },
            shard: None,
            cells: [0, 2],
            traps: vec![],
            before: boxes.clone(),
            after: boxes,
            timing: VerifyTiming::default(),
            what_stops: None,
        };
        let h = report.headline();
        assert_eq!(h.verified, 0.25);
        assert_eq!(h.verified_existing_trajectories, 1.0);
        let json = report.to_json();
        assert!(
            json.starts_with(
                r#"{"headline":{"verified":0.25,"verified_existing_trajectories":1.0,"#
            ),
            "{json}"
        );
        assert_eq!(VerifyReport::from_json(&json, "j").unwrap(), report);
    }
}
