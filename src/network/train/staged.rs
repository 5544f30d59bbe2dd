//! A staged run's progress on disk: what [`train_to_target`](super::train_to_target) has done
//! between its stages, so that an interrupted run of hours continues where it stopped, to the
//! same network. May import: the trainer's data, recipe and adaptive reports, Fnv, safetensors
//! I/O.
//!
//! The file holds the loop's state at a stage's start (after a refine stage's round: its
//! samples are in the file) or end: the network, the best one so far and its measurement, the
//! stages' reports, the chosen learning rate, the samples the refine rounds added (normalised),
//! and a fingerprint of everything the run depends on (data, widths, seed, schedule, target,
//! start), so that a checkpoint is never continued with other inputs. Inside a stage the
//! one-stage checkpoint ([`super::resume_until`]) keeps the epochs, one file per stage.

use std::collections::HashMap;
use std::path::{Path, PathBuf};

use super::accuracy::{Measured, Target};
use super::adaptive::RoundReport;
use super::dataset::Dataset;
use super::recipe::{RecipeData, StageReport};
use super::Recipe;
use crate::network::io::{f64_bytes, serialize, write_atomically, RawTensor, RawTensors};
use crate::network::{Layer, Mlp, NetworkError};
use crate::provenance::Fnv;

const FORMAT: &str = "cbfreach-staged-checkpoint-1";

/// Where a staged run keeps its progress, and whether it continues from it.
#[derive(Clone, Debug)]
pub struct StagedCheckpoint {
    /// The run's state between stages (`…/name.ckpt`); the stage in progress keeps its epochs
    /// beside it ([`StagedCheckpoint::stage_file`]).
    pub path: PathBuf,
    /// Continue from `path` where it exists (a fresh run overwrites it).
    pub resume: bool,
}

impl StagedCheckpoint {
    /// The checkpoint of stage `index`'s epochs: `name.stage<index>.ckpt` beside `path`.
    pub fn stage_file(&self, index: usize) -> PathBuf {
        self.path.with_extension(format!("stage{index}.ckpt"))
    }

    /// Removes the run's files (after its network is saved): the state and any stage's.
    pub fn remove(&self, stages: usize) {
        let _ = std::fs::remove_file(&self.path);
        self.remove_stage_files(stages);
    }

    /// Removes the stages' epoch files (a fresh run must not continue stale ones later).
    pub fn remove_stage_files(&self, stages: usize) {
        // Missing files are the normal case (stages skipped, or never interrupted).
        for i in 0..stages {
            let _ = std::fs::remove_file(self.stage_file(i));
        }
    }
}

/// The loop's state between stages.
#[derive(Clone, Debug)]
pub(super) struct Progress {
    /// The stage to run next (the schedule's length: the run is over).
    pub next: usize,
    /// Stage `next`'s round of fresh samples, where it ran already (its samples are in
    /// `added`).
    pub round: Option<RoundReport>,
    /// Refine rounds run (each round's points come from its own seed).
    pub rounds: u64,
    pub refining_done: bool,
    pub met: bool,
    pub confirmed: bool,
    /// The learning rate of the range test.
    pub lr: f64,
    /// The network to continue from, and the best so far with its measurement (normalised).
    pub net: Mlp,
    pub best: (Mlp, Measured),
    pub stages: Vec<StageReport>,
    /// Wall-clock seconds of the run before this process.
    pub seconds: f64,
    /// The samples the refine rounds added, normalised: pointwise and secant.
    pub added: Dataset,
    pub added_secant: Option<Dataset>,
    /// The stages of the shorter schedule this run began under, where a later one extended it
    /// ([`shared_stages`]).
    pub extended_from: Option<usize>,
}

/// Which schedule wrote a checkpoint, against the run's own ([`Progress::load`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) enum Written {
    /// The run's schedule itself: any state continues, the finished one too.
    Same,
    /// Its first `k` stages, a schedule the run's extends: a state within them continues.
    Prefix(usize),
}

