"""Pinocchio FK of every catalogue arm against the closed-form formulas of ROBOTS.md.

The formulas are written here from ROBOTS.md, independently of the URDFs and of
robots.geometry, so a wrong URDF number or axis shows up as a mismatch.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from armd import robots
from armd.errors import BadRequest

N = 3000
c, s = math.cos, math.sin


def insomniac(q: np.ndarray) -> np.ndarray:
    h0, L1, L2, L3 = 0.1473, 0.14605, 0.187325, 0.100
    q0, q1, q2, q3, _ = q
    rho = L1 * c(q1) + L2 * c(q1 + q2) + L3 * c(q1 + q2 + q3)
    z = h0 + L1 * s(q1) + L2 * s(q1 + q2) + L3 * s(q1 + q2 + q3)
    return np.array([rho * c(q0), rho * s(q0), z])


def sg5ut(q: np.ndarray) -> np.ndarray:
    a2, a3, a4 = 0.155, 0.123, 0.185
    q1, q2, q3, q4 = q
    r = a4 * c(q2 + q3 + q4) + a3 * c(q2 + q3) + a2 * c(q2)
    return np.array([c(q1) * r, s(q1) * r, a4 * s(q2 + q3 + q4) + a3 * s(q2 + q3) + a2 * s(q2)])


def sg5ut_dh(q: np.ndarray) -> np.ndarray:
    """The seed's DH chain itself: T = Rz(theta) Tz(d) Tx(a) Rx(alpha), product of four."""
    table = [(math.pi / 2, 0.0), (0.0, 0.155), (0.0, 0.123), (math.pi / 2, 0.185)]
    T = np.eye(4)
    for (alpha, a), th in zip(table, q, strict=True):
        A = np.array(
            [
                [c(th), -s(th) * c(alpha), s(th) * s(alpha), a * c(th)],
                [s(th), c(th) * c(alpha), -c(th) * s(alpha), a * s(th)],
                [0, s(alpha), c(alpha), 0],
                [0, 0, 0, 1],
            ]
        )
        T = T @ A
    return T[:3, 3]


def gupta3(q: np.ndarray) -> np.ndarray:
    d1, d2 = 0.150, 0.130
    q1, q2, q3 = q
    rho = d1 * c(q2) + d2 * c(q2 + q3)
    return np.array([rho * c(q1), rho * s(q1), d1 * s(q2) + d2 * s(q2 + q3)])


def desk4(q: np.ndarray) -> np.ndarray:
    h_leg, x_steer, y_steer, a2, a3, h0, v0 = 0.138, 0.012, 0.008, 0.135, 0.147, 0.060, 0.070
    q1, q2, q3 = q
    u = x_steer + a2 * c(q2) + a3 * c(q2 + q3) + h0
    v = y_steer
    z = h_leg + a2 * s(q2) + a3 * s(q2 + q3) - v0
    return np.array([c(q1) * u - s(q1) * v, s(q1) * u + c(q1) * v, z])


FORMULAS = {"insomniac": insomniac, "sg5ut": sg5ut, "gupta3": gupta3, "desk4": desk4}
PITCH_JOINTS = {"insomniac": [1, 2, 3], "sg5ut": [1, 2, 3], "gupta3": [1, 2], "desk4": []}


def random_in_limits(arm: robots.Robot, n: int, seed: int = 1) -> np.ndarray:
    rng = np.random.default_rng(seed)
    out = []
    while len(out) < n:
        q = rng.uniform(arm.limits.lower, arm.limits.upper, size=(n, arm.nq))
        out.extend(q[arm.limits.contains_batch(q)])
    return np.array(out[:n])


def test_catalogue_names() -> None:
    assert robots.names() == ["desk4", "gupta3", "insomniac", "sg5ut", "so101"]


@pytest.mark.parametrize("name", sorted(FORMULAS))
def test_fk_matches_closed_form(name: str) -> None:
    arm = robots.load(name)
    worst = max(float(np.max(np.abs(arm.fk(q) - FORMULAS[name](q)))) for q in random_in_limits(arm, N))
    assert worst < 1e-12, f"{name}: FK differs from ROBOTS.md by {worst:.3g} m"


def test_sg5ut_matches_the_seed_dh_table() -> None:
    arm = robots.load("sg5ut")
    for q in random_in_limits(arm, 500):
        assert np.max(np.abs(arm.fk(q) - sg5ut_dh(q))) < 1e-12


