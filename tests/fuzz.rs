//! A mutation fuzzer over scenario files and expressions, run in-process through the library as
//! the CLI's `check`, `simulate`, `reach`, `equilibria` and `verify` run it: every input must
//! end in a result or an error, never a panic, an abort or a run past 5 s. `fuzz_bounded` runs
//! for a bounded time in the test suite; `fuzz_long` (ignored; `FUZZ_INPUTS=100000 cargo test
//! --release --test fuzz -- --ignored --nocapture`) is the long run whose figures are in
//! docs/results.md. Seeded (ChaCha), so a failure names its input and seed.

use std::path::Path;
use std::sync::mpsc;
use std::time::{Duration, Instant};

use cbfreach::equilibria::find_equilibria;
use cbfreach::filter::SafetyFilter;
use cbfreach::problem::ProblemOptions;
use cbfreach::reach::{Backend, CpuBackend, ReachProblem, ReachSettings};
use cbfreach::simulate::{simulate_filtered, Integrator};
use cbfreach::verify::{equilibrium_search_for, Verifier, VerifySettings};
use cbfreach::{Mlp, Scenario};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// The seeds: a small scenario with a network, and the shipped ones' text (their networks are
/// replaced by the small one, so that every run is short).
const SMALL: &str = r#"
name = "fuzz"
[parameters]
k = 1.0
[system]
states = ["x1", "x2"]
inputs = ["u"]
f = ["x2", "-x1"]
g = [["0"], ["1"]]
kappa = ["-k*x1 - 2*x2"]
[[cbf]]
name = "wall"
h = "(x1 - 2)^2 + x2^2 - 1"
alpha = 1.0
[network]
file = "net.safetensors"
architecture = [2, 8, 1]
[reach]
region = { lower = [-4, -2], upper = [6, 2] }
m_c = 0.1
dt = 0.05
horizon = 2.0
goal = { lower = [-0.5, -0.5], upper = [0.5, 0.5] }
initial = [{ lower = [-1.1, 0.9], upper = [-0.9, 1.1] }]
partition = { lower = [-3, -1], upper = [-2, 1], counts = [2, 2] }
"#;

const NUMBERS: [&str; 18] = [
    "0",
    "-0",
    "1",
    "-1",
    "1e300",
    "-1e300",
    "1e-300",
    "1e9",
    "nan",
    "inf",
    "-inf",
    "18446744073709551615",
    "4294967296",
    "2147483647",
    "0.5",
    "1e400",
    "3",
    "100000",
];

const PIECES: [&str; 20] = [
    "x1", "x2", "k", "pi", "0", "1", "1e308", "sqrt", "ln", "exp", "sin", "tanh", "abs", "min",
    "max", "^", "/", "*", "(", ")",
];

/// A random expression over x1, x2 (possibly singular, deep or large).
fn expression(rng: &mut ChaCha8Rng, depth: usize) -> String {
    if depth == 0 || rng.random_bool(0.3) {
        return match rng.random_range(0..5) {
            0 => "x1".into(),
            1 => "x2".into(),
            2 => "k".into(),
            3 => NUMBERS[rng.random_range(0..NUMBERS.len())].replace("nan", "0"),
            _ => format!("{}", rng.random_range(-5.0..5.0_f64)),
        };
    }
    let a = expression(rng, depth - 1);
    let b = expression(rng, depth - 1);
    match rng.random_range(0..12) {
        0 => format!("({a} + {b})"),
        1 => format!("({a} - {b})"),
        2 => format!("({a} * {b})"),
        3 => format!("({a} / {b})"),
        4 => format!("({a})^{}", rng.random_range(-3..40)),
        5 => format!("sqrt({a})"),
        6 => format!("ln({a})"),
        7 => format!("exp({a})"),
        8 => format!("max({a}, {b})"),
        9 => format!("abs({a})"),
        10 => format!("tanh({a})"),
        // A long product or a deep nest: the sizes that grow when differentiated.
        _ => {
            let k = rng.random_range(2..400);
            if rng.random_bool(0.5) {
                vec![format!("({a} + 1)"); k].join("*")
            } else {
                (0..k.min(250)).fold(a, |e, _| format!("sqrt({e} + 1)"))
            }
        }
    }
}

