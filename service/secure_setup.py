"""The secure setup's files: a Zenoh router on which every session logs in, with a default-deny
access-control list that gives each role what it needs and nothing more, and each side's client
configuration (docs/security.md).

Roles, each its own user: the service (``armd-service``), one adapter per arm
(``armd-adapter-<robot>``: its own arm's keys only, so that one arm's adapter cannot speak for
another), an operator and a guest. ``armd secure-setup DIR`` writes the files for the arms it
serves with fresh passwords; ``docs/security/`` holds them for the catalogue with example ones
(``tests/test_secure_setup.py`` checks that they are this module's output).
"""

from __future__ import annotations

import json
import os
import re
import secrets
from collections.abc import Mapping, Sequence
from pathlib import Path

from armd.errors import BadRequest

SERVICE, OPERATOR, GUEST = "armd-service", "operator", "guest"
ADAPTER_KEYS_IN = ("trajectory", "gripper", "estop", "unlock")  # what an adapter hears
ADAPTER_KEYS_OUT = ("state", "events", "sensors/*")  # what it says (its range sensors' readings too)
WATCHED = ("state", "events", "trajectory", "sensors/*", "track")  # what an operator may watch (track: armd record)
READ_ONLY = ("info", "fk", "ik", "plan", "detect")  # a guest's verbs, with `robots`
# What the router lets through, by size (its low-pass filter: larger is dropped at the router,
# before any armd process sees it), each the limit of what reads it:
SIZE_LIMITS = {
    "query": 1_000_000,  # a request: the service's max_payload_bytes (service/protocol.py Limits)
    "control": 4096,  # a gripper or unlock put: adapters/base.py CONTROL_BYTES
    "report": 64 * 1024,  # an adapter's state, event or reading: service/server.py REPORT_BYTES
    "trajectory": 8 * 1024 * 1024,  # adapters/trajectory_message.py MAX_BYTES
}
MAX_MESSAGE = 16 * 1024 * 1024  # [bytes] the most the router puts together of one message (zconfig)
MAX_SESSIONS = 10_000  # sessions the router holds (zconfig)
TLS_ROUTER = '// tls: { listen_certificate: "router.pem", listen_private_key: "router.key" },'
TLS_CLIENT = '// link: { tls: { root_ca_certificate: "ca.pem" } },'


def adapter_user(robot: str) -> str:
    return f"armd-adapter-{robot}"


def users(robots: Sequence[str]) -> list[str]:
    """Every user of the setup, in the order the users file lists them."""
    return [SERVICE, *(adapter_user(r) for r in robots), OPERATOR, GUEST]


def new_passwords(robots: Sequence[str]) -> dict[str, str]:
    """A fresh random password for every user; the guest's is ``guest`` (it is meant to be
    published: read-only access for anyone)."""
    return {u: ("guest" if u == GUEST else secrets.token_urlsafe(18)) for u in users(robots)}


def _rule(rid: str, flow: str, messages: Sequence[str], keys: Sequence[str]) -> str:
    return (
        f'      {{ id: {json.dumps(rid)}, permission: "allow", flows: [{json.dumps(flow)}], '
        f"messages: {json.dumps(list(messages))},\n        key_exprs: {json.dumps(list(keys))} }},"
    )


def _keys(prefix: str, robot: str, names: Sequence[str]) -> list[str]:
    return [f"{prefix}/{robot}/{n}" for n in names]


def _check(robots: Sequence[str], prefix: str) -> None:
    for name in (*robots, *prefix.split("/")):
        if not re.fullmatch(r"[A-Za-z0-9_.-]+", name):
            raise BadRequest(f"{name!r} cannot be part of a key expression in an ACL rule", field="robots")
    if len(set(robots)) != len(robots):
        raise BadRequest("an arm is named twice", field="robots")