@pytest.mark.parametrize("name", sorted(FORMULAS))
def test_tool_pitch_is_sum_of_pitch_joints(name: str) -> None:
    arm = robots.load(name)
    for q in random_in_limits(arm, 500, seed=2):
        expected = sum(q[i] for i in PITCH_JOINTS[name])
        wrapped = math.remainder(arm.tool_pitch(q) - expected, 2 * math.pi)
        assert abs(wrapped) < 1e-12


@pytest.mark.parametrize("name", sorted(FORMULAS))
def test_geometry_parameters_describe_the_urdf(name: str) -> None:
    arm = robots.load(name)
    assert arm.geometry is not None
    for q in random_in_limits(arm, 500, seed=3):
        assert np.max(np.abs(arm.geometry.fk(q) - arm.fk(q))) < 1e-12


@pytest.mark.parametrize("name", sorted(FORMULAS))
def test_jacobian_matches_finite_differences(name: str) -> None:
    arm = robots.load(name)
    h = 1e-6
    for q in random_in_limits(arm, 50, seed=4):
        J = arm.jacobian(q)
        for k in range(arm.nq):
            dq = np.zeros(arm.nq)
            dq[k] = h
            fd = (arm.fk(q + dq) - arm.fk(q - dq)) / (2 * h)
            assert np.max(np.abs(J[:, k] - fd)) < 1e-8


def test_wrist_roll_does_not_move_the_tool_point() -> None:
    arm = robots.load("insomniac")
    q = arm.neutral.copy()
    p0 = arm.fk(q)
    q[4] = 1.2
    assert np.max(np.abs(arm.fk(q) - p0)) < 1e-15


def test_desk4_gripper_stays_level() -> None:
    arm = robots.load("desk4")
    for q in random_in_limits(arm, 200, seed=5):
        assert abs(arm.tool_pitch(q)) < 1e-12


def test_neutral_is_within_limits_and_actuator_ranges() -> None:
    for name in robots.names():
        arm = robots.load(name)
        assert arm.limits.contains(arm.neutral)
        arm.actuators.commands(arm.neutral)  # raises if any actuator leaves its range


def test_scanner_reading_is_seed_000_point() -> None:
    arm = robots.load("insomniac")
    p = arm.sensor_point("et_left", 0.3, math.radians(-20))
    # seed 000 eq. 5: sensor-frame point (D cos phi, D sin phi), then offset by the sensor's place
    assert np.allclose(p, [0.12 + 0.3 * c(math.radians(-20)), 0.10 + 0.3 * s(math.radians(-20)), 0.10], atol=1e-15)
    p = arm.sensor_point("et_right", 0.5, 0.4)
    assert np.allclose(p, [0.12 + 0.5 * c(0.4), -0.10 + 0.5 * s(0.4), 0.10], atol=1e-15)


def test_gripper_sensor_looks_along_the_tool_axis() -> None:
    arm = robots.load("insomniac")
    q = np.array([0.3, 1.2, -1.0, -0.9, 0.4])
    p = arm.sensor_point("gripper_et", 0.1, q=q)
    pitch = 1.2 - 1.0 - 0.9
    expected = insomniac(q) + 0.1 * np.array([c(pitch) * c(0.3), c(pitch) * s(0.3), s(pitch)])
    assert np.allclose(p, expected, atol=1e-12)


@pytest.mark.parametrize(
    ("sensor", "distance", "bearing", "field"),
    [
        ("et_left", 0.05, 0.0, "range"),  # below the GP2D12's 0.10 m
        ("et_left", 0.95, 0.0, "range"),
        ("et_left", float("nan"), 0.0, "range"),
        ("et_right", 0.3, float("inf"), "bearing"),
        ("nose", 0.3, 0.0, "sensor"),
    ],
)
def test_bad_sensor_readings(sensor: str, distance: float, bearing: float, field: str) -> None:
    arm = robots.load("insomniac")
    with pytest.raises(BadRequest) as e:
        arm.sensor_point(sensor, distance, bearing)
    assert e.value.field == field


def test_joint_vector_validation() -> None:
    arm = robots.load("gupta3")
    assert arm.joint_vector([0, 1, -1]).tolist() == [0.0, 1.0, -1.0]
    for bad in ([0, 1], [0, 1, float("nan")], "abc", [[0, 1, 2]], None, [0, "x", 1]):
        with pytest.raises(BadRequest):
            arm.joint_vector(bad)
