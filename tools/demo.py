"""``armd demo``: the service with simulated arms, and a scripted client session on every arm.

It opens a Zenoh router in this process on a free loopback port (so it never collides with
a running ``armd serve``), starts the service and one simulated arm per catalogue arm, then,
as any client would, over Zenoh: IK with each approach mode, an unreachable target, a joint
move, a Cartesian line move and a stop in the middle of a move. It prints one table row per
request (target, status, error, round-trip time) and writes a trajectory plot of every move
and a workspace map of every arm to a folder it names. On the insomniac it then plays seed
000's scenario (:mod:`.seed000`): a can on its floor, found by its scanners, picked up and put
down on its left, the can's final place read off the simulator's floor.

Targets are chosen for each arm from its own workspace (the batch IK's reachability at a few
candidate points), so the script needs no numbers of any particular arm.
"""

from __future__ import annotations

import json
import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from armd import robots, solvers
from armd.clients import ArmClient, TrajectoryReply
from armd.errors import BadRequest, ServiceError, UnknownRobot
from armd.planning.clearance import clear_move
from armd.robots import Robot

from .plot import plot_reply


@dataclass
class Row:
    arm: str
    case: str
    request: str
    status: str
    error_m: float | None
    ms: float
    note: str = ""


def _fmt(v: object) -> str:
    if isinstance(v, (list, tuple, np.ndarray)):
        return "[" + ", ".join(f"{float(x):.3f}" for x in v) + "]"
    return str(v)


def _frame(arm: Robot) -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
    """The arm's yaw axis (a point of it), outward and sideways directions at the neutral pose
    (horizontal, unit) and its horizontal reach there [m]."""
    home = arm.fk(arm.neutral)
    axis = np.array([*arm.geometry.base, 0.0]) if arm.geometry is not None else np.zeros(3)
    out = (home - axis) * np.array([1.0, 1.0, 0.0])
    reach = float(np.linalg.norm(out))
    outward = out / reach if reach > 1e-6 else np.array([1.0, 0.0, 0.0])
    return axis, outward, np.array([-outward[1], outward[0], 0.0]), reach or 0.2


def _candidates(arm: Robot) -> np.ndarray:
    """Points in front of the arm, nearest the neutral tool point first."""
    home = arm.fk(arm.neutral)
    axis, outward, side, reach = _frame(arm)
    lateral = float((home - axis) @ side)
    us = np.linspace(0.2 * reach, 1.2 * reach, 30)
    zs = np.linspace(home[2] - 1.5 * reach, home[2] + 0.5 * reach, 40)
    U, Z = np.meshgrid(us, zs)
    pts = axis + np.outer(U.ravel(), outward) + (lateral + 0.03) * side
    pts[:, 2] = Z.ravel()
    return pts[np.argsort(np.linalg.norm(pts - home, axis=1))]


def _target(arm: Robot, approach: object) -> list[float] | None:
    """A point the arm reaches with ``approach``, near its neutral tool point (None: no such point,
    or an approach this arm cannot take: the service will say so)."""
    pts = _candidates(arm)
    try:
        ok = solvers.reachable(arm, pts, approach=approach)
    except BadRequest:
        return None
    return [round(float(x), 4) for x in pts[np.argmax(ok)]] if ok.any() else None


