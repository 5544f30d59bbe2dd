//! The trainer's batched passes (values, tangents, IBP boxes) and its `Params`/`Scalar`.
//! May import: the network types, its safetensors I/O, `crate::matmul`.
//!
//! Batched forward and backward passes with forward-mode tangents, on the GEMMs of [`crate::matmul`].
//!
//! A batch of `B` samples with `n_t` tangent directions is one matrix of `r·B` rows,
//! `r = 1 + n_t`: rows `0..B` are the primal activations, rows `(j+1)B..(j+2)B` the tangents
//! `∂a/∂x_j`. Every layer is then one GEMM for all rows,
//!
//! ```text
//! Z_k = A_{k−1} W_kᵀ (+ b_k on primal rows),   A_k = D_k Z_k,   D_k = diag(z_k > 0) of the primal row,
//! ```
//!
//! i.e. the tangents follow the primal's ReLU pattern (`ReLU'(0) = 0`, as [`Mlp::jacobian`]).
//! Since `D_k` is piecewise constant, the backward pass is the same for primal and tangent rows:
//! `G_{k−1} = D_{k−1} (G_k W_k)`, `∂L/∂W_k = G_kᵀ A_{k−1}` (one GEMM over all `r·B` rows),
//! `∂L/∂b_k = Σ_primal rows G_k`. The cost is about `r×` a plain forward/backward.
//!
//! Determinism: the `gemm` crate threads only its loops over output blocks (m and n); each
//! output entry's sum over `k` runs in one fixed order, so results do not depend on the
//! thread count or on scheduling. They may differ between CPUs with different SIMD kernels
//! (FMA or not), as any floating-point code.
//!
//! [`Mlp::jacobian`]: super::Mlp::jacobian

use std::ops::{Add, AddAssign, Div, Mul, MulAssign, Sub};

use safetensors::tensor::Dtype;

use super::io::{f32_bytes, f64_bytes, RawTensors};
use super::{Layer, Mlp, NetworkError};
use crate::matmul::{matmul_strided, MatmulScalar, Threads};