/// The first `k` of `recipe`'s stages whose run's fingerprint (`print` of a schedule) is
/// `stored` (the longest such prefix): a checkpoint written under a schedule that `recipe`
/// extends (stages added at its end, as the certify stages were in 2026-12) continues into the
/// added stages.
pub(super) fn shared_stages(
    stored: &str,
    recipe: &Recipe,
    print: impl Fn(&Recipe) -> String,
) -> Option<usize> {
    (1..=recipe.stages.len()).rev().find(|&k| {
        let prefix = Recipe {
            stages: recipe.stages[..k].to_vec(),
            ..recipe.clone()
        };
        print(&prefix) == stored
    })
}

/// A digest of everything a staged run's result depends on.
pub(super) fn fingerprint(
    init: Option<&Mlp>,
    widths: &[usize],
    seed: u64,
    data: &RecipeData,
    recipe: &Recipe,
    target: &Target,
) -> String {
    let mut h = Fnv::default();
    h.bytes(b"staged-1").usize(widths.len());
    for &w in widths {
        h.usize(w);
    }
    h.bytes(&seed.to_le_bytes());
    // Debug prints every float with its shortest round-trip form: equal text, equal values.
    h.str(&format!("{recipe:?}")).str(&format!("{target:?}"));
    let mut dataset = |d: Option<&Dataset>| {
        let Some(d) = d else {
            h.usize(0);
            return;
        };
        h.usize(d.n_in).usize(d.n_out).usize(d.len());
        let jac = d.jacobians.as_deref().unwrap_or(&[]);
        let w = d.weights.as_deref().unwrap_or(&[]);
        for x in d.inputs.iter().chain(&d.targets).chain(jac).chain(w) {
            h.f64(*x);
        }
    };
    dataset(Some(data.pointwise));
    dataset(data.secant);
    dataset(Some(data.validation));
    h.bytes(&[data.oracle.is_some() as u8]);
    match init {
        Some(net) => {
            for l in &net.layers {
                for x in l.weight.iter().chain(&l.bias) {
                    h.f64(*x);
                }
            }
        }
        None => {
            h.usize(0);
        }
    }
    h.hex()
}

/// Samples `from..` of `d`.
pub(super) fn tail(d: &Dataset, from: usize) -> Dataset {
    let (n, m) = (d.n_in, d.n_out);
    Dataset {
        n_in: n,
        n_out: m,
        inputs: d.inputs[from * n..].to_vec(),
        targets: d.targets[from * m..].to_vec(),
        jacobians: d.jacobians.as_ref().map(|j| j[from * m * n..].to_vec()),
        weights: d.weights.as_ref().map(|w| w[from..].to_vec()),
    }
}

fn f64_tensor(name: String, shape: Vec<usize>, values: &[f64]) -> RawTensor {
    (name, safetensors::Dtype::F64, shape, f64_bytes(values))
}

fn push_net(t: &mut Vec<RawTensor>, prefix: &str, net: &Mlp) {
    for (k, l) in net.layers.iter().enumerate() {
        t.push(f64_tensor(
            format!("{prefix}.{k}.weight"),
            vec![l.n_out, l.n_in],
            &l.weight,
        ));
        t.push(f64_tensor(
            format!("{prefix}.{k}.bias"),
            vec![l.n_out],
            &l.bias,
        ));
    }
}

fn push_data(t: &mut Vec<RawTensor>, prefix: &str, d: &Dataset) {
    let len = d.len();
    t.push(f64_tensor(
        format!("{prefix}.inputs"),
        vec![len, d.n_in],
        &d.inputs,
    ));
    t.push(f64_tensor(
        format!("{prefix}.targets"),
        vec![len, d.n_out],
        &d.targets,
    ));
    if let Some(j) = &d.jacobians {
        t.push(f64_tensor(
            format!("{prefix}.jacobians"),
            vec![len, d.n_out * d.n_in],
            j,
        ));
    }
    if let Some(w) = &d.weights {
        t.push(f64_tensor(format!("{prefix}.weights"), vec![len], w));
    }
}

