"""`armd router --config` and `armd serve --config` run as a user runs them (separate processes):
the file's endpoints are the ones opened (the TLS router of docs/security opens its TLS port),
``--listen`` replaces them, and listening on the network with nobody logging in is warned of."""

from __future__ import annotations

import signal
import subprocess
import sys
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import pytest
import zenoh

from armd.clients import ArmClient
from armd.service.zconfig import client_config, free_port, network_config
from tests.conftest import wait_for

pytestmark = pytest.mark.slow  # (seconds: processes, routers, emulated boards; `pytest -m "not slow"` skips it)

ROOT = Path(__file__).resolve().parent.parent
DOCS = ROOT / "docs" / "security"


@contextmanager
def running(*args: str, ready: str) -> Iterator[tuple[subprocess.Popen[str], str]]:
    """``armd ARGS`` in a process of its own, once it printed a line containing ``ready``: the
    process and that line. Stopped with SIGTERM at the end, as a service manager stops it."""
    proc = subprocess.Popen(
        [sys.executable, "-m", "armd.cli", *args], cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
    )
    assert proc.stdout is not None and proc.stderr is not None
    try:
        line = proc.stdout.readline()  # the first line says where it listens, or the process ended
        assert ready in line, (line, proc.stderr.read() if proc.poll() is not None else "")
        yield proc, line
    finally:
        proc.send_signal(signal.SIGTERM)
        try:
            proc.wait(timeout=20)
        finally:
            proc.kill()
    assert proc.returncode == 0, proc.stderr.read()


def _tls_copy(name: str, tmp: Path, certs: Path, tls_port: int, tcp_port: int) -> Path:
    """docs/security/NAME on free ports, its certificate paths pointing at ``certs``."""
    text = (DOCS / name).read_text()
    for old, new in {
        "tls/127.0.0.1:7448": f"tls/127.0.0.1:{tls_port}",
        "tcp/127.0.0.1:7447": f"tcp/127.0.0.1:{tcp_port}",
        '"certs/': f'"{certs}/',
    }.items():
        text = text.replace(old, new)
    assert f"tls/127.0.0.1:{tls_port}" in text and f'"{certs}/' in text, f"{name} changed: mend this test"
    out = tmp / name
    out.write_text(text)
    return out


def test_the_tls_router_listens_where_its_file_says(tmp_path: Path, certs: Path) -> None:
    """`armd router --config tls-router.json5`: a client with tls-client.json5 queries through its
    TLS port a queryable that sits on its loopback TCP port; plain TCP to the TLS port gets no session."""
    tls_port, tcp_port = free_port(), free_port()
    router_file = _tls_copy("tls-router.json5", tmp_path, certs, tls_port, tcp_port)
    client_file = _tls_copy("tls-client.json5", tmp_path, certs, tls_port, tcp_port)
    with running("router", "--config", str(router_file), ready="zenoh router") as (_, line):
        assert f"tls/127.0.0.1:{tls_port}" in line and f"tcp/127.0.0.1:{tcp_port}" in line, line
        local = zenoh.open(network_config(connect=[f"tcp/127.0.0.1:{tcp_port}"]))
        answers = local.declare_queryable(
            "armd-test/echo",
            lambda q: q.reply(q.key_expr, b"echo: " + (q.payload.to_bytes() if q.payload is not None else b"")),
        )
        remote = zenoh.open(network_config(config_file=str(client_file)))
        try:
            got: list[bytes] = []

            def asked() -> bool:  # until the router has told the TLS client about the queryable
                got.extend(
                    r.ok.payload.to_bytes()
                    for r in remote.get("armd-test/echo", payload=b"hello", timeout=1.0)
                    if r.ok is not None
                )
                return bool(got)

            wait_for(asked, what="a reply over TLS")
            assert got[0] == b"echo: hello"
            # and a put from the TLS side reaches a subscriber on the loopback side
            heard: list[bytes] = []
            sub = local.declare_subscriber("armd-test/said", lambda s: heard.append(s.payload.to_bytes()))

            def said() -> bool:  # until the router has told the TLS client about the subscriber
                remote.put("armd-test/said", b"over tls")
                time.sleep(0.05)
                return bool(heard)

            wait_for(said, what="a put over TLS")
            assert heard[0] == b"over tls"
            sub.undeclare()
            with pytest.raises(zenoh.ZError):  # plain TCP to the TLS port: no Zenoh session opens
                zenoh.open(client_config([f"tcp/127.0.0.1:{tls_port}"])).close()
        finally:
            answers.undeclare()
            remote.close()
            local.close()


