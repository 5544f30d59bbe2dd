//! What a reach run gives per initial box: its [`Tube`] of recorded sets and how it ended
//! ([`TubeEnd`]), built alike by every engine. Imports boxes, serde and the validated step's `OpenCause`.

use serde::ser::{Serialize, SerializeStruct, Serializer};
use serde::Deserialize;

use crate::boxes::IntervalBox;
use crate::reach::validated::OpenCause;

/// One recorded time of a tube.
#[derive(Clone, Debug, serde::Serialize)]
pub struct TubeSample {
    /// Time `t`.
    pub t: f64,
    /// Lower corner of the box (x coordinates; with a transform, of the parallelotope's
    /// bounding box).
    pub lower: Vec<f64>,
    /// Upper corner.
    pub upper: Vec<f64>,
    /// Closeness radius `r_t` to add (Minkowski method; in z's ℓ∞ norm with a transform);
    /// 0 for the disturbance method.
    pub radius: f64,
    /// The z-box, with a transform.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub z_lower: Option<Vec<f64>>,
    /// The z-box, with a transform.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub z_upper: Option<Vec<f64>>,
    /// A box in x that contains the filtered system's set: `[lower, upper]` for the
    /// disturbance method (both within the safe set's half-spaces), the bounding box of the
    /// Minkowski sum otherwise.
    pub set: IntervalBox,
    /// In continuous time: an x-box that holds every true state since the previous sample
    /// (the steps' flowpipes), for checks that speak of all times.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub flowpipe: Option<IntervalBox>,
}

impl TubeSample {
    /// The box in x that bounds the filtered system's states at `t`.
    pub fn filtered_set(&self) -> &IntervalBox {
        &self.set
    }
}

/// Why a step turned the embedding state inside out: the step itself, or bounds of the field
/// that disagree (engines that cannot tell say [`Inversion::Unattributed`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Inversion {
    /// One bound of the field alone inverts the box: the field contracts faster than `1/dt`
    /// across the box, so the step is too large for this system.
    StepTooLarge,
    /// Each bound of the field alone keeps the box, but their meet inverts it: two sound
    /// bounds of the same field cannot disagree, so one of them is not a bound — the network's,
    /// widened by an `M` smaller than its actual error there.
    BoundsDisagree,
    /// The field kept the box, but the stepped set and the step's validated flowpipe (an
    /// a-priori enclosure of the same trajectories) do not meet: an assumption of both failed
    /// (the filter's QP without a solution along the way, or `M` below the network's error).
    PipeDisjoint,
    /// Not recorded by this engine.
    Unattributed,
}

/// How a tube ended: at the horizon, or early at time `t`, after which it says nothing.
/// Serialized (inside [`Tube`]) as `valid` and, for an early end, its [`Display`] as `note`.
///
/// [`Display`]: std::fmt::Display
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub enum TubeEnd {
    /// Every step ran and every set stayed in `C`.
    #[default]
    Horizon,
    /// The set at the sample time `t` lies in a box proven absorbing for the goal or a trap
    /// ([`super::absorb`]): every later state stays in that target, so the tube stops there (its
    /// last sample is that set). Only where the problem has absorbing boxes (`verify`).
    Absorbed {
        /// The sample time.
        t: f64,
    },
    /// The set left the region `C` at `t` (the tube's last sample is that set): the theorem
    /// and `M_C` only hold inside `C`.
    LeftRegion {
        /// The time of the step whose set left `C`.
        t: f64,
    },
    /// The step from `t` found no finite error bound where the set is, in every frame: cells of
    /// the error map without a certified bound (e.g. where `v` jumps), or a box beyond the map's
    /// region `C` (the set's x-box, or its step's a-priori enclosure).
    NoCertifiedBound {
        /// The start of the step that could not be taken.
        t: f64,
        /// The map certifies every cell of `C` ([`crate::reach::ReachProblem::certified_on_all_of_c`]),
        /// so the bound was asked beyond `C`: the sets grew too wide, not a jump of `v`.
        beyond_c: bool,
    },
    /// Continuous time: the flowpipe of the step ending at `t` left the region `C`.
    FlowpipeLeftRegion {
        /// The start of the step whose flowpipe left `C`.
        t: f64,
    },
    /// Continuous time: no a-priori enclosure of the step from `t` (Picard–Lindelöf did not
    /// close with step `h`).
    NoEnclosure {
        /// The start of the step.
        t: f64,
        /// The validated step's size.
        h: f64,
        /// Why it did not close.
        cause: OpenCause,
    },
    /// Sampled-data: no enclosure of the motion between samples from `t`.
    NoIntersampleEnclosure {
        /// The start of the period.
        t: f64,
    },
    /// The embedding state's lower corner passed its upper one at `t`.
    Inverted {
        /// The time of the step.
        t: f64,
        /// Which term of the step turned the box inside out.
        cause: Inversion,
    },
    /// The embedding state overflowed (or became NaN) at `t`.
    NonFinite {
        /// The time of the step.
        t: f64,
    },
}

