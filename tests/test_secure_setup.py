"""armd.service.secure_setup and ``armd secure-setup``: the files docs/security holds are its
output for the catalogue (so the documented setup is the one the code writes), a setup for
arms of one's own opens a working router, and bad names and passwords are refused.

To write docs/security anew after changing the module: ``python -m tests.test_secure_setup``."""

from __future__ import annotations

import stat
import subprocess
import sys
from pathlib import Path

import pytest
import zenoh

from armd import robots
from armd.errors import BadRequest
from armd.service import secure_setup
from armd.service.zconfig import network_config

ROOT = Path(__file__).resolve().parent.parent
DOCS = ROOT / "docs" / "security"
CLIENTS = ("service", "operator", "guest")


def example_passwords(names: list[str]) -> dict[str, str]:
    """The example passwords of docs/security (to be changed: docs/security.md)."""
    pw = {u: f"change-me-{u.removeprefix('armd-')}" for u in secure_setup.users(names)}
    pw[secure_setup.GUEST] = "guest"
    return pw


def documented() -> dict[str, str]:
    names = robots.names()
    return secure_setup.files(names, example_passwords(names), "docs/security/users.txt")


def test_docs_security_is_what_secure_setup_writes_for_the_catalogue() -> None:
    for name, text in documented().items():
        assert (DOCS / name).read_text() == text, f"docs/security/{name}: run python -m tests.test_secure_setup"
    adapters = sorted(p.name for p in DOCS.glob("adapter*.json5"))
    assert adapters == [f"adapter-{r}.json5" for r in robots.names()]  # no stale adapter file beside them


def test_each_arm_has_its_own_adapter_user_whose_rules_name_only_its_arm() -> None:
    text = secure_setup.router_config(["a1", "b2"], "users.txt")
    for arm, other in (("a1", "b2"), ("b2", "a1")):
        block = text[text.index(f'id: "adapter-{arm}-listen"') : text.index(f'id: "adapter-{arm}-token"') + 200]
        assert f"armd/{arm}/trajectory" in block and f"armd/{other}/" not in block
        # (the one wildcard: seeing that the service follows every arm's state, events and sensors)
        assert [line for line in block.splitlines() if "armd/*/" in line] == [
            '        key_exprs: ["armd/*/state", "armd/*/events", "armd/*/sensors/*"] },'
        ]
    assert 'usernames: ["armd-adapter-a1"]' in text and 'usernames: ["armd-adapter-b2"]' in text


def test_bad_names_and_passwords_are_refused(tmp_path: Path) -> None:
    for bad in (["arm/x"], ["*"], [""], ["a", "a"], ['a"b'], ["a\nb"], ["a:b"], ["a\tb"]):
        with pytest.raises(BadRequest):
            secure_setup.router_config(bad, "users.txt")
    pw = secure_setup.new_passwords(["a"])
    with pytest.raises(BadRequest, match="no password for armd-adapter-a"):
        secure_setup.files(["a"], {k: v for k, v in pw.items() if k != "armd-adapter-a"}, "users.txt")
    with pytest.raises(BadRequest, match="colon"):
        secure_setup.files(["a"], {**pw, "operator": "x:y"}, "users.txt")
    out = tmp_path / "setup"
    secure_setup.write(out, {"users.txt": "x"})
    with pytest.raises(BadRequest, match=r"already holds users\.txt"):
        secure_setup.write(out, {"users.txt": "y"})
    assert (out / "users.txt").read_text() == "x"
    (out / "operator.json5").symlink_to(tmp_path / "elsewhere.txt")  # a dangling link in the folder
    with pytest.raises(BadRequest, match=r"already holds operator\.json5"):
        secure_setup.write(out, {"operator.json5": "secret"})
    assert not (tmp_path / "elsewhere.txt").exists()


