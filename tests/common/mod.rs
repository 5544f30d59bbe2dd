//! Fixtures shared by the integration tests.
#![allow(dead_code)]

use std::path::{Path, PathBuf};

use cbfreach::network::Mlp;
use cbfreach::problem::ProblemOptions;
use cbfreach::reach::ReachProblem;
use cbfreach::scenario::Scenario;

/// Path of a shipped scenario file.
pub fn scenario_path(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("scenarios")
        .join(name)
}

/// Path of a test fixture, `tests/fixtures/<name>`.
pub fn fixture_path(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("tests/fixtures")
        .join(name)
}

/// A test fixture (`tests/fixtures/<name>`) with each `(from, to)` replaced in its text; every
/// `from` must be there (a fixture that changed fails here, not in an assertion downstream).
pub fn fixture_with(name: &str, changes: &[(&str, &str)]) -> Scenario {
    let path = fixture_path(name);
    let mut text = std::fs::read_to_string(&path).expect("fixture readable");
    for (from, to) in changes {
        assert!(text.contains(from), "{name} changed: `{from}` is gone");
        text = text.replacen(from, to, 1);
    }
    let dir = path.parent().expect("fixtures' folder");
    Scenario::from_toml(&text, name, dir).expect("fixture variant valid")
}

/// The paper's scenario 1.
pub fn integrator() -> Scenario {
    Scenario::load(&scenario_path("integrator.toml")).expect("scenario 1 loads")
}

/// The paper's scenario 2.
pub fn double_integrator() -> Scenario {
    Scenario::load(&scenario_path("double-integrator.toml")).expect("scenario 2 loads")
}

/// The scenario compiled as the CLI does ([`ReachProblem::from_scenario`]): its shipped
/// network, the transform it asks for and, by its `m_c = "local"`, the network's certified
/// error map.
pub fn shipped_problem(s: &Scenario) -> ReachProblem {
    ReachProblem::from_scenario(s, &ProblemOptions::default()).unwrap()
}

/// The same with another network (and its error map).
pub fn shipped_problem_with(s: &Scenario, network: &Path) -> ReachProblem {
    let options = ProblemOptions {
        network: Some(network.to_path_buf()),
        ..ProblemOptions::default()
    };
    ReachProblem::from_scenario(s, &options).unwrap()
}

/// A network of the given widths whose every weight and bias is 0: `N ≡ 0`, standing in for a
/// filter that never acts (`v = 0`), so that its error is 0.
pub fn zero_network(widths: &[usize]) -> Mlp {
    let mut net = Mlp::random(widths, 3);
    for layer in &mut net.layers {
        layer.weight.iter_mut().for_each(|w| *w = 0.0);
        layer.bias.iter_mut().for_each(|b| *b = 0.0);
    }
    net
}

/// Compiles scenario text given inline (errors carry the name `test.toml`).
pub fn from_text(text: &str) -> Result<Scenario, cbfreach::scenario::ScenarioError> {
    Scenario::from_toml(text, "test.toml", Path::new("."))
}

/// `ẋ₁ = −30x₁ + x₂`, `ẋ₂ = −x₂` at `dt = 0.05`: `1 + dt·∂₁F₁ = −0.5`, so the Euler map
/// `x₁ ← −0.5x₁ + 0.05x₂` turns `x₁` around and its largest value over a set lies on the lower
/// face `x₁ = x̲₁`, not the upper one. The CBF `x₁ + 100` never binds on the region (`v = 0`).
pub const CONTRACTING: &str = r#"
name = "contracting"
[system]
states = ["x1", "x2"]
inputs = ["u"]
f = ["-30*x1 + x2", "-x2"]
g = [["1"], ["0"]]
kappa = ["0"]
[[cbf]]
h = "x1 + 100"
[reach]
region = { lower = [-2, -2], upper = [2, 2] }
m_c = 0.001
dt = 0.05
horizon = 0.5
goal = { lower = [-0.1, -0.1], upper = [0.1, 0.1] }
initial = [
  { lower = [0.5, 0.0], upper = [0.52, 1.0] },
  { lower = [-0.3, -1.0], upper = [-0.25, 0.5] },
]
"#;

/// A small valid scenario as text, to be broken by the error tests.
pub const SMALL: &str = r#"
name = "small"
[system]
states = ["x", "y"]
inputs = ["u"]
f = ["y", "-x"]
g = [["0"], ["1"]]
kappa = ["-x - y"]
[[cbf]]
h = "y + 2"
[reach]
region = { lower = [-1, -1], upper = [1, 1] }
m_c = 0.1
dt = 0.05
horizon = 1.0
goal = { lower = [-0.1, -0.1], upper = [0.1, 0.1] }
"#;