/// One mutation of scenario text.
fn mutate(rng: &mut ChaCha8Rng, text: &str) -> String {
    let mut lines: Vec<String> = text.lines().map(String::from).collect();
    let rounds = rng.random_range(1..4);
    for _ in 0..rounds {
        if lines.is_empty() {
            break;
        }
        let i = rng.random_range(0..lines.len());
        match rng.random_range(0..9) {
            // A number replaced by an extreme one.
            0 | 1 => {
                let line = &lines[i];
                let spans: Vec<(usize, usize)> = number_spans(line);
                if let Some(&(a, b)) = spans.get(rng.random_range(0..spans.len().max(1))) {
                    let n = NUMBERS[rng.random_range(0..NUMBERS.len())];
                    lines[i] = format!("{}{n}{}", &line[..a], &line[b..]);
                }
            }
            // An expression string replaced.
            2 | 3 => {
                let line = &lines[i];
                if let (Some(a), Some(b)) = (line.find('"'), line.rfind('"')) {
                    if a < b {
                        let depth = rng.random_range(1..6);
                        lines[i] = format!(
                            "{}\"{}\"{}",
                            &line[..a],
                            expression(rng, depth),
                            &line[b + 1..]
                        );
                    }
                }
            }
            4 => {
                lines.remove(i);
            }
            5 => {
                let l = lines[i].clone();
                lines.insert(i, l);
            }
            // Random pieces spliced in.
            6 => {
                let line = &lines[i];
                let at = (0..=line.len())
                    .filter(|&k| line.is_char_boundary(k))
                    .nth(rng.random_range(0..=line.chars().count()))
                    .unwrap_or(0);
                let p = PIECES[rng.random_range(0..PIECES.len())];
                lines[i] = format!("{}{p}{}", &line[..at], &line[at..]);
            }
            // A list grown or shrunk.
            7 => {
                lines[i] = lines[i]
                    .replacen("[2, 2]", "[100000, 100000]", 1)
                    .replacen("[2, 8, 1]", "[2, 400, 400, 1]", 1)
                    .replacen("\"x1\", \"x2\"", "\"x1\", \"x2\", \"x3\"", 1)
                    .replacen("[\"0\"], [\"1\"]", "[\"0\"]", 1);
            }
            _ => {
                let cut = rng.random_range(0..=lines[i].len());
                let cut = (0..=cut)
                    .rev()
                    .find(|&k| lines[i].is_char_boundary(k))
                    .unwrap_or(0);
                lines[i].truncate(cut);
            }
        }
    }
    lines.join("\n")
}

/// Byte spans of the numbers in a line.
fn number_spans(line: &str) -> Vec<(usize, usize)> {
    let b = line.as_bytes();
    let mut out = Vec::new();
    let mut k = 0;
    while k < b.len() {
        if b[k].is_ascii_digit() {
            let start = k;
            while k < b.len() && (b[k].is_ascii_digit() || b[k] == b'.' || b[k] == b'e') {
                k += 1;
            }
            out.push((start, k));
        } else {
            k += 1;
        }
    }
    out
}

/// What the inputs did.
#[derive(Debug, Default, Clone, Copy)]
struct Stats {
    inputs: usize,
    /// Scenarios that compiled (the others were refused with an error).
    valid: usize,
    /// Valid scenarios whose command ended in an error.
    errors: usize,
    panics: usize,
    /// Inputs past 5 s of CPU time (or still running after 120 s of wall time).
    timeouts: usize,
    /// Inputs past 5 s of wall time but not of CPU time (a loaded machine).
    slow_under_load: usize,
}

/// CPU time of the whole process, in seconds (the engines run on rayon's threads too).
fn process_cpu_s() -> f64 {
    let mut t = libc::timespec {
        tv_sec: 0,
        tv_nsec: 0,
    };
    // SAFETY: a valid clock id and a pointer to a timespec.
    unsafe { libc::clock_gettime(libc::CLOCK_PROCESS_CPUTIME_ID, &mut t) };
    t.tv_sec as f64 + t.tv_nsec as f64 * 1e-9
}

/// Runs one command on the scenario text (`which`: 0 check, 1 simulate, 2 reach,
/// 3 equilibria, 4 verify); `Ok(true)` when the scenario was valid.
fn run_one(text: &str, dir: &Path, which: usize) -> Result<bool, String> {
    let s = match Scenario::from_toml(text, "fuzz.toml", dir) {
        Ok(s) => s,
        Err(e) => {
            // Errors are text for the user: they must print.
            let _ = e.to_string();
            return Ok(false);
        }
    };
    // In-process runs are kept short: at most 100 steps (the limits of long runs are checked
    // up front by the scenario, which this input passed).
    let mut s = s;
    s.reach.horizon = s.reach.horizon.min(100.0 * s.reach.dt);
    match which {
        0 => {
            if s.network.as_ref().is_some_and(|n| n.file.exists()) {
                let _ = cbfreach::problem::load_network(&s, None).map_err(|e| e.to_string());
            }
        }
        1 => {
            let filter = SafetyFilter::new(&s);
            let x0 = s.reach.region.center();
            let _ = simulate_filtered(&filter, &x0, s.reach.dt, s.reach.steps(), Integrator::Euler);
        }
        2 | 4 => {
            let problem = match ReachProblem::from_scenario(&s, &ProblemOptions::default()) {
                Ok(p) => p,
                Err(e) => return Err(e.to_string()),
            };
            if which == 2 {
                let initial: Vec<_> = s.reach.initial.iter().take(4).cloned().collect();
                let _ = CpuBackend
                    .reach(&problem, &initial, &ReachSettings::default(), &|_, _| {})
                    .map_err(|e| e.to_string());
            } else {
                let verifier = Verifier {
                    scenario: &s,
                    problem: &problem,
                    backend: &CpuBackend,
                    reach: ReachSettings::default(),
                    traps: Vec::new(),
                };
                let settings = VerifySettings {
                    grid: vec![2; s.n()],
                    refine_depth: 1,
                    budget: 8,
                    ..VerifySettings::default()
                };
                let _ = verifier
                    .run(&settings, &|_, _, _| {})
                    .map_err(|e| e.to_string());
            }
        }
        _ => {
            if let Some(mut search) = equilibrium_search_for(s.n()) {
                search.starts_per_axis = search.starts_per_axis.min(6);
                let _ = find_equilibria(&SafetyFilter::new(&s), &s.reach.region, &search);
            }
        }
    }
    Ok(true)
}

