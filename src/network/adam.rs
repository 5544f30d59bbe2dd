//! Adam's moments and step count over the trainer's layer parameters.
//! May import: the batched passes' `Params` and `Scalar` only.
//!
//! Adam (Kingma & Ba 2015) over a list of layer parameters.
//!
//! `m ← β₁ m + (1−β₁) g`, `v ← β₂ v + (1−β₂) g²`,
//! `θ ← θ − lr · m̂ / (√v̂ + ε)` with `m̂ = m/(1−β₁ᵗ)`, `v̂ = v/(1−β₂ᵗ)`.

use super::batch::{Params, Scalar};

/// Adam's moments and step count.
#[derive(Clone, Debug, PartialEq)]
pub(crate) struct Adam<T> {
    pub m: Vec<Params<T>>,
    pub v: Vec<Params<T>>,
    /// Steps taken.
    pub t: u64,
    pub beta1: f64,
    pub beta2: f64,
    pub eps: f64,
}

impl<T: Scalar> Adam<T> {
    pub fn new(params: &[Params<T>], beta1: f64, beta2: f64, eps: f64) -> Self {
        let zeros: Vec<Params<T>> = params.iter().map(|p| p.zeros_like()).collect();
        Adam {
            m: zeros.clone(),
            v: zeros,
            t: 0,
            beta1,
            beta2,
            eps,
        }
    }

    /// One step with learning rate `lr` and gradients `grads`.
    pub fn step(&mut self, params: &mut [Params<T>], grads: &[Params<T>], lr: f64) {
        self.t += 1;
        let t = self.t.min(i32::MAX as u64) as i32;
        let b1 = T::from_f64(self.beta1);
        let b2 = T::from_f64(self.beta2);
        let c1 = T::from_f64(1.0 - self.beta1);
        let c2 = T::from_f64(1.0 - self.beta2);
        // Bias corrections folded into the step size and ε (the usual efficient form).
        let bc1 = 1.0 - self.beta1.powi(t);
        let bc2 = 1.0 - self.beta2.powi(t);
        let step = T::from_f64(lr * bc2.sqrt() / bc1);
        let eps = T::from_f64(self.eps * bc2.sqrt());
        for (((p, g), m), v) in params
            .iter_mut()
            .zip(grads)
            .zip(&mut self.m)
            .zip(&mut self.v)
        {
            update(
                &mut p.w, &g.w, &mut m.w, &mut v.w, b1, b2, c1, c2, step, eps,
            );
            update(
                &mut p.b, &g.b, &mut m.b, &mut v.b, b1, b2, c1, c2, step, eps,
            );
        }
    }
}

#[allow(clippy::too_many_arguments)]
fn update<T: Scalar>(
    p: &mut [T],
    g: &[T],
    m: &mut [T],
    v: &mut [T],
    b1: T,
    b2: T,
    c1: T,
    c2: T,
    step: T,
    eps: T,
) {
    for (((p, &g), m), v) in p.iter_mut().zip(g).zip(m.iter_mut()).zip(v.iter_mut()) {
        *m = b1 * *m + c1 * g;
        *v = b2 * *v + c2 * g * g;
        *p = *p - step * *m / (v.sqrt() + eps);
    }
}
