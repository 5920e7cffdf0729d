"""docs/zmq-schema.md holds a schema for every topic the daemon publishes. (`fluidsense run`
over real ZeroMQ sockets, each message checked against those schemas:
tests/system/test_zmq.py.)"""

from __future__ import annotations

from support.events import SCHEMAS


def test_the_document_has_a_schema_per_topic():
    assert set(SCHEMAS) == {"heartbeat", "state", "cycle", "pressure", "fault", "task", "log", "contact", "grasp",
                            "slip", "released"}
    assert all(schema.get("additionalProperties") is False for schema in SCHEMAS.values())


def _turn(outlet, sub, want, turns=200):
    """Let the outlet read what subscribers sent and move what the daemon queued, until ``sub``
    has a message matching ``want`` (None after ``turns`` turns): inproc, one thread."""
    for _ in range(turns):
        outlet.read_subscriptions()
        outlet.forward()
        while sub.poll(0):
            frames = sub.recv_multipart()
            if want(frames):
                return frames
        sub.poll(5)  # waits on the pipe, bounded; the outlet turns again either way
    return None


def test_the_welcome_comes_once_the_subscriptions_are_in():
    """The welcome promises that everything published after it reaches the subscriber. A
    subscriber that is connected but has not subscribed yet gets no welcome (it would drop it
    anyway); once it subscribes to its topic and then to hello, the welcome comes, and the
    very next event reaches it: the outlet sends it only after the subscription to hello,
    and so every subscription before it, is in the trie."""
    import zmq
    from fluidsense.common.names import welcome_instance
    from fluidsense.controller.telemetry.outlet import Outlet

    ctx = zmq.Context()
    outlet = Outlet(ctx, "inproc://welcome-pub", "inproc://welcome-inlet", hwm=100, instance="0123456789abcdef")
    daemon = ctx.socket(zmq.PUSH)
    daemon.connect("inproc://welcome-inlet")
    sub = ctx.socket(zmq.SUB)
    sub.connect("inproc://welcome-pub")
    try:
        assert _turn(outlet, sub, lambda frames: True, turns=20) is None  # attached, nothing subscribed
        sub.setsockopt(zmq.SUBSCRIBE, b"state")
        sub.setsockopt(zmq.SUBSCRIBE, b"hello")
        welcome = _turn(outlet, sub, lambda frames: welcome_instance(frames) is not None)
        assert welcome is not None and welcome_instance(welcome) == "0123456789abcdef"
        daemon.send_multipart([b"state", b'{"to": "charge"}'])
        assert _turn(outlet, sub, lambda frames: len(frames) == 2) == [b"state", b'{"to": "charge"}']
        # a second subscriber's welcome reaches the first too, with the same id, which it ignores
        other = ctx.socket(zmq.SUB)
        other.connect("inproc://welcome-pub")
        other.setsockopt(zmq.SUBSCRIBE, b"hello")
        assert welcome_instance(_turn(outlet, other, lambda frames: True)) == "0123456789abcdef"
        assert sub.poll(1000) and welcome_instance(sub.recv_multipart()) == "0123456789abcdef"
        other.close(0)
    finally:
        for s in (sub, daemon, outlet.xpub, outlet.inlet):
            s.close(0)
        ctx.term()
