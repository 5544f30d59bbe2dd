//! Issue 39: nothing a user types crashes the program, nothing stale is trusted, no work is
//! lost. One test (at least) per class: panic, abort, hang, silent acceptance, truncated file;
//! each failed on the code before the issue.

mod common;
use common::cbfreach;

use std::io::Write;
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};

use cbfreach::error_map::{error_map_path, CellBound, ErrorMap, ErrorMapError};
use cbfreach::problem::ProblemOptions;
use cbfreach::reach::{CpuBackend, ReachProblem, ReachSettings};
use cbfreach::verify::checkpoint::{Checkpoint, Journal};
use cbfreach::verify::{merge, BoxVerdict, Verifier, VerifyError, VerifySettings};
use cbfreach::{IntervalBox, Mlp, Scenario};

/// Runs the binary: (exit code, stdout, stderr); -1 for a signal.
/// A small scenario with a 2×8×1 network in a fresh folder: (folder, scenario file).
fn small(dir: &Path, edit: &[(&str, &str)]) -> PathBuf {
    let net = dir.join("net.safetensors");
    if !net.exists() {
        Mlp::random(&[2, 8, 1], 3)
            .save_safetensors(&net, &Default::default())
            .unwrap();
    }
    let mut text = format!(
        "{}\n[network]\nfile = \"net.safetensors\"\narchitecture = [2, 8, 1]\n",
        common::SMALL
    );
    for (from, to) in edit {
        assert!(text.contains(from), "{from}");
        text = text.replace(from, to);
    }
    let path = dir.join("s.toml");
    std::fs::write(&path, text).unwrap();
    path
}

fn no_panic(code: i32, stderr: &str) {
    assert!(code != 101 && code != -1, "code {code}: {stderr}");
    assert!(!stderr.contains("panicked"), "{stderr}");
}

// --- panics -----------------------------------------------------------------------------------

#[test]
fn a_huge_partition_is_an_error_not_a_panic() {
    let dir = tempfile::tempdir().unwrap();
    let s = small(
        dir.path(),
        &[(
            "horizon = 1.0",
            "horizon = 1.0\npartition = { lower = [-1, -1], upper = [1, 1], counts = [4000000000, 4000000000] }",
        )],
    );
    let (code, _, err) = cbfreach(&["check", s.to_str().unwrap()]);
    no_panic(code, &err);
    assert_eq!(code, 2);
    assert!(err.contains("reach.partition.counts"), "{err}");
}

/// Runs cbfreach with `args` (and `last`, a path) with its standard output a pipe whose reader
/// is gone (`| head -c 0`). The reading end is closed before the process starts: closed after
/// the spawn, a fast command could fill the pipe's buffer first and succeed.
fn with_stdout_closed(args: &[&str], last: Option<&Path>) -> std::process::Output {
    let (reader, writer) = std::io::pipe().unwrap();
    drop(reader);
    Command::new(env!("CARGO_BIN_EXE_cbfreach"))
        .args(args)
        .args(last)
        .stdout(writer)
        .stderr(Stdio::piped())
        .output()
        .unwrap()
}

#[test]
fn a_full_or_closed_standard_output_ends_with_a_message_after_the_files() {
    let dir = tempfile::tempdir().unwrap();
    let s = small(dir.path(), &[]);
    // /dev/full: every write fails.
    let full = std::fs::OpenOptions::new()
        .write(true)
        .open("/dev/full")
        .unwrap();
    let out = Command::new(env!("CARGO_BIN_EXE_cbfreach"))
        .args(["check", s.to_str().unwrap()])
        .stdout(full)
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    no_panic(out.status.code().unwrap_or(-1), &err);
    assert_eq!(out.status.code(), Some(2), "{err}");
    assert!(err.contains("standard output"), "{err}");
    // A closed pipe (`| head -c 0`), with a result file that must still be written.
    let json = dir.path().join("v.json");
    let s = s.to_str().unwrap();
    let grid = ["verify", s, "--time", "euler", "--grid", "4,4", "--json"];
    let out = with_stdout_closed(&grid, Some(&json));
    let err = String::from_utf8_lossy(&out.stderr);
    no_panic(out.status.code().unwrap_or(-1), &err);
    assert_ne!(out.status.code(), Some(0), "{err}");
    let text = std::fs::read_to_string(&json).unwrap();
    assert!(cbfreach::VerifyReport::from_json(&text, "v.json").is_ok());
}

