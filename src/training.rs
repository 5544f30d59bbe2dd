//! `cbfreach train`'s job (the CLI parses and prints): the scenario's filter sampled into
//! training and validation data ([`TrainingData`]), the surrogate `N ≈ v` trained on them —
//! by the default staged schedule to the scenario's `[training] target` ([`StagedPlan`]) or as
//! one stage of given settings ([`train_one_stage`]) — and the network in the scenario's units
//! with the metadata that makes the run reproducible ([`Trained`]; docs/networks.md).

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use crate::boxes::IntervalBox;
use crate::dataset::{
    filter_dataset, grid_spacing, refinement_points, restrict_to_band, steep_samples,
    training_points, validation_points, weigh_box, DatasetSummary, FilterOracle, Slopes,
};
use crate::filter::SafetyFilter;
use crate::network::train::{
    self, Dataset, EpochStats, ErrorStats, Measured, Normalisation, Recipe, RecipeData,
    RecipeProgress, RecipeReport, Resolution, SlopeLimit, StagedCheckpoint, Target, TrainReport,
    TrainSettings,
};
use crate::network::{Mlp, NetworkError};
use crate::scenario::Scenario;

/// Most weights and biases a network to train may have (100 million: ~2 GB of f32 copies).
pub const MAX_PARAMETERS: usize = 100_000_000;

/// Why a training job could not run.
#[derive(Debug, thiserror::Error)]
pub enum TrainingError {
    /// The layer widths do not fit the scenario's states and inputs, or one is 0.
    #[error(
        "architecture {architecture:?}: expected positive widths that start with n = {n} and \
         end with m = {m} (e.g. [{n}, 64, 64, {m}])"
    )]
    Architecture {
        /// The widths given.
        architecture: Vec<usize>,
        /// The scenario's states.
        n: usize,
        /// Its inputs.
        m: usize,
    },
    /// More weights than the trainer holds.
    #[error(
        "architecture {architecture:?}: {parameters} weights and biases, more than the \
         {MAX_PARAMETERS} the trainer holds in memory"
    )]
    TooLarge {
        /// The widths given.
        architecture: Vec<usize>,
        /// Its weights and biases (saturating).
        parameters: usize,
    },
    /// No architecture given and none in the scenario's `[network]`.
    #[error("no [network] in the scenario: give an architecture")]
    NoArchitecture,
    /// The network to start from has other widths.
    #[error("{path}: architecture {found} differs from {expected:?}")]
    InitArchitecture {
        /// Its file.
        path: String,
        /// Its widths, as `2x64x2`.
        found: String,
        /// The run's.
        expected: Vec<usize>,
    },
    /// The training grid does not fit the scenario.
    #[error("{0}")]
    Grid(String),
    /// Training, measuring or reading a network failed.
    #[error(transparent)]
    Network(#[from] NetworkError),
}

/// Told how far the filter's sampling has come.
pub trait DataProgress: Sync {
    /// A data set of `points` points begins (`what`: its name).
    fn begin(&self, what: &str, points: usize);
    /// Points of it done so far.
    fn done(&self, points: usize);
    /// It is finished.
    fn end(&self);
}

/// No progress to tell.
pub struct Quiet;

impl DataProgress for Quiet {
    fn begin(&self, _: &str, _: usize) {}
    fn done(&self, _: usize) {}
    fn end(&self) {}
}

/// Samples added around the grid points of `S` where `v` is steep.
#[derive(Clone, Debug, PartialEq)]
pub struct Dense {
    /// A grid point is steep where some `|∂vᵢ/∂xⱼ|` exceeds this.
    pub slope: f64,
    /// How many times finer per axis the added samples are than the grid.
    pub factor: usize,
}

/// What the training data are made of. Every field's default is the one of `cbfreach train`.
#[derive(Clone, Debug, PartialEq)]
pub struct DataOptions {
    /// Points per axis of the training grid; default `None`: the scenario's `[training] grid`.
    pub grid: Option<Vec<usize>>,
    /// The slope targets; default the pointwise Jacobian.
    pub slopes: Slopes,
    /// Samples added where `v` is steep; default none.
    pub dense: Option<Dense>,
    /// Slopes above this mark a jump, not a steep point (for [`Dense`]); default none.
    pub jacobian_cap: Option<f64>,
    /// Which unsafe samples are trained on ([`UnsafeBand`]); default those within two grid
    /// spacings of `S`.
    pub unsafe_band: UnsafeBand,
    /// The samples in this box weigh this much in both loss terms; default none.
    pub focus: Option<(IntervalBox, f64)>,
}