/// The float type a training run computes in.
pub(crate) trait Scalar:
    MatmulScalar
    + Default
    + PartialOrd
    + Send
    + Sync
    + std::fmt::Debug
    + Add<Output = Self>
    + Sub<Output = Self>
    + Mul<Output = Self>
    + Div<Output = Self>
    + AddAssign
    + MulAssign
    + 'static
{
    const DTYPE: Dtype;
    fn from_f64(x: f64) -> Self;
    fn to_f64(self) -> f64;
    fn sqrt(self) -> Self;
    fn to_bytes(v: &[Self]) -> Vec<u8>;
    fn read(raw: &RawTensors<'_>, name: &str) -> Result<Vec<Self>, NetworkError>;
}

impl Scalar for f32 {
    const DTYPE: Dtype = Dtype::F32;
    fn from_f64(x: f64) -> Self {
        x as f32
    }
    fn to_f64(self) -> f64 {
        self as f64
    }
    fn sqrt(self) -> Self {
        f32::sqrt(self)
    }
    fn to_bytes(v: &[Self]) -> Vec<u8> {
        f32_bytes(v)
    }
    fn read(raw: &RawTensors<'_>, name: &str) -> Result<Vec<Self>, NetworkError> {
        raw.f32s(name)
    }
}

impl Scalar for f64 {
    const DTYPE: Dtype = Dtype::F64;
    fn from_f64(x: f64) -> Self {
        x
    }
    fn to_f64(self) -> f64 {
        self
    }
    fn sqrt(self) -> Self {
        f64::sqrt(self)
    }
    fn to_bytes(v: &[Self]) -> Vec<u8> {
        f64_bytes(v)
    }
    fn read(raw: &RawTensors<'_>, name: &str) -> Result<Vec<Self>, NetworkError> {
        raw.f64s(name)
    }
}

/// One layer's parameters (or their gradients / Adam moments) in the working precision.
#[derive(Clone, Debug, PartialEq)]
pub(crate) struct Params<T> {
    /// `W`, `[n_out, n_in]` row-major.
    pub w: Vec<T>,
    /// `b`, `[n_out]`.
    pub b: Vec<T>,
    pub n_in: usize,
    pub n_out: usize,
}

impl<T: Scalar> Params<T> {
    pub fn zeros_like(&self) -> Self {
        Params {
            w: vec![T::ZERO; self.w.len()],
            b: vec![T::ZERO; self.b.len()],
            n_in: self.n_in,
            n_out: self.n_out,
        }
    }
}

/// The network in working precision.
pub(crate) fn to_params<T: Scalar>(mlp: &Mlp) -> Vec<Params<T>> {
    mlp.layers
        .iter()
        .map(|l| Params {
            w: l.weight.iter().map(|&x| T::from_f64(x)).collect(),
            b: l.bias.iter().map(|&x| T::from_f64(x)).collect(),
            n_in: l.n_in,
            n_out: l.n_out,
        })
        .collect()
}

/// Back to an f64 [`Mlp`] (exact: f32 → f64 widening is exact).
pub(crate) fn to_mlp<T: Scalar>(params: &[Params<T>]) -> Mlp {
    Mlp {
        layers: params
            .iter()
            .map(|p| Layer {
                weight: p.w.iter().map(|x| x.to_f64()).collect(),
                bias: p.b.iter().map(|x| x.to_f64()).collect(),
                n_in: p.n_in,
                n_out: p.n_out,
            })
            .collect(),
    }
}

/// Buffers for one batch: `acts[k]` is the input of layer `k` (`acts[0]` the network input,
/// filled by the caller), `out` the network output, `g`/`tmp` backward scratch.
///
/// The rows come in `r` groups of `b`, one row per sample in each: group 0 the samples
/// themselves, then either the input tangents `e_j` ([`Workspace::load_inputs`], masked by
/// group 0's ReLU pattern: forward-mode `DN`) or the stencil points `x ± h_j e_j`
/// ([`Workspace::load_stencil`], primal rows with their own patterns: central differences).
pub(crate) struct Workspace<T> {
    pub acts: Vec<Vec<T>>,
    pub out: Vec<T>,
    pub g: Vec<T>,
    tmp: Vec<T>,
    /// Samples in this batch.
    pub b: usize,
    /// Row groups: 1 primal + tangent directions, or 1 + 2 per direction for a stencil.
    pub r: usize,
    /// The stencil's steps `h_j` when the groups after the first are stencil points.
    stencil: Option<Vec<f64>>,
}

impl<T: Scalar> Workspace<T> {
    pub fn new(n_layers: usize) -> Self {
        Workspace {
            acts: vec![Vec::new(); n_layers],
            out: Vec::new(),
            g: Vec::new(),
            tmp: Vec::new(),
            b: 0,
            r: 1,
            stencil: None,
        }
    }

    /// Sets the batch layout and fills `acts[0]`: primal rows from `x(i)` (the i-th sample's
    /// input), tangent group `j` rows with the unit vector `e_j`.
    pub fn load_inputs<'a>(
        &mut self,
        n_in: usize,
        b: usize,
        tangents: bool,
        x: impl Fn(usize) -> &'a [f64],
    ) {
        self.b = b;
        self.r = if tangents { 1 + n_in } else { 1 };
        self.stencil = None;
        let a0 = &mut self.acts[0];
        a0.clear();
        a0.resize(self.r * b * n_in, T::ZERO);
        for i in 0..b {
            for (dst, &src) in a0[i * n_in..(i + 1) * n_in].iter_mut().zip(x(i)) {
                *dst = T::from_f64(src);
            }
        }
        for j in 0..self.r - 1 {
            for i in 0..b {
                a0[((j + 1) * b + i) * n_in + j] = T::ONE;
            }
        }
    }

    /// Sets the batch layout and fills `acts[0]` with a central-difference stencil: group 0
    /// the samples `x(i)`, groups `1 + 2j` and `2 + 2j` the points `x(i) ± h_j e_j`
    /// (`h`: one step, or one per input). Every row is primal, so the network's secants
    /// `(N(x + h_j e_j) − N(x − h_j e_j))/2h_j` ([`Workspace::slope`]) depend on where its
    /// ReLUs switch, which its pointwise Jacobian does not: a slope loss on them moves the
    /// kinks too.
    pub fn load_stencil<'a>(
        &mut self,
        n_in: usize,
        b: usize,
        h: &[f64],
        x: impl Fn(usize) -> &'a [f64],
    ) {
        let step: Vec<f64> = (0..n_in).map(|j| h[j.min(h.len() - 1)]).collect();
        self.b = b;
        self.r = 1 + 2 * n_in;
        let a0 = &mut self.acts[0];
        a0.clear();
        a0.resize(self.r * b * n_in, T::ZERO);
        for g in 0..self.r {
            for i in 0..b {
                let (xi, row) = (x(i), &mut a0[(g * b + i) * n_in..(g * b + i + 1) * n_in]);
                for (dst, &src) in row.iter_mut().zip(xi) {
                    *dst = T::from_f64(src);
                }
                if g > 0 {
                    // Group 1 + 2j holds x + h_j e_j, group 2 + 2j holds x − h_j e_j.
                    let (j, sign) = ((g - 1) / 2, if g % 2 == 1 { 1.0 } else { -1.0 });
                    row[j] = T::from_f64(xi[j] + sign * step[j]);
                }
            }
        }
        self.stencil = Some(step);
    }

    /// Rows whose ReLU patterns are their own: the first group, or all with a stencil.
    fn primal_rows(&self) -> usize {
        if self.stencil.is_some() {
            self.r * self.b
        } else {
            self.b
        }
    }

    /// Whether the groups after the first hold slopes (tangents or a stencil).
    pub fn has_slopes(&self) -> bool {
        self.r > 1
    }

    /// Sample `i`'s slope `∂N_o/∂x_j` (of `m` outputs) after [`Workspace::forward`]: the
    /// tangent, or the stencil's central difference.
    pub fn slope(&self, i: usize, j: usize, o: usize, m: usize) -> f64 {
        let b = self.b;
        match &self.stencil {
            None => self.out[((j + 1) * b + i) * m + o].to_f64(),
            Some(h) => {
                let plus = self.out[((1 + 2 * j) * b + i) * m + o].to_f64();
                let minus = self.out[((2 + 2 * j) * b + i) * m + o].to_f64();
                (plus - minus) / (2.0 * h[j])
            }
        }
    }

    /// Sets `∂L/∂` of sample `i`'s slope `∂N_o/∂x_j` to `d` in `g` (zeroed by the caller):
    /// on the tangent row, or `±d/2h_j` on the stencil's two rows.
    pub fn set_slope_gradient(&mut self, i: usize, j: usize, o: usize, m: usize, d: f64) {
        let b = self.b;
        match &self.stencil {
            None => self.g[((j + 1) * b + i) * m + o] = T::from_f64(d),
            Some(h) => {
                let d = d / (2.0 * h[j]);
                self.g[((1 + 2 * j) * b + i) * m + o] = T::from_f64(d);
                self.g[((2 + 2 * j) * b + i) * m + o] = T::from_f64(-d);
            }
        }
    }

    /// Forward pass; afterwards `out` holds `r·B × n_L` rows (primal, then tangents or the
    /// stencil).
    pub fn forward(&mut self, net: &[Params<T>]) {
        let rows = self.r * self.b;
        let primal_rows = self.primal_rows();
        let nl = net.len();
        for (k, p) in net.iter().enumerate() {
            let (inp, rest) = self.acts.split_at_mut(k + 1);
            let input = &inp[k];
            let output: &mut Vec<T> = if k + 1 < nl {
                &mut rest[0]
            } else {
                &mut self.out
            };
            output.clear();
            output.resize(rows * p.n_out, T::ZERO);
            matmul_strided(
                (rows, p.n_in, p.n_out),
                input,
                (p.n_in, 1),
                &p.w,
                (1, p.n_in),
                output,
                (p.n_out, 1),
                Threads::Pool,
            );
            let (primal, tangents) = output.split_at_mut(primal_rows * p.n_out);
            for row in primal.chunks_exact_mut(p.n_out) {
                for (z, &bias) in row.iter_mut().zip(&p.b) {
                    *z += bias;
                }
            }
            if k + 1 < nl {
                for z in primal.iter_mut() {
                    if !is_active(*z) {
                        *z = T::ZERO;
                    }
                }
                mask_tangents(primal, tangents);
            }
        }
    }

    /// Backward pass from `g` (`∂L/∂out`, `r·B × n_L`, filled by the caller) into `grads`
    /// (overwritten).
    pub fn backward(&mut self, net: &[Params<T>], grads: &mut [Params<T>]) {
        let rows = self.r * self.b;
        let primal_rows = self.primal_rows();
        for k in (0..net.len()).rev() {
            let p = &net[k];
            let gr = &mut grads[k];
            let input = &self.acts[k];
            // ∂L/∂W = Gᵀ A: (n_out × rows)(rows × n_in)
            matmul_strided(
                (p.n_out, rows, p.n_in),
                &self.g,
                (1, p.n_out),
                input,
                (p.n_in, 1),
                &mut gr.w,
                (p.n_in, 1),
                Threads::Pool,
            );
            gr.b.iter_mut().for_each(|v| *v = T::ZERO);
            for row in self.g[..primal_rows * p.n_out].chunks_exact(p.n_out) {
                for (d, &v) in gr.b.iter_mut().zip(row) {
                    *d += v;
                }
            }
            if k > 0 {
                self.tmp.clear();
                self.tmp.resize(rows * p.n_in, T::ZERO);
                matmul_strided(
                    (rows, p.n_out, p.n_in),
                    &self.g,
                    (p.n_out, 1),
                    &p.w,
                    (p.n_in, 1),
                    &mut self.tmp,
                    (p.n_in, 1),
                    Threads::Pool,
                );
                // D_{k}: the primal ReLU pattern of this layer's input, for every row group
                // (a stencil's rows are all primal: each its own).
                let mask_src = &input[..primal_rows * p.n_in];
                for group in self.tmp.chunks_exact_mut(primal_rows * p.n_in) {
                    for (gv, &a) in group.iter_mut().zip(mask_src) {
                        if !is_active(a) {
                            *gv = T::ZERO;
                        }
                    }
                }
                std::mem::swap(&mut self.g, &mut self.tmp);
            }
        }
    }
}