/// Two circular obstacles on a two-input integrator with input bounds `|uᵢ| ≤ b`: a general QP
/// (active sets mix CBF rows and bounds; near the bounds it is infeasible).
pub fn two_obstacles(b: f64) -> String {
    format!(
        r#"
name = "two"
[system]
states = ["x1", "x2"]
inputs = ["u1", "u2"]
f = ["0", "0"]
g = [["1", "0"], ["0", "1"]]
kappa = ["-x1", "-x2"]
[[cbf]]
h = "(x1 - 2)^2 + x2^2 - 1"
[[cbf]]
h = "(x1 + 1)^2 + (x2 - 2)^2 - 0.5"
[input_bounds]
lower = [-{b}, -{b}]
upper = [{b}, {b}]
[reach]
region = {{ lower = [-3, -3], upper = [4, 4] }}
m_c = 0
dt = 0.05
horizon = 1
goal = {{ lower = [-0.1, -0.1], upper = [0.1, 0.1] }}
"#
    )
}

/// `count` (1 to 4) spheres of radius 0.6 on the 3-D integrator `ẋ = u`, `κ = −x`, with
/// `|uᵢ| ≤ 2`: a general QP whose rows are the spheres' and six input bounds.
pub fn spheres_with_bounds(count: usize) -> String {
    let centres = [
        "1.5, 0.3, 0",
        "0.2, 1.5, -0.2",
        "0.4, -0.1, 1.5",
        "1.5, 1.5, 1.5",
    ];
    let cbfs: String = centres[..count]
        .iter()
        .map(|c| {
            let c: Vec<&str> = c.split(", ").collect();
            format!(
                "[[cbf]]\nh = \"(x1 - ({}))^2 + (x2 - ({}))^2 + (x3 - ({}))^2 - 0.36\"\n",
                c[0], c[1], c[2]
            )
        })
        .collect();
    format!(
        r#"name = "spheres"
[system]
states = ["x1", "x2", "x3"]
inputs = ["u1", "u2", "u3"]
f = ["0", "0", "0"]
g = [["1", "0", "0"], ["0", "1", "0"], ["0", "0", "1"]]
kappa = ["-x1", "-x2", "-x3"]
{cbfs}
[input_bounds]
lower = [-2, -2, -2]
upper = [2, 2, 2]
[reach]
region = {{ lower = [-1, -1, -1], upper = [3, 3, 3] }}
m_c = 0
dt = 0.05
horizon = 1
goal = {{ lower = [-0.3, -0.3, -0.3], upper = [0.3, 0.3, 0.3] }}
"#
    )
}

/// Runs the `cbfreach` binary: its exit code, stdout and stderr.
pub fn cbfreach(args: &[&str]) -> (i32, String, String) {
    let out = std::process::Command::new(env!("CARGO_BIN_EXE_cbfreach"))
        .args(args)
        .output()
        .expect("runs");
    (
        out.status.code().unwrap_or(-1),
        String::from_utf8_lossy(&out.stdout).into_owned(),
        String::from_utf8_lossy(&out.stderr).into_owned(),
    )
}

/// A random network (seeded) whose last layer is scaled by `scale`: outputs within about
/// ±`scale`, a small perturbation of the zero controller correction.
pub fn small_network(widths: &[usize], seed: u64, scale: f64) -> Mlp {
    let mut net = Mlp::random(widths, seed);
    if let Some(last) = net.layers.last_mut() {
        last.weight.iter_mut().for_each(|w| *w *= scale);
        last.bias.iter_mut().for_each(|b| *b *= scale);
    }
    net
}

/// A wall `x₁ ≥ 0` approached under `κ = −2(x₁ + 1)`: the filter's `u = −x₁` makes `x₁` decay
/// at rate 1 in continuous time, but held over `T_s = 1.5` it overshoots, `x₁ ← −0.5·x₁`: the
/// held input carries the state into the obstacle. `x₂` just decays. The network is the
/// filter's correction `v = x₁ + 2` (exact on `x₁ ≥ −2`), built by hand.
pub const WALL: &str = r#"
name = "wall"
[system]
states = ["x1", "x2"]
inputs = ["u"]
f = ["0", "-x2"]
g = [["1"], ["0"]]
kappa = ["-2*x1 - 2"]
[[cbf]]
name = "wall"
h = "x1"
[reach]
region = { lower = [-1.5, -1], upper = [1.5, 1] }
m_c = 0.01
dt = 0.1
horizon = 3.0
goal = { lower = [-0.1, -0.1], upper = [0.1, 0.1] }
initial = [ { lower = [1.0, 0.0], upper = [1.1, 0.1] } ]
"#;