/// A reader that closes the pipe (`cbfreach simulate … | head`) ends the output it wanted: the
/// run ends quietly, with the status of a process the pipe's signal ended (128 + 13), as `cat`
/// does (before: `error: Broken pipe (os error 32)`, and a panic before that).
#[test]
fn a_closed_pipe_ends_quietly() {
    let dir = tempfile::tempdir().unwrap();
    let s = small(dir.path(), &[]);
    for args in [
        &["simulate", s.to_str().unwrap(), "--samples", "200"][..],
        &["check", s.to_str().unwrap()][..],
    ] {
        let out = with_stdout_closed(args, None);
        let err = String::from_utf8_lossy(&out.stderr);
        no_panic(out.status.code().unwrap_or(-1), &err);
        assert_eq!(out.status.code(), Some(141), "{args:?}: {err}");
        assert!(err.trim().is_empty(), "{args:?}: {err}");
    }
}

// --- aborts -----------------------------------------------------------------------------------

#[test]
fn an_expression_whose_derivatives_explode_is_refused_up_front() {
    let dir = tempfile::tempdir().unwrap();
    let product = vec!["(x + 3)"; 1000].join("*");
    let s = small(
        dir.path(),
        &[("h = \"y + 2\"", &format!("h = \"{product}\""))],
    );
    let (code, _, err) = cbfreach(&["reach", s.to_str().unwrap()]);
    no_panic(code, &err);
    assert_eq!(code, 2, "{err}");
    assert!(err.contains("cbf[0].h") && err.contains("nodes"), "{err}");
}

#[test]
fn equilibria_of_six_states_end() {
    let dir = tempfile::tempdir().unwrap();
    let text = r#"
name = "six"
[system]
states = ["a", "b", "c", "d", "e", "f"]
inputs = ["u"]
f = ["-a", "-b", "-c", "-d", "-e", "-f"]
g = [["0"], ["0"], ["0"], ["0"], ["0"], ["1"]]
kappa = ["0"]
[reach]
region = { lower = [-1, -1, -1, -1, -1, -1], upper = [1, 1, 1, 1, 1, 1] }
m_c = 0.1
dt = 0.1
horizon = 1.0
goal = { lower = [-0.1, -0.1, -0.1, -0.1, -0.1, -0.1], upper = [0.1, 0.1, 0.1, 0.1, 0.1, 0.1] }
"#;
    let path = dir.path().join("six.toml");
    std::fs::write(&path, text).unwrap();
    let (code, out, err) = cbfreach(&["equilibria", path.to_str().unwrap()]);
    no_panic(code, &err);
    assert_eq!(code, 0, "{err}");
    assert!(out.contains("1 isolated equilibria"), "{out}");
}

// --- hangs ------------------------------------------------------------------------------------

#[test]
fn a_run_of_billions_of_steps_is_refused() {
    let dir = tempfile::tempdir().unwrap();
    for (edit, shown) in [
        (("horizon = 1.0", "horizon = 1e9"), "horizon 1e9 / dt 0.05"),
        (("dt = 0.05", "dt = 1e-300"), "horizon 1 / dt 1e-300"),
        (
            ("horizon = 1.0", "horizon = 1e300"),
            "horizon 1e300 / dt 0.05",
        ),
    ] {
        let s = small(dir.path(), &[edit]);
        let (code, _, err) = cbfreach(&["check", s.to_str().unwrap()]);
        no_panic(code, &err);
        assert_eq!(code, 2);
        // The numbers as typed, not 300 digits.
        assert!(
            err.contains("reach.horizon") && err.contains("steps") && err.contains(shown),
            "{err}"
        );
    }
    let s = small(dir.path(), &[]);
    let (code, _, err) = cbfreach(&["simulate", s.to_str().unwrap(), "--horizon", "1e300"]);
    no_panic(code, &err);
    assert_eq!(code, 2, "{err}");
    assert!(err.contains("--horizon 1e300 / --dt 0.05"), "{err}");
    // The same number of steps asked for on the command line (it ran on, silently).
    let s = small(dir.path(), &[]);
    let (code, _, err) = cbfreach(&["reach", s.to_str().unwrap(), "--substeps", "1000000000"]);
    no_panic(code, &err);
    assert_eq!(code, 2, "{err}");
    assert!(err.contains("--substeps 1000000000"), "{err}");
}