/// Buffers of the interval-bound-propagation (IBP) width penalty of certified training
/// (Gowal et al. 2018): a batch of boxes `[c − ε, c + ε]` propagated in centre–radius form,
///
/// ```text
/// ẑ_c = W c + b,  ẑ_r = |W| r,   l = ẑ_c − ẑ_r,  u = ẑ_c + ẑ_r,
/// c' = (relu(u) + relu(l))/2,   r' = (relu(u) − relu(l))/2        (hidden layers),
/// ```
///
/// each layer two GEMMs over the `B` boxes (one with `W`, one with `|W|`). The backward pass
/// goes through both: `∂L/∂W = G_cᵀ C + sign(W) ⊙ (G_rᵀ R)`, `∂L/∂b = Σ G_c`, and through the
/// ReLU interval map with the same `ReLU'(0) = 0` convention as the primal pass.
pub(crate) struct IbpWorkspace<T> {
    /// Centre and radius of each layer's input, `B × n_in` (index 0: the boxes).
    c: Vec<Vec<T>>,
    r: Vec<Vec<T>>,
    /// Pre-activation bounds `l`, `u` of each hidden layer, `B × n_out`.
    lo: Vec<Vec<T>>,
    hi: Vec<Vec<T>>,
    /// `|W_k|`.
    abs_w: Vec<Vec<T>>,
    /// Output centre and radius, `B × m`.
    pub out_c: Vec<T>,
    pub out_r: Vec<T>,
    /// Scratch of the backward pass.
    gc: Vec<T>,
    gr: Vec<T>,
    tc: Vec<T>,
    tr: Vec<T>,
    /// Boxes in the batch.
    pub b: usize,
}

