//! `cbfreach train` end to end: the staged schedule, dense and secant slope samples, and the
//! folded network it saves.

mod common;
use common::cbfreach;

/// The whole numbers on the first line of `stdout` that contains `needle`, in order.
fn numbers_on_line(stdout: &str, needle: &str) -> Option<Vec<usize>> {
    let line = stdout.lines().find(|l| l.contains(needle))?;
    Some(
        line.split_whitespace()
            .filter_map(|w| w.parse().ok())
            .collect(),
    )
}

/// `cbfreach train` of a 2×8×2 network for one epoch on scenario 1's `grid` (points per
/// axis), written to `out`, with `extra` arguments.
fn train_small(grid: &str, out: &std::path::Path, extra: &[&str]) -> (i32, String, String) {
    let path = common::scenario_path("integrator.toml");
    let mut args = vec![
        "train",
        path.to_str().unwrap(),
        "--architecture",
        "2,8,2",
        "--grid",
        grid,
        "--epochs",
        "1",
        "--out",
        out.to_str().unwrap(),
    ];
    args.extend_from_slice(extra);
    cbfreach(&args)
}

#[test]
fn train_adds_finer_samples_only_where_v_is_steep() {
    // Scenario 1's filter is steep near (4.1, 0.8): `--dense-slope` adds a 4× finer grid
    // within one spacing of each steep grid point of S (at most 9² − 3² new points each);
    // a threshold above every slope adds none. `--focus-box` weighs the grid's 6 × 5 points in
    // [−0.5, 0.5]² (x₁ = −0.5, −0.3, …, 0.5 and x₂ = −0.4, …, 0.4; none of the finer ones).
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path();
    let out = dir.join("net.safetensors");
    let added = |slope: &str| {
        let (code, stdout, stderr) = train_small(
            "41,31",
            &out,
            &[
                "--jacobian-huber",
                "1",
                "--dense-slope",
                slope,
                "--focus-box=-0.5,-0.5:0.5,0.5",
                "--focus-weight",
                "10",
            ],
        );
        assert_eq!(code, 0, "{stderr}");
        // stderr is not a terminal here: a line per epoch stands in for the hidden bar.
        assert!(stderr.contains("epoch 1/1: loss "), "{stderr}");
        let focus = numbers_on_line(&stdout, "in the focus box weigh");
        assert_eq!(focus, Some(vec![30, 10]), "{stdout}");
        let numbers = numbers_on_line(&stdout, "finer added around")
            .unwrap_or_else(|| panic!("no dense-sample line in {stdout}"));
        (numbers[0], numbers[1])
    };
    let (points, seeds) = added("5");
    assert!(
        seeds > 0 && points > 0,
        "{points} points around {seeds} seeds"
    );
    assert!(
        points <= seeds * (81 - 9),
        "{points} points around {seeds} seeds"
    );
    assert_eq!(added("1e9"), (0, 0));
}

#[test]
fn train_takes_secant_slope_targets_and_records_their_step() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path();
    let out = dir.join("net.safetensors");
    let train = |step: &str| train_small("21,16", &out, &["--slope-step", step]);
    let (code, _, stderr) = train("0.02,0.01");
    assert_eq!(code, 0, "{stderr}");
    let (_, metadata) = cbfreach::network::Mlp::load_safetensors_with_metadata(&out).unwrap();
    assert_eq!(
        metadata.get("slope_step").map(String::as_str),
        Some("[0.02, 0.01]")
    );
    for (bad, says) in [
        ("0", "--slope-step 0: expected a finite step > 0"),
        ("0.1,0.1,0.1", "3 values, expected one or one per state (2)"),
    ] {
        let (code, _, stderr) = train(bad);
        assert_ne!(code, 0);
        assert!(stderr.contains(says), "{bad}: {stderr}");
    }
}

