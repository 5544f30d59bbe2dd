#!/usr/bin/env python3
"""Containment fuzz: random filtered systems, their sets against the real system's trajectories.

For each seed: a random 2- or 3-state system (linear drift with sine, cosine or product terms,
sometimes turning; an input matrix that may depend on the state; a ball or a half-plane
obstacle; sometimes input bounds, then a general QP), a 32x32 network trained by
`cbfreach train --budget 0.1`, its error certified by `cbfreach error`, then `cbfreach reach
--json` of four random initial boxes under each time model and setting below. Every recorded
set must hold the states that `cbfreach simulate` gives from the boxes' safe corners and 40
random safe points, at the same times (to 1e-7 of the set's width): RK4 at a tenth of the
step for `continuous` (every state between two samples also inside that step's flowpipe), the
exact zero-order hold for `sampled`, the Euler map for `euler`. An escape is printed with the
box, time, coordinate and set. Then `verify --grid 6,6 --check 3` (4,4,4 in three states)
checks the verdicts against simulated starts. The exit status is 1 if a state escaped or a
verdict disagreed. Only the CLI is used, so this checks what users run.

    python3 tools/containment_fuzz.py --first 0 --count 20 [--exotic] [--class-k] [--high-order]
        [--binary PATH]

Standard settings: continuous (the defaults), continuous with --exact nowhere --face-local,
continuous --transform auto, sampled (T_s = dt), euler, and every third seed continuous on the
GPU engine. --exotic: --taylor3, turned frames, Lyapunov coordinates without clipped slabs,
three substeps with CROWN bounds, sampled with T_s = 2 dt, and the GPU engine in f64, f32 with
a transform, and Euler. Results: docs/results.md ("Random systems against their sets").
"""

import argparse
import json
import os
import random
import subprocess
import sys
import tempfile
import time


def generate(rng, index, class_k=False, high_order=False):
    """A random scenario's text, its h as a Python function, and (n, dt). With `class_k`, the
    CBF's class-K function is a nonlinear function of h drawn from a stream of its own (the rest
    of the system is the seed's, as without). With `high_order`, a double integrator with a
    drift whose obstacle is a bound on x1 alone, kept by `order = 2` (a high-order CBF)."""
    n = 2 if high_order else rng.choice([2, 2, 2, 3])
    xs = [f"x{i + 1}" for i in range(n)]
    f = []
    for i in range(n):
        terms = [f"{rng.uniform(-0.5, 0.5):.3f}*{x}" for x in xs if rng.random() < 0.4]
        r = rng.random()
        if r < 0.3:
            terms.append(f"{rng.uniform(-0.4, 0.4):.3f}*sin({rng.choice(xs)})")
        elif r < 0.5:
            terms.append(f"{rng.uniform(-0.2, 0.2):.3f}*{rng.choice(xs)}*{rng.choice(xs)}")
        elif r < 0.6:
            terms.append(f"{rng.uniform(-0.2, 0.2):.3f}*cos({rng.choice(xs)})")
        f.append(" + ".join(terms) if terms else "0")
    if rng.random() < 0.3:
        turn = rng.uniform(0.5, 2.0)
        f[0] = f"{f[0]} + {turn:.3f}*x2"
        f[1] = f"{f[1]} - {turn:.3f}*x1"
    if n == 2 and (rng.random() < 0.3 or high_order):
        # A double integrator with a drift: one input on the velocity.
        m = 1
        f = [f"x2 + {f[0]}", f[1]]
        g = [["0"], [rng.choice(["1", "1 + 0.3*cos(x1)", "1.5"])]]
        kappa = [f"-{rng.uniform(0.5, 2):.3f}*x1 - {rng.uniform(1.5, 3):.3f}*x2"]
    else:
        m = n
        g = [["0"] * n for _ in range(n)]
        for i in range(n):
            g[i][i] = rng.choice(
                ["1", "1", f"1 + {rng.uniform(0, 0.4):.2f}*cos({rng.choice(xs)})",
                 f"{rng.uniform(0.5, 1.5):.2f}"])
        if rng.random() < 0.3:
            i, j = rng.sample(range(n), 2)
            g[i][j] = f"{rng.uniform(-0.3, 0.3):.2f}"
        kappa = [f"-{rng.uniform(0.8, 3):.3f}*{x}" for x in xs]
    if rng.random() < 2 / 3:
        o = [rng.uniform(0.8, 2.0)] + [rng.uniform(-0.6, 0.6) for _ in range(n - 1)]
        r = rng.uniform(0.3, 0.7)
        h = " + ".join(f"({x} - {c:.3f})^2" for x, c in zip(xs, o)) + f" - {r * r:.4f}"

        def h_of(p, o=o, r=r):
            return sum((a - c) ** 2 for a, c in zip(p, o)) - r * r
    else:
        c = rng.uniform(1.5, 2.5)
        h = f"{c:.3f} - x1 - 0.3*x2"

        def h_of(p, c=c):
            return c - p[0] - 0.3 * p[1]
    if high_order:
        c = rng.uniform(1.2, 2.2)
        h = f"{c:.3f} - x1 - {rng.uniform(0, 0.1):.3f}*x1^3" if rng.random() < 0.5 \
            else f"{c:.3f} - x1"
        h = h if rng.random() < 0.7 else f"(x1 - {c:.3f})^2 - 0.09"
        text_h = h

        def h_of(p, text_h=text_h):
            return eval(text_h.replace("^", "**"), {}, {"x1": p[0], "x2": p[1]})
    alpha = rng.choice([0.5, 1.0, 2.0, 3.0])
    if class_k:
        own = random.Random(7919 * index + 1)
        a, b = own.uniform(0.2, 2.0), own.uniform(0.1, 2.0)
        alpha = json.dumps(own.choice([f"{a:.3f}*h + {b:.3f}*h^3", f"{a:.3f}*h + {b:.3f}*h^2",
                                       f"{a:.3f}*tanh({b:.3f}*h) + 0.05*h"]))
    lo = [-2.0] + [-1.8] * (n - 1)
    hi = [3.0] + [1.8] * (n - 1)
    dt = rng.choice([0.02, 0.04, 0.05])
    initial = []
    while len(initial) < 4:
        w = rng.uniform(0.03, 0.3)
        low = [rng.uniform(a, b - w) for a, b in zip(lo, hi)]
        up = [v + w for v in low]
        if h_of([(a + b) / 2 for a, b in zip(low, up)]) > 0:
            initial.append((low, up))
    text = f'name = "fuzz{index}"\n[system]\nstates = {json.dumps(xs)}\n'
    text += f"inputs = {json.dumps([f'u{i + 1}' for i in range(m)])}\n"
    text += f"f = {json.dumps(f)}\ng = {json.dumps(g)}\nkappa = {json.dumps(kappa)}\n"
    text += f'[[cbf]]\nname = "obstacle"\nh = "{h}"\nalpha = {alpha}\n'
    if high_order:
        text += "order = 2\n"
    if rng.random() < 0.3:
        b = rng.uniform(2, 5)
        text += f"[input_bounds]\nlower = {[-b] * m}\nupper = {[b] * m}\n"
    text += f'[network]\nfile = "fuzz{index}.safetensors"\narchitecture = [{n}, 32, 32, {m}]\n'
    text += f"[training]\ngrid = {[31] * n if n == 2 else [15] * n}\n"
    text += "target = { linf = 0.2, slope_p95 = 1.0 }\n"
    text += f"[reach]\nregion = {{ lower = {lo}, upper = {hi} }}\ndt = {dt}\nhorizon = 3.0\n"
    text += f"goal = {{ lower = {[-0.3] * n}, upper = {[0.3] * n} }}\n"
    text += "initial = [ " + ", ".join(
        f"{{ lower = {a}, upper = {b} }}" for a, b in initial) + " ]\n"
    return text, h_of, n, dt


