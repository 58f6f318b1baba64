"""A user's arm folder, checked before anything of it is built (robots/checks.py): joint count and
chain depth caps, finite limits of sane magnitudes, meshes only from inside the arm's folder and
under their caps. A bad arm is refused with an error naming its file and what is wrong; a mesh that
cannot be used refuses it unless robot.toml's ``[collision] meshes_optional = true`` (then ``info``
says that collisions are not checked, and why); one bad arm never takes the others down."""

from __future__ import annotations

import os
import struct
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import zenoh

from armd import robots, solvers
from armd.clients import ArmClient
from armd.errors import RobotFileError
from armd.robots import checks
from armd.service.server import Service
from armd.service.zconfig import network_config

LIMIT = 'lower="-1.5" upper="1.5" velocity="2" effort="1"'
BOX = '<collision><origin xyz="0 0 0.025"/><geometry><box size="0.02 0.02 0.03"/></geometry></collision>'


def _urdf(n: int, *, limit: str = LIMIT, shape: str = BOX, extra: str = "") -> str:
    """A chain of ``n`` revolute joints (yaw, then pitches), 0.05 m apart, each link a box, then a
    tool frame."""
    links = ['<link name="base"/>'] + [f'<link name="l{i}">{shape}</link>' for i in range(1, n + 1)]
    joints = [
        f'<joint name="j{i}" type="revolute"><parent link="{"base" if i == 1 else f"l{i - 1}"}"/>'
        f'<child link="l{i}"/><origin xyz="0 0 0.05"/><axis xyz="{"0 0 1" if i == 1 else "0 1 0"}"/>'
        f"<limit {limit}/></joint>"
        for i in range(1, n + 1)
    ]
    tool = f'<link name="tool"/><joint name="tool_fixed" type="fixed"><parent link="l{n}"/><child link="tool"/></joint>'
    return f'<robot name="arm">{"".join(links)}{"".join(joints)}{tool}{extra}</robot>'


def _toml(joints: int, extra: str = "") -> str:
    names = ", ".join(f'"j{i}"' for i in range(1, joints + 1))
    return f"[robot]\njoints = [{names}]\nneutral = [{', '.join(['0.3'] * joints)}]\n{extra}"


def _arm(root: Path, name: str, urdf: str, toml: str) -> Path:
    folder = root / name
    folder.mkdir(parents=True)
    (folder / "robot.urdf").write_text(urdf)
    (folder / "robot.toml").write_text(toml)
    return folder


def _stl(path: Path, triangles: int, claim: int | None = None) -> None:
    """A binary STL of ``triangles`` small triangles, its header claiming ``claim`` of them."""
    path.parent.mkdir(parents=True, exist_ok=True)
    tri = struct.pack("<12fH", 0, 0, 1, 0, 0, 0, 0.01, 0, 0, 0, 0.01, 0, 0)
    tet = [
        ((0, 0, 0), (0.02, 0, 0), (0, 0.02, 0)),
        ((0, 0, 0), (0, 0.02, 0), (0, 0, 0.02)),
        ((0, 0, 0), (0, 0, 0.02), (0.02, 0, 0)),
        ((0.02, 0, 0), (0, 0.02, 0), (0, 0, 0.02)),
    ]
    body = b"".join(struct.pack("<3f", 0, 0, 1) + struct.pack("<9f", *sum(t, ())) + b"\0\0" for t in tet)
    body += tri * max(0, triangles - len(tet))
    path.write_bytes(b"\0" * 80 + struct.pack("<I", triangles if claim is None else claim) + body)


def _mesh(filename: str) -> str:
    return f'<collision><geometry><mesh filename="{filename}"/></geometry></collision>'


# -- joints and depth ---------------------------------------------------------------------------


@pytest.mark.timeout(30)  # (before: not loaded in 90 s)
def test_a_thousand_joint_urdf_is_refused_at_once(tmp_path: Path) -> None:
    folder = _arm(tmp_path, "big", _urdf(1000), _toml(1000))
    started = time.monotonic()
    with pytest.raises(RobotFileError) as e:
        robots.load_folder(folder)
    assert time.monotonic() - started < 1.0
    assert (
        e.value.file == str((folder / "robot.urdf").resolve()) and f"over {checks.MAX_JOINTS} joints" in e.value.problem
    )


