//! Point simulation of a closed loop `ẋ = F(x)` with explicit Euler or classical RK4.
//!
//! Used for the filtered system `F = f̃ + g v` (ground truth), the NN system `f̃ + g N`, and as
//! the judge of every set the reachability engine computes (docs/design.md §3).

use std::io::Write;

use rand::{Rng, SeedableRng};
use serde::{Serialize, Serializer};

use crate::boxes::IntervalBox;
use crate::filter::{FilterError, SafetyFilter};
use crate::reach::TimeModel;

/// The time-stepping scheme.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, clap::ValueEnum)]
#[serde(rename_all = "lowercase")]
pub enum Integrator {
    /// `x ← x + dt F(x)`, as the paper.
    Euler,
    /// Classical fourth-order Runge–Kutta.
    Rk4,
    /// Zero-order hold: the control `u_k = κ(x_k) + v(x_k)` computed once per step and held
    /// while the plant `ẋ = f(x) + g(x)u_k` is integrated by RK4 at a tenth of the step (a
    /// digital controller; what `time = "sampled"` bounds). A closed-loop field with no input
    /// to hold (the NN system) is integrated by RK4 at that fine step.
    Zoh,
}

impl Integrator {
    /// The scheme whose trajectories a time model's sets bound: RK4 for `continuous` (the
    /// ODE), the zero-order hold for `sampled`, the map itself for `euler`. What `simulate`
    /// runs when no scheme is named.
    pub fn for_time(time: TimeModel) -> Integrator {
        match time {
            TimeModel::Continuous => Integrator::Rk4,
            TimeModel::Sampled { .. } => Integrator::Zoh,
            TimeModel::Euler => Integrator::Euler,
        }
    }

    /// Its step under `time` with integration step `dt`: the hold's is the control period
    /// where the model has one, every other scheme's `dt`.
    pub fn step(self, time: TimeModel, dt: f64) -> f64 {
        match (self, time) {
            (Integrator::Zoh, TimeModel::Sampled { control_period }) => control_period,
            _ => dt,
        }
    }

    /// Its name as `--integrator` takes it.
    pub fn name(self) -> &'static str {
        match self {
            Integrator::Euler => "euler",
            Integrator::Rk4 => "rk4",
            Integrator::Zoh => "zoh",
        }
    }
}

/// RK4 steps per step of [`Integrator::Zoh`].
pub const ZOH_SUBSTEPS: usize = 10;

/// One simulated trajectory.
#[derive(Clone, Debug, Serialize)]
pub struct Trajectory {
    /// Initial state.
    pub x0: Vec<f64>,
    /// Times `t₀ = 0, t₁, …`.
    pub t: Vec<f64>,
    /// States at those times.
    pub x: Vec<Vec<f64>>,
    /// Why the trajectory stopped before the horizon (e.g. an infeasible filter), if it did;
    /// serialized as its text.
    #[serde(serialize_with = "as_text")]
    pub stopped: Option<Stop>,
}

/// Why a trajectory stopped before the horizon: its field could not be evaluated at the state
/// reached at `t` (the last one recorded).
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
#[error("at t = {t}: {cause}")]
pub struct Stop {
    /// The time of the state where the field failed.
    pub t: f64,
    /// Why the field failed there.
    #[source]
    pub cause: FieldFailure,
}

/// Why a closed loop's field could not be evaluated at a state.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum FieldFailure {
    /// The filter gave no `v(x)`: its QP is infeasible (a status of the problem, not a fault),
    /// a CBF is not differentiable there, or the solver failed.
    #[error(transparent)]
    Filter(#[from] FilterError),
    /// Another field's failure, as its text.
    #[error("{0}")]
    Other(String),
}

impl FieldFailure {
    /// Whether the filter's QP has no solution there.
    pub fn is_infeasible(&self) -> bool {
        matches!(self, FieldFailure::Filter(FilterError::Infeasible { .. }))
    }
}

impl From<String> for FieldFailure {
    fn from(message: String) -> FieldFailure {
        FieldFailure::Other(message)
    }
}

/// An optional [`Stop`] as its text (or null), as the JSON has always held it.
fn as_text<S: Serializer>(stop: &Option<Stop>, serializer: S) -> Result<S::Ok, S::Error> {
    match stop {
        Some(stop) => serializer.collect_str(stop),
        None => serializer.serialize_none(),
    }
}

impl Trajectory {
    /// The last state.
    pub fn last(&self) -> &[f64] {
        self.x.last().map_or(&self.x0, |v| v)
    }
}

