//! A run's state and its checkpoint file: weights, Adam moments and step, per-sample scores,
//! epoch and history. May import: the trainer's data, settings and report, Adam, the batched
//! passes' parameters, safetensors I/O.

use std::collections::HashMap;
use std::path::Path;

use super::dataset::{check_dims, Dataset};
use super::report::EpochStats;
use super::settings::{Precision, TrainSettings};
use crate::network::adam::Adam;
use crate::network::batch::{to_mlp, to_params, Params, Scalar};
use crate::network::io::{f64_bytes, serialize, write_atomically, RawTensor, RawTensors};
use crate::network::{Mlp, NetworkError};

impl EpochStats {
    /// Numbers per history row in a checkpoint.
    const ROW: usize = 11;

    fn to_row(&self) -> [f64; Self::ROW] {
        [
            self.epoch as f64,
            self.epochs as f64,
            self.loss,
            self.max_error,
            self.mean_error,
            self.max_slope_error.unwrap_or(f64::NAN),
            self.lr,
            self.samples as f64,
            self.seconds,
            self.ibp_width.unwrap_or(f64::NAN),
            self.revived as f64,
        ]
    }

    fn from_row(r: &[f64]) -> Self {
        EpochStats {
            epoch: r[0] as usize,
            epochs: r[1] as usize,
            loss: r[2],
            max_error: r[3],
            mean_error: r[4],
            max_slope_error: (!r[5].is_nan()).then_some(r[5]),
            lr: r[6],
            samples: r[7] as usize,
            seconds: r[8],
            // Checkpoints from before the IBP term have 9 columns.
            ibp_width: r.get(9).copied().filter(|x| !x.is_nan()),
            revived: r.get(10).map_or(0, |&x| x as usize),
        }
    }
}

/// Everything a run needs to continue: the checkpoint contents.
pub(super) struct State<T> {
    pub(super) params: Vec<Params<T>>,
    pub(super) adam: Adam<T>,
    /// Epochs completed.
    pub(super) epoch: usize,
    /// Per-sample loss from the last visit (hard-example scores).
    pub(super) score: Vec<f64>,
    pub(super) history: Vec<EpochStats>,
}

const CHECKPOINT_FORMAT: &str = "cbfreach-train-checkpoint";

impl<T: Scalar> State<T> {
    pub(super) fn fresh(init: &Mlp, data: &Dataset, s: &TrainSettings) -> Self {
        let params = to_params::<T>(init);
        let adam = Adam::new(&params, s.adam_beta1, s.adam_beta2, s.adam_eps);
        State {
            params,
            adam,
            epoch: 0,
            score: vec![0.0; data.len()],
            history: Vec::new(),
        }
    }

    fn to_bytes(&self, settings: &TrainSettings, path: &Path) -> Result<Vec<u8>, NetworkError> {
        let mut t: Vec<RawTensor> = Vec::new();
        let groups = [
            ("net", &self.params),
            ("adam_m", &self.adam.m),
            ("adam_v", &self.adam.v),
        ];
        for (g, ps) in groups {
            for (k, p) in ps.iter().enumerate() {
                t.push((
                    format!("{g}.{k}.weight"),
                    T::DTYPE,
                    vec![p.n_out, p.n_in],
                    T::to_bytes(&p.w),
                ));
                t.push((
                    format!("{g}.{k}.bias"),
                    T::DTYPE,
                    vec![p.n_out],
                    T::to_bytes(&p.b),
                ));
            }
        }
        t.push((
            "score".into(),
            safetensors::Dtype::F64,
            vec![self.score.len()],
            f64_bytes(&self.score),
        ));
        let mut meta = HashMap::new();
        meta.insert("format".into(), CHECKPOINT_FORMAT.into());
        meta.insert("epoch".into(), self.epoch.to_string());
        meta.insert("adam_t".into(), self.adam.t.to_string());
        meta.insert("architecture".into(), to_mlp(&self.params).architecture());
        meta.insert("samples".into(), self.score.len().to_string());
        let json = |e: serde_json::Error| NetworkError::Format {
            path: path.to_path_buf(),
            message: e.to_string(),
        };
        meta.insert(
            "precision".into(),
            serde_json::to_string(&settings.precision).map_err(json)?,
        );
        meta.insert(
            "settings".into(),
            serde_json::to_string(settings).map_err(json)?,
        );
        // History as an f64 tensor: JSON would not round-trip every float exactly.
        let hist: Vec<f64> = self.history.iter().flat_map(EpochStats::to_row).collect();
        t.push((
            "history".into(),
            safetensors::Dtype::F64,
            vec![self.history.len(), EpochStats::ROW],
            f64_bytes(&hist),
        ));
        serialize(&t, meta, path)
    }