impl<T: Scalar> IbpWorkspace<T> {
    pub fn new(n_layers: usize) -> Self {
        IbpWorkspace {
            c: vec![Vec::new(); n_layers],
            r: vec![Vec::new(); n_layers],
            lo: vec![Vec::new(); n_layers],
            hi: vec![Vec::new(); n_layers],
            abs_w: vec![Vec::new(); n_layers],
            out_c: Vec::new(),
            out_r: Vec::new(),
            gc: Vec::new(),
            gr: Vec::new(),
            tc: Vec::new(),
            tr: Vec::new(),
            b: 0,
        }
    }

    /// Propagates the `b` boxes of centre `centre(i)` and radius `radius` (one entry per input)
    /// through `net`; afterwards `out_c`, `out_r` hold the output intervals' centres and radii.
    pub fn forward<'a>(
        &mut self,
        net: &[Params<T>],
        b: usize,
        centre: impl Fn(usize) -> &'a [f64],
        radius: &[f64],
    ) {
        let nl = net.len();
        let n_in = net[0].n_in;
        self.b = b;
        let c0 = &mut self.c[0];
        c0.clear();
        let r0 = &mut self.r[0];
        r0.clear();
        for i in 0..b {
            c0.extend(centre(i)[..n_in].iter().map(|&x| T::from_f64(x)));
            r0.extend(radius[..n_in].iter().map(|&x| T::from_f64(x)));
        }
        for (k, p) in net.iter().enumerate() {
            let aw = &mut self.abs_w[k];
            aw.clear();
            aw.extend(
                p.w.iter()
                    .map(|&w| if w < T::ZERO { T::ZERO - w } else { w }),
            );
            let mut zc = vec![T::ZERO; b * p.n_out];
            let mut zr = vec![T::ZERO; b * p.n_out];
            let (m, kk, n) = (b, p.n_in, p.n_out);
            matmul_strided(
                (m, kk, n),
                &self.c[k],
                (kk, 1),
                &p.w,
                (1, kk),
                &mut zc,
                (n, 1),
                Threads::Pool,
            );
            matmul_strided(
                (m, kk, n),
                &self.r[k],
                (kk, 1),
                aw,
                (1, kk),
                &mut zr,
                (n, 1),
                Threads::Pool,
            );
            for row in zc.chunks_exact_mut(n) {
                for (z, &bias) in row.iter_mut().zip(&p.b) {
                    *z += bias;
                }
            }
            if k + 1 < nl {
                let half = T::from_f64(0.5);
                let (lo, hi) = (&mut self.lo[k], &mut self.hi[k]);
                lo.clear();
                hi.clear();
                let (cn, rn) = (&mut self.c[k + 1], &mut self.r[k + 1]);
                cn.clear();
                rn.clear();
                for (&c, &r) in zc.iter().zip(&zr) {
                    let (l, u) = (c - r, c + r);
                    lo.push(l);
                    hi.push(u);
                    let rl = if is_active(l) { l } else { T::ZERO };
                    let ru = if is_active(u) { u } else { T::ZERO };
                    cn.push(half * (ru + rl));
                    rn.push(half * (ru - rl));
                }
            } else {
                self.out_c = zc;
                self.out_r = zr;
            }
        }
    }

    /// Backward pass from `∂L/∂out_c` and `∂L/∂out_r` (`B × m` each) into `grads`
    /// (overwritten).
    pub fn backward(&mut self, net: &[Params<T>], g_c: &[T], g_r: &[T], grads: &mut [Params<T>]) {
        let b = self.b;
        self.gc.clear();
        self.gc.extend_from_slice(g_c);
        self.gr.clear();
        self.gr.extend_from_slice(g_r);
        for k in (0..net.len()).rev() {
            let p = &net[k];
            let (n_in, n_out) = (p.n_in, p.n_out);
            if k + 1 < net.len() {
                // Through the ReLU interval map: gc, gr are w.r.t. this layer's (c', r').
                let half = T::from_f64(0.5);
                for idx in 0..b * n_out {
                    let (gcv, grv) = (self.gc[idx], self.gr[idx]);
                    let gu = if is_active(self.hi[k][idx]) {
                        half * (gcv + grv)
                    } else {
                        T::ZERO
                    };
                    let gl = if is_active(self.lo[k][idx]) {
                        half * (gcv - grv)
                    } else {
                        T::ZERO
                    };
                    self.gc[idx] = gu + gl;
                    self.gr[idx] = gu - gl;
                }
            }
            let gw = &mut grads[k];
            // ∂L/∂W = G_cᵀ C + sign(W) ⊙ (G_rᵀ R).
            matmul_strided(
                (n_out, b, n_in),
                &self.gc,
                (1, n_out),
                &self.c[k],
                (n_in, 1),
                &mut gw.w,
                (n_in, 1),
                Threads::Pool,
            );
            self.tc.clear();
            self.tc.resize(n_out * n_in, T::ZERO);
            matmul_strided(
                (n_out, b, n_in),
                &self.gr,
                (1, n_out),
                &self.r[k],
                (n_in, 1),
                &mut self.tc,
                (n_in, 1),
                Threads::Pool,
            );
            for ((d, &t), &w) in gw.w.iter_mut().zip(&self.tc).zip(&p.w) {
                if w > T::ZERO {
                    *d += t;
                } else if w < T::ZERO {
                    *d = *d - t;
                }
            }
            gw.b.iter_mut().for_each(|v| *v = T::ZERO);
            for row in self.gc.chunks_exact(n_out) {
                for (d, &v) in gw.b.iter_mut().zip(row) {
                    *d += v;
                }
            }
            if k > 0 {
                self.tc.clear();
                self.tc.resize(b * n_in, T::ZERO);
                self.tr.clear();
                self.tr.resize(b * n_in, T::ZERO);
                let (m, kk, n) = (b, n_out, n_in);
                matmul_strided(
                    (m, kk, n),
                    &self.gc,
                    (kk, 1),
                    &p.w,
                    (n, 1),
                    &mut self.tc,
                    (n, 1),
                    Threads::Pool,
                );
                matmul_strided(
                    (m, kk, n),
                    &self.gr,
                    (kk, 1),
                    &self.abs_w[k],
                    (n, 1),
                    &mut self.tr,
                    (n, 1),
                    Threads::Pool,
                );
                std::mem::swap(&mut self.gc, &mut self.tc);
                std::mem::swap(&mut self.gr, &mut self.tr);
            }
        }
    }
}