/// A control period where nothing is sampled was ignored; one of 10³⁰⁰ hung the engine.
#[test]
fn control_periods_that_hold_nothing_or_forever_are_refused() {
    let dir = tempfile::tempdir().unwrap();
    let s = small(dir.path(), &[]);
    let s = s.to_str().unwrap();
    for args in [
        vec!["reach", s, "--control-period", "0.1"],
        vec!["reach", s, "--time", "sampled", "--control-period", "1e300"],
    ] {
        let (code, _, err) = cbfreach(&args);
        no_panic(code, &err);
        assert_eq!(code, 2, "{args:?}: {err}");
        assert!(
            err.contains("control") && !err.contains("00000000"),
            "{err}"
        );
    }
}

/// `error --max-cells 0` certified for 40 s and wrote a map of `M = ∞` beside the network;
/// the other counts and widths of `error` took any value. Refused before any work.
#[test]
fn error_refuses_empty_budgets_and_widths() {
    let dir = tempfile::tempdir().unwrap();
    let s = small(dir.path(), &[]);
    let s = s.to_str().unwrap();
    for (option, value) in [
        ("--max-cells", "0"),
        ("--budget", "0"),
        ("--refine", "0"),
        ("--local-ratio", "0.5"),
        ("--floor", "-0.5"),
        ("--box-width", "0"),
        ("--min-cell", "nan"),
    ] {
        let (code, _, err) = cbfreach(&["error", s, &format!("{option}={value}")]);
        no_panic(code, &err);
        assert_eq!(code, 2, "{option} {value}: {err}");
        assert!(err.contains(option), "{err}");
    }
    let left: Vec<_> = std::fs::read_dir(dir.path())
        .unwrap()
        .flatten()
        .map(|e| e.file_name())
        .filter(|n| n.to_string_lossy().contains("errormap"))
        .collect();
    assert!(left.is_empty(), "{left:?}");
}

/// `bench` with an empty batch printed NaN rates; with 10¹¹ boxes it filled the memory.
#[test]
fn bench_refuses_empty_and_huge_batches_by_name() {
    for (option, value) in [
        ("--boxes", "0"),
        ("--boxes", "1,100000000000"),
        ("--steps", "0"),
    ] {
        let (code, out, err) = cbfreach(&["bench", "--backend", "cpu", option, value]);
        no_panic(code, &err);
        assert_eq!(code, 2, "{out}{err}");
        assert!(err.contains(option), "{err}");
        assert!(!out.contains("NaN"), "{out}");
    }
}

// --- silent acceptance ------------------------------------------------------------------------

#[test]
fn nan_over_the_region_is_refused() {
    let dir = tempfile::tempdir().unwrap();
    let s = small(dir.path(), &[("h = \"y + 2\"", "h = \"1/(x-x)\"")]);
    let (code, _, err) = cbfreach(&["check", s.to_str().unwrap()]);
    assert_eq!(code, 2);
    assert!(err.contains("cbf[0].h") && err.contains("finite"), "{err}");
    let s = small(dir.path(), &[]);
    let (code, _, err) = cbfreach(&["simulate", s.to_str().unwrap(), "--from", "nan,0"]);
    assert_eq!(code, 2, "{err}");
    assert!(err.contains("finite"), "{err}");
}

#[test]
fn the_architecture_is_checked_against_the_network_file() {
    let dir = tempfile::tempdir().unwrap();
    let s = small(
        dir.path(),
        &[(
            "architecture = [2, 8, 1]",
            "architecture = [2, 400, 400, 1]",
        )],
    );
    let (code, _, err) = cbfreach(&["check", s.to_str().unwrap()]);
    assert_eq!(code, 2);
    assert!(
        err.contains("2×400×400×1") && err.contains("2×8×1"),
        "{err}"
    );
}

