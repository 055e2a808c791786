"""The ``safe-bc`` command line, generated from :mod:`safe_bc.cli.jobs` by tyro.

A command's flags are its record's fields (help: their docstrings; nested configs: dotted
flags such as ``--selection.eps`` or ``--bc.train.lr``); the work is :mod:`safe_bc.cli.api`'s.
Bad input is one line, ``safe-bc CMD: error: ...``, and exit code 2.
"""

from __future__ import annotations

import contextlib
import inspect
import io
import itertools
import os
import re
import shlex
import shutil
import signal
import sys
from collections.abc import Callable, Sequence
from typing import Any


def _commands() -> dict[str, tuple[str, str]]:
    from safe_bc.methods import METHOD_COMMANDS

    own = {c.name: (c.record_name, c.name) for c in METHOD_COMMANDS.values()}
    return {
        "collect": ("CollectJob", "collect"),
        "describe": ("DescribeJob", "describe"),
        "train": ("TrainJob", "train"),
        "evaluate": ("EvaluateJob", "evaluate"),
        "expert": ("ExpertJob", "expert"),
        "reproduce": ("ReproduceJob", "reproduce"),
        "compare": ("CompareJob", "compare"),
        "tune": ("TuneJob", "tune"),
        "method": ("MethodJob", "method"),
        **own,
        "export": ("ExportJob", "export"),
        "render": ("RenderJob", "render"),
    }


COMMANDS: dict[str, tuple[str, str]] = _commands()
"""Command -> (its record in :mod:`safe_bc.cli.jobs`, its function in :mod:`safe_bc.cli.api`).
The commands from before ``safe-bc method NAME`` (after ``method``) are those of
:data:`safe_bc.methods.METHOD_COMMANDS`, their records and functions read from their methods'
code (by name, through ``jobs`` and ``api``); they run as before, after one line to stderr
naming the new form (:func:`_new_form`)."""

RAY_COMMANDS = frozenset({"collect", "compare", "evaluate", "expert", "reproduce", "tune"})
"""Commands that may start or join Ray: with ``RAY_ADDRESS`` set they join the cluster before
they write anything."""

REQUIRES = {
    "selection.quantile": ("selection.threshold", "quantile"),
    "selection.segment_steps": ("selection.mode", "bc_safe"),
    "selection.beta": ("selection.mode", "cost_weighted"),
}
"""``safe-bc train``: a setting that only applies with another's value (given without it, the
command is refused rather than the setting silently ignored)."""


ALIASES = {
    "train": {"--seed": "--bc.train.seed"},
    "reproduce": {"--env": "--task"},
    "evaluate": {
        "--defer-width": "--handover.width",
        "--defer-hold": "--handover.hold",
        "--defer-lookahead": "--handover.lookahead",
        "--defer-hold-on": "--handover.hold-on",
    },
}
"""Other spellings a command takes, per command: alias -> the field's flag (short flags kept
from the hand-written CLI, and the names flags had before they took their config's)."""


HELP_FLAGS = ("-h", "--help")
"""The short help (:mod:`safe_bc.cli.help`: one entry per flag, the first sentence of its
docstring); ``--help-full`` is tyro's help with the whole docstrings."""

ONE_LINE_ERRORS = (
    ("safe_bc.bc.checkpoint", "CheckpointError"),
    ("safe_bc.data.store", "DatasetError"),
    ("safe_bc.distributed.runtime", "RayUnavailableError"),
    ("safe_bc.data.locks", "OutputLockedError"),
)
"""Errors (module, class) that end a command with one line and exit code 2, besides
:class:`UsageError`, ``ValueError`` and ``FileNotFoundError``; looked up only where their
module is loaded, so that the command line does not import torch or pyarrow to start."""


class UsageError(Exception):
    """Bad command-line input: one line, exit code 2."""