/// What ended a tube early, as data: [`TubeEnd`] without its times, for summaries (`verify`
/// sums the area of the boxes not verified by it).
#[derive(
    Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Hash, serde::Serialize, Deserialize,
)]
#[serde(rename_all = "kebab-case")]
pub enum EndKind {
    /// The set, or the flowpipe of a step, left `C`.
    LeftRegion,
    /// Trajectories from the initial box provably leave `C` in the first step: `C` is not
    /// invariant there.
    ExitsAtStart,
    /// The set holds states proven to leave `C` within a step (it may hold more than the
    /// reachable states).
    Exits,
    /// A step's enclosure reaches past a side of `C` not proven inward.
    PastRegion,
    /// A step's enclosure grew faster than it closed within `C`.
    NoEnclosure,
    /// No finite error bound where the set is (`M = ∞` cells, or beyond `C`).
    NoCertifiedBound,
    /// The error map certifies all of `C`, and the set or its step reached past it: the sets
    /// grew too wide, not a hole in the map.
    BoundBeyondC,
    /// Sampled data: no enclosure of the motion between samples.
    NoIntersampleEnclosure,
    /// The set turned inside out.
    Inverted,
    /// The set turned inside out after sets on which the QP is not proven feasible: the
    /// trajectories may have met an infeasible QP, where no bound of `v` holds.
    InvertedAfterUnprovenQp,
    /// The embedding state overflowed.
    NonFinite,
}

impl EndKind {
    /// What it says to a user, in a few words.
    pub fn describe(self) -> &'static str {
        match self {
            EndKind::LeftRegion => "the sets left C",
            EndKind::ExitsAtStart => {
                "trajectories from the box provably leave C at once (C is not invariant there: \
                 verify a region inside C)"
            }
            EndKind::Exits => "the sets hold states proven to leave C",
            EndKind::PastRegion => "a step's enclosure reached past C",
            EndKind::NoEnclosure => "a step's enclosure did not close (substeps may help)",
            EndKind::NoCertifiedBound => "the sets met cells with no certified error bound",
            EndKind::BoundBeyondC => {
                "the sets grew past C, where the error map certifies nothing (smaller boxes \
                 keep them in C)"
            }
            EndKind::NoIntersampleEnclosure => "no enclosure of the motion between samples",
            EndKind::Inverted => "the sets turned inside out",
            EndKind::InvertedAfterUnprovenQp => {
                "the sets turned inside out after sets on which the QP is not proven feasible \
                 (the trajectories may meet an infeasible QP)"
            }
            EndKind::NonFinite => "the embedding state overflowed",
        }
    }
}

impl TubeEnd {
    /// What ended the tube early (`None` at the horizon or in an absorbing box).
    pub fn kind(&self) -> Option<EndKind> {
        Some(match *self {
            TubeEnd::Horizon | TubeEnd::Absorbed { .. } => return None,
            TubeEnd::LeftRegion { .. } | TubeEnd::FlowpipeLeftRegion { .. } => EndKind::LeftRegion,
            TubeEnd::NoCertifiedBound {
                beyond_c: false, ..
            } => EndKind::NoCertifiedBound,
            TubeEnd::NoCertifiedBound { beyond_c: true, .. } => EndKind::BoundBeyondC,
            TubeEnd::NoEnclosure { cause, .. } => match cause {
                OpenCause::ExitsFromStart => EndKind::ExitsAtStart,
                OpenCause::Exits => EndKind::Exits,
                OpenCause::PastC => EndKind::PastRegion,
                OpenCause::Grows => EndKind::NoEnclosure,
            },
            TubeEnd::NoIntersampleEnclosure { .. } => EndKind::NoIntersampleEnclosure,
            TubeEnd::Inverted { .. } => EndKind::Inverted,
            TubeEnd::NonFinite { .. } => EndKind::NonFinite,
        })
    }

