"""What the comparison scripts share: the box file they read and the result file they write."""

import json
from pathlib import Path


def read_spec(path):
    """The boxes and settings (README.md here), with the step, the step count and how often to
    record the sets."""
    spec = json.loads(Path(path).read_text())
    return spec, spec["dt"], spec["steps"], spec.get("record_every", spec["steps"])


def write_result(path, result, label):
    """Writes the result (`run_s`: the times of the Euler loop) and prints its rate."""
    Path(path).write_text(json.dumps(result))
    best = min(result["run_s"])
    print(
        f"{label}: {result['boxes']} boxes × {result['steps']} steps in {best:.3f} s (best of "
        f"{len(result['run_s'])}): {result['boxes'] * result['steps'] / best:.0f} box-steps/s"
    )


def layer_names(tensors):
    """The indices of the linear layers in PyTorch's nn.Sequential names (`0.weight`, `2.weight`,
    …) and the network's widths, input first."""
    layers = sorted({int(name.split(".")[0]) for name in tensors})
    widths = [tensors[f"{layers[0]}.weight"].shape[1]] + [
        tensors[f"{i}.weight"].shape[0] for i in layers
    ]
    return layers, widths