impl Default for DataOptions {
    fn default() -> Self {
        DataOptions {
            grid: None,
            slopes: Slopes::Pointwise,
            dense: None,
            jacobian_cap: None,
            unsafe_band: UnsafeBand::Spacings(2.0),
            focus: None,
        }
    }
}

/// Which samples outside `S` are trained on. A network need follow `v` outside `S` only as
/// far as the error map's cells across `∂S` reach; deeper in an obstacle `v` grows without
/// bound where `L_g h → 0` (scenario 2 near (1, 0): up to 26 within 0.3 of `S`, against 6 on
/// `S`), and those targets drag the fit on the safe side: at a quarter of the schedule,
/// 2×128×128×128×1, keeping them within 0.3 rather than 0.05 left scenario 2's slope p95 at
/// 0.46 instead of 0.19 and its mean error at 0.032 instead of 0.0087 (docs/networks.md).
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum UnsafeBand {
    /// Every feasible sample.
    All,
    /// Those within this distance of `S` along some axis, in the states' units.
    Within(f64),
    /// Those within this many grid spacings of `S` along some axis (each axis its own
    /// spacing: the units of the states do not matter).
    Spacings(f64),
}

impl UnsafeBand {
    /// One stage's default (`cbfreach train --epochs`): the distance the recorded recipes of
    /// docs/networks.md ran with, so that their commands still make their networks.
    pub const ONE_STAGE: UnsafeBand = UnsafeBand::Within(0.3);

    /// The distance per axis, or none (every sample), for a grid of `grid` points per axis on
    /// `s`'s training region.
    pub fn widths(&self, s: &Scenario, grid: &[usize]) -> Option<Vec<f64>> {
        match *self {
            UnsafeBand::All => None,
            UnsafeBand::Within(d) => Some(vec![d; s.n()]),
            UnsafeBand::Spacings(k) => Some(grid_spacing(s, grid).iter().map(|h| k * h).collect()),
        }
    }
}

/// What sampling did besides the grid, for the report.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct DataNotes {
    /// Samples added where `v` is steep, and around how many grid points.
    pub dense: Option<(usize, usize)>,
    /// Unsafe samples left out, and the band's width per axis they lie beyond.
    pub left_out: Option<(usize, Vec<f64>)>,
    /// Samples in the focus box.
    pub focused: Option<usize>,
}

/// The training and validation data of one scenario.
pub struct TrainingData {
    /// The training grid's points per axis.
    pub grid: Vec<usize>,
    /// Its points (the staged schedule samples its secant slopes there).
    pub points: Vec<Vec<f64>>,
    /// The training samples, in the scenario's units.
    pub data: Dataset,
    /// What the filter gave on them.
    pub summary: DatasetSummary,
    /// Points between the grid's, never trained on, with pointwise slopes (as `cbfreach
    /// error` measures).
    pub validation: Dataset,
    /// What the filter gave there.
    pub validation_summary: DatasetSummary,
    /// What sampling did besides the grid.
    pub notes: DataNotes,
    options: DataOptions,
}

/// The filter on a set of points.
fn sample(
    s: &Scenario,
    points: &[Vec<f64>],
    slopes: &Slopes,
    what: &str,
    progress: &dyn DataProgress,
) -> (Dataset, DatasetSummary) {
    let filter = SafetyFilter::new(s);
    progress.begin(what, points.len());
    let out = filter_dataset(&filter, points, slopes, &|done| progress.done(done));
    progress.end();
    out
}

