"""The SSC-32 emulator, driven through pyserial on its pseudo-terminal, as an adapter drives the board."""

from __future__ import annotations

import itertools
import math
import random
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest
import serial

from armd.adapters.emulators.ssc32 import GroupMove, SSC32Emulator


class FakeClock:
    """A clock [s] that moves only when told: exact interpolation checks."""

    def __init__(self) -> None:
        self.now = 100.0

    def __call__(self) -> float:
        return self.now


def wait_for(condition: Callable[[], bool], timeout: float = 1.0) -> None:
    """Wait until ``condition()`` (the emulator's thread has read a line), or fail after ``timeout`` [s]."""
    end = time.monotonic() + timeout
    while not condition():
        assert time.monotonic() < end, "the emulator did not act in time"
        time.sleep(0.002)


def send(ser: serial.Serial, emu: SSC32Emulator, line: bytes) -> None:
    """Write a move line and wait until the emulator has recorded it (in ``history`` or ``errors``)."""
    before = len(emu.history) + len(emu.errors)
    ser.write(line)
    wait_for(lambda: len(emu.history) + len(emu.errors) > before)


@pytest.fixture
def emu() -> Iterator[SSC32Emulator]:
    with SSC32Emulator() as e:
        yield e


@pytest.fixture
def ser(emu: SSC32Emulator) -> Iterator[serial.Serial]:
    with serial.Serial(emu.port, 115200, timeout=1) as s:
        yield s


@pytest.fixture
def fake() -> Iterator[tuple[SSC32Emulator, serial.Serial, FakeClock]]:
    clock = FakeClock()  # frozen: an ideal link and an instant board, or nothing would ever arrive
    with SSC32Emulator(clock=clock, baud=None, query_delay=0.0) as e, serial.Serial(e.port, 115200, timeout=1) as s:
        yield e, s, clock


def test_group_move_with_time_lands_all_servos_together(emu: SSC32Emulator, ser: serial.Serial) -> None:
    send(ser, emu, b"#0P1000#1P2000\r")  # first commands: jump
    assert emu.pulses() == {0: 1000.0, 1: 2000.0}
    assert not emu.moving()
    send(ser, emu, b"#0P1500#1P1000T200\r")
    start = emu.history[-1].time
    assert emu.target(0) == 1500 and emu.target(1) == 1000
    time.sleep(max(0.0, start + 0.1 - time.monotonic()))
    before = time.monotonic()
    p0, p1 = emu.pulse(0), emu.pulse(1)
    f = (0.5 * (before + time.monotonic()) - start) / 0.2  # fraction of the move done when read
    assert 0.3 < f < 0.8, "the test was too slow to look mid-move"
    assert (p0 - 1000) / 500 == pytest.approx(f, abs=0.03)  # 500 us to go
    assert (2000 - p1) / 1000 == pytest.approx(f, abs=0.03)  # 1000 us to go, in the same time
    assert emu.moving()
    time.sleep(max(0.0, start + 0.25 - time.monotonic()))
    assert emu.pulses() == {0: 1500.0, 1: 1000.0}
    assert not emu.moving()
    assert emu.history[-1] == GroupMove(start, {0: 1500, 1: 1000}, {}, 200)


def test_interpolation_is_linear_and_shared(fake: tuple[SSC32Emulator, serial.Serial, FakeClock]) -> None:
    emu, ser, clock = fake
    send(ser, emu, b"#0P1000#5P2000\r")
    send(ser, emu, b"#0P2000#5P1500T1000\r")
    for dt, p0, p5 in ((0.0, 1000, 2000), (0.25, 1250, 1875), (0.5, 1500, 1750), (1.0, 2000, 1500), (5.0, 2000, 1500)):
        clock.now = 100.0 + dt
        assert emu.pulse(0) == pytest.approx(p0) and emu.pulse(5) == pytest.approx(p5)