class Demo:
    def __init__(self, client: ArmClient, out: Path, rows: list[Row], echo: Callable[[Row], None]) -> None:
        self.client, self.out, self.rows, self.echo = client, out, rows, echo

    def record(self, row: Row) -> None:
        self.rows.append(row)
        self.echo(row)

    def timed(self, arm: str, case: str, request: str, call: Callable[[], Any]) -> tuple[Any, float] | None:
        t0 = time.perf_counter()
        try:
            result = call()
        except ServiceError as e:
            self.record(Row(arm, case, request, e.code, None, 1000 * (time.perf_counter() - t0), e.message))
            return None
        return result, 1000 * (time.perf_counter() - t0)

    def ik(self, arm: Robot, case: str, target: list[float], approach: object) -> None:
        got = self.timed(arm.name, case, _fmt(target), lambda: self.client.ik(arm.name, target, approach=approach))
        if got is not None:
            r, ms = got
            note = r.reason or f"branch {r.branch}, pitch {math.degrees(r.pitch):.1f} deg"
            self.record(Row(arm.name, case, _fmt(target), r.status, r.position_error, ms, note))

    def move(self, arm: Robot, case: str, goal: object, path: str, shown: str) -> bool:
        """Plan (plotted), then move and wait until the arm is still at the goal."""
        c = self.client
        got = self.timed(arm.name, case, shown, lambda: c.plan(arm.name, goal, path=path))
        if got is None:
            return False
        plan, _ = got
        assert isinstance(plan, TrajectoryReply)
        png = self.out / f"{arm.name}-{case.replace(' ', '-')}.png"
        plot_reply(c, arm.name, plan, png)
        got = self.timed(arm.name, case, shown, lambda: c.move(arm.name, goal, path=path))
        if got is None:
            return False
        mv, ms = got
        state = c.wait_until_still(arm.name, mv.goal, timeout=mv.duration + 10.0)
        reached = c.fk(arm.name, state["position"]).position
        error = float(np.linalg.norm(reached - np.asarray(goal["target"]))) if isinstance(goal, dict) else None
        self.record(Row(arm.name, case, shown, "done", error, ms, f"{mv.duration:.2f} s trajectory, plot {png.name}"))
        return True

    def stop(self, arm: Robot) -> None:
        c = self.client
        lim = arm.limits
        here = np.array(c.state(arm.name)["position"])
        far = np.where(np.abs(lim.upper - here) > np.abs(lim.lower - here), lim.upper, lim.lower)
        goal = here  # a long joint move toward the far limits, as far as the coupled limits allow
        for fraction in (0.8, 0.6, 0.4, 0.2, 0.1):  # ... and the arm's world (a move from rest is straight)
            q = here + fraction * (far - here)
            if lim.contains(q) and clear_move(arm, here, q):
                goal = q
                break
        got = self.timed(arm.name, "stop", "mid-move", lambda: c.move(arm.name, goal.tolist()))
        if got is None:
            return
        mv, _ = got
        time.sleep(min(0.4, mv.duration / 3))
        got = self.timed(arm.name, "stop", "mid-move", lambda: c.stop(arm.name))
        if got is None:
            return
        r, ms = got
        state = c.wait_until_still(arm.name, timeout=float(r["duration"]) + 10.0)
        short = float(np.max(np.abs(np.array(state["position"]) - goal)))
        self.record(
            Row(
                arm.name,
                "stop",
                "mid-move",
                "stopped",
                None,
                ms,
                f"at rest {r['duration']:.2f} s later, {math.degrees(short):.0f} deg short of the goal",
            )
        )

    def run(self, arm: Robot, workspace_step: float) -> None:
        for approach in ("parallel", "perpendicular", "free"):
            target = _target(arm, approach) or _target(arm, None)
            assert target is not None
            self.ik(arm, f"ik {approach}", target, approach)
        home = arm.fk(arm.neutral)
        _, outward, _, reach = _frame(arm)
        far = [round(float(v), 3) for v in home + (1.5 * reach + 0.3) * outward]
        self.ik(arm, "ik unreachable", far, None)
        target = _target(arm, None)
        assert target is not None
        if self.move(arm, "joint move", {"target": target, "approach": None}, "joint", _fmt(target)):
            for dx, dz in ((-0.04, 0.0), (0.0, -0.04), (0.0, 0.04), (0.04, 0.0)):
                end = [round(target[0] + dx, 4), target[1], round(target[2] + dz, 4)]
                try:
                    self.client.plan(arm.name, {"target": end}, path="line")
                except ServiceError:
                    continue  # this line leaves the reachable space: try another direction
                self.move(arm, "line move", {"target": end}, "line", _fmt(end))
                break
        self.stop(arm)
        from armd.tools import workspace

        ws = workspace.compute(arm, step=workspace_step, heights=8)
        png = self.out / f"{arm.name}-workspace.png"
        workspace.plot(ws, arm, png)


