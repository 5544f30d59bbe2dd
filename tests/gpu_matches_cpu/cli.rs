//! `cbfreach reach --backend gpu|auto` from the command line.

use super::*;

/// `cbfreach reach --backend gpu|auto` prints the adapter and the tubes; a bad adapter name is an
/// error, not a panic.
#[test]
fn cli_backend_gpu_and_auto() {
    let Some(_gpu) = gpu() else { return };
    let gpu = GpuContext::new().expect("the adapter found above");
    let dir = tempfile::tempdir().unwrap();
    let net_path = dir.path().join("net.safetensors");
    small_network(&[2, 16, 16, 2], 8, 0.05)
        .save_safetensors(&net_path, &Default::default())
        .unwrap();
    let scenario = common::scenario_path("integrator.toml");
    let run = |extra: &[&str]| {
        let out = std::process::Command::new(env!("CARGO_BIN_EXE_cbfreach"))
            .arg("reach")
            .arg(&scenario)
            .arg("--network")
            .arg(&net_path)
            .args(["--m-c", "0.05", "--every", "25", "--time", "euler"])
            .args(extra)
            // The filter's own pieces make the kernels slow to compile on lavapipe; the first
            // run checks them, the others the flags.
            .args(if extra.contains(&"--exact") {
                &[][..]
            } else {
                &["--exact", "nowhere"][..]
            })
            .output()
            .unwrap();
        (
            out.status.success(),
            String::from_utf8_lossy(&out.stdout).to_string()
                + &String::from_utf8_lossy(&out.stderr),
        )
    };
    let (ok, text) = run(&[
        "--backend",
        "gpu",
        "--bounds",
        "forward",
        "--exact",
        "closed-form",
    ]);
    assert!(
        ok && text.contains("GPU adapter:") && text.contains("backend gpu"),
        "{text}"
    );
    // The filter's own pieces run there too (the default `--exact closed-form`), no notice.
    assert!(
        text.contains("the filter's pieces") && !text.contains("note:"),
        "{text}"
    );
    // f64 by default where the adapter has f64 shaders (its sets match the CPU's; f32's a-priori
    // rounding bounds cost verdicts), f32 on request.
    let default_type = if gpu.has_f64() { "f64)" } else { "f32)" };
    assert!(text.contains(default_type), "{text}");
    let (ok, text) = run(&["--backend", "auto", "--bounds", "ibp"]);
    assert!(ok && text.contains("using the CPU"), "{text}");
    // A dozen boxes run faster on the CPU engine: auto says so and uses it, whatever the
    // adapter.
    let (ok, text) = run(&["--backend", "auto", "--bounds", "crown"]);
    assert!(
        ok && text.contains("12 boxes run faster on the CPU engine")
            && text.contains("backend cpu"),
        "{text}"
    );
    // Thousands run on a real GPU.
    let problem = ReachProblem::new(&integrator(), small_network(&[2, 16, 16, 2], 8, 0.05), 0.05)
        .unwrap()
        .with_time(TimeModel::Euler, 1);
    let settings = ReachSettings {
        bounds: BoundMethod::Crown,
        exact: ExactField::Nowhere,
        ..ReachSettings::default()
    };
    let many = cbfreach::reach::choose_engine(
        cbfreach::reach::EngineChoice::Auto,
        &Default::default(),
        &settings,
        &problem,
        cbfreach::reach::AUTO_GPU_BOXES,
    )
    .unwrap();
    assert_eq!(
        many.backend.name() == "cpu",
        gpu.is_software(),
        "{:?}",
        many.notices
    );
    if gpu.is_software() {
        // A software adapter is slower than the CPU engine: auto passes it over...
        assert!(
            many.notices.iter().any(|n| n.contains("software")),
            "{:?}",
            many.notices
        );
        // ... unless it is named.
        let name = gpu.describe();
        let first = name.split_whitespace().next().unwrap_or("");
        let (ok, text) = run(&[
            "--backend",
            "auto",
            "--bounds",
            "forward",
            "--adapter",
            first,
        ]);
        assert!(ok && text.contains("backend gpu"), "{text}");
    }
    if gpu_f64().is_some() {
        let (ok, text) = run(&["--backend", "gpu", "--bounds", "forward-backward", "--f64"]);
        assert!(ok && text.contains("f64)"), "{text}");
    }
    let (ok, text) = run(&["--backend", "gpu", "--bounds", "forward", "--f32"]);
    assert!(ok && text.contains("f32)"), "{text}");
    let (ok, text) = run(&["--backend", "gpu", "--f32", "--f64"]);
    assert!(
        !ok && text.contains("--f32") && text.contains("--f64"),
        "{text}"
    );
    // Local error margins and face-local bounds run on the GPU (the map beside the network).
    let mut map = small_error_map(&integrator().reach.region);
    // Stamped for the scenario the command runs (provenance, issue 39).
    map.stamp(&integrator(), &net_path).unwrap();
    map.save(&cbfreach::error_map::error_map_path(&net_path))
        .unwrap();
    let (ok, text) = run(&[
        "--backend",
        "gpu",
        "--bounds",
        "forward-backward",
        "--face-local",
        "--local-margin",
    ]);
    assert!(
        ok && text.contains("backend gpu") && text.contains("local bounds of the error map"),
        "{text}"
    );
    let (ok, text) = run(&["--backend", "cpu", "--f64"]);
    assert!(!ok && text.contains("--f64"), "{text}");
    let (ok, text) = run(&["--backend", "cpu", "--f32"]);
    assert!(!ok && text.contains("--f32"), "{text}");
    let (ok, text) = run(&[
        "--backend",
        "gpu",
        "--bounds",
        "forward",
        "--adapter",
        "no-such-gpu",
    ]);
    assert!(!ok && text.contains("no GPU adapter named like"), "{text}");
    assert!(!text.contains("panicked"), "{text}");
    // `bench --profile`: a step's time, one line per kind of dispatch, one per GEMM.
    let out = std::process::Command::new(env!("CARGO_BIN_EXE_cbfreach"))
        .args([
            "bench",
            "--backend",
            "gpu",
            "--profile",
            "--boxes",
            "8",
            "--steps",
            "2",
        ])
        .args(["--bounds", "forward-backward", "--scenario"])
        .arg(&scenario)
        .arg("--network")
        .arg(&net_path)
        .output()
        .unwrap();
    let text = String::from_utf8_lossy(&out.stderr).to_string();
    assert!(out.status.success(), "{text}");
    assert!(text.contains("profile (8 boxes,"), "{text}");
    let kernel_count = |name: &str| -> usize {
        let line = text
            .lines()
            .find(|l| l.trim_start().starts_with(&format!("{name} ")))
            .unwrap_or_else(|| panic!("no {name} line: {text}"));
        let field = line.split_whitespace().nth(1).unwrap();
        field.trim_end_matches('×').parse().unwrap()
    };
    let gemm_lines = text
        .lines()
        .filter(|l| l.trim_start().starts_with("gemm ") && l.contains("GFLOP/s"))
        .count();
    assert!(gemm_lines > 0, "{text}");
    // Software adapters run the flat GEMM, real GPUs the tiles: one kernel, never two.
    let kernels: Vec<&str> = ["gemm_flat", "gemm_wide", "gemm"]
        .into_iter()
        .filter(|&k| {
            // A kernel's line is its name and its count ("gemm  12×"), not a product's line.
            text.lines().any(|l| {
                let mut words = l.split_whitespace();
                words.next() == Some(k) && words.next().is_some_and(|w| w.ends_with('×'))
            })
        })
        .collect();
    assert_eq!(kernels.len(), 1, "{text}");
    assert_eq!(kernel_count(kernels[0]), gemm_lines, "{text}");
    assert_eq!(kernel_count("embed"), 1, "{text}");
}

