//! Options shared by several subcommands (`reach`, `verify`, `plot`, `paper`, `bench`): clap
//! structs that convert into the library's option types and hold no logic. Their defaults
//! come from `ReachSettings::default()`; a scenario's `[settings]` table replaces those, and
//! an option given on the command line replaces both.

use std::path::PathBuf;

use cbfreach::bounds::BoundMethod;
use cbfreach::error_map::ErrorMapError;
use cbfreach::gpu::Precision;
use cbfreach::problem::{ProblemError, ProblemOptions};
use cbfreach::reach::engine::EngineError;
use cbfreach::reach::{
    choose_engine, Backend, EngineChoice, ExactField, GpuOptions, ReachMethod, ReachProblem,
    ReachSettings, Turning,
};
use cbfreach::scenario::{Margin, TransformChoice};

use super::given;

/// Which engine runs a command's sets, and the GPU's options (`reach`, `verify`).
#[derive(clap::Args, Clone, Debug)]
pub struct EngineArgs {
    /// Engine: `cpu`, `gpu` (wgpu; forward, forward-backward and crown bounds), or `auto` (a
    /// real GPU that runs these settings, for runs of 1,024 boxes or more; else the CPU with a
    /// notice; never a change in what is computed, only where).
    #[arg(long, default_value = "cpu")]
    pub backend: EngineChoice,
    /// GPU adapter and precision.
    #[command(flatten)]
    pub gpu: GpuArgs,
}

/// How the GPU engine runs (`reach`, `verify`, `bench`).
#[derive(clap::Args, Clone, Debug, Default)]
pub struct GpuArgs {
    /// GPU adapter whose name contains this (case-insensitive); default: a real GPU before a
    /// software one.
    #[arg(long)]
    pub adapter: Option<String>,
    /// GPU engine in f64 (shaders with wgpu's SHADER_F64; an error where the adapter lacks
    /// it). The default wherever the adapter has f64 shaders. The CPU engine computes in f64
    /// always.
    #[arg(long = "f64", conflicts_with = "f32")]
    pub f64: bool,
    /// GPU engine in f32: faster (1.75× for forward-backward on an H100), but every sum's
    /// rounding is bounded a priori, which for 400-wide layers widens the network's bounds by
    /// ~10⁻⁴ of their magnitude at every step: sets are measurably wider than in f64, and some
    /// boxes that verify in f64 do not.
    #[arg(long = "f32")]
    pub f32: bool,
}

impl GpuArgs {
    /// The library's options.
    pub fn options(&self) -> GpuOptions {
        GpuOptions {
            adapter: self.adapter.clone(),
            precision: match (self.f64, self.f32) {
                (true, _) => Some(Precision::F64),
                (_, true) => Some(Precision::F32),
                _ => None,
            },
        }
    }
}

/// Where the disturbance method takes the filter exactly (`reach`, `verify`).
#[derive(clap::Args, Clone, Debug)]
pub struct ExactArgs {
    /// Where the CPU engine uses the filter itself besides the network plus its error margin:
    /// `closed-form` (closed-form filters: the filtered system's own field where the filter is
    /// provably one smooth function on the set, its enclosures of `v` elsewhere), `inactive`
    /// (only `v = 0` where the filter is proven inactive; any filter), `nowhere`.
    #[arg(long, value_enum, default_value_t = ReachSettings::default().exact)]
    pub exact: ExactField,
    /// Bound the network on every set (the same as `--exact nowhere`).
    #[arg(long, conflicts_with = "exact")]
    pub network_everywhere: bool,
}

/// The shape of the sets (`reach`, `verify`).
#[derive(clap::Args, Clone, Debug, Default)]
pub struct SetArgs {
    /// With a transform, keep the parallelotope alone. By default the CPU engine also runs the
    /// embedding in x and keeps, at every step, the meet of the x-box and the parallelotope,
    /// each tightening the other (about twice the work per step; a box in x follows sets that
    /// turn, the parallelotope sets that contract).
    #[arg(long)]
    pub parallelotope_only: bool,
}

