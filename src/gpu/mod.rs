//! The GPU engine (wgpu, WGSL compute shaders): whole batches of boxes bounded and integrated
//! on the device, sound in f32 (issue 3; docs/design.md §3–§5).
//!
//! - [`context`]: adapter selection (a real GPU before a software one, `--adapter NAME`), the
//!   device with the adapter's limits.
//! - [`kernels`]: one struct per pipeline (`shaders/*.wgsl`, included at compile time).
//! - [`disk_cache`]: compiled pipelines kept on disk between runs (`$CBFREACH_CACHE_DIR`).
//! - [`buffers`]: `#[repr(C)]` images of what the kernels read; the device layout.
//! - [`codegen`]: scenario expressions as WGSL interval inclusion functions.
//! - [`exp64`]: the f64 shaders' `exp` enclosure mirrored in Rust, and run on the device.
//! - [`probe`]: single WGSL primitives run on the device, for tests against their Rust originals;
//!   [`probe_field`] those that read the problem's generated field (the slab form, curved rates).
//! - [`margins`]: the error map as a range-maximum structure on the device, for local error
//!   margins (`--local-margin`): the CPU's exact `M` for any set size in O(log) reads.
//! - [`GpuBackend`]: [`crate::reach::Backend`] on the device: forward linear bounds,
//!   forward-backward (forward ∩ IBP intermediate bounds, one backward CROWN pass from the
//!   output) and backward CROWN, each in f32 or (`--f64`, [`Precision::F64`]) f64.
//!
//! # Error model (docs/design.md §3)
//!
//! The device computes in f32 (or f64) with no rounding-mode control; Vulkan allows
//! round-to-nearest or towards zero, so a computed `+ − ×` is within one ulp (`u = 2⁻²³`
//! relative in f32, `2⁻⁵²` in f64) of the exact result, and subnormals may be flushed. Every
//! shader is written once over `real`; the precision prelude (`shaders/real_f32.wgsl`,
//! `real_f64.wgsl`) sets `u`, `γ̂_N = 4(N+3)u`, the outward step and the smallest normal
//! number. The kernels keep the CPU's invariant (the *computed* forms, evaluated exactly, bound
//! the exact network with the stored f64 weights) by:
//!
//! - **Dot products** (a layer's `W·Ĉ`, `|W|·R̂`): the computed sum of `N` terms, each the
//!   product of an f32-rounded weight and a coefficient (two roundings), errs by at most
//!   `γ̂_N·Σ|W||·| + N·scale·ABS_UNIT` with `γ̂_N = (N+3)·2⁻²¹ ≥ 2γ_{N+3}`,
//!   `γ_k = k u/(1 − k u)` (the factor 2 covers the rounding of the magnitude sum, which the
//!   GEMM computes as `|W|·V`), and `ABS_UNIT = (1 + max|W|)·2⁻¹²⁰` for flushed subnormals. The
//!   bound is added to the constant of the radius form `R̂`, rounded up (`err_bound` in
//!   `shaders/common.wgsl`); layer widths are limited to 2¹⁸ so that `N u ≤ 1/32`.
//! - **First layer**: `Ĉ = [fl(W₁) | fl(b₁)]` with the conversion error
//!   `≤ 2⁻²⁴(Σ|W₁|·|x| + |b₁|)` in `R̂`'s constant (f32; in f64 the weights are the host's
//!   exactly, and only the absolute part for a flushed subnormal is added: `conversion_error`
//!   in `shaders/common.wgsl`). A face's pinned coordinates are folded into the constant, as
//!   on the CPU, with the CPU's one bound `ε` of the fold's rounding per box (from constants
//!   uploaded after the network, rounded up in f32: `buffers::FlatNetwork`), widening the
//!   first layer's concretisation and entering the next layer's `R̂` as `rowsum(|W|)·ε`
//!   (`shaders/fold.wgsl`).
//! - **ReLU and output**: as `bounds::forward` on the CPU, with the device's `γ̂`; IBP alongside
//!   (forward-backward) as `bounds::ibp`, intersected.
//! - **Backward passes** (`shaders/backward.wgsl`): as `bounds::crown`: `Λ ← Wⱼᵀ·(Λ∘s)` is one
//!   GEMM for all boxes, and `β` moves outward by `err_bound(2nⱼ + 2, Σ|Λ∘s| w + |Λt|)`, with
//!   `w = |Wⱼ| magⱼ + |bⱼ|` from a GEMM of `max(u, 0)`; the pass's start `Λ = fl(W_k)` adds its
//!   conversion error `err_bound(2, |W_k| mag_k + |b_k|)` to `β` (f32; as above in f64).
//! - **Single operations** (interval arithmetic, concretisation, Euler step): each result is
//!   stepped outward (`up`, `down`: one ulp through the bit pattern in f32; `max(|x|·2⁻⁵⁰,
//!   MIN_NORMAL)` arithmetically in f64, which WGSL cannot bitcast without 64-bit integers);
//!   divisions three steps (2.5 ulp accurate); `exp`, `ln`, `sqrt`, `sin`, `cos` widened by the
//!   WGSL accuracy table. f64 constants enter as the device intervals that contain them; `dt`
//!   as `[↓dt, ↑dt]`.
//! - **f64**: Vulkan itself promises f64 operations only single precision; the f64 engine
//!   assumes IEEE-754 `+ − ×` (correctly rounded: lavapipe's LLVM code, NVIDIA, AMD) and
//!   widens by one ulp (`u = 2⁻⁵²`) as above, divisions by three steps. SPIR-V has `exp`,
//!   `log` for 32-bit floats only, so the f64 shaders evaluate `ln`, `sqrt` in f32 at an
//!   argument on the safe side and widen by the f32 accuracy (relative ~1e-6); `exp` is an f64
//!   range reduction and polynomial with a rigorous remainder ([`exp64`] mirrors it, a test
//!   compares the two on the device), and `sin`, `cos` f64 polynomials with a rigorous
//!   remainder (`real_f64.wgsl`), over the exact range of the interval (endpoints and
//!   extrema), as on the CPU.
//! - **Overflow, NaN**: WGSL does not promise IEEE infinities, so every bound is compared with
//!   `1e30`; a box past it is reported as non-finite, as the CPU reports an overflow.
//!
//! - **Local error margins**: the map's cells rounded outward, their bounds rounded up, found
//!   by comparisons alone (`margins`): `M` on the device is the CPU's
//!   `ErrorMap::local_bound` of the computed x-box in f64, at least it in f32.
//!
//! The Euler step itself is the paper's, not a validated integrator (README, Limitations).