/// Integrates `ẋ = field(x)` from `x0` over `steps` steps of `dt`; stops early (and says why)
/// when the field cannot be evaluated.
pub fn integrate<E: Into<FieldFailure>>(
    field: impl Fn(&[f64]) -> Result<Vec<f64>, E>,
    x0: &[f64],
    dt: f64,
    steps: usize,
    integrator: Integrator,
) -> Trajectory {
    iterate(|x| step(&field, x, dt, integrator), x0, dt, steps)
}

/// The trajectory of the map `x ← next(x)` from `x0` over `steps` steps of `dt`; stops early
/// (and says why) where `next` fails.
fn iterate<E: Into<FieldFailure>>(
    mut next: impl FnMut(&[f64]) -> Result<Vec<f64>, E>,
    x0: &[f64],
    dt: f64,
    steps: usize,
) -> Trajectory {
    let mut traj = Trajectory {
        x0: x0.to_vec(),
        t: vec![0.0],
        x: vec![x0.to_vec()],
        stopped: None,
    };
    let mut x = x0.to_vec();
    for k in 0..steps {
        match next(&x) {
            Ok(y) => x = y,
            Err(e) => {
                traj.stopped = Some(Stop {
                    t: k as f64 * dt,
                    cause: e.into(),
                });
                break;
            }
        }
        traj.t.push((k + 1) as f64 * dt);
        traj.x.push(x.clone());
    }
    traj
}

/// One step of the scheme.
pub fn step<E>(
    field: impl Fn(&[f64]) -> Result<Vec<f64>, E>,
    x: &[f64],
    dt: f64,
    integrator: Integrator,
) -> Result<Vec<f64>, E> {
    let axpy = |a: &[f64], s: f64, b: &[f64]| -> Vec<f64> {
        a.iter().zip(b).map(|(ai, bi)| ai + s * bi).collect()
    };
    match integrator {
        Integrator::Euler => Ok(axpy(x, dt, &field(x)?)),
        Integrator::Rk4 => rk4(&field, x, dt),
        Integrator::Zoh => {
            let mut y = x.to_vec();
            for _ in 0..ZOH_SUBSTEPS {
                y = rk4(&field, &y, dt / ZOH_SUBSTEPS as f64)?;
            }
            Ok(y)
        }
    }
}

/// One classical RK4 step (also of the box embedding's widths, [`crate::reach::Transient`]).
pub(crate) fn rk4<E>(
    field: &impl Fn(&[f64]) -> Result<Vec<f64>, E>,
    x: &[f64],
    dt: f64,
) -> Result<Vec<f64>, E> {
    let axpy = |a: &[f64], s: f64, b: &[f64]| -> Vec<f64> {
        a.iter().zip(b).map(|(ai, bi)| ai + s * bi).collect()
    };
    let k1 = field(x)?;
    let k2 = field(&axpy(x, 0.5 * dt, &k1))?;
    let k3 = field(&axpy(x, 0.5 * dt, &k2))?;
    let k4 = field(&axpy(x, dt, &k3))?;
    Ok((0..x.len())
        .map(|i| x[i] + dt / 6.0 * (k1[i] + 2.0 * k2[i] + 2.0 * k3[i] + k4[i]))
        .collect())
}

/// One zero-order-hold step of the filtered system: `u = κ(x) + v(x)` held over `dt` while
/// `ẋ = f(x) + g(x)u` is integrated by RK4 at `dt / ZOH_SUBSTEPS`, `watch` shown the state
/// after each substep.
fn zoh_step(
    filter: &SafetyFilter,
    x: &[f64],
    dt: f64,
    mut watch: impl FnMut(&[f64]),
) -> Result<Vec<f64>, FilterError> {
    let s = filter.scenario();
    let (n, m) = (s.n(), s.m());
    let v = filter.eval(x)?;
    let u: Vec<f64> = s.kappa_at(x).iter().zip(&v).map(|(k, v)| k + v).collect();
    let plant = |y: &[f64]| -> Result<Vec<f64>, FilterError> {
        let g = s.g_at(y);
        Ok((0..n)
            .map(|i| s.f[i].eval(y) + (0..m).map(|k| g[i * m + k] * u[k]).sum::<f64>())
            .collect())
    };
    let mut y = x.to_vec();
    for _ in 0..ZOH_SUBSTEPS {
        y = rk4(&plant, &y, dt / ZOH_SUBSTEPS as f64)?;
        watch(&y);
    }
    Ok(y)
}

