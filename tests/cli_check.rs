//! `cbfreach check`: what it finds in a scenario before any network is trained (the paper's
//! scenarios, CBFs no input acts on, loops that turn sets, a general QP's active sets, a `C`
//! the flow leaves, a loop at the goal that grows boxes before it shrinks them).

mod common;
use common::cbfreach;
use std::path::PathBuf;

/// A copy of the shipped scenario `shipped` in `dir`, with its first `from` made `to`.
fn edited_copy(dir: &tempfile::TempDir, shipped: &str, from: &str, to: &str) -> PathBuf {
    let text = std::fs::read_to_string(common::scenario_path(shipped)).unwrap();
    assert!(text.contains(from), "{shipped} lacks `{from}`");
    let path = dir.path().join(shipped);
    std::fs::write(&path, text.replacen(from, to, 1)).unwrap();
    path
}

/// `cbfreach check <path>`'s output, asserting that it succeeded.
fn check(path: &std::path::Path) -> String {
    let (code, stdout, stderr) = cbfreach(&["check", path.to_str().unwrap()]);
    assert_eq!(code, 0, "{}: {stderr}", path.display());
    stdout
}

/// Both paper scenarios check, and `check` says that the filtered flow leaves their `C`
/// (scenario 1 past `x₁ = −3.5` where the obstacle's row pushes out; scenario 2 through
/// `x₁ = −4` at full reverse speed), which `verify` over all of `C` loses cells to.
#[test]
fn check_summarises_both_paper_scenarios() {
    for (name, side) in [
        ("integrator.toml", "through x1 = -3.5"),
        ("double-integrator.toml", "through x1 = -4"),
    ] {
        let path = common::scenario_path(name);
        let stdout = check(&path);
        assert!(stdout.contains("is valid"), "{stdout}");
        assert!(
            stdout.contains("C is not invariant") && stdout.contains(side),
            "{stdout}"
        );
        assert!(!stdout.contains("boxes at the goal grow"), "{stdout}");
        assert!(stdout.contains("α(h) = 1·h"), "{stdout}");
    }
}

/// A class-K function of `h` (scenario 1 with `α(h) = h³ + 0.5h`) is printed as written, and
/// `check` runs its filter.
#[test]
fn check_prints_a_class_k_function_as_written() {
    let dir = tempfile::tempdir().unwrap();
    let path = edited_copy(
        &dir,
        "integrator.toml",
        "alpha = 1.0",
        "alpha = \"h^3 + 0.5*h\"",
    );
    let stdout = check(&path);
    assert!(stdout.contains("α(h) = h^3 + 0.5*h"), "{stdout}");
    assert!(stdout.contains("starts on a grid over C ∩ S"), "{stdout}");
}

/// Where the true filtered system goes from a grid over `C ∩ S`, said before any network: on
/// scenario 1 every start reaches the origin or the trap at (3, 0) within its 10 s; with a 1 s
/// horizon most get there after it, and `check` says so with the time they need; scenario 2
/// names the starts that meet its infeasible QP.
#[test]
fn check_says_where_the_true_system_goes_and_when_the_horizon_is_too_short() {
    let survey = |stdout: &str| -> String {
        let line = stdout
            .lines()
            .find(|l| l.contains("starts on a grid over C ∩ S"));
        line.unwrap_or_else(|| panic!("{stdout}")).to_string()
    };
    // The counts of a line (`from N it …`) add up to its starts (`from N starts`).
    let total = |line: &str| -> (usize, usize) {
        let after = |word: &str| -> Vec<usize> {
            (line.split("from ").skip(1))
                .filter(|part| part.split_whitespace().nth(1) == Some(word))
                .map(|part| part.split_whitespace().next().unwrap().parse().unwrap())
                .collect()
        };
        (after("starts")[0], after("it").iter().sum())
    };
    let line = survey(&check(&common::scenario_path("integrator.toml")));
    assert!(
        line.contains("from 62 it reaches the goal or a trap by T = 10"),
        "{line}"
    );
    assert!(!line.contains("after T"), "{line}");
    let tmp = tempfile::tempdir().unwrap();
    let path = edited_copy(&tmp, "integrator.toml", "horizon = 10.0", "horizon = 1.0");
    let line = survey(&check(&path));
    assert!(
        line.contains("by T = 1;") && line.contains("it gets there after T, all by t = "),
        "{line}"
    );
    let (starts, counted) = total(&line);
    assert_eq!((starts, counted), (62, 62), "{line}");
    let line = survey(&check(&common::scenario_path("double-integrator.toml")));
    assert!(line.contains("it meets an infeasible QP"), "{line}");
    let (starts, counted) = total(&line);
    assert_eq!(starts, counted, "{line}");
}