#[test]
fn train_without_epochs_runs_the_staged_schedule_and_saves_a_folded_network() {
    // No tuning flags: range test, stages, the scenario's target judged and said; the file is
    // a plain MLP in the scenario's units with the normalisation and the run as metadata.
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("net.safetensors");
    let path = common::scenario_path("integrator.toml");
    let small = [
        "train",
        path.to_str().unwrap(),
        "--architecture",
        "2,8,2",
        "--grid",
        "21,16",
        "--budget",
        "0.01",
        "--out",
        out.to_str().unwrap(),
    ];
    let (code, stdout, stderr) = cbfreach(&small);
    assert_eq!(code, 0, "{stderr}");
    for part in [
        "schedule: fit",
        "certify 3",
        "max ℓ∞ ≤ 0.188, slope p95 ≤ 0.218",
        "range test",
    ] {
        assert!(stdout.contains(part), "no `{part}` in {stdout}");
    }
    assert!(
        stdout.contains("target reached") || stdout.contains("target NOT reached"),
        "{stdout}"
    );
    // Without a terminal, every stage that trains logs lines, certify stages too (they
    // measure only at their end: before, they ran without one).
    assert!(stderr.contains("certify 1 epoch "), "{stderr}");
    let (net, metadata) = cbfreach::network::Mlp::load_safetensors_with_metadata(&out).unwrap();
    assert_eq!(net.architecture(), "2x8x2");
    let norm = cbfreach::network::train::Normalisation::from_metadata(&metadata)
        .unwrap()
        .expect("normalisation recorded");
    assert_eq!(norm.input_centre, vec![0.5, 0.0]); // C = [−3.5, 4.5] × [−3, 3]
    assert!(metadata.contains_key("recipe_report"));
    // Its progress was kept beside the network while it ran, and is gone once it is saved.
    assert!(stdout.contains("net.ckpt after every stage"), "{stdout}");
    let left: Vec<_> = std::fs::read_dir(tmp.path())
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    assert_eq!(left, ["net.safetensors"]);
    // An interrupted run's progress is not started over without `--resume`.
    std::fs::write(tmp.path().join("net.ckpt"), b"progress").unwrap();
    let (code, _, stderr) = cbfreach(&[
        "train",
        path.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
    ]);
    assert_ne!(code, 0);
    assert!(
        stderr.contains("net.ckpt holds the progress") && stderr.contains("--resume"),
        "{stderr}"
    );
    // With `--resume`, a file that is no checkpoint is refused by name.
    let (code, _, stderr) = cbfreach(&[small.as_slice(), &["--resume"]].concat());
    assert_ne!(code, 0);
    assert!(
        stderr.contains("net.ckpt: cannot resume") && stderr.contains("not a training checkpoint"),
        "{stderr}"
    );
    let (code, _, stderr) = cbfreach(&["train", path.to_str().unwrap(), "--budget", "0"]);
    assert_ne!(code, 0);
    assert!(stderr.contains("--budget 0"), "{stderr}");
}

#[test]
fn train_refuses_tuning_flags_without_epochs_and_the_budget_with_it() {
    // The staged schedule chooses its own rates, batches and terms: a tuning flag given without
    // `--epochs` used to be ignored without a word.
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("net.safetensors");
    let path = common::scenario_path("integrator.toml");
    for flags in [
        &["--lr", "0.5"][..],
        &["--batch-size", "64"],
        &["--ibp-weight", "0.01"],
        &["--revive-every", "4"],
        &["--slope-step", "0.02", "--secant-network"],
        &["--no-normalise"],
    ] {
        let args = [
            &[
                "train",
                path.to_str().unwrap(),
                "--out",
                out.to_str().unwrap(),
            ][..],
            flags,
        ]
        .concat();
        let (code, _, stderr) = cbfreach(&args);
        assert_eq!(code, 2, "{flags:?}: {stderr}");
        assert!(
            stderr.contains("--epochs <EPOCHS>") && stderr.contains(flags[0]),
            "{flags:?}: {stderr}"
        );
    }
    let (code, _, stderr) = train_small("21,16", &out, &["--budget", "0.5"]);
    assert_eq!(code, 2, "{stderr}");
    assert!(
        stderr.contains("'--epochs <EPOCHS>' cannot be used with '--budget <BUDGET>'"),
        "{stderr}"
    );
    assert!(!out.exists() && !tmp.path().join("net.ckpt").exists());
}
