//! `cbfreach reach <scenario>`: tubes from the scenario's initial boxes.

use std::path::PathBuf;

use cbfreach::bounds::BoundMethod;
use cbfreach::network::Mlp;
use cbfreach::reach::{
    Backend, CpuBackend, ExactField, ReachMethod, ReachProblem, ReachResult, ReachSettings,
    Transform,
};
use cbfreach::scenario::{Margin, Scenario, TransformChoice};
use serde::Serialize;

use super::{fmt_point, load_scenario, progress_bar, CliResult};

/// Arguments of `cbfreach reach`.
#[derive(clap::Args)]
pub struct ReachArgs {
    /// The scenario file (TOML).
    pub scenario: PathBuf,
    /// Engine: `cpu`, `gpu` (wgpu; forward, forward-backward and crown bounds), or `auto` (the
    /// GPU when an adapter exists and runs these settings, else the CPU with a notice).
    #[arg(long, default_value = "cpu")]
    pub backend: String,
    /// GPU adapter and precision.
    #[command(flatten)]
    pub gpu: GpuArgs,
    /// How the network is bounded over each box.
    #[arg(long, value_enum, default_value_t = BoundMethod::ForwardBackward)]
    pub bounds: BoundMethod,
    /// How the network's error enters the sets.
    #[arg(long, value_enum, default_value_t = ReachMethod::Disturbance)]
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
    /// Record every K-th step (the last is always recorded).
    #[arg(long, default_value_t = 1, value_parser = |s: &str| super::whole_at_least(s, 1))]
    pub every: usize,
    /// The network, `M_C` and coordinates.
    #[command(flatten)]
    pub problem: ProblemArgs,
    /// Write the tubes as JSON here.
    #[arg(long)]
    pub json: Option<PathBuf>,
    /// Draw the tubes here (.png or .svg).
    #[arg(long)]
    pub plot: Option<PathBuf>,
}

#[derive(Serialize)]
struct ReachJson<'a> {
    scenario: &'a str,
    backend: String,
    bounds: BoundMethod,
    method: ReachMethod,
    dt: f64,
    time: cbfreach::reach::TimeModel,
    substeps: usize,
    m_c: f64,
    #[serde(flatten)]
    result: &'a ReachResult,
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
    /// The GPU number type for a device: as asked, else f64 where the device has f64 shaders.
    pub fn precision_for(&self, ctx: &cbfreach::gpu::GpuContext) -> cbfreach::gpu::Precision {
        use cbfreach::gpu::Precision;
        if self.f32 || (!self.f64 && !ctx.has_f64()) {
            Precision::F32
        } else {
            Precision::F64
        }
    }
}

