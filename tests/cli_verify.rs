//! `cbfreach verify`'s hints after its summary: the band along `∂S` it skipped, what ended
//! the tubes it did not verify, and which knob stops the leaves whose sets were too loose
//! (and `reach`'s, for its tubes that stopped).

mod common;
use common::cbfreach;

/// `cbfreach <args> --json <file>`: its output and the file's text, asserting that it succeeded.
fn with_json(args: &[&str]) -> (String, String) {
    let tmp = tempfile::tempdir().unwrap();
    let path = tmp.path().join("out.json");
    let (code, stdout, stderr) = cbfreach(&[args, &["--json", path.to_str().unwrap()]].concat());
    assert_eq!(code, 0, "{stderr}");
    (stdout, std::fs::read_to_string(&path).unwrap())
}

/// Where much of the region lies in cells straddling `∂S` (skipped unless refined), `verify`
/// says so and names `--refine-boundary`; with it, no hint, and the band's halves in `S` join
/// the safe area. Every verified run also says what ended the tubes it did not verify.
#[test]
fn verify_points_to_the_skipped_band_along_the_safe_sets_boundary() {
    let scenario = common::scenario_path("double-integrator.toml");
    let scenario = scenario.to_str().unwrap();
    let args = ["verify", scenario, "--grid", "5,3", "--time", "euler"];
    let (code, stdout, stderr) = cbfreach(&args);
    assert_eq!(code, 0, "{stderr}");
    assert!(
        stdout.contains(
            "40.0% of the region lies in cells straddling ∂S, skipped: --refine-boundary"
        ),
        "{stdout}"
    );
    assert!(stdout.contains("what ended their tubes:"), "{stdout}");
    let (code, stdout, stderr) =
        cbfreach(&[&args[..], &["--refine", "1", "--refine-boundary"]].concat());
    assert_eq!(code, 0, "{stderr}");
    assert!(!stdout.contains("straddling ∂S, skipped"), "{stdout}");
    assert!(
        stdout.contains("the band along the safe set's boundary refined"),
        "{stdout}"
    );
}

/// Where the sets were too loose, `verify` runs the largest such leaves again with `M = 0`, with
/// twice the substeps and with face-local bounds, and names the knob: scenario 1's cells round
/// the goal with a margin far above the network's certified error (1.5 against 0.18; the
/// network's field everywhere, so that the margin counts) all verify with `M = 0`, none with the
/// other knobs; the JSON holds the same as data.
#[test]
fn verify_names_the_error_margin_where_it_stops_the_sets() {
    let scenario = common::scenario_path("integrator.toml");
    let (stdout, json) = with_json(&[
        "verify",
        scenario.to_str().unwrap(),
        "--region=-0.4,-0.4:0.4,0.4",
        "--grid",
        "4,4",
        "--m-c",
        "1.5",
        "--exact",
        "nowhere",
    ]);
    assert!(
        stdout.contains(
            "the 8 largest leaves whose sets were too loose (50% of their area), run again: \
             with M = 0 (the network taken as exact) 8 verify, with 2× the substeps 0, with \
             --face-local 0: the network's error margin stops them"
        ),
        "{stdout}"
    );
    // The JSON holds it as data.
    let report = cbfreach::verify::VerifyReport::from_json(&json, "v.json").unwrap();
    let w = report.what_stops.expect("what_stops in the JSON");
    assert_eq!((w.leaves.len(), w.reruns.without_error), (8, 8));
    assert_eq!(
        (w.reruns.finer_step, w.reruns.face_local),
        (Some(0), Some(0))
    );
    assert_eq!(w.reruns.culprit, cbfreach::verify::Culprit::Error);
    assert!(json.contains("\"culprit\":\"error\""), "{json}");
}

/// `reach` runs its stopped tubes again the same way: scenario 1's twelve boxes with `M = 1.5`
/// (the network's field everywhere) all stop, and with `M = 0` most of the eight rerun reach
/// the horizon, none with the finer step; its JSON holds the same.
#[test]
fn reach_names_the_error_margin_where_it_stops_the_tubes() {
    let scenario = common::scenario_path("integrator.toml");
    let (stdout, json) = with_json(&[
        "reach",
        scenario.to_str().unwrap(),
        "--m-c",
        "1.5",
        "--exact",
        "nowhere",
    ]);
    assert!(
        stdout.contains("12 of 12 sets stopped (INVALID)"),
        "{stdout}"
    );
    let line = stdout
        .lines()
        .find(|l| l.contains("of them run again"))
        .expect(&stdout);
    assert!(
        line.contains("8 of them run again, to the horizon: with M = 0")
            && line.contains(
                "with 2× the substeps 0, with --face-local 0: the network's error margin stops them"
            ),
        "{line}"
    );
    assert!(
        json.contains("\"what_stops\":{\"boxes\":8,") && json.contains("\"culprit\":\"error\""),
        "{json}"
    );
}

/// Without face-local bounds, a rerun with them is the third knob: scenario 1's 8 × 6 whole
/// cells under the Euler map (no finer step there) verify 3 of the 8 leaves rerun with them,
/// none with `M = 0`, so the bounds are named.
#[test]
fn verify_names_the_bounds_where_face_local_bounds_would_verify() {
    let scenario = common::scenario_path("integrator.toml");
    let args = [
        "verify",
        scenario.to_str().unwrap(),
        "--grid",
        "8,6",
        "--time",
        "euler",
    ];
    let (code, stdout, stderr) = cbfreach(&args);
    assert_eq!(code, 0, "{stderr}");
    assert!(
        stdout.contains(
            "with M = 0 (the network taken as exact) 0 verify, with --face-local 3: the \
             network's bounds stop them"
        ),
        "{stdout}"
    );
    let (code, stdout, _) = cbfreach(&[&args[..], &["--no-what-stops"]].concat());
    assert_eq!(code, 0);
    assert!(!stdout.contains("run again"), "{stdout}");
}