/// The reach settings of `reach` and `verify`.
#[derive(clap::Args, Clone, Debug)]
pub struct ReachFlags {
    /// How the network is bounded over each box.
    #[arg(long, value_enum, default_value_t = ReachSettings::default().bounds)]
    pub bounds: BoundMethod,
    /// How the network's error enters the sets.
    #[arg(long, value_enum, default_value_t = ReachSettings::default().method)]
    pub method: ReachMethod,
    /// Bound the network on each face of a box separately (tighter, 2n× the bound cost).
    #[arg(long)]
    pub face_local: bool,
    /// Where the CPU engine integrates the filtered system's own field instead of the network.
    #[command(flatten)]
    pub exact: ExactArgs,
    /// The shape of the sets.
    #[command(flatten)]
    pub sets: SetArgs,
    /// Continuous time: bound steps on a proven piece of the filter by its Taylor form to
    /// second order too (a third-order remainder)
    #[arg(long)]
    pub taylor3: bool,
    /// Continuous time, a scalar input's closed form: do not bound the field across a switching
    /// surface by the lattice of the filter's pieces (only by the enclosures of `v`)
    #[arg(long)]
    pub no_lattice: bool,
    /// Continuous time with a transform: do not clip each frame's slabs by the other frame's
    /// sets before bounding the field on them (far looser where the closed loop rotates)
    #[arg(long)]
    pub no_meet_slabs: bool,
}

impl ReachFlags {
    /// `base` (the scenario's settings) with the options given on the command line.
    pub fn settings(&self, base: &ReachSettings) -> ReachSettings {
        let mut s = base.clone();
        if given("bounds") {
            s.bounds = self.bounds;
        }
        if given("method") {
            s.method = self.method;
        }
        s.face_local |= self.face_local;
        if self.exact.network_everywhere {
            s.exact = ExactField::Nowhere;
        } else if given("exact") {
            s.exact = self.exact.exact;
        }
        if self.sets.parallelotope_only {
            s.intersect_x = false;
        }
        s.taylor3 |= self.taylor3;
        if self.no_lattice {
            s.lattice = false;
        }
        if self.no_meet_slabs {
            s.meet_slabs = false;
        }
        s
    }
}

/// What `reach`, `verify` and `plot` need to compile a problem.
#[derive(clap::Args, Clone, Debug, Default)]
pub struct ProblemArgs {
    /// Override the scenario's M_C: a number ≥ 0, or `certified`, `measured` or `local` (from
    /// the error map beside the network, as in the scenario file).
    #[arg(long = "m-c")]
    pub m_c: Option<Margin>,
    /// Use this network instead of the scenario's.
    #[arg(long)]
    pub network: Option<PathBuf>,
    /// Coordinates of the embedding: `default` (x where the closed loop at the goal contracts
    /// in ℓ∞, else `auto`), `none`, `auto`, `lyapunov`; the scenario's choice when absent.
    #[arg(long)]
    pub transform: Option<TransformChoice>,
    /// Disturbance method: use the certified local error bounds of the error map beside the
    /// network (written by `cbfreach error`) instead of one global M_C (the default when the
    /// scenario says `m_c = "local"`).
    #[arg(long)]
    pub local_margin: bool,
    /// Disturbance method: do not intersect the sets with the safe set's affine half-spaces
    /// (`S` is forward invariant under the filter, so intersecting is sound; this switch is for
    /// comparisons).
    #[arg(long)]
    pub no_safe_set: bool,
    /// What the sets bound: `continuous` (the filtered ODE, validated steps), `sampled` (a
    /// digital controller held over --control-period), `euler` (the paper's Euler map);
    /// default: the scenario's `[reach] time`, else continuous.
    #[arg(long, value_parser = ["continuous", "sampled", "euler"])]
    pub time: Option<String>,
    /// The control period T_s of `--time sampled`, K·dt with K a whole number ≥ 1 (default:
    /// the scenario's, else dt).
    #[arg(long)]
    pub control_period: Option<f64>,
    /// Cut each continuous-time step in K validated steps (default: the scenario's, else 1).
    #[arg(long, value_parser = |s: &str| super::whole_at_least(s, 1))]
    pub substeps: Option<usize>,
    /// Continuous time, where the closed loop at the goal turns sets: keep them in K frames
    /// turned about the turn, whose slabs clip each other (1: none turned; default: the
    /// scenario's `[reach] turned_frames`, else chosen from the turn and said).
    #[arg(long, value_name = "K", value_parser = |s: &str| super::whole_at_least(s, 1))]
    pub turned_frames: Option<usize>,
}

impl ProblemArgs {
    /// The library's options.
    pub fn options(&self) -> ProblemOptions {
        ProblemOptions {
            network: self.network.clone(),
            m_c: self.m_c,
            transform: self.transform.clone(),
            local_margin: self.local_margin,
            no_safe_set: self.no_safe_set,
            time: self.time.clone(),
            control_period: self.control_period,
            substeps: self.substeps,
            turned_frames: self.turned_frames,
        }
    }
}

