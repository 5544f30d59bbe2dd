//! The `cbfreach` binary: the commands of the foundation issue, end to end.

mod common;
use common::cbfreach;

use std::process::Command;

#[test]
fn equilibria_json_lists_the_papers_four() {
    let path = common::scenario_path("integrator.toml");
    let (code, stdout, stderr) = cbfreach(&["equilibria", path.to_str().unwrap(), "--json"]);
    assert_eq!(code, 0, "{stderr}");
    let v: serde_json::Value = serde_json::from_str(&stdout).expect("JSON");
    let list = v.as_array().expect("array");
    assert_eq!(list.len(), 4);
    let kinds: Vec<&str> = list.iter().map(|e| e["kind"].as_str().unwrap()).collect();
    assert_eq!(kinds, ["stable", "saddle", "saddle", "stable"]);
    let undesirable: Vec<bool> = list
        .iter()
        .map(|e| e["undesirable"].as_bool().unwrap())
        .collect();
    assert_eq!(undesirable, [false, true, true, true]);
    let eig = &list[3]["eigenvalues"];
    assert!((eig[0][0].as_f64().unwrap() + 2.0).abs() < 1e-4);
    assert!((eig[1][0].as_f64().unwrap() + 1.0).abs() < 1e-4);
}

#[test]
fn simulate_writes_csv_that_ends_at_the_right_equilibria() {
    let path = common::scenario_path("integrator.toml");
    let (code, stdout, stderr) = cbfreach(&[
        "simulate",
        path.to_str().unwrap(),
        "--from",
        "6,0.3",
        "--from",
        "-2,2",
    ]);
    assert_eq!(code, 0, "{stderr}");
    let lines: Vec<&str> = stdout.lines().collect();
    assert_eq!(lines[0], "trajectory,t,x1,x2");
    let last_of = |k: &str| -> Vec<f64> {
        let row = lines
            .iter()
            .rev()
            .find(|l| l.starts_with(&format!("{k},")))
            .unwrap();
        row.split(',').skip(2).map(|v| v.parse().unwrap()).collect()
    };
    let a = last_of("0");
    let b = last_of("1");
    assert!((a[0] - 3.0).abs() < 1e-2 && a[1].abs() < 1e-2, "{a:?}");
    assert!(b[0].abs() < 1e-3 && b[1].abs() < 1e-3, "{b:?}");
}

#[test]
fn bad_input_gives_a_clear_error_and_exit_code_2() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path();
    let bad = dir.join("bad.toml");
    std::fs::write(&bad, common::SMALL.replace("-x - y", "-x - q")).unwrap();
    let (code, _, stderr) = cbfreach(&["check", bad.to_str().unwrap()]);
    assert_eq!(code, 2);
    assert!(
        stderr.contains("bad.toml") && stderr.contains("system.kappa[0]"),
        "{stderr}"
    );
    assert!(stderr.contains("column"), "{stderr}");

    let path = common::scenario_path("integrator.toml");
    let (code, _, stderr) = cbfreach(&["simulate", path.to_str().unwrap(), "--from", "1,x"]);
    assert_eq!(code, 2);
    assert!(
        stderr.contains("--from") && stderr.contains("`x`"),
        "{stderr}"
    );
    let (code, _, stderr) = cbfreach(&["simulate", path.to_str().unwrap(), "--from", "1,2,3"]);
    assert_eq!(code, 2);
    assert!(stderr.contains("expected 2 numbers"), "{stderr}");
    let (code, _, stderr) = cbfreach(&["reach", path.to_str().unwrap(), "--every", "0"]);
    assert_eq!(code, 2);
    assert!(
        stderr.contains("--every") && stderr.contains("whole number ≥ 1"),
        "{stderr}"
    );
}

