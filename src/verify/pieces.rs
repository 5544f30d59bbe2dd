//! The verdict of whole initial boxes: from a box's own tube, or, where that proves nothing,
//! from its pieces, split and refined as `verify` refines ([`verify_by_pieces`], `cbfreach
//! paper`). May import `reach` and `verify`'s verifier.

use super::checkpoint::Journal;
use super::{
    judge_with_feasibility, BoxVerdict, Reason, Trap, Verdict, Verifier, VerifyError,
    VerifySettings,
};
use crate::boxes::{fmt_point, IntervalBox};
use crate::reach::{CpuBackend, ReachProblem, ReachSettings, Tube};
use crate::scenario::Scenario;

/// Pieces per axis of an initial box that is not verified whole.
pub const SPLIT: usize = 4;

/// Boxes a refined box's pieces run in at a time: each finished chunk is journaled, so an
/// interrupt waits for at most one (seconds), while a 64-box batch still spreads the
/// network's weights over enough boxes (scenario 2's hard box runs ~2,700 pieces).
pub const PIECES_CHUNK: usize = 64;

/// Where [`verify_by_pieces`] keeps the finished pieces of initial box `k`, whose pieces run
/// as `settings` (a checkpoint a box, so that an interrupted run resumes: `cbfreach paper
/// --resume`); [`no_journals`] keeps nothing.
pub type PiecesJournals<'a> =
    dyn Fn(usize, &VerifySettings) -> Result<Box<dyn Journal>, VerifyError> + 'a;

/// Journals that keep nothing ([`PiecesJournals`]).
pub fn no_journals(_: usize, _: &VerifySettings) -> Result<Box<dyn Journal>, VerifyError> {
    Ok(Box::new(super::checkpoint::NoJournal))
}

/// Extra pieces refinement may run per initial box.
pub const REFINE_BUDGET: usize = 4096;

/// How [`verify_by_pieces`] refines the pieces of an initial box not verified whole
/// (`cbfreach paper --refine --max-substeps`).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PiecesSettings {
    /// Bisection rounds of the pieces not verified. Default: 10.
    pub refine: usize,
    /// In continuous time, the most substeps a refined piece's step is cut into
    /// ([`VerifySettings::max_substeps`]). Default: 8, twice `verify`'s: the pieces of
    /// scenario 2's box at (−1, 1.5) pass 0.11 from the jump of `v` at (3, 0), and at the
    /// tenth round (0.0016 wide, steps of dt/4 there) its corner piece's set still meets the
    /// error map's `M = ∞` cells; with dt/8 it converges (docs/results.md). Only pieces of
    /// depth ≥ 5 in two states see the difference.
    pub max_substeps: usize,
}

impl Default for PiecesSettings {
    fn default() -> Self {
        PiecesSettings {
            refine: 10,
            max_substeps: 8,
        }
    }
}

/// How an initial box got its verdict ([`verify_by_pieces`]); `Display` gives the note that
/// `cbfreach paper` prints.
#[derive(Clone, Debug, PartialEq)]
pub enum PieceOutcome {
    /// From the box's own tube.
    Whole {
        /// Why, where the verdict says more than itself.
        reason: Option<Reason>,
        /// The tube's last set (said where there is no reason).
        final_set: Option<IntervalBox>,
        /// For a verified box: whether the QP is proven feasible along its tube.
        feasible: Option<bool>,
    },
    /// Every piece has the same verified verdict.
    Pieces {
        /// The pieces (leaves of the refinement), with their verdicts and last sets: their
        /// count, sizes and proven-feasible share are read from them.
        leaves: Vec<BoxVerdict>,
    },
    /// The pieces did not all verify: the whole box's outcome stands.
    Undecided {
        /// The whole box's outcome ([`PieceOutcome::Whole`]).
        whole: Box<PieceOutcome>,
        /// Pieces verified.
        proven: usize,
        /// Pieces in all.
        pieces: usize,
        /// The narrowest and widest piece.
        width: (f64, f64),
    },
}

/// The verdict of one initial box and how it was reached.
#[derive(Clone, Debug, PartialEq)]
pub struct PiecesVerdict {
    /// The verdict.
    pub verdict: Verdict,
    /// How.
    pub outcome: PieceOutcome,
}

impl PiecesVerdict {
    /// The pieces that proved the verdict, where the box was proven in pieces.
    pub fn proven_pieces(&self) -> Option<&[BoxVerdict]> {
        match &self.outcome {
            PieceOutcome::Pieces { leaves, .. } => Some(leaves),
            _ => None,
        }
    }
}

/// Whether the filter's QP was proven feasible on every set of a verified box.
fn feasibility_clause(feasible: Option<bool>) -> &'static str {
    match feasible {
        Some(true) => "; QP proven feasible",
        Some(false) => "; QP feasibility not proven",
        None => "",
    }
}

/// The narrowest and widest of `leaves`, a piece's size being its widest side (bisection
/// halves one side at a time).
fn piece_widths(leaves: &[BoxVerdict]) -> (f64, f64) {
    leaves
        .iter()
        .map(|b| b.initial.widths().into_iter().fold(0.0_f64, f64::max))
        .fold((f64::INFINITY, 0.0_f64), |(lo, hi), w| {
            (lo.min(w), hi.max(w))
        })
}

/// `0.031` or `0.016–0.031`.
fn size((narrow, wide): (f64, f64)) -> String {
    let (narrow, wide) = (format!("{narrow:.3}"), format!("{wide:.3}"));
    if narrow == wide {
        wide
    } else {
        format!("{narrow}–{wide}")
    }
}