impl TrainingData {
    /// Samples the scenario's filter as `options` say.
    pub fn sample(
        s: &Scenario,
        options: &DataOptions,
        progress: &dyn DataProgress,
    ) -> Result<TrainingData, TrainingError> {
        let grid = options.grid.clone().unwrap_or(s.training.grid.clone());
        let points = training_points(s, Some(&grid)).map_err(TrainingError::Grid)?;
        let slopes = &options.slopes;
        let (mut data, mut summary) = sample(s, &points, slopes, "training data", progress);
        let mut notes = DataNotes::default();
        if let Some(dense) = &options.dense {
            let seeds = steep_samples(s, &data, dense.slope, options.jacobian_cap);
            // Only in S: inside an obstacle `v` can grow without bound (scenario 2 near
            // (1, 0)), and more such targets would drag the fit on the safe side.
            let mut added = refinement_points(
                &s.training.region,
                &grid,
                seeds.iter().copied(),
                dense.factor,
            );
            added.retain(|x| s.is_safe(x));
            notes.dense = Some((added.len(), seeds.len()));
            let (finer, finer_summary) = sample(s, &added, slopes, "finer samples", progress);
            data.append(finer)?;
            summary.add(&finer_summary);
        }
        if let Some(band) = options.unsafe_band.widths(s, &grid) {
            notes.left_out = Some((restrict_to_band(s, &mut data, &band), band));
        }
        if let Some((focus, weight)) = &options.focus {
            notes.focused = Some(weigh_box(&mut data, focus, *weight));
        }
        let (validation, validation_summary) = sample(
            s,
            &validation_points(s, &grid),
            &Slopes::Pointwise,
            "validation data",
            progress,
        );
        Ok(TrainingData {
            grid,
            points,
            data,
            summary,
            validation,
            validation_summary,
            notes,
            options: options.clone(),
        })
    }

    /// What the data were made of, for the network's metadata: not trainer settings, but
    /// reproducing the run needs them.
    fn metadata(&self) -> BTreeMap<String, String> {
        let o = &self.options;
        let mut m = BTreeMap::new();
        if let Some(dense) = &o.dense {
            m.insert("dense_slope".into(), dense.slope.to_string());
            m.insert("dense_factor".into(), dense.factor.to_string());
        }
        if let Slopes::Secant(h) = &o.slopes {
            m.insert("slope_step".into(), format!("{h:?}"));
        }
        if let Some((_, band)) = &self.notes.left_out {
            m.insert("unsafe_band".into(), format!("{band:?}"));
        }
        if let Some((focus, weight)) = &o.focus {
            let join = |v: &[f64]| v.iter().map(f64::to_string).collect::<Vec<_>>().join(",");
            let text = format!("{}:{}", join(&focus.lower), join(&focus.upper));
            m.insert("focus_box".into(), text);
            m.insert("focus_weight".into(), weight.to_string());
        }
        m
    }
}

/// The layer widths of a run: `given`, else the scenario's `[network]` architecture; they
/// must start with its states and end with its inputs.
pub fn architecture(s: &Scenario, given: Option<&[usize]>) -> Result<Vec<usize>, TrainingError> {
    let architecture = match (given, &s.network) {
        (Some(a), _) => a.to_vec(),
        (None, Some(net)) => net.architecture.clone(),
        (None, None) => return Err(TrainingError::NoArchitecture),
    };
    if architecture.len() < 2
        || architecture.contains(&0)
        || architecture[0] != s.n()
        || architecture[architecture.len() - 1] != s.m()
    {
        return Err(TrainingError::Architecture {
            architecture,
            n: s.n(),
            m: s.m(),
        });
    }
    // Weights, Adam's two moments and each thread's gradients are f32 copies of these: refused
    // here rather than aborted on when allocated.
    let parameters = architecture
        .windows(2)
        .map(|w| (w[0].saturating_add(1)).saturating_mul(w[1]))
        .fold(0_usize, usize::saturating_add);
    if parameters > MAX_PARAMETERS {
        return Err(TrainingError::TooLarge {
            architecture,
            parameters,
        });
    }
    Ok(architecture)
}

/// A trained network in the scenario's units, ready to save.
pub struct Trained {
    /// The network (rounded to f32 where asked).
    pub net: Mlp,
    /// What the file records: the normalisation, the scenario, the run's report and data.
    pub metadata: BTreeMap<String, String>,
    /// Whether to save it as F32.
    pub f32: bool,
}

impl Trained {
    /// Writes the network with its metadata as safetensors.
    pub fn save(&self, path: &Path) -> Result<(), TrainingError> {
        match self.f32 {
            true => self.net.save_safetensors_f32(path, &self.metadata)?,
            false => self.net.save_safetensors(path, &self.metadata)?,
        }
        Ok(())
    }
}

/// The network with every weight rounded to the nearest f32 (saved as F32; its errors are
/// measured after the rounding).
fn rounded_to_f32(net: &Mlp) -> Mlp {
    let mut out = net.clone();
    for l in &mut out.layers {
        for w in l.weight.iter_mut().chain(&mut l.bias) {
            *w = *w as f32 as f64;
        }
    }
    out
}

