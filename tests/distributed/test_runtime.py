"""Starting or joining Ray: RAY_ADDRESS checked in seconds, a local Ray on loopback only."""

from __future__ import annotations

import ipaddress
import os
import socket
import time
from pathlib import Path

import psutil
import pytest

from safe_bc.distributed.runtime import (
    RayUnavailableError,
    check_ray_address,
    parse_ray_address,
)


def refused_address() -> tuple[socket.socket, str]:
    """A loopback port that refuses connections (bound, never listening) while the socket
    is open."""
    sock = socket.socket()
    sock.bind(("127.0.0.1", 0))
    return sock, f"127.0.0.1:{sock.getsockname()[1]}"


@pytest.mark.parametrize(
    ("text", "host", "port"),
    [
        ("10.0.0.5:6379", "10.0.0.5", 6379),
        (" head.example:6380 ", "head.example", 6380),
        ("[::1]:6379", "::1", 6379),
        ("ray://head:10002", "head", 10002),
        ("ray://head", "head", 10001),
        ("auto", None, None),
    ],
)
def test_parse_ray_address(text: str, host: str | None, port: int | None) -> None:
    address = parse_ray_address(text)
    assert (address.host, address.port) == (host, port)


@pytest.mark.parametrize("text", ["head", "head:port", "http://head:8265", "ray://", ":6379"])
def test_malformed_ray_address_is_one_line(text: str) -> None:
    with pytest.raises(RayUnavailableError, match="expected host:port") as info:
        parse_ray_address(text)
    assert "\n" not in str(info.value) and text.strip() in str(info.value)