/// `cbfreach reach --time sampled --backend gpu` runs on the GPU engine (f64) and prints the
/// CPU engine's tubes (the same lines, findings between samples included); `--f32` is refused
/// naming the setting and the way out.
#[test]
fn cli_sampled_on_the_gpu() {
    let Some(_gpu) = gpu_f64() else { return };
    let dir = tempfile::tempdir().unwrap();
    let net_path = dir.path().join("net.safetensors");
    small_network(&[2, 16, 16, 2], 8, 0.05)
        .save_safetensors(&net_path, &Default::default())
        .unwrap();
    let run = |extra: &[&str]| {
        let out = std::process::Command::new(env!("CARGO_BIN_EXE_cbfreach"))
            .arg("reach")
            .arg(common::scenario_path("integrator.toml"))
            .arg("--network")
            .arg(&net_path)
            .args(["--m-c", "0.05", "--every", "25", "--time", "sampled"])
            .args(["--exact", "nowhere", "--bounds", "forward"])
            .args(extra)
            .output()
            .unwrap();
        let stdout = String::from_utf8_lossy(&out.stdout).to_string();
        let all = stdout.clone() + &String::from_utf8_lossy(&out.stderr);
        (out.status.success(), stdout, all)
    };
    let (ok, cpu, text) = run(&["--backend", "cpu"]);
    assert!(ok, "{text}");
    let (ok, gpu, text) = run(&["--backend", "gpu"]);
    assert!(
        ok && text.contains("backend gpu") && text.contains("f64)"),
        "{text}"
    );
    // The tubes' lines and their findings (the header names the backend, the footer times it).
    let tubes = |s: &str| -> Vec<String> {
        s.lines()
            .filter(|l| l.starts_with("  (") || l.starts_with("    "))
            .map(String::from)
            .collect()
    };
    assert!(
        tubes(&cpu).len() >= 12 && cpu.contains("UNSAFE BETWEEN SAMPLES"),
        "{cpu}"
    );
    assert_eq!(tubes(&cpu), tubes(&gpu), "{cpu}\n{gpu}");
    let (ok, _, text) = run(&["--backend", "gpu", "--f32"]);
    assert!(
        !ok && text.contains("sampled") && text.contains("f32") && text.contains("--backend cpu"),
        "{text}"
    );
}