def settings(dt, index, exotic):
    """(name, reach flags, simulate integrator, simulation step)."""
    fine, ts = dt / 10, 2 * dt
    if exotic:
        return [
            ("continuous --taylor3", ["--taylor3"], "rk4", fine),
            ("continuous, three turned frames",
             ["--transform", "auto", "--turned-frames", "3"], "rk4", fine),
            ("continuous, Lyapunov coordinates, slabs not clipped",
             ["--transform", "lyapunov", "--no-meet-slabs"], "rk4", fine),
            ("continuous, 3 substeps, CROWN", ["--substeps", "3", "--bounds", "crown"], "rk4", fine),
            ("sampled, T_s = 2 dt", ["--time", "sampled", "--control-period", str(ts)], "zoh", ts),
            ("continuous on the GPU", ["--backend", "gpu", "--exact", "inactive"], "rk4", fine),
            ("continuous on the GPU, f32, auto coordinates",
             ["--backend", "gpu", "--exact", "inactive", "--f32", "--transform", "auto"],
             "rk4", fine),
            ("euler on the GPU", ["--backend", "gpu", "--exact", "inactive", "--time", "euler"],
             "euler", dt),
        ]
    chosen = [
        ("continuous", [], "rk4", fine),
        ("continuous --exact nowhere --face-local",
         ["--exact", "nowhere", "--face-local"], "rk4", fine),
        ("continuous --transform auto", ["--transform", "auto"], "rk4", fine),
        ("sampled", ["--time", "sampled"], "zoh", dt),
        ("euler", ["--time", "euler"], "euler", dt),
    ]
    if index % 3 == 0:
        chosen.append(("continuous on the GPU", ["--backend", "gpu", "--exact", "inactive"],
                       "rk4", fine))
    return chosen


# Allowed excess, relative to the set's width: the simulation's own error (RK4 at dt/10 over a
# few seconds is far below it), not the sets'.
TOLERANCE = 1e-7


def excess(x, lower, upper):
    """The largest distance of x outside [lower, upper], relative to the interval's width."""
    return max(max(lo - v, v - up) / max(up - lo, 1e-3) for v, lo, up in zip(x, lower, upper))