/// The ReLU derivative's convention: a neuron is active iff its pre-activation is `> 0`
/// (NaN counts as inactive).
fn is_active<T: Scalar>(z: T) -> bool {
    z > T::ZERO
}

/// Zeroes tangent entries whose primal neuron is inactive (`primal` already ReLU'd).
fn mask_tangents<T: Scalar>(primal: &[T], tangents: &mut [T]) {
    if primal.is_empty() {
        return;
    }
    for group in tangents.chunks_exact_mut(primal.len()) {
        for (t, &a) in group.iter_mut().zip(primal) {
            if !is_active(a) {
                *t = T::ZERO;
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Batched forward with tangents equals `Mlp::forward` and `Mlp::jacobian`.
    #[test]
    fn batched_forward_matches_pointwise() {
        let mlp = Mlp::random(&[3, 9, 7, 2], 5);
        let xs: Vec<Vec<f64>> = (0..13)
            .map(|i| {
                let t = i as f64 * 0.37;
                vec![t.sin(), (2.0 * t).cos(), t - 2.0]
            })
            .collect();
        let net = to_params::<f64>(&mlp);
        let mut ws = Workspace::<f64>::new(net.len());
        ws.load_inputs(3, xs.len(), true, |i| &xs[i]);
        ws.forward(&net);
        let b = xs.len();
        for (i, x) in xs.iter().enumerate() {
            let y = mlp.forward(x);
            let j = mlp.jacobian(x);
            for o in 0..2 {
                assert!((ws.out[i * 2 + o] - y[o]).abs() < 1e-12);
                for d in 0..3 {
                    let t = ws.out[((d + 1) * b + i) * 2 + o];
                    assert!((t - j[o * 3 + d]).abs() < 1e-12);
                }
            }
        }
    }

    /// A stencil's slopes are the central differences of `Mlp::forward`, its first group the
    /// values, and they differ from the pointwise Jacobian where a ReLU switches in between.
    #[test]
    fn stencil_slopes_are_central_differences() {
        let mlp = Mlp::random(&[2, 12, 9, 3], 4);
        let xs: Vec<Vec<f64>> = (0..17)
            .map(|i| vec![0.21 * i as f64 - 1.7, 0.9 - 0.13 * i as f64])
            .collect();
        let h = [0.3, 0.05];
        let net = to_params::<f64>(&mlp);
        let mut ws = Workspace::<f64>::new(net.len());
        ws.load_stencil(2, xs.len(), &h, |i| &xs[i]);
        ws.forward(&net);
        let mut differs = 0;
        for (i, x) in xs.iter().enumerate() {
            let y = mlp.forward(x);
            let jac = mlp.jacobian(x);
            for o in 0..3 {
                assert!((ws.out[i * 3 + o] - y[o]).abs() < 1e-12);
                for (j, &hj) in h.iter().enumerate() {
                    let (mut plus, mut minus) = (x.clone(), x.clone());
                    plus[j] += hj;
                    minus[j] -= hj;
                    let fd = (mlp.forward(&plus)[o] - mlp.forward(&minus)[o]) / (2.0 * hj);
                    let slope = ws.slope(i, j, o, 3);
                    assert!((slope - fd).abs() < 1e-10, "sample {i}: {slope} vs {fd}");
                    if (slope - jac[o * 2 + j]).abs() > 1e-6 {
                        differs += 1;
                    }
                }
            }
        }
        // Otherwise the test could not tell a stencil from tangents.
        assert!(differs > 0);
    }

    /// Backward gradients against central finite differences of
    /// `L = Σ_rows Σ_o c_{row,o} out_{row,o}` (primal and tangent rows, or a stencil's rows:
    /// there every row's own ReLU pattern masks it, so the biases get the slopes' gradient).
    #[test]
    fn backward_matches_finite_differences() {
        backward_matches_finite_differences_with(None);
        backward_matches_finite_differences_with(Some(&[0.07, 0.11]));
    }

    fn backward_matches_finite_differences_with(stencil: Option<&[f64]>) {
        let mlp = Mlp::random(&[2, 6, 5, 2], 9);
        let xs: Vec<Vec<f64>> = (0..4)
            .map(|i| vec![0.3 * i as f64 - 0.5, 0.2 - 0.1 * i as f64])
            .collect();
        let load = |ws: &mut Workspace<f64>| match stencil {
            Some(h) => ws.load_stencil(2, xs.len(), h, |i| &xs[i]),
            None => ws.load_inputs(2, xs.len(), true, |i| &xs[i]),
        };
        let loss = |net: &[Params<f64>]| {
            let mut ws = Workspace::<f64>::new(net.len());
            load(&mut ws);
            ws.forward(net);
            ws.out
                .iter()
                .enumerate()
                .map(|(k, v)| v * (1.0 + (k as f64 * 0.7).sin()))
                .sum::<f64>()
        };
        let net = to_params::<f64>(&mlp);
        let mut ws = Workspace::<f64>::new(net.len());
        load(&mut ws);
        ws.forward(&net);
        ws.g = (0..ws.out.len())
            .map(|k| 1.0 + (k as f64 * 0.7).sin())
            .collect();
        let mut grads: Vec<Params<f64>> = net.iter().map(|p| p.zeros_like()).collect();
        ws.backward(&net, &mut grads);
        let h = 1e-6;
        for k in 0..net.len() {
            for idx in 0..net[k].w.len() {
                let mut plus = net.clone();
                plus[k].w[idx] += h;
                let mut minus = net.clone();
                minus[k].w[idx] -= h;
                let fd = (loss(&plus) - loss(&minus)) / (2.0 * h);
                assert!(
                    (fd - grads[k].w[idx]).abs() < 1e-6 * (1.0 + fd.abs()),
                    "layer {k} w[{idx}]: fd {fd} vs {}",
                    grads[k].w[idx]
                );
            }
            for idx in 0..net[k].b.len() {
                let mut plus = net.clone();
                plus[k].b[idx] += h;
                let mut minus = net.clone();
                minus[k].b[idx] -= h;
                let fd = (loss(&plus) - loss(&minus)) / (2.0 * h);
                assert!((fd - grads[k].b[idx]).abs() < 1e-6 * (1.0 + fd.abs()));
            }
        }
    }
}