/// Compiles the problem, naming the command-line option where the options' `M_C` failed.
pub fn compile(
    s: &cbfreach::Scenario,
    args: &ProblemArgs,
) -> Result<ReachProblem, Box<dyn std::error::Error>> {
    let choice = args.transform.as_ref().unwrap_or(&s.reach.transform);
    if *choice == cbfreach::scenario::TransformChoice::Chosen {
        // The coordinates were left to cbfreach: say which and why.
        let (_, why) = cbfreach::reach::Transform::chosen(s);
        println!("coordinates (reach.transform not set): {why}");
    }
    let turning = Turning::at_goal(s);
    if let Some(t) = &turning {
        println!("note: {t}");
    }
    if let Some(t) = cbfreach::reach::Transient::at_goal(s, choice) {
        println!("note: {t}");
    }
    let problem = ReachProblem::from_scenario(s, &args.options()).map_err(
        |e| -> Box<dyn std::error::Error> {
            match e {
                ProblemError::Margin {
                    margin,
                    source,
                    file,
                    field,
                } => {
                    let field = if field == "m_c" {
                        "--m-c".into()
                    } else {
                        field
                    };
                    // A stale map's message already says to run `error` again: one piece of advice.
                    let text = source.to_string();
                    match (text.strip_suffix(" (run `cbfreach error` again)"), *source) {
                        (Some(head), _) => format!(
                    "{field} = {margin}: {head} (run `cbfreach error {file}` again, or give --m-c)"
                ),
                        (None, ErrorMapError::Io { .. } | ErrorMapError::Format { .. }) => format!(
                    "{field} = {margin}: {text} (run `cbfreach error {file}` first, or give --m-c)"
                ),
                        (None, _) => format!("{field} = {margin}: {text} (or give --m-c)"),
                    }
                    .into()
                }
                ProblemError::Time(e) => format!(
                    "--time {}: {e}",
                    args.time.as_deref().unwrap_or(s.reach.time.name())
                )
                .into(),
                ProblemError::NoNetwork { file } => {
                    format!("{file}: no [network] section and no --network given").into()
                }
                // The option as given, where it was given.
                e if args.turned_frames.is_some() => e
                    .to_string()
                    .replace("reach.turned_frames = ", "--turned-frames ")
                    .into(),
                e => e.into(),
            }
        },
    )?;
    let frames = problem.turned.len() + 1;
    let chosen = args.turned_frames.or(s.reach.turned_frames).is_none();
    if let Some(t) = turning.filter(|_| frames > 1 && chosen) {
        // The frames were left to cbfreach too.
        println!(
            "turned frames (reach.turned_frames not set): the sets are kept in z and {} copies of \
             it turned by multiples of π/{} as well, whose slabs clip each other (their meet \
             shrinks at about {:.3} where one frame's boxes grow at {:.3}); 1 turns none",
            frames - 1,
            2 * frames,
            t.rate_in(frames),
            t.box_rate(),
        );
    }
    Ok(problem)
}

/// The engine asked for a run of `boxes` boxes, its notices printed (an engine refuses
/// settings it does not run).
pub fn engine(
    args: &EngineArgs,
    settings: &mut ReachSettings,
    problem: &ReachProblem,
    boxes: usize,
) -> Result<Box<dyn Backend + Sync>, Box<dyn std::error::Error>> {
    let gpu = &args.gpu;
    let chosen = choose_engine(args.backend, &gpu.options(), settings, problem, boxes).map_err(
        |e| -> Box<dyn std::error::Error> {
            match e {
                EngineError::PrecisionOnCpu(_) => {
                    let flag = if gpu.f64 { "--f64" } else { "--f32" };
                    format!(
                        "{flag} selects the GPU engine's number type; the CPU engine computes \
                         in f64 always (drop {flag}, or use --backend gpu/auto)"
                    )
                    .into()
                }
                e => e.into(),
            }
        },
    )?;
    for notice in &chosen.notices {
        println!("{notice}");
    }
    Ok(chosen.backend)
}

/// A settings error with the option that sets the field.
pub fn settings_flag_error(e: &cbfreach::reach::SettingsError) -> String {
    format!("--{}: {e}", e.field().replace('_', "-"))
}