def test_speed_limits_the_move(fake: tuple[SSC32Emulator, serial.Serial, FakeClock]) -> None:
    emu, ser, clock = fake
    send(ser, emu, b"#0P1000\r")
    send(ser, emu, b"#0P2000S500\r")  # 1000 us at 500 us/s: 2 s
    clock.now += 1.0
    assert emu.pulse(0) == pytest.approx(1500)
    assert emu.moving()
    clock.now += 1.0
    assert emu.pulse(0) == 2000 and not emu.moving()


def test_speed_and_time_the_slower_wins(fake: tuple[SSC32Emulator, serial.Serial, FakeClock]) -> None:
    """The user guide's example: ch17 from 2000 to 750 at 500 us/s needs 2.5 s > T2000."""
    emu, ser, clock = fake
    send(ser, emu, b"#5P1500#17P2000#2P1500\r")
    send(ser, emu, b"#5 P1600 #17 P750 S500 #2 P2250 T2000\r")
    clock.now += 2.0  # T alone would have ended the move here
    assert emu.pulse(17) == pytest.approx(2000 - 500 * 2.0)
    assert emu.pulse(5) == pytest.approx(1500 + 100 * 2.0 / 2.5)  # slowed down to arrive with ch17
    assert emu.moving()
    clock.now += 0.5
    assert emu.pulses() == {2: 2250.0, 5: 1600.0, 17: 750.0}
    assert not emu.moving()
    send(ser, emu, b"#17P1000S500T2000\r")  # 250 us at 500 us/s: 0.5 s < T, T wins
    clock.now += 1.0
    assert emu.pulse(17) == pytest.approx(875)


def test_q_answers_plus_while_moving_then_dot(emu: SSC32Emulator, ser: serial.Serial) -> None:
    ser.write(b"#0P1500\r#0P1700T300\r")
    ser.write(b"Q\r")
    assert ser.read(1) == b"+"
    time.sleep(0.35)
    ser.write(b"Q\r")
    assert ser.read(1) == b"."
    ser.timeout = 0.1
    assert ser.read(1) == b"", "Q answers one character, no carriage return"


def test_qp_returns_one_byte_pulse_over_ten(emu: SSC32Emulator, ser: serial.Serial) -> None:
    ser.write(b"#3P1500#4P2500\r")
    ser.write(b"QP3\r")
    assert ser.read(1) == bytes([150])
    ser.write(b"QP 4\r")
    assert ser.read(1) == bytes([250])
    ser.write(b"QP7\r")  # never commanded: no pulse
    assert ser.read(1) == bytes([0])
    ser.write(b"QP3QP4\r")  # several channels: one byte each
    assert ser.read(2) == bytes([150, 250])
    ser.timeout = 0.1
    assert ser.read(1) == b"", "no carriage return after QP"


def test_qp_follows_the_motion(fake: tuple[SSC32Emulator, serial.Serial, FakeClock]) -> None:
    emu, ser, clock = fake
    send(ser, emu, b"#0P1000\r")
    send(ser, emu, b"#0P2000T1000\r")
    clock.now += 0.5
    ser.write(b"QP0\r")
    assert ser.read(1) == bytes([150])


def test_analog_inputs_answer_a_byte_each_the_first_read_not_valid(
    fake: tuple[SSC32Emulator, serial.Serial, FakeClock],
) -> None:
    """The guide: V<pin> answers one byte, the volts times 256/5 (2 V: 102, 3.5 V: 179); the
    first read of a pin makes it analog and is not valid (the pull-up's level); a power cycle
    makes it digital again. The board's filter: a read sees the pin as it was 8 ms before."""
    emu, ser, clock = fake
    seen: list[tuple[str, float]] = []

    def volts(pin: str, t: float, pulse: Any) -> float:
        seen.append((pin, t))
        return {"A": 2.0, "B": 3.5, "C": 6.0, "D": -0.3}.get(pin, 0.0)

    emu.analog = volts
    clock.now = 10.0
    ser.write(b"VA VB\r")
    assert ser.read(2) == bytes([255, 255])  # (made analog: not valid data)
    assert seen == []
    ser.write(b"VAVB\r")
    assert ser.read(2) == bytes([102, 179])  # the guide's own example
    assert seen == [("A", pytest.approx(9.992)), ("B", pytest.approx(9.992))]
    ser.write(b"vc\r")
    assert ser.read(1) == bytes([255])
    ser.write(b"VDVH\r")
    assert ser.read(2) == bytes([255, 255])
    ser.write(b"VCVDVH\r")  # over 4.98 V: 255; below 0: 0; nothing wired: 0
    assert ser.read(3) == bytes([255, 0, 0])
    emu.power_cycle()
    ser.write(b"VA\r")
    assert ser.read(1) == bytes([255])
    ser.write(b"VI\r")  # no pin I
    ser.timeout = 0.1
    assert ser.read(1) == b""
    assert emu.errors == ["VI"]