/// [`WALL`]'s network: the filter's correction `v = x₁ + 2`, one neuron.
pub fn wall_network() -> Mlp {
    let mut net = Mlp::random(&[2, 1, 1], 1);
    net.layers[0].weight = vec![1.0, 0.0];
    net.layers[0].bias = vec![2.0];
    net.layers[1].weight = vec![1.0];
    net.layers[1].bias = vec![0.0];
    net
}

/// The NN closed loop `f̃(x) + g(x) N(x)`.
pub fn nn_field(s: &Scenario, net: &Mlp, x: &[f64]) -> Result<Vec<f64>, String> {
    let (n, m) = (s.n(), s.m());
    let f = s.f_tilde_at(x);
    let g = s.g_at(x);
    let u = net.forward(x);
    Ok((0..n)
        .map(|i| f[i] + (0..m).map(|k| g[i * m + k] * u[k]).sum::<f64>())
        .collect())
}

/// `ẋ = u` driven past a curved wall `h = x₁ + 1 + 0.2x₂² ≥ 0` by `κ = (−0.4(x₁ + 1.6),
/// −0.2x₂)`, the CBF's class-K function `alpha` (a TOML value), `C = [−1.5, 1.5]²`; `reach`
/// holds the rest of the `[reach]` table. The filter's correction stays below 0.28 on `C ∩ S`
/// with `α = 3h³ + 0.1h`.
pub fn curved_wall(alpha: &str, reach: &str) -> Scenario {
    from_text(&format!(
        r#"
name = "curved-wall"
[system]
states = ["x1", "x2"]
inputs = ["u1", "u2"]
f = ["0", "0"]
g = [["1", "0"], ["0", "1"]]
kappa = ["-0.4*(x1 + 1.6)", "-0.2*x2"]
[[cbf]]
h = "x1 + 1 + 0.2*x2^2"
alpha = {alpha}
[reach]
region = {{ lower = [-1.5, -1.5], upper = [1.5, 1.5] }}
dt = 0.05
goal = {{ lower = [-1.2, -0.3], upper = [-0.8, 0.3] }}
{reach}
"#
    ))
    .unwrap()
}

/// A high-order CBF written out on a double integrator pushed towards a wall
/// (`κ = −x₁ − 2x₂ + 1.2`): `h = 1.5 − x₁ − 0.1x₁³`, which no input acts on, listed first,
/// beside `ψ = L_f̃h + h` (neither affine, so sets are not clipped to them), `C = [−2, 2]²`;
/// `reach` holds the rest of the `[reach]` table.
pub fn high_order_wall(reach: &str) -> Scenario {
    wall_of_order(
        "[[cbf]]\nh = \"1.5 - x1 - 0.1*x1^3 - (1 + 0.3*x1^2)*x2\"",
        reach,
    )
}

/// [`high_order_wall`] with its second CBF written by `order = 2` instead of by hand.
pub fn high_order_wall_by_order(reach: &str) -> Scenario {
    wall_of_order("order = 2", reach)
}

fn wall_of_order(second: &str, reach: &str) -> Scenario {
    from_text(&format!(
        r#"
name = "wall"
[system]
states = ["x1", "x2"]
inputs = ["u"]
f = ["x2", "0"]
g = [["0"], ["1"]]
kappa = ["-x1 - 2*x2 + 1.2"]
[[cbf]]
h = "1.5 - x1 - 0.1*x1^3"
{second}
[reach]
region = {{ lower = [-2, -2], upper = [2, 2] }}
dt = 0.05
goal = {{ lower = [-0.1, -0.1], upper = [0.1, 0.1] }}
{reach}
"#
    ))
    .unwrap()
}

/// A point mass in the plane (`ṗ = v`, `v̇ = u`, states `px, py, vx, vy`) under
/// `κ = −p − damping·v`, with `cbfs` (its `[[cbf]]` tables) and `reach` (the keys of its
/// `[reach]` table).
pub fn planar_point_mass(damping: f64, cbfs: &str, reach: &str) -> Scenario {
    from_text(&format!(
        r#"
name = "planar"
[system]
states = ["px", "py", "vx", "vy"]
inputs = ["ax", "ay"]
f = ["vx", "vy", "0", "0"]
g = [["0", "0"], ["0", "0"], ["1", "0"], ["0", "1"]]
kappa = ["-px - {damping}*vx", "-py - {damping}*vy"]
{cbfs}
[reach]
{reach}
"#
    ))
    .unwrap()
}