def print_row(row: Row) -> None:
    err = "" if row.error_m is None else f"{row.error_m:.1e}"
    print(
        f"{row.arm:<10} {row.case:<16} {row.request:<26} {row.status:<12} {err:>8} {row.ms:8.1f}  {row.note}",
        flush=True,
    )


def _seed000(client: ArmClient, sim: Any, demo: Demo, say: Callable[[str], None]) -> None:
    """Seed 000's scenario (:mod:`.seed000`) on the simulated insomniac: a row for what the
    sensors found (its error: from where the can is), the pick and the place (its error: the
    can's place from where it was asked to go, read off the simulator's floor)."""
    from . import seed000

    started = time.perf_counter()
    r = seed000.run(client, say)
    ms = (time.perf_counter() - started) * 1000
    found = r["found"]
    truth = np.array(seed000.CAN["position"], dtype=float)
    err = float(np.linalg.norm(np.array(found["position"][:2]) - truth))
    arm = seed000.ROBOT
    demo.record(
        Row(arm, "seed000 detect", _fmt(found["position"]), "stable", err, ms, f"+- {found['uncertainty']:.4f} m")
    )
    pick = r["pick"]
    demo.record(Row(arm, "seed000 pick", _fmt(pick["target"]), "done" if pick["done"] else "stopped", None, ms))
    place = r["place"]
    (can,) = [o for o in sim.sensors.objects if o.name == seed000.CAN["name"]]
    put = float(np.linalg.norm(np.array(can.position) - np.array(r["put_at"])))
    status = "done" if place is not None and place["done"] and can.z == 0.0 else "stopped"
    demo.record(Row(arm, "seed000 place", _fmt(r["put_at"]), status, put, ms, "the can, on the floor"))


def run(
    names: Sequence[str],
    out: Path,
    *,
    time_scale: float = 2.0,
    workspace_step: float = 0.008,
    echo: Callable[[Row], None] = print_row,
    say: Callable[[str], None] = print,
) -> list[Row]:
    """The service and a simulated arm for each of ``names`` (every catalogue arm if empty) on
    a free local endpoint, the scripted session on each; plots and ``demo.json`` in ``out``.
    Every request's row goes to ``echo`` as it is done; ``say`` gets the banner and the summary."""
    import zenoh

    from armd.adapters.sim import SimAdapter
    from armd.service.server import Service
    from armd.service.zconfig import free_endpoint, network_config

    arms = {name: robots.load(name) for name in robots.names()}
    chosen = list(names) or list(arms)
    for name in chosen:
        if name not in arms:
            raise UnknownRobot(name, arms)
    out.mkdir(parents=True, exist_ok=True)
    endpoint = free_endpoint()
    started = time.perf_counter()
    zenoh.init_log_from_env_or("error")
    session = zenoh.open(network_config(listen=[endpoint]))
    service = Service(session, {n: arms[n] for n in chosen})
    from armd.adapters.sim_sensors import objects_of

    from . import seed000

    world = {seed000.ROBOT: objects_of([seed000.CAN])}  # (seed 000's scenario: a can on the insomniac's floor)
    sims = {n: SimAdapter(session, arms[n], time_scale=time_scale, objects=world.get(n, [])) for n in chosen}
    rows: list[Row] = []
    say(f"armd demo: service and simulated arms on {endpoint}; plots in {out.resolve()}/")
    say(f"{'arm':<10} {'case':<16} {'target / goal [m]':<26} {'status':<12} {'error m':>8} {'ms':>8}  note")
    try:
        with ArmClient(endpoint, timeout=15.0) as client:
            demo = Demo(client, out, rows, echo)
            for name in chosen:
                demo.run(arms[name], workspace_step)
            if seed000.ROBOT in chosen:
                _seed000(client, sims[seed000.ROBOT], demo, say)
    finally:
        for sim in sims.values():
            sim.close()
        service.close()
        session.close()
    (out / "demo.json").write_text(json.dumps([r.__dict__ for r in rows], indent=2))
    pngs = sorted(p.name for p in out.glob("*.png"))
    say(
        f"{len(rows)} requests on {len(chosen)} arms in {time.perf_counter() - started:.1f} s; "
        f"{len(pngs)} plots and demo.json in {out.resolve()}/"
    )
    return rows
