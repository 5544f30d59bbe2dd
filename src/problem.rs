//! From a scenario to a compiled [`ReachProblem`]: which network, which `M_C` (a number or the
//! error map beside the network), which coordinates. May import `scenario`, `network`,
//! `reach` and `surrogate_error`; the CLI's `--network`, `--m-c`, `--transform`, … fill
//! [`ProblemOptions`].

use std::path::{Path, PathBuf};

use crate::error_map::{margin_value, ErrorMap, ErrorMapError};
use crate::network::{Mlp, NetworkError};
use crate::reach::{ReachError, ReachProblem, TimeModel, Transform, Turning};
use crate::scenario::{Margin, Scenario, TransformChoice};

/// What a caller may change of the scenario's problem; `ProblemOptions::default()` is the
/// scenario as written.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct ProblemOptions {
    /// This network instead of the scenario's `[network] file` (default: the scenario's).
    pub network: Option<PathBuf>,
    /// This `M_C` instead of the scenario's `reach.m_c` (default: the scenario's).
    pub m_c: Option<Margin>,
    /// These coordinates instead of the scenario's `reach.transform` (default: the
    /// scenario's).
    pub transform: Option<TransformChoice>,
    /// Use the certified local bounds of the error map beside the network instead of one
    /// global `M_C` (default: false; the scenario's `m_c = "local"`, unless `m_c` overrides
    /// it, turns it on too).
    pub local_margin: bool,
    /// Do not meet the sets with the safe set's affine half-spaces (default: false; for
    /// comparisons).
    pub no_safe_set: bool,
    /// This time model instead of the scenario's `reach.time`: `continuous`, `sampled` or
    /// `euler` (default: the scenario's).
    pub time: Option<String>,
    /// This `T_s` instead of the scenario's `reach.control_period` (`sampled`; default: the
    /// scenario's, else `dt`).
    pub control_period: Option<f64>,
    /// This many validated steps per `dt` instead of the scenario's `reach.substeps`
    /// (`continuous`; default: the scenario's).
    pub substeps: Option<usize>,
    /// Keep continuous-time sets in this many frames turned about the closed loop's turn at
    /// the goal (1: none turned; default: the scenario's `reach.turned_frames`, else
    /// [`ProblemOptions::chosen_turned_frames`]).
    pub turned_frames: Option<usize>,
}

impl ProblemOptions {
    /// The turned frames a problem gets where neither the options nor the scenario say: where
    /// it runs in continuous time in the `auto` coordinates (`choice`) and its closed loop at the goal
    /// turns sets at least as fast as it shrinks them ([`Turning`]), the frames
    /// [`Turning::frames`] picks; else 1 (none turned).
    pub fn chosen_turned_frames(
        s: &Scenario,
        problem: &ReachProblem,
        choice: &TransformChoice,
    ) -> usize {
        // Turns keep a frame as good as z only in the `auto` coordinates, where each pair's
        // block is `[[α, β], [−β, α]]`; a matrix of the user's is left as given.
        let auto = matches!(choice, TransformChoice::Auto | TransformChoice::Chosen);
        let turns = auto && problem.time == TimeModel::Continuous && problem.transform.is_some();
        match turns.then(|| Turning::at_goal(s)).flatten() {
            Some(turning) => turning.frames(),
            None => 1,
        }
    }
}

