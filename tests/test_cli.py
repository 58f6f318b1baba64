"""The armd command line, run as a user runs it: a separate process."""

from __future__ import annotations

import json
import logging
import subprocess
import sys
from pathlib import Path

import pytest

pytestmark = pytest.mark.slow  # (seconds: processes, routers, emulated boards; `pytest -m "not slow"` skips it)


def armd(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "armd.cli", *args],
        capture_output=True,
        text=True,
        cwd=Path(__file__).resolve().parent.parent,
        timeout=120,
    )


def test_catalogue_lists_every_arm() -> None:
    out = armd("catalogue")
    assert out.returncode == 0, out.stderr
    for name in ("insomniac", "sg5ut", "gupta3", "desk4"):
        assert f"{name}:" in out.stdout
    assert "coupled linkage" in out.stdout


def test_catalogue_json() -> None:
    out = armd("catalogue", "--json")
    data = json.loads(out.stdout)
    assert data["gupta3"]["joints"][2]["name"] == "elbow"
    assert data["desk4"]["coupled_limits"][0]["upper"] == 0.9


def test_bad_robots_dir_is_a_clear_error(tmp_path: Path) -> None:
    out = armd("catalogue", "--robots-dir", str(tmp_path / "nowhere"))
    assert out.returncode == 1
    assert "armd: error:" in out.stderr and "is not a folder" in out.stderr
    assert "Traceback" not in out.stderr


def test_an_adapter_with_a_missing_port_says_so_in_one_line() -> None:
    out = armd("adapter", "ssc32", "insomniac", "--port", "/dev/ttyNOSUCHPORT", "--connect", "tcp/127.0.0.1:9")
    assert out.returncode == 1
    assert out.stderr.strip().splitlines() == [out.stderr.strip()]  # one line
    assert "cannot open /dev/ttyNOSUCHPORT" in out.stderr and "Traceback" not in out.stderr


def test_an_adapter_waits_for_a_router_and_says_so() -> None:
    import signal
    import time

    from armd.adapters.emulators.ssc32 import SSC32Emulator
    from armd.service.zconfig import free_endpoint

    with SSC32Emulator() as emu:
        proc = subprocess.Popen(
            [
                sys.executable,
                "-m",
                "armd.cli",
                "adapter",
                "ssc32",
                "insomniac",
                "--port",
                emu.port,
                "--connect",
                free_endpoint(),
            ],
            cwd=Path(__file__).resolve().parent.parent,
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
        )
        time.sleep(4.0)
        proc.send_signal(signal.SIGINT)
        _, err = proc.communicate(timeout=20)
    assert proc.returncode == 0, err
    assert "no Zenoh router answers" in err and "retrying" in err and "Traceback" not in err


def test_estop_and_unlock_reach_the_adapter_with_no_service(tmp_path: Path) -> None:
    """`armd estop` and `armd unlock` put straight on the adapter's keys: no service runs here."""
    import zenoh

    from armd import robots
    from armd.adapters.sim import SimAdapter
    from armd.service.zconfig import free_endpoint, network_config

    endpoint = free_endpoint()
    router = zenoh.open(network_config(listen=[endpoint], mode="router"))
    session = zenoh.open(network_config(connect=[endpoint]))
    adapter = SimAdapter(session, robots.load("gupta3"))
    try:
        out = armd("estop", "gupta3", "--connect", endpoint)
        assert out.returncode == 0, out.stderr
        assert f"adapter {adapter.id} (sim): stopping" in out.stdout
        out = armd("unlock", "gupta3", "--assume-rest", "--connect", endpoint, "--wait", "5")
        assert out.returncode == 1 and "nothing to unlock" in out.stderr  # the simulator always knows
        out = armd("estop", "desk4", "--connect", endpoint, "--wait", "0.3")
        assert out.returncode == 1 and "no adapter of desk4 acknowledged" in out.stderr
        # a stop now: the command loads neither NumPy nor Pinocchio before it is sent (0.3 s)
        code = (
            "import sys; from armd.cli import main; "
            f"r = main(['--log-level', 'error', 'estop', 'gupta3', '--connect', '{endpoint}', '--json']); "
            "print(r, sorted(m for m in ('numpy', 'pinocchio', 'armd.robots') if m in sys.modules))"
        )
        r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
        assert r.stdout.splitlines()[-1] == "0 []", r.stdout + r.stderr
        assert json.loads(r.stdout.splitlines()[0])["adapter"] == adapter.id
    finally:
        adapter.close()
        session.close()
        router.close()


