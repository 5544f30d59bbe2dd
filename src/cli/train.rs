//! `cbfreach dataset` and `cbfreach train`: the surrogate network `N ≈ v`.

use std::io::IsTerminal;
use std::path::PathBuf;

use cbfreach::boxes::fmt_numbers;
use cbfreach::dataset::{filter_dataset, training_points, DatasetSummary, Slopes};
use cbfreach::filter::SafetyFilter;
use cbfreach::network::train::{
    self, EpochStats, RecipeProgress, SlopeCap, StagedCheckpoint, TrainSettings,
};
use cbfreach::network::Mlp;
use cbfreach::scenario::Scenario;
use cbfreach::training::{
    self, DataOptions, DataProgress, Dense, OneStage, StagedPlan, TrainingData, UnsafeBand,
};

use super::{load_scenario, progress_bar, CliResult};

/// Arguments of `cbfreach dataset`.
#[derive(clap::Args)]
pub struct DatasetArgs {
    /// The scenario file (TOML).
    pub scenario: PathBuf,
    /// Points per axis (default: the scenario's training grid).
    #[arg(long, value_delimiter = ',')]
    pub grid: Option<Vec<usize>>,
    /// Write the samples as CSV (x…, v…, Dv…) here.
    #[arg(long, short)]
    pub out: Option<PathBuf>,
}