def _one_line_errors() -> tuple[type[BaseException], ...]:
    """:data:`ONE_LINE_ERRORS` whose modules are loaded (an error of a module never imported
    cannot have been raised), with the built-in ones."""
    loaded = [getattr(sys.modules[m], n) for m, n in ONE_LINE_ERRORS if m in sys.modules]
    return (UsageError, ValueError, FileNotFoundError, *loaded)


def given(argv: Sequence[str]) -> set[str]:
    """The dotted field names set on the command line (``--bc.train.batch-size=8`` ->
    ``bc.train.batch_size``)."""
    return {a[2:].split("=")[0].replace("-", "_") for a in argv if a.startswith("--")}


def _one_line(box: str) -> str:
    """tyro's error box (drawn in UTF-8 or ASCII) as one line: its sections but the helptext
    ones, joined."""
    sections, rows = [], []
    for line in re.sub(r"\x1b\[[0-9;]*m", "", box).splitlines()[1:]:  # below the title
        body = line.strip().strip("│").strip()
        if set(body) <= set("─-╰╯ "):  # a rule, the bottom edge or an empty line
            sections.append(" ".join(rows))
            rows = []
        else:
            rows.append(body)
    sections.append(" ".join(rows))
    keep = [_short(s) for s in sections if s and not re.match(r"(Argument|For full) help", s)]
    return "; ".join(keep).replace("__tyro-dummy-inner__.", "").removeprefix("Error parsing ")


def _short(section: str) -> str:
    """A section of tyro's box without its help texts: the unrecognized flags alone (not the
    values after them) and the suggested flags' names (at most 3), not their docstrings."""
    if section.startswith("Unrecognized options:"):
        flags = [t for t in section.split(":", 1)[1].replace(",", " ").split() if t[:1] == "-"]
        return f"unrecognized option(s) {', '.join(flags)}" if flags else section
    if section.startswith("Perhaps you meant"):
        names = list(dict.fromkeys(re.findall(r"(?<![\w-])--[\w][\w.-]*", section)))
        return f"did you mean {', '.join(names[:3])}?" if names else section
    return section


def _flag_of(message: str, cls: type) -> str:
    """``message`` of a config's ValueError (``lr must be ...``, ``a.b: lr must be ...``)
    led by the flag of the field it names (``--bc.train.lr: lr must be ...``)."""
    import dataclasses
    import typing

    from safe_bc.cli.jobs import Flat

    def names(c: Any, prefix: str) -> list[str]:
        out = []
        for f in dataclasses.fields(c):
            hint = typing.get_type_hints(c, include_extras=True)[f.name]
            annotated = typing.get_origin(hint) is typing.Annotated
            kind = typing.get_args(hint)[0] if annotated else hint
            flat = annotated and Flat in typing.get_args(hint)[1:]
            inner = prefix if flat else f"{prefix}{f.name}."
            sub = names(kind, inner) if dataclasses.is_dataclass(kind) else []
            out += sub or [f"{prefix}{f.name}"]
        return out

    found = re.match(r"(?:([\w.]*): )?(\w+)(?:\[i\])? must", message)
    if not found:
        # the record's name, or the nested config's field, that tyro puts before a message
        # which names its flag itself
        return re.sub(r"^[A-Z]\w*: |^[\w.]+: (?=--)", "", message)
    group = "".join(
        f"{p}."
        for p in (found[1] or "").split(".")
        if p and p[0].islower() and p not in ("run", "config")
    )
    hits = [n for n in names(cls, "") if n == f"{group}{found[2]}" or n.endswith("." + found[2])]
    detail = message.split(": ", 1)[1] if found[1] is not None else message
    return f"--{hits[0].replace('_', '-')}: {detail}" if hits else message


