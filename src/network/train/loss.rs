//! The loss terms per sample and per chunk of a batch: values, Sobolev (pointwise or secant,
//! capped, Huber), IBP. May import: the trainer's data and settings, the batched passes.

use super::dataset::Dataset;
use super::settings::TrainSettings;
use crate::network::batch::{IbpWorkspace, Params, Scalar, Workspace};

/// Errors of sample `s`, sitting at batch row `i` of a forward pass.
pub(super) struct SampleErrors {
    /// `‖e‖∞`.
    pub(super) value: f64,
    /// `‖e‖₂²`.
    pub(super) value_sq: f64,
    /// `max |E|`.
    pub(super) slope: f64,
    /// `‖E‖_F²`, or the sum of the Huber costs of `E`'s entries.
    pub(super) slope_sq: f64,
}

/// Sample `s`'s Jacobian target `Dv` (`m × n`, row-major), unless the data has none or one of
/// its entries is not finite or exceeds `cap` ([`TrainSettings::jacobian_cap`]).
pub(super) fn slope_target(data: &Dataset, s: usize, cap: Option<f64>) -> Option<&[f64]> {
    let k = data.n_out * data.n_in;
    let dv = &data.jacobians.as_ref()?[s * k..(s + 1) * k];
    let cap = cap.unwrap_or(f64::INFINITY);
    dv.iter().all(|d| d.abs() <= cap).then_some(dv)
}

/// The Sobolev term's cost of a slope residual `d`: `d²`, or Huber's `2δ|d| − δ²` beyond `δ`
/// ([`TrainSettings::jacobian_huber`]).
fn slope_cost(d: f64, huber: Option<f64>) -> f64 {
    match huber {
        Some(delta) if d.abs() > delta => 2.0 * delta * d.abs() - delta * delta,
        _ => d * d,
    }
}

/// Half the derivative of [`slope_cost`]: `d`, clamped to `[−δ, δ]` under Huber.
fn slope_cost_half_derivative(d: f64, huber: Option<f64>) -> f64 {
    match huber {
        Some(delta) => d.clamp(-delta, delta),
        None => d,
    }
}

pub(super) fn sample_errors<T: Scalar>(
    ws: &Workspace<T>,
    data: &Dataset,
    i: usize,
    s: usize,
    settings: &TrainSettings,
) -> SampleErrors {
    let (n, m) = (data.n_in, data.n_out);
    let mut e = SampleErrors {
        value: 0.0,
        value_sq: 0.0,
        slope: 0.0,
        slope_sq: 0.0,
    };
    for (o, &t) in data.target(s).iter().enumerate() {
        let d = ws.out[i * m + o].to_f64() - t;
        e.value = e.value.max(d.abs());
        e.value_sq += d * d;
    }
    if ws.has_slopes() {
        if let Some(dv) = slope_target(data, s, settings.jacobian_cap) {
            for j in 0..n {
                for o in 0..m {
                    let d = ws.slope(i, j, o, m) - dv[o * n + j];
                    e.slope = e.slope.max(d.abs());
                    e.slope_sq += slope_cost(d, settings.jacobian_huber);
                }
            }
        }
    }
    e
}

/// What one visit of a sample found: its loss (the hard-example score) and errors.
pub(super) struct Visit {
    pub(super) sample: usize,
    pub(super) loss: f64,
    pub(super) value: f64,
    pub(super) slope: f64,
}

/// Buffers for one chunk of a batch ([`TrainSettings::chunk_size`]): its share of the batch's
/// gradient, the visits of its samples and the sum of its IBP widths.
pub(super) struct ChunkWorker<T> {
    ws: Workspace<T>,
    ibp: IbpWorkspace<T>,
    pub(super) grads: Vec<Params<T>>,
    ibp_grads: Vec<Params<T>>,
    pub(super) visits: Vec<Visit>,
    pub(super) width_sum: f64,
}

impl<T: Scalar> ChunkWorker<T> {
    pub(super) fn new(params: &[Params<T>]) -> Self {
        ChunkWorker {
            ws: Workspace::new(params.len()),
            ibp: IbpWorkspace::new(params.len()),
            grads: params.iter().map(|p| p.zeros_like()).collect(),
            ibp_grads: params.iter().map(|p| p.zeros_like()).collect(),
            visits: Vec::new(),
            width_sum: 0.0,
        }
    }