/// A cart-pole under pole placement (tests/fixtures/cartpole.toml) is far from normal at the
/// goal: `check` says boxes there grow tenfold before they shrink, before any network exists.
#[test]
fn check_says_when_boxes_at_the_goal_grow_before_they_shrink() {
    let path = common::fixture_path("cartpole.toml");
    let stdout = check(&path);
    assert!(
        stdout.contains("boxes at the goal grow to 10.0× their width (in x, at t = 0.63)"),
        "{stdout}"
    );
}

/// A position bound on a triple integrator has relative degree three: `order = 2` leaves its
/// `ψ₁` inert, and `check` says to write `order = 3`, which makes the QP feasible on `C ∩ S`.
#[test]
fn check_says_which_order_a_position_bound_needs() {
    let tmp = tempfile::tempdir().unwrap();
    let path = tmp.path().join("jerk.toml");
    let text = |order: usize| {
        format!(
            r#"name = "jerk"
[system]
states = ["x1", "x2", "x3"]
inputs = ["u"]
f = ["x2", "x3", "0"]
g = [["0"], ["0"], ["1"]]
kappa = ["-x1 - 3*x2 - 3*x3"]
[[cbf]]
name = "wall"
h = "1.5 - x1"
order = {order}
alpha = 2
[reach]
region = {{ lower = [-2, -2, -2], upper = [2, 2, 2] }}
dt = 0.05
horizon = 5
goal = {{ lower = [-0.1, -0.1, -0.1], upper = [0.1, 0.1, 0.1] }}
"#
        )
    };
    // The training data say whether the QP's infeasible points lie in S.
    let dataset = |path: &std::path::Path| {
        let (code, stdout, stderr) =
            cbfreach(&["dataset", path.to_str().unwrap(), "--grid", "9,9,9"]);
        assert_eq!(code, 0, "{stderr}");
        stdout
    };
    std::fs::write(&path, text(2)).unwrap();
    let stdout = check(&path);
    assert!(
        stdout.contains("CBF wall.psi1: no input acts on it")
            && stdout.contains("write order = 3 in cbf[0], or add")
            && stdout.contains("the QP is infeasible at"),
        "{stdout}"
    );
    let data = dataset(&path);
    assert!(data.contains(" of them in S)"), "{data}");
    std::fs::write(&path, text(3)).unwrap();
    let data = dataset(&path);
    assert!(
        data.contains("infeasible skipped (all outside S)"),
        "{data}"
    );
    let stdout = check(&path);
    assert!(
        stdout.contains("CBF wall.psi2: h = ")
            && stdout.contains("which CBF wall.psi2 is (a high-order CBF)")
            && stdout.contains("the QP is feasible at all"),
        "{stdout}"
    );
    assert!(!stdout.contains("write order"), "{stdout}");
}

