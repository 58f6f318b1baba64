"""Zenoh configurations: the embedded router, a member of an existing network, a client.

Multicast scouting is always off (armd never announces itself on a LAN by surprise;
endpoints are explicit), and so is gossip. So is shared memory (see :func:`_quiet`).
"""

from __future__ import annotations

import ipaddress
import json
import socket
from pathlib import Path

import zenoh

from armd.errors import BadRequest

DEFAULT_ENDPOINT = "tcp/127.0.0.1:7447"


def free_port() -> int:
    """A TCP port on 127.0.0.1 that nothing listens on now (the OS's pick), for a router of
    one's own: the demo, the benchmarks and the tests."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def free_endpoint() -> str:
    """``tcp/127.0.0.1:<a free port>`` (:func:`free_port`)."""
    return f"tcp/127.0.0.1:{free_port()}"


# [bytes] The largest message a session puts together from its fragments (Zenoh's default: 1 GiB,
# held in memory before anyone may look at its size): larger ones are dropped as they arrive.
# armd's largest is a trajectory (at most 8 MiB: adapters/trajectory_message.py) or its reply.
MAX_MESSAGE_BYTES = 16 * 1024 * 1024
# Sessions a router of armd's holds (Zenoh's default: 1,000, which 999 sessions of anyone's filled:
# an operator's `armd stop` could not connect). Each is a socket: `armd serve` and `armd router`
# raise their open-file limit to match (cli/common.py).
MAX_SESSIONS = 10_000


def _quiet(conf: zenoh.Config) -> zenoh.Config:
    conf.insert_json5("transport/link/rx/max_message_size", str(MAX_MESSAGE_BYTES))
    conf.insert_json5("transport/unicast/max_sessions", str(MAX_SESSIONS))
    conf.insert_json5("scouting/multicast/enabled", "false")
    conf.insert_json5("scouting/gossip/enabled", "false")
    # Shared memory off: with it, every client session on this host that sends a payload over
    # 3 KB (an IK batch) makes a 16 MB segment that a router maps and keeps until it exits
    # (measured: ~20 MB of the router's memory per such session, for ever). armd's payloads
    # are small JSON; TCP on loopback carries them.
    conf.insert_json5("transport/shared_memory/enabled", "false")
    return conf


def _reconnect_fast(conf: zenoh.Config) -> zenoh.Config:
    """After a router restart, reconnect within ~0.5 s (the default backs off to 4 s)."""
    conf.insert_json5("connect/retry", '{"period_init_ms": 100, "period_max_ms": 500, "period_increase_factor": 2}')
    return conf


def network_config(
    *,
    listen: list[str] | None = None,
    connect: list[str] | None = None,
    config_file: str | None = None,
    mode: str | None = None,
) -> zenoh.Config:
    """The configuration of a long-running armd process (service, adapter, router).

    - ``config_file``: a Zenoh JSON5 configuration, used as it is: its endpoints, TLS,
      credentials, access control and the rest. ``listen``/``connect``/``mode``, where given,
      replace the file's values for those keys; where not given, the file's stand.
    - ``connect`` given: join an existing network as a client of the router(s) there (or
      ``mode``): a router routes everything between its clients, liveliness included. A
      ``mode="router"`` listens on ``listen`` (default tcp/127.0.0.1:7447) as well.
    - otherwise: an embedded router listening on ``listen`` (default tcp/127.0.0.1:7447).

    Never Zenoh's own default listen endpoint for a router (``tcp/[::]:7447``: every interface)
    unless a file asks for it.
    """
    if config_file:
        if not Path(config_file).is_file():
            raise BadRequest(f"Zenoh config file {config_file} not found", field="config")
        try:
            conf = zenoh.Config.from_file(config_file)
        except Exception as e:  # zenoh raises its own ZError
            raise BadRequest(f"Zenoh cannot read {config_file}: {e}", field="config") from None
        if listen:
            conf.insert_json5("listen/endpoints", json.dumps(listen))
        if connect:
            conf.insert_json5("connect/endpoints", json.dumps(connect))
        if mode:
            conf.insert_json5("mode", json.dumps(mode))
        return conf
    conf = zenoh.Config()
    if connect:
        conf.insert_json5("mode", json.dumps(mode or "client"))
        conf.insert_json5("connect/endpoints", json.dumps(connect))
        _reconnect_fast(conf)
        if listen or mode == "router":
            conf.insert_json5("listen/endpoints", json.dumps(listen or [DEFAULT_ENDPOINT]))
    else:
        conf.insert_json5("mode", json.dumps(mode or "router"))
        conf.insert_json5("listen/endpoints", json.dumps(listen or [DEFAULT_ENDPOINT]))
        conf.insert_json5("connect/endpoints", "[]")
    return _quiet(conf)


def client_config(connect: list[str] | None = None, config_file: str | None = None) -> zenoh.Config:
    """A client of the network: connects to ``connect`` (default the embedded router's endpoint)."""
    if config_file:
        return network_config(config_file=config_file, connect=connect)
    conf = zenoh.Config()
    conf.insert_json5("mode", '"client"')
    conf.insert_json5("connect/endpoints", json.dumps(connect or [DEFAULT_ENDPOINT]))
    return _quiet(_reconnect_fast(conf))


# -- what a configuration listens on, and who may open a session there -------------------------

_IP_LINKS = ("tcp", "udp", "tls", "quic", "ws")  # the protocols whose endpoints are host:port
_TLS_LINKS = ("tls", "quic")  # the ones that can ask a client for its certificate (mutual TLS)


def _mode(conf: zenoh.Config) -> str:
    return str(json.loads(conf.get_json("mode")) or "peer")  # Zenoh's default mode is peer


def endpoints(conf: zenoh.Config, which: str) -> list[str]:
    """The ``"listen"`` or ``"connect"`` endpoints a session opened with ``conf`` uses: the
    configured list, or Zenoh's default for the configuration's mode (Zenoh also accepts one
    list per mode, ``{router: [...], peer: [...]}``)."""
    value = json.loads(conf.get_json(f"{which}/endpoints"))
    if isinstance(value, dict):
        value = value.get(_mode(conf), [])
    return [str(e) for e in value or []]


def is_loopback(endpoint: str) -> bool | None:
    """Whether ``endpoint`` (``proto/host:port[?metadata][#config]``) is reachable from this
    machine only: an address in 127.0.0.0/8, ``::1`` or ``localhost``. None for links that have
    no host (a Unix socket, a serial line)."""
    proto, _, address = endpoint.partition("/")
    if proto not in _IP_LINKS:
        return None
    host = address.split("?", 1)[0].split("#", 1)[0].rpartition(":")[0].strip("[]")
    if host.lower() == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:  # a host name: it may resolve to anything
        return False


def unauthenticated_endpoints(conf: zenoh.Config) -> list[str]:
    """The listen endpoints of ``conf`` that other machines can reach and where Zenoh opens a
    session for anyone: not loopback, and neither user/password checked
    (``transport.auth.usrpwd.dictionary_file``: a ``user``/``password`` alone are the
    credentials this process presents, they check nobody) nor, on a TLS or QUIC endpoint,
    client certificates (``transport.link.tls.enable_mtls``). See docs/security.md."""
    if json.loads(conf.get_json("transport/auth/usrpwd/dictionary_file")):
        return []
    mtls = json.loads(conf.get_json("transport/link/tls/enable_mtls")) is True
    return [
        e
        for e in endpoints(conf, "listen")
        if is_loopback(e) is False and not (mtls and e.partition("/")[0] in _TLS_LINKS)
    ]


def exposure_warning(conf: zenoh.Config) -> str | None:
    """One line to warn with where :func:`unauthenticated_endpoints` finds any, else None."""
    open_ = unauthenticated_endpoints(conf)
    if not open_:
        return None
    return (
        f"listening on {', '.join(open_)} with no authentication: anyone on that network can query the "
        "service, publish trajectories and move the arms; see docs/security.md (user/password, TLS, "
        "access control) or listen on 127.0.0.1"
    )