impl Progress {
    /// Writes the state to `path` (atomically: an interrupted write leaves the last one).
    pub(super) fn save(&self, path: &Path, fingerprint: &str) -> Result<(), NetworkError> {
        let mut t = Vec::new();
        push_net(&mut t, "net", &self.net);
        push_net(&mut t, "best", &self.best.0);
        let m = &self.best.1;
        // Exact floats as tensors: the next stages' decisions compare them.
        t.push(f64_tensor(
            "best_measured".into(),
            vec![4],
            &[m.linf, m.mean, m.slope_p95, m.ibp_looseness],
        ));
        t.push(f64_tensor("lr".into(), vec![1], &[self.lr]));
        push_data(&mut t, "added", &self.added);
        if let Some(s) = &self.added_secant {
            push_data(&mut t, "added_secant", s);
        }
        let json = |e: serde_json::Error| NetworkError::Format {
            path: path.to_path_buf(),
            message: e.to_string(),
        };
        let mut meta = HashMap::new();
        meta.insert("format".into(), FORMAT.into());
        meta.insert("fingerprint".into(), fingerprint.into());
        meta.insert("next".into(), self.next.to_string());
        meta.insert("rounds".into(), self.rounds.to_string());
        meta.insert(
            "flags".into(),
            format!(
                "{} {} {}",
                self.refining_done as u8, self.met as u8, self.confirmed as u8
            ),
        );
        meta.insert("seconds".into(), self.seconds.to_string());
        if let Some(k) = self.extended_from {
            meta.insert("extended_from".into(), k.to_string());
        }
        meta.insert(
            "stages".into(),
            serde_json::to_string(&self.stages).map_err(json)?,
        );
        if let Some(r) = &self.round {
            meta.insert("round".into(), serde_json::to_string(r).map_err(json)?);
        }
        write_atomically(path, &serialize(&t, meta, path)?)
    }

    /// Reads a state written by [`Progress::save`] for a run whose stored fingerprint `written`
    /// recognises ([`Written`]); `shape` is the data's `(n_in, n_out)`, `secant` whether the
    /// run has secant data. A run stopped under a schedule that this one extends continues
    /// where its stage lies within the shared stages.
    pub(super) fn load(
        path: &Path,
        written: impl Fn(&str) -> Option<Written>,
        shape: (usize, usize),
        secant: bool,
    ) -> Result<Progress, NetworkError> {
        let bytes = std::fs::read(path).map_err(|source| NetworkError::Io {
            path: path.to_path_buf(),
            source,
        })?;
        let bad = |message: String| NetworkError::Checkpoint {
            path: path.to_path_buf(),
            message,
        };
        let raw = RawTensors::parse(&bytes, path)
            .map_err(|_| bad("not a training checkpoint (unreadable as safetensors)".into()))?;
        let meta = |key: &str| {
            raw.metadata
                .get(key)
                .cloned()
                .ok_or_else(|| bad(format!("metadata key `{key}` missing")))
        };
        if meta("format")? != FORMAT {
            return Err(bad(
                "not a checkpoint of the staged schedule (a one-stage run's, with `--epochs`?)"
                    .into(),
            ));
        }
        let number = |key: &str| {
            meta(key)?
                .parse::<u64>()
                .map_err(|e| bad(format!("metadata `{key}`: {e}")))
        };
        let next = number("next")? as usize;
        let written = written(&meta("fingerprint")?);
        let within = match written {
            Some(Written::Same) => true,
            Some(Written::Prefix(k)) => next < k,
            None => false,
        };
        if !within {
            return Err(bad(
                "it was written by a run with other data, architecture, seed, \
                 schedule or target (the scenario, a flag or the start changed): run without \
                 `--resume` to start afresh"
                    .into(),
            ));
        }
        let flags: Vec<bool> = meta("flags")?.split(' ').map(|f| f == "1").collect();
        let [refining_done, met, confirmed] = flags[..] else {
            return Err(bad("metadata `flags`: expected three".into()));
        };
        let json = |key: &str, text: String| bad(format!("metadata `{key}`: {text}"));
        let stages: Vec<StageReport> =
            serde_json::from_str(&meta("stages")?).map_err(|e| json("stages", e.to_string()))?;
        let round = match raw.metadata.get("round") {
            Some(r) => Some(serde_json::from_str(r).map_err(|e| json("round", e.to_string()))?),
            None => None,
        };
        let seconds = meta("seconds")?
            .parse::<f64>()
            .map_err(|e| json("seconds", e.to_string()))?;
        let measured = raw.f64s_unchecked("best_measured")?;
        let [linf, mean, slope_p95, ibp_looseness] = measured[..] else {
            return Err(bad("tensor `best_measured`: expected 4 values".into()));
        };
        let lr = raw
            .f64s("lr")?
            .first()
            .copied()
            .ok_or_else(|| bad("tensor `lr` is empty".into()))?;
        let net = read_net(&raw, "net", path)?;
        let best = read_net(&raw, "best", path)?;
        let added = read_data(&raw, "added", shape, path)?;
        let added_secant = match secant {
            true => Some(read_data(&raw, "added_secant", shape, path)?),
            false => None,
        };
        // Begun under a shorter schedule: as the checkpoint says (it continued one already), or
        // as this load finds.
        let extended_from = match (raw.metadata.get("extended_from"), written) {
            (Some(k), _) => Some(
                k.parse::<usize>()
                    .map_err(|e| json("extended_from", e.to_string()))?,
            ),
            (None, Some(Written::Prefix(k))) => Some(k),
            (None, _) => None,
        };
        Ok(Progress {
            next,
            extended_from,
            round,
            rounds: number("rounds")?,
            refining_done,
            met,
            confirmed,
            lr,
            net,
            best: (
                best,
                Measured {
                    linf,
                    mean,
                    slope_p95,
                    ibp_looseness,
                },
            ),
            stages,
            seconds,
            added,
            added_secant,
        })
    }
}