/// A CBF no input acts on (a position bound on a double integrator) is named with what to do
/// (the high-order CBF to add, which then keeps its row), and the QP's infeasible share is
/// said; a well-posed scenario says its QP is feasible.
#[test]
fn check_names_a_cbf_no_input_acts_on_and_where_the_qp_is_infeasible() {
    let tmp = tempfile::tempdir().unwrap();
    let path = edited_copy(
        &tmp,
        "double-integrator.toml",
        "h = \"(x1 - 2)^2 + x2^2 - 1\"",
        "h = \"1.5 - x1\"",
    );
    let stdout = check(&path);
    assert!(
        stdout.contains("CBF obstacle: no input acts on it (L_g h = 0 on all of C)")
            && stdout.contains("relative degree is above one")
            && stdout.contains("write order = 2 in cbf[0], or add"),
        "{stdout}"
    );
    let line = stdout
        .lines()
        .find(|l| l.contains("the QP is infeasible at"))
        .unwrap_or_else(|| panic!("{stdout}"));
    assert!(line.contains("`obstacle` needs"), "{line}");
    // The filter in words, its rows counted from the scenario.
    assert!(
        stdout.contains("filter: 2 constraint rows, closed form (scalar input"),
        "{stdout}"
    );
    // The note ends with the high-order CBF to add; added, it keeps the inert row, and the QP
    // is feasible on all of C ∩ S.
    let next = stdout
        .split("[[cbf]] h = \"")
        .nth(1)
        .and_then(|rest| rest.split('"').next())
        .unwrap_or_else(|| panic!("{stdout}"));
    let text = std::fs::read_to_string(&path).unwrap().replacen(
        "h = \"1.5 - x1\"",
        &format!("h = \"1.5 - x1\"\n[[cbf]]\nname = \"next\"\nh = \"{next}\""),
        1,
    );
    std::fs::write(&path, text).unwrap();
    let stdout = check(&path);
    assert!(
        stdout.contains("its row asks L_f̃ h + α(h) ≥ 0, which CBF next is (a high-order CBF)")
            && stdout.contains("the QP is feasible at all"),
        "{stdout}"
    );
    // `order = 2` writes the same CBF: the same note and the same feasibility.
    let text = std::fs::read_to_string(&path).unwrap().replacen(
        &format!("[[cbf]]\nname = \"next\"\nh = \"{next}\""),
        "order = 2",
        1,
    );
    std::fs::write(&path, text).unwrap();
    let stdout = check(&path);
    assert!(
        stdout.contains("which CBF obstacle.psi1 is (a high-order CBF)")
            && stdout.contains("written by cbf[0].order")
            && stdout.contains("the QP is feasible at all"),
        "{stdout}"
    );
    let path = common::scenario_path("integrator.toml");
    let stdout = check(&path);
    assert!(!stdout.contains("no input acts"), "{stdout}");
    assert!(stdout.contains("the QP is feasible at all"), "{stdout}");
    // Scenario 2's obstacle row turns round at (1, 0), where L_g h = 2x₂ vanishes: v jumps.
    let path = common::scenario_path("double-integrator.toml");
    let stdout = check(&path);
    assert!(
        stdout.contains("CBF obstacle: where it needs the input")
            && stdout.contains("at (1.0000, 0.0000): v divides by ‖L_g h‖²"),
        "{stdout}"
    );
}

/// A lightly damped closed loop at the goal (the pendulum fixture at `−0.25 ± 0.97i`) is named
/// as the reason boxes cannot shrink, by `check` and before a run; the fixture's own damped
/// loop (`−1.55 ± 1.25i` at the origin, a real pair at its goal) is not.
#[test]
fn check_and_runs_name_a_loop_that_turns_sets_faster_than_it_shrinks_them() {
    let tmp = tempfile::tempdir().unwrap();
    let text = std::fs::read_to_string(common::fixture_path("pendulum.toml")).unwrap();
    let light = text
        .replace("k1 = 4.0", "k1 = 1.0")
        .replace("k2 = 3.0", "k2 = 0.4")
        .replace("theta_ref = 1.0", "theta_ref = 0.0")
        .replace(
            "lower = [0.9, -0.1], upper = [1.1, 0.1]",
            "lower = [-0.1, -0.1], upper = [0.1, 0.1]",
        );
    let note = "the closed loop at the goal turns sets at least as fast as it shrinks them \
                (eigenvalues -0.250 ± 0.968i)";
    for (name, text, turns) in [("light.toml", &light, true), ("damped.toml", &text, false)] {
        let path = tmp.path().join(name);
        std::fs::write(&path, text).unwrap();
        let stdout = check(&path);
        assert_eq!(stdout.contains(note), turns, "{name}: {stdout}");
        assert_eq!(stdout.contains("turns sets"), turns, "{name}: {stdout}");
    }
    // Before a run too (no network needed to say it: the run then stops for the missing file).
    let path = tmp.path().join("light.toml");
    let (_, stdout, _) = cbfreach(&["reach", path.to_str().unwrap()]);
    assert!(
        stdout.contains(&format!("note: {note}")) && stdout.contains("α + |β| = 0.718"),
        "{stdout}"
    );
    // With a network, continuous time keeps the sets in turned frames and says how many.
    cbfreach::network::Mlp::random(&[2, 64, 64, 1], 3)
        .save_safetensors(
            &tmp.path().join("pendulum.safetensors"),
            &Default::default(),
        )
        .unwrap();
    let light = path.to_str().unwrap();
    let run = |extra: &[&str]| cbfreach(&[&["reach", light, "--m-c", "0.01"][..], extra].concat());
    let (code, stdout, stderr) = run(&["--backend", "cpu"]);
    assert_eq!(code, 0, "{stderr}");
    assert!(
        stdout.contains(
            "turned frames (reach.turned_frames not set): the sets are kept in z and 4 copies \
             of it turned by multiples of π/10"
        ) && stdout.contains("z in 5 frames turned by multiples of π/10"),
        "{stdout}"
    );
    // Given: not said; 1 turns none; refused by name where they cannot help.
    let (code, stdout, _) = run(&["--backend", "cpu", "--turned-frames", "2"]);
    assert_eq!(code, 0);
    assert!(
        !stdout.contains("turned frames (") && stdout.contains("in 2 frames"),
        "{stdout}"
    );
    let (code, stdout, _) = run(&["--backend", "cpu", "--turned-frames", "1"]);
    assert_eq!(code, 0);
    assert!(
        !stdout.contains("turned by multiples")
            && stdout.contains("slabs clipped by the other frame's sets"),
        "{stdout}"
    );
    let (code, _, stderr) = run(&["--time", "euler", "--turned-frames", "2"]);
    assert_ne!(code, 0);
    assert!(
        stderr.contains("--turned-frames 2: turned frames tighten continuous time alone"),
        "{stderr}"
    );
}