pub mod backend;
pub mod buffers;
pub mod codegen;
pub mod context;
pub mod disk_cache;
pub mod exp64;
pub mod kernels;
pub mod margins;
pub mod probe;
pub mod probe_field;

pub use backend::GpuBackend;
pub use context::GpuContext;

/// The device's number type.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub enum Precision {
    /// f32 (every device).
    #[default]
    F32,
    /// f64 (`wgpu::Features::SHADER_F64`; `--f64`).
    F64,
}

impl Precision {
    /// Bytes per number.
    pub fn bytes(self) -> u64 {
        match self {
            Precision::F32 => 4,
            Precision::F64 => 8,
        }
    }

    /// `f32` or `f64`.
    pub fn name(self) -> &'static str {
        match self {
            Precision::F32 => "f32",
            Precision::F64 => "f64",
        }
    }
}

/// Why the GPU engine could not run.
#[derive(Debug, thiserror::Error)]
pub enum GpuError {
    /// No adapter (or none with the requested name).
    #[error("no GPU adapter{}; available: {}", requested.as_ref().map(|r| format!(" named like `{r}`")).unwrap_or_default(), if available.is_empty() { "none (install a Vulkan driver, e.g. mesa-vulkan-drivers)".to_string() } else { available.join(", ") })]
    NoAdapter {
        /// The `--adapter` name, if one was given.
        requested: Option<String>,
        /// Every adapter found.
        available: Vec<String>,
    },
    /// The device could not be created or reported an error.
    #[error("GPU device: {0}")]
    Device(String),
    /// A shader did not compile (a bug, or a dynamics expression the emitter got wrong).
    #[error("GPU shader: {0}")]
    Shader(String),
    /// The problem does not fit the engine.
    #[error("GPU engine: {0}")]
    Problem(String),
    /// A buffer or dispatch would exceed the device's limits even after splitting.
    #[error("GPU limits: {0}")]
    TooLarge(String),
    /// `--f64` on an adapter without f64 shaders.
    #[error("adapter `{0}` has no f64 shaders (wgpu::Features::SHADER_F64); run without --f64, or pick another adapter with --adapter")]
    NoF64(String),
    /// The engine does not implement these settings yet.
    #[error("not on the GPU yet: {0}")]
    Unsupported(String),
}