/// Arguments of `cbfreach train`.
#[derive(clap::Args)]
pub struct TrainArgs {
    /// The scenario file (TOML).
    pub scenario: PathBuf,
    /// Points per axis of the training grid (default: the scenario's).
    #[arg(long, value_delimiter = ',')]
    pub grid: Option<Vec<usize>>,
    /// Layer widths, e.g. 2,64,64,2 (default: the scenario's architecture).
    #[arg(long, value_delimiter = ',')]
    pub architecture: Option<Vec<usize>>,
    /// Run one stage of this many passes over the data, with the tuning flags below, instead
    /// of the default staged schedule (fit, secant, certify; docs/networks.md) that stops at
    /// the scenario's `[training] target`. The tuning flags below (rates, batch, terms) apply
    /// only with it, and are refused without it.
    #[arg(long)]
    pub epochs: Option<usize>,
    /// Multiplies every stage's epochs of the default schedule (e.g. 0.25 for a quick run).
    #[arg(long, default_value_t = 1.0, conflicts_with = "epochs")]
    pub budget: f64,
    /// With `--epochs`: train on the data as it is, not normalised (the runs of
    /// docs/networks.md were made so).
    #[arg(long, requires = "epochs")]
    pub no_normalise: bool,
    /// Samples per Adam step. Large batches make an epoch much cheaper (scenario 1 on two
    /// cores: 3.5–4 s at 4096 with `--chunk-size 512`, 10–13 s at 256); fine-tunes at 4096 did
    /// as well as at 256 (README).
    #[arg(long, default_value_t = 256, requires = "epochs")]
    pub batch_size: usize,
    /// Samples per gradient chunk: a batch's chunks run side by side on the cores and their
    /// gradients are added in a fixed order, so a seed gives the same network on any number of
    /// threads (but not with another chunk size). `--chunk-size` ≥ `--batch-size` reproduces
    /// runs made before chunks existed.
    #[arg(long, default_value_t = 128, requires = "epochs")]
    pub chunk_size: usize,
    /// Initial learning rate (cosine decay to `--lr-min`).
    #[arg(long, default_value_t = 1e-3, requires = "epochs")]
    pub lr: f64,
    /// Final learning rate. A fine-tune (`--init`) starts Adam afresh, and its first steps move
    /// every weight by about `--lr`: start it near where the previous run ended.
    #[arg(long, default_value_t = 1e-5, requires = "epochs")]
    pub lr_min: f64,
    /// Weight λ of the Jacobian term λ‖DN − Dv‖² (0 disables).
    #[arg(long, default_value_t = 0.1, requires = "epochs")]
    pub jacobian_weight: f64,
    /// Leave samples whose target slope |∂vᵢ/∂xⱼ| exceeds this out of the Jacobian term (where
    /// v jumps, e.g. scenario 2 at (1, 0) and (3, 0), finite-difference slopes are ~1/step).
    /// Without it the staged schedule leaves out those steeper than 3 times the grid's 99th
    /// percentile (in normalised units), one stage (`--epochs`) none.
    #[arg(long)]
    pub jacobian_cap: Option<f64>,
    /// Slope targets as secants over ±this step (one value or one per state) instead of the
    /// pointwise Jacobian: where `v` has a kink between grid points (scenario 1 near
    /// (4.1, 0.8), slope 0 on one side and ~20 on the other) no network meets both one-sided
    /// slopes, and their pull bends the fit's values; half the grid's spacing is a good start.
    #[arg(long, value_delimiter = ',', requires = "epochs")]
    pub slope_step: Option<Vec<f64>>,
    /// With `--slope-step`: the Sobolev term compares the network's own central differences
    /// over the same steps with the secant targets, instead of its pointwise Jacobian (which is
    /// constant on each linear region, so its loss cannot move where the ReLUs switch; the
    /// differences can). Five rows per sample against three: scenario 1's epoch at batch 4096
    /// takes 4.4 s against 3.5 s.
    #[arg(long, requires = "slope_step")]
    pub secant_network: bool,
    /// Huber threshold of the Jacobian term: slope residuals beyond it cost linearly, so the few
    /// samples on a steep kink do not steer every step.
    #[arg(long, requires = "epochs")]
    pub jacobian_huber: Option<f64>,
    /// Seed of the initial weights and the shuffles.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Fraction of the samples, those of largest loss in the previous epoch, revisited in each
    /// late epoch (0 disables).
    #[arg(long, default_value_t = 0.1, requires = "epochs")]
    pub hard_fraction: f64,
    /// Extra visits of each of those samples per late epoch.
    #[arg(long, default_value_t = 1, requires = "epochs")]
    pub hard_repeats: usize,
    /// Fraction of the epochs after which hard examples are revisited.
    #[arg(long, default_value_t = 0.5, requires = "epochs")]
    pub hard_start: f64,
    /// Weight λ_ibp of the certified-training term: λ_ibp times the mean IBP output width over
    /// the boxes [x − ε, x + ε] around each batch's inputs (0 disables).
    #[arg(long, default_value_t = 0.0, requires = "epochs")]
    pub ibp_weight: f64,
    /// Half-width ε of the IBP boxes: one value, or one per state.
    #[arg(
        long,
        value_delimiter = ',',
        default_value = "0.05",
        requires = "epochs"
    )]
    pub ibp_radius: Vec<f64>,
    /// Epoch (over the whole run, resumed epochs included) from which the IBP term is on.
    #[arg(long, default_value_t = 0, requires = "epochs")]
    pub ibp_start: usize,
    /// Epochs over which ε ramps up linearly from the IBP start.
    #[arg(long, default_value_t = 0, requires = "epochs")]
    pub ibp_ramp: usize,
    /// Penalise only the IBP width in excess of the network's own linear range over each box,
    /// Σⱼ |∂N/∂xⱼ(x)| 2εⱼ: the plain width also penalises the slope that v needs.
    #[arg(long, requires = "epochs")]
    pub ibp_excess: bool,
    /// Every this many epochs, give the hidden neurons that no training sample activates fresh
    /// incoming weights and zero outgoing ones (the network's function is unchanged): dead
    /// ReLUs get no gradient, and without this the paper-size networks lose most of their
    /// deeper neurons early in training. 0 disables.
    #[arg(long, default_value_t = 0, requires = "epochs")]
    pub revive_every: usize,
    /// Train on the unsafe part of the grid only within this distance of S, in the states'
    /// units (checked along the axes at the distance and half of it); default two grid
    /// spacings of each axis, 0.3 with `--epochs` (as docs/networks.md's runs were made). Deep inside an obstacle `v` grows without bound where
    /// `L_g h → 0`, and those points would drag the fit. Negative: keep every feasible point.
    #[arg(long, allow_negative_numbers = true)]
    pub unsafe_band: Option<f64>,
    /// Add samples around the grid points of S where `v` is steep (some |∂vᵢ/∂xⱼ| above this,
    /// none above `--jacobian-cap`, which marks jumps):
    /// the points of S on a grid `--dense-factor` times finer within one spacing of each, so
    /// that the network sees the shape of kinks and jumps that the grid does not resolve.
    #[arg(long)]
    pub dense_slope: Option<f64>,
    /// How many times finer per axis the added samples are than the training grid.
    #[arg(long, default_value_t = 4, value_parser = |s: &str| super::whole_at_least(s, 2))]
    pub dense_factor: usize,
    /// Weigh the samples in this box (LOWER:UPPER, e.g. the goal set -0.5,-0.5:0.5,0.5) by
    /// `--focus-weight` in both loss terms: near the goal `v` is often 0 and the tubes must
    /// contract there, which a small slope error of the network already prevents.
    #[arg(long)]
    pub focus_box: Option<String>,
    /// Weight of the samples in `--focus-box`.
    #[arg(long, default_value_t = 10.0)]
    pub focus_weight: f64,
    /// Save the weights as F32 (exact: the trainer works in f32) instead of F64.
    #[arg(long)]
    pub f32: bool,
    /// Start from this network (safetensors) instead of random weights, with fresh Adam
    /// moments and the full learning-rate schedule (fine-tuning); ignored when resuming.
    #[arg(long)]
    pub init: Option<PathBuf>,
    /// Continue an interrupted run from its checkpoint beside the output file (`NAME.ckpt`):
    /// the staged schedule from its last stage and epochs (also where a newer cbfreach's
    /// schedule adds stages at its end: it runs on into them), or one stage (`--epochs`) from
    /// its epochs. Without it the staged schedule refuses to start over such a file.
    #[arg(long)]
    pub resume: bool,
    /// Where to write the network (default: the scenario's network file).
    #[arg(long, short)]
    pub out: Option<PathBuf>,
}

