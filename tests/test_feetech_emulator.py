"""The Feetech STS3215 emulator, driven through the vendor's SDK (``feetech-servo-sdk``, imported
as ``scservo_sdk``) on its pseudo-terminal, as a program drives a real bus."""

from __future__ import annotations

import time
from collections.abc import Iterator

import pytest
import serial

from armd.adapters.emulators.feetech import (
    GOAL_POSITION,
    MODEL_STS3215,
    OVERLOAD_ERROR,
    FeetechEmulator,
    checksum,
    packet,
)

sdk = pytest.importorskip("scservo_sdk")  # (the hardware extra: installed by the README's test command)

TORQUE, ACCEL, GOAL_SPEED, LOCK, ID, OFFSET, PRESENT = 40, 41, 46, 55, 5, 31, 56


@pytest.fixture()
def bus() -> Iterator[tuple[FeetechEmulator, object, object]]:
    with FeetechEmulator([1, 2, 3]) as emu:
        port = sdk.PortHandler(emu.port)
        assert port.openPort() and port.setBaudRate(1_000_000)
        try:
            yield emu, port, sdk.PacketHandler(0)
        finally:
            port.closePort()


def test_the_checksum_is_the_manuals() -> None:
    # the manual's example: ping servo 1, FF FF 01 02 01 FB
    assert packet(1, 0x01) == bytes.fromhex("ff ff 01 02 01 fb")
    assert checksum(bytes([1, 2, 1])) == 0xFB


def test_ping_read_write_through_the_sdk(bus: tuple[FeetechEmulator, object, object]) -> None:
    emu, port, ph = bus
    for i in (1, 2, 3):
        model, result, error = ph.ping(port, i)  # type: ignore[attr-defined]
        assert (model, result, error) == (MODEL_STS3215, sdk.COMM_SUCCESS, 0)
    model, result, _ = ph.ping(port, 9)  # type: ignore[attr-defined]
    assert result == sdk.COMM_RX_TIMEOUT  # nobody there: no answer at all
    assert ph.read2ByteTxRx(port, 2, PRESENT)[:2] == (2048, sdk.COMM_SUCCESS)  # type: ignore[attr-defined]
    assert ph.write2ByteTxRx(port, 2, GOAL_POSITION, 2500) == (sdk.COMM_SUCCESS, 0)  # type: ignore[attr-defined]
    time.sleep(0.3)
    assert emu.position(2) == 2048  # torque off: the goal is kept, nothing moves
    assert ph.write1ByteTxRx(port, 2, TORQUE, 1) == (sdk.COMM_SUCCESS, 0)  # type: ignore[attr-defined]
    time.sleep(0.5)
    assert abs(emu.position(2) - 2500) <= 1


def test_a_servo_moves_within_the_speed_and_acceleration_it_is_given(
    bus: tuple[FeetechEmulator, object, object],
) -> None:
    emu, port, ph = bus
    ph.write1ByteTxRx(port, 1, ACCEL, 20)  # type: ignore[attr-defined]  # 2000 counts/s^2
    ph.write2ByteTxRx(port, 1, GOAL_SPEED, 800)  # type: ignore[attr-defined]  # counts/s
    ph.write2ByteTxRx(port, 1, GOAL_POSITION, 3500)  # type: ignore[attr-defined]
    ph.write1ByteTxRx(port, 1, TORQUE, 1)  # type: ignore[attr-defined]
    time.sleep(2.5)
    trace = emu.trace(1)
    t = [a for a, _ in trace]
    p = [b for _, b in trace]
    v = [(p[k + 1] - p[k]) / (t[k + 1] - t[k]) for k in range(len(p) - 1)]
    a = [(v[k + 1] - v[k]) / (t[k + 1] - t[k]) for k in range(len(v) - 1)]
    assert max(v) <= 800 * (1 + 1e-6) and max(v) > 790  # it reaches the speed it was given, never more
    assert max(abs(x) for x in a) <= 2000 * 1.001
    assert abs(p[-1] - 3500) < 1


