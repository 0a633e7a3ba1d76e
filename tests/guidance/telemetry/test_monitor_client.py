"""MonitorClient's queues: a short ring per car for state and health (the newest kept), zenoh's
FIFO channels for the other kinds (every one, in order). Real zenoh sessions on 127.0.0.1,
multicast scouting off; the car is a bare session publishing with ``CongestionControl.BLOCK``
so every message reaches the monitor and any loss is the client's own."""

from __future__ import annotations

import json
import socket
import threading
import time
from collections.abc import Iterator
from typing import Any

import pytest
import zenoh

from guidance.errors import UserError
from guidance.telemetry.client import FIFO_KINDS, RING_KINDS, MonitorClient, TelemetryEvent
from guidance.telemetry.session import open_session, session_config


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def wait_for_match(publishers: list[zenoh.Publisher], timeout_s: float = 10.0) -> None:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        # zenoh-python 1.10 returns a MatchingStatus (its stub says bool): accept both
        statuses = (p.matching_status for p in publishers)
        if all(bool(getattr(st, "matching", st)) for st in statuses):
            return
        time.sleep(0.02)
    raise AssertionError("the monitor's subscriptions never reached the car")


def drain(client: MonitorClient, quiet_s: float = 0.5) -> list[TelemetryEvent]:
    """Every event until none came for ``quiet_s``."""
    events = []
    while (event := client.get(quiet_s)) is not None:
        events.append(event)
    return events


@pytest.fixture
def car() -> Iterator[tuple[zenoh.Session, int]]:
    port = free_port()
    session = open_session(session_config(mode="peer", listen=[f"tcp/127.0.0.1:{port}"]))
    try:
        yield session, port
    finally:
        session.close()


def message(kind: str, seq: int) -> bytes:
    body = {"schema": f"guidance.{kind}/1", "vehicle_id": "car1", "seq": seq, "t_s": seq * 0.01}
    return json.dumps(body).encode()