def test_ver(ser: serial.Serial) -> None:
    ser.write(b"VER\r")
    assert ser.read_until(b"\r") == b"SSC32-V2.50USB\r"
    ser.timeout = 0.1
    assert ser.read(1) == b"", "nothing after the carriage return"


def test_ver_custom_and_lowercase() -> None:
    with SSC32Emulator(version="SSC32-1.06XE") as emu, serial.Serial(emu.port, 115200, timeout=1) as ser:
        ser.write(b"ver\r")
        assert ser.read_until(b"\r") == b"SSC32-1.06XE\r"


def test_out_of_range_pulses_are_clamped_and_recorded(emu: SSC32Emulator, ser: serial.Serial) -> None:
    send(ser, emu, b"#0P1500#1P1500#2P2500#3P500\r")
    assert emu.out_of_range == []  # the limits themselves are valid
    send(ser, emu, b"#0P3000#1P100#2P2400\r")
    assert emu.out_of_range == [(0, 3000), (1, 100)]
    assert emu.pulses() == {0: 2500.0, 1: 500.0, 2: 2400.0, 3: 500.0}
    assert emu.history[-1].pulses == {0: 3000, 1: 100, 2: 2400}  # as received


def test_p0_turns_the_pulses_off(emu: SSC32Emulator, ser: serial.Serial) -> None:
    send(ser, emu, b"#0P1500#1P1500\r")
    send(ser, emu, b"#0P0\r")
    assert emu.pulse(0) == 0.0 and emu.target(0) is None and emu.pulses() == {1: 1500.0}
    assert emu.out_of_range == [(0, 0)]
    send(ser, emu, b"#0P1000T1000\r")  # off has no position: the next command jumps
    assert emu.pulse(0) == 1000.0


def test_line_endings_spaces_and_case(emu: SSC32Emulator, ser: serial.Serial) -> None:
    send(ser, emu, b"#0 p1500 #1 P1600 s500 t100\r\n")
    send(ser, emu, b"\n#2P17\n00\r")  # line feeds are ignored, wherever they are
    send(ser, emu, b"#3P1800\t\r")
    assert [m.pulses for m in emu.history] == [{0: 1500, 1: 1600}, {2: 1700}, {3: 1800}]
    assert emu.history[0].speeds == {1: 500} and emu.history[0].duration_ms == 100
    assert emu.errors == []


def test_a_command_runs_only_at_its_carriage_return(emu: SSC32Emulator, ser: serial.Serial) -> None:
    ser.write(b"#0P1500#1P")
    time.sleep(0.05)
    assert emu.history == [] and emu.pulses() == {}
    send(ser, emu, b"1600\r")
    assert emu.pulses() == {0: 1500.0, 1: 1600.0}


def test_malformed_lines_are_recorded_and_ignored(emu: SSC32Emulator, ser: serial.Serial) -> None:
    send(ser, emu, b"#0P1200\r")
    bad = ["#0P", "HELLO", "#32P1500", "#0P1500T", "QP32", "#1P1500 #2P1600 T100 #3P1700", "STOP40"]
    for line in bad:
        send(ser, emu, line.encode() + b"\r")
    assert emu.errors == bad
    assert len(emu.history) == 1 and emu.pulses() == {0: 1200.0}
    send(ser, emu, b"#0P1300\r")  # still working
    assert emu.pulse(0) == 1300.0
    ser.write(b"VER\r")
    assert ser.read_until(b"\r") == b"SSC32-V2.50USB\r"