/// A stamped map of 4 × 4 cells with bound 0.05 over C of the small scenario, beside its
/// network: (scenario file, network file).
fn stamped_map(dir: &Path) -> (PathBuf, PathBuf) {
    let file = small(dir, &[("m_c = 0.1", "m_c = \"local\"")]);
    let s = Scenario::load(&file).unwrap();
    let net = dir.join("net.safetensors");
    let cells: Vec<CellBound> = s
        .reach
        .region
        .partition(&[4, 4])
        .into_iter()
        .map(|c| CellBound {
            lower: c.lower,
            upper: c.upper,
            bound: 0.05,
        })
        .collect();
    let mut map =
        ErrorMap::from_bounds(&net, &s.reach.region, 0.04, 0.04, Some((0.05, &cells))).unwrap();
    map.stamp(&s, &net).unwrap();
    map.save(&error_map_path(&net)).unwrap();
    (file, net)
}

#[test]
fn an_error_map_is_refused_when_what_it_certifies_against_changed() {
    let dir = tempfile::tempdir().unwrap();
    let (file, net) = stamped_map(dir.path());
    let s = Scenario::load(&file).unwrap();
    assert!(ReachProblem::from_scenario(&s, &ProblemOptions::default()).is_ok());
    // Another class-K gain, another obstacle, another region: each refused, by name.
    for (edit, what) in [
        (("h = \"y + 2\"", "h = \"y + 2\"\nalpha = 0.3"), "filter"),
        (("h = \"y + 2\"", "h = \"y + 1.5\""), "filter"),
        (("upper = [1, 1] }", "upper = [1, 1.5] }"), "region"),
    ] {
        let changed = small(dir.path(), &[("m_c = 0.1", "m_c = \"local\""), edit]);
        let s = Scenario::load(&changed).unwrap();
        let e = ErrorMap::load_certified(&net, &s).unwrap_err();
        assert!(matches!(&e, ErrorMapError::Changed { .. }), "{e}");
        assert!(e.to_string().contains(what), "{e}");
        let e = ReachProblem::from_scenario(&s, &ProblemOptions::default())
            .err()
            .unwrap();
        assert!(e.to_string().contains(what), "{e}");
    }
    // A map from before provenance is refused too.
    let s = Scenario::load(&small(dir.path(), &[("m_c = 0.1", "m_c = \"local\"")])).unwrap();
    let mut old = ErrorMap::load(&error_map_path(&net)).unwrap();
    old.provenance = None;
    old.save(&error_map_path(&net)).unwrap();
    assert!(matches!(
        ErrorMap::load_certified(&net, &s),
        Err(ErrorMapError::Unstamped { .. })
    ));
}

#[test]
fn a_map_with_cells_removed_does_not_verify_more() {
    let dir = tempfile::tempdir().unwrap();
    let (file, net) = stamped_map(dir.path());
    let s = Scenario::load(&file).unwrap();
    let mut map = ErrorMap::load(&error_map_path(&net)).unwrap();
    map.cells.truncate(8);
    map.save(&error_map_path(&net)).unwrap();
    assert!(matches!(
        ErrorMap::load_certified(&net, &s),
        Err(ErrorMapError::CellsChanged { .. })
    ));
    // Even with its hash made to match, the cells no longer cover C.
    map.cells_hash = Some(map.cells_digest());
    map.save(&error_map_path(&net)).unwrap();
    let e = ErrorMap::load_certified(&net, &s).unwrap_err();
    assert!(matches!(e, ErrorMapError::Uncovered { .. }), "{e}");
    // And a box where no cell is bounds +∞, never 0.
    let map = map.reindexed();
    let hole = IntervalBox::new(vec![0.6, 0.6], vec![0.7, 0.7]).unwrap();
    assert_eq!(map.local_bound(&hole), f64::INFINITY);
}

#[test]
fn merge_refuses_shards_of_different_networks() {
    let dir = tempfile::tempdir().unwrap();
    let s = small(dir.path(), &[]);
    let mut files = Vec::new();
    for (k, seed) in [(1, 3), (2, 4)] {
        // The second shard runs with another network file.
        if k == 2 {
            Mlp::random(&[2, 8, 1], seed)
                .save_safetensors(&dir.path().join("net.safetensors"), &Default::default())
                .unwrap();
        }
        let json = dir.path().join(format!("shard{k}.json"));
        let shard = format!("{k}/2");
        let (code, _, err) = cbfreach(&[
            "verify",
            s.to_str().unwrap(),
            "--time",
            "euler",
            "--grid",
            "2,2",
            "--shard",
            &shard,
            "--json",
            json.to_str().unwrap(),
        ]);
        assert!(code == 0 || code == 2, "{err}");
        files.push(json);
    }
    let parts: Vec<_> = files
        .iter()
        .map(|f| {
            let text = std::fs::read_to_string(f).unwrap();
            (
                f.display().to_string(),
                cbfreach::VerifyReport::from_json(&text, "x").unwrap(),
            )
        })
        .collect();
    let e = merge(parts).unwrap_err().to_string();
    assert!(e.contains("network_hash"), "{e}");
}

