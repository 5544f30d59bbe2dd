"""The paper's pipeline for scenario 1's reachable sets: auto_LiRPA's CROWN bounds of the network
over each box at every Euler step, then the embedding system's step, in PyTorch.

The closed loop of `scenarios/integrator.toml`: ẋ = K x + N(x) + w, K = diag(−k1, −k2), w ∈
[−M, M]ⁿ the network's error. At each step auto_LiRPA bounds N over every box at once (a batch)
by backward CROWN with affine bounds C̲x + d̲ ≤ N(x) ≤ C̄x + d̄ (`return_A`), and the embedding
system takes, for each coordinate i, the bounds of (Kx + N(x) + w)ᵢ over the box's face where
xᵢ is at its lower (upper) end. This is what `cbfreach reach --bounds crown --exact nowhere
--no-safe-set --m-c M` computes (`--relu same-slope`: `--bounds crown-same-slope`).

Usage: python lirpa_reach.py BOXES.json NETWORK.safetensors OUT.json [--relu adaptive|same-slope]
BOXES.json as for immrax_reach.py.
"""

import argparse
import time

import torch
from auto_LiRPA import BoundedModule, BoundedTensor, PerturbationLpNorm
from safetensors.torch import load_file

from common import layer_names, read_spec, write_result

parser = argparse.ArgumentParser()
parser.add_argument("boxes")
parser.add_argument("network")
parser.add_argument("out")
parser.add_argument("--relu", choices=["adaptive", "same-slope"], default="adaptive")
parser.add_argument("--f32", action="store_true", help="compute in float32 (default float64)")
parser.add_argument("--repeats", type=int, default=1)
args = parser.parse_args()

dtype = torch.float32 if args.f32 else torch.float64
spec, dt, steps, every = read_spec(args.boxes)
k = torch.tensor([-spec["k"][0], -spec["k"][1]], dtype=dtype)
m = spec["m"]


def load_network(path):
    """The safetensors MLP as the nn.Sequential whose state_dict it is."""
    tensors = load_file(path)
    layers, widths = layer_names(tensors)
    modules = []
    for i in layers:
        w = tensors[f"{i}.weight"]
        while len(modules) < i:
            modules.append(torch.nn.ReLU())
        modules.append(torch.nn.Linear(w.shape[1], w.shape[0]))
    model = torch.nn.Sequential(*modules).to(dtype)
    model.load_state_dict({name: t.to(dtype) for name, t in tensors.items()})
    return model.eval(), widths


model, widths = load_network(args.network)
boxes = torch.tensor(spec["boxes"], dtype=dtype)  # [B, 2 (lower, upper), n]
bounded = BoundedModule(
    model, torch.zeros(1, widths[0], dtype=dtype), bound_opts={"relu": args.relu}, device="cpu"
)
needed = {bounded.output_name[0]: [bounded.input_name[0]]}


def face_minimum(c, d, lower, upper, at_upper):
    """Per coordinate i, the minimum of (c x + d)ᵢ over the box's face where xᵢ is at its lower
    (or, with `at_upper`, upper) end: c [B, n, n], d [B, n], lower/upper [B, n]."""
    low = torch.where(c > 0, lower[:, None, :], upper[:, None, :])
    n = lower.shape[1]
    face = upper if at_upper else lower
    eye = torch.eye(n, dtype=torch.bool)
    low = torch.where(eye, face[:, None, :], low)
    return (c * low).sum(-1) + d


def step(lower, upper):
    x = BoundedTensor((lower + upper) / 2, PerturbationLpNorm(x_L=lower, x_U=upper))
    _, _, a = bounded.compute_bounds(
        x=(x,), method="CROWN", return_A=True, needed_A_dict=needed
    )
    a = a[bounded.output_name[0]][bounded.input_name[0]]
    c_lo, d_lo, c_hi, d_hi = a["lA"], a["lbias"], a["uA"], a["ubias"]
    kk = torch.diag_embed(k).expand_as(c_lo)
    # ẋᵢ on the face xᵢ = x̲ᵢ is at least min (K + C̲)x + d̲ − M, on xᵢ = x̄ᵢ at most
    # max (K + C̄)x + d̄ + M = −min (−(K + C̄))x − d̄ + M.
    rate_lo = face_minimum(kk + c_lo, d_lo, lower, upper, False) - m
    rate_hi = -face_minimum(-(kk + c_hi), -d_hi, lower, upper, True) + m
    return lower + dt * rate_lo, upper + dt * rate_hi


def tube():
    lower, upper = boxes[:, 0, :].clone(), boxes[:, 1, :].clone()
    recorded = {"0": torch.stack([lower, upper], 1).tolist()}
    with torch.no_grad():
        for s in range(1, steps + 1):
            lower, upper = step(lower, upper)
            if s % every == 0 or s == steps:
                recorded[str(s)] = torch.stack([lower, upper], 1).tolist()
    return recorded


times = []
for _ in range(max(args.repeats, 1)):
    start = time.perf_counter()
    sets = tube()
    times.append(time.perf_counter() - start)
out = {
    "tool": "auto_LiRPA",
    "torch": torch.__version__,
    "dtype": str(dtype).replace("torch.", ""),
    "relu": args.relu,
    "network": widths,
    "boxes": len(spec["boxes"]),
    "steps": steps,
    "run_s": times,
    "threads": torch.get_num_threads(),
    "sets": sets,
}
write_result(args.out, out, f"auto_LiRPA CROWN ({out['dtype']}, {args.relu})")
