"""docs/security/router.json5's roles, each its own user, through a real router with the ACL:
what each may do works, and each thing it may not do is denied (the router drops it: nothing
reaches anyone). Every row of docs/security.md's table of roles is a test here."""

from __future__ import annotations

import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest
import zenoh

from armd.service.zconfig import network_config
from tests.test_security import secured  # noqa: F401 (the fixture: a router with the ACL, and each role's config)

pytestmark = pytest.mark.slow  # (seconds: processes, routers, emulated boards; `pytest -m "not slow"` skips it)

SETTLE = 0.4  # [s] for a declaration to reach the router and the other sessions
WAIT = 0.6  # [s] how long a delivery is waited for


@pytest.fixture
def roles(secured: dict[str, Path]) -> Iterator[Callable[[str], zenoh.Session]]:  # noqa: F811
    """A session per role on demand (several of one role: call it again), closed at the end."""
    opened: list[zenoh.Session] = []

    def open_as(role: str) -> zenoh.Session:
        session = zenoh.open(network_config(config_file=str(secured[role])))
        opened.append(session)
        return session

    yield open_as
    for s in opened:
        s.close()


def delivered(publisher: zenoh.Session, key: str, observer: zenoh.Session) -> bool:
    """Whether a put of ``publisher`` on ``key`` reaches a subscriber of ``observer``."""
    got = threading.Event()
    sub = observer.declare_subscriber(key, lambda s: got.set())
    time.sleep(SETTLE)
    publisher.put(key, b'{"id": "probe"}')
    seen = got.wait(WAIT)
    sub.undeclare()
    return seen


def answered(querier: zenoh.Session, key: str, answerer: zenoh.Session) -> bool:
    """Whether a query of ``querier`` on ``key`` gets a reply from a queryable of ``answerer``."""
    q = answerer.declare_queryable("armd/**", lambda query: query.reply(query.key_expr, b'{"spoof": true}'))
    time.sleep(SETTLE)
    replies = list(querier.get(key, timeout=WAIT))
    q.undeclare()
    return any(r.ok is not None for r in replies)


def token_seen(declarer: zenoh.Session, key: str, observer: zenoh.Session) -> bool:
    seen = threading.Event()
    sub = observer.liveliness().declare_subscriber(key, lambda s: seen.set())
    time.sleep(SETTLE)
    token = declarer.liveliness().declare_token(key)
    ok = seen.wait(WAIT)
    token.undeclare()
    sub.undeclare()
    return ok


# -- what each role may do ---------------------------------------------------------------------------


def test_the_service_publishes_trajectories_and_stops_that_adapters_hear(roles: Callable[[str], zenoh.Session]) -> None:
    service, adapter = roles("service"), roles("adapter-desk4")
    assert delivered(service, "armd/desk4/trajectory", adapter)
    assert delivered(service, "armd/desk4/estop", adapter)
    assert delivered(service, "armd/desk4/gripper", adapter)


def test_adapters_report_to_the_service_and_their_tokens_are_seen(roles: Callable[[str], zenoh.Session]) -> None:
    service, adapter = roles("service"), roles("adapter-desk4")
    assert delivered(adapter, "armd/desk4/state", service)
    assert delivered(adapter, "armd/desk4/events", service)
    assert token_seen(adapter, "armd/desk4/adapter/a1", service)


def test_an_operator_asks_every_verb_stops_and_watches(roles: Callable[[str], zenoh.Session]) -> None:
    service, operator, adapter = roles("service"), roles("operator"), roles("adapter-desk4")
    assert answered(operator, "armd/desk4/move", service)
    assert delivered(operator, "armd/desk4/estop", adapter)
    assert delivered(operator, "armd/desk4/unlock", adapter)
    assert delivered(adapter, "armd/desk4/state", operator)
    assert delivered(service, "armd/desk4/trajectory", operator)


def test_a_guest_asks_the_read_only_verbs(roles: Callable[[str], zenoh.Session]) -> None:
    service, guest = roles("service"), roles("guest")
    for verb in ("info", "fk", "ik", "plan"):
        assert answered(guest, f"armd/desk4/{verb}", service), verb
    assert answered(guest, "armd/robots", service)


def test_an_operator_asks_the_verbs_that_move(roles: Callable[[str], zenoh.Session]) -> None:
    service, operator = roles("service"), roles("operator")
    for verb in ("stop", "gripper"):
        assert answered(operator, f"armd/desk4/{verb}", service), verb


def test_each_arms_adapter_hears_and_speaks_for_its_own_arm(roles: Callable[[str], zenoh.Session]) -> None:
    service, gupta3 = roles("service"), roles("adapter-gupta3")
    assert delivered(service, "armd/gupta3/trajectory", gupta3)
    assert delivered(gupta3, "armd/gupta3/state", service)
    assert token_seen(gupta3, "armd/gupta3/adapter/g1", service)


# -- and what each may not ---------------------------------------------------------------------------


@pytest.mark.parametrize("verb", ["move", "stop", "gripper", "world"])  # (world: changes what plans do)
def test_a_guest_cannot_ask_a_verb_that_moves(roles: Callable[[str], zenoh.Session], verb: str) -> None:
    service, guest = roles("service"), roles("guest")
    assert not answered(guest, f"armd/desk4/{verb}", service)


@pytest.mark.parametrize("key", ["trajectory", "estop", "gripper", "unlock"])
def test_a_guest_cannot_command_an_adapter(roles: Callable[[str], zenoh.Session], key: str) -> None:
    guest, adapter = roles("guest"), roles("adapter-desk4")
    assert not delivered(guest, f"armd/desk4/{key}", adapter)