def test_a_state_flood_keeps_the_newest_while_every_prompt_arrives_in_order(
    car: tuple[zenoh.Session, int],
) -> None:
    session, port = car
    states, prompts, ring, fifo = 1000, 64, 8, 64
    block = zenoh.CongestionControl.BLOCK
    pub_state = session.declare_publisher("guidance/car1/state", congestion_control=block)
    pub_prompt = session.declare_publisher("guidance/car1/prompt", congestion_control=block)
    with MonitorClient([f"tcp/127.0.0.1:{port}"], ring_size=ring, fifo_size=fifo) as client:
        wait_for_match([pub_state, pub_prompt])
        # the reader is stalled while the car floods: 1000 states, a prompt every ~16 of them
        p = 0
        for s in range(1, states + 1):
            pub_state.put(message("state", s))
            if s % (states // prompts) == 0 and p < prompts:
                p += 1
                pub_prompt.put(message("prompt", p))
        assert p == prompts
        time.sleep(1.0)  # all of it delivered on loopback; nobody reads yet
        events = drain(client)
    seqs = {k: [e.message["seq"] for e in events if e.kind == k and e.message] for k in RING_KINDS}
    got_prompts = [e.message["seq"] for e in events if e.kind == "prompt" and e.message]
    # ring: zenoh dropped the oldest states; the newest `ring` are kept, in order
    assert seqs["state"] == list(range(states - ring + 1, states + 1))
    # fifo: every prompt, in the order sent (the FIFO held exactly its capacity)
    assert got_prompts == list(range(1, prompts + 1))
    assert client.received == ring + prompts and client.undecodable == 0


def test_a_reader_that_keeps_up_sees_every_state_and_liveliness_in_order(
    car: tuple[zenoh.Session, int],
) -> None:
    session, port = car
    block = zenoh.CongestionControl.BLOCK
    pub = session.declare_publisher("guidance/car1/state", congestion_control=block)
    with MonitorClient([f"tcp/127.0.0.1:{port}"]) as client:
        events: list[TelemetryEvent] = []
        reader = threading.Thread(target=lambda: events.extend(drain(client, 3.0)))
        reader.start()  # reads while the car publishes (each car's ring holds only 4)
        token = session.liveliness().declare_token("guidance/car1")
        wait_for_match([pub])
        for s in range(1, 101):  # 50 Hz: a look every 10 ms at most, so the ring of 4 has
            pub.put(message("state", s))  # 80 ms of slack for a reader delayed by the load
            time.sleep(0.02)
        time.sleep(0.3)
        token.undeclare()
        reader.join(10.0)
    kinds = [e.kind for e in events]
    assert kinds[0] == "alive" and kinds[-1] == "gone"  # a car's messages come between
    assert [e.message["seq"] for e in events if e.kind == "state" and e.message] == list(
        range(1, 101)
    )


def test_bad_payloads_are_counted_not_returned(car: tuple[zenoh.Session, int]) -> None:
    session, port = car
    pub = session.declare_publisher(
        "guidance/car1/decision", congestion_control=zenoh.CongestionControl.BLOCK
    )
    with MonitorClient([f"tcp/127.0.0.1:{port}"]) as client:
        wait_for_match([pub])
        for payload in (b"not json", b"[1, 2]", message("decision", 1)):
            pub.put(payload)
        events = drain(client)
    assert [e.kind for e in events] == ["decision"]
    assert client.undecodable == 2 and client.received == 1


def test_channel_kinds_cover_every_kind_once() -> None:
    from guidance.telemetry.keys import KINDS

    assert sorted((*RING_KINDS, *FIFO_KINDS)) == sorted(KINDS)
    assert set(RING_KINDS) == {"state", "health"}


def test_an_unopened_client_waits_and_returns_nothing() -> None:
    client = MonitorClient([f"tcp/127.0.0.1:{free_port()}"])
    t0 = time.monotonic()
    assert client.get(0.1) is None and client.get(0) is None
    assert 0.09 < time.monotonic() - t0 < 10.0  # waits its 0.1 s, not for a car
    with pytest.raises(UserError):
        MonitorClient(ring_size=0)


def flood_unread(
    car: tuple[zenoh.Session, int], cars: int, states: int, **client_args: Any
) -> tuple[MonitorClient, dict[str, list[int]]]:
    """``cars`` cars publish ``states`` states each, one car after the other, while the client
    reads nothing; then it is drained: the client, and each car's seqs handed out."""
    session, port = car
    block = zenoh.CongestionControl.BLOCK
    pubs = [
        session.declare_publisher(f"guidance/car{c}/state", congestion_control=block)
        for c in range(cars)
    ]
    with MonitorClient([f"tcp/127.0.0.1:{port}"], **client_args) as client:
        wait_for_match(pubs)
        for pub in pubs:
            for s in range(1, states + 1):
                pub.put(message("state", s))
        time.sleep(1.0)
        events = drain(client)
    newest: dict[str, list[int]] = {}
    for e in events:
        if e.kind == "state" and e.message:
            newest.setdefault(e.vehicle_id, []).append(e.message["seq"])
    return client, newest


def test_a_stalled_reader_still_finds_every_cars_newest_state(
    car: tuple[zenoh.Session, int],
) -> None:
    """40 cars flood 300 states each, one car after the other, while nobody reads: each car
    keeps its own newest (a ring shared by the fleet kept only the last cars')."""
    cars, states = 40, 300
    client, newest = flood_unread(car, cars, states)
    assert sorted(newest) == sorted(f"car{c}" for c in range(cars))
    for vid, seqs in newest.items():  # each car's newest ring_size (2), in order
        assert seqs == [states - 1, states], vid
    assert client.overwritten == cars * (states - 2)


def test_a_look_over_its_budget_keeps_each_cars_newest_one(
    car: tuple[zenoh.Session, int],
) -> None:
    """30 cars of 5 states each while nobody reads, with a look budget of 40: two per car
    would be 60, so each car's newest one is handed out, and the rest counted."""
    cars, states = 30, 5
    client, newest = flood_unread(car, cars, states, look_states=40)
    assert newest == {f"car{c}": [states] for c in range(cars)}
    assert client.overwritten == cars * (states - 1)


def test_many_new_cars_are_asked_for_with_one_query_a_few_one_each() -> None:
    """A fleet appearing at once (a monitor opening on it, a router restart) costs one query of
    the fleet at the next get, not one per car; three cars are asked one by one."""
    from guidance.telemetry.client import MANY_NEW_CARS

    with MonitorClient(["tcp/127.0.0.1:9"]) as client:  # nobody there: the queries go unanswered
        for i in range(MANY_NEW_CARS + 4):
            client.query_latest(f"car{i}")
        assert client.queries == 0  # asked at the next get
        client.get(0)
        assert client.queries == 1
        for i in range(3):
            client.query_latest(f"late{i}")
        client.get(0)
        assert client.queries == 4


def test_the_pause_between_looks_grows_with_the_look_and_is_capped() -> None:
    """Half the reader's time at most on folding (a look of 0.1 s: 0.1 s of pause), a look of
    microseconds barely waits, and nothing waits longer than MAX_PAUSE_S."""
    from guidance.telemetry.client import BUSY_FRACTION, MAX_PAUSE_S, pause_after

    assert BUSY_FRACTION == 0.5
    assert pause_after(0.1) == pytest.approx(0.1)
    assert pause_after(20e-6) == pytest.approx(20e-6)
    assert pause_after(3.0) == MAX_PAUSE_S
    assert pause_after(-1.0) == 0.0


def test_twenty_cars_through_a_router_all_reach_the_latest_view() -> None:
    """20 cars, each a zenoh client session of one router with a liveliness token, publish
    state at 10 Hz for 2 s; the monitor's view (FleetView, what the table, --json and the
    web map show) holds every car, each at its last state. Not timed."""
    from guidance.tools.monitor_view import FleetView

    port = free_port()
    router = open_session(session_config(mode="router", listen=[f"tcp/127.0.0.1:{port}"]))
    sessions: list[zenoh.Session] = []
    try:
        with MonitorClient([f"tcp/127.0.0.1:{port}"]) as client:
            pubs, tokens = [], []
            for c in range(20):
                s = open_session(session_config(mode="client", connect=[f"tcp/127.0.0.1:{port}"]))
                sessions.append(s)
                pubs.append(s.declare_publisher(f"guidance/car{c:02d}/state"))
                tokens.append(s.liveliness().declare_token(f"guidance/car{c:02d}"))
            wait_for_match(pubs)
            view = FleetView()
            rounds = 20
            for r in range(1, rounds + 1):
                for c, pub in enumerate(pubs):
                    body = json.loads(message("state", r))
                    body.update(vehicle_id=f"car{c:02d}", x_m=float(c), y_m=float(r))
                    pub.put(json.dumps(body).encode())
                deadline = time.monotonic() + 0.1
                while (e := client.get(max(0.0, deadline - time.monotonic()))) is not None:
                    view.apply(e)
            for e in drain(client, 1.0):
                view.apply(e)
    finally:
        for s in sessions:
            s.close()
        router.close()
    assert sorted(view.cars) == [f"car{c:02d}" for c in range(20)]
    for c in range(20):
        state = view.cars[f"car{c:02d}"].state
        assert state is not None and state["seq"] == rounds and state["x_m"] == float(c)
