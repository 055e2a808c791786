"""Starting or joining Ray.

* **Local runs** (``RAY_ADDRESS`` unset or ``local``: tests, a laptop) start a private Ray
  whose processes (GCS, raylet, workers, the driver) listen on loopback only, so token
  authentication is not needed and is switched off.
* **Cluster runs** (``RAY_ADDRESS`` set) join that cluster with Ray's own authentication
  settings (``RAY_AUTH_MODE=token`` + ``RAY_AUTH_TOKEN``), after a quick check that something
  answers at the address (:func:`check_ray_address`): without it ``ray.init()`` retries for
  more than ten minutes when nothing is there.

A local Ray's own processes (GCS, raylet and through it the workers) run in a session of
their own, so a signal to the driver's process group (``timeout``, ``docker stop``, ``kill --
-PGID``) reaches the driver only, which then stops Ray itself; they still die with the driver
(Ray asks the kernel to kill them when it exits). Ctrl-C and SIGTERM during ``ray.init`` are
held until it returns (:func:`signals_held`): an exception raised inside it left a
half-started Ray that crashed the driver on exit.
"""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from typing import Any
from urllib.parse import urlsplit

# Ray is imported where it is used: the command line checks RAY_ADDRESS before importing it.

CONNECT_TIMEOUT_S = 5.0
"""How long :func:`check_ray_address` waits for a TCP connection to the cluster."""

RAY_CLIENT_PORT = 10001
"""Ray Client's default port (``ray://host`` without a port)."""


class RayUnavailableError(ConnectionError):
    """``RAY_ADDRESS`` names no reachable Ray cluster (the message is one line)."""


@dataclass(frozen=True)
class RayAddress:
    """``RAY_ADDRESS`` taken apart."""

    text: str
    """As given."""
    host: str | None
    """Host to probe; ``None`` for ``auto`` (Ray looks the cluster up itself)."""
    port: int | None
    """Port to probe (GCS, or Ray Client's for ``ray://``)."""


def parse_ray_address(text: str) -> RayAddress:
    """``host:port`` (the GCS), ``[v6]:port``, ``ray://host[:port]`` (Ray Client) or ``auto``.

    >>> parse_ray_address("10.0.0.5:6379")
    RayAddress(text='10.0.0.5:6379', host='10.0.0.5', port=6379)
    >>> parse_ray_address("ray://head").port
    10001

    Raises:
        RayUnavailableError: anything else (Ray would refuse it too).
    """
    text = text.strip()
    if text == "auto":
        return RayAddress(text, None, None)
    client = text.startswith("ray://")
    rest = text.removeprefix("ray://")
    usage = "expected host:port (e.g. 10.0.0.5:6379), ray://host:port, auto or local"
    try:
        parts = urlsplit("//" + rest)
        host, port = parts.hostname, parts.port
    except ValueError:
        host, port = None, None
    if not host or "/" in rest or (port is None and not client):
        raise RayUnavailableError(f"RAY_ADDRESS={text}: {usage}")
    return RayAddress(text, host, RAY_CLIENT_PORT if port is None else port)


def check_ray_address(timeout: float = CONNECT_TIMEOUT_S) -> str | None:
    """Fail fast when ``RAY_ADDRESS`` names a cluster that is not there.

    Opens (and closes) one TCP connection to the address: a refused connection, an unknown
    host or no answer within ``timeout`` seconds raises at once, where ``ray.init()`` would
    retry for minutes. Something answering there is not proven to be Ray: for that case
    :func:`ensure_ray` bounds Ray's own connection attempts.

    Returns:
        The address, or ``None`` for a local run (``RAY_ADDRESS`` unset, empty or ``local``).

    Raises:
        RayUnavailableError: a malformed address or nothing reachable there.
    """
    text = os.environ.get("RAY_ADDRESS", "").strip()
    if not text or text == "local":
        return None
    address = parse_ray_address(text)
    if address.host is None:
        return text
    try:
        with socket.create_connection((address.host, address.port), timeout=timeout):
            pass
    except socket.gaierror as e:
        raise RayUnavailableError(
            f"RAY_ADDRESS={text}: unknown host {address.host!r} ({e.strerror}); "
            "unset RAY_ADDRESS for a local run"
        ) from None
    except OSError as e:
        why = "no answer" if isinstance(e, TimeoutError) else (e.strerror or str(e)).lower()
        raise RayUnavailableError(
            f"RAY_ADDRESS={text}: no Ray cluster reachable at {address.host}:{address.port} "
            f"({why}); start it or unset RAY_ADDRESS for a local run"
        ) from None
    return text


def loopback_only() -> None:
    """Make a local Ray started by this process listen on 127.0.0.1 only.

    Measured on Ray 2.60 (Linux): by default the GCS, raylet, workers and driver listen on
    ``::`` (all interfaces) and ``ray.init(_node_ip_address="127.0.0.1")`` does not help
    (Ray turns a loopback address into the machine's). Ray binds every gRPC server to
    loopback when the node's IP is ``127.0.0.1``, which it picks when
    ``ray_constants.ENABLE_RAY_CLUSTER`` is off (``RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER=0``,
    read when Ray is imported). The flag only decides the node's IP of a Ray started from
    this process; the environment variable carries it to child processes.
    """
    import ray._private.ray_constants as ray_constants

    os.environ["RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER"] = "0"
    ray_constants.ENABLE_RAY_CLUSTER = False