    /// The gradient of the samples `chunk` of a batch of `batch_len` samples into `grads`
    /// (overwritten): their terms of the batch loss (a mean over the whole batch), the IBP term
    /// too where `ibp_radius` is given.
    pub(super) fn gradient(
        &mut self,
        params: &[Params<T>],
        data: &Dataset,
        chunk: &[usize],
        batch_len: usize,
        settings: &TrainSettings,
        ibp_radius: Option<&[f64]>,
    ) {
        let (n_in, n_out) = (data.n_in, data.n_out);
        let lambda = settings.jacobian_weight;
        let ws = &mut self.ws;
        let b = chunk.len();
        let excess = settings.ibp_excess.then_some(ibp_radius).flatten();
        let slopes = lambda > 0.0 || excess.is_some();
        match (&settings.secant_step, slopes) {
            (Some(h), true) => ws.load_stencil(n_in, b, h, |i| data.input(chunk[i])),
            _ => ws.load_inputs(n_in, b, slopes, |i| data.input(chunk[i])),
        }
        ws.forward(params);
        // ∂L/∂out, L = (1/batch_len) Σ w_s (‖e‖² + λ‖E‖²).
        ws.g.clear();
        ws.g.resize(ws.out.len(), T::ZERO);
        self.visits.clear();
        for (i, &s) in chunk.iter().enumerate() {
            let w = data.weight(s);
            let c = 2.0 * w / batch_len as f64;
            for (o, &t) in data.target(s).iter().enumerate() {
                let d = ws.out[i * n_out + o].to_f64() - t;
                ws.g[i * n_out + o] = T::from_f64(c * d);
            }
            if ws.has_slopes() {
                let dv = slope_target(data, s, settings.jacobian_cap).filter(|_| lambda > 0.0);
                for j in 0..n_in {
                    for o in 0..n_out {
                        let slope = ws.slope(i, j, o, n_out);
                        let mut g = 0.0;
                        if let Some(dv) = dv {
                            let d = slope - dv[o * n_in + j];
                            g +=
                                c * lambda * slope_cost_half_derivative(d, settings.jacobian_huber);
                        }
                        if let Some(radius) = excess {
                            // −λ_ibp |∂N_o/∂x_j| 2ε_j / (batch widths), the linear range's part.
                            let count = (batch_len * n_out) as f64;
                            if slope != 0.0 {
                                g -= settings.ibp_weight * 2.0 * radius[j] * slope.signum() / count;
                            }
                        }
                        ws.set_slope_gradient(i, j, o, n_out, g);
                    }
                }
            }
            let se = sample_errors(ws, data, i, s, settings);
            self.visits.push(Visit {
                sample: s,
                loss: w * (se.value_sq + lambda * se.slope_sq),
                value: se.value,
                slope: se.slope,
            });
        }
        ws.backward(params, &mut self.grads);
        self.width_sum = 0.0;
        if let Some(radius) = ibp_radius {
            let (lambda_ibp, count) = (settings.ibp_weight, batch_len * n_out);
            let centre = |i: usize| data.input(chunk[i]);
            let (ibp, grads) = (&mut self.ibp, &mut self.ibp_grads);
            self.width_sum = ibp_term(ibp, params, grads, lambda_ibp, count, b, centre, radius);
            for (g, gi) in self.grads.iter_mut().zip(&self.ibp_grads) {
                for (d, &v) in g.w.iter_mut().zip(&gi.w).chain(g.b.iter_mut().zip(&gi.b)) {
                    *d += v;
                }
            }
        }
    }
}

/// The IBP term `λ · (1/count) Σ_{i,o} 2 r_o(c_i, ε)` over the boxes of centres `centre(i)`,
/// `i < b` (`count`: the widths of the whole batch, of which these are a part): its gradient
/// goes to `grads` (overwritten); returns the sum of the widths `2 r_o`.
#[allow(clippy::too_many_arguments)]
pub(super) fn ibp_term<'a, T: Scalar>(
    ws: &mut IbpWorkspace<T>,
    params: &[Params<T>],
    grads: &mut [Params<T>],
    lambda: f64,
    count: usize,
    b: usize,
    centre: impl Fn(usize) -> &'a [f64],
    radius: &[f64],
) -> f64 {
    ws.forward(params, b, centre, radius);
    let n = ws.out_r.len();
    let g_c = vec![T::ZERO; n];
    let g_r = vec![T::from_f64(2.0 * lambda / count.max(1) as f64); n];
    ws.backward(params, &g_c, &g_r, grads);
    ws.out_r.iter().map(|r| 2.0 * r.to_f64()).sum()
}
