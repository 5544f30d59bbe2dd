//! Which engine runs a problem: the CPU, a GPU, or the GPU where it can ([`EngineChoice`]),
//! and what to tell a user whose settings an engine refuses ([`refusal`]). May import `reach` and
//! `gpu`; what a caller should be told comes back as notices, not printed.

use std::str::FromStr;
use std::sync::Arc;

use super::{Backend, CpuBackend, ReachProblem, ReachSettings, Unsupported};
use crate::gpu::{GpuBackend, GpuContext, GpuError, Precision};

/// Which engine: `cpu`, `gpu`, or `auto` (the GPU when a real adapter exists and runs the
/// settings, else the CPU).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum EngineChoice {
    /// The CPU engine (f64 always).
    #[default]
    Cpu,
    /// The wgpu engine.
    Gpu,
    /// The GPU where it runs the settings and is not a software adapter, else the CPU.
    Auto,
}

impl FromStr for EngineChoice {
    type Err = crate::scenario::ChoiceError;

    fn from_str(text: &str) -> Result<EngineChoice, Self::Err> {
        match text {
            "cpu" => Ok(EngineChoice::Cpu),
            "gpu" => Ok(EngineChoice::Gpu),
            "auto" => Ok(EngineChoice::Auto),
            _ => Err(crate::scenario::ChoiceError {
                found: text.to_string(),
                expected: "cpu, gpu or auto",
            }),
        }
    }
}

/// The GPU engine's adapter and number type.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct GpuOptions {
    /// An adapter whose name contains this (case-insensitive); default: a real GPU before a
    /// software one.
    pub adapter: Option<String>,
    /// The number type; default: f64 where the adapter has f64 shaders, else f32.
    pub precision: Option<Precision>,
}

impl GpuOptions {
    /// The number type on a device: as asked, else f64 where the device has f64 shaders.
    pub fn precision_for(&self, ctx: &GpuContext) -> Precision {
        match self.precision {
            Some(p) => p,
            None if ctx.has_f64() => Precision::F64,
            None => Precision::F32,
        }
    }
}

/// Why no engine could be made.
#[derive(Debug, thiserror::Error)]
pub enum EngineError {
    /// A GPU number type was asked of the CPU engine.
    #[error(
        "precision {} selects the GPU engine's number type; the CPU engine computes in f64 \
         always",
        .0.name()
    )]
    PrecisionOnCpu(Precision),
    /// The GPU could not be opened.
    #[error(transparent)]
    Gpu(#[from] GpuError),
}

/// An engine and what the caller should be told about how it was chosen.
pub struct Engine {
    /// The engine.
    pub backend: Box<dyn Backend + Sync>,
    /// One line each: the adapter, or why `auto` fell back to the CPU.
    pub notices: Vec<String>,
}

/// What to tell a user whose settings an engine refuses: the setting, and how to change it.
pub fn refusal(unsupported: Unsupported) -> String {
    match unsupported {
        Unsupported::Bounds(b) => format!(
            "{b} bounds (bounds = \"{b}\"): the GPU engine has forward, forward-backward and \
             crown bounds; use one of them (--bounds) or the CPU engine (--backend cpu)"
        ),
        Unsupported::Sampled(what) => format!(
            "time = \"sampled\" with {what}: the GPU engine bounds a sampled run's network in \
             f64 alone, to compute what the CPU engine computes (docs/design.md §7.4); drop the \
             setting or use the CPU engine (--backend cpu)"
        ),
        Unsupported::Continuous(what) => format!(
            "time = \"continuous\" with {what}: the GPU engine's continuous step lacks it \
             (it runs the disturbance method, docs/design.md §7.4); change the setting or use \
             the CPU engine (--backend cpu)"
        ),
        Unsupported::ExactGeneralQp => "exact = \"closed-form\" for a general QP filter: the GPU \
             engine evaluates the one-row and scalar closed forms alone; set exact = \"inactive\" \
             (--exact inactive) or use the CPU engine (--backend cpu)"
            .to_string(),
        Unsupported::Function(f) => format!(
            "{f} in the scenario: the GPU engine does not evaluate it (WGSL's is f32 to 4096 \
             ulp); use the CPU engine (--backend cpu)"
        ),
    }
}

/// Boxes a run needs for `auto` to take a real GPU: below it the CPU engine was the faster
/// (an H200 took ~3.3 ms a step for 12 boxes, its host's 16 cores run ~45,000 box-steps a
/// second, and a cold start compiles the pipelines for up to a minute; docs/results.md); from
/// thousands of boxes the GPU is several times faster.
pub const AUTO_GPU_BOXES: usize = 1024;

/// The engine for `choice` on `gpu`'s adapter, for a run of `boxes` boxes. `auto` never
/// changes what is computed, only where: it takes the GPU where that engine runs `problem`
/// under `settings` as they are ([`GpuBackend::runs`]), the adapter is a real GPU (a software
/// adapter is many times slower than the CPU engine) and the run has at least
/// [`AUTO_GPU_BOXES`] boxes (both unless the adapter is named), else the CPU with a notice
/// naming why. `gpu` with settings the GPU engine does not run is refused by its `reach`,
/// naming the setting ([`refusal`]). A precision asked of an adapter without f64 shaders is an
/// error, also with `auto`.
pub fn choose_engine(
    choice: EngineChoice,
    gpu: &GpuOptions,
    settings: &ReachSettings,
    problem: &ReachProblem,
    boxes: usize,
) -> Result<Engine, EngineError> {
    let cpu = |notices: Vec<String>| Engine {
        backend: Box::new(CpuBackend),
        notices,
    };
    if choice == EngineChoice::Cpu {
        if let Some(p) = gpu.precision {
            return Err(EngineError::PrecisionOnCpu(p));
        }
        return Ok(cpu(vec![]));
    }
    let auto = choice == EngineChoice::Auto;
    if let (true, Err(u)) = (auto, GpuBackend::runs(problem, settings)) {
        return Ok(cpu(vec![format!(
            "notice: --backend auto: not on the GPU engine: {}; using the CPU",
            refusal(u)
        )]));
    }
    if auto && boxes < AUTO_GPU_BOXES && gpu.adapter.is_none() {
        return Ok(cpu(vec![format!(
            "notice: --backend auto: {boxes} boxes run faster on the CPU engine (the GPU \
             engine pays from about {AUTO_GPU_BOXES} boxes); using the CPU (--backend gpu to use \
             the GPU anyway)"
        )]));
    }
    match GpuContext::with_adapter(gpu.adapter.as_deref()) {
        Ok(ctx) if auto && ctx.is_software() && gpu.adapter.is_none() => Ok(cpu(vec![format!(
            "notice: --backend auto: the only GPU adapter is a software one ({}); using the \
             CPU (name it with --adapter to use it anyway)",
            ctx.describe()
        )])),
        Ok(ctx) => {
            let notice = format!("GPU adapter: {}", ctx.describe());
            let precision = gpu.precision_for(&ctx);
            let engine = GpuBackend::with_precision(Arc::new(ctx), precision)?;
            // What the engine refuses in its precision (f32 sampled runs).
            if let (true, Err(u)) = (auto, engine.supports(problem, settings)) {
                return Ok(cpu(vec![format!(
                    "notice: --backend auto: not on the GPU engine: {}; using the CPU",
                    refusal(u)
                )]));
            }
            Ok(Engine {
                backend: Box::new(engine),
                notices: vec![notice],
            })
        }
        Err(e) if auto => Ok(cpu(vec![format!(
            "notice: --backend auto: {e}; using the CPU"
        )])),
        Err(e) => Err(e.into()),
    }
}
