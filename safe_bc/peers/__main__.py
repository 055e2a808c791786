"""``python -m safe_bc.peers prepare|evaluate``: ``make peers``'s steps in safe_bc's env."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path


def main(argv: list[str] | None = None) -> int:
    from safe_bc.peers.run import BLOCK, COST_LIMIT

    parser = argparse.ArgumentParser(prog="python -m safe_bc.peers", description=__doc__)
    sub = parser.add_subparsers(dest="step", required=True)
    for name in ("prepare", "evaluate"):
        p = sub.add_parser(name)
        p.add_argument("--task", default="rehab", help="a vector task (default: rehab)")
        p.add_argument("--demos", type=Path, default=None, help="default: the task's")
        p.add_argument("--runs", type=Path, default=Path("runs/peers"))
    prep = sub.choices["prepare"]
    prep.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    prep.add_argument("--cost-limit", type=float, default=COST_LIMIT)
    prep.add_argument("--scale", type=float, default=1.0, help="multiplies every budget")
    ev = sub.choices["evaluate"]
    ev.add_argument("--out", type=Path, default=Path("results/peers"))
    ev.add_argument("--block", type=int, default=BLOCK)
    ev.add_argument("--patients", type=int, default=200)
    ev.add_argument("--recommender", type=Path, default=None,
                    help="default: results/beyond_<task>/recommender where it exists")  # fmt: skip
    ev.add_argument("--workers", type=int, default=0)
    args = parser.parse_args(argv)

    from safe_bc.peers import run
    from safe_bc.tasks import task_defaults

    demos = args.demos or Path(task_defaults(args.task).demos)
    if args.step == "prepare":
        print(run.prepare(demos, args.runs, seeds=tuple(args.seeds), cost_limit=args.cost_limit,
                          scale=args.scale))  # fmt: skip
        return 0
    rec = args.recommender or Path(f"results/beyond_{args.task}/recommender")
    print(run.evaluate(args.task, demos, args.runs, args.out, block=args.block,
                       patients=args.patients, recommender=rec, workers=args.workers))  # fmt: skip
    return 0


if __name__ == "__main__":
    sys.exit(main())