/// The filter's sampling, one progress bar per data set.
#[derive(Default)]
struct Bars(std::sync::Mutex<Option<indicatif::ProgressBar>>);

impl DataProgress for Bars {
    fn begin(&self, what: &str, points: usize) {
        if let Ok(mut bar) = self.0.lock() {
            *bar = Some(progress_bar(points as u64, what));
        }
    }
    fn done(&self, points: usize) {
        if let Ok(Some(bar)) = self.0.lock().as_deref() {
            bar.set_position(points as u64);
        }
    }
    fn end(&self) {
        if let Ok(Some(bar)) = self.0.lock().as_deref() {
            bar.finish_and_clear();
        }
    }
}

fn print_summary(s: &Scenario, d: &DatasetSummary) {
    // A high-order CBF's QP is infeasible wherever ψ < 0, outside S: say whether S is clear.
    let where_ = match (d.infeasible, d.infeasible_in_s) {
        (0, _) => String::new(),
        (_, 0) => " (all outside S)".to_string(),
        (_, k) => format!(" ({k} of them in S)"),
    };
    println!(
        "{}: {} grid points, {} samples ({} outside S, {} where the filter acts), {} infeasible skipped{where_}",
        s.file, d.grid_points, d.samples, d.unsafe_samples, d.active_samples, d.infeasible
    );
}

