"""The SSC-32 emulator, driven through pyserial on its pseudo-terminal, as an adapter drives the board."""

from __future__ import annotations

import signal
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest
import serial

from clients.emulators.ssc32 import GroupMove, SSC32Emulator


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
    clock = FakeClock()
    with SSC32Emulator(clock=clock) as e, serial.Serial(e.port, 115200, timeout=1) as s:
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
    send(ser, emu, b"#2P1700\n")
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
    proc = subprocess.Popen([sys.executable, "-m", "clients.emulators.ssc32"], cwd=root, text=True,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE)
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
