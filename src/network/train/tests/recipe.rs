//! Normalisation (fold, unfold, the saved file), early stopping and the staged recipe.

use super::*;

/// `smooth_data` in badly scaled units: inputs `x ↦ (500 x + 2000, 0.01 x)`, targets `× 1000
/// + 50`, slopes accordingly.
fn badly_scaled(k: usize) -> Dataset {
    let mut d = smooth_data(k);
    for x in d.inputs.chunks_exact_mut(2) {
        x[0] = 500.0 * x[0] + 2000.0;
        x[1] *= 0.01;
    }
    for v in &mut d.targets {
        *v = 1000.0 * *v + 50.0;
    }
    for dv in d.jacobians.as_mut().expect("slopes").chunks_exact_mut(2) {
        dv[0] *= 1000.0 / 500.0;
        dv[1] *= 1000.0 / 0.01;
    }
    d
}

/// A recipe's data with pointwise slopes alone (no secant set), and the refine stages' oracle
/// where one is given.
fn values_only<'a>(
    data: &'a Dataset,
    validation: &'a Dataset,
    oracle: Option<&'a dyn Oracle>,
) -> RecipeData<'a> {
    RecipeData {
        pointwise: data,
        secant: None,
        validation,
        oracle,
    }
}

/// [`train_to_target`] from a fresh network of `widths` (seed 1), with no checkpoint and no
/// progress: how most tests run the recipe.
fn train_fresh(
    widths: &[usize],
    input: &RecipeData,
    recipe: &Recipe,
    target: &Target,
) -> (Mlp, RecipeReport) {
    train_to_target(None, widths, 1, input, recipe, target, None, |_| {}).expect("trains")
}

#[test]
fn normalised_data_are_unit_scaled_and_the_folded_network_is_the_normalised_model() {
    let data = badly_scaled(9);
    let norm = Normalisation::from_data(&data);
    let unit = norm.dataset(&data, None).expect("fits");
    assert!(unit.inputs.iter().all(|x| (-1.0..=1.0).contains(x)));
    assert!(unit.inputs.contains(&-1.0) && unit.inputs.contains(&1.0));
    let spread = unit.targets.iter().fold(0.0f64, |a, v| a.max(v.abs()));
    assert!(
        (0.5..5.0).contains(&spread),
        "normalised targets up to {spread}"
    );

    let normalised = Mlp::random(&[2, 8, 8, 2], 3);
    let folded = norm.fold(&normalised).expect("fits");
    for x in data.inputs.chunks_exact(2).step_by(7) {
        let xn: Vec<f64> = (0..2)
            .map(|j| (x[j] - norm.input_centre[j]) / norm.input_scale[j])
            .collect();
        let expected: Vec<f64> = normalised
            .forward(&xn)
            .iter()
            .zip(&norm.output_centre)
            .map(|(y, c)| c + norm.output_scale * y)
            .collect();
        for (a, b) in folded.forward(x).iter().zip(&expected) {
            assert!(
                (a - b).abs() <= 1e-9 * (1.0 + b.abs()),
                "{a} against {b} at {x:?}"
            );
        }
    }
    // Value errors scale by the one output scale; slopes are the same after the change of units.
    let phys = evaluate(&folded, &data).expect("fits");
    let unit_errors = evaluate(&normalised, &unit).expect("fits");
    let ratio = phys.max_error / (norm.output_scale * unit_errors.max_error);
    assert!((ratio - 1.0).abs() < 1e-9, "ratio {ratio}");
    // unfold inverts fold.
    let back = norm.unfold(&folded).expect("fits");
    for (l, m) in back.layers.iter().zip(&normalised.layers) {
        for (a, b) in l
            .weight
            .iter()
            .chain(&l.bias)
            .zip(m.weight.iter().chain(&m.bias))
        {
            assert!((a - b).abs() < 1e-9, "{a} against {b}");
        }
    }
    // The exported file is a plain MLP giving the same outputs, with the maps as metadata.
    let bytes = folded
        .to_safetensors_bytes(&norm.metadata())
        .expect("serialises");
    let path = std::env::temp_dir().join(format!("normalised-{}.safetensors", std::process::id()));
    std::fs::write(&path, bytes).expect("writes");
    let (loaded, metadata) = Mlp::load_safetensors_with_metadata(&path).expect("loads");
    std::fs::remove_file(&path).ok();
    assert_eq!(loaded, folded);
    assert_eq!(
        Normalisation::from_metadata(&metadata).expect("parses"),
        Some(norm)
    );
}

