"""armd's Zenoh configurations: shared memory is off, so a router keeps no memory of the
clients on its host that sent it large payloads."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest
import zenoh

from service.zconfig import network_config
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
