"""The Dynamixel X-series emulator (Protocol 2.0), driven through ROBOTIS's SDK
(``dynamixel-sdk``) on its pseudo-terminal, as a program drives a U2D2."""

from __future__ import annotations

import time
from collections.abc import Iterator

import pytest
import serial

from armd.adapters.emulators.dynamixel import (
    GOAL_POSITION,
    HARDWARE_ERROR,
    MODEL_XM430_W350,
    PRESENT_POSITION,
    PRESENT_VOLTAGE,
    PROFILE_VELOCITY,
    TORQUE,
    DynamixelEmulator,
    crc16,
    packet,
    stuff,
    unstuff,
)

sdk = pytest.importorskip("dynamixel_sdk")


@pytest.fixture()
def bus() -> Iterator[tuple[DynamixelEmulator, object, object]]:
    with DynamixelEmulator([1, 2, 3]) as emu:
        port = sdk.PortHandler(emu.port)
        assert port.openPort() and port.setBaudRate(1_000_000)
        try:
            yield emu, port, sdk.PacketHandler(2.0)
        finally:
            port.closePort()


def test_the_crc_and_the_stuffing_are_the_manuals() -> None:
    # the e-Manual's ping of id 1: FF FF FD 00 01 03 00 01 19 4E
    assert packet(1, 0x01) == bytes.fromhex("ff ff fd 00 01 03 00 01 19 4e")
    assert crc16(bytes.fromhex("ff ff fd 00 01 03 00 01")) == 0x4E19
    assert stuff(bytes.fromhex("01 ff ff fd 02")) == bytes.fromhex("01 ff ff fd fd 02")
    assert unstuff(bytes.fromhex("01 ff ff fd fd 02")) == bytes.fromhex("01 ff ff fd 02")


def test_ping_read_write_through_the_sdk(bus: tuple[DynamixelEmulator, object, object]) -> None:
    _emu, port, ph = bus
    for i in (1, 2, 3):
        assert ph.ping(port, i) == (MODEL_XM430_W350, sdk.COMM_SUCCESS, 0)  # type: ignore[attr-defined]
    assert ph.ping(port, 9)[1] == sdk.COMM_RX_TIMEOUT  # type: ignore[attr-defined]
    assert ph.read4ByteTxRx(port, 1, PRESENT_POSITION) == (2048, sdk.COMM_SUCCESS, 0)  # type: ignore[attr-defined]
    assert ph.write4ByteTxRx(port, 1, GOAL_POSITION, 3000) == (sdk.COMM_SUCCESS, 0)  # type: ignore[attr-defined]
    assert ph.write1ByteTxRx(port, 1, TORQUE, 1) == (sdk.COMM_SUCCESS, 0)  # type: ignore[attr-defined]
    time.sleep(0.6)
    assert ph.read4ByteTxRx(port, 1, PRESENT_POSITION)[0] == 3000  # type: ignore[attr-defined]


def test_the_eeprom_is_locked_while_the_torque_is_on(bus: tuple[DynamixelEmulator, object, object]) -> None:
    _emu, port, ph = bus
    ph.write1ByteTxRx(port, 2, TORQUE, 1)  # type: ignore[attr-defined]
    assert ph.write1ByteTxRx(port, 2, 7, 9) == (sdk.COMM_SUCCESS, 7)  # type: ignore[attr-defined]  # access error
    assert ph.write4ByteTxRx(port, 2, PRESENT_POSITION, 5) == (sdk.COMM_SUCCESS, 7)  # type: ignore[attr-defined]
    ph.write1ByteTxRx(port, 2, TORQUE, 0)  # type: ignore[attr-defined]
    # written: the status comes from id 9, which the SDK, waiting for id 2's, does not take
    assert ph.write1ByteTxRx(port, 2, 7, 9)[0] == sdk.COMM_RX_TIMEOUT  # type: ignore[attr-defined]
    assert ph.ping(port, 9)[1] == sdk.COMM_SUCCESS  # type: ignore[attr-defined]


def test_a_bad_crc_is_answered_with_the_crc_error(bus: tuple[DynamixelEmulator, object, object]) -> None:
    emu, _port, _ = bus
    bad = bytearray(packet(1, 0x03, bytes([TORQUE, 0, 1])))
    bad[-1] ^= 0xFF
    with serial.Serial(emu.port, 1_000_000, timeout=0.05) as ser:
        ser.write(bytes(bad))
        reply = ser.read(11)
    assert reply[7] == 0x55 and reply[8] == 3  # a status: CRC error
    assert emu.register(1, TORQUE) == 0


