"""``fluidsense keys``: CURVE key pairs for a command socket reachable from the network."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path


def register(sub) -> None:
    p = sub.add_parser("keys", help="make CURVE keys for the command socket",
                       description="Write a server key pair and a client key pair into DIR; put the client's public "
                       "key (DIR/clients/*.key) where publisher.cmd_curve.clients_dir points, and give the client "
                       "its secret key file. Secret key files are written mode 0600 and never overwritten; "
                       "an existing server key pair in DIR is kept (run again with another --client to add one).")
    p.add_argument("dir", help="output directory")
    p.add_argument("--client", default="client", help="client key name (default client)")
    p.set_defaults(func=main)


def main(args: argparse.Namespace) -> int:
    import zmq
    from fluidsense.controller.config.curve import write_key_file

    out = Path(args.dir)
    name = Path(args.client).name
    if name != args.client or name in ("", ".", "..", "server"):
        print(f"fluidsense: error: --client {args.client!r}: a plain file name other than 'server'", file=sys.stderr)
        return 2
    clients = out / "clients"
    files = {"server public": out / "server.key", "server secret": out / "server.key_secret",
             "client public": clients / f"{name}.key", "client secret": out / f"{name}.key_secret"}
    make = ["server", "client"]
    server_files = [files["server public"].exists(), files["server secret"].exists()]
    if all(server_files):  # another client for the same server: its keys stay
        make.remove("server")
    elif any(server_files):
        print(f"fluidsense: error: {out}: holds half a server key pair; remove it or choose another DIR",
              file=sys.stderr)
        return 2
    existing = [str(files[f"client {k}"]) for k in ("public", "secret") if files[f"client {k}"].exists()]
    if existing:
        print(f"fluidsense: error: {existing[0]}: exists; keys are never overwritten (remove them or "
              "choose another --client name)", file=sys.stderr)
        return 2
    try:
        clients.mkdir(parents=True, exist_ok=True)
        for who in make:
            public, secret = zmq.curve_keypair()
            write_key_file(files[f"{who} public"], public)
            write_key_file(files[f"{who} secret"], public, secret)
    except OSError as exc:
        print(f"fluidsense: error: {exc.filename or out}: {exc.strerror or exc}", file=sys.stderr)
        return 2
    for label, path in files.items():
        print(f"{label}: {path}")
    print(f"config: publisher.cmd_curve: {{server_secret_file: {files['server secret']}, "
          f"clients_dir: {clients}}}")
    return 0
