//! A user's own system without hand-tuning (issue 38): settings chosen and said, honest
//! headlines, pictures of systems with more than two states, and the smaller items
//! (expressions for numbers, no driver noise, titles naming the margin used, simulate's count).

mod common;
use common::cbfreach;

use std::path::{Path, PathBuf};
use std::process::Command;

use cbfreach::reach::{CoordinatesReason, Transform};
use cbfreach::scenario::Scenario;

fn root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

fn chain3() -> String {
    root()
        .join("tests/fixtures/chain3.toml")
        .display()
        .to_string()
}

/// A scenario from TOML text, its relative paths against `scenarios/`.
fn scenario(text: &str) -> Result<Scenario, String> {
    Scenario::from_toml(text, "test.toml", &root().join("scenarios")).map_err(|e| e.to_string())
}

const SMALL: &str = r#"
name = "small"
[parameters]
g = 9.81
PARAMS
[system]
states = ["x", "theta"]
inputs = ["u"]
f = ["sin(theta)", "0"]
g = [["0"], ["1"]]
kappa = ["-x - theta"]
PERIODIC
[input_bounds]
lower = [LOWER]
upper = [10.0]
[reach]
region = { lower = [-1.0, REGION_LO], upper = [1.0, 3.0] }
m_c = 0.1
dt = 0.1
horizon = 1.0
goal = { lower = [-0.1, -0.1], upper = [0.1, 0.1] }
"#;

fn small(params: &str, periodic: &str, lower: &str, region_lo: &str) -> Result<Scenario, String> {
    scenario(
        &SMALL
            .replace("PARAMS", params)
            .replace("PERIODIC", periodic)
            .replace("LOWER", lower)
            .replace("REGION_LO", region_lo),
    )
}