    /// Whether the tube ran to the horizon inside `C` (its sets bound the filtered system
    /// throughout), or stopped in an absorbing box, which bounds it from there on.
    pub fn valid(&self) -> bool {
        matches!(self, TubeEnd::Horizon | TubeEnd::Absorbed { .. })
    }

    /// The same end `by` later (a step taken from `t = 0` placed in a longer tube).
    pub fn later(self, by: f64) -> TubeEnd {
        let mut end = self;
        match &mut end {
            TubeEnd::Horizon => {}
            TubeEnd::Absorbed { t }
            | TubeEnd::LeftRegion { t }
            | TubeEnd::NoCertifiedBound { t, .. }
            | TubeEnd::FlowpipeLeftRegion { t }
            | TubeEnd::NoEnclosure { t, .. }
            | TubeEnd::NoIntersampleEnclosure { t }
            | TubeEnd::Inverted { t, .. }
            | TubeEnd::NonFinite { t } => *t += by,
        }
        end
    }

    /// When the tube ended early (`None` at the horizon).
    pub fn t(&self) -> Option<f64> {
        match *self {
            TubeEnd::Horizon => None,
            TubeEnd::Absorbed { t }
            | TubeEnd::LeftRegion { t }
            | TubeEnd::NoCertifiedBound { t, .. }
            | TubeEnd::FlowpipeLeftRegion { t }
            | TubeEnd::NoEnclosure { t, .. }
            | TubeEnd::NoIntersampleEnclosure { t }
            | TubeEnd::Inverted { t, .. }
            | TubeEnd::NonFinite { t } => Some(t),
        }
    }
}

impl std::fmt::Display for TubeEnd {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let became = |f: &mut std::fmt::Formatter<'_>, t: f64, what: &str| {
            write!(
                f,
                "t = {t:.3}: the embedding state became {what} (a step too large for this \
                 system, M below the network's error, or a QP without a solution on the way)"
            )
        };
        match *self {
            TubeEnd::Horizon => f.write_str("ran to the horizon"),
            TubeEnd::Absorbed { t } => write!(
                f,
                "t = {t:.3}: absorbed: the set lies in a box proven absorbing for the goal or a \
                 trap, so every later state stays in that target"
            ),
            TubeEnd::LeftRegion { t } => write!(f, "t = {t:.3}: the set left the region C"),
            TubeEnd::NoCertifiedBound { t, beyond_c: false } => write!(
                f,
                "t = {t:.3}: the set meets cells of the error map with no certified bound \
                 (M = ∞), or its step reaches beyond C"
            ),
            TubeEnd::NoCertifiedBound { t, beyond_c: true } => write!(
                f,
                "t = {t:.3}: the step needs the error bound beyond C, where the error map \
                 certifies nothing (the set or its step's enclosure reaches past C's sides): the \
                 sets grew too wide here (from the field itself, or from a large M); smaller \
                 boxes keep them in C"
            ),
            TubeEnd::FlowpipeLeftRegion { t } => {
                write!(f, "t = {t:.3}: the flowpipe of the step left the region C")
            }
            TubeEnd::NoEnclosure {
                t,
                h,
                cause: OpenCause::Grows,
            } => write!(
                f,
                "t = {t:.3}: no a-priori enclosure of the step (Picard–Lindelöf did not close \
                 with h = {h}; more substeps may close it)"
            ),
            TubeEnd::NoEnclosure {
                t,
                cause: OpenCause::PastC,
                ..
            } => write!(
                f,
                "t = {t:.3}: no enclosure of the step within C: it reaches past a side of C \
                 that the field is not proven to point into (states of the set may leave C, or \
                 the field's bounds are too wide to rule it out; smaller boxes may keep it in, \
                 substeps do not)"
            ),
            TubeEnd::NoEnclosure {
                h,
                cause: OpenCause::ExitsFromStart,
                ..
            } => write!(
                f,
                "t = 0: trajectories from the initial box provably leave C within {h}: C is not \
                 invariant there"
            ),
            TubeEnd::NoEnclosure {
                t,
                h,
                cause: OpenCause::Exits,
            } => write!(
                f,
                "t = {t:.3}: the set holds states that provably leave C within the next {h} \
                 (the set may hold more than the reachable states: smaller boxes may keep it in \
                 C)"
            ),
            TubeEnd::NoIntersampleEnclosure { t } => {
                write!(f, "t = {t:.3}: no enclosure of the motion between samples")
            }
            TubeEnd::Inverted {
                t,
                cause: Inversion::StepTooLarge,
            } => write!(
                f,
                "t = {t:.3}: the embedding state became inverted: the field contracts faster \
                 than 1/dt across the box (a smaller dt, or more substeps)"
            ),
            TubeEnd::Inverted {
                t,
                cause: Inversion::BoundsDisagree,
            } => write!(
                f,
                "t = {t:.3}: the embedding state became inverted: the network's bounds widened \
                 by M and the filter's own bounds of the field disagree, so M is below the \
                 network's actual error there (a certified M: m_c = \"certified\" or \"local\")"
            ),
            TubeEnd::Inverted {
                t,
                cause: Inversion::PipeDisjoint,
            } => write!(
                f,
                "t = {t:.3}: the embedding state became inverted: the stepped set and the step's \
                 validated enclosure do not meet, so an assumption of both failed (a QP without \
                 a solution on the way, or M below the network's error)"
            ),
            TubeEnd::Inverted { t, .. } => became(f, t, "inverted"),
            TubeEnd::NonFinite { t } => became(f, t, "non-finite"),
        }
    }
}