def test_stop_holds_a_servo_where_it_is(fake: tuple[SSC32Emulator, serial.Serial, FakeClock]) -> None:
    emu, ser, clock = fake
    send(ser, emu, b"#0P1000#1P1000\r")
    send(ser, emu, b"#0P2000#1P2000T1000\r")
    clock.now += 0.3
    before = len(emu.errors)
    ser.write(b"STOP 0\r")
    ser.write(b"Q\r")  # answered after STOP: STOP has run
    assert ser.read(1) == b"+", "the original move's time has not elapsed"
    assert len(emu.errors) == before
    clock.now += 0.2
    assert emu.pulse(0) == pytest.approx(1300) and emu.target(0) == 1300
    assert emu.pulse(1) == pytest.approx(1500)
    clock.now += 0.5
    ser.write(b"Q\r")
    assert ser.read(1) == b"."
    assert emu.pulses() == {0: pytest.approx(1300), 1: 2000.0}


def test_not_responding_times_out_then_recovers(emu: SSC32Emulator, ser: serial.Serial) -> None:
    ser.timeout = 0.3
    send(ser, emu, b"#0P1500\r")
    emu.responding = False
    ser.write(b"VER\r#0P2000\rQ\r")
    assert ser.read_until(b"\r") == b""
    assert emu.pulse(0) == 1500.0 and len(emu.history) == 1
    emu.responding = True
    ser.write(b"VER\r")
    assert ser.read_until(b"\r") == b"SSC32-V2.50USB\r"
    send(ser, emu, b"#0P2000\r")
    assert emu.pulse(0) == 2000.0


def test_stop_is_idempotent_and_ends_the_thread() -> None:
    emu = SSC32Emulator()
    with pytest.raises(RuntimeError):
        _ = emu.port
    port = emu.start()
    assert Path(port).exists() and emu.port == port
    name = f"ssc32-emulator {port}"
    assert any(t.name == name for t in threading.enumerate())
    with serial.Serial(port, 115200, timeout=1) as ser:
        ser.write(b"VER\r")
        assert ser.read_until(b"\r") == b"SSC32-V2.50USB\r"
        emu.stop()
        assert not any(t.name == name for t in threading.enumerate())
        emu.stop()
    emu.stop()


def test_run_as_a_program_until_ctrl_c() -> None:
    root = Path(__file__).resolve().parent.parent
    proc = subprocess.Popen(
        [sys.executable, "-m", "armd.adapters.emulators.ssc32"],
        cwd=root,
        text=True,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
    )
    watchdog = threading.Timer(10, proc.kill)  # a hung program ends, and its readline() returns ""
    watchdog.start()
    try:
        assert proc.stdout is not None
        port = proc.stdout.readline().strip()
        with serial.Serial(port, 115200, timeout=2) as ser:
            ser.write(b"#0P1500\rVER\r")
            assert ser.read_until(b"\r") == b"SSC32-V2.50USB\r"
        assert proc.stdout.readline().startswith("move: GroupMove(")
        proc.send_signal(signal.SIGINT)
        assert proc.wait(timeout=5) == 0
    finally:
        watchdog.cancel()
        proc.kill()
        proc.wait()


# -- the link, the board's timing, power and the output trace -------------------------------------------------------


def byte_time(baud: int) -> float:
    """How long one byte takes on the link [s] (8N1: 10 bits)."""
    return 10 / baud


# [s] how much later than due the emulator may read a write, or the test a reply, on a loaded
# 2-core host: the kernel thread that carries a terminal's bytes, and the test's own thread,
# wait their turns (never sooner: each check is a floor, at the link's exact time, and this above it)
JITTER = 0.015