/// Where `error`'s budget runs out before the cells meet their targets (the chain of three
/// integrators' network in 200 evaluations: 1 of 100), it says how to give it more.
#[test]
fn error_says_how_to_give_a_spent_budget_more() {
    let tmp = tempfile::tempdir().unwrap();
    for file in ["chain3.toml", "chain3.safetensors"] {
        std::fs::copy(common::fixture_path(file), tmp.path().join(file)).unwrap();
    }
    let path = tmp.path().join("chain3.toml");
    let args = ["error", path.to_str().unwrap(), "--looseness-boxes", "0"];
    let (code, stdout, stderr) = cbfreach(&[&args[..], &["--budget", "200"]].concat());
    assert_eq!(code, 0, "{stderr}");
    let line = stdout
        .lines()
        .find(|l| l.contains("the budget ran out with"))
        .unwrap_or_else(|| panic!("{stdout}"));
    // The cell cap was not what ran out: only the budget is named.
    assert!(
        line.contains("`--budget 2000` (ten times)") && !line.contains("--max-cells"),
        "{line}"
    );
    // The certified bound's gap is to the largest error found, the grid's or the dense
    // samples' (a pendulum's said 734 % over the samples' 0.0057 beside the grid's 0.0084).
    let number_after = |key: &str| -> f64 {
        let rest = stdout.split(key).nth(1).unwrap_or("?");
        let word = rest.split([' ', ',', '%', ':']).next().unwrap();
        word.parse().unwrap_or_else(|_| panic!("{key}: {stdout}"))
    };
    let (grid, attained) = (
        number_after("max ℓ∞ error "),
        number_after("network attains "),
    );
    let certified = number_after("certified M_C over C ∩ S: ");
    let gap = number_after("max ℓ∞ error by ");
    let expected = 100.0 * (certified / grid.max(attained) - 1.0);
    assert!(
        (gap - expected).abs() <= 0.01 * expected.abs() + 0.5,
        "{gap} against {expected}: {stdout}"
    );
}

/// A map certified for another filter gets one piece of advice, naming the scenario.
#[test]
fn a_stale_error_map_is_named_with_one_piece_of_advice() {
    let tmp = tempfile::tempdir().unwrap();
    let path = tmp.path().join("changed.toml");
    let net = common::scenario_path("double-integrator.safetensors");
    let text = std::fs::read_to_string(common::scenario_path("double-integrator.toml"))
        .unwrap()
        .replace("k2 = 2.0", "k2 = 2.5")
        .replace(
            "file = \"double-integrator.safetensors\"",
            &format!("file = {:?}", net.to_str().unwrap()),
        );
    std::fs::write(&path, text).unwrap();
    let (code, _, stderr) = cbfreach(&["reach", path.to_str().unwrap()]);
    assert_eq!(code, 2, "{stderr}");
    assert!(
        stderr.contains("certified for another version of the filter"),
        "{stderr}"
    );
    assert_eq!(stderr.matches("cbfreach error").count(), 1, "{stderr}");
    assert!(stderr.contains("again, or give --m-c)"), "{stderr}");
}

#[test]
fn default_command_reports_equilibria_and_endpoints() {
    let (code, stdout, stderr) = cbfreach(&[]);
    assert_eq!(code, 0, "{stderr}");
    assert!(
        stdout.contains("Equilibria of the filtered system in C (4)"),
        "{stdout}"
    );
    assert!(stdout.contains("trapped at (3.0000, 0.0000)"), "{stdout}");
    assert!(stdout.contains("reaches the origin"), "{stdout}");
}

#[test]
fn bench_reports_rates_for_each_method_and_batch() {
    let (code, stdout, stderr) = cbfreach(&[
        "bench",
        "--backend",
        "cpu",
        "--boxes",
        "1,4",
        "--steps",
        "2",
        "--bounds",
        "forward,ibp",
        "--peak",
        "100",
    ]);
    assert_eq!(code, 0, "{stderr}");
    let rows: Vec<&str> = stdout
        .lines()
        .filter(|l| l.trim_start().starts_with("cpu"))
        .collect();
    assert_eq!(rows.len(), 4, "{stdout}");
    for row in rows {
        let rate: f64 = row.split_whitespace().nth(3).unwrap().parse().unwrap();
        assert!(rate > 0.0, "{row}");
    }
}