#[test]
fn a_slope_cap_in_the_data_units_marks_samples_without_slope_targets() {
    let data = badly_scaled(5);
    let norm = Normalisation::from_data(&data);
    let unit = norm
        .dataset(&data, Some(SlopeLimit::Data(50.0)))
        .expect("fits");
    unit.validate().expect("NaN slopes are allowed");
    let k = data.n_in * data.n_out;
    let jac = data.jacobians.as_ref().expect("slopes");
    let ujac = unit.jacobians.as_ref().expect("slopes");
    let (mut capped, mut kept) = (0, 0);
    for s in 0..data.len() {
        let steep = jac[s * k..(s + 1) * k].iter().any(|d| d.abs() > 50.0);
        let nan = ujac[s * k..(s + 1) * k].iter().all(|d| d.is_nan());
        assert_eq!(steep, nan, "sample {s}");
        capped += usize::from(nan);
        kept += usize::from(!nan);
        assert_eq!(slope_target(&unit, s, None).is_some(), !steep);
    }
    assert!(capped > 0 && kept > 0, "{capped} capped, {kept} kept");
}

/// Where `v` jumps, a few slope targets of order `jump / step` outweigh every other sample
/// under a squared loss (scenario 2's secant stage went from max error 1.25 to 3.2): the
/// staged schedule leaves the outliers out of the slope term by default and trains their
/// values as before.
#[test]
fn the_recipe_leaves_slope_outliers_out_and_fits_better_for_it() {
    let mut data = smooth_data(30);
    // Six samples (under 1 %: a jump is a curve, a thin share of a grid) get the slope target
    // of a jump of 1 over a step of 10⁻⁴.
    let k = data.n_in * data.n_out;
    let jumps: Vec<usize> = (0..data.len()).filter(|s| s % 150 == 7).collect();
    for &s in &jumps {
        data.jacobians.as_mut().expect("slopes")[s * k..(s + 1) * k]
            .copy_from_slice(&[1e4, 0.0, 0.0, 0.0]);
    }
    let validation = smooth_data(17);
    let input = values_only(&data, &validation, None);
    let target = Target {
        linf: Some(1e-6),
        slope_p95: None,
    };
    let run = |cap: SlopeCap| {
        let mut recipe = Recipe::for_data(data.len(), &[2.0 / 29.0; 2], 0.05, 1);
        recipe.slope_cap = cap;
        train_fresh(&[2, 16, 16, 2], &input, &recipe, &target).1
    };
    let capped = run(Recipe::for_data(1, &[1.0], 1.0, 1).slope_cap);
    assert_eq!(
        capped.steep.pointwise_left_out,
        jumps.len(),
        "{:?}",
        capped.steep
    );
    assert!(capped.steep.pointwise_limit.is_some());
    let uncapped = run(SlopeCap::Off);
    assert_eq!(uncapped.steep.pointwise_left_out, 0);
    // The six samples' pull wrecks the fit of the other 894.
    assert!(
        capped.measured.linf < 0.5 * uncapped.measured.linf,
        "max error {} with the cap, {} without",
        capped.measured.linf,
        uncapped.measured.linf
    );
}

#[test]
fn train_until_stops_when_told() {
    let data = smooth_data(9);
    let mut seen = 0;
    let (_, report) = train_until(
        Mlp::random(&[2, 8, 2], 1),
        &data,
        &quick(50, 0.0),
        |e, net| {
            seen += 1;
            assert_eq!(net().input_dim(), 2);
            if e.epoch == 3 {
                Flow::Stop
            } else {
                Flow::Continue
            }
        },
    )
    .expect("trains");
    assert_eq!((report.epochs.len(), seen), (3, 3));
}