def test_sync_read_answers_in_the_order_asked_and_sync_write_moves_them_all(
    bus: tuple[FeetechEmulator, object, object],
) -> None:
    emu, port, ph = bus
    w = sdk.GroupSyncWrite(port, ph, GOAL_POSITION, 2)
    for i, goal in ((1, 1000), (2, 3000), (3, 2100)):
        w.addParam(i, [goal & 0xFF, goal >> 8])
    assert w.txPacket() == sdk.COMM_SUCCESS
    for i in (1, 2, 3):
        ph.write1ByteTxRx(port, i, TORQUE, 1)  # type: ignore[attr-defined]
    time.sleep(1.0)
    r = sdk.GroupSyncRead(port, ph, PRESENT, 2)
    for i in (3, 1, 2):
        r.addParam(i)
    assert r.txRxPacket() == sdk.COMM_SUCCESS
    assert [r.getData(i, PRESENT, 2) for i in (1, 2, 3)] == [1000, 3000, 2100]
    order = [i for _, i, inst in emu.instructions if inst == 0x82]
    assert order == [0xFE]  # one broadcast instruction; the replies came 3, 1, 2 (the SDK reads them so)


def test_the_link_runs_at_the_bus_rate() -> None:
    """A sync read of 6 servos' 10 bytes: 13 bytes out, 6 x 16 back: at 115200 baud that is
    9.5 ms of bits; at 1 Mbaud about 1.1 ms."""
    for baud, least in ((115_200, (13 + 96) * 10 / 115_200), (1_000_000, (13 + 96) * 10 / 1_000_000)):
        with FeetechEmulator([1, 2, 3, 4, 5, 6], baud=baud) as emu:
            port = sdk.PortHandler(emu.port)
            assert port.openPort() and port.setBaudRate(baud)
            ph = sdk.PacketHandler(0)
            r = sdk.GroupSyncRead(port, ph, PRESENT, 10)
            for i in range(1, 7):
                r.addParam(i)
            times = []
            for _ in range(20):
                t = time.perf_counter()
                assert r.txRxPacket() == sdk.COMM_SUCCESS
                times.append(time.perf_counter() - t)
            port.closePort()
            assert min(times) >= least, (baud, min(times), least)


def test_a_bad_checksum_is_ignored_and_recorded(bus: tuple[FeetechEmulator, object, object]) -> None:
    emu, _port, _ = bus
    bad = bytearray(packet(1, 0x03, bytes([GOAL_POSITION, 0x00, 0x01])))
    bad[-1] ^= 0xFF
    with serial.Serial(emu.port, 1_000_000, timeout=0.05) as ser:
        ser.write(bytes(bad))
        assert ser.read(6) == b""  # no answer
    assert any("checksum" in e for e in emu.errors)
    assert emu.register(1, GOAL_POSITION, 2) == 2048  # nothing written


def test_the_eeprom_is_locked_until_unlocked_and_an_id_can_be_changed(
    bus: tuple[FeetechEmulator, object, object],
) -> None:
    emu, port, ph = bus
    assert ph.write1ByteTxRx(port, 3, ID, 7) == (sdk.COMM_SUCCESS, 0)  # type: ignore[attr-defined]  # locked: ignored
    assert ph.ping(port, 3)[1] == sdk.COMM_SUCCESS  # type: ignore[attr-defined]
    ph.write1ByteTxRx(port, 3, LOCK, 0)  # type: ignore[attr-defined]
    ph.write1ByteTxRx(port, 3, ID, 7)  # type: ignore[attr-defined]  # (the status comes from the servo's new id)
    assert ph.ping(port, 7)[1] == sdk.COMM_SUCCESS  # type: ignore[attr-defined]
    assert ph.ping(port, 3)[1] != sdk.COMM_SUCCESS  # type: ignore[attr-defined]
    emu.power_cycle()
    assert ph.ping(port, 7)[1] == sdk.COMM_SUCCESS  # type: ignore[attr-defined]  # the EEPROM kept it


