"""Which CPU and torch kernels this machine has, and whether a batched forward rounds
differently from one-row passes on real CarRacing frames (why ``BCNet.forward_rows`` runs each
row on its own), with ``forward_rows`` checked against one-row passes.

Run: ``python -m scripts.batch_rounding``; ``results/checks/machine_types.md`` holds its
output on the machine types it was run on.
"""

from __future__ import annotations

import sys

import numpy as np
import torch

NETS = (((16, 32, 32), 128), ((8, 16, 16), 64), ((16, 32, 32), 256))
"""(channels, hidden) of the nets checked: the default and the study's extremes."""
BATCHES = (2, 3, 4, 8)


def cpu_line(key: str) -> str:
    """The first ``/proc/cpuinfo`` line starting with ``key`` ("" where there is none)."""
    try:
        with open("/proc/cpuinfo") as f:
            return next((line.strip() for line in f if line.startswith(key)), "")
    except OSError:
        return ""


def main() -> None:
    from safe_bc.bc import CAR_RACING_BOUNDS, BCNet, ModelSpec, NetworkConfig, PreprocessConfig
    from safe_bc.bc.preprocess import preprocess
    from safe_bc.tasks import make_env

    cap = torch.backends.cpu.get_cpu_capability()
    print("python", sys.version.split()[0], "torch", torch.__version__, "capability", cap)
    print(cpu_line("model name"))
    flags = cpu_line("flags").split()
    print(*(f"{f} {f in flags}" for f in ("avx2", "avx512f", "amx_tile")))
    torch.set_num_threads(1)
    env = make_env()
    env.reset(seed=3)
    frames = []
    for t in range(120):
        obs, *_ = env.step(np.array([0.0, 0.3 if t % 3 else 0.0, 0.0], np.float32))
        frames.append(obs)
    env.close()
    x = preprocess(np.stack(frames), PreprocessConfig())
    spec = ModelSpec.for_data((96, 96, 3), 3, CAR_RACING_BOUNDS)
    for channels, hidden in NETS:
        torch.manual_seed(0)
        net = NetworkConfig(hidden=hidden, channels=channels)
        m = BCNet(spec, PreprocessConfig(), net).eval()
        with torch.inference_mode():
            rows = torch.cat([m(x[i : i + 1]) for i in range(len(x))])
            for b in BATCHES:
                n = len(x) // b * b
                batched = torch.cat([m(x[i : i + b]) for i in range(0, n, b)])
                fr = torch.cat([m.forward_rows(x[i : i + b]) for i in range(0, n, b)])
                print(
                    f"net {channels}-{hidden} batch {b}: plain batched differs in "
                    f"{int((batched != rows[:n]).sum())}/{rows[:n].numel()} elements; "
                    f"forward_rows equal: {torch.equal(fr, rows[:n])}"
                )


if __name__ == "__main__":
    main()
