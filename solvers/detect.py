"""Objects found by the scanning range sensors (seed 000 sections 4 and 7): edges in each
sweep's range profile, kept when they stay put over repeated sweeps, placed in the base frame.

A scanner's sweep is its readings in one direction of its servo (one ``sweep`` count), in order
of bearing. An object is a run of readings in range (a reading out of range, or a jump of range
by more than ``JUMP``, ends it), of ``MIN_READINGS`` or more. Its edges lie between the run's end
readings and their neighbours out of it (half a step each way: the bearing resolution); a run
that reaches the sweep's end is cut there (``cut``: not the object's edge). The seed's test of a
stable object is that its edges are where they were on the sweep before: here, every one of
the last ``sweeps`` sweeps has it, its edges within ``EDGE_TOL`` steps and its range within
``RANGE_TOL``.

An object is taken as round (a can, the seed's test objects): seen at the nearest range ``d``
between edges ``2 delta`` apart, an upright cylinder's centre is ``D = d / (1 - sin delta)``
from the sensor along the middle bearing, and its radius ``D sin delta``: exact for a cylinder
and a beam that is a ray. ``uncertainty`` [m] is one standard deviation of the position: the
bearing's half step at that distance and the range's noise (the model's, through its curve).
An object seen by both scanners is given once, by the sensor whose sighting is the more certain.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from armd.robots import Robot
from armd.robots.types import FloatArray

JUMP = 0.03  # [m] a change of range between two readings this large parts two objects
MIN_READINGS = 2  # readings in range an object needs in a sweep
EDGE_TOL = 1.5  # [steps] how far an edge may move between sweeps for the object to be the same
RANGE_TOL = 0.02  # [m] ... and its range
SAME_OBJECT = 0.03  # [m] two sensors' objects nearer than this (and their uncertainties) are one


@dataclass(frozen=True)
class Sighting:
    """One object in one sweep of one scanner: its edges' bearings [rad], the nearest range [m]."""

    sensor: str
    sweep: int
    first: float
    last: float
    near: float
    readings: int
    cut: bool  # it reaches an end of the sweep (an edge not seen)


@dataclass(frozen=True)
class DetectedObject:
    """An object in the base frame: ``position`` (its centre, at the beam's height), ``surface``
    (the nearest point seen), ``width`` [m], ``uncertainty`` [m], the ``sensor`` that placed it
    (and every one that saw it), its edges' ``bearings``, the sweeps that saw it of those looked at,
    whether it is ``stable``."""

    position: FloatArray
    surface: FloatArray
    width: float
    uncertainty: float
    sensor: str
    sensors: tuple[str, ...]
    bearings: tuple[float, float]
    range: float
    seen: int
    sweeps: int
    stable: bool
    cut: bool

    def to_dict(self) -> dict[str, Any]:
        return {
            "position": [round(float(x), 5) for x in self.position],
            "surface": [round(float(x), 5) for x in self.surface],
            "width": round(self.width, 5),
            "uncertainty": round(self.uncertainty, 5),
            "sensor": self.sensor,
            "sensors": list(self.sensors),
            "bearings": [round(b, 5) for b in self.bearings],
            "range": round(self.range, 5),
            "seen": self.seen,
            "sweeps": self.sweeps,
            "stable": self.stable,
            "cut": self.cut,
        }


def sightings(sensor: str, sweep: int, readings: Sequence[Mapping[str, Any]], step: float) -> list[Sighting]:
    """The objects of one sweep (its readings: ``bearing`` [rad], ``range`` [m] or None)."""
    rs = sorted(readings, key=lambda r: float(r["bearing"]))
    out: list[Sighting] = []
    run: list[int] = []

    def close(run: list[int]) -> None:
        if len(run) < MIN_READINGS:
            return
        a, b = run[0], run[-1]
        first = (float(rs[a - 1]["bearing"]) + float(rs[a]["bearing"])) / 2 if a > 0 else float(rs[a]["bearing"])
        last = (
            (float(rs[b]["bearing"]) + float(rs[b + 1]["bearing"])) / 2 if b < len(rs) - 1 else float(rs[b]["bearing"])
        )
        near = min(float(rs[i]["range"]) for i in run)
        out.append(Sighting(sensor, sweep, first, last, near, len(run), a == 0 or b == len(rs) - 1))

    for i, r in enumerate(rs):
        if r["range"] is None:
            close(run)
            run = []
            continue
        if run and abs(float(r["range"]) - float(rs[run[-1]]["range"])) > JUMP:
            close(run)
            run = []
        run.append(i)
    close(run)
    return out


def _same(a: Sighting, b: Sighting, step: float) -> bool:
    return (
        abs(a.first - b.first) <= EDGE_TOL * step
        and abs(a.last - b.last) <= EDGE_TOL * step
        and abs(a.near - b.near) <= RANGE_TOL
    )


def detect(robot: Robot, sweeps: Mapping[str, Sequence[Sequence[Mapping[str, Any]]]]) -> list[DetectedObject]:
    """The objects ``robot``'s scanners see in ``sweeps`` (per sensor: its last complete sweeps,
    oldest first, each a list of readings), nearest first."""
    found: list[DetectedObject] = []
    for name, its in sweeps.items():
        if not its:
            continue
        s = robot.sensors[name]
        curve = s.curve
        step = s.sweep_step
        per = [sightings(name, k, sw, step) for k, sw in enumerate(its)]
        for newest in per[-1]:
            matched = [newest]
            for older in per[:-1]:
                twin = next((o for o in older if _same(o, newest, step)), None)
                if twin is not None:
                    matched.append(twin)
            first = float(np.mean([m.first for m in matched]))
            last = float(np.mean([m.last for m in matched]))
            near = float(np.mean([m.near for m in matched]))
            half = max((last - first) / 2, 0.0)
            sin_half = math.sin(min(half, math.pi / 2 - 1e-6))
            centre = near / (1.0 - sin_half)
            mid = (first + last) / 2
            origin, u = robot.sensor_ray(name, mid)
            # one sigma: the bearing's half step at that distance, and the range's noise through the curve
            sigma_range = 0.0
            if curve is not None:
                a, b = curve.ab
                v = a / (near + b)
                sigma_range = a / v**2 * curve.noise_volts / math.sqrt(len(matched))
            uncertainty = math.hypot(centre * step / 2, sigma_range)
            cut = any(m.cut for m in matched)
            found.append(
                DetectedObject(
                    position=origin + centre * u,
                    surface=origin + near * u,
                    width=2 * centre * sin_half,
                    uncertainty=uncertainty,
                    sensor=name,
                    sensors=(name,),
                    bearings=(first, last),
                    range=near,
                    seen=len(matched),
                    sweeps=len(its),
                    stable=len(matched) == len(its) and not cut,
                    cut=cut,
                )
            )
    # one object seen by two scanners: given once, by the more certain sighting (stable first)
    found.sort(key=lambda o: (not o.stable, o.uncertainty))
    merged: list[DetectedObject] = []
    for o in found:
        k = next(
            (
                i
                for i, m in enumerate(merged)
                if np.linalg.norm((m.position - o.position)[:2])
                <= max(SAME_OBJECT, 3 * (m.uncertainty + o.uncertainty))
            ),
            None,
        )
        if k is None:
            merged.append(o)
        elif o.sensor not in merged[k].sensors:
            merged[k] = dataclasses.replace(merged[k], sensors=(*merged[k].sensors, o.sensor))
    merged.sort(key=lambda o: float(np.linalg.norm(o.position[:2])))
    return merged