def test_a_command_takes_effect_when_its_last_byte_arrives_at_9600() -> None:
    line = b"#0P1500#1P1600#2P1700T100\r"
    expected = len(line) * byte_time(9600)  # 27 bytes: 28 ms
    with SSC32Emulator(baud=9600) as emu, serial.Serial(emu.port, 9600, timeout=1) as ser:
        written = time.monotonic()
        ser.write(line)
        assert time.monotonic() - written < 0.005, "the host's write returns at once"
        time.sleep(max(0.0, written + 0.6 * expected - time.monotonic()))
        assert emu.history == [] and emu.pulses() == {}, "executed before its carriage return arrived"
        wait_for(lambda: len(emu.history) == 1)
        seen = time.monotonic() - written
        assert expected - 0.001 <= emu.history[0].time - written <= expected + JITTER
        assert expected - 0.001 <= seen <= expected + JITTER + 0.005  # (wait_for looks every 2 ms)
        assert emu.pulses() == {0: 1500.0, 1: 1600.0, 2: 1700.0}


def test_link_timing_is_exact_on_a_frozen_clock() -> None:
    clock = FakeClock()
    line = b"#0P1500\r"
    with SSC32Emulator(clock=clock, baud=9600) as emu, serial.Serial(emu.port, 9600, timeout=1) as ser:
        ser.write(line + line.replace(b"1500", b"1600"))
        wait_for(lambda: emu.link_backlog() > 0)  # the emulator has read the bytes, at 100.0
        assert emu.link_backlog() == pytest.approx(2 * len(line) * byte_time(9600))
        clock.now += len(line) * byte_time(9600) - 1e-9
        time.sleep(0.02)
        assert emu.history == []
        clock.now += 1e-9
        wait_for(lambda: len(emu.history) == 1)
        assert emu.history[0].time == pytest.approx(100.0 + len(line) * byte_time(9600), abs=1e-9)
        assert emu.pulse(0) == 1500.0
        clock.now += len(line) * byte_time(9600)
        wait_for(lambda: len(emu.history) == 2)
        assert emu.pulse(0) == 1600.0 and emu.link_backlog() == 0.0


def test_a_host_faster_than_the_link_falls_behind() -> None:
    """Group moves of 40 bytes at 50 Hz need 2000 B/s; 9600 baud carries 960: each executes later than the last."""
    dt, n, period = byte_time(9600), 10, 0.02
    lines = [f"#0P{1000 + 10 * k}#1P1500#2P1500#3P1500#14P1500T20\r".encode() for k in range(n)]
    assert {len(line) for line in lines} == {40}
    with SSC32Emulator(baud=9600) as emu, serial.Serial(emu.port, 9600, timeout=1) as ser:
        written, free = [], []
        start = time.monotonic()
        for k, line in enumerate(lines):
            time.sleep(max(0.0, start + k * period - time.monotonic()))
            written.append(time.monotonic())
            ser.write(line)
            time.sleep(0.002)
            free.append(time.monotonic() + emu.link_backlog())  # when the link will have carried all of it
        wait_for(lambda: len(emu.history) == n, timeout=2)
    arrival = -math.inf
    for k, move in enumerate(emu.history):
        arrival = max(arrival, written[k]) + 40 * dt  # the link is busy from the first write on
        assert arrival - 0.001 <= move.time <= arrival + JITTER
        assert move.pulses[0] == 1000 + 10 * k  # in order
    lag = [move.time - w for move, w in zip(emu.history, written, strict=True)]
    assert all(b > a for a, b in itertools.pairwise(lag)), lag
    assert lag[-1] == pytest.approx(n * 40 * dt - (n - 1) * period, abs=0.01)  # 0.237 s
    # each line puts the link's end later (its 40 bytes take twice the period): counted from when this
    # thread read the backlog, which a busy host may hold, not from when it meant to
    assert all(b - a > period for a, b in itertools.pairwise(free)), free


@pytest.mark.parametrize(("query", "size"), [(b"Q\r", 1), (b"QP0\r", 1), (b"VER\r", 15)])
def test_query_delay_delays_the_reply(query: bytes, size: int) -> None:
    delays = {}
    for query_delay in (0.0, 0.05):
        with (
            SSC32Emulator(baud=115200, query_delay=query_delay) as emu,
            serial.Serial(emu.port, 115200, timeout=1) as ser,
        ):
            send(ser, emu, b"#0P1500\r")
            written = time.monotonic()
            ser.write(query)
            assert len(ser.read(size)) == size
            delays[query_delay] = time.monotonic() - written
    link = (len(query) + size) * byte_time(115200)
    # never sooner than the link and the delay allow; a busy host only adds (up to JITTER)
    assert link - 0.001 <= delays[0.0] <= link + JITTER
    assert 0.05 + link - 0.001 <= delays[0.05] <= 0.05 + link + JITTER