/// Item 5: parameters and bounds may be expressions (before, `"-0.25*9.81"` was refused as
/// "invalid type: string"); bad ones name their key.
#[test]
fn parameters_and_bounds_take_expressions() {
    let s = small(r#"u_min = "-0.25*g""#, "", r#""-0.25*9.81""#, "-3.0").unwrap();
    assert_eq!(s.input_bounds.as_ref().unwrap().lower, vec![-0.25 * 9.81]);
    assert_eq!(s.parameters["u_min"], -0.25 * 9.81);
    // One parameter may use another, whatever their order; boxes may use parameters and pi.
    let s = small(
        r#"a = "b/2"
b = "2*g""#,
        "",
        r#""-a""#,
        r#""-pi""#,
    )
    .unwrap();
    assert_eq!(s.parameters["a"], 9.81);
    assert_eq!(s.input_bounds.as_ref().unwrap().lower, vec![-9.81]);
    assert_eq!(s.reach.region.lower[1], -std::f64::consts::PI);
    let chain = Scenario::load(Path::new(&chain3())).unwrap();
    assert_eq!(chain.parameters["a_min"], -0.2 * 9.81);
    for (params, lower, needle) in [
        ("", r#""-0.25*gg""#, "input_bounds.lower[0]"),
        (
            r#"a = "b"
b = "a""#,
            "0.0",
            "parameters.",
        ),
        (r#"a = "1/0""#, "0.0", "parameters.a"),
        ("", r#""x""#, "input_bounds.lower[0]"),
    ] {
        let e = small(params, "", lower, "-3.0").unwrap_err();
        assert!(e.contains(needle), "{e}");
    }
}

/// Item 2: periodic states are read, and sets wider than a period are refused by name.
#[test]
fn periodic_states_keep_sets_within_a_period() {
    let periodic = r#"periodic = { theta = ["-pi", "pi"] }"#;
    let s = small("", periodic, "-10.0", r#""-pi""#).unwrap();
    assert_eq!(s.periodic.len(), 1);
    assert_eq!(s.periodic[0].state, 1);
    assert!((s.periodic[0].period() - 2.0 * std::f64::consts::PI).abs() < 1e-15);
    let e = small("", periodic, "-10.0", "-4.0").unwrap_err();
    assert!(
        e.contains("reach.region") && e.contains("outside its period"),
        "{e}"
    );
    let e = small("", r#"periodic = { phi = [0.0, 1.0] }"#, "-10.0", "-3.0").unwrap_err();
    assert!(
        e.contains("system.periodic.phi") && e.contains("not a state"),
        "{e}"
    );
    let e = small("", r#"periodic = { theta = [1.0] }"#, "-10.0", "-3.0").unwrap_err();
    assert!(e.contains("expected a period"), "{e}");
}

/// Item 2: coordinates left open are x where the closed loop at the goal contracts in ℓ∞ (the
/// paper's scenario 1: unchanged), the contracting ones where it does not (the chain of
/// integrators), and the run says which and why.
#[test]
fn coordinates_left_open_are_chosen_and_said() {
    let paper = Scenario::builtin().unwrap();
    let (t, why) = Transform::chosen(&paper);
    assert!(t.is_none());
    assert!(matches!(why, CoordinatesReason::ContractsInX { mu_x } if mu_x < 0.0));
    let chain = Scenario::load(Path::new(&chain3())).unwrap();
    let (t, why) = Transform::chosen(&chain);
    assert!(t.is_some());
    match why {
        CoordinatesReason::NotContractingInX { mu_x, mu_z } => {
            assert_eq!(mu_x, 1.0);
            assert!(mu_z < 0.0, "{mu_z}");
        }
        other => panic!("{other:?}"),
    }
    let (code, out, err) = cbfreach(&["reach", &chain3(), "--time", "euler"]);
    assert_eq!(code, 0, "{err}");
    assert!(
        out.lines().next().unwrap().contains(
            "coordinates (reach.transform not set): z = T x (\"auto\"): the closed loop at the \
             goal is not contracting in ℓ∞ in x"
        ),
        "{out}"
    );
    // Said only when chosen.
    let (_, out, _) = cbfreach(&["reach", &chain3(), "--time", "euler", "--transform", "none"]);
    assert!(
        !out.contains("coordinates (reach.transform not set)"),
        "{out}"
    );
}

/// Item 2, systems that oscillate: a damped pendulum held by a CBF below its nominal
/// controller's target, whose closed loop at the goal has complex eigenvalues (−1.55 ± 1.25i),
/// gets coordinates in which it contracts at `α + |β|` (before: `μ∞ = 2.2·10¹²` in z, and
/// `tests/fixtures/pendulum.toml` verified 0.3 % of 32 × 32 cells, now 97.7 %); an undamped oscillator, which no coordinates contract in ℓ∞, keeps x and
/// says why.
#[test]
fn coordinates_left_open_contract_systems_that_oscillate() {
    // The fixture steered to the origin: (gains, damping).
    let pendulum = |k1: &str, k2: &str, b: &str| {
        common::fixture_with(
            "pendulum.toml",
            &[
                ("b = 0.1", b),
                ("k1 = 4.0", k1),
                ("k2 = 3.0", k2),
                ("theta_ref = 1.0", "theta_ref = 0.0"),
                (
                    "lower = [0.9, -0.1], upper = [1.1, 0.1]",
                    "lower = [-0.1, -0.1], upper = [0.1, 0.1]",
                ),
            ],
        )
    };
    let (t, why) = Transform::chosen(&pendulum("k1 = 4.0", "k2 = 3.0", "b = 0.1"));
    assert!(t.is_some(), "{why}");
    let rate = -1.55 + (4.0_f64 - 1.55 * 1.55).sqrt();
    match why {
        CoordinatesReason::NotContractingInX { mu_x, mu_z } => {
            assert_eq!(mu_x, 1.0);
            assert!(
                (mu_z - rate).abs() < 1e-9,
                "μ∞ in z {mu_z}, expected {rate}"
            );
        }
        other => panic!("{other:?}"),
    }
    // The fixture, whose goal lies beyond the CBF (the filter binds there: λ ≈ −2, twice).
    let fixture = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures/pendulum.toml");
    let (t, why) = Transform::chosen(&Scenario::load(&fixture).unwrap());
    assert!(t.is_some(), "{why}");
    assert!(
        matches!(why, CoordinatesReason::NotContractingInX { mu_z, .. } if mu_z < -1.0),
        "{why}"
    );
    let (t, why) = Transform::chosen(&pendulum("k1 = 1.0", "k2 = 0.0", "b = 0.0"));
    assert!(t.is_none());
    assert!(
        why.to_string()
            .contains("no contracting coordinates (the best found, μ∞ = 1.000 in z, is no better)"),
        "{why}"
    );
}

/// Items 3 and 4: a 3-state system verifies, its headline leads with the share proven
/// feasible (in the summary and the JSON), and its verdict map, tubes and trajectories draw as
/// projections and slices with the state names on the axes.
#[test]
fn three_states_verify_and_draw_as_projections_and_slices() {
    let tmp = tempfile::tempdir().unwrap();
    let json = tmp.path().join("v.json");
    let (code, out, err) = cbfreach(&[
        "verify",
        &chain3(),
        "--time",
        "euler",
        "--grid",
        "3,3,3",
        "--region=-0.3,-0.3,-0.3:0.3,0.3,0.3",
        "--refine",
        "0",
        "--json",
        json.to_str().unwrap(),
        "--plot",
        tmp.path().join("v.svg").to_str().unwrap(),
    ]);
    assert_eq!(code, 0, "{err}");
    let headline = out
        .lines()
        .find(|l| l.contains("verified"))
        .expect("a verified line");
    assert!(
        headline.contains("the filter proven feasible on every set"),
        "the first verified share is the proven one: {out}"
    );
    let report: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
    let h = &report["headline"];
    let (proven, existing) = (
        h["verified"].as_f64().unwrap(),
        h["verified_existing_trajectories"].as_f64().unwrap(),
    );
    assert!(proven <= existing && existing > 0.0, "{h}");
    let input = json.to_str().unwrap();
    for (figure, extra, caption) in [
        ("verdicts", vec!["--input", input], "[projected along a]"),
        (
            "verdicts",
            vec!["--input", input, "--axes", "v,a", "--slice", "p=0.5"],
            "[p = 0.5]",
        ),
        ("tubes", vec!["--axes", "p,a"], "[projected along v]"),
        ("trajectories", vec!["--slice", "a=0"], "[a = 0]"),
    ] {
        let svg = tmp.path().join(format!("{figure}.svg"));
        let (chain, path) = (chain3(), svg.to_str().unwrap().to_string());
        let mut args = vec!["plot", &chain, "--figure", figure, "-o", &path];
        args.extend(extra.iter().copied());
        let (code, _, err) = cbfreach(&args);
        assert_eq!(code, 0, "{figure} {extra:?}: {err}");
        let text = std::fs::read_to_string(&svg).unwrap();
        assert!(text.contains(caption), "{figure} {extra:?}: no `{caption}`");
    }
    let (code, _, err) = cbfreach(&[
        "plot",
        &chain3(),
        "--figure",
        "tubes",
        "-o",
        tmp.path().join("x.svg").to_str().unwrap(),
        "--slice",
        "q=0",
    ]);
    assert_ne!(code, 0);
    assert!(err.contains("`q` is not a state"), "{err}");
}

/// Item 4 over time: `--axes t,NAME` draws one state's tubes and trajectories against time
/// (the other states projected), a verdict map as each box's band until its tube ended, and an
/// error map as the bound along the state: all the pictures of a one-state system. Minkowski
/// tubes, verdict maps with a state projected, and verdicts or maps of another system say why
/// they are not drawn.
#[test]
fn one_state_draws_over_time() {
    let tmp = tempfile::tempdir().unwrap();
    let wall = root().join("tests/fixtures/wall1d.toml");
    let wall = wall.to_str().unwrap().to_string();
    let chain = chain3();
    for (scenario, figure, extra, needle) in [
        (
            &chain,
            "tubes",
            vec!["--axes", "t,p"],
            "[projected along v, a]",
        ),
        (
            &chain,
            "trajectories",
            vec!["--axes", "time,a"],
            "[projected along p, v]",
        ),
        (&wall, "trajectories", vec![], "gap"),
    ] {
        let svg = tmp.path().join(format!("{figure}.svg"));
        let path = svg.to_str().unwrap().to_string();
        let mut args = vec!["plot", scenario, "--figure", figure, "-o", &path];
        args.extend(extra.iter().copied());
        let (code, _, err) = cbfreach(&args);
        assert_eq!(code, 0, "{figure} {extra:?}: {err}");
        // The SVG's text elements, their padding folded.
        let text = std::fs::read_to_string(&svg).unwrap();
        let text = text.split_whitespace().collect::<Vec<_>>().join(" ");
        assert!(text.contains(needle), "{figure} {extra:?}: no `{needle}`");
        // The wall gives time a unit (`t = "s"`), chain3 none.
        assert!(
            text.contains("> t </text>") || text.contains("> t [s] </text>"),
            "{figure} {extra:?}: no t axis"
        );
    }
    // `reach --plot` of a one-state system draws its tube over time (N ≡ 0 and a margin
    // that covers |v| ≤ 1.5: a picture, not a claim).
    std::fs::copy(
        root().join("tests/fixtures/wall1d.toml"),
        tmp.path().join("w.toml"),
    )
    .unwrap();
    common::zero_network(&[1, 16, 16, 1])
        .save_safetensors(&tmp.path().join("wall1d.safetensors"), &Default::default())
        .unwrap();
    let (w, svg) = (tmp.path().join("w.toml"), tmp.path().join("reach.svg"));
    let tubes = tmp.path().join("reach.json");
    let (code, out, err) = cbfreach(&[
        "reach",
        w.to_str().unwrap(),
        "--m-c",
        "1.5",
        "--plot",
        svg.to_str().unwrap(),
        "--json",
        tubes.to_str().unwrap(),
    ]);
    assert_eq!(code, 0, "{err}");
    let json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&tubes).unwrap()).unwrap();
    assert_eq!(json["states"], serde_json::json!(["gap"]));
    assert_eq!(json["units"]["u"], "m/s");
    assert!(out.contains("tubes drawn to"), "{out}");
    let text = std::fs::read_to_string(&svg).unwrap();
    assert!(text.split_whitespace().any(|w| w == "gap"), "no state axis");
    // The tube's bars start at t = 0, where the unsafe set's bands do (the first bar, which
    // holds the initial set, was drawn as a line at its end).
    let left = |fill: &str| -> Vec<(f64, f64)> {
        (text.split("<rect").skip(1))
            .filter(|r| r.contains(&format!("fill=\"{fill}\"")))
            .map(|r| {
                let at = |key: &str| -> f64 {
                    let v = r.split(&format!("{key}=\"")).nth(1).unwrap();
                    v.split('"').next().unwrap().parse().unwrap()
                };
                (at("x"), at("y"))
            })
            .collect()
    };
    let mut bars = left("#0072B2");
    // The lowest is the legend's swatch, below the chart.
    bars.sort_by(|a, b| a.1.total_cmp(&b.1));
    bars.pop();
    let first_bar = bars.iter().map(|b| b.0).fold(f64::INFINITY, f64::min);
    let shading = left("#CDCDCD")
        .iter()
        .map(|b| b.0)
        .fold(f64::INFINITY, f64::min);
    assert!(
        bars.len() > 5 && first_bar == shading,
        "{first_bar} against {shading}"
    );
    // Its verdict map is each box's band over time, its error map the bound along the state.
    // With no --grid: 64 cells along its one state (the default was 64 × 64 whatever the
    // state count, and refused here).
    let (json, svg) = (tmp.path().join("v.json"), tmp.path().join("v.svg"));
    let (code, out, err) = cbfreach(&[
        "verify",
        w.to_str().unwrap(),
        "--m-c",
        "1.5",
        "--json",
        json.to_str().unwrap(),
        "--plot",
        svg.to_str().unwrap(),
    ]);
    assert_eq!(code, 0, "{err}");
    assert!(out.contains("grid [64],"), "{out}");
    // The report names its states and their units for whoever reads it next.
    let report: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
    assert_eq!(report["run"]["states"], serde_json::json!(["gap"]));
    assert_eq!(report["run"]["units"]["gap"], "m");
    assert_eq!(report["run"]["units"]["t"], "s");
    let text = std::fs::read_to_string(&svg).unwrap();
    let text = text.split_whitespace().collect::<Vec<_>>().join(" ");
    assert!(
        text.contains("each box until its tube ended"),
        "verdicts: no caption"
    );
    assert!(text.contains("> t [s] </text>"), "verdicts: no t axis");
    let (code, _, err) = cbfreach(&["error", w.to_str().unwrap(), "--budget", "200"]);
    assert_eq!(code, 0, "{err}");
    let svg = tmp.path().join("e.svg");
    let (code, _, err) = cbfreach(&[
        "plot",
        w.to_str().unwrap(),
        "--figure",
        "error-map",
        "-o",
        svg.to_str().unwrap(),
    ]);
    assert_eq!(code, 0, "{err}");
    let text = std::fs::read_to_string(&svg).unwrap();
    let text = text.split_whitespace().collect::<Vec<_>>().join(" ");
    assert!(text.contains("along gap"), "error map: no caption");
    // The axes carry the scenario's units (`[system] units`): the error is in u's.
    assert!(
        text.contains("> M [m/s] </text>"),
        "error map: no bound axis"
    );
    assert!(
        text.contains("> gap [m] </text>"),
        "error map: no state axis"
    );
    // Verdicts and maps of this one-state system are refused over a three-state one, named.
    let map = tmp.path().join("wall1d.errormap.json");
    for (figure, input, needle) in [
        (
            "verdicts",
            &json,
            "verdicts of a system with 1 state, not of",
        ),
        (
            "error-map",
            &map,
            "an error map of a system with 1 state, not of",
        ),
    ] {
        let input = input.to_str().unwrap();
        let out = tmp.path().join("other.svg");
        let args = ["plot", &chain, "--figure", figure, "--input", input, "-o"];
        let (code, _, err) = cbfreach(&[&args[..], &[out.to_str().unwrap()]].concat());
        assert_ne!(code, 0, "{figure} of another system drawn");
        assert!(
            err.contains(input) && err.contains(needle),
            "{figure}: {err}"
        );
        assert!(!out.exists(), "{figure}: a picture was written");
    }
    // The wall's equilibrium (gap = 2, made by the filter) lies in the goal: every
    // trajectory ends at the goal, and is drawn so.
    let text = std::fs::read_to_string(tmp.path().join("trajectories.svg")).unwrap();
    assert!(
        text.contains("ends at the goal") && !text.contains("undesirable"),
        "the wall's trajectories"
    );
    let out = tmp.path().join("x.svg");
    let out = out.to_str().unwrap();
    for (scenario, args, needle) in [
        (
            &chain,
            vec![
                "--figure",
                "verdicts",
                "--input",
                "none.json",
                "--axes",
                "t,p",
                "--slice",
                "a=0",
            ],
            "needs every other state of",
        ),
        (
            &chain,
            vec!["--figure", "minkowski", "--axes", "t,p"],
            "Minkowski tubes are drawn over two states",
        ),
        (
            &wall,
            vec!["--figure", "trajectories", "--axes", "gap,gap"],
            "draw it over time (--axes t,gap)",
        ),
    ] {
        let mut all = vec!["plot", scenario.as_str(), "-o", out];
        all.extend(args.iter().copied());
        let (code, _, err) = cbfreach(&all);
        assert_ne!(code, 0, "{args:?}");
        assert!(err.contains(needle), "{args:?}: {err}");
    }
}

/// Item 5: the GPU path prints no driver noise without a desktop session (before: libwayland's
/// `error: XDG_RUNTIME_DIR is invalid or not set`, once per Vulkan driver).
#[test]
fn the_gpu_path_prints_no_driver_noise() {
    let out = Command::new(env!("CARGO_BIN_EXE_cbfreach"))
        .args([
            "bench",
            "--backend",
            "gpu",
            "--boxes",
            "1",
            "--steps",
            "1",
            "--bounds",
            "forward",
        ])
        .env_remove("XDG_RUNTIME_DIR")
        .env_remove("NODEVICE_SELECT")
        .output()
        .expect("runs");
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!err.contains("XDG_RUNTIME_DIR"), "{err}");
}

/// Item 5: a tubes picture drawn with the error map's local bounds says so, not the global
/// `M_C` (before: `M_C = 8.80…` in the title of scenario 2's local-margin tubes).
#[test]
fn tube_titles_name_the_margin_used() {
    let tmp = tempfile::tempdir().unwrap();
    let text = std::fs::read_to_string(root().join("scenarios/double-integrator.toml")).unwrap();
    let net = root().join("scenarios/double-integrator.safetensors");
    let start = text.find("initial = [").unwrap();
    let text = text[..start]
        .replace("horizon = 10.0", "horizon = 0.25")
        .replace(
            "file = \"double-integrator.safetensors\"",
            &format!("file = {:?}", net.display().to_string()),
        )
        + "initial = [{ lower = [-3.1, 0.9], upper = [-2.9, 1.1] }]\n";
    let file = tmp.path().join("short.toml");
    std::fs::write(&file, text).unwrap();
    for command in ["plot", "reach"] {
        let svg = tmp.path().join(format!("{command}.svg"));
        let (code, _, err) = match command {
            "plot" => cbfreach(&[
                "plot",
                file.to_str().unwrap(),
                "--figure",
                "tubes",
                "-o",
                svg.to_str().unwrap(),
            ]),
            _ => cbfreach(&[
                "reach",
                file.to_str().unwrap(),
                "--time",
                "euler",
                "--plot",
                svg.to_str().unwrap(),
            ]),
        };
        assert_eq!(code, 0, "{err}");
        let title = std::fs::read_to_string(&svg).unwrap();
        assert!(title.contains("certified local M"), "{command}");
        assert!(!title.contains("M_C ="), "{command}");
    }
}

/// Item 5: simulate counts the trajectories that stopped, in one line (before: one stderr
/// line per trajectory and no count). Scenario 2's QP is infeasible in the strip
/// (3.05–4.95) × [−2, −1.75].
#[test]
fn simulate_counts_infeasible_trajectories() {
    let (code, out, err) = cbfreach(&[
        "simulate",
        root()
            .join("scenarios/double-integrator.toml")
            .to_str()
            .unwrap(),
        "--samples",
        "12",
        "--box",
        "3.5,-1.95:4.5,-1.9",
        "--horizon",
        "0.2",
    ]);
    assert_eq!(code, 0, "{err}");
    assert!(!out.is_empty());
    let lines: Vec<&str> = err.lines().filter(|l| !l.trim().is_empty()).collect();
    assert_eq!(lines.len(), 1, "{err}");
    assert!(
        lines[0].contains("12 of 12 trajectories stopped early, 12 of them at an infeasible QP"),
        "{err}"
    );
}

/// Item 2: an inverted set says which term of the step inverted it. In `ẋ = u`, `κ = −5x`, a
/// step too large for how fast the loop contracts (dt = 0.5: `x ← −1.5x`) no longer inverts
/// the box (the faces are widened where a step turns a state around) but leaves C when the
/// Euler map does; a network whose error exceeds the `M` it is given (a constant
/// 10 with M = 0, where v ≤ 0.4) disagrees with the filter's own bounds.
#[test]
fn an_inverted_set_names_the_step_or_the_margin() {
    use cbfreach::network::{Layer, Mlp};
    use cbfreach::reach::{Backend, CpuBackend, Inversion, ReachProblem, ReachSettings, TubeEnd};
    let fast = |dt: f64, h: &str, x0: f64| {
        scenario(&format!(
            r#"
name = "fast"
[system]
states = ["x", "y"]
inputs = ["u", "w"]
f = ["0", "0"]
g = [["1", "0"], ["0", "1"]]
kappa = ["-5*x", "-5*y"]
[[cbf]]
h = "{h}"
[reach]
region = {{ lower = [-3.0, -3.0], upper = [3.0, 3.0] }}
m_c = 0.0
dt = {dt}
horizon = 2.0
goal = {{ lower = [-0.1, -0.1], upper = [0.1, 0.1] }}
initial = [{{ lower = [{lo}, 0.9], upper = [{hi}, 1.1] }}]
"#,
            lo = x0 - 0.1,
            hi = x0 + 0.1
        ))
        .unwrap()
    };
    let constant = |c: f64| Mlp {
        layers: vec![
            Layer {
                weight: vec![0.0; 2],
                bias: vec![0.0],
                n_in: 2,
                n_out: 1,
            },
            Layer {
                weight: vec![0.0; 2],
                bias: vec![c, c],
                n_in: 1,
                n_out: 2,
            },
        ],
    };
    let run = |s: &Scenario, net: Mlp| {
        // The Euler map's step, whose inversion is under test.
        let problem = ReachProblem::new(s, net, 0.0)
            .unwrap()
            .with_time(cbfreach::reach::TimeModel::Euler, 1);
        let r = CpuBackend
            .reach(
                &problem,
                &s.reach.initial,
                &ReachSettings::default(),
                &|_, _| {},
            )
            .unwrap();
        r.boxes[0].end
    };
    // A step that turns the state around (1 + dt·∂F/∂x = −1.5) no longer inverts the box: the
    // faces are widened to hold the map (design §7), and the sets leave C exactly when the
    // Euler map's own trajectories do (from x = 1: −1.5, 2.25, −3.375 at t = 1.5).
    let end = run(&fast(0.5, "100 - x^2 - y^2", 1.0), constant(0.0));
    assert!(
        matches!(end, TubeEnd::LeftRegion { t } if (t - 1.5).abs() < 1e-9),
        "{end:?}"
    );
    // x ≥ −2 with α = 1 acts where x > 1/2: the box across x = 1/2 has no proven piece, so the
    // filter's enclosures of v ∈ [0, 0.4] meet the network's 10.
    let end = run(&fast(0.04, "x + 2", 0.5), constant(10.0));
    assert!(
        matches!(
            end,
            TubeEnd::Inverted {
                cause: Inversion::BoundsDisagree,
                ..
            }
        ),
        "{end:?}"
    );
    assert!(end.to_string().contains("M is below"), "{end}");
}

/// A tube that ends for want of an error bound says whether the map lacks bounds there (a jump
/// of `v`) or the step asked beyond `C`: the shipped unicycle's map certifies every cell, and
/// its box's sets, in z coordinates, widen until a step's a-priori enclosure reaches past
/// `px = −3.5`. The old message blamed cells "with no certified bound", of which it has none.
#[test]
fn a_tube_without_an_error_bound_says_whether_it_reached_beyond_c() {
    use cbfreach::reach::{Backend, CpuBackend, ReachSettings, TubeEnd};
    let s = Scenario::load(&common::scenario_path("unicycle.toml")).unwrap();
    let problem = common::shipped_problem(&s);
    assert!(problem.certified_on_all_of_c());
    // Twice the scenario's box in position (its own now ends a step later, its enclosure not
    // closing, since the curved rates' barrier starts from its fixed point).
    let wide = cbfreach::IntervalBox::new(vec![-3.2, 0.0, -0.1], vec![-2.8, 0.4, 0.1]).unwrap();
    let r = CpuBackend
        .reach(&problem, &[wide], &ReachSettings::default(), &|_, _| {})
        .unwrap();
    let end = r.boxes[0].end;
    assert!(
        matches!(end, TubeEnd::NoCertifiedBound { beyond_c: true, .. }),
        "{end:?}"
    );
    assert!(end
        .to_string()
        .contains("beyond C, where the error map certifies nothing"));
    // Scenario 2's map has cells without a bound (v jumps at (1, 0) and (3, 0)): either cause.
    let s2 = Scenario::load(&common::scenario_path("double-integrator.toml")).unwrap();
    assert!(!common::shipped_problem(&s2).certified_on_all_of_c());
    let either = TubeEnd::NoCertifiedBound {
        t: 1.0,
        beyond_c: false,
    };
    assert!(either
        .to_string()
        .contains("no certified bound (M = ∞), or its step reaches beyond C"));
}

#[test]
fn train_says_when_the_grid_cannot_resolve_the_target() {
    // The unicycle's filter steepens to ~76 per unit next to the obstacle: on a 9×7×9 grid
    // the grid's own interpolant misses v by far more than the target 0.1 between the points,
    // and train says so before and after training (a tiny network, a sliver of the schedule).
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("net.safetensors");
    let path = root().join("scenarios/unicycle.toml");
    let (code, stdout, stderr) = cbfreach(&[
        "train",
        path.to_str().unwrap(),
        "--architecture",
        "3,8,2",
        "--grid",
        "9,7,9",
        "--budget",
        "0.01",
        "--out",
        out.to_str().unwrap(),
    ]);
    assert_eq!(code, 0, "{stderr}");
    let line = stdout
        .lines()
        .find(|l| l.starts_with("grid resolution:"))
        .unwrap_or_else(|| panic!("no grid resolution line in {stdout}"));
    let miss: f64 = line
        .split("misses v by up to ")
        .nth(1)
        .and_then(|r| r.split_whitespace().next())
        .and_then(|x| x.parse().ok())
        .unwrap_or_else(|| panic!("no figure in `{line}`"));
    assert!(miss > 0.5, "{line}");
    assert!(line.contains("above the target 0.1"), "{line}");
    assert!(
        stdout.contains("the refine stages sample it where the network errs most"),
        "{stdout}"
    );
    assert!(stdout.contains("target NOT reached"), "{stdout}");
    assert!(
        stdout.contains("the grid itself resolves v only to"),
        "{stdout}"
    );
    // Eight neurons miss even the samples they were trained on: a larger network comes first.
    assert!(
        stdout.contains("it misses its own training samples in C ∩ S by up to")
            && stdout.contains("a larger [network] architecture comes before more data"),
        "{stdout}"
    );
    let (_, metadata) = cbfreach::network::Mlp::load_safetensors_with_metadata(&out).unwrap();
    let res: cbfreach::network::train::Resolution =
        serde_json::from_str(&metadata["grid_resolution"]).expect("recorded");
    assert!((res.max - miss).abs() < 1e-4 * (1.0 + miss), "{res:?}");
}

/// `--backend auto` takes the GPU for runs of thousands of boxes only: the paper's 12 boxes
/// run faster on the CPU engine (on an H200 1.6 s with the pipelines cached, 73 s cold,
/// against 0.4 s on its host's CPU), and the run says so. Decided before any adapter is
/// opened, so the same on every machine.
#[test]
fn auto_runs_a_few_boxes_on_the_cpu_and_says_why() {
    let scenario = root().join("scenarios/integrator.toml");
    let (code, out, err) = cbfreach(&[
        "reach",
        scenario.to_str().unwrap(),
        "--backend",
        "auto",
        "--time",
        "euler",
    ]);
    assert_eq!(code, 0, "{err}");
    assert!(
        out.contains("12 boxes run faster on the CPU engine") && out.contains("backend cpu"),
        "{out}"
    );
}
