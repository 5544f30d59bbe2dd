//! How a reach run goes: [`ReachSettings`] (the one source of the CLI's defaults, and of a
//! scenario's `[settings.reach]` table) and what an engine cannot run ([`Unsupported`]). May
//! import `bounds` only.

use serde::{Deserialize, Serialize};

use crate::bounds::BoundMethod;

/// How NN-system boxes become sets of the filtered system.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize, clap::ValueEnum)]
#[serde(rename_all = "kebab-case")]
pub enum ReachMethod {
    /// The network's error as a bounded input disturbance (sound by construction).
    #[default]
    Disturbance,
    /// The paper's closeness radius and Minkowski sum (Theorem 2).
    Minkowski,
}

impl std::fmt::Display for ReachMethod {
    /// The command-line and JSON name (`disturbance`, `minkowski`).
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            ReachMethod::Disturbance => "disturbance",
            ReachMethod::Minkowski => "minkowski",
        })
    }
}

/// Settings of one reach run. `ReachSettings::default()` is what `cbfreach reach` and
/// `verify` run with no options; a scenario's `[settings.reach]` table sets any of the fields
/// by name (kebab-case values, e.g. `bounds = "crown"`), and command-line options override
/// both.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct ReachSettings {
    /// How the network is bounded over each box. Default: `forward-backward`.
    pub bounds: BoundMethod,
    /// Disturbance or Minkowski. Default: `disturbance`.
    pub method: ReachMethod,
    /// Record every K-th step (and always the last); at least 1. Default: 1.
    pub every: usize,
    /// Bound the network on each face of the box separately (tighter, 2n× the bound cost;
    /// immrax's `local` mode). Default: false.
    pub face_local: bool,
    /// Disturbance method: where the filtered system's own field (the filter's closed form)
    /// replaces or tightens the network and its error margin ([`super::pieces`]); both
    /// engines take it (the GPU's in `shaders/filter.wgsl`). Default: `closed-form`.
    pub exact: ExactField,
    /// Disturbance method with a transform: also run the embedding in x coordinates and keep, at
    /// every step, the intersection of the x-box with the parallelotope, each tightened by the
    /// other (CPU engine). A box in x follows the flow where it turns the set (sliding along a
    /// constraint) and the parallelotope where it contracts (near the goal). Default: true.
    pub intersect_x: bool,
    /// Continuous time, disturbance method, closed-form filters: where the filter is proven
    /// one smooth piece `Φ` on the set, also bound each step by `Φ`'s Taylor form to second
    /// order (`h²/2·DΦ·Φ` on the set's faces, a third-order remainder over the flowpipe;
    /// [`super::end_rates::taylor3_rates`]) beside the first-order one, whose `h²/2·DΦ·F` over
    /// the flowpipe grows with how far the set moves in a step. Both engines; asked of another
    /// time model, the run is refused. Default: false.
    pub taylor3: bool,
    /// Continuous time, disturbance method, a scalar input's closed form with constant `g`:
    /// where no piece is proven on the set, also bound the field on each slab by the lattice of
    /// the filter's pieces (`Fᵢ` is the larger or the smaller of smooth fields; the CPU
    /// engine's `lattice_slab_field`, the GPU's `lattice_rates`), which keeps how `v` moves with
    /// the state where an enclosure of `v` does not. Default: true.
    pub lattice: bool,
    /// Continuous time, with several frames (a transform and `intersect_x`): clip each frame's
    /// slabs by the other frames' sets over the step before bounding the field on them (design
    /// §7.1 item 7). Where the frames' boxes meet in a polygon, a face of one box is shorter
    /// within the other, and a rotating closed loop's sets no longer grow by the whole rotation
    /// a step. Both engines; no effect in one frame or another time model. Default: true.
    pub meet_slabs: bool,
}