/// `cbfreach` with no arguments reproduces the paper's scenario-1 verdicts with the shipped
/// network and its certified error map, in continuous time — four boxes behind the obstacle
/// `trapped` at (3, 0), the other eight `converges` (two of them as pieces) — and those
/// verdicts agree with the ground-truth filtered ODE (RK4 at a tenth of `dt`) from a 5 × 5 grid
/// of starts in every box (a wrong verdict, or a trap that is not one, fails here).
#[test]
fn default_run_reproduces_the_papers_verdicts_and_they_are_true() {
    use cbfreach::filter::SafetyFilter;
    use cbfreach::reach::TimeModel;
    use cbfreach::verify::simulate_model;

    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path();
    let out = Command::new(env!("CARGO_BIN_EXE_cbfreach"))
        .current_dir(dir)
        .output()
        .expect("runs");
    let stdout = String::from_utf8_lossy(&out.stdout).into_owned();
    assert!(
        out.status.success(),
        "{stdout}\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(stdout.contains("→ 8 converges, 4 trapped"), "{stdout}");
    assert!(stdout.contains("Time model: continuous"), "{stdout}");
    for fig in ["trajectories", "tubes", "minkowski"] {
        let png = dir.join("out").join(format!("integrator-{fig}.png"));
        assert!(
            std::fs::metadata(&png)
                .map(|m| m.len() > 10_000)
                .unwrap_or(false),
            "{png:?}"
        );
    }

    let s = common::integrator();
    let filter = SafetyFilter::new(&s);
    for (k, b) in s.reach.initial.iter().enumerate() {
        let trapped_box = k < 4;
        for i in 0..5 {
            for j in 0..5 {
                let x0 = b.point_at(&[i as f64 / 4.0, j as f64 / 4.0]);
                // The ODE by RK4 at dt/10, as `verify --check` simulates it.
                let (tr, _) = simulate_model(&filter, &x0, TimeModel::Continuous, 10);
                let end = tr.x.last().unwrap();
                let target = if trapped_box { [3.0, 0.0] } else { [0.0, 0.0] };
                let d = (end[0] - target[0]).hypot(end[1] - target[1]);
                assert!(d < 0.05, "box {k}: start {x0:?} ends at {end:?}");
            }
        }
    }
}

/// `cbfreach paper`: scenario 2's boxes that are not verified whole, or whose QP feasibility
/// is not proven whole, are split and refined; every one of the nine is proven to converge with
/// the QP feasible (the two at (±1, 1.5) and the one at (5, 1) only as pieces), and each does
/// reach the goal set under the ground-truth filter (25 starts per box); the run prints the
/// times table. The box at (−1, 1.5) needs 576 pieces: ~2.3 CPU-minutes (74 s on two
/// cores, 2026-12-03), so CI runs it beside the cut below.
#[test]
fn paper_verifies_split_boxes_of_scenario_2_truly() {
    paper_scenario_2(None, 9);
}

/// The same with the pieces' bisection off (`--refine 0`): each box is split into 4 × 4 pieces
/// at most, which proves seven of the nine (not the two at (±1, 1.5), whose trajectories pass
/// near the jump of `v` at (3, 0)); every verdict given is true.
#[test]
fn paper_verifies_split_boxes_of_scenario_2_truly_without_bisection() {
    paper_scenario_2(Some("0"), 7);
}

/// `paper` refuses to start over an interrupted run's checkpoints, naming the file and
/// `--resume`, before any work.
#[test]
fn paper_refuses_to_start_over_an_interrupted_run() {
    let tmp = tempfile::tempdir().unwrap();
    let stray = tmp.path().join("double-integrator-box03.checkpoint");
    std::fs::write(&stray, "{}\n").unwrap();
    let (code, stdout, stderr) = cbfreach(&["paper", "-o", tmp.path().to_str().unwrap()]);
    assert_ne!(code, 0, "{stdout}");
    assert!(
        stderr.contains("double-integrator-box03.checkpoint") && stderr.contains("--resume"),
        "{stderr}"
    );
    assert!(!stdout.contains("Scenario 1"), "{stdout}");
    assert!(stray.exists());
}

/// Runs `cbfreach paper` (with `--refine` if given) and checks its figures and scenario 2's
/// verdicts: at least `at_least` boxes proven to converge, each with the QP proven feasible and
/// each reaching the goal under the ground-truth filter from 25 starts.
fn paper_scenario_2(refine: Option<&str>, at_least: usize) {
    use cbfreach::filter::SafetyFilter;
    use cbfreach::simulate::{simulate_filtered, Integrator};

    let tmp = tempfile::tempdir().unwrap();
    // A folder not there yet: `paper` makes it.
    let dir = tmp.path().join("paper");
    let mut args = vec!["paper", "-o", dir.to_str().unwrap()];
    if let Some(r) = refine {
        args.extend(["--refine", r]);
    }
    let (code, stdout, stderr) = cbfreach(&args);
    assert_eq!(code, 0, "{stderr}");
    // The split boxes' checkpoints go once the run has ended.
    let left: Vec<_> = std::fs::read_dir(&dir)
        .unwrap()
        .flatten()
        .filter(|e| e.file_name().to_string_lossy().ends_with(".checkpoint"))
        .map(|e| e.path())
        .collect();
    assert!(left.is_empty(), "{left:?}");
    // Beside the paper's figures, each shipped network's error map.
    for name in ["integrator", "double-integrator"] {
        let map = dir.join(format!("{name}-error-map.png"));
        assert!(map.exists(), "{} missing: {stdout}", map.display());
    }
    assert!(stdout.contains("next to the paper's"), "{stdout}");
    let scenario_2 = &stdout[stdout.find("Scenario 2").expect("scenario 2 runs")..];
    let s = common::double_integrator();
    let filter = SafetyFilter::new(&s);
    let mut proven = 0;
    for b in &s.reach.initial {
        let line = scenario_2
            .lines()
            .find(|l| {
                l.trim_start()
                    .starts_with(&format!("({:.4}, {:.4})", b.lower[0], b.lower[1]))
            })
            .expect("a verdict line per box");
        if !line.contains("converges") {
            continue;
        }
        proven += 1;
        // Whole or in pieces (split further where a piece's sets leave the QP's feasibility
        // unproven), every box's QP is proven feasible along its sets.
        assert!(line.ends_with("; QP proven feasible"), "{line}");
        for i in 0..5 {
            for j in 0..5 {
                let x0 = b.point_at(&[i as f64 / 4.0, j as f64 / 4.0]);
                let tr =
                    simulate_filtered(&filter, &x0, s.reach.dt, s.reach.steps(), Integrator::Euler);
                let end = tr.x.last().unwrap();
                assert!(s.reach.goal.contains(end), "{line}: {x0:?} ends at {end:?}");
            }
        }
    }
    assert!(proven >= at_least, "{proven} proven: {scenario_2}");
    assert!(scenario_2.contains("every piece converges"), "{scenario_2}");
    assert!(
        scenario_2.contains(&format!("→ {proven} converges")),
        "{scenario_2}"
    );
}

/// `cbfreach reach` on scenario 2 with forward bounds and `extra` arguments: its stdout and
/// its `--json`.
fn reach_scenario_2(extra: &[&str]) -> (String, serde_json::Value) {
    let path = common::scenario_path("double-integrator.toml");
    let dir = tempfile::tempdir().unwrap();
    let json = dir.path().join("tubes.json");
    let mut args = vec![
        "reach",
        path.to_str().unwrap(),
        "--time",
        "euler",
        "--bounds",
        "forward",
        "--json",
        json.to_str().unwrap(),
    ];
    args.extend_from_slice(extra);
    let (code, stdout, stderr) = cbfreach(&args);
    assert_eq!(code, 0, "{stderr}");
    let v = serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).expect("JSON");
    (stdout, v)
}

