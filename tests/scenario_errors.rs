//! Every class of bad scenario input gives an error naming the file, the key and what was
//! expected (and, for expressions, the column).

mod common;

use cbfreach::filter::{FilterError, SafetyFilter};
use common::{from_text, SMALL};

/// The error message for `SMALL` with `from` replaced by `to`.
fn error_for(from: &str, to: &str) -> String {
    assert!(SMALL.contains(from), "fixture lacks `{from}`");
    match from_text(&SMALL.replacen(from, to, 1)) {
        Ok(_) => panic!("`{to}` was accepted"),
        Err(e) => e.to_string(),
    }
}

fn assert_mentions(message: &str, parts: &[&str]) {
    for p in parts {
        assert!(message.contains(p), "`{message}` does not mention `{p}`");
    }
}

#[test]
fn the_fixture_is_valid() {
    let s = from_text(SMALL).expect("valid");
    assert_eq!((s.n(), s.m()), (2, 1));
    assert_eq!(s.reach.steps(), 20);
}

#[test]
fn unknown_symbol_names_key_and_column() {
    let m = error_for(r#"kappa = ["-x - y"]"#, r#"kappa = ["-x - z"]"#);
    assert_mentions(&m, &["test.toml", "system.kappa[0]", "column 6", "z"]);
}

#[test]
fn malformed_expression_names_column() {
    let m = error_for(r#"h = "y + 2""#, r#"h = "y + * 2""#);
    assert_mentions(&m, &["test.toml", "cbf[0].h", "column"]);
    let m = error_for(r#"h = "y + 2""#, r#"h = "(y + 2""#);
    assert_mentions(&m, &["cbf[0].h", "column"]);
    let m = error_for(r#"h = "y + 2""#, r#"h = "y^0.5""#);
    assert_mentions(&m, &["cbf[0].h", "integer"]);
}

/// An expression of megabytes (a generated file's was 90 MB) is refused before it is lexed, and
/// the message quotes its start and end, not all of it: it took 16 s to be refused and printed.
#[test]
fn a_huge_expression_is_refused_quickly_with_a_short_message() {
    let huge = format!("y{}", " + y".repeat(400_000));
    let start = std::time::Instant::now();
    let m = error_for(r#"h = "y + 2""#, &format!(r#"h = "{huge}""#));
    assert_mentions(
        &m,
        &[
            "test.toml",
            "cbf[0].h",
            "expression too long",
            "1600001 bytes",
        ],
    );
    assert!(m.len() < 600, "{} characters of message", m.len());
    assert!(m.contains("(1600001 characters)"), "{m}");
    eprintln!("refused in {:?}", start.elapsed());
    // A short one is quoted whole.
    let m = error_for(r#"h = "y + 2""#, r#"h = "y + * 2""#);
    assert!(m.ends_with("`y + * 2`"), "{m}");
}

#[test]
fn wrong_dimension_of_g() {
    let m = error_for(r#"g = [["0"], ["1"]]"#, r#"g = [["0"], ["1", "2"]]"#);
    assert_mentions(&m, &["test.toml", "system.g[1]", "expected 1"]);
    let m = error_for(r#"g = [["0"], ["1"]]"#, r#"g = [["0"]]"#);
    assert_mentions(&m, &["system.g", "expected 2 rows"]);
    let m = error_for(r#"f = ["y", "-x"]"#, r#"f = ["y"]"#);
    assert_mentions(&m, &["system.f", "expected 2"]);
}

#[test]
fn empty_or_inverted_boxes() {
    let m = error_for(
        "lower = [-1, -1], upper = [1, 1]",
        "lower = [1, -1], upper = [-1, 1]",
    );
    assert_mentions(
        &m,
        &["test.toml", "reach.region", "inverted", "coordinate 0"],
    );
    let m = error_for(
        "lower = [-1, -1], upper = [1, 1]",
        "lower = [-1], upper = [1]",
    );
    assert_mentions(&m, &["reach.region", "length 2"]);
    let m = error_for(
        "goal = { lower = [-0.1, -0.1], upper = [0.1, 0.1] }",
        "goal = { lower = [-0.1, 0.2], upper = [0.1, 0.1] }",
    );
    assert_mentions(&m, &["reach.goal", "inverted", "coordinate 1"]);
}

#[test]
fn turned_frames_out_of_range() {
    for k in ["0", "17"] {
        assert_mentions(
            &error_for("dt = 0.05", &format!("dt = 0.05\nturned_frames = {k}")),
            &[
                "reach.turned_frames",
                "from 1 (none turned) to 16",
                &format!("found {k}"),
            ],
        );
    }
}

#[test]
fn non_positive_dt_and_horizon() {
    assert_mentions(&error_for("dt = 0.05", "dt = 0"), &["reach.dt", "dt > 0"]);
    assert_mentions(&error_for("dt = 0.05", "dt = -1"), &["reach.dt", "dt > 0"]);
    assert_mentions(
        &error_for("horizon = 1.0", "horizon = -2"),
        &["reach.horizon"],
    );
    assert_mentions(&error_for("dt = 0.05", "dt = nan"), &["reach.dt", "finite"]);
    // Longer than the horizon (1.0): it used to run one step of 1e308, every box `unknown`.
    assert_mentions(
        &error_for("dt = 0.05", "dt = 1e308"),
        &["reach.dt", "longer than the horizon", "dt ≤ horizon"],
    );
}

#[test]
fn bad_settings_and_unknown_keys() {
    assert_mentions(&error_for("m_c = 0.1", "m_c = -0.1"), &["reach.m_c"]);
    assert_mentions(
        &error_for("m_c = 0.1", r#"m_c = "guessed""#),
        &["reach.m_c", "certified"],
    );
    assert_mentions(
        &error_for("m_c = 0.1", "m_c = 0.1\nnorm = \"3\""),
        &["reach.norm", "\"inf\""],
    );
    // A value of the wrong shape shows the line and says what the key takes (not serde's "did
    // not match any variant of untagged enum").
    for (from, to, key, expected) in [
        ("m_c = 0.1", "m_c = [0.1]", "m_c = [0.1]", "\"certified\""),
        (
            "m_c = 0.1",
            "m_c = 0.1\ntransform = [1.0, 0.0, 0.0, 1.0]",
            "transform = [1.0",
            "as rows",
        ),
        (
            "goal = { lower = [-0.1, -0.1]",
            "goal = { lower = [true, -0.1]",
            "goal",
            "expression",
        ),
    ] {
        let message = error_for(from, to);
        assert_mentions(&message, &[key, expected]);
        assert!(!message.contains("untagged"), "{message}");
    }
    // A typo in a key is caught, not ignored.
    assert_mentions(&error_for("dt = 0.05", "dtt = 0.05"), &["test.toml", "dtt"]);
    // Invalid TOML says where.
    assert_mentions(
        &error_for("dt = 0.05", "dt = = 0.05"),
        &["test.toml", "line"],
    );
    assert_mentions(
        &error_for(r#"states = ["x", "y"]"#, r#"states = ["x", "x"]"#),
        &["system.states[1]", "twice"],
    );
    assert_mentions(
        &error_for(
            "[[cbf]]\nh = \"y + 2\"",
            "[[cbf]]\nh = \"y + 2\"\nalpha = 0",
        ),
        &["cbf[0].alpha", "positive"],
    );
    // A class-K function of h: what is not one is refused by what fails, naming the key.
    for (alpha, expected) in [
        (r#""h + 1""#, "α(0) = 1"),
        (r#""sqrt(h)""#, "Lipschitz"),
        (r#""h - h^2""#, "increases"),
        (r#""-h^3""#, "positive"),
        (r#""h*y""#, "unknown symbol `y`"),
    ] {
        let message = error_for(
            "[[cbf]]\nh = \"y + 2\"",
            &format!("[[cbf]]\nh = \"y + 2\"\nalpha = {alpha}"),
        );
        assert_mentions(&message, &["test.toml", "cbf[0].alpha", expected]);
    }
    for alpha in [r#""h^3 + 0.5*h""#, r#""tanh(h)""#, r#""2*k""#] {
        let text = SMALL
            .replace(
                "[[cbf]]\nh = \"y + 2\"",
                &format!("[[cbf]]\nh = \"y + 2\"\nalpha = {alpha}"),
            )
            .replace("[system]", "[parameters]\nk = 1.5\n[system]");
        assert!(
            from_text(&text).is_ok(),
            "{alpha}: {:?}",
            from_text(&text).err()
        );
    }
}

/// `order = r`: a relative degree from 1 to 4, above every level the input acts on, and one
/// class-K function or one per level; refused by the key that is wrong.
#[test]
fn high_order_cbfs_are_refused_by_the_key_that_is_wrong() {
    let cbf = "[[cbf]]\nh = \"y + 2\"";
    for (order, expected) in [("0", "1 to 4, found 0"), ("5", "1 to 4, found 5")] {
        let message = error_for(cbf, &format!("{cbf}\norder = {order}"));
        assert_mentions(&message, &["test.toml", "cbf[0].order", expected]);
    }
    // The input acts on y + 2 itself: relative degree one.
    let message = error_for(cbf, &format!("{cbf}\norder = 2"));
    assert_mentions(
        &message,
        &[
            "cbf[0].order",
            "acts on h1 already",
            "relative degree is 1",
            "order = 1",
        ],
    );
    // A position bound (f = [y, -x], the input on y): relative degree two.
    let position = "[[cbf]]\nh = \"x + 2\"\norder = 2";
    let message = error_for(cbf, &format!("{position}\nalpha = [1, 2, 3]"));
    assert_mentions(
        &message,
        &["cbf[0].alpha", "expected 2 class-K functions", "found 3"],
    );
    let message = error_for(cbf, &format!("{position}\nalpha = [1, \"h - h^2\"]"));
    assert_mentions(&message, &["cbf[0].alpha[1]", "increases"]);
    let message = error_for(cbf, &format!("{position}\nalpha = [\"-h\", 1]"));
    assert_mentions(&message, &["cbf[0].alpha[0]", "positive"]);
    let message = error_for(cbf, &format!("{position}\nalpha = \"-h\""));
    assert_mentions(&message, &["cbf[0].alpha", "positive"]);
    let s = from_text(&SMALL.replace(cbf, &format!("{position}\nalpha = [1, \"h^3 + h\"]")))
        .expect("valid");
    let names: Vec<&str> = s.cbfs.iter().map(|c| c.name.as_str()).collect();
    assert_eq!(names, ["h1", "h1.psi1"]);
    assert!(s.cbfs[0].inert && !s.cbfs[1].inert);
    // ψ₁ = ∇h·f̃ + α₁(h) = y + (x + 2), whatever α₂ is.
    for x in [[0.3, -0.7], [-1.0, 1.0], [0.9, 0.2]] {
        let psi = x[1] + x[0] + 2.0;
        assert!((s.cbfs[1].h.eval(&x) - psi).abs() < 1e-15, "{x:?}");
    }
}

#[test]
fn network_architecture_must_match_the_system() {
    let text = format!("{SMALL}\n[network]\nfile = \"n.safetensors\"\narchitecture = [2, 8, 2]\n");
    let m = from_text(&text)
        .expect_err("m = 1 but the network has 2 outputs")
        .to_string();
    assert_mentions(&m, &["network.architecture", "2×…×1"]);
}

#[test]
fn cbf_not_differentiable_where_evaluated() {
    let s = from_text(&SMALL.replace(r#"h = "y + 2""#, r#"h = "abs(x) + y + 2""#)).unwrap();
    let filter = SafetyFilter::new(&s);
    // Smooth away from x = 0 ...
    assert!(filter.eval(&[0.5, 0.0]).is_ok());
    // ... and at the kink the filter says so instead of using a made-up gradient.
    match filter.eval(&[0.0, 0.0]) {
        Err(FilterError::NotDifferentiable { what, x }) => {
            assert!(what.contains("h1"), "{what}");
            assert_eq!(x, vec![0.0, 0.0]);
        }
        other => panic!("expected NotDifferentiable, got {other:?}"),
    }
}

#[test]
fn missing_file_names_the_file() {
    let e = cbfreach::scenario::Scenario::load(std::path::Path::new("no/such/file.toml"))
        .expect_err("missing");
    assert_mentions(&e.to_string(), &["no/such/file.toml", "cannot read"]);
}

/// `reach.m_c` left out is the error map's local bounds (what `cbfreach error` writes, the
/// four-command workflow of the README), and where that map is missing the error says the key,
/// the value as the file would write it and what to run. Before, a scenario without `m_c` was
/// refused by the TOML reader (`missing field m_c`), and the message printed `Local`.
#[test]
fn m_c_left_out_takes_the_error_map_and_names_it_when_missing() {
    use cbfreach::scenario::Margin;
    use cbfreach::{ProblemOptions, ReachProblem, Scenario};
    let s = from_text(&SMALL.replacen("m_c = 0.1\n", "", 1)).expect("m_c may be left out");
    assert_eq!(s.reach.m_c, Margin::Local);
    // chain3's network is shipped, its error map is not.
    let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures");
    let text = std::fs::read_to_string(dir.join("chain3.toml")).unwrap();
    assert!(text.contains("\nm_c = 0.35"), "fixture changed");
    let text: String = text
        .lines()
        .filter(|l| !l.starts_with("m_c ="))
        .collect::<Vec<_>>()
        .join("\n");
    let s = Scenario::from_toml(&text, "chain3.toml", &dir).unwrap();
    let e = ReachProblem::from_scenario(&s, &ProblemOptions::default()).unwrap_err();
    assert_mentions(
        &e.to_string(),
        &[
            "reach.m_c = \"local\"",
            "chain3.errormap.json",
            "run `cbfreach error",
        ],
    );
}

/// `[system] units` labels states and inputs (`v [m/s]`); a name that is neither, or a unit
/// that is empty, long or holds control characters, is refused by key.
#[test]
fn units_label_axes_and_bad_ones_are_named() {
    let with = |units: &str| {
        SMALL.replacen(
            r#"kappa = ["-x - y"]"#,
            &format!("kappa = [\"-x - y\"]\n{units}"),
            1,
        )
    };
    let s = from_text(&with(r#"units = { x = "m", u = "N" }"#)).expect("valid");
    assert_eq!(
        (s.label("x"), s.label("y"), s.label("u")),
        ("x [m]".into(), "y".into(), "u [N]".into())
    );
    assert_eq!(s.input_unit(), Some("N"));
    let s = from_text(&with(r#"units = { x = "m", t = "s" }"#)).expect("valid");
    assert_eq!((s.input_unit(), s.time_label()), (None, "t [s]".into()));
    for (units, parts) in [
        (
            r#"units = { q = "m" }"#,
            &[
                "system.units.q",
                "neither a state nor an input",
                "x, y",
                "u",
            ][..],
        ),
        (
            r#"units = { x = "" }"#,
            &["system.units.x", "expected a unit"][..],
        ),
        (
            r#"units = { x = "metres per second squared" }"#,
            &["system.units.x", "24"][..],
        ),
        (
            r#"units = { x = "m\ns" }"#,
            &["system.units.x", "printable"][..],
        ),
    ] {
        match from_text(&with(units)) {
            Ok(_) => panic!("`{units}` was accepted"),
            Err(e) => assert_mentions(&e.to_string(), parts),
        }
    }
}

/// A training grid is refused before it is built where its samples would not fit in memory:
/// 20 million points in two states, fewer where each point holds more numbers (six states and
/// three inputs: 27 a point, 5.9 million points).
#[test]
fn a_training_grid_too_large_for_memory_is_refused_by_size() {
    use cbfreach::dataset::training_points;
    let small = from_text(SMALL).unwrap();
    let e = training_points(&small, Some(&vec![4473, 4473])).unwrap_err();
    assert!(
        e.contains("more than the 20000000") && e.contains("2 states and 1 inputs"),
        "{e}"
    );
    let six = from_text(
        &SMALL
            .replace(r#"states = ["x", "y"]"#, r#"states = ["x", "y", "a", "b", "c", "d"]"#)
            .replace(r#"inputs = ["u"]"#, r#"inputs = ["u", "w", "z"]"#)
            .replace(r#"f = ["y", "-x"]"#, r#"f = ["y", "-x", "0", "0", "0", "0"]"#)
            .replace(
                r#"g = [["0"], ["1"]]"#,
                r#"g = [["0", "0", "0"], ["1", "0", "0"], ["0", "1", "0"], ["0", "0", "1"], ["0", "0", "0"], ["0", "0", "0"]]"#,
            )
            .replace(r#"kappa = ["-x - y"]"#, r#"kappa = ["-x - y", "-a", "-b"]"#)
            .replace("lower = [-1, -1]", "lower = [-1, -1, -1, -1, -1, -1]")
            .replace("upper = [1, 1]", "upper = [1, 1, 1, 1, 1, 1]")
            .replace(
                "{ lower = [-0.1, -0.1], upper = [0.1, 0.1] }",
                "{ lower = [-0.1, -0.1, -0.1, -0.1, -0.1, -0.1], upper = [0.1, 0.1, 0.1, 0.1, 0.1, 0.1] }",
            ),
    )
    .unwrap();
    let e = training_points(&six, Some(&vec![14; 6])).unwrap_err();
    assert!(
        e.contains("7529536 points, more than the 5925925") && e.contains("27 numbers a point"),
        "{e}"
    );
}

/// The device does not evaluate `atan` or `atan2`: a problem whose closed loop calls one is
/// refused by name (so `auto` takes the CPU engine) before any adapter is asked for.
#[test]
fn the_device_refuses_atan_by_name() {
    use cbfreach::expressions::Func;
    let text = |kappa: &str| {
        format!(
            r#"
name = "heading"
[system]
states = ["x", "y"]
inputs = ["u"]
f = ["0", "0"]
g = [["1"], ["0"]]
kappa = ["{kappa}"]
[[cbf]]
h = "x + 2"
[reach]
region = {{ lower = [-1, 0.5], upper = [1, 1.5] }}
m_c = 0.01
dt = 0.02
horizon = 1.0
goal = {{ lower = [-0.1, 0.9], upper = [0.1, 1.1] }}
"#
        )
    };
    let problem = |kappa: &str| {
        let s = common::from_text(&text(kappa)).unwrap();
        cbfreach::reach::ReachProblem::new(&s, cbfreach::network::Mlp::random(&[2, 8, 1], 1), 0.01)
            .unwrap()
    };
    let settings = cbfreach::reach::ReachSettings::default();
    for (kappa, refused) in [
        ("-atan2(x, y)", Some(Func::Atan2)),
        ("-atan(x)", Some(Func::Atan)),
        ("-x", None),
    ] {
        let p = problem(kappa);
        assert_eq!(
            cbfreach::gpu::codegen::not_on_device(&p),
            refused,
            "{kappa}"
        );
        let runs = cbfreach::gpu::GpuBackend::runs(&p, &settings);
        match refused {
            Some(f) => {
                let why = runs.unwrap_err();
                assert_eq!(why, cbfreach::reach::Unsupported::Function(f.name()));
                let said = cbfreach::reach::refusal(why);
                assert!(
                    said.contains(f.name()) && said.contains("--backend cpu"),
                    "{said}"
                );
            }
            None => assert!(runs.is_ok(), "{kappa}: {runs:?}"),
        }
    }
}