/// Where the disturbance method uses the filter itself besides (or instead of) the network plus
/// its error margin ([`super::pieces`]).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize, clap::ValueEnum)]
#[serde(rename_all = "kebab-case")]
pub enum ExactField {
    /// Nowhere: the network and its margin on every step.
    #[default]
    Nowhere,
    /// `v = 0` where the filter is proven inactive on the set (any filter, QP included).
    Inactive,
    /// The filtered system's own field where the filter is provably one smooth function on
    /// the set (inactive, or one piece throughout: a closed form's binding row, a QP's active
    /// set), met with the network's bounds where a constraint binds; elsewhere the network's
    /// bounds met with the pieces' enclosures of `v` on each face (any QP filter on the CPU;
    /// the GPU engine only for the closed forms).
    ClosedForm,
}

impl ExactField {
    /// A clause for summaries (empty for [`ExactField::Nowhere`]).
    pub fn clause(self) -> &'static str {
        match self {
            ExactField::Nowhere => "",
            ExactField::Inactive => " (v = 0 where the filter is proven inactive)",
            ExactField::ClosedForm => {
                " (the filter's pieces: its own field where its active set is proven fixed \
                 on the set, its enclosures elsewhere)"
            }
        }
    }
}

/// Settings that do not fit together; each names the field.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
pub enum SettingsError {
    /// `face_local` with the Minkowski method.
    #[error(
        "face_local works with method = disturbance only (the Minkowski method's closeness rate \
         needs one C for the whole box)"
    )]
    FaceLocalNeedsDisturbance,
    /// `every = 0`.
    #[error("every must be at least 1")]
    EveryZero,
}

impl SettingsError {
    /// The field at fault.
    pub fn field(&self) -> &'static str {
        match self {
            SettingsError::FaceLocalNeedsDisturbance => "face_local",
            SettingsError::EveryZero => "every",
        }
    }
}

/// What an engine cannot run ([`super::Backend::supports`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq, thiserror::Error)]
pub enum Unsupported {
    /// The engine has no such network bounds.
    #[error("the engine has no {0} bounds")]
    Bounds(BoundMethod),
    /// The engine runs `time = "continuous"`, but not with this setting (named as a user sets
    /// it).
    #[error("the engine does not run time = \"continuous\" with {0}")]
    Continuous(&'static str),
    /// The engine runs `time = "sampled"`, but not with this setting (named as a user sets it).
    #[error("the engine does not run time = \"sampled\" with {0}")]
    Sampled(&'static str),
    /// The engine evaluates the one-row and scalar closed forms alone, not the active-set
    /// pieces of a general QP filter.
    #[error("the engine has no exact field for a general QP filter")]
    ExactGeneralQp,
    /// The scenario calls a function the engine does not evaluate (the device: `atan`, `atan2`).
    #[error("the engine does not evaluate {0}, which the scenario calls")]
    Function(&'static str),
}

impl ReachSettings {
    /// What the run takes exactly: as asked for with the disturbance method, nothing with the
    /// Minkowski method (whose embedding bounds the NN system).
    pub fn exact_field(&self) -> ExactField {
        match self.method {
            ReachMethod::Disturbance => self.exact,
            ReachMethod::Minkowski => ExactField::Nowhere,
        }
    }

    /// Checks combinations: the Minkowski method's closeness rate needs one slope matrix `C`
    /// for the whole box, which face-local bounds do not give; `every` is at least 1.
    pub fn validate(&self) -> Result<(), SettingsError> {
        if self.face_local && self.method == ReachMethod::Minkowski {
            return Err(SettingsError::FaceLocalNeedsDisturbance);
        }
        if self.every == 0 {
            return Err(SettingsError::EveryZero);
        }
        Ok(())
    }
}

impl Default for ReachSettings {
    fn default() -> Self {
        ReachSettings {
            bounds: BoundMethod::ForwardBackward,
            method: ReachMethod::Disturbance,
            every: 1,
            face_local: false,
            exact: ExactField::ClosedForm,
            intersect_x: true,
            taylor3: false,
            lattice: true,
            meet_slabs: true,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::ReachMethod;

    #[test]
    fn a_methods_printed_name_is_its_file_and_command_line_name() {
        for m in [ReachMethod::Disturbance, ReachMethod::Minkowski] {
            let json = serde_json::to_string(&m).expect("serialises");
            assert_eq!(json, format!("\"{m}\""));
            let flag = clap::ValueEnum::to_possible_value(&m).expect("a value");
            assert_eq!(flag.get_name(), m.to_string());
        }
    }
}
