//! What training reports ([`EpochStats`], [`TrainReport`]) and the f64 measurement of a
//! network's errors on a data set ([`evaluate`], [`pointwise_errors`]). May import: the
//! trainer's data, settings and loss terms, the batched passes, [`Mlp`], [`NetworkError`].

use std::collections::BTreeMap;

use serde::{Deserialize, Serialize};

use super::dataset::{check_dims, Dataset};
use super::loss::sample_errors;
use super::settings::TrainSettings;
use crate::network::batch::{to_params, Workspace};
use crate::network::{Mlp, NetworkError};

/// What one epoch did, passed to the progress callback and kept in the report.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct EpochStats {
    /// Epochs completed (1-based).
    pub epoch: usize,
    /// Total epochs of the run.
    pub epochs: usize,
    /// Mean weighted loss over the epoch's samples.
    pub loss: f64,
    /// Max over samples of `‖N(x_s) − v_s‖∞`, each measured when the sample was visited
    /// (weights move during the epoch; [`TrainReport::final_errors`] is exact).
    pub max_error: f64,
    /// Mean over samples of `‖N(x_s) − v_s‖∞`, measured likewise.
    pub mean_error: f64,
    /// Max over samples of `max |DN − Dv|` (entrywise), when the Jacobian term is on.
    pub max_slope_error: Option<f64>,
    /// Learning rate used.
    pub lr: f64,
    /// Sample visits (data plus hard-example repeats).
    pub samples: usize,
    /// Wall-clock seconds of the epoch.
    pub seconds: f64,
    /// Mean IBP output width `2 r_o` over the epoch's boxes, when the IBP term is on.
    #[serde(default)]
    pub ibp_width: Option<f64>,
    /// Dormant hidden neurons revived after this epoch ([`TrainSettings::revive_every`]).
    #[serde(default)]
    pub revived: usize,
}

/// Errors of a network on a data set, in f64, over the samples of positive weight.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ErrorStats {
    /// Samples measured.
    pub samples: usize,
    /// `max_s ‖N(x_s) − v_s‖∞`.
    pub max_error: f64,
    /// Sample index where `max_error` is attained.
    pub argmax: usize,
    /// `mean_s ‖N(x_s) − v_s‖∞`.
    pub mean_error: f64,
    /// `max_s ‖N(x_s) − v_s‖₂`.
    pub max_error_l2: f64,
    /// `max_s max_ij |DN − Dv|_ij`, when the data have Jacobians.
    pub max_slope_error: Option<f64>,
    /// `mean_s max_ij |DN − Dv|_ij`, when the data have Jacobians.
    pub mean_slope_error: Option<f64>,
}

/// Per-sample errors of a network on a data set (see [`pointwise_errors`]).
#[derive(Clone, Debug, PartialEq)]
pub struct PointErrors {
    /// `‖N(x_s) − v_s‖∞` for every sample.
    pub value: Vec<f64>,
    /// `‖N(x_s) − v_s‖₂` for every sample.
    pub value_l2: Vec<f64>,
    /// `max_ij |DN(x_s) − Dv_s|_ij` for every sample, when the data have Jacobians.
    pub slope: Option<Vec<f64>>,
}

/// The outcome of [`train`](super::train).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct TrainReport {
    /// One entry per epoch, including those run before a resume.
    pub epochs: Vec<EpochStats>,
    /// Errors of the returned (f64) network on the whole data set.
    pub final_errors: ErrorStats,
    /// Wall-clock seconds of this call (training and final evaluation).
    pub seconds: f64,
    /// Epoch the run resumed from, if it did.
    pub resumed_from: Option<usize>,
}

impl TrainReport {
    /// The report as string metadata for [`Mlp::save_safetensors`]: `max_error`,
    /// `mean_error`, `max_slope_error`, `epochs`, `final_loss`, and the full report as JSON
    /// under `train_report`.
    pub fn metadata(&self) -> BTreeMap<String, String> {
        let mut m = BTreeMap::new();
        m.insert("max_error".into(), self.final_errors.max_error.to_string());
        m.insert(
            "mean_error".into(),
            self.final_errors.mean_error.to_string(),
        );
        if let Some(s) = self.final_errors.max_slope_error {
            m.insert("max_slope_error".into(), s.to_string());
        }
        m.insert("epochs".into(), self.epochs.len().to_string());
        if let Some(last) = self.epochs.last() {
            m.insert("final_loss".into(), last.loss.to_string());
        }
        if let Ok(json) = serde_json::to_string(self) {
            m.insert("train_report".into(), json);
        }
        m
    }
}

/// Errors of `mlp` on `data` in f64, over the samples of positive weight.
pub fn evaluate(mlp: &Mlp, data: &Dataset) -> Result<ErrorStats, NetworkError> {
    let pe = pointwise_errors(mlp, data)?;
    let mut st = ErrorStats {
        samples: 0,
        max_error: 0.0,
        argmax: 0,
        mean_error: 0.0,
        max_error_l2: 0.0,
        max_slope_error: pe.slope.as_ref().map(|_| 0.0),
        mean_slope_error: pe.slope.as_ref().map(|_| 0.0),
    };
    let (mut sum, mut sum_slope) = (0.0, 0.0);
    for s in 0..data.len() {
        if data.weight(s) <= 0.0 {
            continue;
        }
        st.samples += 1;
        sum += pe.value[s];
        if pe.value[s] > st.max_error {
            st.max_error = pe.value[s];
            st.argmax = s;
        }
        st.max_error_l2 = st.max_error_l2.max(pe.value_l2[s]);
        if let Some(sl) = &pe.slope {
            sum_slope += sl[s];
            st.max_slope_error = st.max_slope_error.map(|m| m.max(sl[s]));
        }
    }
    let n = st.samples.max(1) as f64;
    st.mean_error = sum / n;
    st.mean_slope_error = st.mean_slope_error.map(|_| sum_slope / n);
    Ok(st)
}

/// Per-sample value (and, with Jacobians in the data, slope) errors of `mlp` on every sample
/// of `data`, in f64 — e.g. for a local error bound per cell instead of one global `M_C`.
pub fn pointwise_errors(mlp: &Mlp, data: &Dataset) -> Result<PointErrors, NetworkError> {
    mlp.validate("<network>")?;
    data.validate()?;
    check_dims(mlp, data)?;
    let params = to_params::<f64>(mlp);
    let n = data.len();
    let tangents = data.jacobians.is_some();
    let mut ws = Workspace::<f64>::new(params.len());
    let mut out = PointErrors {
        value: vec![0.0; n],
        value_l2: vec![0.0; n],
        slope: tangents.then(|| vec![0.0; n]),
    };
    const CHUNK: usize = 1024;
    let idx: Vec<usize> = (0..n).collect();
    for chunk in idx.chunks(CHUNK) {
        ws.load_inputs(data.n_in, chunk.len(), tangents, |i| data.input(chunk[i]));
        ws.forward(&params);
        for (i, &s) in chunk.iter().enumerate() {
            let e = sample_errors(&ws, data, i, s, &TrainSettings::default());
            out.value[s] = e.value;
            out.value_l2[s] = e.value_sq.sqrt();
            if let Some(sl) = &mut out.slope {
                sl[s] = e.slope;
            }
        }
    }
    Ok(out)
}