BLOCK_EXTRAS = "import sys; sys.modules.update(serial=None, matplotlib=None, meshcat=None); "


def test_the_service_and_the_simulated_arms_need_no_extra() -> None:
    """pyserial (hardware), matplotlib and meshcat (view) are extras: the service, the client,
    the simulated arms and the command line import without them."""
    code = BLOCK_EXTRAS + ("import armd.service.server, armd.adapters.sim, armd.cli, armd.clients; print('ok')")
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0 and r.stdout.strip() == "ok", r.stderr


def test_a_command_whose_extra_is_missing_says_which_to_install() -> None:
    code = BLOCK_EXTRAS + (
        "from armd.cli import main; sys.exit(main(['adapter', 'ssc32', 'insomniac', '--port', '/dev/null']))"
    )
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert r.returncode == 1 and "pip install 'armd[hardware]'" in r.stderr, r.stderr
    assert len(r.stderr.strip().splitlines()) == 1, r.stderr


def test_usage_errors_exit_2_and_armds_errors_exit_1() -> None:
    """argparse's usage errors (an unknown verb, a missing argument) exit 2; what armd finds wrong
    (an unknown robot) exits 1, in one line."""
    assert armd("nosuchverb").returncode == 2
    assert armd("fk").returncode == 2
    out = armd("catalogue", "--robots-dir", "/nonexistent-armd-dir")
    assert out.returncode == 1 and out.stderr.strip().count("\n") == 0 and out.stderr.startswith("armd: error:")


def test_one_log_level_before_or_after_the_command() -> None:
    """``--log-level`` goes before the command or after it; without it the daemons log at info
    and the rest at warning; ``serve -v`` is ``--log-level debug``."""
    from armd.cli import build_parser

    def level(*argv: str) -> str:
        args = build_parser().parse_args(list(argv))
        return str(args.log_level or getattr(args, "log_default", "warning"))

    assert level("serve") == "info" and level("adapter", "sim", "insomniac") == "info"
    assert level("fk", "insomniac", "0") == "warning" and level("catalogue") == "warning"
    assert level("--log-level", "error", "serve") == "error" and level("serve", "--log-level", "debug") == "debug"
    assert level("serve", "-v") == "debug" and level("--log-level", "debug", "robots") == "debug"
    code = (
        "import logging; from armd.cli import main; main(['--log-level', 'debug', 'catalogue', '--json']); "
        "print(logging.getLogger('armd').getEffectiveLevel())"
    )
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0 and r.stdout.strip().splitlines()[-1] == str(logging.DEBUG), r.stderr
    assert armd("catalogue", "--log-level", "loud").returncode == 2


def test_a_daemon_stops_though_zenoh_cannot_close_its_session() -> None:
    """Zenoh's close can block on a link it cannot tear down (eclipse-zenoh/zenoh#2675): a
    daemon told to stop waits for it a bounded time, then exits anyway."""
    import threading
    import time

    from armd.cli.common import close_session

    released = threading.Event()

    class Stuck:  # (a session whose close hangs, as Zenoh's may)
        closed = False

        def close(self) -> None:
            released.wait(30)
            self.closed = True

    stuck, t0 = Stuck(), time.monotonic()
    close_session(stuck, wait=0.3)
    assert 0.25 < time.monotonic() - t0 < 2.0 and not stuck.closed
    released.set()

    class Quick:
        closed = False

        def close(self) -> None:
            self.closed = True

    quick, t0 = Quick(), time.monotonic()
    close_session(quick)
    assert quick.closed and time.monotonic() - t0 < 1.0