#[test]
fn the_recipe_stops_at_its_target_and_says_when_it_is_not_reached() {
    let data = badly_scaled(40);
    let validation = badly_scaled(17);
    let recipe = Recipe::for_data(data.len(), &[1000.0 / 39.0, 0.02 / 39.0], 0.5, 2);
    let planned = recipe.stages[0].settings.epochs;
    let input = values_only(&data, &validation, None);
    // Within 5 % of the targets' range (2000): the fit stage gets there and stops early.
    let target = Target {
        linf: Some(100.0),
        slope_p95: None,
    };
    let (net, report) = train_fresh(&[2, 16, 16, 2], &input, &recipe, &target);
    assert!(report.reached, "{report:?}");
    assert_eq!(report.stages[0].name, "fit");
    assert!(
        report.stages[0].epochs < planned,
        "{} of {planned} epochs",
        report.stages[0].epochs
    );
    assert!(report
        .stages
        .iter()
        .all(|s| s.name == "fit" || s.name.starts_with("certify")));
    let m = measure(&net, &validation, &recipe.ibp_radius).expect("measures");
    assert!(m.linf <= 100.0 && (m.linf - report.measured.linf).abs() < 1e-9 * m.linf);
    // A target no network of this size meets: every stage runs in full, and it is said.
    let target = Target {
        linf: Some(1e-6),
        slope_p95: None,
    };
    let small = Recipe::for_data(data.len(), &[1000.0 / 39.0, 0.02 / 39.0], 0.02, 1);
    let (_, report) = train_fresh(&[2, 8, 2], &input, &small, &target);
    assert!(!report.reached);
    assert_eq!(report.stages[0].epochs, small.stages[0].settings.epochs);
}

/// The IBP term is trained on the boxes the recipe measures its looseness on, in the data's
/// own units (the certify stages had taken the trainer's default half-width 0.05 in every
/// input: on ACC in newtons, metres and m/s the looseness rose through them), in the certify
/// stages, and from the first stage on networks of three or more hidden layers.
#[test]
fn the_ibp_term_is_trained_on_the_boxes_its_looseness_is_measured_on() {
    let spacing = [1000.0 / 39.0, 0.02 / 39.0];
    for hidden in [1, 2, DEEP_HIDDEN_LAYERS, DEEP_HIDDEN_LAYERS + 1] {
        let recipe = Recipe::for_data(1600, &spacing, 1.0, hidden);
        assert_eq!(recipe.ibp_radius, spacing.map(|h| 2.0 * h).to_vec());
        let certify = |s: &Stage| matches!(s.kind, StageKind::Certify(_));
        assert_eq!(
            recipe.stages.iter().filter(|s| certify(s)).count(),
            CERTIFY_WEIGHTS.len()
        );
        for stage in &recipe.stages {
            // Deep networks train the term from the first stage (the looseness compounds
            // layer by layer); shallow ones in the certify stages only.
            let on = certify(stage) || hidden >= DEEP_HIDDEN_LAYERS;
            assert_eq!(
                stage.settings.ibp_weight > 0.0,
                on,
                "{} ({hidden})",
                stage.name
            );
            if on {
                assert_eq!(
                    stage.settings.ibp_radius, recipe.ibp_radius,
                    "{}",
                    stage.name
                );
            }
        }
    }
}

/// `v(x) = x₁ + 2 max(0, 0.1 − |x₁ − 0.375|)` on `[0, 1]²`: a bump of height 0.2 between the
/// lines x₁ = 0.25 and 0.5 of a 5 × 5 grid, which sees only `x₁`.
struct Bump;

fn bump(x: &[f64]) -> f64 {
    x[0] + 2.0 * (0.1 - (x[0] - 0.375).abs()).max(0.0)
}

impl Oracle for Bump {
    fn bounds(&self) -> (Vec<f64>, Vec<f64>) {
        (vec![0.0, 0.0], vec![1.0, 1.0])
    }
    fn judged(&self, _: &[f64]) -> bool {
        true
    }
    fn sample(&self, points: &[Vec<f64>], slopes: SampleSlopes) -> Dataset {
        let slope = |x: &[f64]| match x[0] - 0.375 {
            d if d.abs() >= 0.1 => 1.0,
            d if d < 0.0 => 3.0,
            _ => -1.0,
        };
        Dataset {
            n_in: 2,
            n_out: 1,
            inputs: points.iter().flatten().copied().collect(),
            targets: points.iter().map(|x| bump(x)).collect(),
            jacobians: (slopes != SampleSlopes::Values)
                .then(|| points.iter().flat_map(|x| [slope(x), 0.0]).collect()),
            weights: None,
        }
    }
}

