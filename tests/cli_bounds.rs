//! `cbfreach bounds`: JSON that contains sampled network outputs, a table, and named errors.

mod common;
use common::cbfreach;

use std::collections::BTreeMap;
use std::path::PathBuf;

use cbfreach::network::Mlp;
use tempfile::TempDir;

/// A small random network saved in a fresh temporary directory, returned with it: the caller
/// keeps the directory alive, and it is removed on drop (also when a test panics).
fn saved_network() -> (Mlp, PathBuf, TempDir) {
    let dir = tempfile::tempdir().expect("temp dir");
    let path = dir.path().join("net.safetensors");
    let net = Mlp::random(&[2, 16, 16, 2], 3);
    net.save_safetensors(&path, &BTreeMap::new())
        .expect("saves");
    (net, path, dir)
}

fn floats(v: &serde_json::Value) -> Vec<f64> {
    v.as_array()
        .expect("array")
        .iter()
        .map(|x| x.as_f64().expect("number"))
        .collect()
}

#[test]
fn json_bounds_contain_sampled_outputs_for_every_method() {
    let (net, path, _dir) = saved_network();
    let (lo, hi) = ([-0.7, 0.2], [-0.2, 0.6]);
    for method in [
        "ibp",
        "crown",
        "crown-same-slope",
        "forward",
        "forward-backward",
        "forward-backward-same-slope",
    ] {
        let (code, stdout, stderr) = cbfreach(&[
            "bounds",
            path.to_str().unwrap(),
            "--lower",
            "-0.7,0.2",
            "--upper",
            "-0.2,0.6",
            "--method",
            method,
            "--json",
        ]);
        assert_eq!(code, 0, "{method}: {stderr}");
        let v: serde_json::Value = serde_json::from_str(&stdout).expect("JSON");
        let (lower, upper) = (floats(&v["lower"]), floats(&v["upper"]));
        let (b_lower, b_upper) = (floats(&v["b_lower"]), floats(&v["b_upper"]));
        let a_lower: Vec<Vec<f64>> = v["A_lower"]
            .as_array()
            .unwrap()
            .iter()
            .map(floats)
            .collect();
        let a_upper: Vec<Vec<f64>> = v["A_upper"]
            .as_array()
            .unwrap()
            .iter()
            .map(floats)
            .collect();
        assert_eq!(
            (lower.len(), a_lower.len(), a_upper[0].len()),
            (2, 2, 2),
            "{method}"
        );
        for s in 0..=10 {
            for t in 0..=10 {
                let x = [
                    lo[0] + (hi[0] - lo[0]) * s as f64 / 10.0,
                    lo[1] + (hi[1] - lo[1]) * t as f64 / 10.0,
                ];
                let y = net.forward(&x);
                for o in 0..2 {
                    let tol = 1e-12 * (1.0 + y[o].abs());
                    assert!(
                        lower[o] - tol <= y[o] && y[o] <= upper[o] + tol,
                        "{method} {x:?}"
                    );
                    let fl = a_lower[o][0] * x[0] + a_lower[o][1] * x[1] + b_lower[o];
                    let fu = a_upper[o][0] * x[0] + a_upper[o][1] * x[1] + b_upper[o];
                    assert!(
                        fl - tol <= y[o] && y[o] <= fu + tol,
                        "{method} form at {x:?}"
                    );
                }
            }
        }
    }
}

#[test]
fn table_and_named_errors() {
    let (_, path, _dir) = saved_network();
    let p = path.to_str().unwrap();
    let (code, stdout, stderr) = cbfreach(&["bounds", p, "--lower", "-1,-1", "--upper", "1,1"]);
    assert_eq!(code, 0, "{stderr}");
    assert!(
        stdout.contains("crown") && stdout.contains("output"),
        "{stdout}"
    );

    let (code, _, stderr) = cbfreach(&["bounds", p, "--lower", "-1,-1,0", "--upper", "1,1"]);
    assert_ne!(code, 0);
    assert!(
        stderr.contains("--lower") && stderr.contains("dimension is 2"),
        "{stderr}"
    );

    let (code, _, stderr) = cbfreach(&["bounds", p, "--lower", "0,1", "--upper", "1,0.5"]);
    assert_ne!(code, 0);
    assert!(stderr.contains("inverted"), "{stderr}");

    let (code, _, stderr) = cbfreach(&["bounds", p, "--lower", "0,x", "--upper", "1,1"]);
    assert_ne!(code, 0);
    assert!(stderr.contains("--lower"), "{stderr}");

    let (code, _, stderr) = cbfreach(&[
        "bounds", p, "--lower", "0,0", "--upper", "1,1", "--method", "nope",
    ]);
    assert_ne!(code, 0);
    assert!(stderr.contains("--method"), "{stderr}");
}