def parse(argv: Sequence[str]) -> tuple[str, Any]:
    """``(command, its job record)`` of ``argv``; ``--help`` prints and exits 0.

    Raises:
        UsageError: a bad command, flag or value (the configs' ``__post_init__`` checks).
    """
    import tyro

    from safe_bc.cli import jobs

    if not argv or argv[0] in ("-h", "--help"):
        lines = [f"  {c:<10} {_doc(getattr(jobs, job))}" for c, (job, _) in COMMANDS.items()]
        usage = "usage: safe-bc {" + ",".join(COMMANDS) + "} [-h] ..."
        if not argv:
            raise UsageError(f"choose a command: {', '.join(COMMANDS)}")
        print("\n".join([usage, "", "Safety-focused behaviour cloning as a Ray study.", ""]))
        print("\n".join(lines))
        raise SystemExit(0)
    command = argv[0]
    if command not in COMMANDS:
        raise UsageError(f"unknown command {command!r}: choose {', '.join(COMMANDS)}")
    rest = _unalias(command, argv[1:])
    if command == "method":
        return command, _parse_method(rest)
    cls = getattr(jobs, COMMANDS[command][0])
    aliases = "\n".join(f"Alias {a} for {f}." for a, f in ALIASES.get(command, {}).items())
    about = inspect.cleandoc(cls.__doc__ or "") + (f"\n\n{aliases}" if aliases else "")
    if any(a in HELP_FLAGS for a in rest):
        from safe_bc.cli.help import render

        width = min(max(shutil.get_terminal_size((100, 24)).columns, 80), 120)
        _tell_new_form(command, rest)
        print(render(cls, f"safe-bc {command}", about, width=width))
        raise SystemExit(0)
    rest = ["--help" if a == "--help-full" else a for a in rest]
    err = io.StringIO()
    try:
        with contextlib.redirect_stderr(err):
            job = tyro.cli(cls, args=rest, prog=f"safe-bc {command}", description=about)
    except SystemExit as e:
        if e.code in (0, None):
            raise
        raise UsageError(_flag_of(_one_line(err.getvalue()), cls)) from None
    except ValueError as e:  # a flattened config's __post_init__ (tyro lets it through)
        raise UsageError(_flag_of(str(e), cls)) from None
    return command, _task_defaults(command, job, given(rest))


def _tell_new_form(command: str, argv: Sequence[str]) -> None:
    """One line to stderr giving an old command's ``safe-bc method NAME`` form (nothing for
    the others)."""
    new = _new_form(command, argv)
    if new:
        print(f"`safe-bc {command}` is `{new}` now", file=sys.stderr)


def _new_form(command: str, argv: Sequence[str]) -> str | None:
    """The ``safe-bc method NAME`` form of an old command (``None``: ``command`` is not one),
    its method the registered one taking the config the old command runs.

    >>> _new_form("query", []), _new_form("train", [])
    ('safe-bc method queries', None)
    >>> _new_form("improve", ["--out", "o", "--method=selfimitation"])
    'safe-bc method selfimprove'
    """
    import dataclasses

    from safe_bc.methods import METHOD_COMMANDS, method_of_config

    old = METHOD_COMMANDS.get(command)
    if old is None:
        return None
    modes = dict(old.configs)
    chosen = next(iter(modes))
    for before, a in itertools.pairwise(["", *argv]):
        chosen = a.partition("=")[2] if a.startswith("--method=") else chosen
        chosen = a if before == "--method" else chosen
    record = old.record()
    name = modes.get(chosen, old.configs[0][1])
    field = next(f for f in dataclasses.fields(record) if f.name == name)
    return f"safe-bc method {method_of_config(field.default_factory()).name}"  # type: ignore[misc]


