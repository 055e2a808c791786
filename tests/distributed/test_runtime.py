"""Starting or joining Ray: RAY_ADDRESS checked in seconds, a local Ray on loopback only."""

from __future__ import annotations

import ipaddress
import os
import socket
import time

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