def test_an_offset_moves_what_the_servo_reports(bus: tuple[FeetechEmulator, object, object]) -> None:
    _emu, port, ph = bus
    ph.write1ByteTxRx(port, 1, LOCK, 0)  # type: ignore[attr-defined]
    ph.write2ByteTxRx(port, 1, OFFSET, 100)  # type: ignore[attr-defined]
    assert ph.read2ByteTxRx(port, 1, PRESENT)[0] == 2048 - 100  # type: ignore[attr-defined]
    ph.write2ByteTxRx(port, 1, OFFSET, (1 << 11) | 100)  # type: ignore[attr-defined]  # -100: sign in bit 11
    assert ph.read2ByteTxRx(port, 1, PRESENT)[0] == 2048 + 100  # type: ignore[attr-defined]


def test_a_servo_held_against_its_goal_overloads_and_lets_go(bus: tuple[FeetechEmulator, object, object]) -> None:
    emu, port, ph = bus
    ph.write1ByteTxRx(port, 1, 35, 30)  # type: ignore[attr-defined]  # (locked: the factory's 2 s stays)
    emu.hold(1, 2100.0)
    ph.write2ByteTxRx(port, 1, GOAL_POSITION, 3000)  # type: ignore[attr-defined]
    ph.write1ByteTxRx(port, 1, TORQUE, 1)  # type: ignore[attr-defined]
    time.sleep(1.0)
    _, _, error = ph.read2ByteTxRx(port, 1, PRESENT)  # type: ignore[attr-defined]
    assert error == 0 and abs(emu.position(1) - 2100) < 1  # stopped by what is in the way, loaded, not yet overloaded
    time.sleep(1.3)
    _, _, error = ph.read2ByteTxRx(port, 1, PRESENT)  # type: ignore[attr-defined]
    assert error & OVERLOAD_ERROR
    assert ph.read1ByteTxRx(port, 1, TORQUE)[0] == 0  # type: ignore[attr-defined]  # it let go
    emu.hold(1, None)
    ph.write1ByteTxRx(port, 1, TORQUE, 1)  # type: ignore[attr-defined]  # enabled again: the alarm clears
    assert ph.read2ByteTxRx(port, 1, PRESENT)[2] == 0  # type: ignore[attr-defined]


def test_lost_replies_and_a_silent_servo(bus: tuple[FeetechEmulator, object, object]) -> None:
    emu, port, ph = bus
    emu.drop_replies(2, 1)
    assert ph.ping(port, 2)[1] == sdk.COMM_RX_TIMEOUT  # type: ignore[attr-defined]
    assert ph.ping(port, 2)[1] == sdk.COMM_SUCCESS  # type: ignore[attr-defined]
    emu.silence(2)
    assert ph.ping(port, 2)[1] == sdk.COMM_RX_TIMEOUT  # type: ignore[attr-defined]
    assert ph.write1ByteTxRx(port, 2, TORQUE, 1)[0] == sdk.COMM_RX_TIMEOUT  # type: ignore[attr-defined]
    assert ph.read1ByteTxRx(port, 2, TORQUE)[1] == sdk.COMM_RX_TIMEOUT  # type: ignore[attr-defined]
    emu.silence(2, False)
    assert ph.read1ByteTxRx(port, 2, TORQUE)[0] == 0  # type: ignore[attr-defined]  # it never heard the write


def test_voltage_and_temperature_alarms(bus: tuple[FeetechEmulator, object, object]) -> None:
    emu, port, ph = bus
    emu.set_temperature(3, 75.0)
    assert ph.read1ByteTxRx(port, 3, 63)[0] == 75 and ph.ping(port, 3)[2] & 4  # type: ignore[attr-defined]
    emu.set_voltage(3.5)
    assert ph.read1ByteTxRx(port, 1, 62)[0] == 35 and ph.ping(port, 1)[2] & 1  # type: ignore[attr-defined]
