"""One error tree (armd.errors): a code belongs to one class, the builtin bases a Python caller
expects, and the same types over the wire as in-process."""

from __future__ import annotations

import inspect
import re
from pathlib import Path

import pytest

from armd import errors
from armd.clients import ArmClient
from armd.errors import BY_CODE, ArmdError, BadRequest, LimitError, ServiceError, UnknownRobot, from_reply

ROOT = Path(__file__).resolve().parent.parent
CLASSES = [c for _, c in inspect.getmembers(errors, inspect.isclass) if issubclass(c, ArmdError)]


def test_every_error_lives_in_armd_errors() -> None:
    """No error class is defined anywhere else in the package."""
    elsewhere = []
    for layer in ("robots", "solvers", "planning", "service", "clients", "adapters", "tools", "cli"):
        for path in (ROOT / layer).rglob("*.py"):
            for m in re.finditer(r"^class (\w+)\((.*)\):", path.read_text(), re.M):
                bases = m.group(2)
                if "Error" in bases or "BadRequest" in bases or "Exception" in bases:
                    elsewhere.append(f"{path.relative_to(ROOT)}: {m.group(1)}({bases})")
    assert not elsewhere, elsewhere


def test_a_code_belongs_to_one_class_and_its_subclasses() -> None:
    for cls in CLASSES:
        if cls is ServiceError:
            continue
        owner = BY_CODE[cls.code]
        assert issubclass(cls, owner), f"{cls.__name__} has code {cls.code!r}, which is {owner.__name__}'s"
    assert BY_CODE["bad_request"] is BadRequest and BY_CODE["limit"] is LimitError and BY_CODE["internal"] is ArmdError


def test_the_builtin_bases_a_caller_expects() -> None:
    assert issubclass(errors.BadRequest, ValueError) and issubclass(errors.NoReply, TimeoutError)
    assert issubclass(errors.UnknownRobot, LookupError) and issubclass(errors.TooLarge, BadRequest)


def test_every_code_of_the_protocol_has_its_class() -> None:
    table = (ROOT / "docs" / "protocol.md").read_text()
    documented = set(re.findall(r"^\| `([a-z_]+)` \|", table, re.M))
    assert {"bad_request", "unknown_robot", "limit", "internal"} <= documented
    assert documented <= set(BY_CODE), documented - set(BY_CODE)


def test_an_error_reply_is_of_its_codes_class() -> None:
    e = from_reply({"code": "bad_request", "message": "q must have 5 values", "field": "q"})
    assert isinstance(e, ServiceError) and isinstance(e, BadRequest) and isinstance(e, ValueError)
    assert e.code == "bad_request" and e.field == "q" and e.message == "q must have 5 values"
    limit = from_reply({"code": "limit", "message": "m", "name": "elbow", "value": 3.0, "kind": "position"})
    assert isinstance(limit, LimitError) and limit.name == "elbow" and limit.value == 3.0  # type: ignore[attr-defined]
    for plain in ({"code": "internal", "message": "bug"}, {"code": "from_the_future", "message": "?"}):
        e = from_reply(plain)
        assert type(e) is ServiceError and e.code == plain["code"]
    assert type(from_reply({"code": "limit", "message": "a"})) is type(limit)  # (one class per code)


def test_over_the_wire_the_same_types_as_in_process(client: ArmClient) -> None:
    with pytest.raises(BadRequest) as bad:
        client.fk("insomniac", [0.0, 0.0])
    assert isinstance(bad.value, ServiceError) and bad.value.field == "q"
    with pytest.raises(UnknownRobot) as unknown:
        client.fk("nosuch", [0.0])
    assert "insomniac" in unknown.value.fields["available"]