/// The bump's data on a 5 × 5 grid, validation points between them, and a short recipe (fit,
/// refine and certify stages) whose rounds score `candidates` fresh points.
fn bump_run(candidates: usize) -> (Dataset, Dataset, Recipe) {
    let grid = |k: usize, offset: f64| -> Vec<Vec<f64>> {
        let h = 1.0 / (k - 1) as f64;
        (0..k * k)
            .map(|s| vec![offset + (s % k) as f64 * h, offset + (s / k) as f64 * h])
            .filter(|x| x[0] <= 1.0 && x[1] <= 1.0)
            .collect()
    };
    let data = Bump.sample(&grid(5, 0.0), SampleSlopes::Pointwise);
    let validation = Bump.sample(&grid(5, 0.125), SampleSlopes::Pointwise);
    let mut recipe = Recipe::for_data(data.len(), &[0.25, 0.25], 0.1, 2);
    recipe.refinement.candidates = candidates;
    recipe.stages.retain(|s| s.kind != StageKind::Secant);
    (data, validation, recipe)
}

#[test]
fn refine_stages_add_samples_where_the_network_errs_and_check_it_on_fresh_points() {
    let (data, validation, recipe) = bump_run(1024);
    let target = Target {
        linf: Some(0.05),
        slope_p95: None,
    };
    let input = values_only(&data, &validation, Some(&Bump));
    let (_, report) = train_fresh(&[2, 16, 16, 1], &input, &recipe, &target);
    let rounds: Vec<&RoundReport> = report
        .stages
        .iter()
        .filter_map(|s| s.round.as_ref())
        .collect();
    assert!(!rounds.is_empty(), "{report:?}");
    let added: usize = rounds.iter().map(|r| r.added).sum();
    assert!(
        added > 0 && report.samples == data.len() + added,
        "{report:?}"
    );
    // The first round's worst fresh point lies on the bump, which the grid does not show.
    assert!((rounds[0].at[0] - 0.375).abs() < 0.1, "{:?}", rounds[0]);
    assert!(rounds[0].max_error > 0.1, "{:?}", rounds[0]);
    let fresh = report.fresh.as_ref().expect("a last check with an oracle");
    assert_eq!((fresh.added, fresh.scored), (0, 1024), "{fresh:?}");
    assert!(!report.reached || fresh.max_error <= 0.05, "{report:?}");
    assert!(
        fresh.max_error < 0.5 * rounds[0].max_error,
        "fresh {fresh:?} against the first round {:?}",
        rounds[0]
    );
    // It fits the samples it was trained on, the bump's included, far closer than the
    // first round found it missing them.
    let fit = report.training_fit.expect("measured with an oracle");
    assert!(
        fit < 0.5 * rounds[0].max_error,
        "{fit} against {:?}",
        rounds[0]
    );
}

/// A network too small for `v` (one hidden neuron: one kink, where the bump has three) misses
/// the very samples the refine stages add on the bump, so `training_fit` is above the target:
/// the run can tell a user that a larger network, not more data, is what is missing.
#[test]
fn a_network_too_small_for_v_misses_its_own_training_samples() {
    let (data, validation, recipe) = bump_run(1024);
    let target = Target {
        linf: Some(0.05),
        slope_p95: None,
    };
    let input = values_only(&data, &validation, Some(&Bump));
    let (_, report) = train_fresh(&[2, 1, 1], &input, &recipe, &target);
    assert!(!report.reached, "{report:?}");
    assert!(report.samples > data.len(), "no samples added: {report:?}");
    let fit = report.training_fit.expect("measured with an oracle");
    assert!(fit > 0.05, "one neuron fits the bump's samples to {fit}");
}