/// The default staged schedule for one scenario's data, before it runs: what it will do, the
/// target it stops at, and how finely the training grid resolves `v`.
pub struct StagedPlan {
    /// The stages and their settings.
    pub recipe: Recipe,
    /// The scenario's `[training] target` (or the default one).
    pub target: Target,
    /// The training grid's own multilinear interpolant against `v` at the validation points.
    pub resolution: Resolution,
}

/// What the staged schedule ran and measured.
pub struct Staged {
    /// The network and its metadata.
    pub trained: Trained,
    /// The stages, the normalisation and whether the target was reached.
    pub report: RecipeReport,
    /// The saved network on the validation points (after any f32 rounding).
    pub measured: Measured,
}

impl StagedPlan {
    /// The schedule for `data` and a network of layer widths `widths`, its stages' epochs
    /// multiplied by `budget`.
    pub fn new(
        s: &Scenario,
        data: &TrainingData,
        widths: &[usize],
        budget: f64,
        seed: u64,
    ) -> StagedPlan {
        let r = &s.training.region;
        let grid = &data.grid;
        let spacing = grid_spacing(s, grid);
        let hidden = train::hidden_layers(widths);
        let mut recipe = Recipe::for_data(data.data.len(), &spacing, budget, hidden);
        recipe.refinement.seed = seed;
        let target = s.training.target.map_or(Target::default(), |t| Target {
            linf: t.linf,
            slope_p95: t.slope_p95,
        });
        let resolution = train::grid_resolution(
            &r.lower,
            &r.upper,
            grid,
            &data.data,
            &data.validation,
            target.linf.unwrap_or(f64::INFINITY),
        );
        StagedPlan {
            recipe,
            target,
            resolution,
        }
    }

    /// Runs the schedule from `init` (in the scenario's units; `None`: random weights from
    /// `seed`) to the target; `f32` rounds the result's weights to f32. With `checkpoint` the
    /// run keeps its progress there and may continue from it ([`StagedCheckpoint`]).
    #[allow(clippy::too_many_arguments)]
    pub fn run(
        &self,
        s: &Scenario,
        data: &TrainingData,
        architecture: &[usize],
        init: Option<(&Path, &Mlp)>,
        seed: u64,
        f32: bool,
        checkpoint: Option<&StagedCheckpoint>,
        progress: &dyn DataProgress,
        on_epoch: impl FnMut(&RecipeProgress),
    ) -> Result<Staged, TrainingError> {
        if let Some((path, net)) = init {
            if net.widths() != architecture {
                return Err(init_mismatch(path, net, architecture));
            }
        }
        let slopes = Slopes::Secant(self.recipe.secant_step.clone());
        let (mut secant, _) = sample(s, &data.points, &slopes, "secant slopes", progress);
        if let Some(band) = data.options.unsafe_band.widths(s, &data.grid) {
            restrict_to_band(s, &mut secant, &band);
        }
        let oracle = FilterOracle::new(s);
        let recipe_data = RecipeData {
            pointwise: &data.data,
            secant: Some(&secant),
            validation: &data.validation,
            oracle: Some(&oracle),
        };
        let (net, report) = train::train_to_target(
            init.map(|(_, net)| net),
            architecture,
            seed,
            &recipe_data,
            &self.recipe,
            &self.target,
            checkpoint,
            on_epoch,
        )?;
        let net = if f32 { rounded_to_f32(&net) } else { net };
        let measured = train::measure(&net, &data.validation, &self.recipe.ibp_radius)?;
        let mut metadata = report.normalisation.metadata();
        metadata.insert("scenario".into(), s.name.clone());
        if let Ok(json) = serde_json::to_string(&report) {
            metadata.insert("recipe_report".into(), json);
        }
        if let Ok(json) = serde_json::to_string(&self.resolution) {
            metadata.insert("grid_resolution".into(), json);
        }
        metadata.insert("validation_max_linf".into(), measured.linf.to_string());
        metadata.insert(
            "validation_slope_p95".into(),
            measured.slope_p95.to_string(),
        );
        Ok(Staged {
            trained: Trained { net, metadata, f32 },
            report,
            measured,
        })
    }
}

fn init_mismatch(path: &Path, net: &Mlp, expected: &[usize]) -> TrainingError {
    TrainingError::InitArchitecture {
        path: path.display().to_string(),
        found: net.architecture(),
        expected: expected.to_vec(),
    }
}

