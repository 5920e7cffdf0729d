"""``fluidsense monitor`` and ``fluidsense cmd``: clients of a running daemon."""

from __future__ import annotations

import argparse
import json
import sys

from fluidsense.common.exitcodes import EXIT_BAD_INPUT, EXIT_OK, EXIT_TIMEOUT
from fluidsense.common.names import COMMANDS


def register(sub) -> None:
    p = sub.add_parser("monitor", help="show live state and results from a running daemon",
                       description="One screen, updated in place: state and cycle phase, pressure now with a "
                       "trace of the last seconds, valve outputs as the device reports them, the last results, "
                       "faults with what to do. With --log (or any of --count, --timeout, --topic, --all, "
                       "--json, or when the output is not a terminal): one line per message, for scripts.")
    p.add_argument("--log", action="store_true", help="one line per message instead of the screen")
    p.add_argument("--config", "-c", help="cell config naming the endpoint (default: config/cell-sim.yaml)")
    p.add_argument("--endpoint", help="PUB endpoint, e.g. tcp://127.0.0.1:5560 (overrides --config)")
    p.add_argument("--cmd-endpoint", help="command endpoint the screen asks for status once a second "
                   "(default: the config's, unless it needs CURVE keys)")
    p.add_argument("--topic", action="append", help="topic to show (repeatable; default: all but pressure)")
    p.add_argument("--all", action="store_true", help="every topic, pressure included")
    p.add_argument("--count", type=int, help="exit after this many messages")
    p.add_argument("--timeout", type=float, help="exit after this many seconds without a message")
    p.add_argument("--json", action="store_true", help="print raw JSON messages")
    p.set_defaults(func=cmd_monitor)

    p = sub.add_parser("cmd", help="send one request to the command socket",
                       description="Send a request and print the reply, e.g. "
                       "fluidsense cmd status, fluidsense cmd '{\"cmd\": \"cycle\", \"store_reference\": true}'.")
    p.add_argument("request", help=f"a command name ({', '.join(COMMANDS)}) or a JSON object; the commands and "
                   "their fields: docs/zmq-schema.md")
    p.add_argument("--config", "-c", help="cell config naming the endpoint (default: config/cell-sim.yaml)")
    p.add_argument("--endpoint", help="command endpoint, e.g. tcp://127.0.0.1:5561")
    p.add_argument("--timeout", type=float, default=5.0)
    p.add_argument("--client-key", help="CURVE: this client's secret key file (with --server-key)")
    p.add_argument("--server-key", help="CURVE: the daemon's public key file")
    p.add_argument("--wait", type=float, metavar="SECONDS", nargs="?", const=120.0,
                   help="for a request that starts a cycle (cycle, measure, grip): also wait up to SECONDS "
                   "(default 120) for that cycle's result (topic cycle, from the publisher the config names) "
                   "and print it; for a grip, its grasp (topic grasp: the gripper holds until a release)")
    p.set_defaults(func=cmd_cmd)


def cmd_monitor(args: argparse.Namespace) -> int:
    from fluidsense.daemon import app

    from ..monitor import monitor

    endpoint, cmd_endpoint = args.endpoint, args.cmd_endpoint
    if endpoint is None or (cmd_endpoint is None and args.config is not None):
        publisher = app.load(args.config).publisher
        endpoint = endpoint or publisher.pub
        if cmd_endpoint is None and publisher.cmd_curve is None:
            cmd_endpoint = publisher.cmd
    lines = args.log or args.json or args.all or args.topic or args.count is not None or args.timeout is not None
    if not lines and sys.stdout.isatty():
        from ..screen import run_screen

        return run_screen(endpoint, cmd_endpoint)
    topics = args.topic or ["state", "cycle", "heartbeat", "fault", "task", "log"]
    if args.all:
        topics = [""]
    return monitor(endpoint, topics, args.count, args.timeout, args.json)


def cmd_cmd(args: argparse.Namespace) -> int:
    from fluidsense.daemon import app

    from ..monitor import send_command

    endpoint = args.endpoint or app.load(args.config).publisher.cmd
    try:
        request = json.loads(args.request)
    except json.JSONDecodeError:
        request = {"cmd": args.request}
    curve = (args.client_key, args.server_key) if args.client_key and args.server_key else None
    if curve is not None:
        from fluidsense.controller.config.curve import read_secret_key

        read_secret_key(args.client_key)  # refused when others can read it, like the daemon's own key
    if args.wait is not None:
        return _cmd_and_wait(args, endpoint, request, curve)
    reply = send_command(endpoint, request, args.timeout, curve=curve)
    print(json.dumps(reply, indent=2))
    return EXIT_OK if reply.get("ok") else EXIT_BAD_INPUT


def _cmd_and_wait(args: argparse.Namespace, endpoint: str, request: dict, curve) -> int:
    """The request, then its cycle's result: subscribed first (the daemon's welcome), so a
    result that comes at once is not lost; a result from another daemon instance is not it."""
    from fluidsense.client import Gripper
    from fluidsense.client.types import NoReply, Refused
    from fluidsense.daemon import app

    pub = app.load(args.config).publisher.pub
    # a held grip's cycle ends only at its release: what it answers is its grasp
    topic = "grasp" if request.get("cmd") == "grip" else "cycle"
    with Gripper(endpoint, pub, timeout_s=args.timeout, event_timeout_s=args.wait, curve=curve,
                 topics=(topic,)) as g:
        try:
            reply = g.request(request)
        except Refused as exc:
            print(json.dumps(exc.reply, indent=2))
            return EXIT_BAD_INPUT
        except NoReply as exc:
            raise TimeoutError(f"{exc}: is the daemon running?") from exc
        print(json.dumps(reply, indent=2))
        if "cycle_id" not in reply:
            return EXIT_OK  # nothing started: nothing to wait for
        try:
            result = g.wait_for(topic, reply["cycle_id"], args.wait, instance=reply.get("instance"))
        except NoReply as exc:
            print(f"fluidsense: {exc}", file=sys.stderr)
            return EXIT_TIMEOUT
    print(json.dumps(result.data, indent=2))
    return EXIT_OK