#[test]
fn an_interrupted_staged_run_continues_to_the_same_network() {
    // Each stage keeps its epochs every 3.
    let (data, validation, mut recipe) = bump_run(256);
    for st in &mut recipe.stages {
        st.settings.checkpoint_every = 3;
    }
    let target = Target {
        linf: Some(0.01),
        slope_p95: None,
    };
    let input = values_only(&data, &validation, Some(&Bump));
    let dir = std::env::temp_dir().join(format!("cbfreach-staged-{}", std::process::id()));
    std::fs::create_dir_all(&dir).expect("a temporary directory");
    let fresh = StagedCheckpoint {
        path: dir.join("net.ckpt"),
        resume: false,
    };
    let seen = std::cell::RefCell::new(Vec::new());
    let run = |c: &StagedCheckpoint, stop: Option<(usize, usize)>| {
        seen.borrow_mut().clear();
        train_to_target(
            None,
            &[2, 16, 16, 1],
            1,
            &input,
            &recipe,
            &target,
            Some(c),
            |p| {
                seen.borrow_mut().push((p.stage_index, p.epoch, p.measured));
                if stop == Some((p.stage_index, p.epoch)) {
                    panic!(
                        "interrupted (on purpose) at stage {} epoch {}",
                        p.stage_index, p.epoch
                    );
                }
            },
        )
    };
    let (whole, report) = run(&fresh, None).expect("trains");
    let whole_seen = seen.borrow().clone();
    let names = |r: &RecipeReport| -> Vec<(String, usize, bool)> {
        r.stages
            .iter()
            .map(|s| (s.name.clone(), s.epochs, s.kept))
            .collect()
    };
    // Interrupted in a stage after a refine round, past its first epochs' checkpoint: the
    // state holds the round's samples, the stage's file its epochs.
    let refined = report
        .stages
        .iter()
        .find(|s| s.round.as_ref().is_some_and(|r| r.added > 0) && s.epochs >= 5)
        .expect("a refine stage that trains");
    let stage = recipe
        .stages
        .iter()
        .position(|s| s.name == refined.name)
        .expect("in the recipe");
    fresh.remove(recipe.stages.len());
    // The fit stage after a measurement (at epoch 20) and a checkpoint (at 21), the refine
    // stage after its first epochs' checkpoint (at 3) and before any.
    for (stage, stop, from) in [(0, 22, 22), (stage, 4, 4), (stage, 2, 1)] {
        let interrupted = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
            run(&fresh, Some((stage, stop)))
        }));
        assert!(interrupted.is_err());
        assert!(fresh.path.exists());
        assert_eq!(fresh.stage_file(stage).exists(), stop > 3);
        let resumed = StagedCheckpoint {
            resume: true,
            ..fresh.clone()
        };
        let (net, again) = run(&resumed, None).expect("continues");
        // It ran on from where it stopped: no earlier stage again, the stage from its
        // checkpoint's epoch.
        let first = seen.borrow().first().copied();
        let at = (stage, from);
        assert_eq!(first.map(|(s, e, _)| (s, e)), Some(at));
        // Its figures are this epoch's measurement, as the whole run showed, or none yet: not
        // the figures the stage started from.
        let shown = first.and_then(|f| f.2);
        let then = whole_seen
            .iter()
            .find(|w| (w.0, w.1) == at)
            .and_then(|w| w.2);
        assert!(
            shown.is_none() || shown == then,
            "{shown:?} against {then:?}"
        );
        assert_eq!(net, whole, "stopped at epoch {stop}: another network");
        assert_eq!(names(&again), names(&report));
        assert_eq!(again.samples, report.samples);
        assert!(!fresh.stage_file(stage).exists());
        fresh.remove(recipe.stages.len());
    }
    // Another seed's run does not continue this one's progress: refused, naming the file.
    let _ = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
        run(&fresh, Some((stage, 4)))
    }));
    let resumed = StagedCheckpoint {
        resume: true,
        ..fresh.clone()
    };
    let other = train_to_target(
        None,
        &[2, 16, 16, 1],
        2,
        &input,
        &recipe,
        &target,
        Some(&resumed),
        |_| {},
    );
    let message = other.expect_err("refused").to_string();
    assert!(
        message.contains("net.ckpt") && message.contains("other data, architecture, seed"),
        "{message}"
    );
    let _ = std::fs::remove_dir_all(&dir);
}

/// A certify stage that breaks the target is dropped and ends the run: the network returned is
/// the last one that met it, and the later stages (at higher weights) do not run.
#[test]
fn a_certify_stage_that_breaks_the_target_is_dropped_and_ends_the_run() {
    let (data, validation, mut recipe) = bump_run(256);
    recipe.stages.retain(|s| s.kind != StageKind::Refine);
    let certify: Vec<usize> = (0..recipe.stages.len())
        .filter(|&i| matches!(recipe.stages[i].kind, StageKind::Certify(_)))
        .collect();
    assert_eq!(certify.len(), CERTIFY_WEIGHTS.len());
    // The second pulls every IBP width to 0 (a constant network) faster than Adam's step
    // at the schedule's rate would.
    let crush = &mut recipe.stages[certify[1]];
    crush.kind = StageKind::Certify(1e3);
    crush.settings.ibp_weight = 1e3;
    crush.settings.learning_rate = 1e-2;
    let target = Target {
        linf: Some(0.3),
        slope_p95: None,
    };
    let input = values_only(&data, &validation, None);
    let (net, report) = train_fresh(&[2, 16, 16, 1], &input, &recipe, &target);
    let ran: Vec<(&str, bool)> = report
        .stages
        .iter()
        .map(|s| (s.name.as_str(), s.kept))
        .collect();
    assert_eq!(
        ran,
        [("fit", true), ("certify 1", true), ("certify 2", false)],
        "{report:?}"
    );
    let dropped = &report.stages[2].measured;
    assert!(
        dropped.linf > 0.3,
        "the crushing stage met the target: {dropped:?}"
    );
    // What is returned is certify 1's network, which met it.
    assert!(report.reached, "{report:?}");
    assert_eq!(report.measured, report.stages[1].measured);
    let m = measure(&net, &validation, &recipe.ibp_radius).expect("measures");
    assert!(
        m.linf <= 0.3 && (m.linf - report.measured.linf).abs() < 1e-9,
        "{m:?}"
    );
}