/// Fuzzes `count` inputs (or until `budget` passes), each under a 5 s limit in its own thread.
fn fuzz(count: usize, seed: u64, budget: Duration) -> Stats {
    let dir = tempfile::tempdir().unwrap();
    Mlp::random(&[2, 8, 1], 3)
        .save_safetensors(&dir.path().join("net.safetensors"), &Default::default())
        .unwrap();
    Mlp::random(&[2, 8, 2], 4)
        .save_safetensors(&dir.path().join("net2.safetensors"), &Default::default())
        .unwrap();
    let seeds = [
        SMALL.to_string(),
        std::fs::read_to_string(
            Path::new(env!("CARGO_MANIFEST_DIR")).join("scenarios/integrator.toml"),
        )
        .unwrap()
        .replace("integrator.safetensors", "net2.safetensors")
        .replace("[2, 400, 400, 400, 2]", "[2, 8, 2]")
        .replace("m_c = \"local\"", "m_c = 0.2"),
    ];
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let mut stats = Stats::default();
    let clock = Instant::now();
    // Panics are counted, not printed 100,000 times.
    let hook = std::panic::take_hook();
    std::panic::set_hook(Box::new(|_| {}));
    while stats.inputs < count && clock.elapsed() < budget {
        let base = &seeds[rng.random_range(0..seeds.len())];
        let text = mutate(&mut rng, base);
        let which = stats.inputs % 5;
        let (tx, rx) = mpsc::channel();
        let path = dir.path().to_path_buf();
        let input = text.clone();
        std::thread::spawn(move || {
            let r = std::panic::catch_unwind(|| run_one(&input, &path, which));
            let _ = tx.send(r);
        });
        stats.inputs += 1;
        let cpu = process_cpu_s();
        // 5 s of wall time, else up to 120 s more if it has not used 5 s of CPU time (the
        // machine is shared): a time-out is an input that uses 5 s of CPU.
        let mut got = rx.recv_timeout(Duration::from_secs(5));
        if got.is_err() {
            let wait = Instant::now();
            while got.is_err()
                && process_cpu_s() - cpu < 5.0
                && wait.elapsed() < Duration::from_secs(120)
            {
                got = rx.recv_timeout(Duration::from_millis(200));
            }
            if got.is_ok() && process_cpu_s() - cpu < 5.0 {
                stats.slow_under_load += 1;
            } else {
                got = Err(mpsc::RecvTimeoutError::Timeout);
            }
        }
        match got {
            Ok(Ok(Ok(true))) => stats.valid += 1,
            Ok(Ok(Ok(false))) => {}
            Ok(Ok(Err(_))) => {
                stats.valid += 1;
                stats.errors += 1;
            }
            Ok(Err(_)) => {
                stats.panics += 1;
                eprintln!("PANIC (command {which}) on:\n{text}\n---");
            }
            Err(_) => {
                stats.timeouts += 1;
                eprintln!("TIME-OUT (command {which}) on:\n{text}\n---");
            }
        }
    }
    std::panic::set_hook(hook);
    stats
}

/// The suite's bounded run: 20 s of inputs, none of which may panic or run past 5 s.
#[test]
fn fuzz_bounded() {
    let stats = fuzz(usize::MAX, 39, Duration::from_secs(20));
    eprintln!("fuzz: {stats:?}");
    assert!(stats.inputs > 50, "{stats:?}");
    assert!(stats.valid > 5, "{stats:?}");
    assert_eq!((stats.panics, stats.timeouts), (0, 0), "{stats:?}");
}

/// The long run: `FUZZ_INPUTS` inputs (default 100,000), `FUZZ_SEED` (default 1).
#[test]
#[ignore]
fn fuzz_long() {
    let count = std::env::var("FUZZ_INPUTS")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(100_000);
    let seed = std::env::var("FUZZ_SEED")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(1);
    let clock = Instant::now();
    let stats = fuzz(count, seed, Duration::from_secs(u64::MAX / 4));
    eprintln!(
        "fuzz: {stats:?} in {:.0} s (seed {seed})",
        clock.elapsed().as_secs_f64()
    );
    assert_eq!((stats.panics, stats.timeouts), (0, 0), "{stats:?}");
}
