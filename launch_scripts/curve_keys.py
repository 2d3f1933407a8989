"""Create the CURVE keys of a deployment: the services' key pair and the clients' key pairs.

    python -m launch_scripts.curve_keys DIR [--client NAME ...]

Writes DIR/server.key_secret (the services' key pair: keep it on the machines that run the
services), DIR/server.key (its public key: give it to every client), and for each client
NAME (default: one named "controller") DIR/clients/NAME.key_secret and NAME.key, with its
public key copied to DIR/authorized_clients/. Existing key pairs are kept, so running it
again with a new name adds a client. Start the services with --curve-keys DIR; hand
clients/NAME.key_secret and server.key to the client NAME (then delete the secret file
here), and see docs/protocol.md section 9 for how a client connects. Exit status 2 with one
line on stderr for a bad name or an unwritable directory.
"""

from __future__ import annotations

import sys

import zmq

from ipc.transport import create_key_directory
from launch_scripts.cli import OneLineParser


def build_parser() -> OneLineParser:
    parser = OneLineParser(prog="python -m launch_scripts.curve_keys", description=__doc__.split("\n\n")[0])
    parser.add_argument("directory", metavar="DIR", help="key directory to create or extend")
    parser.add_argument("--client", action="append", metavar="NAME",
                        help="a client to create a key pair for and authorise (repeatable; default: controller)")
    return parser


def main(argv=None) -> int:
    args = build_parser().parse_args(argv)
    if not zmq.has("curve"):
        print("error: this libzmq was built without CURVE", file=sys.stderr)
        return 2
    try:
        written = create_key_directory(args.directory, args.client or ["controller"])
    except (ValueError, OSError) as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    for path in written:
        print(path)
    return 0


if __name__ == "__main__":
    sys.exit(main())