// --- truncated files --------------------------------------------------------------------------

#[test]
fn a_write_cut_short_leaves_the_old_file() {
    let dir = tempfile::tempdir().unwrap();
    let s = small(dir.path(), &[]);
    let out = dir.path().join("t.json");
    std::fs::write(&out, "GOOD").unwrap();
    // A file-size limit of 4 × 512 bytes: the write is cut short (SIGXFSZ).
    let status = Command::new("sh")
        .arg("-c")
        .arg(format!(
            "ulimit -f 4; exec {} simulate {} --samples 200 --format json --out {}",
            env!("CARGO_BIN_EXE_cbfreach"),
            s.display(),
            out.display()
        ))
        .output()
        .unwrap();
    assert!(!status.status.success());
    assert_eq!(std::fs::read_to_string(&out).unwrap(), "GOOD");
}

#[test]
fn output_paths_are_checked_before_the_work() {
    let dir = tempfile::tempdir().unwrap();
    let s = small(dir.path(), &[]);
    let (code, out, err) = cbfreach(&[
        "verify",
        s.to_str().unwrap(),
        "--json",
        "/no/such/folder/v.json",
    ]);
    assert_eq!(code, 2);
    assert!(err.contains("/no/such/folder/v.json"), "{err}");
    assert!(!out.contains("verdict"), "ran before failing: {out}");
    // train (it trained, then failed on its first checkpoint), dataset (it sampled the
    // filter first) and plot (the figure's work first, then a backend's error).
    let s = s.to_str().unwrap();
    for args in [
        vec![
            "train",
            s,
            "--grid",
            "5,5",
            "--epochs",
            "1",
            "-o",
            "/no/such/folder/n.safetensors",
        ],
        vec!["dataset", s, "--grid", "5,5", "-o", "/no/such/folder/d.csv"],
        vec![
            "plot",
            s,
            "--figure",
            "tubes",
            "-o",
            "/no/such/folder/p.png",
        ],
    ] {
        let (code, out, err) = cbfreach(&args);
        no_panic(code, &err);
        assert_eq!(code, 2, "{args:?}: {err}");
        assert!(err.contains("/no/such/folder/"), "{err}");
        assert!(
            !err.contains("backend error") && !out.contains("epoch"),
            "{out}{err}"
        );
        assert!(!err.contains("epoch 1/1"), "trained before failing: {err}");
    }
}

/// A journal that stops the run after `stop_after` recorded chunks.
struct StopAfter<'a> {
    inner: &'a Checkpoint,
    left: std::sync::atomic::AtomicUsize,
}

impl Journal for StopAfter<'_> {
    fn lookup(&self, cell: usize, depth: usize, b: &IntervalBox) -> Option<(BoxVerdict, usize)> {
        self.inner.lookup(cell, depth, b)
    }
    fn record(&self, done: &[(BoxVerdict, usize)]) -> Result<(), VerifyError> {
        self.left.fetch_sub(1, std::sync::atomic::Ordering::SeqCst);
        self.inner.record(done)
    }
    fn stop_requested(&self) -> bool {
        self.left.load(std::sync::atomic::Ordering::SeqCst) == 0
    }
}