impl std::fmt::Display for PieceOutcome {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            PieceOutcome::Whole {
                reason,
                final_set,
                feasible,
            } => {
                match (reason, final_set) {
                    (Some(r), _) => write!(f, "{r}")?,
                    (None, Some(set)) => write!(
                        f,
                        "final set {} … {}",
                        fmt_point(&set.lower),
                        fmt_point(&set.upper)
                    )?,
                    (None, None) => {}
                }
                f.write_str(feasibility_clause(*feasible))
            }
            PieceOutcome::Pieces { .. } => Ok(()),
            PieceOutcome::Undecided {
                whole,
                proven,
                pieces,
                width,
            } => write!(
                f,
                "{whole} ({proven} of {pieces} pieces {} wide verified)",
                size(*width)
            ),
        }
    }
}

impl std::fmt::Display for PiecesVerdict {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match &self.outcome {
            PieceOutcome::Pieces { leaves } => {
                write!(
                    f,
                    "as {} pieces {} wide: every piece {}",
                    leaves.len(),
                    size(piece_widths(leaves)),
                    self.verdict.name()
                )?;
                let proven_feasible = |b: &&BoxVerdict| b.feasible == Some(true);
                let area = |b: &BoxVerdict| b.initial.volume();
                match leaves.iter().filter(proven_feasible).count() {
                    n if n == leaves.len() => f.write_str(feasibility_clause(Some(true))),
                    0 => f.write_str(feasibility_clause(Some(false))),
                    _ => write!(
                        f,
                        "; QP proven feasible on {:.1} % of the box",
                        100.0 * leaves.iter().filter(proven_feasible).map(area).sum::<f64>()
                            / leaves.iter().map(area).sum::<f64>()
                    ),
                }
            }
            other => write!(f, "{other}"),
        }
    }
}

/// The verdict of each initial box of `tubes` (their tubes under `reach`): from its own tube,
/// or, where that proves nothing (or does not prove the QP feasible), from its `SPLITⁿ`
/// pieces and `settings.refine` rounds of bisection of the pieces not verified (the
/// refinement of `verify`, on the CPU engine, cutting the step of deeper pieces up to
/// `settings.max_substeps` in continuous time), whose leaves must all share one verified
/// verdict.
/// Each split box's finished pieces go to its journal from `journals` (boxes it recorded are
/// not run again; [`VerifyError::Interrupted`] when it asks to stop). `progress` is told
/// (boxes split, boxes to split).
#[allow(clippy::too_many_arguments)]
pub fn verify_by_pieces(
    scenario: &Scenario,
    problem: &ReachProblem,
    reach: &ReachSettings,
    traps: &[Trap],
    tubes: &[Tube],
    settings: PiecesSettings,
    journals: &PiecesJournals<'_>,
    progress: &(dyn Fn(usize, usize) + Sync),
) -> Result<Vec<PiecesVerdict>, VerifyError> {
    let mut out: Vec<PiecesVerdict> = tubes
        .iter()
        .map(|tube| {
            let (j, feasible) = judge_with_feasibility(problem, scenario, traps, tube);
            PiecesVerdict {
                verdict: j.verdict,
                outcome: PieceOutcome::Whole {
                    final_set: tube.last().map(|l| l.set.clone()),
                    reason: j.reason,
                    feasible,
                },
            }
        })
        .collect();
    // Split what the whole box leaves open: its verdict, or the QP's feasibility along its
    // sets (the pieces' sets are narrower and may stay clear of where the QP fails).
    let retry: Vec<usize> = (0..tubes.len())
        .filter(|&k| {
            let v = out[k].verdict;
            let unproven = matches!(
                out[k].outcome,
                PieceOutcome::Whole {
                    feasible: Some(false),
                    ..
                }
            );
            v.is_refinable() || (v.is_verified() && unproven)
        })
        .collect();
    let verifier = Verifier {
        scenario,
        problem,
        backend: &CpuBackend,
        reach: reach.clone(),
        traps: traps.to_vec(),
    };
    progress(0, retry.len());
    for (done, &k) in retry.iter().enumerate() {
        let run = VerifySettings {
            region: Some(tubes[k].initial.clone()),
            grid: vec![SPLIT; scenario.n()],
            refine_depth: settings.refine,
            budget: REFINE_BUDGET,
            refine_feasibility: true,
            refine_boundary: false,
            max_substeps: settings.max_substeps,
            absorb: VerifySettings::default().absorb,
            shard: None,
            chunk: Some(PIECES_CHUNK),
        };
        let journal = journals(k, &run)?;
        let report = verifier.run_journaled(&run, &|_, _, _| {}, journal.as_ref())?;
        progress(done + 1, retry.len());
        let leaves = report.after;
        let proven = leaves.iter().filter(|b| b.verdict.is_verified()).count();
        match leaves.first().map(|b| b.verdict) {
            Some(v) if proven == leaves.len() && leaves.iter().all(|b| b.verdict == v) => {
                out[k] = PiecesVerdict {
                    verdict: v,
                    outcome: PieceOutcome::Pieces { leaves },
                };
            }
            _ => {
                let whole = std::mem::replace(
                    &mut out[k].outcome,
                    PieceOutcome::Whole {
                        reason: None,
                        final_set: None,
                        feasible: None,
                    },
                );
                out[k].outcome = PieceOutcome::Undecided {
                    whole: Box::new(whole),
                    proven,
                    pieces: leaves.len(),
                    width: piece_widths(&leaves),
                };
            }
        }
    }
    Ok(out)
}