def _parse_method(argv: Sequence[str]) -> Any:
    """``safe-bc method NAME ...`` (or ``--name NAME``): the
    :class:`~safe_bc.cli.jobs.MethodJob` of the registered method ``NAME``, its other flags
    those of :func:`safe_bc.cli.jobs.method_job` (``--config.FIELD``: the method's config
    record)."""
    import tyro

    from safe_bc.cli import jobs
    from safe_bc.methods import METHODS

    names = ",".join(METHODS)
    name, rest, args = None, [], iter(argv)
    if argv and not argv[0].startswith("-"):
        name, args = argv[0], iter(argv[1:])
    for a in args:
        if a == "--name":
            name = next(args, None)
        elif a.startswith("--name="):
            name = a.partition("=")[2]
        else:
            rest.append(a)
    if name is None:
        if {"-h", "--help", "--help-full"} & set(rest):
            print("usage: safe-bc method NAME --start PATH --out PATH [...]")
            print(f"(NAME: {names.replace(',', ', ')})\n")
            import shutil
            import textwrap

            width = min(shutil.get_terminal_size((80, 24)).columns, 120)
            about = " ".join(inspect.cleandoc(jobs.MethodJob.__doc__ or "").split())
            print(textwrap.fill(about, width) + "\n")
            for f in ("name", "start", "out", "demos"):
                doc = " ".join(inspect.cleandoc(_field_doc(jobs.MethodJob, f)).split())
                print(textwrap.fill(f"  --{f:<8} {doc}", width, subsequent_indent=" " * 13))
            print("  --config.FIELD  The method's settings (safe-bc method NAME --help).\n")
            raise SystemExit(0)
        raise UsageError(f"name a method: safe-bc method {{{names}}} ...")
    if name not in METHODS:
        raise UsageError(f"unknown method {name!r}: choose {names.replace(',', ', ')}")
    argv = [name, *rest]
    spec = METHODS[argv[0]]
    cls = jobs.method_job(spec.config)
    about = f"Run the method {spec.name} from a checkpoint (rerun to resume)."
    err = io.StringIO()
    try:
        with contextlib.redirect_stderr(err):
            parsed = tyro.cli(cls, args=list(argv[1:]), prog=f"safe-bc method {spec.name}",
                              description=about)  # fmt: skip
    except SystemExit as e:
        if e.code in (0, None):
            raise
        raise UsageError(_flag_of(_one_line(err.getvalue()), cls)) from None
    except ValueError as e:
        raise UsageError(_flag_of(str(e), cls)) from None
    return jobs.MethodJob(spec.name, parsed.start, parsed.out, parsed.config, parsed.demos)


def _field_doc(cls: type, name: str) -> str:
    """The docstring of ``cls``'s field ``name`` (the string right below it in the source)."""
    import ast

    body = ast.parse(inspect.getsource(cls)).body[0].body  # type: ignore[attr-defined]
    for node, below in itertools.pairwise(body):
        target = getattr(node, "target", None)
        if getattr(target, "id", None) == name and isinstance(below, ast.Expr):
            return str(below.value.value)  # type: ignore[attr-defined]
    return ""


def _unalias(command: str, argv: Sequence[str]) -> list[str]:
    """``argv`` with :data:`ALIASES` spelled out (``--seed=1`` too)."""
    table = ALIASES.get(command, {})
    out = []
    for a in argv:
        flag, eq, value = a.partition("=")
        out.append(table.get(flag, flag) + eq + value)
    return out


def _doc(cls: type) -> str:
    return (cls.__doc__ or "").split("\n")[0].rstrip(".")


def _task_defaults(command: str, job: Any, flags: set[str]) -> Any:
    """Defaults that depend on the task: ``reproduce``'s demos and out folders; checks the
    ``train`` settings that apply only with another (:data:`REQUIRES`)."""
    import dataclasses
    from pathlib import Path

    if command == "reproduce":
        from safe_bc.tasks import task_defaults

        task = task_defaults(job.config.task)
        paths = {"demos": task.demos, "out": task.results}
        own = {k: Path(v) for k, v in paths.items() if k not in flags}
        return dataclasses.replace(job, config=dataclasses.replace(job.config, **own))
    if command == "train":
        for name, (other, value) in REQUIRES.items():
            have = getattr(job.run.selection, other.split(".")[1])
            if name in flags and have != value:
                flag, needs = "--" + name.replace("_", "-"), "--" + other.replace("_", "-")
                raise UsageError(f"{flag} applies with {needs} {value}")
    return job