/// As the fields `valid` and, for an end before the horizon (absorbed included), `note` (the
/// ending's text) of the tube.
impl Serialize for TubeEnd {
    fn serialize<S: Serializer>(&self, serializer: S) -> Result<S::Ok, S::Error> {
        let early = *self != TubeEnd::Horizon;
        let mut s = serializer.serialize_struct("TubeEnd", if early { 2 } else { 1 })?;
        s.serialize_field("valid", &self.valid())?;
        if early {
            s.serialize_field("note", &self.to_string())?;
        }
        s.end()
    }
}

/// Sampled-data: the first step whose set, or whose enclosure of the motion since the step
/// before, is not proven inside `S` (`hᵢ ≥ 0` on all of it). A digitally implemented filter
/// does not keep `S` invariant between samples, so this is a finding about the system (the
/// held input may carry the state out of `S`), not a bug; the tube goes on, its sets still
/// bound the sampled system.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct UnsafeBetweenSamples {
    /// The end of the step.
    pub t: f64,
    /// The CBF not proven nonnegative.
    pub cbf: String,
    /// Whether the set at `t` lies entirely outside `S` (`hᵢ < 0` on all of it): every
    /// trajectory from the box is unsafe then.
    pub entirely: bool,
}

impl std::fmt::Display for UnsafeBetweenSamples {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self.entirely {
            true => write!(
                f,
                "t = {:.3}: {} < 0 on the whole set: the held input carried every state out of S",
                self.t, self.cbf
            ),
            false => write!(
                f,
                "t = {:.3}: {} ≥ 0 not proven on the set or the motion since the last step: the \
                 held input may carry states out of S between samples",
                self.t, self.cbf
            ),
        }
    }
}

/// The sets of one initial box over time.
#[derive(Clone, Debug, serde::Serialize)]
pub struct Tube {
    /// The initial box.
    pub initial: IntervalBox,
    /// Recorded times (every K-th step and the last).
    pub tube: Vec<TubeSample>,
    /// How the tube ended: the result says nothing after an early end.
    #[serde(flatten)]
    pub end: TubeEnd,
    /// Engine steps (`substeps` per `dt`) that integrated the filtered system's own field, the
    /// filter proven one smooth function on the set ([`super::ReachSettings::exact`]).
    pub exact_steps: usize,
    /// Engine steps whose field also took the closed form's enclosures of `v` on the set's faces
    /// ([`super::ExactField::ClosedForm`], where no piece was proven).
    pub enclosed_steps: usize,
    /// Sampled-data: where the sets first may leave `S` (absent otherwise).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub unsafe_between_samples: Option<UnsafeBetweenSamples>,
}