def test_a_routers_file_connects_where_it_says(tmp_path: Path) -> None:
    """`armd router --config FILE` whose file connects to another router (two machines' routers,
    docs/deployment.md): it joins it, and a query from one side is answered on the other; the
    line it prints at start says so."""
    a, b = free_port(), free_port()
    first = zenoh.open(network_config(listen=[f"tcp/127.0.0.1:{a}"], mode="router"))
    conf = tmp_path / "second.json5"
    conf.write_text(
        f'{{ mode: "router", listen: {{ endpoints: ["tcp/127.0.0.1:{b}"] }}, '
        f'connect: {{ endpoints: ["tcp/127.0.0.1:{a}"] }}, scouting: {{ multicast: {{ enabled: false }} }} }}'
    )
    answers = first.declare_queryable("armd-test/where", lambda q: q.reply(q.key_expr, b"on the first router"))
    try:
        with running("router", "--config", str(conf), ready="zenoh router") as (_, line):
            assert f"listening on tcp/127.0.0.1:{b}, connected to tcp/127.0.0.1:{a}" in line, line
            far = zenoh.open(client_config([f"tcp/127.0.0.1:{b}"]))
            try:
                got: list[bytes] = []

                def asked() -> bool:
                    got.extend(
                        r.ok.payload.to_bytes() for r in far.get("armd-test/where", timeout=1.0) if r.ok is not None
                    )
                    return bool(got)

                wait_for(asked, what="a reply through both routers")
                assert got[0] == b"on the first router"
            finally:
                far.close()
    finally:
        answers.undeclare()
        first.close()


def test_listen_replaces_the_files_endpoints(tmp_path: Path, certs: Path) -> None:
    """`armd router --config FILE --listen E`: E alone is opened; the file's ports stay closed."""
    tls_port, tcp_port, port = free_port(), free_port(), free_port()
    router_file = _tls_copy("tls-router.json5", tmp_path, certs, tls_port, tcp_port)
    with running("router", "--config", str(router_file), "--listen", f"tcp/127.0.0.1:{port}", ready="zenoh router") as (
        _,
        line,
    ):
        assert line.rstrip().endswith(f"listening on tcp/127.0.0.1:{port}"), line
        zenoh.open(client_config([f"tcp/127.0.0.1:{port}"])).close()
        with pytest.raises(zenoh.ZError):
            zenoh.open(client_config([f"tcp/127.0.0.1:{tcp_port}"])).close()


def test_serve_listens_where_its_file_says_and_does_not_warn_on_loopback(tmp_path: Path) -> None:
    port = free_port()
    conf = tmp_path / "serve.json5"
    conf.write_text(
        f'{{ mode: "router", listen: {{ endpoints: ["tcp/127.0.0.1:{port}"] }},'
        " scouting: { multicast: { enabled: false } } }"
    )
    with running("serve", "--config", str(conf), ready="armd serving") as (proc, line):
        assert f"on tcp/127.0.0.1:{port}" in line, line
        with ArmClient(f"tcp/127.0.0.1:{port}", timeout=10.0) as c:
            assert "gupta3" in [r["name"] for r in c.robots()]
    assert "warning" not in proc.stderr.read()


@pytest.mark.parametrize("command", ["serve", "router"])
def test_listening_on_the_network_without_a_login_is_warned_of(command: str) -> None:
    """One warning line naming docs/security.md before the session opens. The address is
    TEST-NET-1 (192.0.2.1, on no machine), so nothing opens to the network: the process then
    says in one line that Zenoh cannot listen there, and exits 1."""
    endpoint = f"tcp/192.0.2.1:{free_port()}"
    out = subprocess.run(
        [sys.executable, "-m", "armd.cli", command, "--listen", endpoint],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=60,
    )
    warnings = [line for line in out.stderr.splitlines() if line.startswith("armd: warning:")]
    assert len(warnings) == 1, out.stderr
    assert endpoint in warnings[0] and "docs/security.md" in warnings[0]
    assert out.returncode == 1 and "armd: error: Zenoh cannot open the session" in out.stderr
    assert "Traceback" not in out.stderr


def test_the_loopback_router_is_not_warned_of() -> None:
    port = free_port()
    with running("router", "--listen", f"tcp/127.0.0.1:{port}", ready="zenoh router") as (proc, line):
        assert line.rstrip().endswith(f"listening on tcp/127.0.0.1:{port}"), line
    assert "warning" not in proc.stderr.read()
