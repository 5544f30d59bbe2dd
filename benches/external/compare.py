"""cbfreach beside immrax and the paper's auto_LiRPA pipeline on scenario 1, on this machine.

For each tool and box set: the wall time of the sets (the Euler loop, not start-up or
compilation) as box-steps per second, and how far the sets lie from cbfreach's computed by the
same method (relative to the set's width; cbfreach's must never be tighter, beyond rounding,
than a tool that computes the same bounds without rounding them outward).

Run it with the Python that has immrax and auto_LiRPA (benches/external/README.md), from the
repository root, after `cargo build --release`:

    python benches/external/compare.py [--boxes 12,256] [--steps 250] [--m 0]
"""

import argparse
import json
import re
import subprocess
import sys
import tempfile
import tomllib
from pathlib import Path

here = Path(__file__).resolve().parent
root = here.parent.parent
parser = argparse.ArgumentParser()
parser.add_argument("--scenario", default=str(root / "scenarios/integrator.toml"))
parser.add_argument("--cbfreach", default=str(root / "target/release/cbfreach"))
parser.add_argument(
    "--boxes",
    default="12,256",
    help="box sets: 12 is the scenario's own (the paper's) boxes; any other count is a grid of "
    "boxes 0.05 wide left of the obstacle, whose sets all converge",
)
parser.add_argument("--steps", type=int, default=250)
parser.add_argument(
    "--m", type=float, default=0.0, help="the network's error bound M (global) for every tool"
)
parser.add_argument(
    "--tools",
    default="immrax,lirpa",
    help="tools beside cbfreach: immrax, lirpa (auto_LiRPA), comma-separated",
)
parser.add_argument(
    "--methods",
    default="forward,crown",
    help="cbfreach's bound methods to run: forward (beside immrax), crown (beside auto_LiRPA)",
)
args = parser.parse_args()
if not Path(args.cbfreach).is_file():
    sys.exit(f"no cbfreach binary at {args.cbfreach}: run `cargo build --release` or pass --cbfreach")
work = Path(tempfile.mkdtemp(prefix="cbfreach-compare-"))
scenario = tomllib.loads(Path(args.scenario).read_text())
reach = scenario["reach"]