def router_config(
    robots: Sequence[str], users_file: str, listen: str = "tcp/127.0.0.1:7447", prefix: str = "armd"
) -> str:
    """The router's JSON5 configuration: login against ``users_file``, listening on ``listen``,
    and the ACL for ``robots`` (each arm's adapter its own user)."""
    _check(robots, prefix)
    p = prefix
    rules: list[str] = [
        "      // -- the service: answers every verb, publishes trajectories, gripper commands and stops,",
        "      //    follows adapters' state, events and tokens",
        _rule("service-answer", "ingress", ["declare_queryable", "reply"], [f"{p}/**"]),
        _rule("service-answer-queries", "egress", ["query"], [f"{p}/**"]),
        _rule("service-publish", "ingress", ["put"], _keys(p, "*", ("trajectory", "gripper", "estop"))),
        _rule(
            "service-publish-see", "egress", ["declare_subscriber"], _keys(p, "*", ("trajectory", "gripper", "estop"))
        ),
        _rule("service-follow", "ingress", ["declare_subscriber"], _keys(p, "*", ADAPTER_KEYS_OUT)),
        _rule("service-follow-get", "egress", ["put"], _keys(p, "*", ADAPTER_KEYS_OUT)),
        _rule("service-tokens", "ingress", ["declare_liveliness_subscriber", "liveliness_query"], [f"{p}/*/adapter/*"]),
        _rule("service-tokens-get", "egress", ["liveliness_token", "reply"], [f"{p}/*/adapter/*"]),
        _rule("service-own-token", "ingress", ["liveliness_token"], [f"{p}/service/*"]),
        "      // (tracking streams: an operator's puts on track, every estop (which ends a stream), and the",
        "      //  stream's events, said on the arm's events: never taken for an adapter's, whose token it",
        "      //  cannot declare)",
        _rule("service-track", "ingress", ["declare_subscriber", "put"], _keys(p, "*", ("track", "estop", "events"))),
        _rule(
            "service-track-get", "egress", ["put", "declare_subscriber"], _keys(p, "*", ("track", "estop", "events"))
        ),
        "      // (replicas: each follows the others' tokens and shares the arms' run-time obstacles)",
        _rule(
            "service-replicas",
            "ingress",
            ["declare_liveliness_subscriber", "liveliness_query", "put", "declare_subscriber"],
            [f"{p}/service/*", *_keys(p, "*", ("obstacles",))],
        ),
        _rule(
            "service-replicas-get",
            "egress",
            ["liveliness_token", "reply", "put", "declare_subscriber"],
            [f"{p}/service/*", *_keys(p, "*", ("obstacles",))],
        ),
    ]
    for r in robots:
        rules += [
            f"      // -- {r}'s adapter: hears {r}'s trajectories, gripper commands, stops and unlocks; says",
            f"      //    {r}'s state, events and sensors; declares {r}'s token. Nothing else: no other arm, no verb.",
            _rule(f"adapter-{r}-listen", "ingress", ["declare_subscriber"], _keys(p, r, ADAPTER_KEYS_IN)),
            _rule(f"adapter-{r}-listen-get", "egress", ["put"], _keys(p, r, ADAPTER_KEYS_IN)),
            _rule(f"adapter-{r}-report", "ingress", ["put"], _keys(p, r, ADAPTER_KEYS_OUT)),
            # (the service follows every arm's state and events with one wildcard subscriber each:
            # an adapter denied the sight of it would conclude that nobody listens, and say nothing)
            _rule(f"adapter-{r}-report-see", "egress", ["declare_subscriber"], _keys(p, "*", ADAPTER_KEYS_OUT)),
            _rule(f"adapter-{r}-token", "ingress", ["liveliness_token"], [f"{p}/{r}/adapter/*"]),
        ]
    rules += [
        "      // -- an operator: asks every verb, puts estop, unlock and track (a tracking stream), watches state,",
        "      //    events, trajectories, sensors",
        _rule("operator-ask", "ingress", ["query"], [f"{p}/**"]),
        _rule("operator-ask-get", "egress", ["reply", "declare_queryable"], [f"{p}/**"]),
        _rule("operator-stop", "ingress", ["put"], _keys(p, "*", ("estop", "unlock", "track"))),
        _rule("operator-stop-see", "egress", ["declare_subscriber"], _keys(p, "*", ("estop", "unlock", "track"))),
        _rule("operator-watch", "ingress", ["declare_subscriber"], _keys(p, "*", WATCHED)),
        _rule("operator-watch-get", "egress", ["put"], _keys(p, "*", WATCHED)),
        '      // -- a guest: the read-only verbs (a "guest" user whose password is published)',
        _rule("guest-ask", "ingress", ["query"], [f"{p}/robots", *_keys(p, "*", READ_ONLY)]),
        _rule("guest-ask-get", "egress", ["reply"], [f"{p}/robots", *_keys(p, "*", READ_ONLY)]),
        "      // (a client that keeps a querier, as ArmClient does, asks the router which queryables",
        "      // match; denied their declarations, it concludes none does and sends nothing)",
        _rule("see-the-service", "egress", ["declare_queryable"], [f"{p}/**"]),
    ]
    subjects = [
        ("service", SERVICE),
        *((f"adapter-{r}", adapter_user(r)) for r in robots),
        ("operator", OPERATOR),
        ("guest", GUEST),
    ]
    service_rules = [
        "service-answer",
        "service-answer-queries",
        "service-publish",
        "service-publish-see",
        "service-follow",
        "service-follow-get",
        "service-tokens",
        "service-tokens-get",
        "service-own-token",
        "service-track",
        "service-track-get",
        "service-replicas",
        "service-replicas-get",
    ]
    operator_rules = [
        "operator-ask",
        "operator-ask-get",
        "operator-stop",
        "operator-stop-see",
        "operator-watch",
        "operator-watch-get",
    ]
    policies = [
        ("service", "service", service_rules),
        *(
            (
                f"adapter-{r}",
                f"adapter-{r}",
                [f"adapter-{r}-{s}" for s in ("listen", "listen-get", "report", "report-see", "token")],
            )
            for r in robots
        ),
        ("operator", "operator", operator_rules),
        ("guest", "guest", ["guest-ask", "guest-ask-get", "see-the-service"]),
    ]
    filters = [
        ("requests", ["query"], [f"{p}/**"], SIZE_LIMITS["query"]),
        # (not estop: any put on it stops the arm, whatever it holds; only the 16 MiB above bounds it)
        ("commands", ["put"], _keys(p, "*", ("gripper", "unlock", "track")), SIZE_LIMITS["control"]),
        ("reports", ["put"], _keys(p, "*", ADAPTER_KEYS_OUT), SIZE_LIMITS["report"]),
        ("trajectories", ["put"], _keys(p, "*", ("trajectory",)), SIZE_LIMITS["trajectory"]),
    ]
    lines = [
        "// armd: a Zenoh router that authenticates every session and lets only trusted users move arms.",
        "// Written by `armd secure-setup` (armd.service.secure_setup); docs/security.md explains it.",
        "// Run it with: armd router --config router.json5",
        "{",
        '  mode: "router",',
        f"  listen: {{ endpoints: [{json.dumps(listen)}] }},",
        "  scouting: { multicast: { enabled: false }, gossip: { enabled: false } },",
        "  transport: {",
        "    // Shared memory off, as armd's own configurations have it: a router otherwise keeps a 16 MB",
        "    // segment for every client on its host that ever sent a payload over 3 KB (docs/reliability.md).",
        "    shared_memory: { enabled: false },",
        "    // Room for an operator's session beside anyone's 1,000 (Zenoh's default is 1,000 in all).",
        f"    unicast: {{ max_sessions: {MAX_SESSIONS} }},",
        "    // Every session must log in (Zenoh's user/password is all or nothing for a router).",
        f"    auth: {{ usrpwd: {{ dictionary_file: {json.dumps(users_file)} }} }},",
        "    link: {",
        "      // No message larger than this is put together from its fragments (Zenoh's default: 1 GiB,",
        "      // in memory before anything can look at its size).",
        f"      rx: {{ max_message_size: {MAX_MESSAGE} }},",
        '      // TLS, where wanted: add "tls/0.0.0.0:7448" to listen.endpoints and uncomment:',
        f"      {TLS_ROUTER}",
        "    },",
        "  },",
        "  // Sizes: what each key's reader takes at most; anything larger is dropped here, unread by any",
        "  // armd process (a guest's 100 MB request included).",
        "  low_pass_filter: [",
        *(
            f'    {{ id: {json.dumps(fid)}, flows: ["ingress"], messages: {json.dumps(msgs)},\n'
            f"      key_exprs: {json.dumps(keys)}, size_limit: {limit} }},"
            for fid, msgs, keys, limit in filters
        ),
        "  ],",
        "  access_control: {",
        "    enabled: true,",
        "    // Deny by default and allow each role what it needs, nothing more: a deny-list would let",
        '    // wildcard queries such as "armd/**" through, since a rule only matches key expressions it',
        '    // contains. Flows: "ingress" is what a session sends the router, "egress" what the router',
        "    // sends it. A session that publishes or asks must also be let to see who listens or answers",
        "    // (egress declare_subscriber / declare_queryable): a Zenoh client sends nothing on a key",
        "    // for which it believes there is none.",
        '    default_permission: "deny",',
        "    rules: [",
        *rules,
        "    ],",
        "    subjects: [",
        *(f"      {{ id: {json.dumps(sid)}, usernames: [{json.dumps(user)}] }}," for sid, user in subjects),
        "    ],",
        "    policies: [",
        *(
            f"      {{ id: {json.dumps(pid)}, subjects: [{json.dumps(sub)}],\n        rules: {json.dumps(rs)} }},"
            for pid, sub, rs in policies
        ),
        "    ],",
        "  },",
        "}",
    ]
    return "\n".join(lines) + "\n"