/// Where the disturbance method takes the filter exactly (`reach`, `verify`).
#[derive(clap::Args, Clone, Debug, Default)]
pub struct ExactArgs {
    /// Where the CPU engine uses the filter itself besides the network plus its error margin:
    /// `closed-form` (closed-form filters: the filtered system's own field where the filter is
    /// provably one smooth function on the set, its enclosures of `v` elsewhere), `inactive`
    /// (only `v = 0` where the filter is proven inactive; any filter), `nowhere`.
    #[arg(long, value_enum, default_value_t = ExactField::ClosedForm)]
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

impl ExactArgs {
    /// The setting asked for.
    pub fn field(&self) -> ExactField {
        if self.network_everywhere {
            ExactField::Nowhere
        } else {
            self.exact
        }
    }
}

/// What `reach`, `verify` and `plot` need to compile a problem.
#[derive(clap::Args, Clone, Debug, Default)]
pub struct ProblemArgs {
    /// Override the scenario's M_C: a number ≥ 0, or `certified`, `measured` or `local` (from
    /// the error map beside the network, as in the scenario file).
    #[arg(long = "m-c", value_parser = parse_margin)]
    pub m_c: Option<Margin>,
    /// Use this network instead of the scenario's.
    #[arg(long)]
    pub network: Option<PathBuf>,
    /// Coordinates of the embedding: `none`, `auto`, `lyapunov`, or the scenario's choice when absent.
    #[arg(long)]
    pub transform: Option<String>,
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
    /// The control period T_s of `--time sampled`, a multiple of dt (default: the scenario's,
    /// else dt).
    #[arg(long)]
    pub control_period: Option<f64>,
    /// Cut each continuous-time step in K validated steps (default: the scenario's, else 1).
    #[arg(long, value_parser = |s: &str| super::whole_at_least(s, 1))]
    pub substeps: Option<usize>,
}

/// `--transform` or the scenario's choice.
pub fn transform_choice(s: &Scenario, flag: Option<&str>) -> Result<TransformChoice, String> {
    match flag {
        None => Ok(s.reach.transform.clone()),
        Some("none") => Ok(TransformChoice::Identity),
        Some("auto") => Ok(TransformChoice::Auto),
        Some("lyapunov") => Ok(TransformChoice::Lyapunov),
        Some(other) => Err(format!(
            "--transform {other}: expected none, auto or lyapunov"
        )),
    }
}

/// Compiles the reach problem of a scenario with its (or the given) network.
pub fn compile(
    s: &Scenario,
    args: &ProblemArgs,
) -> Result<ReachProblem, Box<dyn std::error::Error>> {
    let net = load_network(s, args.network.as_ref())?;
    let path = network_path(s, args.network.as_ref())?;
    let m_c = resolve_margin(s, args.m_c, &path)?;
    let transform = Transform::for_scenario(s, &transform_choice(s, args.transform.as_deref())?)?;
    let mut problem = ReachProblem::with_transform(s, net, m_c, transform)?;
    if args.time.is_some() || args.control_period.is_some() || args.substeps.is_some() {
        let old = match s.reach.time {
            cbfreach::reach::TimeModel::Sampled { control_period } => Some(control_period),
            _ => None,
        };
        let name = args.time.as_deref().unwrap_or(s.reach.time.name());
        let time = cbfreach::reach::TimeModel::parse(name, args.control_period.or(old), s.reach.dt)
            .map_err(|e| format!("--time {name}: {e}"))?;
        problem = problem.with_time(time, args.substeps.unwrap_or(s.reach.substeps));
    }
    if args.no_safe_set {
        problem = problem.without_safe_set();
    }
    // Local bounds on request, or by the scenario's `m_c = "local"` unless --m-c overrides it.
    let local = args.local_margin || args.m_c.unwrap_or(s.reach.m_c) == Margin::Local;
    if !local {
        return Ok(problem);
    }
    let map = cbfreach::surrogate_error::ErrorMap::load_for(&path).map_err(|e| {
        format!(
            "local error margins: {e} (run `cbfreach error {}` first)",
            s.file
        )
    })?;
    Ok(problem.with_error_map(map)?)
}

/// Loads the network named by `--network` or by the scenario.
pub fn load_network(
    s: &Scenario,
    path: Option<&PathBuf>,
) -> Result<Mlp, Box<dyn std::error::Error>> {
    let path = network_path(s, path)?;
    if !path.exists() {
        return Err(format!(
            "{}: network file {} does not exist (train one with `cbfreach train {}`)",
            s.file,
            path.display(),
            s.file
        )
        .into());
    }
    Ok(Mlp::load_safetensors(&path)?)
}

/// The network file named by `--network` or by the scenario.
pub fn network_path(
    s: &Scenario,
    path: Option<&PathBuf>,
) -> Result<PathBuf, Box<dyn std::error::Error>> {
    match (path, &s.network) {
        (Some(p), _) => Ok(p.clone()),
        (None, Some(net)) => Ok(net.file.clone()),
        (None, None) => {
            Err(format!("{}: no [network] section and no --network given", s.file).into())
        }
    }
}

/// `--m-c`: a number ≥ 0, or where in the error map to take `M_C` from.
fn parse_margin(text: &str) -> Result<Margin, String> {
    match text {
        "certified" => Ok(Margin::Certified),
        "measured" => Ok(Margin::Measured),
        "local" => Ok(Margin::Local),
        _ => match text.parse::<f64>() {
            Ok(v) if v.is_finite() && v >= 0.0 => Ok(Margin::Value(v)),
            _ => Err(format!(
                "expected a number ≥ 0, certified, measured or local, found {text:?}"
            )),
        },
    }
}

/// `M_C` from the flag or the scenario; `"certified"` / `"measured"` / `"local"` come from the
/// error map beside `network` (written by `cbfreach error`).
pub fn resolve_margin(
    s: &Scenario,
    flag: Option<Margin>,
    network: &std::path::Path,
) -> Result<f64, String> {
    let margin = flag.unwrap_or(s.reach.m_c);
    cbfreach::surrogate_error::margin_value(margin, network).map_err(|e| {
        let source = match flag {
            Some(_) => "--m-c".to_string(),
            None => format!("{}: reach.m_c", s.file),
        };
        format!(
            "{source} = {margin:?}: {e} (run `cbfreach error {}` first, or give --m-c)",
            s.file
        )
    })
}

/// Runs the command.
pub fn run(args: &ReachArgs) -> CliResult {
    let s = load_scenario(&args.scenario)?;
    if !matches!(args.backend.as_str(), "cpu" | "gpu" | "auto") {
        return Err(format!("--backend {}: expected cpu, gpu or auto", args.backend).into());
    }
    let problem = compile(&s, &args.problem)?;
    let m_c = problem.m_c;
    if let Some(t) = &problem.transform {
        println!("embedding in z = T x, T = {:?} (ρ = {:.1e})", t.t, t.rho);
    }
    let mut settings = ReachSettings {
        bounds: args.bounds,
        method: args.method,
        every: args.every,
        face_local: args.face_local,
        exact: args.exact.field(),
        intersect_x: !args.sets.parallelotope_only,
    };
    let backend = choose_backend(
        engine_for_time(&args.backend, &problem),
        &args.gpu,
        &settings,
    )?;
    settle_for_engine(&mut settings, backend.as_ref(), &problem);
    let bar = progress_bar(problem.steps as u64, "Euler steps");
    let result = backend.reach(&problem, &s.reach.initial, &settings, &|done, _| {
        bar.set_position(done as u64)
    })?;
    bar.finish_and_clear();

    let margin = match &problem.error_map {
        Some(map) if args.method == ReachMethod::Disturbance => format!(
            "M = local bounds of the error map (certified global {})",
            map.certified_linf
                .map_or("none".into(), |v| format!("{v:.4}"))
        ),
        _ => format!("M_C = {m_c}"),
    } + settings.exact_field().clause()
        + if problem.frames(&settings).len() > 1 {
            INTERSECT_X_CLAUSE
        } else {
            ""
        };
    let within = super::safe_set_clause(&problem.safe_set_for(args.method).names());
    println!(
        "{}: {} boxes × {} steps, time {}, {} bounds{}, {:?} method, {margin}{within}, backend {}",
        s.file,
        result.boxes.len(),
        problem.steps,
        time_clause(&problem),
        args.bounds,
        if args.face_local { " (face-local)" } else { "" },
        args.method,
        backend.name()
    );
    for tube in &result.boxes {
        if let Some(last) = tube.last() {
            let set = last.filtered_set().clone();
            let width = set.widths().iter().fold(0.0_f64, |a, &b| a.max(b));
            let where_ = if set.is_subset_of(&s.reach.goal) {
                "in the goal set".to_string()
            } else {
                format!("max width {width:.3}")
            };
            println!(
                "  {} … {}  →  t = {:.2}: {} … {}  {}{}",
                fmt_point(&tube.initial.lower),
                fmt_point(&tube.initial.upper),
                last.t,
                fmt_point(&set.lower),
                fmt_point(&set.upper),
                where_,
                match (tube.valid, &tube.note) {
                    (true, _) => String::new(),
                    (false, Some(note)) => format!("  INVALID ({note})"),
                    (false, None) => "  INVALID".to_string(),
                }
            );
        }
    }
    // Boxes stop where their sets leave C: the rate counts the steps run.
    let run: usize = result.boxes.iter().map(|t| t.steps_run(problem.dt)).sum();
    let all = result.boxes.len() * problem.steps;
    println!(
        "  time: {:.3} s embedding ({:.0} box-steps/s; {run} of {all} box-steps run), {:.3} s \
         Minkowski",
        result.timing.reach_s,
        run as f64 / result.timing.reach_s.max(1e-12),
        result.timing.minkowski_s
    );
    if settings.exact_field() != ExactField::Nowhere {
        let exact: usize = result.boxes.iter().map(|t| t.exact_steps).sum();
        let enclosed: usize = result.boxes.iter().map(|t| t.enclosed_steps).sum();
        println!(
            "  the filtered system's own field (the filter proven one smooth function on the set) \
             on {exact} of the {run} box-steps{}",
            if enclosed > 0 {
                format!(", the closed form's enclosures of v on {enclosed}")
            } else {
                String::new()
            }
        );
    }
    let invalid = result.boxes.iter().filter(|t| !t.valid).count();
    if invalid > 0 {
        println!(
            "  {invalid} of {} sets stopped (INVALID): {}`cbfreach verify` splits boxes until they \
             verify",
            result.boxes.len(),
            if args.face_local {
                ""
            } else {
                "bounds on each face of a box (--face-local, 2n× the bound cost) are tighter, and "
            }
        );
    }
    if let Some(path) = &args.json {
        let json = ReachJson {
            scenario: &s.file,
            backend: backend.name(),
            bounds: args.bounds,
            method: args.method,
            dt: problem.dt,
            time: problem.time,
            substeps: problem.steps_per_dt(),
            m_c,
            result: &result,
        };
        std::fs::write(path, serde_json::to_string(&json)?)
            .map_err(|e| format!("{}: {e}", path.display()))?;
        println!("  tubes written to {}", path.display());
    }
    if let Some(path) = &args.plot {
        super::plot::plot_tubes(&s, &result, args.every, m_c, path)?;
    }
    Ok(())
}

/// For summaries: the time model, with its substeps.
pub fn time_clause(problem: &ReachProblem) -> String {
    match problem.steps_per_dt() {
        1 => problem.time.to_string(),
        k => format!("{} ({k} validated steps per dt)", problem.time),
    }
}

/// `--backend auto` takes the CPU where the time model is not the Euler map (the GPU engine
/// runs that alone), with a notice; `cpu` and `gpu` stay as asked (the GPU engine refuses).
pub fn engine_for_time<'a>(which: &'a str, problem: &ReachProblem) -> &'a str {
    if which == "auto" && problem.time != cbfreach::reach::TimeModel::Euler {
        println!(
            "notice: --backend auto: the GPU engine runs time = \"euler\" only; using the CPU \
             for time = \"{}\"",
            problem.time.name()
        );
        return "cpu";
    }
    which
}