/// A general QP's active sets are counted where the scenario is checked: three spheres on three
/// inputs with `|uᵢ| ≤ 2` enumerate 105 (an input's two bounds never together); a fourth sphere
/// passes the 128 enumerated, and `check` says that no certified error bound exists (which
/// before only `error` found out).
#[test]
fn check_counts_a_general_qps_active_sets_and_says_when_there_are_too_many() {
    let tmp = tempfile::tempdir().unwrap();
    for (count, expected) in [
        (3, "its certified bounds enumerate 105 active sets"),
        (4, "its active sets are past those enumerated (128 sets of at most 4 rows): no certified error bound"),
    ] {
        let path = tmp.path().join(format!("s{count}.toml"));
        std::fs::write(&path, common::spheres_with_bounds(count)).unwrap();
        let stdout = check(&path);
        assert!(stdout.contains(expected), "{stdout}");
    }
}

/// An initial box outside `S` is named by `check`, and `reach` does not run it: its sets are
/// clipped to `S` and bound the trajectories that start there (a user's box at (0.5, 0.8) of a
/// pendulum whose high-order CBF asks ω ≤ 2(0.8 − θ) ran to "the embedding state became
/// inverted", with its own field counted on 7 of 6 box-steps). A box partly in `S` runs, said.
#[test]
fn an_initial_box_outside_s_is_named_and_not_run() {
    let tmp = tempfile::tempdir().unwrap();
    let text = std::fs::read_to_string(common::fixture_path("pendulum.toml")).unwrap();
    let boxes = "initial = [ { lower = [-0.1, -0.1], upper = [0.1, 0.1] } ]";
    assert!(text.contains(boxes));
    let text = text
        .replace(
            boxes,
            "initial = [ { lower = [0.5, 0.8], upper = [0.55, 0.85] }, \
             { lower = [0.1, 1.0], upper = [0.2, 1.2] }, \
             { lower = [-0.1, -0.1], upper = [0.1, 0.1] } ]",
        )
        .replace("architecture = [2, 64, 64, 1]", "architecture = [2, 16, 1]");
    let path = tmp.path().join("pendulum.toml");
    std::fs::write(&path, text).unwrap();
    let stdout = check(&path);
    // h = 0.8 − θ − 0.5ω: −0.075 at (0.5, 0.8), and from −0.2 to 0.2 over the second box.
    for line in [
        "initial box 0 (0.5000, 0.8000) … (0.5500, 0.8500) lies outside S (limit < 0 on all of it)",
        "initial box 1 (0.1000, 1.0000) … (0.2000, 1.2000) lies partly outside S (limit not ≥ 0",
    ] {
        assert!(stdout.contains(line), "{stdout}");
    }
    assert!(!stdout.contains("initial box 2"), "{stdout}");
    cbfreach::network::Mlp::random(&[2, 16, 1], 3)
        .save_safetensors(
            &tmp.path().join("pendulum.safetensors"),
            &Default::default(),
        )
        .unwrap();
    let json = tmp.path().join("r.json");
    let (code, stdout, stderr) = cbfreach(&[
        "reach",
        path.to_str().unwrap(),
        "--m-c",
        "0.01",
        "--backend",
        "cpu",
        "--json",
        json.to_str().unwrap(),
    ]);
    assert_eq!(code, 0, "{stderr}");
    assert!(
        stdout.contains("(0.5000, 0.8000) … (0.5500, 0.8500)  →  not run: the box lies outside S")
            && stdout.contains("2 boxes × 400 steps")
            && stdout.contains("(the next box starts partly outside S"),
        "{stdout}"
    );
    let json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
    assert_eq!(json["outside_s"][0]["lower"], serde_json::json!([0.5, 0.8]));
    assert_eq!(json["boxes"].as_array().map(Vec::len), Some(2), "{json}");
}