/// Runs `cbfreach dataset`.
pub fn run_dataset(args: &DatasetArgs) -> CliResult {
    let s = load_scenario(&args.scenario)?;
    super::check_outputs(&[args.out.as_deref()])?;
    let points = training_points(&s, args.grid.as_ref())?;
    let filter = SafetyFilter::new(&s);
    let bars = Bars::default();
    bars.begin("filter on the grid", points.len());
    let (data, summary) = filter_dataset(&filter, &points, &Slopes::Pointwise, &|done| {
        bars.done(done)
    });
    bars.end();
    print_summary(&s, &summary);
    if let Some(path) = &args.out {
        let mut text = String::new();
        let names: Vec<String> = s
            .states
            .iter()
            .cloned()
            .chain(s.inputs.iter().map(|u| format!("v_{u}")))
            .chain(
                s.inputs
                    .iter()
                    .flat_map(|u| s.states.iter().map(move |x| format!("d{u}_d{x}"))),
            )
            .collect();
        text.push_str(&names.join(","));
        text.push('\n');
        let (n, m) = (s.n(), s.m());
        for k in 0..data.len() {
            let mut row: Vec<String> = data.inputs[k * n..(k + 1) * n]
                .iter()
                .map(f64::to_string)
                .collect();
            row.extend(data.targets[k * m..(k + 1) * m].iter().map(f64::to_string));
            if let Some(j) = &data.jacobians {
                row.extend(j[k * m * n..(k + 1) * m * n].iter().map(f64::to_string));
            }
            text.push_str(&row.join(","));
            text.push('\n');
        }
        cbfreach::output::write_atomic(path, text.as_bytes())
            .map_err(|e| format!("{}: {e}", path.display()))?;
        println!("samples written to {}", path.display());
    }
    Ok(())
}

/// Runs `cbfreach train`.
pub fn run_train(args: &TrainArgs) -> CliResult {
    if !(args.budget.is_finite() && args.budget > 0.0) {
        return Err(format!("--budget {}: expected a finite factor > 0", args.budget).into());
    }
    let s = load_scenario(&args.scenario)?;
    let architecture = training::architecture(&s, args.architecture.as_deref())?;
    let out = match (&args.out, &s.network) {
        (Some(p), _) => p.clone(),
        (None, Some(net)) => net.file.clone(),
        (None, None) => return Err("give --out FILE".into()),
    };
    // The network and its checkpoint (beside it) are written after the work: checked now.
    super::check_outputs(&[Some(&out)])?;
    let progress = out.with_extension("ckpt");
    if args.epochs.is_none() && !args.resume && progress.exists() {
        return Err(format!(
            "{} holds the progress of an interrupted run: `--resume` continues it; remove the file to start afresh",
            progress.display()
        )
        .into());
    }
    let options = data_options(args, &s)?;
    let bars = Bars::default();
    let data = TrainingData::sample(&s, &options, &bars)?;
    if let (Some((added, seeds)), Some(dense)) = (data.notes.dense, &options.dense) {
        println!(
            "{added} samples {}× finer added around the {seeds} grid points of S where some |∂vᵢ/∂xⱼ| > {}{}",
            dense.factor,
            dense.slope,
            args.jacobian_cap
                .map_or(String::new(), |cap| format!(" and none > {cap} (a jump)"))
        );
    }
    print_summary(&s, &data.summary);
    // `check` says the rest of the filter's findings; an inert CBF makes the training moot.
    for inert in cbfreach::filter::inert_cbfs(&s)
        .iter()
        .filter(|i| i.kept_by.is_none())
    {
        println!("warning: {}", super::check::inert_note(&s, inert));
    }
    if let Some((excluded, band)) = &data.notes.left_out {
        let band: Vec<String> = band.iter().map(|b| format!("{b:.4}")).collect();
        println!(
            "{excluded} unsafe samples farther from S than ({}) along every axis left out of the training{}",
            band.join(", "),
            match options.unsafe_band {
                UnsafeBand::Spacings(k) => format!(" ({k} grid spacings: --unsafe-band sets a distance)"),
                _ => String::new(),
            }
        );
    }
    if let Some(count) = data.notes.focused {
        println!(
            "{count} samples in the focus box weigh {}",
            args.focus_weight
        );
    }
    let init = args
        .init
        .as_deref()
        .map(|path| Mlp::load_safetensors(path).map(|net| (path, net)))
        .transpose()?;
    let init = init.as_ref().map(|(path, net)| (*path, net));
    let job = Job {
        args,
        s: &s,
        architecture: &architecture,
        out: &out,
        data: &data,
        init,
    };
    match args.epochs {
        None => run_staged(&job, &bars),
        Some(epochs) => run_one_stage(&job, epochs),
    }
}

