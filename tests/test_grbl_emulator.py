"""The GRBL 1.1 emulator, driven through pyserial on its pseudo-terminal, as an adapter drives the Arduino."""

from __future__ import annotations

import collections
import signal
import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from contextlib import ExitStack
from pathlib import Path

import pytest
import serial

from clients.emulators.grbl import GrblEmulator

WELCOME = "Grbl 1.1h ['$' for help]"
Open = Callable[..., tuple[GrblEmulator, serial.Serial]]


class FakeClock:
    """A clock [s] that moves only when told: exact motion checks."""

    def __init__(self) -> None:
        self.now = 100.0

    def __call__(self) -> float:
        return self.now


@pytest.fixture
def grbl() -> Iterator[Open]:
    """Start an emulator (keyword arguments as GrblEmulator's), open its port, read the welcome."""
    with ExitStack() as stack:

        def make(**kwargs: object) -> tuple[GrblEmulator, serial.Serial]:
            emu = stack.enter_context(GrblEmulator(**kwargs))  # type: ignore[arg-type]
            ser = stack.enter_context(serial.Serial(emu.port, 115200, timeout=1))
            assert read_until(ser, WELCOME)[-1] == WELCOME
            return emu, ser

        yield make


def readline(ser: serial.Serial) -> str:
    return ser.readline().decode().strip()


def read_until(ser: serial.Serial, last: str) -> list[str]:
    """The non-empty lines received up to and including ``last`` (fails on a time-out)."""
    lines: list[str] = []
    while not lines or lines[-1] != last:
        raw = ser.readline()
        assert raw, f"timed out waiting for {last!r} after {lines}"
        if raw.strip():
            lines.append(raw.decode().strip())
    return lines


def command(ser: serial.Serial, line: str) -> list[str]:
    """Send one line; return what came back up to its ``ok`` or ``error:N``."""
    ser.write(line.encode() + b"\n")
    lines: list[str] = []
    while not lines or not (lines[-1] == "ok" or lines[-1].startswith("error:")):
        raw = ser.readline()
        assert raw, f"no answer to {line!r} after {lines}"
        if raw.strip():
            lines.append(raw.decode().strip())
    return lines


def status(ser: serial.Serial) -> dict[str, str]:
    """Ask ``?`` and parse the report: {"state": "Idle", "MPos": "0.000,0.000,0.000", "FS": "0,0", ...}."""
    ser.write(b"?")
    line = readline(ser)
    while not line.startswith("<"):
        line = readline(ser)
    state, *fields = line[1:-1].split("|")
    return {"state": state} | dict(f.split(":", 1) for f in fields)


def mpos(report: dict[str, str]) -> list[float]:
    return [float(v) for v in report["MPos"].split(",")]


def wait_for(condition: Callable[[], bool], timeout: float = 2.0) -> None:
    end = time.monotonic() + timeout
    while not condition():
        assert time.monotonic() < end, "the emulator did not get there in time"
        time.sleep(0.002)


# -- start, settings -----------------------------------------------------------------------------


def test_welcome_on_open_and_reopening_reboots(grbl: Open) -> None:
    emu, ser = grbl(time_scale=10)
    assert command(ser, "G0 X1") == ["ok"]
    wait_for(lambda: emu.state == "Idle")
    assert emu.steps()["X"] == 250
    ser.close()
    time.sleep(0.05)  # (a close and reopen within the emulator's 2 ms poll would go unseen)
    with serial.Serial(emu.port, 115200, timeout=1) as again:  # the Arduino resets when the port opens
        assert read_until(again, WELCOME) == [WELCOME]
        assert emu.steps() == {"X": 0, "Y": 0, "Z": 0}
        assert mpos(status(again)) == [0.0, 0.0, 0.0]


def test_settings_print_store_and_scale_the_steps(grbl: Open) -> None:
    emu, ser = grbl(time_scale=100)
    printed = command(ser, "$$")
    assert printed[-1] == "ok" and len(printed) == len(emu.settings) + 1
    assert {"$0=10", "$10=1", "$11=0.010", "$30=1000", "$100=250.000", "$101=250.000", "$102=250.000",
            "$110=500.000", "$120=10.000", "$132=200.000"} <= set(printed)
    assert command(ser, "$100=8.8889") == ["ok"]
    assert emu.settings[100] == 8.8889
    assert "$100=8.889" in command(ser, "$$")
    for line, answer in [("$100=abc", "error:2"), ("$7=1", "error:3"), ("$100", "error:3"),
                         ("$100=-1", "error:4"), ("$0=2", "error:6"), ("$100=10000", "error:12")]:
        assert command(ser, line) == [answer], line
    assert command(ser, "G0 X90 Y1") == ["ok"]
    wait_for(lambda: emu.state == "Idle")
    assert emu.steps() == {"X": 800, "Y": 250, "Z": 0}  # round(90 * 8.8889), round(1 * 250)
    assert emu.position()["X"] == pytest.approx(800 / 8.8889)  # GRBL keeps whole steps


