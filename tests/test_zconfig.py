"""armd's Zenoh configurations: shared memory is off, so a router keeps no memory of the
clients on its host that sent it large payloads; a configuration file's endpoints are the ones
used, flags replace them, and with neither a router listens on loopback; listening on the
network with nobody logging in is found, to be warned of."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest
import zenoh

from armd.service.zconfig import (
    DEFAULT_ENDPOINT,
    endpoints,
    exposure_warning,
    is_loopback,
    network_config,
    unauthenticated_endpoints,
)
from tests.conftest import free_port

PLAIN_CLIENT = """
import json, sys, zenoh
conf = zenoh.Config()  # Zenoh's defaults, shared memory on: any client, not only armd's
conf.insert_json5("mode", '"client"')
conf.insert_json5("connect/endpoints", json.dumps([sys.argv[1]]))
conf.insert_json5("scouting/multicast/enabled", "false")
with zenoh.open(conf) as session:
    for _ in range(5):  # 12 KB: over Zenoh's 3 KB threshold for shared memory
        list(session.get("nobody/here", payload=b"x" * 12_000, timeout=2.0))
"""


def _segments() -> set[str]:
    """Zenoh shared-memory segments mapped into this process."""
    return {line.split()[-1] for line in Path("/proc/self/maps").read_text().splitlines() if ".zenoh" in line}


@pytest.mark.parametrize("shm", [True, False], ids=["zenoh-default", "armd"])
def test_a_router_maps_no_client_memory(shm: bool) -> None:
    if not Path("/proc/self/maps").exists():
        pytest.skip("needs /proc (Linux)")
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    conf = network_config(listen=[endpoint])  # the embedded router of `armd serve`
    if shm:  # what Zenoh does by default, to show the test can see it
        conf.insert_json5("transport/shared_memory/enabled", "true")
    before = _segments()
    router = zenoh.open(conf)
    try:
        subprocess.run([sys.executable, "-c", PLAIN_CLIENT, endpoint], check=True, timeout=60)
        new = _segments() - before
    finally:
        router.close()
    assert bool(new) == shm, new


# -- which endpoints: the file's, the flags' where given, else tcp/127.0.0.1:7447 ------------------

DOCS = Path(__file__).resolve().parent.parent / "docs" / "security"


def test_a_file_is_used_as_it_is_and_flags_replace_its_endpoints() -> None:
    tls_router = str(DOCS / "tls-router.json5")
    conf = network_config(config_file=tls_router, mode="router")  # `armd router --config tls-router.json5`
    assert endpoints(conf, "listen") == ["tls/127.0.0.1:7448", "tcp/127.0.0.1:7447"]
    assert json.loads(conf.get_json("transport/link/tls/listen_certificate")) == "certs/router.pem"
    conf = network_config(
        config_file=tls_router, listen=["tcp/127.0.0.1:9001"], connect=["tcp/127.0.0.1:9002"], mode="router"
    )
    assert endpoints(conf, "listen") == ["tcp/127.0.0.1:9001"]
    assert endpoints(conf, "connect") == ["tcp/127.0.0.1:9002"]
    assert json.loads(conf.get_json("transport/link/tls/listen_certificate")) == "certs/router.pem"  # kept
    conf = network_config(config_file=str(DOCS / "tls-client.json5"))  # `armd serve/adapter --config ...`
    assert endpoints(conf, "connect") == ["tls/127.0.0.1:7448"] and endpoints(conf, "listen") == []


@pytest.mark.parametrize(
    "kwargs",
    [{}, {"mode": "router"}, {"connect": ["tcp/127.0.0.1:9002"], "mode": "router"}],
    ids=["serve", "router", "router-connect"],
)
def test_without_a_file_a_router_listens_on_loopback(kwargs: dict[str, Any]) -> None:
    """Never Zenoh's default for a router, tcp/[::]:7447 (every interface)."""
    assert endpoints(network_config(**kwargs), "listen") == [DEFAULT_ENDPOINT]


# -- who is warned: listening beyond loopback with nobody logging in ------------------------------


@pytest.mark.parametrize(
    ("endpoint", "loopback"),
    [
        ("tcp/127.0.0.1:7447", True),
        ("tcp/127.8.9.10:7447", True),
        ("tcp/[::1]:7447", True),
        ("tls/localhost:7448", True),
        ("udp/127.0.0.1:7447#iface=lo", True),
        ("tcp/0.0.0.0:7447", False),
        ("tcp/[::]:7447", False),
        ("tls/192.168.1.20:7448", False),
        ("tcp/lab-server.example:7447", False),
        ("tcp/10.0.0.1:7447?prio=1", False),
        ("unixsock-stream//tmp/armd.sock", None),
    ],
)
def test_is_loopback(endpoint: str, loopback: bool | None) -> None:
    assert is_loopback(endpoint) is loopback


def test_serve_listening_on_every_interface_is_warned_of() -> None:
    warning = exposure_warning(network_config(listen=["tcp/0.0.0.0:7447"]))
    assert warning is not None and "tcp/0.0.0.0:7447" in warning and "docs/security.md" in warning
    assert exposure_warning(network_config(listen=["tcp/127.0.0.1:7447"])) is None
    assert exposure_warning(network_config()) is None
    assert exposure_warning(network_config(connect=["tcp/10.0.0.1:7447"])) is None  # a client listens nowhere


def _conf(json5: str) -> zenoh.Config:
    return zenoh.Config.from_json5(json5)


def test_a_login_or_client_certificates_silence_the_warning() -> None:
    anyone = '{mode: "router", listen: {endpoints: ["tcp/0.0.0.0:7447", "tls/0.0.0.0:7448"]}, %s}'
    assert unauthenticated_endpoints(_conf(anyone % "")) == ["tcp/0.0.0.0:7447", "tls/0.0.0.0:7448"]
    login = 'transport: {auth: {usrpwd: {dictionary_file: "users.txt"}}}'
    assert unauthenticated_endpoints(_conf(anyone % login)) == []
    # a user and password of its own are what this process presents: they check nobody
    presents = 'transport: {auth: {usrpwd: {user: "armd-service", password: "x"}}}'
    assert unauthenticated_endpoints(_conf(anyone % presents)) == ["tcp/0.0.0.0:7447", "tls/0.0.0.0:7448"]
    # TLS alone proves the router to its clients, not the clients to it; mutual TLS does, on TLS links only
    mtls = "transport: {link: {tls: {enable_mtls: true}}}"
    assert unauthenticated_endpoints(_conf(anyone % mtls)) == ["tcp/0.0.0.0:7447"]
    # a router file that names no endpoint gets Zenoh's default, every interface
    assert unauthenticated_endpoints(_conf('{mode: "router"}')) == ["tcp/[::]:7447"]
    # the shipped files: the TLS router listens on loopback only, as shipped; the router with the
    # login may listen on every interface (docs/security.md, docs/deployment.md)
    assert exposure_warning(network_config(config_file=str(DOCS / "tls-router.json5"), mode="router")) is None
    assert (
        exposure_warning(
            network_config(config_file=str(DOCS / "router.json5"), listen=["tcp/0.0.0.0:7447"], mode="router")
        )
        is None
    )
    assert (
        exposure_warning(
            network_config(config_file=str(DOCS / "tls-router.json5"), listen=["tls/0.0.0.0:7448"], mode="router")
        )
        is not None
    )  # TLS, but anyone may open a session
