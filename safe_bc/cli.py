"""The ``safe-bc`` command line."""

from __future__ import annotations

import argparse
import sys
from collections.abc import Callable, Sequence
from pathlib import Path

from safe_bc.data.store import DatasetError

DEFAULT_DEMOS = Path("data/demos")


def _positive(name: str) -> Callable[[str], int]:
    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{name} must be an integer, got {text!r}") from None
        if value < 1:
            raise argparse.ArgumentTypeError(f"{name} must be >= 1, got {value}")
        return value

    return parse


def _non_negative(text: str) -> int:
    value = int(text)
    if value < 0:
        raise argparse.ArgumentTypeError(f"must be >= 0, got {value}")
    return value


def _env_args(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--env",
        choices=["carracing", "rehab"],
        default="carracing",
        help="task: CarRacing-v3 (default) or the rehabilitation pathway",
    )
    p.add_argument(
        "--renderer",
        choices=["fast", "stock"],
        default="fast",
        help="CarRacing renderer (fast is pixel-identical to stock)",
    )


def _cmd_collect(args: argparse.Namespace) -> int:
    from safe_bc.collection import CollectConfig
    from safe_bc.distributed.collect import collect
    from safe_bc.tasks import task_defaults

    defaults = task_defaults(args.env, renderer=args.renderer)
    config = CollectConfig(
        episodes=args.episodes,
        workers=args.workers,
        seed=args.seed,
        env=defaults.env,
        expert=defaults.expert,
        perturbation=defaults.perturbation,
        max_steps=args.max_steps,
        encoding=args.encoding or defaults.encoding,
    )
    report = collect(config, args.out, progress=not args.quiet)
    print(
        f"{args.out}: {len(report.collected)} episode(s) collected, {len(report.reused)} reused, "
        f"{report.steps} steps in {report.seconds:.1f} s ({report.steps_per_s:.0f} steps/s), "
        f"{report.worker_restarts} worker restart(s)"
    )
    return 0


def build_parser() -> argparse.ArgumentParser:
    """The argument parser of ``safe-bc``."""
    parser = argparse.ArgumentParser(
        prog="safe-bc", description="Safety-focused behaviour cloning as a Ray study."
    )
    sub = parser.add_subparsers(dest="command", required=True)

    p = sub.add_parser("collect", help="collect expert demonstrations into Parquet")
    p.add_argument("--episodes", type=_positive("--episodes"), default=5)
    p.add_argument("--workers", type=_positive("--workers"), default=2)
    p.add_argument("--seed", type=_non_negative, default=0)
    p.add_argument("--out", type=Path, default=DEFAULT_DEMOS)
    p.add_argument("--max-steps", type=_positive("--max-steps"), default=None)
    p.add_argument("--encoding", choices=["png", "raw", "vector"], default=None)
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    _env_args(p)
    p.set_defaults(func=_cmd_collect)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point: parse, run, turn expected failures into one-line errors."""
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return args.func(args)
    except (DatasetError, ValueError, FileNotFoundError) as e:
        print(f"safe-bc {args.command}: error: {e}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(
            f"safe-bc {args.command}: interrupted; rerun the same command to resume",
            file=sys.stderr,
        )
        return 130


if __name__ == "__main__":
    sys.exit(main())
