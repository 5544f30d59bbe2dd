//! The `cbfreach` binary: the commands of the foundation issue, end to end.

mod common;

use std::process::Command;

fn cbfreach(args: &[&str]) -> (i32, String, String) {
    let out = Command::new(env!("CARGO_BIN_EXE_cbfreach"))
        .args(args)
        .output()
        .expect("runs");
    (
        out.status.code().unwrap_or(-1),
        String::from_utf8_lossy(&out.stdout).into_owned(),
        String::from_utf8_lossy(&out.stderr).into_owned(),
    )
}

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
    let dir = std::env::temp_dir().join(format!("cbfreach-cli-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
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
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn check_summarises_both_paper_scenarios() {
    for name in ["integrator.toml", "double-integrator.toml"] {
        let path = common::scenario_path(name);
        let (code, stdout, stderr) = cbfreach(&["check", path.to_str().unwrap()]);
        assert_eq!(code, 0, "{stderr}");
        assert!(stdout.contains("is valid"), "{stdout}");
    }
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
