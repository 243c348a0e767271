"""Who holds a connection or a session of the OPC UA front (plugins/opcua/admission.py),
time injected. Issue 29 D4: 32 silent sockets or 32 sessions locked every client out."""

from __future__ import annotations

from fieldgate.plugins.opcua.admission import Admission, AdmissionLimits

LIMITS = AdmissionLimits(
    max_connections=6,
    max_connections_per_peer=3,
    max_sessions=4,
    max_sessions_per_peer=2,
    hello_timeout=5.0,
    activation_timeout=15.0,
)


def test_silent_sockets_of_one_peer_make_room_for_that_peer_only():
    adm = Admission(LIMITS)
    for i in range(3):
        assert adm.open(f"a{i}", "10.0.0.1", now=i) == []
    # the 4th from the same address: its oldest silent connection gives way
    assert adm.open("a3", "10.0.0.1", now=3) == [("a0", "connection_evicted")]
    assert adm.open("b0", "10.0.0.2", now=4) == []
    assert sorted(adm.connections) == ["a1", "a2", "a3", "b0"]


def test_a_session_outranks_a_silent_socket_and_the_idlest_session_goes_first():
    adm = Admission(LIMITS)
    for i, key in enumerate(("s1", "s2", "quiet")):
        adm.open(key, "10.0.0.1", now=i)
        adm.hello(key)
        adm.activated(key)
    adm.message("s1", now=10)
    adm.message("s2", now=11)
    adm.message("quiet", now=3)
    assert adm.open("new", "10.0.0.1", now=12) == [("quiet", "connection_evicted")]
    # over again: of s1, s2 (sessions) and new (no session yet), new gives way
    assert adm.open("silent", "10.0.0.1", now=13) == [("new", "connection_evicted")]


def test_over_the_total_the_crowding_address_gives_way_not_another():
    adm = Admission(LIMITS)
    adm.open("plc-scada", "10.0.0.9", now=0)  # a client that is alone and silent for now
    for i in range(3):
        adm.open(f"x{i}", "10.0.0.2", now=1 + i)
    adm.open("y0", "10.0.0.3", now=5)
    adm.open("y1", "10.0.0.3", now=6)
    # 7th connection in all: 10.0.0.2 holds the most, so one of its own goes
    assert adm.open("z0", "10.0.0.4", now=7) == [("x0", "connection_evicted")]
    assert "plc-scada" in adm.connections


def test_a_new_connection_is_refused_only_when_nothing_else_can_give_way():
    adm = Admission(AdmissionLimits(1, 1, 1, 1, 5.0, 15.0))
    assert adm.open("a", "10.0.0.1", now=0) == []
    assert adm.open("b", "10.0.0.1", now=1) == [("a", "connection_evicted")]
    assert adm.open("c", "10.0.0.2", now=2) == [("b", "connection_evicted")]
    none = Admission(AdmissionLimits(0, 0, 0, 0, 5.0, 15.0))  # (the configuration allows >= 1)
    assert none.open("only", "10.0.0.1", now=0) == [("only", "too_many_connections")]
    assert none.connections == {}


def test_hello_and_activation_deadlines():
    adm = Admission(LIMITS)
    adm.open("silent", "10.0.0.1", now=0)
    adm.open("hello-only", "10.0.0.1", now=0)
    adm.hello("hello-only")
    adm.open("good", "10.0.0.2", now=0)
    adm.hello("good")
    adm.activated("good")
    assert adm.expired(now=4.9) == []
    assert adm.expired(now=5.1) == [("silent", "hello_timeout")]
    assert sorted(adm.expired(now=15.1)) == [
        ("hello-only", "activation_timeout"),
        ("silent", "hello_timeout"),
    ]
    adm.closed("silent")
    adm.closed("hello-only")
    assert adm.expired(now=1000) == []


def test_sessions_detached_ones_go_first_then_the_idlest():
    adm = Admission(LIMITS)
    adm.register_session("s1", "10.0.0.1", now=0)
    adm.register_session("s2", "10.0.0.1", now=0)
    adm.session_state("s1", activated=True, attached=True, last_activity=50)
    adm.session_state("s2", activated=True, attached=False, last_activity=90)  # its client left
    victims = adm.session("new", "10.0.0.1", now=100)
    assert victims == [("s2", "session_evicted")]
    adm.session_closed("new")
    adm.register_session("s3", "10.0.0.1", now=100)
    adm.session_state("s3", activated=True, attached=True, last_activity=99)
    assert adm.session("newer", "10.0.0.1", now=101) == [("s1", "session_evicted")]


def test_forgotten_sessions_are_not_counted():
    adm = Admission(LIMITS)
    for key in ("s1", "s2"):
        adm.register_session(key, "10.0.0.1", now=0)
    adm.keep_sessions(["s2"])
    assert list(adm.sessions) == ["s2"]
    assert adm.session("s3", "10.0.0.1", now=1) == []
