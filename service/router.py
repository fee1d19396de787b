"""`track-router`: a Zenoh router from the Python wheel, for machines without `zenohd`.

Takes the same Zenoh config files as `zenohd -c` (deploy/router.json5, the secured
variants under deploy/secure/): listen endpoints, TLS, user/password authentication and
access control all come from the file. `-l/--listen` and `-e/--connect` add endpoints;
the mode is always "router". Runs until SIGINT or SIGTERM (docs/operations.md).
"""

from __future__ import annotations

import argparse
import json
import sys

from . import __version__
from .wire import DEFAULT_ENDPOINT
from .wire.cli import add_version, open_or_exit, read_file
from .wire.stopping import on_signals

PROG = "track-router"


def parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="track-router", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("-c", "--config", metavar="FILE.json5",
                   help="Zenoh configuration file (as zenohd -c)")
    p.add_argument("-l", "--listen", action="append", default=[], metavar="ENDPOINT",
                   help=f"endpoint to listen on (repeatable; default {DEFAULT_ENDPOINT} "
                        "when neither this nor the config file gives one)")
    p.add_argument("-e", "--connect", action="append", default=[], metavar="ENDPOINT",
                   help="another router to connect to (repeatable)")
    add_version(p)
    return p


def router_config(args: argparse.Namespace):  # -> zenoh.Config
    """The router's zenoh.Config: the file, then the command line's endpoints; multicast
    scouting off unless the file turns it on."""
    import zenoh

    conf = zenoh.Config.from_file(args.config) if args.config else zenoh.Config()
    conf.insert_json5("mode", '"router"')
    if not args.config:
        conf.insert_json5("scouting/multicast/enabled", "false")
    listen = list(args.listen)
    if not listen and not isinstance(json.loads(conf.get_json("listen/endpoints")), list):
        listen = [DEFAULT_ENDPOINT]  # the file sets none (Zenoh's default is every interface)
    if listen:
        conf.insert_json5("listen/endpoints", json.dumps(listen))
    if args.connect:
        conf.insert_json5("connect/endpoints", json.dumps(args.connect))
    return conf


def main(argv: list[str] | None = None) -> None:
    args = parser().parse_args(argv)
    stop = on_signals()
    if args.config:
        read_file(args.config, "the Zenoh configuration", prog=PROG)
    with stop.interrupting():  # a stop while the router opens: at once
        session = open_or_exit(lambda: router_config(args), prog=PROG,
                               what=f" {args.config}" if args.config else "")
    listen = json.loads(router_config(args).get_json("listen/endpoints"))
    print(f"{PROG} {__version__}: router {session.info.zid()} listening on "
          f"{', '.join(map(str, listen))} (zenoh {zenoh_version()})", flush=True)
    stop.wait()
    session.close()
    sys.exit(0)


def zenoh_version() -> str:
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("eclipse-zenoh")
    except PackageNotFoundError:
        return "?"


if __name__ == "__main__":
    main()