/// A run stopped under a schedule continues under one that extends it (stages added at its
/// end, as the certify stages were): to the network a run of the longer schedule gives from
/// the start. One whose shared stages changed is refused.
#[test]
fn a_stopped_run_continues_into_stages_added_to_its_schedule() {
    let (data, validation, mut long) = bump_run(256);
    long.stages.retain(|s| s.kind != StageKind::Refine);
    for st in &mut long.stages {
        st.settings.checkpoint_every = 3;
    }
    let short = Recipe {
        stages: long.stages[..long.stages.len() - 3].to_vec(),
        ..long.clone()
    };
    // Met after the fit: every certify stage holds it, and runs.
    let target = Target {
        linf: Some(0.3),
        slope_p95: None,
    };
    let input = values_only(&data, &validation, None);
    let dir = std::env::temp_dir().join(format!("cbfreach-extended-{}", std::process::id()));
    std::fs::create_dir_all(&dir).expect("a temporary directory");
    let fresh = StagedCheckpoint {
        path: dir.join("net.ckpt"),
        resume: false,
    };
    let resumed = StagedCheckpoint {
        resume: true,
        ..fresh.clone()
    };
    let run = |recipe: &Recipe, c: Option<&StagedCheckpoint>, stop: Option<(usize, usize)>| {
        train_to_target(None, &[2, 16, 16, 1], 1, &input, recipe, &target, c, |p| {
            if stop == Some((p.stage_index, p.epoch)) {
                panic!("interrupted (on purpose) at stage {}", p.stage_index);
            }
        })
    };
    let (whole, report) = run(&long, None, None).expect("trains");
    let names: Vec<&str> = report.stages.iter().map(|s| s.name.as_str()).collect();
    assert_eq!(names.len(), long.stages.len(), "{names:?}");
    // Stopped inside the short schedule's second stage, after its epoch checkpoint.
    let interrupted = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
        run(&short, Some(&fresh), Some((1, 5)))
    }));
    assert!(interrupted.is_err() && fresh.path.exists());
    // Continued into an added stage and stopped there again: the next resume finds the longer
    // schedule's own checkpoint, and the report still says where the run began.
    let added = short.stages.len();
    let interrupted = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
        run(&long, Some(&resumed), Some((added, 5)))
    }));
    assert!(interrupted.is_err() && fresh.path.exists());
    let (net, again) = run(&long, Some(&resumed), None).expect("continues");
    assert_eq!(net, whole);
    assert_eq!(
        (report.extended_from, again.extended_from),
        (None, Some(added))
    );
    let again_names: Vec<&str> = again.stages.iter().map(|s| s.name.as_str()).collect();
    assert_eq!(again_names, names);
    fresh.remove(long.stages.len());

    // A schedule whose shared stages changed (the fit one epoch longer) does not continue it.
    let _ = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
        run(&short, Some(&fresh), Some((1, 5)))
    }));
    let mut changed = long.clone();
    changed.stages[0].settings.epochs += 1;
    let message = run(&changed, Some(&resumed), None)
        .expect_err("refused")
        .to_string();
    assert!(
        message.contains("other data, architecture, seed"),
        "{message}"
    );
    // Nor one that shortens it below the stage it stopped in.
    let cut = Recipe {
        stages: long.stages[..1].to_vec(),
        ..long.clone()
    };
    let message = run(&cut, Some(&resumed), None)
        .expect_err("refused")
        .to_string();
    assert!(
        message.contains("other data, architecture, seed"),
        "{message}"
    );
    fresh.remove(long.stages.len());
    let _ = std::fs::remove_dir(&dir);
}
