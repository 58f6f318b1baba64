"""Commands that need no network: ``armd catalogue``, ``armd plot`` (plan in-process, draw it),
``armd workspace`` (an arm's reachable space, by batch IK) and ``armd secure-setup`` (the
secure setup's files)."""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path
from typing import Any

from .common import all_robots, goal, motion_args, numbers, robot_named


def _deg(x: float) -> str:
    return f"{math.degrees(x):7.1f}"


def cmd_catalogue(args: argparse.Namespace) -> int:
    arms = all_robots(args.robots_dir)
    if args.json:
        print(json.dumps({name: arm.describe() for name, arm in arms.items()}, indent=2))
        return 0
    for name, arm in arms.items():
        reach = arm.fk(arm.neutral)
        print(f"{name}: {arm.title}")
        print(f"  neutral tool point [m]: ({reach[0]:.4f}, {reach[1]:.4f}, {reach[2]:.4f})")
        print(f"  IK: {arm.solver}")
        print(f"  {'joint':<12} {'lower':>7} {'upper':>7}  deg   {'vmax':>6} {'amax':>6} {'jmax':>6}  (rad/s^k)")
        lim = arm.limits
        for i, j in enumerate(arm.joint_names):
            print(
                f"  {j:<12} {_deg(lim.lower[i])} {_deg(lim.upper[i])}      "
                f"{lim.velocity[i]:6.2f} {lim.acceleration[i]:6.1f} {lim.jerk[i]:6.1f}"
            )
        for c in lim.coupled:
            terms = " + ".join(f"{k:g}*{arm.joint_names[i]}" for i, k in enumerate(c.coefficients) if k)
            print(f"  coupled {c.name}: {c.lower:g} <= {terms} <= {c.upper:g} rad")
        acts = ", ".join(f"{a.name} ({a.kind})" for a in arm.actuators.actuators)
        print(f"  actuators: {acts}")
        if arm.sensors:
            print(f"  sensors: {', '.join(sorted(arm.sensors))}")
        if arm.collision is None:
            print(f"  collisions: not checked: {arm.collision_off}")
        for link, what in sorted(arm.collision_links.items()):
            print(f"  collision of {link}: {what}")
        print()
    return 0


def cmd_plot(args: argparse.Namespace) -> int:
    from armd import planning
    from armd.tools.plot import plot_trajectory

    arm = robot_named(args.robot, args.robots_dir)
    start = numbers(args.start, "start") if args.start else arm.neutral
    traj = planning.plan(arm, start, goal(args), path=args.path, speed=args.speed, rate_hz=args.rate)
    out = plot_trajectory(traj, arm, args.out)
    print(
        f"{out}: {traj.path} trajectory of {arm.name}, {traj.duration:.3f} s, {len(traj.times)} samples "
        f"at {traj.rate_hz:g} Hz"
    )
    return 0


def cmd_workspace(args: argparse.Namespace) -> int:
    from armd.tools import workspace

    arm = robot_named(args.robot, args.robots_dir)
    ws = workspace.compute(
        arm, step=args.step, heights=args.heights, progress=workspace.ProgressBar(f"workspace of {arm.name}")
    )
    workspace.plot(ws, arm, args.out)
    cells = ws.side.any_pitch.size + ws.top.any_pitch.size * len(ws.heights)
    line = (
        f"{args.out}: {arm.name} workspace, {ws.step * 1000:g} mm cells; side view: A "
        f"{ws.side.any_pitch.sum() * ws.side.cell_area * 1e4:.0f} cm²"
    )
    if ws.side.parallel is not None:
        line += f", B {ws.side.parallel.sum() * ws.side.cell_area * 1e4:.0f} cm²"
    print(f"{line}; {cells:,} cells per approach by batch IK in {ws.seconds:.2f} s")
    return 0


def cmd_secure_setup(args: argparse.Namespace) -> int:
    """The router's configuration, the users file with fresh passwords and each side's client
    configuration, for the arms named (default: the catalogue and ``--robots-dir``'s)."""
    from armd.errors import UnknownRobot
    from armd.service import secure_setup

    known = list(all_robots(args.robots_dir))  # (a folder's arm of a catalogue name replaces it)
    names = args.robot or known
    unknown = [n for n in names if n not in known]
    if unknown:
        raise UnknownRobot(unknown[0], known)
    out = Path(args.dir)
    contents = secure_setup.files(
        names,
        secure_setup.new_passwords(names),
        str((out / "users.txt").resolve()),
        endpoint=args.endpoint,
        prefix=args.prefix,
    )
    for path in secure_setup.write(out, contents):
        print(path)
    print(
        f"run: armd router --config {out / 'router.json5'}; give each side its file "
        f"(armd serve --config {out / 'service.json5'}, armd adapter ... --config {out}/adapter-<robot>.json5, "
        f"operators {out / 'operator.json5'}, guests {out / 'guest.json5'}); docs/security.md"
    )
    return 0


def register(sub: Any, log_args: argparse.ArgumentParser) -> None:
    p = sub.add_parser("catalogue", parents=[log_args], help="print the arms armd knows, offline")
    p.add_argument("--robots-dir", help="a folder of your own arms (robot.urdf + robot.toml each)")
    p.add_argument("--json", action="store_true", help="print JSON instead of tables")
    p.set_defaults(func=cmd_catalogue)

    p = sub.add_parser(
        "plot", parents=[log_args], help="plan a trajectory offline and write a PNG of it (limits drawn)"
    )
    motion_args(p)
    p.add_argument("--start", nargs="+", metavar="Q", help="start joint vector [rad] (default: neutral)")
    p.add_argument("--rate", type=float, default=None, help="samples per second (default: the arm's)")
    p.add_argument("--out", default="trajectory.png", help="PNG file to write")
    p.add_argument("--robots-dir", help="a folder of your own arms")
    p.set_defaults(func=cmd_plot)

    p = sub.add_parser(
        "workspace", parents=[log_args], help="draw an arm's reachable space (side and top views) to a PNG"
    )
    p.add_argument("robot")
    p.add_argument("--out", default="workspace.png", help="PNG file to write")
    p.add_argument("--step", type=float, default=0.004, help="cell size [m] (default 0.004)")
    p.add_argument("--heights", type=int, default=16, help="heights the top view looks through (default 16)")
    p.add_argument("--robots-dir", help="a folder of your own arms")
    p.set_defaults(func=cmd_workspace)

    p = sub.add_parser(
        "secure-setup",
        parents=[log_args],
        help="write a router with logins and least-privilege roles, and each side's config (docs/security.md)",
    )
    p.add_argument("dir", help="an empty or new folder for the files")
    p.add_argument("--robot", action="append", help="an arm with an adapter user of its own (default: every arm known)")
    p.add_argument("--robots-dir", help="a folder of your own arms")
    p.add_argument(
        "--endpoint",
        default="tcp/127.0.0.1:7447",
        help="where the router listens and the clients connect (default tcp/127.0.0.1:7447)",
    )
    p.add_argument("--prefix", default="armd", help="key expression prefix (default armd)")
    p.set_defaults(func=cmd_secure_setup)