def client_config(who: str, user: str, password: str, connect: str = "tcp/127.0.0.1:7447") -> str:
    """One side's JSON5 configuration: a client of the router, logging in as ``user``."""
    return (
        "\n".join(
            [
                f"// armd: the {who}'s side of router.json5 (armd ... --config {client_file(who)})",
                "{",
                '  mode: "client",',
                f"  connect: {{ endpoints: [{json.dumps(connect)}] }},",
                "  scouting: { multicast: { enabled: false }, gossip: { enabled: false } },",
                "  transport: {",
                f"    auth: {{ usrpwd: {{ user: {json.dumps(user)}, password: {json.dumps(password)} }} }},",
                '    // TLS: connect to "tls/HOST:7448" instead and uncomment:',
                f"    {TLS_CLIENT}",
                "  },",
                "}",
            ]
        )
        + "\n"
    )


def client_file(who: str) -> str:
    return f"{who}.json5"


def files(
    robots: Sequence[str],
    passwords: Mapping[str, str],
    users_file: str,
    endpoint: str = "tcp/127.0.0.1:7447",
    prefix: str = "armd",
) -> dict[str, str]:
    """Every file of the setup, by name: ``router.json5``, ``users.txt`` (``user:password``
    lines), and a client configuration per side: ``service.json5``, ``adapter-<robot>.json5``
    for each arm, ``operator.json5``, ``guest.json5``. The router listens on ``endpoint``; the
    clients connect there."""
    missing = [u for u in users(robots) if not passwords.get(u)]
    if missing:
        raise BadRequest(f"no password for {', '.join(missing)}", field="passwords")
    if any(c in pw for pw in passwords.values() for c in ":\n\r") or any(not pw.strip() for pw in passwords.values()):
        raise BadRequest("a password may not hold a colon or a line break, or be blank", field="passwords")
    sides = {
        "service": SERVICE,
        **{f"adapter-{r}": adapter_user(r) for r in robots},
        "operator": OPERATOR,
        "guest": GUEST,
    }
    out = {
        "router.json5": router_config(robots, users_file, endpoint, prefix),
        "users.txt": "".join(f"{u}:{passwords[u]}\n" for u in users(robots)),
    }
    for who, user in sides.items():
        out[client_file(who)] = client_config(who, user, passwords[user], endpoint)
    return out


def write(directory: Path, contents: Mapping[str, str]) -> list[Path]:
    """Write the files into ``directory`` (made if missing); ``users.txt`` and the clients'
    files, which hold passwords, readable by their owner only. Refuses to overwrite."""
    directory.mkdir(parents=True, exist_ok=True)
    clash = [n for n in contents if (directory / n).exists() or (directory / n).is_symlink()]
    if clash:
        raise BadRequest(f"{directory} already holds {', '.join(sorted(clash))}: choose an empty folder", field="dir")
    written = []
    for name, text in contents.items():
        path = directory / name
        # created here, never through a link planted in its place, and private from the start
        fd = os.open(
            path, os.O_WRONLY | os.O_CREAT | os.O_EXCL | os.O_NOFOLLOW, 0o644 if name == "router.json5" else 0o600
        )
        with os.fdopen(fd, "w") as fh:
            fh.write(text)
        written.append(path)
    return written