#[test]
fn an_interrupted_verification_resumes_to_the_same_report() {
    let s = common::integrator();
    let problem = common::shipped_problem(&s).with_time(cbfreach::reach::TimeModel::Euler, 1);
    let verifier = Verifier {
        scenario: &s,
        problem: &problem,
        backend: &CpuBackend,
        reach: ReachSettings::default(),
        traps: cbfreach::verify::traps_for(&s),
    };
    let settings = VerifySettings {
        grid: vec![6, 4],
        refine_depth: 2,
        chunk: Some(4),
        ..VerifySettings::default()
    };
    let whole = verifier.run(&settings, &|_, _, _| {}).unwrap();
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("v.checkpoint");
    let id = |k: &str| [("settings".to_string(), k.to_string())].into();
    // Stopped twice (in the grid, then in a refinement round), resumed each time.
    let first = Checkpoint::create(&path, id("a")).unwrap();
    let stop = StopAfter {
        inner: &first,
        left: 3.into(),
    };
    let e = verifier
        .run_journaled(&settings, &|_, _, _| {}, &stop)
        .unwrap_err();
    assert!(matches!(e, VerifyError::Interrupted));
    drop(first);
    // A line cut short by a crash is dropped.
    std::fs::OpenOptions::new()
        .append(true)
        .open(&path)
        .unwrap()
        .write_all(b"{\"cell\": 3, \"dep")
        .unwrap();
    let second = Checkpoint::resume(&path, id("a")).unwrap();
    assert!(second.recorded() > 0, "{}", second.recorded());
    let stop = StopAfter {
        inner: &second,
        left: 5.into(),
    };
    assert!(verifier
        .run_journaled(&settings, &|_, _, _| {}, &stop)
        .is_err());
    drop(second);
    // Another run's identity is refused, by name.
    let e = Checkpoint::resume(&path, id("b"))
        .err()
        .unwrap()
        .to_string();
    assert!(e.contains("settings changed"), "{e}");
    let third = Checkpoint::resume(&path, id("a")).unwrap();
    let resumed = verifier
        .run_journaled(&settings, &|_, _, _| {}, &third)
        .unwrap();
    let strip = |r: &cbfreach::VerifyReport| {
        let mut r = r.clone();
        r.timing.reach_s = 0.0;
        r.timing.total_s = 0.0;
        r.to_json()
    };
    assert_eq!(strip(&resumed), strip(&whole));
    assert!(whole.after.len() > whole.before.len(), "refinement ran");
    // The UNSAFE banner counts a box once, though it is in `before` and `after` alike.
    let mut r = whole.clone();
    r.before[0].verdict = cbfreach::Verdict::Unsafe;
    r.after = r.before.clone();
    assert_eq!(r.unsafe_boxes().len(), 1);
}

#[test]
fn error_keeps_a_tighter_map_unless_forced() {
    // The shipped-map loss: a quick `error` run must not replace a tighter certified map.
    let dir = tempfile::tempdir().unwrap();
    let (file, net) = stamped_map(dir.path());
    let map_file = error_map_path(&net);
    let tight = std::fs::read(&map_file).unwrap();
    let args = |force: bool| {
        let mut a = vec![
            "error",
            file.to_str().unwrap(),
            "--budget",
            "200",
            "--looseness-boxes",
            "0",
        ];
        if force {
            a.push("--force");
        }
        a.into_iter().map(String::from).collect::<Vec<_>>()
    };
    let run = |force: bool| {
        let a = args(force);
        cbfreach(&a.iter().map(String::as_str).collect::<Vec<_>>())
    };
    // The random network is far from the filter: its certified bound is far above 0.05.
    let (code, stdout, stderr) = run(false);
    no_panic(code, &stderr);
    assert!(
        format!("{stdout}{stderr}").contains("not replacing"),
        "{stdout}\n{stderr}"
    );
    assert_eq!(std::fs::read(&map_file).unwrap(), tight);
    // Its 200 evaluations ran out, but with the cells within their targets: no advice.
    assert!(
        stdout.contains("budget or cell cap reached") && !stdout.contains("the budget ran out"),
        "{stdout}"
    );
    let looser = map_file.with_extension("looser.json");
    let kept = ErrorMap::load(&looser).unwrap();
    assert!(kept.certified_linf.unwrap_or(f64::INFINITY) > 0.05);
    // --force replaces it, with the looser map.
    let (code, _, stderr) = run(true);
    no_panic(code, &stderr);
    assert_eq!(code, 0, "{stderr}");
    let now = ErrorMap::load(&map_file).unwrap();
    assert_ne!(std::fs::read(&map_file).unwrap(), tight);
    assert!(now.certified_linf.unwrap_or(f64::INFINITY) > 0.05);
}