def test_replies_travel_at_the_link_rate() -> None:
    with SSC32Emulator(baud=9600, query_delay=0.0) as emu, serial.Serial(emu.port, 9600, timeout=1) as ser:
        written = time.monotonic()
        ser.write(b"VER\r")
        assert ser.read_until(b"\r") == b"SSC32-V2.50USB\r"
        link = (4 + 15) * byte_time(9600)  # 20 ms
        assert link - 0.001 <= time.monotonic() - written <= link + JITTER


def test_a_line_feed_alone_does_not_end_a_command(emu: SSC32Emulator, ser: serial.Serial) -> None:
    ser.write(b"#0P1500\n")
    ser.write(b"VER\n")
    time.sleep(0.05)
    assert emu.history == [] and emu.pulses() == {} and ser.in_waiting == 0
    send(ser, emu, b"\r")  # the two are one command now: not understood
    assert emu.errors == ["#0P1500VER"]
    send(ser, emu, b"#0P1500\n\r")
    assert emu.pulses() == {0: 1500.0} and emu.errors == ["#0P1500VER"]


def test_power_cycle_turns_everything_off(fake: tuple[SSC32Emulator, serial.Serial, FakeClock]) -> None:
    emu, ser, clock = fake
    send(ser, emu, b"#0P1000#1P1200\r")
    send(ser, emu, b"#0P2000T1000\r")
    clock.now += 0.5
    emu.power_cycle()
    assert emu.pulses() == {} and emu.target(0) is None and not emu.moving()
    ser.write(b"QP0QP1\r")
    assert ser.read(2) == bytes([0, 0])
    ser.write(b"Q\r")
    assert ser.read(1) == b"."
    send(ser, emu, b"#0P1800T1000\r")  # no known position: jumps
    assert emu.pulse(0) == 1800.0
    assert emu.segments(0)[-2:] == [(100.5, 100.5, 1500.0, 0.0), (100.5, 100.5, 0.0, 1800.0)]
    clock.now += 0.1
    assert emu.segments(1) == [
        (100.0, 100.0, 0.0, 1200.0),
        (100.0, 100.5, 1200.0, 1200.0),
        (100.5, 100.5, 1200.0, 0.0),
        (100.5, 100.6, 0.0, 0.0),
    ]


def test_reopening_the_port_keeps_the_pulses(emu: SSC32Emulator) -> None:
    with serial.Serial(emu.port, 115200, timeout=1) as ser:
        send(ser, emu, b"#0P1500#1P2000\r")
    assert emu.pulses() == {0: 1500.0, 1: 2000.0}
    with serial.Serial(emu.port, 115200, timeout=1) as ser:
        ser.write(b"QP0QP1\r")
        assert ser.read(2) == bytes([150, 200])
        send(ser, emu, b"#0P1000T100\r")  # a known position: a timed move, no jump
        assert emu.pulse(0) > 1000.0


def value_at(segments: list[tuple[float, float, float, float]], t: float) -> float:
    """The output the trace says at ``t``: the last segment containing it (after any jump at ``t``)."""
    for t0, t1, p0, p1 in reversed(segments):
        if t0 <= t <= t1:
            return p1 if t1 == t0 else p0 + (p1 - p0) * (t - t0) / (t1 - t0)
    return 0.0