/// The held-input trajectory from `x0` over `periods` control periods `ts` with the first time
/// (at the end of one of [`ZOH_SUBSTEPS`] RK4 substeps a period) at which the plant is outside
/// `S`: a digital filter does not keep `S` invariant between samples, and this is where the
/// true sampled system shows it.
pub fn simulate_sampled_watching_s(
    filter: &SafetyFilter,
    x0: &[f64],
    ts: f64,
    periods: usize,
) -> (Trajectory, Option<f64>) {
    let s = filter.scenario();
    let h = ts / ZOH_SUBSTEPS as f64;
    let (mut substep, mut left) = (0usize, None);
    let traj = iterate(
        |x| {
            zoh_step(filter, x, ts, |y| {
                substep += 1;
                if left.is_none() && !s.is_safe(y) {
                    left = Some(substep as f64 * h);
                }
            })
        },
        x0,
        ts,
        periods,
    );
    (traj, left)
}

/// Simulates the filtered system `ẋ = f̃(x) + g(x) v(x)`.
pub fn simulate_filtered(
    filter: &SafetyFilter,
    x0: &[f64],
    dt: f64,
    steps: usize,
    integrator: Integrator,
) -> Trajectory {
    if integrator == Integrator::Zoh {
        // The held input is not a function of the current state: step the sampled map (no
        // one watching `S` between samples here).
        return iterate(|x| zoh_step(filter, x, dt, |_| {}), x0, dt, steps);
    }
    // From a start where the QP is feasible, the rows kept by a high-order CBF hold along the
    // ODE's trajectory (SafetyFilter::field_on_trajectories); from any other the trajectory
    // ends where it starts.
    let start = filter.eval(x0);
    let field = |x: &[f64]| -> Result<Vec<f64>, FilterError> {
        match &start {
            Ok(_) => filter.field_on_trajectories(x),
            Err(e) => Err(e.clone()),
        }
    };
    integrate(field, x0, dt, steps, integrator)
}

/// `count` boxes 0.02 wide around safe points spread over the middle of `C` (its central 40 %
/// along each axis): the boxes `cbfreach bench` and the reach benchmarks time (fewer where the
/// middle holds fewer safe points among its samples).
pub fn spread_boxes(scenario: &crate::scenario::Scenario, count: usize) -> Vec<IntervalBox> {
    let c = &scenario.reach.region;
    let n = scenario.n();
    let middle = IntervalBox {
        lower: (0..n)
            .map(|i| c.lower[i] + 0.3 * (c.upper[i] - c.lower[i]))
            .collect(),
        upper: (0..n)
            .map(|i| c.upper[i] - 0.3 * (c.upper[i] - c.lower[i]))
            .collect(),
    };
    sample_box(&middle, 4 * count + 16, 1)
        .into_iter()
        .filter(|x| scenario.is_safe(x))
        .take(count)
        .map(|x| IntervalBox {
            lower: x.iter().map(|v| v - 0.01).collect(),
            upper: x.iter().map(|v| v + 0.01).collect(),
        })
        .collect()
}

/// `count` points drawn uniformly from `b`, deterministic for `seed`; the corners come first
/// (up to `count`), since extreme trajectories often start there.
pub fn sample_box(b: &IntervalBox, count: usize, seed: u64) -> Vec<Vec<f64>> {
    let n = b.dim();
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
    let corners = (0..1usize << n.min(16)).map(|mask| {
        let s: Vec<f64> = (0..n).map(|i| ((mask >> i) & 1) as f64).collect();
        b.point_at(&s)
    });
    let mut points: Vec<Vec<f64>> = corners.take(count).collect();
    while points.len() < count {
        let s: Vec<f64> = (0..n).map(|_| rng.random::<f64>()).collect();
        points.push(b.point_at(&s));
    }
    points
}

/// Writes trajectories as CSV: `trajectory,t,<state names…>`, one row per time.
pub fn write_csv(
    out: &mut impl Write,
    states: &[String],
    trajectories: &[Trajectory],
) -> std::io::Result<()> {
    writeln!(out, "trajectory,t,{}", states.join(","))?;
    for (k, traj) in trajectories.iter().enumerate() {
        for (t, x) in traj.t.iter().zip(&traj.x) {
            let xs: Vec<String> = x.iter().map(|v| v.to_string()).collect();
            writeln!(out, "{k},{t},{}", xs.join(","))?;
        }
    }
    Ok(())
}