# -- motion --------------------------------------------------------------------------------------


def test_a_move_takes_distance_over_feed(grbl: Open) -> None:
    emu, ser = grbl(time_scale=4)
    assert command(ser, "G1 X10 F300") == ["ok"]  # 10 units at 5 units/s: 2 s, 0.5 s at time_scale 4
    start = time.monotonic()
    time.sleep(0.25)
    assert emu.position()["X"] == pytest.approx(20 * (time.monotonic() - start), abs=1.0)
    assert emu.state == "Run"
    wait_for(lambda: emu.state == "Idle", timeout=1.0)
    assert time.monotonic() - start == pytest.approx(0.5, abs=0.1)
    assert emu.position() == {"X": 10.0, "Y": 0.0, "Z": 0.0}


def test_motion_follows_the_clock_exactly(grbl: Open) -> None:
    clock = FakeClock()
    emu, ser = grbl(clock=clock)
    assert command(ser, "G1 X10 Y-5 F300") == ["ok"]  # 11.18 units at 5 units/s: 2.236 s
    clock.now += 1.118034
    assert emu.position()["X"] == pytest.approx(5.0, abs=0.004)
    assert emu.position()["Y"] == pytest.approx(-2.5, abs=0.004)
    report = status(ser)
    assert report["state"] == "Run" and report["FS"] == "300,0"
    clock.now += 1.2
    assert status(ser)["state"] == "Idle"
    assert emu.steps() == {"X": 2500, "Y": -1250, "Z": 0}
    assert command(ser, "G1 Z1 F1000") == ["ok"]  # capped at the $112 max rate, 500 units/min
    clock.now += 0.06
    assert emu.position()["Z"] == pytest.approx(0.5, abs=0.004)
    assert status(ser)["FS"] == "500,0"
    clock.now += 1.0
    assert command(ser, "G0 X0 Y0 Z0") == ["ok"]  # rapid: as fast as no axis exceeds its $11x max rate
    clock.now += 5 / 500 * 60  # X, the longest, at 500 units/min
    assert emu.position()["X"] == pytest.approx(5.0, abs=0.004)
    assert emu.position()["Z"] == pytest.approx(0.5, abs=0.005)  # within a step (1/250)


def test_dwell_waits_for_the_planner_then_dwells(grbl: Open) -> None:
    emu, ser = grbl(time_scale=10)
    assert command(ser, "G1 X2.5 F300") == ["ok"]  # 0.5 s
    start = time.monotonic()
    assert command(ser, "G4 P0.5") == ["ok"]  # answered after the move and the dwell: 1 s, 0.1 s here
    assert time.monotonic() - start == pytest.approx(0.1, abs=0.04)
    assert emu.position()["X"] == 2.5


# -- the line protocol ---------------------------------------------------------------------------


def test_one_answer_per_line(grbl: Open) -> None:
    emu, ser = grbl()
    for line in ["G21", "G90", "G17 G94", "m5", "", "(a comment)", "G0 X0 ; a comment", "N10 G1 F100"]:
        assert command(ser, line) == ["ok"], line
    assert emu.lines == ["G21", "G90", "G17 G94", "m5", "(a comment)", "G0 X0 ; a comment", "N10 G1 F100"]


def test_errors_are_grbl_s_codes(grbl: Open) -> None:
    emu, ser = grbl()
    for line, code in [("G1 X1", 22), ("G99", 20), ("Q5", 20), ("A1", 20), ("123", 1), ("G1 X", 2),
                       ("G1 X1 X2 F100", 25), ("G0 G1 X1", 21), ("G4", 28), ("G1 F-5", 4), ("G0 X1 P2", 36),
                       ("G1.5 X1", 23), ("X" + "1" * 80, 11)]:
        assert command(ser, line) == [f"error:{code}"], line
    assert emu.steps() == {"X": 0, "Y": 0, "Z": 0}  # a line with an error does nothing