HELD_SIGNALS = (signal.SIGINT, signal.SIGTERM)
"""The signals :func:`signals_held` holds back while Ray starts."""


@contextmanager
def signals_held() -> Iterator[None]:
    """Hold Ctrl-C and SIGTERM back until the block ends, then deliver them to the handlers that
    were in place before it.

    ``ray.init`` replaces the SIGTERM handler with its own (``sys.exit``); a Python handler set
    before the block (a study's) is put back, a default one is left as Ray set it. A signal
    that arrived in the block is delivered when it ends, after the handlers are back (one of
    each kind: the kernel keeps no count). Outside the main thread this does nothing (signals
    are handled there).
    """
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    before = {signum: signal.getsignal(signum) for signum in HELD_SIGNALS}
    mask = signal.pthread_sigmask(signal.SIG_BLOCK, HELD_SIGNALS)
    try:
        yield
    finally:
        for signum, handler in before.items():
            if callable(handler) and signal.getsignal(signum) is not handler:
                signal.signal(signum, handler)
        signal.pthread_sigmask(signal.SIG_SETMASK, mask)  # a held signal is handled here


def _unblock_held() -> None:
    signal.pthread_sigmask(signal.SIG_UNBLOCK, [signal.SIGTERM])


def own_session(popen: type[subprocess.Popen]) -> type[subprocess.Popen]:
    """``popen`` whose processes start a session (and process group) of their own, with SIGTERM
    unblocked (they inherit the driver's mask of :func:`signals_held`; Ray blocks SIGINT in
    them on purpose and that stays)."""

    class OwnSession(popen):  # type: ignore[misc, valid-type]
        def __init__(self, *args: Any, **kwargs: Any) -> None:
            inner = kwargs.get("preexec_fn")

            def preexec() -> None:
                if inner is not None:
                    inner()
                _unblock_held()

            kwargs["start_new_session"] = True
            kwargs["preexec_fn"] = preexec
            super().__init__(*args, **kwargs)

    return OwnSession


@contextmanager
def ray_processes_in_own_session() -> Iterator[None]:
    """Ray's processes started in the block (``ray.init`` of a local Ray) get a session of
    their own. Ray starts them with ``ray._private.services.ConsolePopen`` (checked by
    tests/distributed/test_runtime.py against the pinned Ray)."""
    import ray._private.services as services

    popen = services.ConsolePopen
    services.ConsolePopen = own_session(popen)
    try:
        yield
    finally:
        services.ConsolePopen = popen


def start_local_ray(num_cpus: int | None = None, **kwargs) -> None:
    """A private local Ray: loopback only, no token auth, no dashboard, its processes in a
    session of their own; Ctrl-C and SIGTERM while it starts are handled once it has.

    ``kwargs`` go to ``ray.init`` (e.g. ``log_to_driver``, ``object_store_memory``).
    """
    loopback_only()
    # Nothing listens beyond this machine, so no token is needed (Ray >= 2.59 enables token
    # auth by default, which costs ~1 s and writes ~/.ray/auth_token).
    os.environ.setdefault("RAY_AUTH_MODE", "disabled")
    kwargs.setdefault("include_dashboard", False)
    kwargs.setdefault("dashboard_host", "127.0.0.1")
    import ray

    with ray_processes_in_own_session(), signals_held():
        ray.init(address="local", num_cpus=num_cpus, **kwargs)


def stop_ray() -> None:
    """Shut down this process's Ray (its local processes with it), quietly (no-op without
    one)."""
    import logging
    import sys

    if "ray" not in sys.modules:
        return
    import ray

    if not ray.is_initialized():
        return
    logging.getLogger("ray").setLevel(logging.CRITICAL)
    ray.shutdown()


def ensure_ray(num_cpus: int | None = None) -> None:
    """Join the cluster named by ``RAY_ADDRESS``, else start a local Ray (no-op if running).

    ``num_cpus`` only applies to a new local instance; it is never passed when
    connecting to a cluster (Ray refuses it there).

    Raises:
        RayUnavailableError: ``RAY_ADDRESS`` names nothing reachable, or Ray could not
            connect there within about 40 s.
    """
    import ray

    if ray.is_initialized():
        return
    address = check_ray_address()
    if address is None:
        start_local_ray(num_cpus)
        return
    # One round of Ray's connection attempts (~40 s) instead of 20 (~14 minutes) when
    # something that is not a Ray GCS answers at the address.
    os.environ.setdefault("RAY_gcs_server_port_wait_time_s", "1")
    try:
        ray.init()
    except ConnectionError as e:
        first = str(e).strip().splitlines()[0] if str(e).strip() else type(e).__name__
        raise RayUnavailableError(
            f"RAY_ADDRESS={address}: {first} (is a Ray head running there? with token auth, "
            "RAY_AUTH_MODE=token and RAY_AUTH_TOKEN must match the cluster's)"
        ) from e


def cluster_cpus() -> float:
    """Total CPUs of the running Ray cluster."""
    import ray

    return float(ray.cluster_resources().get("CPU", 1.0))


def cpus_per_actor(workers: int) -> float:
    """CPUs to reserve per actor so ``workers`` actors fit the cluster (never above 1).

    Reserving more than the cluster has makes actors wait forever, silently.
    """
    return min(1.0, cluster_cpus() / workers)