fn read_net(raw: &RawTensors, prefix: &str, path: &Path) -> Result<Mlp, NetworkError> {
    let mut layers = Vec::new();
    for k in 0.. {
        let name = format!("{prefix}.{k}.weight");
        let Ok(shape) = raw.shape(&name) else {
            break;
        };
        let weight = raw.f64s(&name)?;
        let bias = raw.f64s(&format!("{prefix}.{k}.bias"))?;
        let [n_out, n_in] = shape[..] else {
            return Err(NetworkError::Checkpoint {
                path: path.to_path_buf(),
                message: format!("tensor `{name}` has shape {shape:?}, expected two axes"),
            });
        };
        layers.push(Layer {
            weight,
            bias,
            n_in,
            n_out,
        });
    }
    let net = Mlp { layers };
    net.validate(&path.display().to_string())?;
    Ok(net)
}

fn read_data(
    raw: &RawTensors,
    prefix: &str,
    (n_in, n_out): (usize, usize),
    path: &Path,
) -> Result<Dataset, NetworkError> {
    let names = raw.names();
    let has = |what: &str| names.iter().any(|n| *n == format!("{prefix}.{what}"));
    let data = Dataset {
        n_in,
        n_out,
        inputs: raw.f64s(&format!("{prefix}.inputs"))?,
        targets: raw.f64s(&format!("{prefix}.targets"))?,
        // A sample without a slope target has NaN slopes.
        jacobians: match has("jacobians") {
            true => Some(raw.f64s_unchecked(&format!("{prefix}.jacobians"))?),
            false => None,
        },
        weights: match has("weights") {
            true => Some(raw.f64s(&format!("{prefix}.weights"))?),
            false => None,
        },
    };
    // No round may have added samples yet.
    let empty = data.inputs.is_empty() && data.targets.is_empty();
    if !empty {
        data.validate().map_err(|e| NetworkError::Checkpoint {
            path: path.to_path_buf(),
            message: format!("samples `{prefix}`: {e}"),
        })?;
    }
    Ok(data)
}