def test_crlf_is_two_lines_as_in_grbl(grbl: Open) -> None:
    _, ser = grbl()
    ser.write(b"G90\r\n")  # '\r' ends the line, '\n' ends an empty one: GRBL answers both
    assert [readline(ser), readline(ser)] == ["ok", "ok"]


def test_status_reports_run_then_idle(grbl: Open) -> None:
    emu, ser = grbl(time_scale=10)
    assert command(ser, "$10=3") == ["ok"]  # MPos and buffer state
    first = status(ser)
    assert first == {"state": "Idle", "MPos": "0.000,0.000,0.000", "Bf": "15,128", "FS": "0,0",
                     "WCO": "0.000,0.000,0.000"}
    assert status(ser)["Ov"] == "100,100,100"  # GRBL sends WCO in the first report, Ov in the second
    assert command(ser, "G1 X10 F300") == ["ok"]
    assert command(ser, "G1 X0") == ["ok"]
    report = status(ser)
    assert report["state"] == "Run" and report["Bf"] == "13,128" and report["FS"] == "300,0"
    assert 0.0 < mpos(report)[0] < 10.0
    wait_for(lambda: emu.state == "Idle")
    assert status(ser) == {"state": "Idle", "MPos": "0.000,0.000,0.000", "Bf": "15,128", "FS": "0,0"}


def test_feed_hold_decelerates_freezes_and_resumes(grbl: Open) -> None:
    clock = FakeClock()
    emu, ser = grbl(clock=clock)
    assert command(ser, "G1 X20 F300") == ["ok"]  # 5 units/s; $120: 10 units/s^2
    clock.now += 0.8
    ser.write(b"!~")  # a resume during the deceleration is ignored, as in GRBL
    report = status(ser)
    assert report["state"] == "Hold:1" and report["FS"] == "300,0"
    clock.now += 0.25
    assert emu.position()["X"] == pytest.approx(4 + 5 * 0.25 - 10 * 0.25**2 / 2, abs=0.004)
    clock.now += 1.0
    report = status(ser)
    assert report["state"] == "Hold:0" and report["FS"] == "0,0"
    assert mpos(report)[0] == pytest.approx(5.25, abs=0.004)  # 4 + v^2 / 2a
    clock.now += 5.0
    assert emu.position()["X"] == pytest.approx(5.25, abs=0.004)  # frozen
    ser.write(b"~")
    assert status(ser)["state"] == "Run"
    clock.now += 1.0
    assert emu.position()["X"] == pytest.approx(10.25, abs=0.004)
    clock.now += 2.0
    assert status(ser)["state"] == "Idle"
    assert emu.position()["X"] == 20.0


def test_character_counting_never_overflows(grbl: Open) -> None:
    emu, ser = grbl(time_scale=4)
    assert command(ser, "G91") == ["ok"]
    lines = [b"G1 X0.1 F300\n"] * 80  # 13 bytes, 20 ms each (5 ms here): the planner fills, then the buffer
    unanswered: collections.deque[int] = collections.deque()
    answers = []
    for line in lines:
        while sum(unanswered) + len(line) > 128:
            answers.append(readline(ser))
            unanswered.popleft()
        ser.write(line)
        unanswered.append(len(line))
    answers += [readline(ser) for _ in unanswered]
    assert answers == ["ok"] * 80
    assert emu.overflows == 0
    assert 100 <= emu.max_rx_used <= 128
    wait_for(lambda: emu.state == "Idle")
    assert emu.steps()["X"] == 2000  # 8 units


def test_a_flooding_host_loses_bytes(grbl: Open) -> None:
    emu, ser = grbl()
    assert command(ser, "G91") == ["ok"]
    ser.write(b"G1 X0.1 F60\n" * 84)  # 1008 bytes at once: 15 blocks planned, 128 bytes buffered, the rest lost
    wait_for(lambda: emu.overflows > 0)
    time.sleep(0.05)
    assert emu.overflows == 1008 - 16 * 12 - 128  # 15 in the planner, 1 waiting in the parser
    assert emu.max_rx_used == 128


# -- alarms, errors, reset, silence ---------------------------------------------------------------