#[test]
fn reach_takes_the_filters_own_field_where_it_is_one_smooth_piece_unless_told_not_to() {
    // Scenario 2's three boxes at x₁ = −3 never meet an active filter: with the default every
    // one of their steps takes the filter's own field (v = 0), also with `--exact inactive`;
    // `--network-everywhere` and `--exact nowhere` bound the network at each.
    let path = common::scenario_path("double-integrator.toml");
    let exact_steps = |extra: &[&str]| {
        let (_, v) = reach_scenario_2(extra);
        let dt = v["dt"].as_f64().unwrap();
        let boxes = v["boxes"].as_array().unwrap();
        let sum = |f: &dyn Fn(&serde_json::Value) -> u64| boxes.iter().map(f).sum::<u64>();
        let exact = sum(&|b| b["exact_steps"].as_u64().unwrap());
        let run = sum(&|b| {
            let last = b["tube"].as_array().unwrap().last().unwrap();
            (last["t"].as_f64().unwrap() / dt).round() as u64
        });
        (exact, run)
    };
    let (pieces, run) = exact_steps(&[]);
    assert!(pieces >= 3 * 200 && pieces <= run, "{pieces} of {run}");
    let (inactive, run) = exact_steps(&["--exact", "inactive"]);
    assert!(
        inactive >= 3 * 200 && inactive <= run,
        "{inactive} of {run}"
    );
    assert_eq!(exact_steps(&["--network-everywhere"]).0, 0);
    assert_eq!(exact_steps(&["--exact", "nowhere"]).0, 0);
    let (code, _, stderr) = cbfreach(&[
        "reach",
        path.to_str().unwrap(),
        "--exact",
        "inactive",
        "--network-everywhere",
    ]);
    assert_ne!(code, 0);
    assert!(stderr.contains("--network-everywhere"), "{stderr}");
}