def box_set(count):
    if count == len(reach["initial"]):
        return [[b["lower"], b["upper"]] for b in reach["initial"]]
    across = max(1, round((count / 2) ** 0.5))
    rows = -(-count // across)
    boxes = []
    for r in range(rows):
        for c in range(across):
            x1 = -3.3 + 3.0 * (c + 0.5) / across
            x2 = -2.5 + 5.0 * (r + 0.5) / rows
            boxes.append([[x1 - 0.025, x2 - 0.025], [x1 + 0.025, x2 + 0.025]])
    return boxes[:count]


def scenario_with(boxes):
    """The scenario file with these initial boxes and an absolute network path."""
    text = Path(args.scenario).read_text()
    network = (Path(args.scenario).parent / scenario["network"]["file"]).resolve()
    text = re.sub(r'(?m)^file = .*$', f'file = "{network}"', text)
    text = re.sub(r"(?ms)^initial = \[.*?^\]\s*$", "", text)
    listed = ",\n".join(f"  {{ lower = {lo}, upper = {up} }}" for lo, up in boxes)
    text = re.sub(
        r"(?m)^horizon = .*$", f"horizon = {args.steps * reach['dt']}", text
    )
    return text.replace("[reach]", f"[reach]\ninitial = [\n{listed},\n]", 1), network


def run(command):
    """Runs a command; on failure, stops with what it printed."""
    done = subprocess.run(command, capture_output=True, text=True)
    if done.returncode != 0:
        sys.exit(f"{' '.join(map(str, command))} failed:\n{done.stderr or done.stdout}")


def run_cbfreach(path, bounds, face_local):
    out = work / f"cbfreach-{bounds}-{face_local}.json"
    # The Euler map, as the other tools integrate (the default is the continuous-time model,
    # whose validated steps are more work than the step compared).
    command = [args.cbfreach, "reach", str(path), "--time", "euler", "--bounds", bounds,
               "--exact", "nowhere", "--no-safe-set", "--m-c", str(args.m), "--json", str(out)]
    if face_local:
        command.append("--face-local")
    run(command)
    result = json.loads(out.read_text())
    steps_run = sum(len(b["tube"]) - 1 for b in result["boxes"])
    return result, steps_run / result["timing"]["reach_s"], steps_run


def run_tool(script, spec_path, network, options):
    out = work / f"{script}-{'-'.join(options) or 'default'}.json"
    run([sys.executable, str(here / script), str(spec_path), str(network), str(out), *options])
    return json.loads(out.read_text())


def distance(ours, theirs):
    """The largest amounts by which cbfreach's sets are wider and tighter than the tool's, over
    the steps where cbfreach's set is valid, relative to the set's width (or to 10⁻³ of the
    initial box's width, where the sets have shrunk below that: at M = 0 sets that converge
    shrink towards a point, and a relative difference of nothing says nothing)."""
    wider = tighter = 0.0
    start = theirs["sets"]["0"]
    for k, sets in theirs["sets"].items():
        for b, (lo, up) in enumerate(sets):
            tube = ours["boxes"][b]["tube"]
            if int(k) >= len(tube):
                continue
            o = tube[int(k)]
            for i in range(len(lo)):
                floor = 1e-3 * (start[b][1][i] - start[b][0][i])
                width = max(up[i] - lo[i], floor)
                for d in (lo[i] - o["lower"][i], o["upper"][i] - up[i]):
                    wider, tighter = max(wider, d / width), max(tighter, -d / width)
    return wider, tighter


rows = []
for count in [int(c) for c in args.boxes.split(",")]:
    boxes = box_set(count)
    text, network = scenario_with(boxes)
    path = work / f"scenario-{count}.toml"
    path.write_text(text)
    spec_path = work / f"boxes-{count}.json"
    spec = {"boxes": boxes, "k": [scenario["parameters"]["k1"], scenario["parameters"]["k2"]],
            "m": args.m, "dt": reach["dt"], "steps": args.steps, "record_every": 1}
    spec_path.write_text(json.dumps(spec))
    if "forward" in args.methods:
        forward, forward_rate, forward_steps = run_cbfreach(path, "forward", True)
        rows.append((count, "cbfreach", "forward, face-local (f64, rounding bounded)",
                     forward_rate, f"{forward_steps} box-steps run", ""))
    if "crown" in args.methods:
        crown, crown_rate, crown_steps = run_cbfreach(path, "crown", False)
        rows.append((count, "cbfreach", "crown (f64, rounding bounded)", crown_rate,
                     f"{crown_steps} box-steps run", ""))
    full = count * args.steps
    if "immrax" in args.tools and "forward" in args.methods:
        for options, label in [(["--x64", "--plain-forward"], "plain forward, face-local (f64)"),
                               (["--x64"], "'crown', face-local (f64)"),
                               ([], "'crown', face-local (f32)")]:
            r = run_tool("immrax_reach.py", spec_path, network, options)
            wider, tighter = distance(forward, r)
            rows.append((count, "immrax", label, full / min(r["run_s"]),
                         f"compiled in {r['compile_and_first_run_s']:.1f} s",
                         f"{wider:.1e} / {tighter:.1e}"))
    if "lirpa" in args.tools and "crown" in args.methods:
        for options, label in [([], "CROWN (f64)"), (["--f32"], "CROWN (f32)")]:
            r = run_tool("lirpa_reach.py", spec_path, network, options)
            wider, tighter = distance(crown, r)
            rows.append((count, "auto_LiRPA", label, full / min(r["run_s"]), "",
                         f"{wider:.1e} / {tighter:.1e}"))

print(f"scenario 1, {args.steps} Euler steps, M = {args.m}; sets beside cbfreach's by the same "
      "method (forward for immrax, crown for auto_LiRPA): cbfreach wider / tighter, relative")
print("| boxes | tool | bounds | box-steps/s | note | cbfreach wider / tighter |")
print("| --- | --- | --- | --- | --- | --- |")
for count, tool, label, rate, note, dist in rows:
    print(f"| {count} | {tool} | {label} | {rate:,.0f} | {note} | {dist} |")