def test_a_chain_deeper_than_the_cap_is_refused(tmp_path: Path) -> None:
    n = checks.MAX_DEPTH + 1  # (under the joint cap: a chain too deep, not too many joints)
    assert n + 1 <= checks.MAX_JOINTS
    with pytest.raises(RobotFileError) as e:
        robots.load_folder(_arm(tmp_path, "deep", _urdf(n, shape=""), _toml(3)))
    assert f"over {checks.MAX_DEPTH} joints from the root" in e.value.problem and e.value.field == f"link 'l{n}'"


@pytest.mark.parametrize(
    ("extra", "said"),
    [
        ('<joint name="loop" type="fixed"><parent link="l3"/><child link="l1"/></joint>', "already a child"),
        ('<link name="stray"/>', "2 root links"),
        ('<joint name="j9" type="fixed"><parent link="l3"/><child link="nowhere"/></joint>', "names no link"),
    ],
)
def test_joints_that_make_no_tree_are_refused(tmp_path: Path, extra: str, said: str) -> None:
    with pytest.raises(RobotFileError, match=said):
        robots.load_folder(_arm(tmp_path, "knot", _urdf(3, extra=extra), _toml(3)))


def test_a_doctype_is_refused_so_no_entity_is_expanded(tmp_path: Path) -> None:
    bomb = '<?xml version="1.0"?><!DOCTYPE robot [<!ENTITY a "aaaaaaaaaa"><!ENTITY b "&a;&a;&a;&a;&a;">]>'
    with pytest.raises(RobotFileError, match="DOCTYPE"):
        robots.load_folder(_arm(tmp_path, "bomb", bomb + _urdf(3).replace('name="arm"', 'name="&b;"'), _toml(3)))


# -- limits and numbers -------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("limit", "toml", "field", "said"),
    [
        ('lower="-1e308" upper="1e308" velocity="2" effort="1"', "", "joint 'j1' <limit> lower", "over 100"),
        ('lower="-1" upper="1" velocity="1e308" effort="1"', "", "joint 'j1' <limit> velocity", "over 1000"),
        ('lower="-1" upper="nan" velocity="2" effort="1"', "", "joint 'j1' <limit> upper", "finite"),
        (LIMIT, "[joints.j2]\nlower = -1e308\n", "joints.j2", "within +-100"),
        (LIMIT, "[joints.j2]\nvelocity = 1e300\n", "joints.j2.velocity", "at most 1000"),
        (LIMIT, "[joints.j2]\nacceleration = 1e300\n", "joints.j2.acceleration", "at most 100000"),
        (LIMIT, "[joints.j3]\njerk = 1e300\n", "joints.j3.jerk", "at most 1e+07"),
        (
            LIMIT,
            '[[coupled_limits]]\nname = "c"\ncoefficients = { j2 = 1.0, j3 = 1.0 }\nupper = 1e308\n',
            "coupled_limits.c.upper",
            "beyond what the joints reach",
        ),
    ],
)
def test_absurd_limits_are_refused_naming_the_joint(
    tmp_path: Path, limit: str, toml: str, field: str, said: str
) -> None:
    """Limits of +-1e308 once loaded, and crashed ``armd serve``'s warm-up: no arm was served."""
    with pytest.raises(RobotFileError) as e:
        robots.load_folder(_arm(tmp_path, "wide", _urdf(3, limit=limit), _toml(3, toml)))
    assert e.value.field == field and said in e.value.problem, e.value


@pytest.mark.parametrize(
    ("old", "new", "field"),
    [
        ('<origin xyz="0 0 0.05"/>', '<origin xyz="1e308 0 0.05"/>', "joint 'j1' <origin> xyz"),
        ('<origin xyz="0 0 0.05"/>', '<origin xyz="0 0 0.05" rpy="0 nan 0"/>', "joint 'j1' <origin> rpy"),
        ('<axis xyz="0 0 1"/>', '<axis xyz="0 0 0"/>', "joint 'j1' <axis> xyz"),
        ('size="0.02 0.02 0.03"', 'size="0.02 0.02 1e300"', "link 'l1' <collision> <box> size"),
    ],
)
def test_numbers_pinocchio_reads_are_finite_and_of_an_arms_size(tmp_path: Path, old: str, new: str, field: str) -> None:
    urdf = _urdf(3)
    assert old in urdf
    with pytest.raises(RobotFileError) as e:
        robots.load_folder(_arm(tmp_path, "odd", urdf.replace(old, new, 1), _toml(3)))
    assert e.value.field == field, e.value


# -- files and meshes ---------------------------------------------------------------------------