/// What both ways of training share.
struct Job<'a> {
    args: &'a TrainArgs,
    s: &'a Scenario,
    architecture: &'a [usize],
    /// Where the network goes.
    out: &'a std::path::Path,
    data: &'a TrainingData,
    /// The network to start from, and its file.
    init: Option<(&'a std::path::Path, &'a Mlp)>,
}

/// The data options the flags give, each flag's value checked.
fn data_options(args: &TrainArgs, s: &Scenario) -> Result<DataOptions, String> {
    let slopes = match &args.slope_step {
        None => Slopes::Pointwise,
        Some(h) if h.len() == 1 || h.len() == s.n() => {
            if let Some(bad) = h.iter().find(|h| !(h.is_finite() && **h > 0.0)) {
                return Err(format!("--slope-step {bad}: expected a finite step > 0"));
            }
            Slopes::Secant(h.clone())
        }
        Some(h) => {
            return Err(format!(
                "--slope-step: {} values, expected one or one per state ({})",
                h.len(),
                s.n()
            ))
        }
    };
    let dense = match args.dense_slope {
        Some(slope) if !(slope.is_finite() && slope >= 0.0) => {
            return Err(format!(
                "--dense-slope {slope}: expected a finite slope ≥ 0"
            ))
        }
        Some(slope) => Some(Dense {
            slope,
            factor: args.dense_factor,
        }),
        None => None,
    };
    let focus = match &args.focus_box {
        Some(text) => {
            let focus = super::simulate::parse_box("--focus-box", text, s.n())?;
            if !(args.focus_weight.is_finite() && args.focus_weight > 0.0) {
                return Err(format!(
                    "--focus-weight {}: expected a finite weight > 0",
                    args.focus_weight
                ));
            }
            Some((focus, args.focus_weight))
        }
        None => None,
    };
    Ok(DataOptions {
        grid: args.grid.clone(),
        slopes,
        dense,
        jacobian_cap: args.jacobian_cap,
        unsafe_band: match (args.unsafe_band, args.epochs) {
            (None, None) => DataOptions::default().unsafe_band,
            (None, Some(_)) => UnsafeBand::ONE_STAGE,
            (Some(d), _) if d < 0.0 => UnsafeBand::All,
            (Some(d), _) => UnsafeBand::Within(d),
        },
        focus,
    })
}