def test_the_trace_is_the_output(fake: tuple[SSC32Emulator, serial.Serial, FakeClock]) -> None:
    emu, ser, clock = fake
    rng = random.Random(7)
    samples: list[tuple[float, dict[int, float]]] = []
    script = [
        b"#0P1000#1P1500\r",
        b"#0P2000#1P1000T1000\r",
        b"#0P1000T250\r",
        b"#1P2000S400\r",
        b"STOP1\r",
        b"#0P0\r",
        b"#0P1200\r",
        b"#0P1300#1P1400T300\r",
        b"#0P1500\r",
    ]
    times = [0.0, 0.2, 0.7, 1.0, 1.5, 2.0, 2.2, 2.5, 2.9]  # [s] after 100.0
    for cmd, t in zip(script, times, strict=True):
        while clock.now + 0.06 < 100.0 + t:  # samples between the commands, at random times
            clock.now += rng.uniform(0.0, 0.06)
            samples.append((clock.now, {ch: emu.pulse(ch) for ch in (0, 1)}))
        clock.now = 100.0 + t
        ser.write(cmd + b"Q\r")  # answered once the command has run (STOP records nothing)
        assert ser.read(1) in (b"+", b".")
        samples.append((clock.now, {ch: emu.pulse(ch) for ch in (0, 1)}))
    clock.now += 1.0
    samples.append((clock.now, {ch: emu.pulse(ch) for ch in (0, 1)}))
    for ch in (0, 1):
        trace = emu.segments(ch)
        assert trace[0][0] == 100.0 and trace[-1][1] == clock.now
        for (_, a1, _, ap1), (b0, _, bp0, _) in itertools.pairwise(trace):
            assert b0 == a1 and bp0 == ap1, "the trace is continuous, jumps included"
        for t, pulses in samples:
            assert value_at(trace, t) == pytest.approx(pulses[ch], abs=1e-9), (ch, t)
    speeds = [(round(t0 - 100, 6), (p1 - p0) / (t1 - t0)) for t0, t1, p0, p1 in emu.segments(0) if t1 > t0]
    assert speeds[:4] == [(0.0, 0.0), (0.2, pytest.approx(1000.0)), (0.7, pytest.approx(-2000.0)), (0.95, 0.0)]
    jumps = [(round(t0 - 100, 6), p0, p1) for t0, t1, p0, p1 in emu.segments(0) if t1 == t0]
    assert jumps == [(0.0, 0.0, 1000.0), (2.0, 1000.0, 0.0), (2.2, 0.0, 1200.0), (2.9, 1300.0, 1500.0)]
    # ch1: 1500 -> 1000 in 1 s from 0.2; at 1.0 (1100) S400 toward 2000; stopped at 1.5 (1300); T300 to 1400
    speeds1 = [(round(t0 - 100, 6), (p1 - p0) / (t1 - t0)) for t0, t1, p0, p1 in emu.segments(1) if t1 > t0]
    assert speeds1 == [
        (0.0, 0.0),
        (0.2, pytest.approx(-500.0)),
        (1.0, pytest.approx(400.0)),
        (1.5, 0.0),
        (2.5, pytest.approx((1400 - 1300) / 0.3)),
        (2.8, 0.0),
    ]


def test_a_host_at_the_wrong_baud_rate_gets_nothing() -> None:
    with SSC32Emulator(baud=9600) as emu:  # the SSC-32U as shipped; the adapter's default is 115200
        with serial.Serial(emu.port, 115200, timeout=0.2) as ser:
            assert emu.host_baud() == 115200
            ser.write(b"#0P1500\rVER\r")
            assert ser.read_until(b"\r") == b""
            assert emu.history == [] and emu.errors
            assert all(e.endswith(" bytes sent at 115200 baud to a board at 9600>") for e in emu.errors)
            assert sum(int(e[1:].split()[0]) for e in emu.errors) == 12
        with serial.Serial(emu.port, 9600, timeout=1) as ser:
            send(ser, emu, b"#0P1500\r")
            ser.write(b"VER\r")
            assert ser.read_until(b"\r") == b"SSC32-V2.50USB\r"
            assert emu.pulses() == {0: 1500.0}