@pytest.mark.parametrize("key", ["state", "events"])
def test_a_guest_cannot_speak_for_an_adapter(roles: Callable[[str], zenoh.Session], key: str) -> None:
    guest, service = roles("guest"), roles("service")
    assert not delivered(guest, f"armd/desk4/{key}", service)


def test_a_guest_cannot_pose_as_an_adapter_or_a_service(roles: Callable[[str], zenoh.Session]) -> None:
    guest, service, operator = roles("guest"), roles("service"), roles("operator")
    assert not token_seen(guest, "armd/desk4/adapter/fake", service)
    assert not answered(operator, "armd/desk4/stop", guest)


def test_a_guest_cannot_watch_trajectories(roles: Callable[[str], zenoh.Session]) -> None:
    service, guest = roles("service"), roles("guest")
    assert not delivered(service, "armd/desk4/trajectory", guest)


def test_an_adapter_cannot_answer_for_the_service(roles: Callable[[str], zenoh.Session]) -> None:
    """The spoof of the issue: a complete armd/** queryable declared with the adapter's
    credentials answered operators' stops while the service was away."""
    adapter, operator = roles("adapter-desk4"), roles("operator")
    assert not answered(operator, "armd/desk4/stop", adapter)


def test_an_adapter_cannot_ask_verbs_or_command_other_adapters(roles: Callable[[str], zenoh.Session]) -> None:
    service, adapter, other = roles("service"), roles("adapter-desk4"), roles("adapter-desk4")
    assert not answered(adapter, "armd/desk4/move", service)
    assert not delivered(adapter, "armd/desk4/trajectory", other)
    assert not delivered(adapter, "armd/desk4/estop", other)


def test_an_operator_cannot_bypass_the_service_or_speak_for_an_adapter(roles: Callable[[str], zenoh.Session]) -> None:
    operator, adapter, service, other = roles("operator"), roles("adapter-desk4"), roles("service"), roles("operator")
    assert not delivered(operator, "armd/desk4/trajectory", adapter)  # (trajectories come checked, from the service)
    assert not delivered(operator, "armd/desk4/gripper", adapter)
    assert not delivered(operator, "armd/desk4/state", service)
    assert not token_seen(operator, "armd/desk4/adapter/fake", service)
    assert not answered(other, "armd/desk4/move", operator)


def test_the_service_cannot_speak_for_an_adapter(roles: Callable[[str], zenoh.Session]) -> None:
    service, observer, adapter = roles("service"), roles("service"), roles("adapter-desk4")
    assert not delivered(service, "armd/desk4/state", observer)
    assert not token_seen(service, "armd/desk4/adapter/fake", observer)
    assert not delivered(service, "armd/desk4/unlock", adapter)


def test_an_adapter_cannot_speak_or_hear_for_another_arm(roles: Callable[[str], zenoh.Session]) -> None:
    """Each arm's adapter its own user: desk4's credentials, stolen or misused, say nothing for
    gupta3 and hear none of its commands."""
    service, desk4 = roles("service"), roles("adapter-desk4")
    assert not delivered(desk4, "armd/gupta3/state", service)
    assert not delivered(desk4, "armd/gupta3/events", service)
    assert not token_seen(desk4, "armd/gupta3/adapter/fake", service)
    for key in ("trajectory", "estop", "gripper"):
        assert not delivered(service, f"armd/gupta3/{key}", desk4), key
    assert not delivered(roles("operator"), "armd/gupta3/unlock", desk4)


def test_an_adapter_cannot_give_its_own_commands_or_watch_others(roles: Callable[[str], zenoh.Session]) -> None:
    adapter, twin, other = roles("adapter-desk4"), roles("adapter-desk4"), roles("adapter-gupta3")
    assert not delivered(adapter, "armd/desk4/gripper", twin)  # (gripper commands come from the service)
    assert not delivered(adapter, "armd/desk4/unlock", twin)  # (an unlock is an operator's word)
    assert not delivered(twin, "armd/desk4/state", adapter)  # it says its state; it watches nobody's
    assert not delivered(other, "armd/gupta3/events", adapter)


@pytest.mark.parametrize("key", ["state", "events"])
def test_a_guest_cannot_watch_an_arm(roles: Callable[[str], zenoh.Session], key: str) -> None:
    adapter, guest = roles("adapter-desk4"), roles("guest")
    assert not delivered(adapter, f"armd/desk4/{key}", guest)


def test_an_operator_cannot_put_an_adapters_events(roles: Callable[[str], zenoh.Session]) -> None:
    """An adapter's `accepted` is what makes a move succeed: nobody else may say it. (The service
    says its tracking streams' events there, and believes an `accepted` only under a live
    adapter's id, whose token it cannot declare: test_the_service_cannot_speak_for_an_adapter.)"""
    service, operator, observer = roles("service"), roles("operator"), roles("service")
    assert delivered(service, "armd/desk4/events", observer)
    assert not delivered(operator, "armd/desk4/events", observer)


def test_an_operator_streams_to_the_service_and_a_guest_cannot(roles: Callable[[str], zenoh.Session]) -> None:
    service, operator, guest, adapter = roles("service"), roles("operator"), roles("guest"), roles("adapter-desk4")
    assert delivered(operator, "armd/desk4/track", service)
    assert delivered(operator, "armd/desk4/estop", service)  # (an estop ends a stream: the service hears it)
    assert not delivered(guest, "armd/desk4/track", service)
    assert not delivered(adapter, "armd/desk4/track", service)
    # an operator hears the puts (`armd record --teleop`, its own session recorded); a guest does not
    recorder = roles("operator")
    assert delivered(operator, "armd/desk4/track", recorder)
    assert not delivered(operator, "armd/desk4/track", guest)