@pytest.mark.parametrize(
    "urdf_name", ["/etc/hostname", "../elsewhere/robot.urdf", "/dev/zero", "link.urdf", "package://../robot.urdf"]
)
def test_the_urdf_is_a_file_of_the_folder(tmp_path: Path, urdf_name: str) -> None:
    folder = _arm(tmp_path, "arm", _urdf(3), _toml(3).replace("[robot]\n", f'[robot]\nurdf = "{urdf_name}"\n'))
    (tmp_path / "elsewhere").mkdir()
    (tmp_path / "elsewhere" / "robot.urdf").write_text(_urdf(3))
    (folder / "link.urdf").symlink_to(tmp_path / "elsewhere" / "robot.urdf")
    with pytest.raises(RobotFileError) as e:
        robots.load_folder(folder)
    assert e.value.file == str(folder / "robot.toml") and e.value.field == "robot.urdf"
    assert "outside the arm's folder" in e.value.problem or "'..'" in e.value.problem, e.value


def test_a_huge_robot_toml_is_not_read(tmp_path: Path) -> None:
    folder = _arm(tmp_path, "arm", _urdf(3), _toml(3) + "#" * checks.MAX_TOML_BYTES + "\n")
    with pytest.raises(RobotFileError, match="at most"):
        robots.load_folder(folder)


def _forbidden(folder: Path) -> None:
    os.mkfifo(folder / "pipe.stl")
    (folder / "meshes").mkdir()
    (folder / "meshes" / "out.stl").symlink_to("/etc/hostname")


FORBIDDEN = [
    ("/etc/passwd", "outside the arm's folder"),
    ("../../etc/hostname", "'..'"),
    ("/dev/zero", "outside the arm's folder"),
    ("file:///etc/passwd", "outside the arm's folder"),
    ("package://../robot.urdf", "'..'"),
    ("http://example.com/a.stl", "a path in the arm's folder"),
    ("meshes/out.stl", "outside the arm's folder"),  # (a link out of the folder)
    ("pipe.stl", "not a regular file"),
]


@pytest.mark.parametrize("optional", [False, True])
@pytest.mark.parametrize(("filename", "said"), FORBIDDEN)
def test_a_mesh_outside_the_folder_is_never_opened(tmp_path: Path, filename: str, said: str, optional: bool) -> None:
    """Whatever robot.toml says: ``meshes_optional`` excuses a mesh that cannot be used, not one
    that is not the arm's."""
    toml = _toml(3, "[collision]\nmeshes_optional = true\n" if optional else "")
    folder = _arm(tmp_path, "arm", _urdf(3, shape=_mesh(filename)), toml)
    _forbidden(folder)
    with pytest.raises(RobotFileError) as e:
        robots.load_folder(folder)
    assert e.value.file == str((folder / "robot.urdf").resolve()) and said in e.value.problem, e.value
    assert e.value.field == "link 'l1' <collision> <mesh filename>" and filename in e.value.problem


def _unusable(folder: Path) -> None:
    meshes = folder / "meshes"
    meshes.mkdir()
    _stl(meshes / "claims.stl", 4, claim=10**9)  # its header claims 10^9 triangles
    _stl(meshes / "many.stl", checks.MAX_TRIANGLES + 1)
    with (meshes / "huge.stl").open("wb") as f:  # (sparse: no disk)
        f.truncate(checks.MAX_MESH_BYTES + 1)
    (meshes / "empty.stl").write_bytes(b"")
    (meshes / "shape.ply").write_text("ply\n")


UNUSABLE = [
    ("meshes/claims.stl", "claims 1,000,000,000 triangles"),
    ("meshes/many.stl", f"a mesh may have at most {checks.MAX_TRIANGLES:,}"),
    ("package://meshes/huge.stl", f"a mesh may be at most {checks.MAX_MESH_BYTES:,}"),
    ("meshes/empty.stl", "is empty"),
    ("meshes/shape.ply", "not a mesh format armd reads"),
    ("meshes/nosuch.stl", "not found"),
]


@pytest.mark.parametrize(("filename", "said"), UNUSABLE)
def test_a_mesh_that_cannot_be_used_refuses_the_arm_unless_robot_toml_allows(
    tmp_path: Path, filename: str, said: str
) -> None:
    """Refused, naming the mesh; with ``meshes_optional`` the mesh alone is left out and said in
    ``info``: the floor is still checked (a tool under it is never ``ok``)."""
    folder = _arm(tmp_path, "arm", _urdf(3, shape=_mesh(filename)), _toml(3))
    _unusable(folder)
    with pytest.raises(RobotFileError) as e:
        robots.load_folder(folder)
    assert said in e.value.problem and "meshes_optional = true" in e.value.problem, e.value
    (folder / "robot.toml").write_text(_toml(3, "[collision]\nmeshes_optional = true\n"))
    arm = robots.load_folder(folder)
    described = arm.describe()["collision"]
    assert described["checked"] is True and described["off"] is None and arm.collision is not None
    assert sorted(described["links"]) == ["l1", "l2", "l3"], described
    assert all(said in why and filename in why for why in described["links"].values()), described
    assert solvers.solve_ik(arm, [0.05, 0.0, -0.02]).status == "collision"  # (under the floor: never ok)


