//! Reachable sets of the filtered system from many initial boxes (paper §3, docs/design.md §2).
//!
//! A [`ReachProblem`] is the compiled problem (scenario dynamics, network, region `C`, `M_C`,
//! `dt`, horizon); a [`Backend`] runs one Euler trajectory of the embedding system per box and
//! returns a [`Tube`] per box. Two methods turn NN-system boxes into filtered-system sets:
//!
//! - [`ReachMethod::Disturbance`] (default, sound by construction): on `C`,
//!   `v(x) ∈ N(x) + [−M_C, M_C]`, so the filtered system is the NN system with a bounded input
//!   disturbance and the embedding with `d̲ − M_C, d̄ + M_C` bounds it directly;
//! - [`ReachMethod::Minkowski`] (the paper's Theorem 2, labelled as such): the NN-system box
//!   plus the closeness radius `r_t` of [`closeness`]. docs/design.md §2.6 explains the gap in its proof.
//!
//! The disturbance method's sets are intersected with the safe set's affine half-spaces at
//! every step ([`safe_set`]: the filter keeps the system in `S`). Every box's result is marked
//! invalid from the first step where its set leaves `C`: the theorem (and `M_C`) only hold
//! inside `C`.

pub mod absorb;
pub mod closeness;
pub mod cpu;
pub mod embedding;
pub mod end_rates;
pub mod engine;
pub mod pieces;
pub mod safe_set;
pub mod sampled;
pub mod sampled_second;
pub mod settings;
pub mod time;
pub mod transform;
pub mod tube;
pub mod turning;
pub mod validated;

use serde::Serialize;

use crate::bounds::BoundMethod;
use crate::boxes::IntervalBox;
use crate::intervals::{box_of, Interval};
use crate::network::Mlp;
use crate::scenario::{Norm, Scenario};
use embedding::Dynamics;
pub use safe_set::SafeSet;
pub use time::TimeModel;
pub use transform::{log_norm_inf, CoordinatesReason, Transform};
pub use tube::{EndKind, Inversion, Tube, TubeEnd, TubeSample, UnsafeBetweenSamples};
pub use turning::{Transient, Turning};

pub use cpu::{BatchBounds, Bounded, CpuBackend};
pub use engine::{choose_engine, refusal, EngineChoice, GpuOptions, AUTO_GPU_BOXES};
pub use settings::{ExactField, ReachMethod, ReachSettings, SettingsError, Unsupported};