/// How one stage of given settings starts.
pub struct OneStage<'a> {
    /// Train on the data as they are (`false`) or normalised from them (`true`, the default
    /// of the staged schedule; the result is folded back into the scenario's units).
    pub normalise: bool,
    /// A network to start from (its file, for messages), in the scenario's units.
    pub init: Option<(&'a Path, &'a Mlp)>,
    /// Continue from this checkpoint where it exists (ignores `init`).
    pub resume: Option<PathBuf>,
    /// Round the result's weights to f32.
    pub f32: bool,
}

/// What one stage ran and measured.
pub struct OneStageRun {
    /// The network and its metadata.
    pub trained: Trained,
    /// Every epoch's figures.
    pub report: TrainReport,
    /// The saved network on the training samples.
    pub training: ErrorStats,
    /// And on the validation points.
    pub validation: ErrorStats,
}

/// Trains `architecture` for one stage of `settings` on `data`; `on_epoch` sees each epoch's
/// figures with its errors in the scenario's units.
pub fn train_one_stage(
    s: &Scenario,
    data: &TrainingData,
    architecture: &[usize],
    settings: &TrainSettings,
    start: OneStage,
    mut on_epoch: impl FnMut(&EpochStats),
) -> Result<OneStageRun, TrainingError> {
    let norm = match start.normalise {
        true => Normalisation::from_data(&data.data),
        false => Normalisation::identity(s.n(), s.m()),
    };
    let normalised = norm.dataset(&data.data, settings.jacobian_cap.map(SlopeLimit::Data))?;
    let settings = norm.settings(settings);
    let scale = norm.output_scale;
    let progress = |e: &EpochStats| {
        on_epoch(&EpochStats {
            max_error: e.max_error * scale,
            mean_error: e.mean_error * scale,
            ..e.clone()
        })
    };
    let (net, report) = match start.resume.filter(|c| c.exists()) {
        Some(checkpoint) => train::resume(&checkpoint, &normalised, &settings, progress)?,
        None => {
            let init = match start.init {
                Some((path, net)) => {
                    let net = norm.unfold(net)?;
                    if net.widths() != architecture {
                        return Err(init_mismatch(path, &net, architecture));
                    }
                    net
                }
                None => Mlp::random(architecture, settings.seed),
            };
            train::train(init, &normalised, &settings, progress)?
        }
    };
    let net = norm.fold(&net)?;
    let net = if start.f32 { rounded_to_f32(&net) } else { net };
    let validation = train::evaluate(&net, &data.validation)?;
    let training = train::evaluate(&net, &data.data)?;
    let mut metadata = report.metadata();
    metadata.extend(norm.metadata());
    metadata.insert("scenario".into(), s.name.clone());
    metadata.extend(data.metadata());
    if settings.secant_step.is_some() {
        metadata.insert("secant_network".into(), "true".into());
    }
    metadata.insert(
        "validation_max_linf".into(),
        validation.max_error.to_string(),
    );
    metadata.insert(
        "validation_max_l2".into(),
        validation.max_error_l2.to_string(),
    );
    Ok(OneStageRun {
        trained: Trained {
            net,
            metadata,
            f32: start.f32,
        },
        report,
        training,
        validation,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn scenario_1() -> Scenario {
        let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR"));
        Scenario::load(&dir.join("scenarios/integrator.toml")).unwrap()
    }

    #[test]
    fn a_run_records_what_its_data_were_made_of() {
        let s = scenario_1();
        assert!(matches!(
            architecture(&s, Some(&[3, 8, 2])),
            Err(TrainingError::Architecture { n: 2, m: 2, .. })
        ));
        // A zero width (it panicked in the trainer's chunking) and an architecture too large
        // to hold are refused by name before any data is made.
        assert!(matches!(
            architecture(&s, Some(&[2, 0, 2])),
            Err(TrainingError::Architecture { .. })
        ));
        assert!(matches!(
            architecture(&s, Some(&[2, 100_000, 100_000, 2])),
            Err(TrainingError::TooLarge {
                parameters: 10_000_600_002,
                ..
            })
        ));
        assert!(matches!(
            architecture(&s, Some(&[2, usize::MAX, 2])),
            Err(TrainingError::TooLarge { .. })
        ));
        assert_eq!(architecture(&s, None).unwrap(), vec![2, 400, 400, 400, 2]);
        let focus = IntervalBox::new(vec![-0.5, -0.5], vec![0.5, 0.5]).unwrap();
        let options = DataOptions {
            grid: Some(vec![11, 9]),
            slopes: Slopes::Secant(vec![0.1]),
            focus: Some((focus, 10.0)),
            ..DataOptions::default()
        };
        let data = TrainingData::sample(&s, &options, &Quiet).unwrap();
        assert!(
            data.notes.focused.is_some_and(|k| k > 0),
            "{:?}",
            data.notes
        );
        assert!(data.notes.left_out.is_some() && data.notes.dense.is_none());
        let settings = TrainSettings {
            epochs: 1,
            ..TrainSettings::default()
        };
        let start = OneStage {
            normalise: true,
            init: None,
            resume: None,
            f32: true,
        };
        let run = train_one_stage(&s, &data, &[2, 8, 2], &settings, start, |_| {}).unwrap();
        let meta = &run.trained.metadata;
        assert_eq!(meta["slope_step"], "[0.1]");
        assert_eq!(meta["focus_box"], "-0.5,-0.5:0.5,0.5");
        assert_eq!(meta["scenario"], s.name);
        assert!(!meta.contains_key("secant_network"));
        let net = &run.trained.net;
        assert!(net.layers.iter().all(|l| {
            let w = l.weight.iter().chain(&l.bias);
            w.clone().all(|w| *w as f32 as f64 == *w)
        }));
        // Another network's widths as the start: refused, naming its file.
        let other = Mlp::random(&[2, 4, 2], 0);
        let start = OneStage {
            normalise: true,
            init: Some((Path::new("other.safetensors"), &other)),
            resume: None,
            f32: false,
        };
        let refused = train_one_stage(&s, &data, &[2, 8, 2], &settings, start, |_| {});
        assert!(
            matches!(&refused, Err(e) if e.to_string().starts_with("other.safetensors: architecture 2x4x2")),
            "{:?}",
            refused.err()
        );
    }

    /// The unsafe samples kept are those within the band of `S` along an axis, the band two
    /// grid spacings of each axis by default (units of the states do not matter), a distance
    /// where one is given, and every one with `All`.
    #[test]
    fn unsafe_samples_are_kept_within_two_grid_spacings_of_s() {
        let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR"));
        let s = Scenario::load(&dir.join("scenarios/double-integrator.toml")).unwrap();
        let grid = vec![101, 41]; // spacings 0.1 and 0.1 on C = [−4, 6] × [−2, 2]
        let band = |unsafe_band| {
            let options = DataOptions {
                grid: Some(grid.clone()),
                unsafe_band,
                ..DataOptions::default()
            };
            TrainingData::sample(&s, &options, &Quiet).unwrap()
        };
        let kept = |d: &TrainingData| -> Vec<Vec<f64>> {
            (0..d.data.len())
                .filter(|&k| d.data.weights.as_ref().is_none_or(|w| w[k] > 0.0))
                .map(|k| d.data.inputs[2 * k..2 * k + 2].to_vec())
                .filter(|x| !s.is_safe(x))
                .collect()
        };
        let near = |x: &[f64], b: f64| {
            (0..2).any(|i| {
                [-b, b, -0.5 * b, 0.5 * b].iter().any(|&d| {
                    let mut y = x.to_vec();
                    y[i] += d;
                    s.is_safe(&y)
                })
            })
        };
        let default = band(DataOptions::default().unsafe_band);
        let (left, widths) = default.notes.left_out.clone().unwrap();
        assert!(widths.iter().all(|w| (w - 0.2).abs() < 1e-12), "{widths:?}");
        let inside = kept(&default);
        assert!(!inside.is_empty() && left > 0);
        assert!(inside.iter().all(|x| near(x, 0.2)));
        // A sample three spacings deep in the obstacle, on the grid, is left out.
        assert!(!inside
            .iter()
            .any(|x| (x[0] - 2.0).abs() < 1e-9 && x[1].abs() < 0.7));
        let wide = band(UnsafeBand::Within(0.5));
        assert!(kept(&wide).len() > inside.len());
        assert!(kept(&wide).iter().all(|x| near(x, 0.5)));
        let all = band(UnsafeBand::All);
        assert!(all.notes.left_out.is_none());
        assert_eq!(kept(&all).len(), default.summary.unsafe_samples);
    }
}