def test_every_mesh_that_cannot_be_used_is_named_in_one_error(tmp_path: Path) -> None:
    urdf = _urdf(3, shape=BOX).replace(BOX, _mesh("meshes/gone1.stl"), 1).replace(BOX, _mesh("meshes/gone2.stl"), 1)
    folder = _arm(tmp_path, "arm", urdf, _toml(3))
    with pytest.raises(RobotFileError) as e:
        robots.load_folder(folder)
    assert "gone1.stl" in e.value.problem and "gone2.stl" in e.value.problem and "1 more" in e.value.problem, e.value
    assert e.value.field == "link 'l1' <collision> <mesh filename>"


def test_robot_toml_stands_in_for_a_link_or_skips_it(tmp_path: Path) -> None:
    """l2's mesh is gone: a box stands in for it, checked exactly as the same box in the URDF;
    l3 skipped: in no pair. A link the URDF lacks is refused, naming robot.toml's field."""
    native = robots.load_folder(_arm(tmp_path, "native", _urdf(3), _toml(3)))
    urdf = _urdf(3)
    urdf = urdf.replace(f'<link name="l2">{BOX}</link>', f'<link name="l2">{_mesh("meshes/gone.stl")}</link>')
    urdf = urdf.replace(f'<link name="l3">{BOX}</link>', f'<link name="l3">{_mesh("meshes/heavy.stl")}</link>')
    stand_in = '[collision]\nskip = ["l3"]\n[collision.stand_in.l2]\nbox = [0.02, 0.02, 0.03]\nxyz = [0, 0, 0.025]\n'
    arm = robots.load_folder(_arm(tmp_path, "arm", urdf, _toml(3, stand_in)))
    assert arm.collision is not None and native.collision is not None
    links = arm.describe()["collision"]["links"]
    assert links == {"l2": "box 0.02 x 0.02 x 0.03 m (robot.toml stand_in)", "l3": "not checked (robot.toml skip)"}
    assert not [p for p in arm.collision.pairs if "l3" in (p.first, p.second)]
    pairs = {(p.first, p.second) for p in arm.collision.pairs}
    assert pairs == {(p.first, p.second) for p in native.collision.pairs if "l3" not in (p.first, p.second)}
    rng = np.random.default_rng(3)
    for q in rng.uniform(-1.5, 1.5, size=(300, 3)):
        hit = arm.collision.first_contact(q)
        same = native.collision.first_contact(q)
        if same is not None and "l3" in (same.first, same.second):
            continue
        assert (hit is None) == (same is None), (q, hit, same)
    bad = _toml(3, '[collision]\nskip = ["nosuch"]\n')
    with pytest.raises(RobotFileError) as e:
        robots.load_folder(_arm(tmp_path, "unknown", _urdf(3), bad))
    assert e.value.field == "collision.skip" and "no link 'nosuch'" in e.value.problem, e.value


def test_meshes_of_the_folder_load_and_are_checked(tmp_path: Path) -> None:
    shapes = {
        1: "meshes/tet.stl",
        2: "package://meshes/tet.stl",
        3: f"file://{tmp_path / 'arm' / 'meshes' / 'tet.stl'}",
    }
    urdf = _urdf(3)
    for i, name in shapes.items():
        urdf = urdf.replace(f'<link name="l{i}">{BOX}', f'<link name="l{i}">{_mesh(name)}', 1)
    folder = _arm(tmp_path, "arm", urdf, _toml(3))
    _stl(folder / "meshes" / "tet.stl", 4)
    arm = robots.load_folder(folder)
    assert arm.collision is not None and arm.describe()["collision"] == {"checked": True, "off": None, "links": {}}
    paths = {g.meshPath for g in arm.collision.geometry.geometryObjects if g.meshPath}
    assert paths == {str((folder / "meshes" / "tet.stl").resolve())}


def test_the_catalogue_passes_its_own_checks() -> None:
    for name in robots.names():
        assert robots.load(name).describe()["collision"] == {"checked": True, "off": None, "links": {}}