def check(run, scenario, h_of, n, flags, integrator, step, json_path):
    """The worst relative excess of a simulated state over its set, and states compared."""
    code, _, err = run(["reach", scenario, "--json", json_path] + flags)
    if code != 0:
        return None, err.strip().splitlines()[-1] if err.strip() else f"exit {code}"
    with open(json_path) as fh:
        result = json.load(fh)
    worst, where, compared = 0.0, None, 0
    for box in result["boxes"]:
        tube = box["tube"]
        if len(tube) < 2:
            continue
        low, up = box["initial"]["lower"], box["initial"]["upper"]
        rng = random.Random(1)
        starts = [[up[i] if c >> i & 1 else low[i] for i in range(n)] for c in range(2 ** n)]
        starts += [[rng.uniform(a, b) for a, b in zip(low, up)] for _ in range(40)]
        starts = [p for p in starts if h_of(p) >= 0]
        args = ["simulate", scenario, "--format", "json", "--integrator", integrator,
                "--dt", repr(step), "--horizon", repr(tube[-1]["t"])]
        for p in starts:
            args += ["--from", ",".join(repr(v) for v in p)]
        code, out, err = run(args)
        if code != 0:
            return None, f"simulate: {err.strip()}"
        for trajectory in json.loads(out):
            states = trajectory["x"]
            for k, sample in enumerate(tube):
                at = round(sample["t"] / step)
                if abs(at * step - sample["t"]) > 1e-9:
                    continue  # a sample between two control periods: no held state there
                if at >= len(states):
                    break
                e = excess(states[at], sample["lower"], sample["upper"])
                compared += 1
                if e > worst:
                    worst, where = e, (low, up, sample["t"], states[at], "set")
                pipe = sample.get("flowpipe")
                if pipe and k > 0 and integrator == "rk4":
                    since = round(tube[k - 1]["t"] / step)
                    for j in range(since, min(at, len(states) - 1) + 1):
                        e = excess(states[j], pipe["lower"], pipe["upper"])
                        if e > worst:
                            worst, where = e, (low, up, j * step, states[j], "flowpipe")
    return worst, (compared, where)


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--first", type=int, default=0, help="first seed")
    parser.add_argument("--count", type=int, default=10, help="systems to try")
    parser.add_argument("--exotic", action="store_true", help="the rarer settings")
    parser.add_argument("--class-k", action="store_true",
                        help="nonlinear class-K functions (a·h + b·h³, a·h + b·h², a·tanh(b·h))")
    parser.add_argument("--high-order", action="store_true",
                        help="double integrators with a bound on x1 kept by order = 2")
    parser.add_argument("--binary", default="target/release/cbfreach")
    parser.add_argument("--dir", help="where the scenarios go (default: a temporary folder)")
    args = parser.parse_args()
    binary = os.path.abspath(args.binary)
    folder = args.dir or tempfile.mkdtemp(prefix="cbfreach-fuzz-")
    os.makedirs(folder, exist_ok=True)

    def run(cli_args, timeout=900):
        p = subprocess.run([binary] + cli_args, capture_output=True, text=True, timeout=timeout)
        return p.returncode, p.stdout, p.stderr

    escapes = 0
    for index in range(args.first, args.first + args.count):
        text, h_of, n, dt = generate(random.Random(index), index, args.class_k, args.high_order)
        scenario = os.path.join(folder, f"fuzz{index}.toml")
        with open(scenario, "w") as fh:
            fh.write(text)
        started = time.time()
        for step in (["train", scenario, "--budget", "0.1"], ["error", scenario]):
            code, out, err = run(step)
            if code != 0:
                print(f"#{index}: {step[0]} failed: {err.strip()}")
                break
        else:
            certified = [l for l in out.splitlines() if l.startswith("certified M_C")]
            print(f"#{index}: {n} states, dt = {dt}, {time.time() - started:.0f} s to train and "
                  f"certify; {certified[0] if certified else ''}", flush=True)
            for name, flags, integrator, step in settings(dt, index, args.exotic):
                json_path = os.path.join(folder, "reach.json")
                worst, info = check(run, scenario, h_of, n, flags, integrator, step, json_path)
                if worst is None:
                    print(f"  {name}: not run: {info}")
                elif worst > TOLERANCE:
                    escapes += 1
                    print(f"  {name}: ESCAPE by {worst:.2e} of the set's width at {info[1]}")
                else:
                    print(f"  {name}: {info[0]} states inside their sets", flush=True)
            # Verdicts too: `verify --check 3` simulates 3ⁿ starts in every verified box with
            # the true filter and fails if one ends elsewhere than its verdict says.
            grid = "6,6" if n == 2 else "4,4,4"
            code, out, err = run(["verify", scenario, "--grid", grid, "--check", "3",
                                  "--no-what-stops"])
            said = [l.strip() for l in out.splitlines() if "ground-truth check" in l]
            if code != 0:
                escapes += 1
                print(f"  verify --check 3: FAILED: {(said or [err.strip()])[0]}")
            else:
                print(f"  verify --check 3: {said[0] if said else 'no verified box'}", flush=True)
    print(f"{escapes} escape(s); scenarios in {folder}")
    sys.exit(1 if escapes else 0)


if __name__ == "__main__":
    main()