/// `cbfreach train --epochs N`: one stage of the flags' settings.
fn run_one_stage(job: &Job, epochs: usize) -> CliResult {
    let Job {
        args,
        s,
        architecture,
        out,
        data,
        init,
    } = *job;
    let checkpoint = out.with_extension("ckpt");
    let settings = TrainSettings {
        epochs,
        batch_size: args.batch_size,
        chunk_size: args.chunk_size,
        learning_rate: args.lr,
        lr_min: args.lr_min,
        jacobian_weight: args.jacobian_weight,
        jacobian_cap: args.jacobian_cap,
        jacobian_huber: args.jacobian_huber,
        seed: args.seed,
        hard_example_fraction: args.hard_fraction,
        hard_example_repeats: args.hard_repeats,
        hard_example_start: args.hard_start,
        ibp_weight: args.ibp_weight,
        ibp_radius: args.ibp_radius.clone(),
        ibp_start: args.ibp_start,
        ibp_ramp: args.ibp_ramp,
        ibp_excess: args.ibp_excess,
        revive_every: args.revive_every,
        secant_step: match &args.slope_step {
            Some(h) if args.secant_network => Some(h.clone()),
            _ => None,
        },
        checkpoint: Some(checkpoint.clone()),
        ..TrainSettings::default()
    };
    let bar = progress_bar(epochs as u64, "epochs");
    // A run takes minutes to hours: where the bar is hidden (stderr to a log file, a batch
    // job), a line per epoch takes its place.
    let logged = !std::io::stderr().is_terminal();
    let progress = |e: &EpochStats| {
        bar.set_position(e.epoch as u64);
        let ibp = e
            .ibp_width
            .map_or(String::new(), |w| format!(", IBP width {w:.4}"));
        let revived = match e.revived {
            0 => String::new(),
            n => format!(", {n} dormant neurons revived"),
        };
        bar.set_message(format!(
            "loss {:.3e}, max error {:.4}{ibp}",
            e.loss, e.max_error
        ));
        if logged {
            eprintln!(
                "epoch {}/{}: loss {:.4e}, max error {:.4}, mean error {:.4}{ibp}, lr {:.2e}, {:.1} s{revived}",
                e.epoch, e.epochs, e.loss, e.max_error, e.mean_error, e.lr, e.seconds
            );
        }
    };
    let start = OneStage {
        normalise: !args.no_normalise,
        init,
        resume: args.resume.then_some(checkpoint),
        f32: args.f32,
    };
    let run = training::train_one_stage(s, data, architecture, &settings, start, progress)?;
    bar.finish_and_clear();
    run.trained.save(out)?;
    let net = &run.trained.net;
    println!(
        "trained {} in {:.1} s ({} epochs): training max ℓ∞ error {:.4}",
        net.architecture(),
        run.report.seconds,
        run.report.epochs.len(),
        run.training.max_error
    );
    if let Some(w) = run.report.epochs.last().and_then(|e| e.ibp_width) {
        println!(
            "mean IBP output width of the last epoch (ε = {:?}): {w:.4}",
            args.ibp_radius
        );
    }
    let val = &run.validation;
    println!(
        "validation on {} unseen points of C ∩ S: max ℓ∞ {:.4}, max ℓ2 {:.4}, mean ℓ∞ {:.4}, max slope error {:.3}",
        data.validation_summary.samples,
        val.max_error,
        val.max_error_l2,
        val.mean_error,
        val.max_slope_error.unwrap_or(f64::NAN)
    );
    println!("network written to {}", out.display());
    Ok(())
}