# -- one bad arm, the others served -------------------------------------------------------------


def _folder_of_arms(root: Path) -> Path:
    """Three arms: ``good``; ``optional``, whose mesh cannot be used and robot.toml allows it;
    ``huge``, 10,000 joints (which segfaulted the loader)."""
    _arm(root, "good", _urdf(3), _toml(3))
    toml = _toml(3, "[collision]\nmeshes_optional = true\n")
    optional = _arm(root, "optional", _urdf(3, shape=_mesh("meshes/claims.stl")), toml)
    _stl(optional / "meshes" / "claims.stl", 4, claim=10**9)
    _arm(root, "huge", _urdf(10_000, shape=""), _toml(3))
    return root


def test_one_bad_arm_is_refused_and_the_others_load(tmp_path: Path) -> None:
    root = _folder_of_arms(tmp_path)
    refused: dict[str, RobotFileError] = {}
    arms = robots.load_dir(root, refused)
    assert sorted(arms) == ["good", "optional"] and list(refused) == ["huge"]
    assert "joints" in refused["huge"].problem and refused["huge"].file.endswith("huge/robot.urdf")
    with pytest.raises(RobotFileError):  # (without ``refused``: the first bad arm's error)
        robots.load_dir(root)


def test_the_service_serves_the_good_arms_and_says_which_checks_are_off(tmp_path: Path, router: str) -> None:
    from armd.cli.common import all_robots

    refused: dict[str, RobotFileError] = {}
    arms = all_robots(str(_folder_of_arms(tmp_path)), refused)
    assert {"good", "optional", "insomniac"} <= set(arms) and "huge" not in arms and list(refused) == ["huge"]
    mine = {name: arms[name] for name in ("good", "optional")}
    session = zenoh.open(network_config(connect=[router]))
    service = Service(session, mine, prefix="users")
    try:
        with ArmClient(router, prefix="users", timeout=10.0) as client:
            assert client.info("good")["collision"] == {"checked": True, "off": None, "links": {}}
            info = client.info("optional")  # (its mesh left out: the floor still checked)
            assert info["collision"]["checked"] is True and info["world"] is not None
            said = info["collision"]["links"]["l1"]
            assert "claims.stl" in said and "1,000,000,000 triangles" in said
            q = np.array([0.1, 0.5, -0.3])
            assert np.allclose(client.fk("good", q.tolist()).position, arms["good"].fk(q))
    finally:
        service.close()
        session.close()


@pytest.mark.slow
def test_armd_catalogue_lists_the_good_arms_and_names_the_bad_one(tmp_path: Path) -> None:
    """Through the command, in its own process: the 10,000-joint arm segfaulted it."""
    root = _folder_of_arms(tmp_path)
    out = subprocess.run(
        [sys.executable, "-m", "armd.cli", "catalogue", "--robots-dir", str(root)],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert out.returncode == 0, out.stderr
    assert "good:" in out.stdout and "optional:" in out.stdout and "insomniac:" in out.stdout
    said = [line for line in out.stdout.splitlines() if line.startswith("  collision of l1: not checked")]
    assert len(said) == 1 and "claims.stl" in said[0], out.stdout  # (the optional arm's mesh, left out)
    assert "huge:" not in out.stdout
    said = [line for line in out.stderr.splitlines() if "huge" in line]
    assert len(said) == 1 and "refused" in said[0] and f"over {checks.MAX_JOINTS} joints" in said[0], out.stderr


def test_the_caps_in_the_doc_are_the_codes() -> None:
    doc = (Path(__file__).resolve().parent.parent / "docs" / "robot-format.md").read_text()
    table = doc.split("## Caps and files")[1].split("\n\n")[2]
    rows = [line.split("|")[2].split()[0] for line in table.splitlines()[2:]]
    caps = [
        checks.MAX_TOML_BYTES,
        checks.MAX_URDF_BYTES,
        checks.MAX_XML_ELEMENTS,
        checks.MAX_XML_DEPTH,
        checks.MAX_JOINTS,
        checks.MAX_DEPTH,
        checks.MAX_POSITION,
        checks.MAX_LENGTH,
        checks.MAX_FACTOR,
        checks.MAX_VELOCITY,
        checks.MAX_ACCELERATION,
        checks.MAX_JERK,
        checks.MAX_MESH_BYTES,
        checks.MAX_MESHES_BYTES,
        checks.MAX_TRIANGLES,
    ]
    assert [float(r) for r in rows] == [float(c) for c in caps], rows