#[test]
fn reach_meets_the_parallelotope_with_its_x_box_unless_told_not_to() {
    // Scenario 2 runs in z = T x. By default the CPU engine keeps the meet of the parallelotope
    // and a box in x, and says so; the box at (−1, 1.5), whose set turns over the obstacle,
    // then stays valid longer than as a parallelotope alone (`--parallelotope-only`).
    let run = |extra: &[&str]| {
        let (stdout, v) = reach_scenario_2(extra);
        let tube = v["boxes"]
            .as_array()
            .unwrap()
            .iter()
            .find(|b| b["initial"]["lower"] == serde_json::json!([-1.1, 1.4]))
            .unwrap_or_else(|| panic!("no box at (-1.1, 1.4): {stdout}"));
        let t = tube["tube"].as_array().unwrap().last().unwrap()["t"]
            .as_f64()
            .unwrap();
        (stdout.contains("sets met with their x-boxes"), t)
    };
    let (met, t_met) = run(&[]);
    let (alone, t_alone) = run(&["--parallelotope-only"]);
    assert!(met && !alone);
    assert!(t_met > t_alone, "{t_met} vs {t_alone}");
}

/// A scenario's `[settings]` table sets the runs' settings, options on the command line
/// override it, and an unknown key is an error that names it.
#[test]
fn scenario_settings_table_sets_defaults_that_options_override() {
    let dir = tempfile::tempdir().unwrap();
    let text = std::fs::read_to_string(common::scenario_path("integrator.toml")).unwrap();
    let net = common::scenario_path("integrator.safetensors");
    let text = text.replace(
        "file = \"integrator.safetensors\"",
        &format!("file = {:?}", net.to_str().unwrap()),
    );
    let write = |name: &str, table: &str| {
        let path = dir.path().join(name);
        std::fs::write(&path, format!("{text}\n{table}")).unwrap();
        path
    };
    let with = write(
        "with.toml",
        "[settings.reach]\nbounds = \"forward\"\nface_local = true\n\
         [settings.verify]\ngrid = [2, 2]\n",
    );
    let verify =
        |scenario: &std::path::Path, extra: &[&str]| verify_euler(dir.path(), scenario, extra).1;
    let run = verify(&with, &[]);
    assert_eq!(run["bounds"], "forward");
    assert_eq!(run["face_local"], true);
    assert_eq!(run["grid"], serde_json::json!([2, 2]));
    let run = verify(&with, &["--bounds", "forward-backward", "--grid", "1,2"]);
    assert_eq!(run["bounds"], "forward-backward");
    assert_eq!(run["face_local"], true);
    assert_eq!(run["grid"], serde_json::json!([1, 2]));

    let bad = write("bad.toml", "[settings.reach]\nbound = \"forward\"\n");
    let (code, _, stderr) = cbfreach(&["check", bad.to_str().unwrap()]);
    assert_eq!(code, 2);
    assert!(stderr.contains("bound"), "{stderr}");
}

/// `cbfreach verify <scenario> --time euler --json <dir>/v.json <extra>`: its standard output
/// and the JSON's `run`.
fn verify_euler(
    dir: &std::path::Path,
    scenario: &std::path::Path,
    extra: &[&str],
) -> (String, serde_json::Value) {
    let json = dir.join("v.json");
    let mut args = vec![
        "verify",
        scenario.to_str().unwrap(),
        "--time",
        "euler",
        "--json",
        json.to_str().unwrap(),
    ];
    args.extend_from_slice(extra);
    let (code, stdout, stderr) = cbfreach(&args);
    assert_eq!(code, 0, "{stdout}{stderr}");
    let v: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
    (stdout, v["run"].clone())
}

