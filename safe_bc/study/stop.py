"""Ctrl-C and SIGTERM during ``safe-bc tune``: the study stops with one line (exit 130 or
143), keeping what finished, and a rerun resumes.

Outside Tune's ``fit`` a signal raises :class:`StudyStopped`; inside :func:`deferred_stop`
(the final phase's training and evaluations, where an exception raised at an arbitrary point
of torch's lazy imports left them half-initialised) the first signal is recorded and raised
at the next :func:`stop_point`, after the agent or evaluation under way is stored, or after
:data:`STOP_GRACE_S` seconds, whichever comes first (``docker stop`` and Kubernetes send
SIGKILL some seconds after SIGTERM); during ``fit`` Tune's own handler saves the experiment
and returns.
"""

from __future__ import annotations

import _thread
import os
import signal
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any

STOP_GRACE_S = 5.0
"""How long a signal inside :func:`deferred_stop` waits for the agent or evaluation under way
before it stops the study anyway (that piece of work is then redone by the rerun)."""


class StudyStopped(KeyboardInterrupt):
    """Ctrl-C (SIGINT) or SIGTERM outside Tune's ``fit`` (setting up; the final phase, once the
    agent or evaluation under way is kept): what finished is kept and a rerun resumes from
    it. ``safe-bc tune`` prints it as one line and exits with :attr:`exit_code`."""

    def __init__(self, signum: int) -> None:
        self.signum = signum
        self.exit_code = 128 + signum
        """The shell's code for the signal: 130 (SIGINT), 143 (SIGTERM)."""
        name = signal.Signals(signum).name
        super().__init__(
            f"stopped by {name}; the finished trials and final-phase agents and evaluations "
            "are kept: rerun the same command to resume from them"
        )


class _Stop:
    """The study's SIGINT and SIGTERM handlers. Outside ``fit`` both raise
    :class:`StudyStopped`. During ``fit`` Tune's own SIGINT handler is in place (it saves the
    experiment and returns); SIGTERM is recorded and handed to it as SIGINT. ``ray.init``
    sets its own SIGTERM handler (``sys.exit``, which aborted the driver) and ``fit`` leaves
    Tune's SIGINT handler behind (which swallowed Ctrl-C in the final phase), so
    :meth:`install` is called again after each."""

    def __init__(self) -> None:
        self.signum = 0
        """The signal that stopped the study (0: none)."""
        self.previous: dict[int, Any] = {}
        self.deferring = 0
        """Inside :func:`deferred_stop`: the first signal is recorded and raised at the next
        :func:`stop_point`, a second one (or :data:`STOP_GRACE_S` later) at once."""
        self.grace: threading.Timer | None = None
        """Delivers the recorded signal again when the grace period is over."""
        self.tune_caught = False
        """Tune's handler has caught a Ctrl-C (see :func:`tune_caught_signal`)."""

    def _outside_fit(self, signum: int, frame: Any) -> None:
        if self.deferring and not self.signum:
            self.signum = signum
            self.grace = threading.Timer(STOP_GRACE_S, _thread.interrupt_main, args=(signum,))
            self.grace.daemon = True
            self.grace.start()
            return
        self.cancel_grace()
        self.signum = self.signum or signum
        raise StudyStopped(signum)

    def cancel_grace(self) -> None:
        if self.grace is not None:
            self.grace.cancel()
            self.grace = None

    def _term(self, signum: int, frame: Any) -> None:
        if signal.getsignal(signal.SIGINT) == self._outside_fit:
            self._outside_fit(signum, frame)  # raises, or defers (returns)
            return
        self.signum = self.signum or signum
        signal.raise_signal(signal.SIGINT)  # Tune's handler: save and return

    def install(self) -> None:
        for signum, handler in ((signal.SIGINT, self._outside_fit), (signal.SIGTERM, self._term)):
            try:
                old = signal.signal(signum, handler)
            except ValueError:  # not the main thread
                return
            self.previous.setdefault(signum, old)

    def restore(self) -> None:
        self.cancel_grace()
        for signum, old in self.previous.items():
            signal.signal(signum, old)


_STOP: _Stop | None = None
"""The handlers of the study running in this process (see :func:`run_study`)."""


@contextmanager
def _stop_signals() -> Iterator[_Stop]:
    global _STOP
    stop = _Stop()
    stop.install()
    _STOP = stop
    try:
        yield stop
    finally:
        _STOP = None
        stop.restore()


def _reinstall_signals() -> None:
    if _STOP is not None:
        _STOP.install()


def _fit_stopped() -> int:
    """After ``fit``: the signal that stopped it (0: none), and the study's handlers back (``fit``
    leaves Tune's SIGINT handler behind, which swallowed a Ctrl-C in the final phase). Tune's
    handler puts the one before it (ours) back when it has caught a signal."""
    if _STOP is None:
        return 0
    if _tune_handles_sigint() and signal.getsignal(signal.SIGINT) == _STOP._outside_fit:
        _STOP.signum = _STOP.signum or signal.SIGINT
    _STOP.install()
    return _STOP.signum


def _tune_handles_sigint() -> bool:
    return threading.current_thread() is threading.main_thread() and not int(
        os.environ.get("TUNE_DISABLE_SIGINT_HANDLER", "0")
    )


def tune_caught_signal() -> None:
    """Note that Tune's SIGINT handler has caught a signal (its notice is the sign: the handler
    logs it before anything else, see :func:`safe_bc.study.console.quiet_stop`)."""
    if _STOP is not None:
        _STOP.tune_caught = True


def stopping() -> bool:
    """A signal is stopping the study run in this process (in ``fit``: Tune's handler has
    caught a Ctrl-C, or a SIGTERM was recorded and handed to it)."""
    return _STOP is not None and bool(_STOP.signum or _STOP.tune_caught)


@contextmanager
def deferred_stop() -> Iterator[None]:
    """A signal inside the block is raised at the next :func:`stop_point` (or at its end)."""
    if _STOP is None:
        yield
        return
    _STOP.deferring += 1
    try:
        yield
    finally:
        _STOP.deferring -= 1
    stop_point()


def stop_point() -> None:
    """Raise :class:`StudyStopped` when a deferred signal has arrived."""
    if _STOP is not None and _STOP.signum:
        _STOP.cancel_grace()
        raise StudyStopped(_STOP.signum)