def test_sync_write_and_sync_read(bus: tuple[DynamixelEmulator, object, object]) -> None:
    _emu, port, ph = bus
    w = sdk.GroupSyncWrite(port, ph, PROFILE_VELOCITY, 8)
    for i, goal in ((1, 1000), (2, 3000), (3, 2100)):
        w.addParam(i, [*(200).to_bytes(4, "little"), *goal.to_bytes(4, "little")])
    assert w.txPacket() == sdk.COMM_SUCCESS
    for i in (1, 2, 3):
        ph.write1ByteTxRx(port, i, TORQUE, 1)  # type: ignore[attr-defined]
    time.sleep(1.0)
    r = sdk.GroupSyncRead(port, ph, PRESENT_POSITION, 4)
    for i in (1, 2, 3):
        r.addParam(i)
    assert r.txRxPacket() == sdk.COMM_SUCCESS
    assert [r.getData(i, PRESENT_POSITION, 4) for i in (1, 2, 3)] == [1000, 3000, 2100]


def test_an_overload_turns_the_torque_off_until_a_reboot(bus: tuple[DynamixelEmulator, object, object]) -> None:
    emu, port, ph = bus
    emu.hold(1, 2100.0)
    ph.write4ByteTxRx(port, 1, GOAL_POSITION, 3000)  # type: ignore[attr-defined]
    ph.write1ByteTxRx(port, 1, TORQUE, 1)  # type: ignore[attr-defined]
    time.sleep(1.4)
    _, _result, error = ph.read1ByteTxRx(port, 1, TORQUE)  # type: ignore[attr-defined]
    assert error & 0x80  # the alert bit
    assert ph.read1ByteTxRx(port, 1, HARDWARE_ERROR)[0] & 32  # type: ignore[attr-defined]  # overload
    assert emu.register(1, TORQUE) == 0
    assert ph.write1ByteTxRx(port, 1, TORQUE, 1)[1] & 0x7F == 7  # type: ignore[attr-defined]  # not until a reboot
    emu.hold(1, None)
    assert ph.reboot(port, 1)[0] == sdk.COMM_SUCCESS  # type: ignore[attr-defined]
    assert ph.write1ByteTxRx(port, 1, TORQUE, 1) == (sdk.COMM_SUCCESS, 0)  # type: ignore[attr-defined]


def test_a_silent_servo_and_a_lost_reply(bus: tuple[DynamixelEmulator, object, object]) -> None:
    emu, port, ph = bus
    emu.drop_replies(3, 1)
    assert ph.ping(port, 3)[1] == sdk.COMM_RX_TIMEOUT  # type: ignore[attr-defined]
    assert ph.ping(port, 3)[1] == sdk.COMM_SUCCESS  # type: ignore[attr-defined]
    emu.silence(3)
    assert ph.ping(port, 3)[1] == sdk.COMM_RX_TIMEOUT  # type: ignore[attr-defined]
    emu.drop_replies(2, 1, after=1)  # (the next reply goes through, the one after is lost)
    assert [ph.ping(port, 2)[1] for _ in range(3)] == [sdk.COMM_SUCCESS, sdk.COMM_RX_TIMEOUT, sdk.COMM_SUCCESS]  # type: ignore[attr-defined]


def test_a_power_cycle_keeps_the_supplys_voltage_and_the_horns_place(
    bus: tuple[DynamixelEmulator, object, object],
) -> None:
    """Off and on: the RAM at its defaults (torque off), the supply's voltage what it was."""
    emu, port, ph = bus
    emu.set_voltage(11.1)
    assert ph.write1ByteTxRx(port, 1, TORQUE, 1) == (sdk.COMM_SUCCESS, 0)  # type: ignore[attr-defined]
    emu.power_cycle()
    assert ph.read1ByteTxRx(port, 1, TORQUE)[0] == 0  # type: ignore[attr-defined]
    assert ph.read2ByteTxRx(port, 1, PRESENT_VOLTAGE)[0] == 111  # type: ignore[attr-defined]
    assert ph.read4ByteTxRx(port, 1, PRESENT_POSITION)[0] == 2048  # type: ignore[attr-defined]
