"""armd's Zenoh configurations: shared memory is off, so a router keeps no memory of the
clients on its host that sent it large payloads; a configuration file's endpoints are the ones
used, flags replace them, and with neither a router listens on loopback."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest
import zenoh

from service.zconfig import DEFAULT_ENDPOINT, endpoints, network_config
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
    conf = network_config(config_file=tls_router, listen=["tcp/127.0.0.1:9001"], connect=["tcp/127.0.0.1:9002"],
                          mode="router")
    assert endpoints(conf, "listen") == ["tcp/127.0.0.1:9001"]
    assert endpoints(conf, "connect") == ["tcp/127.0.0.1:9002"]
    assert json.loads(conf.get_json("transport/link/tls/listen_certificate")) == "certs/router.pem"  # kept
    conf = network_config(config_file=str(DOCS / "tls-client.json5"))  # `armd serve/adapter --config ...`
    assert endpoints(conf, "connect") == ["tls/127.0.0.1:7448"] and endpoints(conf, "listen") == []


@pytest.mark.parametrize("kwargs", [{}, {"mode": "router"}, {"connect": ["tcp/127.0.0.1:9002"], "mode": "router"}],
                         ids=["serve", "router", "router-connect"])
def test_without_a_file_a_router_listens_on_loopback(kwargs: dict[str, Any]) -> None:
    """Never Zenoh's default for a router, tcp/[::]:7447 (every interface)."""
    assert endpoints(network_config(**kwargs), "listen") == [DEFAULT_ENDPOINT]