/// Why a scenario could not be compiled into a problem.
#[derive(Debug, thiserror::Error)]
pub enum ProblemError {
    /// Neither the scenario nor the options name a network.
    #[error("{file}: no [network] section and no network given")]
    NoNetwork {
        /// The scenario file.
        file: String,
    },
    /// The network file does not exist.
    #[error(
        "{file}: network file {} does not exist (train one with `cbfreach train {file}`)",
        path.display()
    )]
    MissingNetwork {
        /// The scenario file.
        file: String,
        /// The network file.
        path: PathBuf,
    },
    /// The network file's layers are not the scenario's `architecture`.
    #[error("{file}: network.architecture is {scenario} but {} is {network}", path.display())]
    Architecture {
        /// The scenario file.
        file: String,
        /// The network file.
        path: PathBuf,
        /// The scenario's widths.
        scenario: String,
        /// The file's widths.
        network: String,
    },
    /// The network file could not be read.
    #[error(transparent)]
    Network(#[from] NetworkError),
    /// `M_C` names the error map, which is missing or holds no certified bound.
    #[error("{field} = {margin}: {source} (run `cbfreach error {file}` first)")]
    Margin {
        /// The scenario file.
        file: String,
        /// Where the margin came from: `<file>: reach.m_c`, or `m_c` of the options.
        field: String,
        /// The margin asked for.
        margin: Margin,
        /// Why the error map could not give it.
        source: Box<ErrorMapError>,
    },
    /// Local margins were asked for but the error map cannot give them.
    #[error("local error margins: {source} (run `cbfreach error {file}` first)")]
    LocalMargins {
        /// The scenario file.
        file: String,
        /// Why the error map could not be read.
        source: Box<ErrorMapError>,
    },
    /// The transform could not be built.
    #[error("{0}")]
    Transform(String),
    /// The time model of the options is not one (its name, or `T_s` not a multiple of `dt`),
    /// or its substeps make more engine steps than a run takes.
    #[error("{0}")]
    Time(String),
    /// The problem does not fit together (network shape, `M_C`, error map over `C`).
    #[error(transparent)]
    Reach(#[from] ReachError),
}

impl ReachProblem {
    /// Compiles a scenario into a problem: its network (or `options.network`), `M_C` from the
    /// scenario (or `options.m_c`; `certified`, `measured` and `local` read the error map
    /// beside the network), its coordinates (or `options.transform`), and the error map's
    /// local bounds where asked.
    pub fn from_scenario(
        s: &Scenario,
        options: &ProblemOptions,
    ) -> Result<ReachProblem, ProblemError> {
        let net = load_network(s, options.network.as_deref())?;
        let path = network_path(s, options.network.as_deref())?;
        let m_c = resolve_margin(s, options.m_c, &path)?;
        let choice = options.transform.as_ref().unwrap_or(&s.reach.transform);
        let transform = Transform::for_scenario(s, choice)
            .map_err(|e| ProblemError::Transform(e.to_string()))?;
        let mut problem = ReachProblem::with_transform(s, net, m_c, transform)?;
        if options.time.is_some() || options.control_period.is_some() || options.substeps.is_some()
        {
            let old = match s.reach.time {
                TimeModel::Sampled { control_period } => Some(control_period),
                _ => None,
            };
            let name = options.time.as_deref().unwrap_or(s.reach.time.name());
            let time = TimeModel::parse(name, options.control_period.or(old), s.reach.dt)
                .map_err(|e| ProblemError::Time(e.to_string()))?;
            let sampled = matches!(time, TimeModel::Sampled { .. });
            if let Some(ts) = options.control_period.filter(|_| !sampled) {
                // A period nothing holds the input over: said, not ignored.
                return Err(ProblemError::Time(format!(
                    "--control-period {ts} holds the input of `sampled` runs; this run's sets \
                     bound {} (add --time sampled)",
                    time.clause()
                )));
            }
            // The scenario's `substeps` cut continuous steps: another model asked for here
            // runs without them (given here with it, they are refused by name).
            let substeps = match (options.substeps, time) {
                (Some(k), _) => k,
                (None, TimeModel::Continuous) => s.reach.substeps,
                (None, _) => 1,
            };
            // The scenario's own substeps were checked with its steps; these are the options'.
            let total = problem.steps as f64 * substeps as f64;
            if total > crate::scenario::limits::MAX_STEPS {
                return Err(ProblemError::Time(format!(
                    "--substeps {substeps}: {} steps × {substeps} is {total:.3e} engine steps, \
                     more than {:.0e}",
                    problem.steps,
                    crate::scenario::limits::MAX_STEPS
                )));
            }
            problem = problem.with_time(time, substeps);
        }
        if options.no_safe_set {
            problem = problem.without_safe_set();
        }
        problem = match options.turned_frames.or(s.reach.turned_frames) {
            Some(frames) => problem.with_turned_frames(s, frames)?,
            // Chosen: where the coordinates have no pair to turn after all, none.
            None => {
                let frames = ProblemOptions::chosen_turned_frames(s, &problem, choice);
                problem.turned = problem.turned_frames_of(s, frames).unwrap_or_default();
                problem
            }
        };
        // Local bounds on request, or by the scenario's `m_c = "local"` unless the options
        // override it.
        let local = options.local_margin || options.m_c.unwrap_or(s.reach.m_c) == Margin::Local;
        if !local {
            return Ok(problem);
        }
        let map =
            ErrorMap::load_certified(&path, s).map_err(|source| ProblemError::LocalMargins {
                file: s.file.clone(),
                source: Box::new(source),
            })?;
        Ok(problem.with_error_map(map)?)
    }
}

/// The network file: `over` when given, else the scenario's `[network] file`.
pub fn network_path(s: &Scenario, over: Option<&Path>) -> Result<PathBuf, ProblemError> {
    match (over, &s.network) {
        (Some(p), _) => Ok(p.to_path_buf()),
        (None, Some(net)) => Ok(net.file.clone()),
        (None, None) => Err(ProblemError::NoNetwork {
            file: s.file.clone(),
        }),
    }
}

/// Loads the network named by `over` or by the scenario.
pub fn load_network(s: &Scenario, over: Option<&Path>) -> Result<Mlp, ProblemError> {
    let path = network_path(s, over)?;
    if !path.exists() {
        return Err(ProblemError::MissingNetwork {
            file: s.file.clone(),
            path,
        });
    }
    let net = Mlp::load_safetensors(&path)?;
    // The scenario's `architecture` describes its own file; another network (`over`) is
    // checked against the states and inputs when the problem is built.
    if let (None, Some(cfg)) = (over, &s.network) {
        if net.widths() != cfg.architecture {
            return Err(ProblemError::Architecture {
                file: s.file.clone(),
                path,
                scenario: join_widths(&cfg.architecture),
                network: join_widths(&net.widths()),
            });
        }
    }
    Ok(net)
}

fn join_widths(w: &[usize]) -> String {
    w.iter().map(usize::to_string).collect::<Vec<_>>().join("×")
}

/// `M_C` from `over` or the scenario; `certified` / `measured` / `local` come from the error
/// map beside `network` (written by `cbfreach error`).
pub fn resolve_margin(
    s: &Scenario,
    over: Option<Margin>,
    network: &Path,
) -> Result<f64, ProblemError> {
    let margin = over.unwrap_or(s.reach.m_c);
    margin_value(margin, s, network).map_err(|source| ProblemError::Margin {
        file: s.file.clone(),
        field: match over {
            Some(_) => "m_c".to_string(),
            None => format!("{}: reach.m_c", s.file),
        },
        margin,
        source: Box::new(source),
    })
}