    pub(super) fn load(
        bytes: &[u8],
        path: &Path,
        data: &Dataset,
        settings: &TrainSettings,
    ) -> Result<Self, NetworkError> {
        let raw = RawTensors::parse(bytes, path)?;
        let mismatch = |message: String| NetworkError::Checkpoint {
            path: path.to_path_buf(),
            message,
        };
        let meta = |key: &str| {
            raw.metadata
                .get(key)
                .cloned()
                .ok_or_else(|| mismatch(format!("metadata key `{key}` missing")))
        };
        if meta("format")? != CHECKPOINT_FORMAT {
            return Err(mismatch("not a cbfreach training checkpoint".into()));
        }
        let precision: Precision = serde_json::from_str(&meta("precision")?)
            .map_err(|e| mismatch(format!("bad precision: {e}")))?;
        if precision != settings.precision {
            return Err(mismatch(format!(
                "checkpoint precision {precision:?}, settings ask for {:?}",
                settings.precision
            )));
        }
        let num = |key: &str| {
            meta(key)?
                .parse::<u64>()
                .map_err(|e| mismatch(format!("metadata `{key}`: {e}")))
        };
        let epoch = num("epoch")? as usize;
        let adam_t = num("adam_t")?;
        let cols = match raw.shape("history")?.as_slice() {
            [_, c] if *c > 0 => *c,
            _ => EpochStats::ROW,
        };
        let history: Vec<EpochStats> = raw
            .f64s_unchecked("history")?
            .chunks_exact(cols)
            .map(EpochStats::from_row)
            .collect();
        let score = raw.f64s("score")?;
        if score.len() != data.len() {
            return Err(mismatch(format!(
                "checkpoint was written for {} samples, the data have {}",
                score.len(),
                data.len()
            )));
        }
        let read_group = |g: &str| -> Result<Vec<Params<T>>, NetworkError> {
            let mut out = Vec::new();
            let mut prev: Option<usize> = None;
            for k in 0.. {
                let wn = format!("{g}.{k}.weight");
                let shape = match raw.shape(&wn) {
                    Ok(s) => s,
                    Err(_) => break,
                };
                let bn = format!("{g}.{k}.bias");
                let w = T::read(&raw, &wn)?;
                let b = T::read(&raw, &bn)?;
                if shape.len() != 2
                    || prev.is_some_and(|p| p != shape[1])
                    || b.len() != shape[0]
                    || w.len() != shape[0] * shape[1]
                {
                    return Err(NetworkError::Shape {
                        path: path.to_path_buf(),
                        name: wn,
                        expected: vec![b.len(), prev.unwrap_or(shape.last().copied().unwrap_or(0))],
                        found: shape,
                    });
                }
                prev = Some(shape[0]);
                out.push(Params {
                    w,
                    b,
                    n_in: shape[1],
                    n_out: shape[0],
                });
            }
            Ok(out)
        };
        let params = read_group("net")?;
        if params.is_empty() {
            return Err(NetworkError::Empty);
        }
        let m = read_group("adam_m")?;
        let v = read_group("adam_v")?;
        let dims = |ps: &[Params<T>]| ps.iter().map(|p| (p.n_in, p.n_out)).collect::<Vec<_>>();
        if dims(&m) != dims(&params) || dims(&v) != dims(&params) {
            return Err(mismatch(
                "Adam moments do not match the network's shapes".into(),
            ));
        }
        check_dims(&to_mlp(&params), data)?;
        let adam = Adam {
            m,
            v,
            t: adam_t,
            beta1: settings.adam_beta1,
            beta2: settings.adam_beta2,
            eps: settings.adam_eps,
        };
        Ok(State {
            params,
            adam,
            epoch,
            score,
            history,
        })
    }

    pub(super) fn save(&self, settings: &TrainSettings, path: &Path) -> Result<(), NetworkError> {
        let bytes = self.to_bytes(settings, path)?;
        write_atomically(path, &bytes)
    }
}