def run(command: str, job: Any, argv: Sequence[str]) -> int:
    """Run ``job`` through :mod:`safe_bc.cli.api`, print its summary; the exit code."""
    from safe_bc.cli import api

    call: Callable[..., Any] = getattr(api, COMMANDS[command][1])
    kwargs: dict[str, Any] = {}
    if command == "tune":
        kwargs["command"] = shlex.join(["safe-bc", *argv])
    done = call(job, **kwargs)
    if done.message:
        print(done.message)
    return done.code


class Interrupted(KeyboardInterrupt):
    """Ctrl-C or SIGTERM outside a study's own handling: one line, exit 130 or 143."""

    def __init__(self, signum: int) -> None:
        self.exit_code = 128 + signum
        super().__init__(
            f"stopped by {signal.Signals(signum).name}; rerun the same command to resume"
        )


def _interrupt(signum: int, frame: Any) -> None:
    raise Interrupted(signum)


def _stop_ray() -> None:
    """Shut this process's Ray down, where a command started it (the command line imports
    Ray only when a command needs it)."""
    if "safe_bc.distributed.runtime" in sys.modules:
        from safe_bc.distributed.runtime import stop_ray

        stop_ray()


def _set_signals(handler: Any) -> None:
    for signum in (signal.SIGINT, signal.SIGTERM):
        signal.signal(signum, handler)


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point: parse, run, turn expected failures into one-line errors.

    Ctrl-C or SIGTERM (``StudyStopped``, a ``KeyboardInterrupt``) prints one line and returns
    130 or 143. Run as the program (``argv`` not given) it also stops on SIGTERM as on Ctrl-C
    where no study handles it, shuts Ray down and exits at once after a stop, and shuts Ray
    down ignoring signals after a finished command.
    """
    argv_given = argv is not None
    if not argv_given:  # the program: SIGTERM stops it like Ctrl-C (a study sets its own)
        _set_signals(_interrupt)
    argv = list(sys.argv[1:] if argv is None else argv)
    name = argv[0] if argv and argv[0] in COMMANDS else None
    where = f"safe-bc {name}" if name else "safe-bc"
    job = None
    try:
        command, job = parse(argv)
        from safe_bc.distributed.runtime import check_ray_address

        if command in RAY_COMMANDS and check_ray_address() is not None:
            # join the cluster before anything is written (a refused address fails in
            # milliseconds, something that is not Ray within ~40 s)
            from safe_bc.distributed.runtime import ensure_ray

            ensure_ray()
        code = run(command, job, argv)
        _tell_new_form(command, argv[1:])  # once it ran: bad input keeps its one line
        if not argv_given:  # the command is done: a signal no longer interrupts its exit
            _set_signals(signal.SIG_IGN)
            _stop_ray()
        return code
    except KeyboardInterrupt as e:  # StudyStopped says which signal and what a rerun does
        if not argv_given:  # another signal ends the program now (Ray's processes with it)
            _set_signals(signal.SIG_DFL)
        what = str(e) or "interrupted; rerun the same command to resume"
        print(f"{where}: {what}", file=sys.stderr, flush=True)
        code = getattr(e, "exit_code", 130)
        if argv_given:  # a caller in this process: its Ray and its exit are its own
            return code
        # the program itself: the line above is its last output (Ray's shutdown printed
        # workers' dying words), nothing is left to write (every output is written whole), and
        # the interpreter's teardown (torch's, Ray's hooks) took seconds
        sys.stdout.flush()
        sys.stderr.flush()
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
        os.dup2(devnull, sys.stderr.fileno())
        _stop_ray()
        os._exit(code)
    except Exception as e:
        if isinstance(e, _one_line_errors()):
            print(f"{where}: error: {e}", file=sys.stderr)
            return 2
        if not isinstance(e, OSError):
            raise
        # writing an output: a full disk, a read-only mount, a file in the way
        out = getattr(job, "out", None)
        place = f"{e.filename}: " if e.filename else f"writing {out}: " if out else ""
        detail = e.strerror or " ".join(str(e).split())
        print(f"{where}: error: {place}{detail}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