/// `verify` proves and prints the absorbing boxes and records them in the JSON; `--no-absorb`
/// (or `absorb = false` in `[settings.verify]`) runs every tube to the horizon.
#[test]
fn verify_says_where_tubes_stop_and_can_run_them_to_the_horizon() {
    let dir = tempfile::tempdir().unwrap();
    let scenario = common::scenario_path("integrator.toml");
    let verify = |scenario: &std::path::Path, extra: &[&str]| {
        let mut args = vec!["--grid", "4,3"];
        args.extend_from_slice(extra);
        let (stdout, run) = verify_euler(dir.path(), scenario, &args);
        (stdout, run["absorbing"].as_array().unwrap().len())
    };
    let (stdout, n) = verify(&scenario, &[]);
    assert!(stdout.contains("absorbing for the goal: (-0.5000, -0.5000) … (0.5000, 0.5000)"));
    assert!(stdout.contains("absorbing for trap 0"), "{stdout}");
    assert_eq!(n, 2);
    let (stdout, n) = verify(&scenario, &["--no-absorb"]);
    assert!(!stdout.contains("absorbing"), "{stdout}");
    assert_eq!(n, 0);
    let text = std::fs::read_to_string(&scenario).unwrap().replace(
        "file = \"integrator.safetensors\"",
        &format!(
            "file = {:?}",
            common::scenario_path("integrator.safetensors")
                .display()
                .to_string()
        ),
    );
    let off = dir.path().join("off.toml");
    std::fs::write(&off, format!("{text}\n[settings.verify]\nabsorb = false\n")).unwrap();
    assert_eq!(verify(&off, &[]).1, 0);
}

#[test]
fn plot_error_map_reads_the_map_beside_the_network_or_the_given_one() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path();
    let svg = dir.join("map.svg");
    let scenario = common::scenario_path("integrator.toml");
    let plot_map = |option: &str, file: &std::path::Path| {
        cbfreach(&[
            "plot",
            scenario.to_str().unwrap(),
            "--figure",
            "error-map",
            option,
            file.to_str().unwrap(),
            "-o",
            svg.to_str().unwrap(),
        ])
    };
    // The map beside the given network: copies of the shipped ones under another name (the
    // map names the network it was made for, and the title shows that name).
    let other = dir.join("other.safetensors");
    std::fs::copy(common::scenario_path("integrator.safetensors"), &other).unwrap();
    let map = std::fs::read_to_string(common::scenario_path("integrator.errormap.json")).unwrap();
    let renamed = map.replacen(
        r#""network":"integrator.safetensors""#,
        r#""network":"other.safetensors""#,
        1,
    );
    assert_ne!(renamed, map);
    std::fs::write(dir.join("other.errormap.json"), renamed).unwrap();
    let (code, stdout, stderr) = plot_map("--network", &other);
    assert_eq!(code, 0, "{stderr}");
    assert!(stdout.contains("written"), "{stdout}");
    let text = std::fs::read_to_string(&svg).unwrap();
    assert!(text.contains("other.safetensors: certified local bound M"));
    // A map file that is not there is named in the error.
    let (code, _, stderr) = plot_map("--input", &dir.join("no-such.errormap.json"));
    assert_ne!(code, 0);
    assert!(stderr.contains("no-such.errormap.json"), "{stderr}");
}

/// `--m-c` takes a number or, as the scenario file's `m_c`, where in the network's error map
/// to read `M_C`; anything else is refused with the accepted forms.
#[test]
fn m_c_flag_takes_a_number_or_reads_the_error_map() {
    use cbfreach::error_map::ErrorMap;
    let map = ErrorMap::load_for(&common::scenario_path("integrator.safetensors")).unwrap();
    let scenario = common::scenario_path("integrator.toml");
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path();
    for (flag, want) in [
        ("certified", map.certified_linf.unwrap()),
        ("measured", map.measured_linf),
        ("local", map.finite_max()),
        ("0.25", 0.25),
    ] {
        let json = dir.join(format!("{flag}.json"));
        let (code, stdout, stderr) = cbfreach(&[
            "verify",
            scenario.to_str().unwrap(),
            "--time",
            "euler",
            "--grid",
            "2,2",
            "--m-c",
            flag,
            "--json",
            json.to_str().unwrap(),
        ]);
        assert_eq!(code, 0, "{flag}: {stdout}{stderr}");
        let v: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
        assert_eq!(v["run"]["m_c"].as_f64(), Some(want), "{flag}");
        assert_eq!(v["run"]["local_margin"].as_bool(), Some(flag == "local"));
    }
    for bad in ["bogus", "-0.1", "nan"] {
        let (code, _, stderr) = cbfreach(&[
            "verify",
            scenario.to_str().unwrap(),
            &format!("--m-c={bad}"),
        ]);
        assert_ne!(code, 0);
        assert!(
            stderr.contains("expected a number ≥ 0, certified, measured or local"),
            "{bad}: {stderr}"
        );
    }
}