/// Why a reach run could not start.
#[derive(Debug, thiserror::Error)]
pub enum ReachError {
    /// The network does not map states to inputs.
    #[error("the network maps ℝ^{net_in} → ℝ^{net_out} but the scenario needs ℝ^{n} → ℝ^{m}")]
    NetworkShape {
        /// Network input dimension.
        net_in: usize,
        /// Network output dimension.
        net_out: usize,
        /// States.
        n: usize,
        /// Inputs.
        m: usize,
    },
    /// An initial box has the wrong dimension or does not lie in `C`.
    #[error("initial box {index}: {message}")]
    InitialBox {
        /// Its index.
        index: usize,
        /// What is wrong.
        message: String,
    },
    /// Bad problem data (`M_C`, the transform's size, the error map's cover).
    #[error("{0}")]
    Settings(String),
    /// Settings that do not fit together (the field is named).
    #[error(transparent)]
    InvalidSettings(#[from] SettingsError),
    /// The network bounds failed.
    #[error(transparent)]
    Bounds(#[from] crate::bounds::BoundsError),
    /// The GPU engine failed.
    #[error(transparent)]
    Gpu(#[from] crate::gpu::GpuError),
}

/// The compiled reach problem: plain data that every backend reads.
#[derive(Clone, Debug)]
pub struct ReachProblem {
    /// The dynamics.
    pub dynamics: Dynamics,
    /// The network `N`.
    pub network: Mlp,
    /// The region `C`.
    pub region: IntervalBox,
    /// `M_C`, the bound on `‖N − v‖∞` over `C` (per input).
    pub m_c: f64,
    /// Certified per-cell error bounds (`cbfreach error`): when present the disturbance method
    /// uses the bound over the cells that the current set meets (a local `M`) instead of `m_c`.
    pub error_map: Option<crate::error_map::ErrorMap>,
    /// Coordinates `z = T x` the embedding runs in (`None`: x itself).
    pub transform: Option<Transform>,
    /// Extra input disturbance from rounding `W₁S` in the transformed network.
    pub network_slack: f64,
    /// Extra state-derivative slack from using `T` for `S⁻¹` (0 without a transform).
    pub field_slack: f64,
    /// Norm of the closeness radius.
    pub norm: Norm,
    /// Euler step.
    pub dt: f64,
    /// Number of steps.
    pub steps: usize,
    /// `[Df̃](C)`: the interval Jacobian over `C` (over `C`'s z-box with a transform), for the
    /// closeness radius's `c_k`.
    pub jacobian_over_region: Vec<Interval>,
    /// `[g](C)`, n×m.
    pub g_over_region: Vec<Interval>,
    /// `ℓ ≥ sup_{x∈C} ‖g(x)‖`.
    pub input_gain: f64,
    /// The affine CBFs' half-spaces: the disturbance method's sets are intersected with them at
    /// every step ([`safe_set`]; `SafeSet::default()` switches it off).
    pub safe_set: SafeSet,
    /// The filter's smooth pieces over sets ([`ReachSettings::exact`]).
    pub pieces: pieces::FilterPieces,
    /// With a transform: the same problem in x coordinates, for [`ReachSettings::intersect_x`].
    pub in_x: Option<Box<ReachProblem>>,
    /// Continuous time, where the closed loop at the goal turns sets: the same problem in
    /// copies of the coordinates turned about the pair ([`turning::turned`]), for
    /// [`ReachSettings::intersect_x`] (empty: none; [`ReachProblem::with_turned_frames`]).
    pub turned: Vec<ReachProblem>,
    /// What the sets bound (the scenario's `[reach] time`; `continuous` by default).
    pub time: TimeModel,
    /// Validated steps per `dt` ([`TimeModel::Continuous`]).
    pub substeps: usize,
    /// Boxes whose trajectories are proven in the goal or a trap from a time on ([`absorb`]):
    /// a tube whose set lies in one at a sample time, with that time left, stops there. Empty
    /// (tubes run to the horizon) but where `verify` proves them.
    pub absorbing: absorb::Absorbers,
}

impl ReachProblem {
    /// Compiles a scenario with its network and `M_C`, in x coordinates.
    pub fn new(scenario: &Scenario, network: Mlp, m_c: f64) -> Result<ReachProblem, ReachError> {
        ReachProblem::with_transform(scenario, network, m_c, None)
    }

    /// Compiles a scenario with its network and `M_C`, the embedding running in `z = T x`
    /// when a transform is given (docs/design.md §2b).
    pub fn with_transform(
        scenario: &Scenario,
        network: Mlp,
        m_c: f64,
        transform: Option<Transform>,
    ) -> Result<ReachProblem, ReachError> {
        let (n, m) = (scenario.n(), scenario.m());
        if network.input_dim() != n || network.output_dim() != m {
            return Err(ReachError::NetworkShape {
                net_in: network.input_dim(),
                net_out: network.output_dim(),
                n,
                m,
            });
        }
        if !(m_c.is_finite() && m_c >= 0.0) {
            return Err(ReachError::Settings(format!(
                "M_C must be a finite number ≥ 0, found {m_c}"
            )));
        }
        if let Some(t) = &transform {
            if t.n != n {
                return Err(ReachError::Settings(format!(
                    "the transform is {}×{} but the system has {n} states",
                    t.n, t.n
                )));
            }
        }
        let region = scenario.reach.region.clone();
        let c = box_of(&region.lower, &region.upper);
        let in_x = match &transform {
            Some(_) => Some(Box::new(ReachProblem::with_transform(
                scenario,
                network.clone(),
                m_c,
                None,
            )?)),
            None => None,
        };
        let (f_tilde, g, network, network_slack, field_slack, region_z) = match &transform {
            None => (
                scenario.f_tilde.clone(),
                scenario.g.clone(),
                network,
                0.0,
                0.0,
                region.clone(),
            ),
            Some(t) => {
                let region_z = t.to_z_box(&region);
                let z_max = region_z
                    .lower
                    .iter()
                    .chain(&region_z.upper)
                    .fold(0.0_f64, |a, v| a.max(v.abs()));
                let (net_z, network_slack) = t.network(&network, z_max);
                // ‖F‖∞ on C for F = f̃ + g(N + w), to bound the error of T for S⁻¹.
                let n_over_c = crate::bounds::network_bounds(
                    &network,
                    &region.lower,
                    &region.upper,
                    BoundMethod::Ibp,
                )?;
                let u_max = Interval::point(
                    n_over_c
                        .lower
                        .iter()
                        .chain(&n_over_c.upper)
                        .fold(0.0_f64, |a, v| a.max(v.abs())),
                ) + Interval::point(m_c)
                    + Interval::point(network_slack);
                let f_max = (0..n)
                    .map(|i| {
                        let gi = (0..m).fold(Interval::point(0.0), |a, k| {
                            a + Interval::point(scenario.g[i][k].eval_interval(&c).mag()) * u_max
                        });
                        (Interval::point(scenario.f_tilde[i].eval_interval(&c).mag()) + gi).upper
                    })
                    .fold(0.0, f64::max);
                (
                    t.vector_field(&scenario.f_tilde),
                    t.input_matrix(&scenario.g),
                    net_z,
                    network_slack,
                    t.field_slack(f_max),
                    region_z,
                )
            }
        };
        let dynamics = Dynamics::new(n, m, f_tilde, g);
        let cz = box_of(&region_z.lower, &region_z.upper);
        let jacobian_over_region = dynamics
            .f_tilde_jacobian
            .iter()
            .flatten()
            .map(|e| e.eval_interval(&cz))
            .collect();
        let g_over_region: Vec<Interval> = dynamics
            .g
            .iter()
            .flatten()
            .map(|e| e.eval_interval(&cz))
            .collect();
        let input_gain = closeness::induced_norm(&g_over_region, n, m, scenario.reach.norm);
        let safe_set = SafeSet::of(scenario, transform.as_ref());
        let pieces = pieces::FilterPieces::new(scenario, &dynamics, transform.as_ref());
        Ok(ReachProblem {
            dynamics,
            network,
            region,
            m_c,
            error_map: None,
            transform,
            network_slack,
            field_slack,
            norm: scenario.reach.norm,
            dt: scenario.reach.dt,
            steps: scenario.reach.steps(),
            jacobian_over_region,
            g_over_region,
            input_gain,
            safe_set,
            pieces,
            in_x,
            turned: Vec::new(),
            time: scenario.reach.time,
            substeps: scenario.reach.substeps,
            absorbing: absorb::Absorbers::default(),
        })
    }

    /// Uses the local bounds of a certified error map instead of the global `M_C` (disturbance
    /// method); the map must cover `C`.
    pub fn with_error_map(
        mut self,
        map: crate::error_map::ErrorMap,
    ) -> Result<ReachProblem, ReachError> {
        if map.certified_linf.is_none() || !self.region.is_subset_of(&map.region) {
            return Err(ReachError::Settings(
                "the error map holds no certified bounds over the region C".into(),
            ));
        }
        if let Some(x) = self.in_x.take() {
            self.in_x = Some(Box::new(x.with_error_map(map.clone())?));
        }
        self.turned = std::mem::take(&mut self.turned)
            .into_iter()
            .map(|p| p.with_error_map(map.clone()))
            .collect::<Result<_, _>>()?;
        self.error_map = Some(map);
        Ok(self)
    }

    /// `change` applied to this problem and to each of its other frames (`in_x`, `turned`).
    fn in_every_frame(mut self, change: &impl Fn(&mut ReachProblem)) -> ReachProblem {
        self.in_x = self.in_x.map(|x| Box::new(x.in_every_frame(change)));
        self.turned = std::mem::take(&mut self.turned)
            .into_iter()
            .map(|p| p.in_every_frame(change))
            .collect();
        change(&mut self);
        self
    }

    /// The network taken as exact, in every frame: `M = 0` and no error map. The sets then
    /// bound the system driven by `N`, not the filtered system: for diagnoses of what the
    /// error margin costs ([`crate::verify::WhatStops`]), never for a verdict.
    pub fn without_error(self) -> ReachProblem {
        self.in_every_frame(&|p| {
            p.m_c = 0.0;
            p.error_map = None;
        })
    }

    /// Without `S`'s half-spaces: sets are not intersected with them (for comparisons), in every
    /// frame.
    pub fn without_safe_set(self) -> ReachProblem {
        self.in_every_frame(&|p| p.safe_set = SafeSet::default())
    }

    /// The half-spaces of `S` that bound the method's sets: the filtered system's (disturbance)
    /// stay in `S`, the NN system's (Minkowski) need not.
    pub fn safe_set_for(&self, method: ReachMethod) -> &SafeSet {
        match method {
            ReachMethod::Disturbance => &self.safe_set,
            ReachMethod::Minkowski => &safe_set::NO_SAFE_SET,
        }
    }

    /// The embedding's initial state for an initial box: its z-box (the box itself without a
    /// transform), intersected with the method's half-spaces of `S`.
    pub fn initial_state(&self, initial: &IntervalBox, method: ReachMethod) -> IntervalBox {
        let mut z = self.frame_box(initial);
        safe_set::clip_to_safe_set(&mut z.lower, &mut z.upper, &self.safe_set_for(method).z);
        z
    }

    /// The problems whose coordinates the sets are kept in under `settings`: this one, and
    /// the same in x and in the turned frames where [`ReachSettings::intersect_x`] applies
    /// (disturbance method, a transform).
    pub fn frames(&self, settings: &ReachSettings) -> Vec<&ReachProblem> {
        let in_x = match (&self.in_x, settings.method) {
            (Some(x), ReachMethod::Disturbance) if settings.intersect_x => Some(&**x),
            _ => None,
        };
        let turned = match in_x {
            Some(_) => &self.turned[..],
            None => &[],
        };
        std::iter::once(self).chain(in_x).chain(turned).collect()
    }

    /// The problem with its sets kept in `frames − 1` copies of its coordinates turned about the
    /// closed loop's complex pairs as well ([`ReachProblem::turned_frames_of`]; `frames ≤ 1`:
    /// none).
    pub fn with_turned_frames(
        mut self,
        scenario: &Scenario,
        frames: usize,
    ) -> Result<ReachProblem, ReachError> {
        self.turned = self.turned_frames_of(scenario, frames)?;
        Ok(self)
    }

    /// The problems of `frames − 1` copies of this problem's coordinates turned about the
    /// closed loop's complex pairs ([`turning::turned`]; `frames ≤ 1`: none), each with this
    /// problem's time model, safe set and error map. Continuous time alone: there each frame's
    /// slabs are clipped by the others' sets (design §7.1 item 8); the Euler map and sampled
    /// data meet frames through x-boxes, which turned frames do not tighten.
    pub fn turned_frames_of(
        &self,
        scenario: &Scenario,
        frames: usize,
    ) -> Result<Vec<ReachProblem>, ReachError> {
        if frames <= 1 {
            return Ok(Vec::new());
        }
        let refuse = |why: String| {
            ReachError::Settings(format!(
                "{}: reach.turned_frames = {frames}: {why}",
                scenario.file
            ))
        };
        if self.time != TimeModel::Continuous {
            return Err(refuse(format!(
                "turned frames tighten continuous time alone (this run: \"{}\")",
                self.time.name()
            )));
        }
        let (Some(t), Some(x)) = (&self.transform, &self.in_x) else {
            return Err(refuse(
                "turned frames turn coordinates z = T x: they need a transform".into(),
            ));
        };
        let goal = scenario.reach.goal.center();
        let a = crate::filter::SafetyFilter::new(scenario)
            .closed_loop_jacobian(&goal)
            .map_err(|e| refuse(e.to_string()))?;
        let turned = turning::turned(t, &a, frames).map_err(|e| refuse(e.to_string()))?;
        turned
            .into_iter()
            .map(|t| {
                let mut p =
                    ReachProblem::with_transform(scenario, x.network.clone(), self.m_c, Some(t))?
                        .with_time(self.time, self.substeps);
                // The x frame is this problem's; the safe set and the error map as this
                // problem's.
                p.in_x = None;
                p.steps = self.steps;
                if self.safe_set == SafeSet::default() {
                    p = p.without_safe_set();
                }
                match &self.error_map {
                    Some(map) => p.with_error_map(map.clone()),
                    None => Ok(p),
                }
            })
            .collect()
    }

    /// The frames turned about the closed loop's turn that the sets are kept in under
    /// `settings`, z itself included (1: z alone, or no transform).
    pub fn turned_frames(&self, settings: &ReachSettings) -> usize {
        self.frames(settings).len().saturating_sub(1).max(1)
    }

    /// Whether [`ReachSettings::meet_slabs`] acts on this problem.
    pub fn meet_slabs_applies(&self, settings: &ReachSettings) -> bool {
        settings.meet_slabs && self.slabs_can_meet(settings)
    }

    /// Whether [`ReachSettings::meet_slabs`] would act, set or not: continuous time with
    /// several frames.
    pub fn slabs_can_meet(&self, settings: &ReachSettings) -> bool {
        self.time == TimeModel::Continuous && self.frames(settings).len() > 1
    }

    /// The box of this problem's coordinates around an x-box (its z-box with a transform).
    pub fn frame_box(&self, x: &IntervalBox) -> IntervalBox {
        match &self.transform {
            Some(t) => t.to_z_box(x),
            None => x.clone(),
        }
    }

    /// The x-box of the embedding state `[lower, upper]` (its parallelotope's bounding box with
    /// a transform), intersected with `safe`'s x half-spaces: every true state lies in it.
    pub fn x_box_in_safe_set(&self, lower: &[f64], upper: &[f64], safe: &SafeSet) -> IntervalBox {
        let mut x = match &self.transform {
            Some(t) => t.to_x_box(lower, upper),
            None => IntervalBox {
                lower: lower.to_vec(),
                upper: upper.to_vec(),
            },
        };
        safe_set::clip_to_safe_set(&mut x.lower, &mut x.upper, &safe.x);
        x
    }

    /// The transform's slack of `piece`'s own field over `x_box` (0 without a transform): the
    /// scenario's `f̃` for the inactive piece, row `k`'s field for `Binding(k)`.
    pub fn piece_slack(&self, piece: crate::filter::FilterPiece, x_box: &IntervalBox) -> f64 {
        match piece {
            crate::filter::FilterPiece::Inactive => self.field_slack,
            crate::filter::FilterPiece::Binding(k) => self.pieces.binding_slack(k, x_box),
        }
    }

    /// Whether [`ReachSettings::lattice`] acts on this problem: continuous time, the disturbance
    /// method with the closed form, a scalar input's closed form, constant `g`.
    pub fn lattice_applies(&self, settings: &ReachSettings) -> bool {
        settings.lattice
            && self.time == TimeModel::Continuous
            && settings.exact_field() == ExactField::ClosedForm
            && self.dynamics.m == 1
            && self.dynamics.g_constant.is_some()
            && self
                .pieces
                .forms()
                .is_some_and(|f| f.method() == crate::filter::FilterMethod::ClosedFormScalar)
    }

    /// Whether a finite `M` exists for every box within `C`: `m_c` is finite and, with an error
    /// map, the map certifies every one of its cells. Then a step that finds no finite `M` asked
    /// for it beyond `C`.
    pub fn certified_on_all_of_c(&self) -> bool {
        match &self.error_map {
            Some(map) => map.certified_everywhere(),
            None => self.m_c.is_finite(),
        }
    }

    /// The disturbance bound `M` for a set whose x-bounding box is `x_box`: the error map's
    /// local bound when there is one, else `M_C`.
    pub fn margin_for(&self, x_box: &IntervalBox) -> f64 {
        match &self.error_map {
            Some(map) => map.local_bound(x_box),
            None => self.m_c,
        }
    }

    /// Whether the filter's QP is proven feasible on every recorded set of `tube`
    /// ([`pieces::FilterPieces::proves_feasible`]).
    pub fn proves_feasible_along(&self, tube: &Tube) -> bool {
        self.proves_feasible_on(&tube.tube)
    }

    /// Whether the filter's QP is proven feasible on each of these sets.
    pub fn proves_feasible_on(&self, sets: &[TubeSample]) -> bool {
        sets.iter()
            .all(|sample| self.pieces.proves_feasible(&sample.set))
    }

    /// The recorded sample of an embedding state `[lower, upper]` (z coordinates with a
    /// transform) with closeness radius `r`: x-boxes of the embedding's set and of the
    /// filtered-system set (the Minkowski sum is taken in the embedding's coordinates, where
    /// `r` is an ℓ∞ radius), both intersected with `safe`'s x half-spaces (none for the
    /// Minkowski method, whose embedding bounds the NN system). Shared by every backend.
    pub fn tube_sample(
        &self,
        lower: &[f64],
        upper: &[f64],
        r: f64,
        t: f64,
        safe: &SafeSet,
    ) -> TubeSample {
        let nn = self.x_box_in_safe_set(lower, upper, safe);
        let set = if r == 0.0 {
            nn.clone()
        } else {
            let grown = |v: &[f64], sign: f64| -> Vec<f64> {
                v.iter()
                    .map(|&x| {
                        let y = Interval::point(x) + Interval::point(sign * r);
                        if sign < 0.0 {
                            y.lower
                        } else {
                            y.upper
                        }
                    })
                    .collect()
            };
            self.x_box_in_safe_set(&grown(lower, -1.0), &grown(upper, 1.0), safe)
        };
        let transformed = self.transform.is_some();
        TubeSample {
            t,
            lower: nn.lower,
            upper: nn.upper,
            radius: r,
            z_lower: transformed.then(|| lower.to_vec()),
            z_upper: transformed.then(|| upper.to_vec()),
            set,
            flowpipe: None,
        }
    }

    /// Checks initial boxes: dimension n and inside `C`.
    pub fn check_initial(&self, boxes: &[IntervalBox]) -> Result<(), ReachError> {
        for (index, b) in boxes.iter().enumerate() {
            if b.dim() != self.dynamics.n {
                return Err(ReachError::InitialBox {
                    index,
                    message: format!("has {} coordinates, expected {}", b.dim(), self.dynamics.n),
                });
            }
            if !b.is_subset_of(&self.region) {
                return Err(ReachError::InitialBox {
                    index,
                    message: format!(
                        "{:?}…{:?} does not lie in the region C {:?}…{:?}",
                        b.lower, b.upper, self.region.lower, self.region.upper
                    ),
                });
            }
        }
        Ok(())
    }
}

/// What a backend returns.
#[derive(Clone, Debug, Serialize)]
pub struct ReachResult {
    /// One tube per initial box, in order.
    pub boxes: Vec<Tube>,
    /// Wall times.
    pub timing: ReachTiming,
}

/// Wall times of a run.
#[derive(Clone, Debug, Default, Serialize)]
pub struct ReachTiming {
    /// The embedding system, network bounds included.
    pub reach_s: f64,
    /// The closeness radius and Minkowski sum (0 for the disturbance method).
    pub minkowski_s: f64,
}

/// A reachability engine.
pub trait Backend {
    /// A name for reports (`cpu`, `gpu (adapter name)`).
    fn name(&self) -> String;

    /// Runs the embedding system from every initial box; `progress` is told after each step
    /// (steps done, steps in all).
    fn reach(
        &self,
        problem: &ReachProblem,
        initial: &[IntervalBox],
        settings: &ReachSettings,
        progress: &(dyn Fn(usize, usize) + Sync),
    ) -> Result<ReachResult, ReachError>;

    /// Boxes per call that keep the engine busy, for callers that batch many boxes (`verify`):
    /// a few hundred fill the CPU's threads; a GPU wants thousands.
    fn preferred_batch(&self) -> usize {
        512
    }

    /// Whether this engine runs `problem` under `settings` as they are, or which setting it
    /// refuses; the CPU engine runs every setting.
    fn supports(
        &self,
        _problem: &ReachProblem,
        _settings: &ReachSettings,
    ) -> Result<(), Unsupported> {
        Ok(())
    }
}