def test_injected_alarm_stops_and_locks_until_unlock(grbl: Open) -> None:
    clock = FakeClock()
    emu, ser = grbl(clock=clock)
    assert command(ser, "G1 X20 F300") == ["ok"]
    clock.now += 1.0
    emu.inject_alarm(5)
    assert readline(ser) == "ALARM:5"
    clock.now += 1.0
    assert emu.position()["X"] == 5.0 and emu.state == "Alarm"
    assert status(ser)["state"] == "Alarm"
    assert command(ser, "G1 X0") == ["error:9"]
    assert command(ser, "$$")[-1] == "ok"  # '$' commands still work
    assert command(ser, "$X") == ["[MSG:Caution: Unlocked]", "ok"]
    assert command(ser, "G1 X0") == ["ok"]
    assert emu.state == "Run"


def test_limit_alarm_needs_a_reset(grbl: Open) -> None:
    emu, ser = grbl()
    emu.inject_alarm(1)  # a hard limit: GRBL reads nothing more until reset
    assert read_until(ser, "[MSG:Reset to continue]") == ["ALARM:1", "[MSG:Reset to continue]"]
    ser.write(b"G0 X1\n")
    assert status(ser)["state"] == "Alarm"  # real-time commands still work, lines are not read
    ser.timeout = 0.2
    assert readline(ser) == ""
    ser.timeout = 1
    ser.write(b"\x18")
    assert read_until(ser, "[MSG:'$H'|'$X' to unlock]") == [WELCOME, "[MSG:'$H'|'$X' to unlock]"]
    assert command(ser, "G0 X1") == ["error:9"]
    assert command(ser, "$X") == ["[MSG:Caution: Unlocked]", "ok"]
    assert "G0 X1" not in emu.lines[:-2]  # the line sent during the lock was flushed by the reset


def test_injected_error_answers_the_next_gcode_line(grbl: Open) -> None:
    emu, ser = grbl(time_scale=10)
    emu.inject_error_on_next_line(9)
    assert command(ser, "$G")[-1] == "ok"  # '$' lines and empty lines are not G-code lines
    assert command(ser, "") == ["ok"]
    assert command(ser, "G0 X1") == ["error:9"]
    time.sleep(0.05)
    assert emu.steps()["X"] == 0  # dropped
    assert command(ser, "G0 X1") == ["ok"]
    wait_for(lambda: emu.steps()["X"] == 250)


def test_reset_mid_move_raises_alarm_3(grbl: Open) -> None:
    clock = FakeClock()
    emu, ser = grbl(clock=clock)
    ser.write(b"\x18")  # idle: only the welcome
    assert read_until(ser, WELCOME) == [WELCOME]
    assert status(ser)["state"] == "Idle"
    assert command(ser, "G1 X20 F300") == ["ok"]
    ser.write(b"G1 X0\n")
    assert readline(ser) == "ok"
    clock.now += 1.0
    ser.write(b"\x18")
    assert read_until(ser, "[MSG:'$H'|'$X' to unlock]") == ["ALARM:3", WELCOME, "[MSG:'$H'|'$X' to unlock]"]
    clock.now += 2.0
    assert emu.position()["X"] == 5.0  # stopped where it was, the planner emptied
    assert command(ser, "G1 X0 F300") == ["error:9"]
    assert command(ser, "$X") == ["[MSG:Caution: Unlocked]", "ok"]
    assert status(ser)["state"] == "Idle"


def test_not_responding_times_out_then_recovers(grbl: Open) -> None:
    emu, ser = grbl()
    emu.responding = False
    ser.timeout = 0.3
    ser.write(b"?G0 X1\n$$\n")
    assert ser.readline() == b""
    assert emu.lines == [] and emu.steps()["X"] == 0
    emu.responding = True
    assert status(ser)["state"] == "Idle"
    assert command(ser, "G90") == ["ok"]


def test_run_as_a_program_until_ctrl_c() -> None:
    root = Path(__file__).resolve().parent.parent
    proc = subprocess.Popen([sys.executable, "-m", "clients.emulators.grbl"], cwd=root, text=True,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    try:
        assert proc.stdout is not None
        port = proc.stdout.readline().strip()
        with serial.Serial(port, 115200, timeout=2) as ser:
            assert read_until(ser, WELCOME) == [WELCOME]
            assert command(ser, "G90") == ["ok"]
        proc.send_signal(signal.SIGINT)
        assert proc.wait(timeout=5) == 0
    finally:
        proc.kill()
        proc.wait()