impl Tube {
    /// A tube that starts at `initial` with no samples yet.
    pub fn new(initial: IntervalBox) -> Tube {
        Tube {
            initial,
            tube: Vec::new(),
            end: TubeEnd::Horizon,
            exact_steps: 0,
            enclosed_steps: 0,
            unsafe_between_samples: None,
        }
    }

    /// False when the tube ended early (e.g. its set left `C`): the result says nothing from
    /// then on.
    pub fn valid(&self) -> bool {
        self.end.valid()
    }

    /// Why the tube ended before the horizon, as text (`None` when it ran to it).
    pub fn note(&self) -> Option<String> {
        (self.end != TubeEnd::Horizon).then(|| self.end.to_string())
    }

    /// The recorded samples of the model: all of them but the set a tube left `C` on, which
    /// ends it without being a state the model reaches inside `C` (no other end pushes one).
    pub fn model_samples(&self) -> &[TubeSample] {
        match self.end {
            TubeEnd::LeftRegion { .. } | TubeEnd::FlowpipeLeftRegion { .. } => {
                &self.tube[..self.tube.len().saturating_sub(1)]
            }
            _ => &self.tube,
        }
    }

    /// The last recorded sample.
    pub fn last(&self) -> Option<&TubeSample> {
        self.tube.last()
    }

    /// Euler steps of size `dt` this tube ran: a box stops where its set leaves `C`, so rates
    /// count these, not boxes × steps.
    pub fn steps_run(&self, dt: f64) -> usize {
        self.last().map_or(0, |l| (l.t / dt).round() as usize)
    }

    /// Engine steps (`k` a `dt`) this tube took, the one that turned its set inside out or
    /// non-finite included (its field was computed, and counted in [`Tube::exact_steps`]).
    pub fn engine_steps(&self, dt: f64, k: usize) -> usize {
        match self.end {
            TubeEnd::Inverted { t, .. } | TubeEnd::NonFinite { t } => {
                (t * k as f64 / dt).round() as usize
            }
            _ => self.steps_run(dt) * k,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// `verify`'s summary of what ended the tubes tells a hole in the error map from sets that
    /// grew past `C` (a 6-state run said "cells with no certified error bound" for all of its
    /// boxes, of a map that certified every cell).
    #[test]
    fn an_error_bound_asked_beyond_c_is_its_own_kind() {
        let end = |beyond_c| TubeEnd::NoCertifiedBound { t: 0.5, beyond_c };
        assert_eq!(end(false).kind(), Some(EndKind::NoCertifiedBound));
        assert_eq!(end(true).kind(), Some(EndKind::BoundBeyondC));
        assert!(EndKind::BoundBeyondC.describe().contains("grew past C"));
        let json = serde_json::to_string(&EndKind::BoundBeyondC).unwrap();
        assert_eq!(json, "\"bound-beyond-c\"");
    }

    /// The JSON of a tube is as before the ending became a type: `valid`, then `note` only for
    /// an early end, between the samples and the step counts.
    #[test]
    fn a_tube_serializes_its_end_as_valid_and_note() {
        let b = IntervalBox::new(vec![0.0], vec![1.0]).unwrap();
        let mut tube = Tube::new(b);
        let json = serde_json::to_string(&tube).unwrap();
        assert_eq!(
            json,
            r#"{"initial":{"lower":[0.0],"upper":[1.0]},"tube":[],"valid":true,"exact_steps":0,"enclosed_steps":0}"#
        );
        tube.end = TubeEnd::LeftRegion { t: 0.25 };
        let json = serde_json::to_string(&tube).unwrap();
        assert!(
            json.ends_with(
                r#""tube":[],"valid":false,"note":"t = 0.250: the set left the region C","exact_steps":0,"enclosed_steps":0}"#
            ),
            "{json}"
        );
        assert_eq!(tube.note().unwrap(), "t = 0.250: the set left the region C");
        assert!(!tube.valid() && tube.end.t() == Some(0.25));
    }
}