/// `cbfreach train` without `--epochs`: the default staged schedule to the scenario's target.
fn run_staged(job: &Job, bars: &Bars) -> CliResult {
    let Job {
        args,
        s,
        architecture,
        out,
        data,
        init,
    } = *job;
    let mut plan = StagedPlan::new(s, data, architecture, args.budget, args.seed);
    if let Some(cap) = args.jacobian_cap {
        plan.recipe.slope_cap = SlopeCap::Above(cap);
    }
    let (recipe, target) = (&plan.recipe, &plan.target);
    let total: usize = recipe.stages.iter().map(|st| st.settings.epochs).sum();
    let ibp = match recipe.stages[0].settings.ibp_weight > 0.0 {
        true => format!(
            "; the IBP term from the fit stage, {} hidden layers",
            train::hidden_layers(architecture)
        ),
        false => String::new(),
    };
    println!(
        "schedule: {} (batch {}{ibp}), target {}",
        recipe
            .stages
            .iter()
            .map(|st| format!("{} {}", st.name, st.settings.epochs))
            .collect::<Vec<_>>()
            .join(", "),
        recipe.stages[0].settings.batch_size,
        target
    );
    print_resolution(&plan.resolution, target.linf);
    // The running figure and the target's are measured on different points: say which.
    println!(
        "progress: 'training max' is the largest error on the training samples as each was visited{}; \
         'last measured' is on unseen points of C ∩ S, the figure the target speaks of",
        match data.summary.unsafe_samples {
            0 => String::new(),
            k => format!(" ({k} of them outside S, where no target applies)"),
        }
    );
    let checkpoint = StagedCheckpoint {
        path: out.with_extension("ckpt"),
        resume: args.resume,
    };
    match (checkpoint.path.exists(), args.resume) {
        (true, true) => println!(
            "resuming from {} (the stages done and the current stage's epochs)",
            checkpoint.path.display()
        ),
        // Refused in run_train.
        (true, false) => {}
        (false, true) => println!(
            "no checkpoint at {}: starting afresh",
            checkpoint.path.display()
        ),
        (false, false) => println!(
            "progress kept in {} after every stage and every 10 epochs: `--resume` continues an interrupted run",
            checkpoint.path.display()
        ),
    }
    let bar = progress_bar(total as u64, "fit");
    let logged = !std::io::stderr().is_terminal();
    let offsets: Vec<usize> = recipe
        .stages
        .iter()
        .scan(0, |acc, st| {
            let start = *acc;
            *acc += st.settings.epochs;
            Some(start)
        })
        .collect();
    let mut last_logged = None;
    let progress = |p: &RecipeProgress| {
        bar.set_position((offsets[p.stage_index] + p.epoch) as u64);
        let measured = p.measured.map_or(String::new(), |m| {
            format!(
                " | last measured: max ℓ∞ {:.4}, slope p95 {:.3}, IBP {:.2}×",
                m.linf, m.slope_p95, m.ibp_looseness
            )
        });
        bar.set_message(format!(
            "{} ({}/{}) {} samples, training max {:.4}{measured}",
            p.stage,
            p.stage_index + 1,
            p.stages,
            p.samples,
            p.max_error
        ));
        // Without a terminal, a line where the figures change and at every tenth of a stage:
        // certify stages measure at their end only, and can run for an hour. (A refine stage
        // whose round added nothing reports at its last epoch with no training max: no line.)
        let tenth = (p.epochs / 10).max(1);
        let trained = !p.max_error.is_nan();
        if logged && trained && (p.measured != last_logged || p.epoch.is_multiple_of(tenth)) {
            last_logged = p.measured;
            eprintln!(
                "{} epoch {}/{}: {} samples, training max {:.4}{measured}",
                p.stage, p.epoch, p.epochs, p.samples, p.max_error
            );
        }
    };
    let run = plan.run(
        s,
        data,
        architecture,
        init,
        args.seed,
        args.f32,
        Some(&checkpoint),
        bars,
        progress,
    )?;
    bar.finish_and_clear();
    run.trained.save(out)?;
    // The network is on disk: its progress is no longer needed.
    checkpoint.remove(recipe.stages.len());
    let (report, measured) = (&run.report, &run.measured);
    let norm = &report.normalisation;
    println!(
        "normalised: inputs centre {} scale {}; outputs centre {} scale {}; learning rate {:.0e} \
         (range test)",
        fmt_numbers(&norm.input_centre),
        fmt_numbers(&norm.input_scale),
        fmt_numbers(&norm.output_centre),
        fmt_numbers(&[norm.output_scale]),
        report.learning_rate
    );
    print_steep(&report.steep, recipe.slope_cap);
    if let Some(k) = report.extended_from {
        println!(
            "continued a run begun under an earlier schedule of {k} stages into this one's {}",
            recipe.stages.len()
        );
    }
    // Whether the target held before each stage: a certify stage is dropped for breaking it, or
    // (short of it) for errors grown by over 10 %.
    let mut met_before = false;
    for st in &report.stages {
        let dropped = match (st.kept, met_before) {
            (true, _) => "",
            (false, true) => " (not kept: the target broke)",
            (false, false) => " (not kept: the errors grew by over 10 %)",
        };
        if st.kept {
            met_before = target.met(&st.measured);
        }
        if let Some(r) = &st.round {
            let at: Vec<String> = r.at.iter().map(|x| format!("{x:.4}")).collect();
            println!(
                "  {}: on {} fresh points of C ∩ S max ℓ∞ {:.4} at ({}), {} above the target; {} samples added around the worst",
                st.name,
                r.scored,
                r.max_error,
                at.join(", "),
                r.above,
                r.added
            );
        }
        println!(
            "  {}: {} epochs, {:.1} s: max ℓ∞ {:.4}, mean {:.4}, slope p95 {:.3}, IBP looseness {:.2}×{}",
            st.name,
            st.epochs,
            st.seconds,
            st.measured.linf,
            st.measured.mean,
            st.measured.slope_p95,
            st.measured.ibp_looseness,
            dropped
        );
    }
    println!(
        "{} {} in {:.1} s ({} training samples) on {} unseen points of C ∩ S: max ℓ∞ {:.4}, mean {:.4}, slope p95 {:.3}, IBP looseness {:.2}×",
        if report.reached { "target reached:" } else { "target NOT reached:" },
        run.trained.net.architecture(),
        report.seconds,
        report.samples,
        data.validation.len(),
        measured.linf,
        measured.mean,
        measured.slope_p95,
        measured.ibp_looseness
    );
    if let Some(r) = &report.fresh {
        println!(
            "  on {} fresh points of C ∩ S never trained on: max ℓ∞ {:.4} at ({}){}",
            r.scored,
            r.max_error,
            r.at.iter()
                .map(|x| format!("{x:.4}"))
                .collect::<Vec<_>>()
                .join(", "),
            target.linf.map_or(String::new(), |t| format!(
                ", {} above the target {t}",
                r.above
            ))
        );
    }
    if let (false, Some(t)) = (report.reached, target.linf) {
        let grid = match plan.resolution.max > t {
            true => format!(
                " (the grid itself resolves v only to {:.4})",
                plan.resolution.max
            ),
            false => String::new(),
        };
        match report.training_fit {
            // The network misses the very points it was trained on: more data alone will not
            // help (the refine stages already sample where it errs).
            Some(fit) if fit > t => println!(
                "  it misses its own training samples in C ∩ S by up to {fit:.4} (above the target): the network is too small (or too little trained) for v here, so a larger [network] architecture comes before more data{grid}"
            ),
            Some(fit) => println!(
                "  it fits its own training samples in C ∩ S to {fit:.4}, and misses between them{grid}: a finer [training] grid"
            ),
            None if plan.resolution.max > t => println!(
                "  the grid itself resolves v only to {:.4} (above), and the refine stages' samples did not close the gap: a larger network or a finer [training] grid",
                plan.resolution.max
            ),
            None => {}
        }
    }
    println!("network written to {}", out.display());
    Ok(())
}

