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
pub mod matmul;
pub mod network;
pub mod plot;
pub mod reach;
pub mod rounding;
pub mod scenario;
pub mod simulate;
pub mod surrogate_error;
pub mod verify;

pub use boxes::IntervalBox;
pub use error::Error;
pub use intervals::Interval;
pub use network::Mlp;