def test_check_ray_address(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.delenv("RAY_ADDRESS", raising=False)
    assert check_ray_address() is None
    for local in ("", "local"):
        monkeypatch.setenv("RAY_ADDRESS", local)
        assert check_ray_address() is None

    sock, address = refused_address()
    with sock:
        monkeypatch.setenv("RAY_ADDRESS", address)
        start = time.perf_counter()
        with pytest.raises(RayUnavailableError) as info:
            check_ray_address()
    assert time.perf_counter() - start < 5
    message = str(info.value)
    assert f"RAY_ADDRESS={address}" in message and "refused" in message and "\n" not in message

    monkeypatch.setenv("RAY_ADDRESS", "no-such-host.invalid:6379")
    with pytest.raises(RayUnavailableError, match=r"unknown host 'no-such-host\.invalid'"):
        check_ray_address()

    with socket.create_server(("127.0.0.1", 0)) as server:  # something answers
        address = f"127.0.0.1:{server.getsockname()[1]}"
        monkeypatch.setenv("RAY_ADDRESS", address)
        assert check_ray_address() == address


def _is_loopback(ip: str) -> bool:
    addr = ipaddress.ip_address(ip.split("%")[0])
    if isinstance(addr, ipaddress.IPv6Address) and addr.ipv4_mapped is not None:
        addr = addr.ipv4_mapped
    return addr.is_loopback


def test_local_ray_listens_on_loopback_only(ray_session) -> None:
    ray = ray_session

    @ray.remote(num_cpus=0)
    def pid() -> int:
        return os.getpid()

    worker = ray.get(pid.remote())  # a worker process exists
    me = psutil.Process()
    bound: dict[str, list[tuple[str, int]]] = {}  # process -> sockets that accept connections
    for proc in [me, *me.children(recursive=True)]:
        try:
            conns = proc.net_connections(kind="inet")
            name = f"{proc.name()} ({proc.pid})"
        except psutil.NoSuchProcess:
            continue
        for c in conns:
            if c.status == psutil.CONN_LISTEN or (c.type == socket.SOCK_DGRAM and not c.raddr):
                bound.setdefault(name, []).append((c.laddr.ip, c.laddr.port))
    exposed = {p: s for p, s in bound.items() if not all(_is_loopback(ip) for ip, _ in s)}
    assert not exposed, f"Ray processes listening beyond loopback: {exposed}"
    # the check saw Ray's servers: GCS, raylet, the worker and the driver itself
    names = " ".join(bound)
    assert "gcs_server" in names and "raylet" in names, bound
    assert f"({worker})" in names and f"({me.pid})" in names, bound
    assert ray.util.get_node_ip_address() == "127.0.0.1"


def _is_ray(p: psutil.Process) -> bool:
    cmd = " ".join(p.cmdline())
    return p.name() in ("gcs_server", "raylet") or "/ray/" in cmd or cmd.startswith("ray::")


def test_ray_processes_run_in_a_session_of_their_own(ray_session) -> None:
    ray = ray_session

    @ray.remote(num_cpus=0)
    def pid() -> int:
        return os.getpid()

    worker = ray.get(pid.remote())
    me = psutil.Process()
    ours = os.getsid(0)
    # Ray's processes only (its binaries, its Python modules, its workers): this process may
    # hold children of its own, such as torch's compile workers, in this session
    ray_procs = {p.pid: p.name() for p in me.children(recursive=True) if _is_ray(p)}
    started = [n for n in ray_procs.values() if n in ("gcs_server", "raylet")]
    assert sorted(started) == ["gcs_server", "raylet"], ray_procs
    # a signal to the driver's process group (timeout, docker stop) reaches none of them
    assert all(os.getsid(p) != ours for p in ray_procs), ray_procs
    assert os.getsid(worker) != ours and os.getpgid(worker) != os.getpgrp()


def _blocked(pid: int) -> int:
    """The signal mask of process ``pid`` (``SigBlk`` in /proc)."""
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("SigBlk:"):
            return int(line.split()[1], 16)
    raise AssertionError("no SigBlk line")


def test_own_session_popen_starts_a_session_with_sigterm_unblocked() -> None:
    import signal
    import subprocess

    from safe_bc.distributed.runtime import own_session, signals_held

    calls = []
    popen = own_session(subprocess.Popen)
    with signals_held():  # as during ray.init: the driver holds SIGINT and SIGTERM back
        assert _blocked(os.getpid()) & (1 << (signal.SIGTERM - 1))
        child = popen(["sleep", "30"], preexec_fn=lambda: calls.append(1))
    try:
        assert os.getsid(child.pid) == child.pid != os.getsid(0)
        mask = _blocked(child.pid)
        assert not mask & (1 << (signal.SIGTERM - 1))
        assert mask & (1 << (signal.SIGINT - 1))  # still held: Ray blocks it in its processes
        child.terminate()
        assert child.wait(timeout=10) == -signal.SIGTERM
    finally:
        child.kill()
        child.wait()
    assert not _blocked(os.getpid()) & (1 << (signal.SIGTERM - 1))


def test_signals_held_deliver_after_the_block_to_the_handlers_set_before_it() -> None:
    import signal

    from safe_bc.distributed.runtime import signals_held

    got: list[tuple[str, int]] = []
    before = {s: signal.getsignal(s) for s in (signal.SIGINT, signal.SIGTERM)}
    try:
        signal.signal(signal.SIGINT, lambda s, f: got.append(("ours", s)))
        signal.signal(signal.SIGTERM, lambda s, f: got.append(("ours", s)))
        with signals_held():
            signal.signal(signal.SIGTERM, lambda s, f: got.append(("ray's", s)))  # as ray.init
            signal.raise_signal(signal.SIGTERM)
            signal.raise_signal(signal.SIGINT)
            assert got == []  # held
        assert sorted(got) == [("ours", signal.SIGINT), ("ours", signal.SIGTERM)]
        # a default SIGTERM handler before the block stays as the block left it (Ray's)
        signal.signal(signal.SIGTERM, signal.SIG_DFL)
        with signals_held():
            signal.signal(signal.SIGTERM, lambda s, f: got.append(("ray's", s)))
        signal.raise_signal(signal.SIGTERM)
        assert got[-1] == ("ray's", signal.SIGTERM)
    finally:
        for s, h in before.items():
            signal.signal(s, h)
