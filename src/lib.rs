//! # cbfreach
//!
//! Sound, batched interval reachability for control systems whose inputs pass through a
//! control-barrier-function (CBF) safety filter, following *Neural Network-assisted Interval
//! Reachability for Systems with Control Barrier Function-Based Safe Controllers* (L4DC 2025).
//!
//! Data flows one way: a [`scenario::Scenario`] file is compiled into plain arrays and expression
//! trees; the ground-truth [`filter::SafetyFilter`] `v(x)` is evaluated by closed forms or
//! clarabel; a ReLU [`network::Mlp`] `N(x) ≈ v(x)` is bounded over boxes by [`bounds`]; the
//! embedding system turns those bounds into tubes; verdicts and pictures read the tubes.
//!
//! The front door: load a [`Scenario`], compile it into a [`ReachProblem`] (its network, `M_C`
//! and coordinates, as [`ProblemOptions`] say), and run a [`Verifier`] on an engine
//! ([`CpuBackend`], or [`GpuBackend`]) over a grid of initial boxes ([`VerifySettings`]); or
//! run the engine's [`Backend::reach`] for [`Tube`]s under [`ReachSettings`]. Every setting's
//! `Default` is what the command line does.
//!
//! ```
//! use cbfreach::{CpuBackend, IntervalBox, ProblemOptions, ReachProblem, Scenario, Verifier,
//!     VerifySettings};
//!
//! let file = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("scenarios/integrator.toml");
//! let scenario = Scenario::load(&file)?;
//! // The paper's Euler map (`time` left out: the continuous-time flow, the default).
//! let options = ProblemOptions { time: Some("euler".into()), ..ProblemOptions::default() };
//! let problem = ReachProblem::from_scenario(&scenario, &options)?;
//! let verifier = Verifier::new(&scenario, &problem, &CpuBackend);
//! // A 4 × 3 grid over [−2, 2] × [−1.5, 1.5], the scenario's own settings otherwise.
//! let settings = VerifySettings {
//!     region: Some(IntervalBox::new(vec![-2.0, -1.5], vec![2.0, 1.5])?),
//!     grid: vec![4, 3],
//!     ..scenario.settings.verify.clone()
//! };
//! let report = verifier.run(&settings, &|_stage, _done, _all| {})?;
//! let shares = report.shares_after();
//! // 62.5 %: the boxes that start near the obstacle are left open at this size.
//! assert!(shares.verified_share > 0.5, "{:.3}", shares.verified_share);
//! # Ok::<(), cbfreach::Error>(())
//! ```
#![warn(missing_docs)]

pub mod bounds;
pub mod boxes;
pub mod dataset;
pub mod equilibria;
pub mod error;
pub mod error_map;
pub mod expressions;
pub mod filter;
pub mod gpu;
pub mod intervals;
pub mod machine;
pub mod matmul;
pub mod network;
pub mod output;
pub mod plot;
pub mod problem;
pub mod provenance;
pub mod reach;
pub mod rounding;
pub mod scenario;
pub mod simulate;
pub mod surrogate_error;
pub mod training;
pub mod verify;

pub use boxes::IntervalBox;
pub use error::Error;
pub use gpu::GpuBackend;
pub use intervals::Interval;
pub use network::Mlp;
pub use problem::{ProblemError, ProblemOptions};
pub use reach::{Backend, CpuBackend, ReachProblem, ReachSettings, Tube, TubeEnd};
pub use scenario::Scenario;
pub use verify::{Verdict, Verifier, VerifyReport, VerifySettings};