/// `cbfreach error --json` gives the issue's fields for a network given with `--network`, writes
/// the error map beside it, measures the looseness on boxes `--box-width` wide, and refuses a
/// width that is not positive by naming it.
#[test]
fn error_json_has_the_measured_and_certified_fields() {
    use cbfreach::network::Mlp;
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path();
    let scenario = dir.join("integrator.toml");
    let text = std::fs::read_to_string(common::scenario_path("integrator.toml")).unwrap();
    assert!(text.contains("grid = [365, 274]"));
    std::fs::write(
        &scenario,
        text.replace("grid = [365, 274]", "grid = [30, 24]"),
    )
    .unwrap();
    let net = dir.join("small.safetensors");
    Mlp::random(&[2, 16, 16, 2], 5)
        .save_safetensors(&net, &Default::default())
        .unwrap();
    let run = |width: &str| {
        cbfreach(&[
            "error",
            scenario.to_str().unwrap(),
            "--network",
            net.to_str().unwrap(),
            "--budget",
            "400",
            "--box-width",
            width,
            "--json",
        ])
    };
    let (code, stdout, stderr) = run("0.3");
    assert_eq!(code, 0, "{stderr}");
    let v: serde_json::Value = serde_json::from_str(&stdout).expect("JSON");
    assert_eq!(
        v["grid_points"].as_u64(),
        Some(60 * 48),
        "twice the training grid per axis"
    );
    assert_eq!(v["argmax"].as_array().map(Vec::len), Some(2));
    let (linf, l2) = (v["linf"].as_f64().unwrap(), v["l2"].as_f64().unwrap());
    assert!(linf > 0.0 && l2 >= linf, "{linf} {l2}");
    // One CBF: a closed form, so a certified bound, finite away from L_g h = 0, ≥ the sampled one.
    let certified = v["certified_linf"]
        .as_f64()
        .expect("a finite certified bound");
    assert!(certified >= linf, "{certified} < {linf}");
    let witness = v["witness_linf"].as_f64().unwrap();
    assert!(
        witness > 0.0 && witness <= certified,
        "{witness} {certified}"
    );
    assert_eq!(v["witness"].as_array().map(Vec::len), Some(2));
    assert!(v["cells"].as_u64().unwrap() > 0);
    assert_eq!(v["looseness"]["width"].as_f64(), Some(0.3));
    assert_eq!(v["box_width"].as_f64(), Some(0.3));
    assert!(v["looseness"]["crown"]["min"].as_f64().unwrap() >= 1.0);
    // The slope error by curvature: three bands in order of curvature, sharing the points.
    let bands = v["slope_by_curvature"]["bands"].as_array().unwrap();
    let shares: Vec<f64> = bands.iter().map(|b| b["share"].as_f64().unwrap()).collect();
    assert_eq!(shares.len(), 3);
    assert!(
        (shares.iter().sum::<f64>() - 1.0).abs() < 1e-12,
        "{shares:?}"
    );
    let edge = |b: usize, k: usize| bands[b]["curvature"][k].as_f64().unwrap();
    assert!(
        edge(0, 1) <= edge(1, 0) && edge(1, 1) <= edge(2, 0),
        "{bands:?}"
    );
    assert!(dir.join("small.errormap.json").exists());
    let (code, _, stderr) = run("0");
    assert_ne!(code, 0);
    assert!(
        stderr.contains("--box-width") && stderr.contains("expected a finite number > 0"),
        "{stderr}"
    );
}