/// For summaries: the sets are the meet of a box in x and the parallelotope.
pub const INTERSECT_X_CLAUSE: &str = ", sets met with their x-boxes";

/// What is the CPU engine's alone becomes, with the GPU engine, what that engine does, with a
/// notice (sound, looser): sets met with their x-boxes become the parallelotope alone.
pub fn settle_for_engine(
    settings: &mut ReachSettings,
    backend: &dyn Backend,
    problem: &ReachProblem,
) {
    if backend.name() == "cpu" {
        return;
    }
    if problem.frames(settings).len() > 1 {
        settings.intersect_x = false;
        println!(
            "note: the GPU engine keeps the parallelotope alone (sets met with their x-boxes are \
             the CPU engine's): --parallelotope-only"
        );
    }
}

/// The engine named by `--backend` (`cpu`, `gpu`, or `auto`: a GPU when an adapter exists and
/// supports the bound method, else the CPU with a one-line notice), on `--adapter`, in f64
/// where the adapter has f64 shaders (else, or with `--f32`, f32); `--f64` on an adapter
/// without f64 shaders is an error, also with `auto`.
///
/// `auto` takes the GPU where it runs the bound method (local error margins and face-local
/// bounds included) and is a real GPU (a software adapter is many times slower than the CPU
/// engine).
pub fn choose_backend(
    which: &str,
    gpu: &GpuArgs,
    settings: &ReachSettings,
) -> Result<Box<dyn Backend + Sync>, Box<dyn std::error::Error>> {
    if !matches!(which, "cpu" | "gpu" | "auto") {
        return Err(format!("--backend {which}: expected cpu, gpu or auto").into());
    }
    if which == "cpu" {
        if gpu.f64 || gpu.f32 {
            let flag = if gpu.f64 { "--f64" } else { "--f32" };
            return Err(format!(
                "{flag} selects the GPU engine's number type; the CPU engine computes in f64 \
                 always (drop {flag}, or use --backend gpu/auto)"
            )
            .into());
        }
        return Ok(Box::new(CpuBackend));
    }
    let supported = cbfreach::gpu::GpuBackend::supports(settings);
    if which == "auto" && !supported {
        println!(
            "notice: --backend auto: the GPU engine has no {} bounds yet; using the CPU",
            settings.bounds
        );
        return Ok(Box::new(CpuBackend));
    }
    match cbfreach::gpu::GpuContext::with_adapter(gpu.adapter.as_deref()) {
        Ok(ctx) if which == "auto" && ctx.is_software() && gpu.adapter.is_none() => {
            println!(
                "notice: --backend auto: the only GPU adapter is a software one ({}); using the \
                 CPU (name it with --adapter to use it anyway)",
                ctx.describe()
            );
            Ok(Box::new(CpuBackend))
        }
        Ok(ctx) => {
            println!("GPU adapter: {}", ctx.describe());
            let precision = gpu.precision_for(&ctx);
            let engine =
                cbfreach::gpu::GpuBackend::with_precision(std::sync::Arc::new(ctx), precision)?;
            Ok(Box::new(engine))
        }
        Err(e) if which == "auto" => {
            println!("notice: --backend auto: {e}; using the CPU");
            Ok(Box::new(CpuBackend))
        }
        Err(e) => Err(e.into()),
    }
}
