"""``fluidsense keys``: CURVE key pairs for a command socket reachable from the network."""

from __future__ import annotations

import argparse
from pathlib import Path


def register(sub) -> None:
    p = sub.add_parser("keys", help="make CURVE keys for the command socket",
                       description="Write a server key pair and a client key pair into DIR; put the client's public "
                       "key (DIR/clients/*.key) where publisher.cmd_curve.clients_dir points, and give the client "
                       "its secret key file.")
    p.add_argument("dir", help="output directory")
    p.add_argument("--client", default="client", help="client key name (default client)")
    p.set_defaults(func=main)


def main(args: argparse.Namespace) -> int:
    import zmq.auth

    out = Path(args.dir)
    (out / "clients").mkdir(parents=True, exist_ok=True)
    server_public, server_secret = zmq.auth.create_certificates(out, "server")
    client_public, client_secret = zmq.auth.create_certificates(out, args.client)
    Path(client_public).rename(out / "clients" / Path(client_public).name)
    print(f"server secret: {server_secret}\nserver public: {server_public}\n"
          f"client public: {out / 'clients' / Path(client_public).name}\nclient secret: {client_secret}\n"
          f"config: publisher.cmd_curve: {{server_secret_file: {server_secret}, clients_dir: {out / 'clients'}}}")
    return 0