/// `simulate` with no `--integrator` runs the system the scenario's time model bounds: RK4 for
/// `continuous` (the default; before, the Euler map, whose trajectories the continuous-time
/// sets do not bound), the zero-order hold at the control period for `sampled`, the map for
/// `euler`; the summary says which.
#[test]
fn simulate_runs_what_the_time_model_bounds_by_default() {
    let path = common::scenario_path("integrator.toml");
    let path = path.to_str().unwrap();
    let run = |extra: &[&str]| {
        let mut args = vec!["simulate", path, "--from", "6,0.3", "--horizon", "0.4"];
        args.extend_from_slice(extra);
        let (code, stdout, stderr) = cbfreach(&args);
        assert_eq!(code, 0, "{stderr}");
        stdout
    };
    let default = run(&[]);
    assert_eq!(default, run(&["--integrator", "rk4"]));
    assert_ne!(default, run(&["--integrator", "euler"]));
    // A sampled copy: the hold at T_s = 2 dt, with its samples 2 dt apart.
    let dir = tempfile::tempdir().unwrap();
    let text = std::fs::read_to_string(path).unwrap().replace(
        "\ndt = 0.04",
        "\ndt = 0.04\ntime = \"sampled\"\ncontrol_period = 0.08",
    );
    assert!(text.contains("control_period"), "scenario 1 changed");
    let sampled = dir.path().join("sampled.toml");
    std::fs::write(&sampled, text).unwrap();
    for name in ["integrator.safetensors", "integrator.errormap.json"] {
        let _ = std::fs::copy(common::scenario_path(name), dir.path().join(name));
    }
    let out = dir.path().join("t.csv");
    let s = sampled.to_str().unwrap();
    let summary = |extra: &[&str]| {
        let mut args = vec!["simulate", s, "--from", "6,0.3", "--horizon", "0.4"];
        args.extend_from_slice(extra);
        args.extend_from_slice(&["-o", out.to_str().unwrap()]);
        let (code, stdout, stderr) = cbfreach(&args);
        assert_eq!(code, 0, "{stderr}");
        (stdout, std::fs::read_to_string(&out).unwrap())
    };
    let (said, held) = summary(&[]);
    assert!(
        said.contains("5 steps (dt = 0.08, zoh: the system time = \"sampled\" bounds)"),
        "{said}"
    );
    assert_eq!(held, summary(&["--integrator", "zoh", "--dt", "0.08"]).1);
}

/// Slabs clipped by the other frame's sets are the default in continuous time with two frames
/// (scenario 2's coordinates), and the summary says so; `verify --no-meet-slabs` with sets too
/// loose says what the clip would do. In x alone (scenario 1) neither appears. `reach
/// --no-meet-slabs` names the clip beside `--face-local` where its tubes stop; by default it
/// names `--face-local` alone.
#[test]
fn verify_says_when_the_slabs_are_clipped() {
    let sc2 = common::scenario_path("double-integrator.toml");
    let sc2 = sc2.to_str().unwrap();
    let clipped = "slabs clipped by the other frame's sets";
    let (code, out, err) = common::cbfreach(&["verify", sc2, "--grid", "10,4"]);
    assert_eq!(code, 0, "{err}");
    assert!(out.contains(clipped), "{out}");
    assert!(!out.contains("--no-meet-slabs"), "{out}");
    let (code, out, err) = common::cbfreach(&["verify", sc2, "--grid", "10,4", "--no-meet-slabs"]);
    assert_eq!(code, 0, "{err}");
    assert!(!out.contains(clipped), "{out}");
    assert!(
        out.contains("without --no-meet-slabs each frame's slabs"),
        "{out}"
    );
    let sc1 = common::scenario_path("integrator.toml");
    let (code, out, err) = common::cbfreach(&["verify", sc1.to_str().unwrap(), "--grid", "8,6"]);
    assert_eq!(code, 0, "{err}");
    assert!(
        !out.contains("meet-slabs") && !out.contains(clipped),
        "{out}"
    );
    let stopped = |extra: &[&str]| {
        let (code, out, err) = common::cbfreach(&[&["reach", sc2][..], extra].concat());
        assert_eq!(code, 0, "{err}");
        out.lines()
            .find(|l| l.contains("sets stopped"))
            .expect(&out)
            .to_string()
    };
    let plain = stopped(&["--no-meet-slabs"]);
    assert!(
        plain.contains("--face-local") && plain.contains("--no-meet-slabs"),
        "{plain}"
    );
    let default = stopped(&[]);
    assert!(
        default.contains("--face-local") && !default.contains("meet-slabs"),
        "{default}"
    );
}