/// One line on the slope targets left out of the Sobolev term, where any were.
fn print_steep(r: &train::SteepReport, cap: SlopeCap) {
    if r.pointwise_left_out + r.secant_left_out == 0 {
        return;
    }
    let why = match cap {
        SlopeCap::Above(c) => format!("with some |∂vᵢ/∂xⱼ| above {c} (--jacobian-cap)"),
        SlopeCap::Outliers(factor) => format!(
            "steeper than {factor} times the grid's 99th percentile (bounds in normalised units: {}), jumps of v or kinks the grid does not resolve",
            [("pointwise", r.pointwise_limit), ("secant", r.secant_limit)]
                .iter()
                .filter_map(|(k, l)| l.map(|l| format!("{k} {l:.2}")))
                .collect::<Vec<_>>()
                .join(", ")
        ),
        SlopeCap::Off => return,
    };
    println!(
        "slope targets left out of the slope term (their values still trained on): {} pointwise and {} secant samples {why}",
        r.pointwise_left_out, r.secant_left_out
    );
}

/// One line on how finely the training grid resolves `v` (its own multilinear interpolant at
/// the validation points), and a warning where that is coarser than the target.
fn print_resolution(r: &train::Resolution, linf: Option<f64>) {
    if r.points == 0 {
        return;
    }
    let at: Vec<String> = r.at.iter().map(|x| format!("{x:.4}")).collect();
    println!(
        "grid resolution: the training grid's own multilinear interpolant misses v by up to {:.4} at ({}) on {} validation points{}",
        r.max,
        at.join(", "),
        r.points,
        linf.map_or(String::new(), |t| format!(" ({} above the target {t})", r.above))
    );
    if linf.is_some_and(|t| r.max > t) {
        println!(
            "  v changes between the grid's points by more than the target: the refine stages sample it where the network errs most"
        );
    }
}