def test_qp_answers_the_pulse_of_the_frame_in_progress(fake: tuple[SSC32Emulator, serial.Serial, FakeClock]) -> None:
    """The board outputs a pulse every 20 ms (the guide) and QP answers its width: the
    interpolation at the frame's start (frames from the board's start, 100.0 here), up to a
    frame behind the output; a command received during a frame leaves that frame's pulse as it
    was; a jump shows at once. ``frame=0``: QP answers the interpolation itself."""
    emu, ser, clock = fake
    send(ser, emu, b"#0P1005\r")
    send(ser, emu, b"#0P2000T1000\r")  # 995 us/s from 100.0

    def qp() -> int:
        ser.write(b"QP0\r")
        return ser.read(1)[0]

    clock.now = 100.5
    assert qp() == 150  # 1502.5 us
    clock.now = 100.519  # the output at 1521.4 us, the frame's pulse at 1502.5
    assert emu.pulse(0) == pytest.approx(1521.405) and qp() == 150
    clock.now = 100.52
    assert qp() == 152
    clock.now = 100.53
    send(ser, emu, b"#0P1000S2000\r")  # turns back at 1532.35 us, 10 ms into the frame
    clock.now = 100.535
    assert emu.pulse(0) == pytest.approx(1522.35) and qp() == 152  # (the frame's: 1522.4 us at 100.52)
    clock.now = 100.54
    assert qp() == 151  # 1532.35 - 2000 us/s x 0.01 s
    clock.now = 100.545
    send(ser, emu, b"#0P1200\r")  # an immediate move: a jump
    assert qp() == 120
    send(ser, emu, b"#0P1300S1000\r")  # from 1200 us, in the same frame
    clock.now = 100.5595  # the output at 1214.5 us; the frame's pulse: 1200 (the jump)
    assert qp() == 120
    emu.frame = 0.0
    assert qp() == 121


def test_a_slow_host_holds_its_bytes_and_what_it_writes_meanwhile_goes_with_them() -> None:
    """``hold_input``: the first bytes written are held (here 15 ms), bytes written meanwhile go
    with them, then both cross the link; bytes written after the hold are held afresh;
    ``hold_input(0)`` ends it. Exact on a frozen clock."""
    clock = FakeClock()
    dt = byte_time(115200)
    a, b = b"#0P1500\r", b"#0P1600#1P1500\r"
    with SSC32Emulator(clock=clock) as emu, serial.Serial(emu.port, 115200, timeout=1) as ser:
        with pytest.raises(ValueError, match="shortest"):
            emu.hold_input(0.02, 0.01)
        emu.hold_input(0.015)
        ser.write(a)
        wait_for(lambda: emu.link_backlog() > 0)  # read at 100.0: held until 100.015
        assert emu.link_backlog() == pytest.approx(0.015 + len(a) * dt)
        clock.now = 100.005
        ser.write(b)
        wait_for(lambda: emu.link_backlog() > 0.010 + len(a) * dt + 1e-9)  # read at 100.005: with them
        assert emu.link_backlog() == pytest.approx(0.010 + (len(a) + len(b)) * dt)
        clock.now = 100.015 + len(a) * dt - 1e-9
        time.sleep(0.02)
        assert emu.history == []
        clock.now = 100.1
        wait_for(lambda: len(emu.history) == 2)
        assert emu.history[0].time == pytest.approx(100.015 + len(a) * dt, abs=1e-9)
        assert emu.history[1].time == pytest.approx(100.015 + (len(a) + len(b)) * dt, abs=1e-9)
        ser.write(a)  # after the hold: held afresh
        wait_for(lambda: len(emu.history) == 2 and emu.link_backlog() > 0)
        clock.now = 100.2
        wait_for(lambda: len(emu.history) == 3)
        assert emu.history[2].time == pytest.approx(100.115 + len(a) * dt, abs=1e-9)
        emu.hold_input(0.0)
        ser.write(a)
        wait_for(lambda: emu.link_backlog() > 0)
        assert emu.link_backlog() == pytest.approx(len(a) * dt)
        emu.hold_input(0.01, 0.02)  # a hold drawn evenly between the two
        clock.now = 101.0
        ser.write(a)
        wait_for(lambda: emu.link_backlog() > len(a) * dt + 1e-9)
        assert 0.01 <= emu.link_backlog() - len(a) * dt <= 0.02
