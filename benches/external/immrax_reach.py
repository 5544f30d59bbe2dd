"""immrax's reachable sets of scenario 1's filtered system, for comparison with cbfreach.

The closed loop of `scenarios/integrator.toml` as immrax models a neural feedback loop:
ẋ = f(x, u, w) = K x + u + w with u = N(x) (the network approximates the filter's correction
v) and w ∈ [−M, M]ⁿ the network's error, K = diag(−k1, −k2). immrax's `NNCEmbeddingSystem` in
its 'crown' mode (forward linear bound propagation, `immrax.inclusion.linbp`, on each face of
the box: 'local') builds the embedding system, and immrax's own `compute_trajectory` integrates
it with Euler steps, jitted and vmapped over the boxes. This is what `cbfreach reach --bounds
forward --face-local --exact nowhere --no-safe-set --m-c M` computes.

Usage: python immrax_reach.py BOXES.json NETWORK.safetensors OUT.json [--x64] [--plain-forward]
BOXES.json: {"boxes": [[lower, upper], ...], "k": [k1, k2], "m": M, "dt": dt, "steps": steps,
"record_every": K}. OUT.json gets the sets every K steps and the times.
"""

import argparse
import tempfile
import time
from pathlib import Path

import jax

parser = argparse.ArgumentParser()
parser.add_argument("boxes")
parser.add_argument("network")
parser.add_argument("out")
parser.add_argument("--x64", action="store_true", help="compute in float64 (default float32)")
parser.add_argument(
    "--plain-forward",
    action="store_true",
    help="drop immrax's intersection of every layer's bounds with interval bounds, so that it "
    "computes plain forward bounds, what `--bounds forward` does: a check of the two "
    "implementations against each other",
)
parser.add_argument("--repeats", type=int, default=3)
args = parser.parse_args()
jax.config.update("jax_enable_x64", args.x64)

import equinox as eqx  # noqa: E402  (after the precision is set)
import immrax as irx  # noqa: E402
import jax.numpy as jnp  # noqa: E402
from immutabledict import immutabledict  # noqa: E402
from safetensors.numpy import load_file  # noqa: E402

from common import layer_names, read_spec, write_result  # noqa: E402

spec, dt, steps, every = read_spec(args.boxes)
k1, k2 = spec["k"]
dtype = jnp.float64 if args.x64 else jnp.float32


def load_network(path):
    """The safetensors MLP (PyTorch's nn.Sequential names) as an immrax NeuralNetwork."""
    tensors = load_file(path)
    layers, widths = layer_names(tensors)
    arch = " ".join(
        [str(widths[0])] + [f"{w} relu" for w in widths[1:-1]] + [str(widths[-1])]
    )
    folder = Path(tempfile.mkdtemp())
    (folder / "arch.txt").write_text(arch)
    net = irx.NeuralNetwork(folder, load=False)
    tensors_of = iter(layers)
    modules = []
    for module in net.seq.layers:
        if isinstance(module, eqx.nn.Linear):
            i = next(tensors_of)
            w = jnp.asarray(tensors[f"{i}.weight"], dtype=dtype)
            b = jnp.asarray(tensors[f"{i}.bias"], dtype=dtype)
            module = eqx.tree_at(lambda l: (l.weight, l.bias), module, (w, b))
        modules.append(module)
    net = eqx.tree_at(lambda n: n.seq, net, eqx.nn.Sequential(modules))
    return net, widths


class Integrator(irx.OpenLoopSystem):
    def __init__(self):
        self.evolution = "continuous"
        self.xlen = 2

    def f(self, t, x, u, w):
        return jnp.array([-k1 * x[0], -k2 * x[1]], dtype=x.dtype) + u + w


if args.plain_forward:
    from jax import lax  # noqa: E402
    from immrax.inclusion import linbp as linbp_module  # noqa: E402

    intersected = linbp_module.linbp_registry[lax.dot_general_p]

    def without_interval_bounds(*a, **k):
        # Unbounded interval bounds: the intersection after the product keeps the affine
        # forms' own concrete bounds.
        b = intersected(*a, **k)
        inf = jnp.full_like(b.l, jnp.inf)
        return linbp_module.LinearBound(b.lA, b.lb, b.uA, b.ub, -inf, inf)

    linbp_module.linbp_registry[lax.dot_general_p] = without_interval_bounds

net, widths = load_network(args.network)
system = irx.NNCSystem(Integrator(), net)
embedding = irx.NNCEmbeddingSystem(system, "crown", "local", "local")
arguments = 1 + 2 + 2 + 2  # t, x, u, w
# The bottom and top corners, as immrax's examples use (README.md here: with both its upper
# bounds take w three times over, with either alone one side does).
corners = irx.two_corners(arguments)
kwargs = immutabledict(
    {"corners": corners, "permutations": irx.standard_permutation(arguments)}
)
m = spec["m"]
w = irx.interval(jnp.array([-m, -m], dtype=dtype), jnp.array([m, m], dtype=dtype))


def tube(x0):
    trajectory = embedding.compute_trajectory(
        0.0, steps * dt, x0, (lambda t, x: w,), dt, solver="euler", f_kwargs=kwargs
    )
    return trajectory.ys


run = jax.jit(jax.vmap(tube))
x0 = jnp.array(
    [list(lo) + list(up) for lo, up in spec["boxes"]], dtype=dtype
)  # immrax's [lower, upper] layout

start = time.perf_counter()
ys = run(x0).block_until_ready()
compile_s = time.perf_counter() - start
times = []
for _ in range(args.repeats):
    start = time.perf_counter()
    ys = run(x0).block_until_ready()
    times.append(time.perf_counter() - start)

# diffrax saves t0 and every step (the rest of its buffer is inf).
recorded = {}
for k in list(range(0, steps + 1, every)) + [steps]:
    sets = ys[:, k, :]
    recorded[str(k)] = [[list(map(float, s[:2])), list(map(float, s[2:]))] for s in sets]
out = {
    "tool": "immrax",
    "version": irx.__version__ if hasattr(irx, "__version__") else "0.3.8",
    "jax": jax.__version__,
    "dtype": str(jnp.dtype(dtype)),
    "plain_forward": args.plain_forward,
    "network": widths,
    "boxes": len(spec["boxes"]),
    "steps": steps,
    "compile_and_first_run_s": compile_s,
    "run_s": times,
    "sets": recorded,
}
write_result(
    args.out,
    out,
    f"immrax ({out['dtype']}{', plain forward' if args.plain_forward else ''}; compiled and "
    f"run first in {compile_s:.1f} s)",
)