@pytest.mark.slow  # (three processes of the command)
def test_the_command_writes_a_setup_whose_router_logs_in_only_its_users(tmp_path: Path) -> None:
    """``armd secure-setup`` for one arm: fresh passwords, files holding them readable by their
    owner only, and a router from its file that lets that arm's adapter in and a stranger not."""
    out = tmp_path / "setup"
    port = zenoh_port()
    done = subprocess.run(
        [
            sys.executable,
            "-m",
            "armd.cli",
            "secure-setup",
            str(out),
            "--robot",
            "gupta3",
            "--endpoint",
            f"tcp/127.0.0.1:{port}",
        ],
        capture_output=True,
        text=True,
        timeout=60,
        cwd=ROOT,
    )
    assert done.returncode == 0, done.stderr
    names = sorted(p.name for p in out.iterdir())
    assert names == [
        "adapter-gupta3.json5",
        "guest.json5",
        "operator.json5",
        "router.json5",
        "service.json5",
        "users.txt",
    ]
    users = dict(line.split(":", 1) for line in (out / "users.txt").read_text().splitlines())
    assert set(users) == {"armd-service", "armd-adapter-gupta3", "operator", "guest"}
    assert len({users[u] for u in users if u != "guest"}) == 3 and all(
        len(users[u]) >= 20 for u in users if u != "guest"
    )
    assert stat.S_IMODE((out / "users.txt").stat().st_mode) == 0o600
    assert stat.S_IMODE((out / "operator.json5").stat().st_mode) == 0o600
    again = subprocess.run(
        [sys.executable, "-m", "armd.cli", "secure-setup", str(out)],
        capture_output=True,
        text=True,
        timeout=60,
        cwd=ROOT,
    )
    assert again.returncode == 1 and "choose an empty folder" in again.stderr  # never overwrites passwords
    unknown = subprocess.run(
        [sys.executable, "-m", "armd.cli", "secure-setup", str(tmp_path / "x"), "--robot", "nosuch"],
        capture_output=True,
        text=True,
        timeout=60,
        cwd=ROOT,
    )
    assert unknown.returncode == 1 and "nosuch" in unknown.stderr
    router = zenoh.open(zenoh.Config.from_file(str(out / "router.json5")))
    try:
        adapter = zenoh.open(network_config(config_file=str(out / "adapter-gupta3.json5")))
        adapter.close()
        wrong = (out / "guest.json5").read_text().replace('password: "guest"', 'password: "nope"')
        (tmp_path / "wrong.json5").write_text(wrong)
        with pytest.raises(Exception):  # noqa: B017 (zenoh's own error: no session for a wrong password)
            zenoh.open(network_config(config_file=str(tmp_path / "wrong.json5"))).close()
    finally:
        router.close()


def zenoh_port() -> int:
    from tests.conftest import free_port

    return free_port()


if __name__ == "__main__":  # write docs/security anew
    for stale in DOCS.glob("adapter*.json5"):
        stale.unlink()
    for name, text in documented().items():
        (DOCS / name).write_text(text)
        print(DOCS / name)


def test_the_routers_size_limits_are_their_readers() -> None:
    """router.json5's low-pass filter drops what each key's reader would refuse anyway: the
    numbers it writes are the readers' own (a reader's cap raised alone would be cut at the router)."""
    from armd.adapters.base import CONTROL_BYTES
    from armd.adapters.trajectory_message import MAX_BYTES
    from armd.service.protocol import Limits
    from armd.service.server import REPORT_BYTES
    from armd.service.zconfig import MAX_MESSAGE_BYTES, MAX_SESSIONS

    assert {
        "query": Limits().max_payload_bytes,
        "control": CONTROL_BYTES,
        "report": REPORT_BYTES,
        "trajectory": MAX_BYTES,
    } == secure_setup.SIZE_LIMITS
    assert secure_setup.MAX_MESSAGE == MAX_MESSAGE_BYTES >= 2 * MAX_BYTES
    from armd.service.track_message import TRACK_BYTES

    assert TRACK_BYTES == CONTROL_BYTES  # (track puts share the commands' filter)
    assert secure_setup.MAX_SESSIONS == MAX_SESSIONS
