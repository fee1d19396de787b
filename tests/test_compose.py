"""docker-compose.yml: static checks, then the same topology as local processes on loopback.

The compose file is read with a small parser of the YAML subset it keeps to (no PyYAML
dependency). The loopback mirror runs a real Zenoh router (a Python session opened from
deploy/router.json5), two `track-service` shards in client mode with the compose file's
own `--meas` partitions and config files, and a feed, all on a free 127.0.0.1 port, and
checks that every target is tracked by exactly one shard.
"""

from __future__ import annotations

import json
import re
import subprocess
import sys
import tomllib
import uuid
from pathlib import Path
from typing import Any

import pytest
import zenoh
from conftest import Collector

from zenoh_track import __main__ as service_cli
from zenoh_track.clients import Client, ServiceProcess
from zenoh_track.clients.feeds import feed as feed_cli
from zenoh_track.clients.lib.process import stop
from zenoh_track.wire import Keys, free_port, unpack, wait_for_tracker

ROOT = Path(__file__).resolve().parent.parent
COMPOSE = ROOT / "docker-compose.yml"
SHARDS = ("shard-a", "shard-b")


# ---------------------------------------------------------------- YAML subset
class SubsetError(ValueError):
    pass


_KEY = re.compile(r"^([A-Za-z0-9_.-]+):(?: (.*))?$")
_INT = re.compile(r"^-?[0-9]+$")


def _scalar(text: str, where: int) -> Any:
    text = text.strip()
    try:
        if text[:1] in ('"', "[", "{"):
            return json.loads(text)
        if text[:1] == "'":
            if len(text) < 2 or not text.endswith("'"):
                raise ValueError("unterminated single-quoted string")
            return text[1:-1].replace("''", "'")
    except ValueError as exc:
        raise SubsetError(f"line {where}: {exc}") from None
    if text in ("true", "false"):
        return text == "true"
    if _INT.match(text):
        return int(text)
    if not text or text[0] in "*&!|>%@`#?-" or ": " in text or " #" in text:
        raise SubsetError(f"line {where}: plain scalar outside the subset: {text!r}")
    return text


def load_subset(text: str) -> dict[str, Any]:
    """Parse the YAML subset of docker-compose.yml: block mappings, block lists of
    scalars, comments on their own lines. Anything else raises SubsetError (so an edit
    outside the subset fails here loudly rather than being misread)."""
    lines: list[tuple[int, int, str]] = []  # (line number, indent, content)
    for no, raw in enumerate(text.splitlines(), 1):
        if "\t" in raw:
            raise SubsetError(f"line {no}: tab")
        body = raw.rstrip()
        if not body.strip() or body.lstrip().startswith("#"):
            continue
        lines.append((no, len(body) - len(body.lstrip(" ")), body.strip()))

    def block(i: int, indent: int) -> tuple[Any, int]:
        if lines[i][2].startswith("- ") or lines[i][2] == "-":
            out: list[Any] = []
            while i < len(lines) and lines[i][1] == indent and lines[i][2].startswith("- "):
                out.append(_scalar(lines[i][2][2:], lines[i][0]))
                i += 1
        else:
            out = {}  # type: ignore[assignment]
            while i < len(lines) and lines[i][1] == indent:
                no, _, content = lines[i]
                m = _KEY.match(content)
                if not m:
                    raise SubsetError(f"line {no}: not 'key: value': {content!r}")
                key, rest = m.group(1), m.group(2)
                if key in out:
                    raise SubsetError(f"line {no}: duplicate key {key!r}")
                if rest is None or not rest.strip():
                    if i + 1 >= len(lines) or lines[i + 1][1] <= indent:
                        raise SubsetError(f"line {no}: {key!r} has no value")
                    out[key], i = block(i + 1, lines[i + 1][1])  # type: ignore[index]
                else:
                    out[key] = _scalar(rest, no)  # type: ignore[index]
                    i += 1
        if i < len(lines) and lines[i][1] > indent:
            raise SubsetError(f"line {lines[i][0]}: unexpected indentation")
        return out, i

    if not lines:
        return {}
    doc, end = block(0, lines[0][1])
    if end != len(lines) or not isinstance(doc, dict):
        raise SubsetError(f"line {lines[end][0] if end < len(lines) else '?'}: "
                          "unexpected dedent")
    return doc


def compose() -> dict[str, Any]:
    return load_subset(COMPOSE.read_text())["services"]


def unescape(arg: str) -> str:
    """Compose interpolation: `$$` is a literal `$`; a single `$` would be a variable."""
    assert "$" not in arg.replace("$$", ""), f"unescaped '$' in {arg!r} (write '$$')"
    return arg.replace("$$", "$")


def host_path(service: dict[str, Any], path: str) -> Path:
    """The repository file behind a container path, through the service's bind mounts."""
    for vol in service.get("volumes", []):
        src, dst = vol.split(":")[:2]
        if path == dst or path.startswith(dst.rstrip("/") + "/"):
            return (ROOT / src / path[len(dst):].lstrip("/")).resolve()
    raise AssertionError(f"{path} is not under any mounted volume of {service}")


def config_arg(cmd: list[str]) -> str:
    for flag in ("-c", "--config"):
        if flag in cmd:
            return cmd[cmd.index(flag) + 1]
    raise AssertionError(f"no -c/--config in {cmd}")


def meas_exprs(cmd: list[str]) -> list[str]:
    return [unescape(cmd[i + 1]) for i, a in enumerate(cmd) if a == "--meas"]


# ---------------------------------------------------------------- static checks
def test_subset_parser_reads_yaml_as_yaml_does():
    services = compose()
    assert set(services) == {"router", *SHARDS, "feed", "display"}
    import yaml  # the test extra's

    assert yaml.safe_load(COMPOSE.read_text())["services"] == services
    with pytest.raises(SubsetError):
        load_subset("a:\n  b: 1 # trailing comment\n")
    with pytest.raises(SubsetError):
        load_subset("a: &anchor\n")


def test_compose_commands_configs_and_router_image():
    services = compose()
    scripts = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["scripts"]
    image = services["router"]["image"]
    name, _, tag = image.partition(":")
    assert name == "eclipse/zenoh" and re.fullmatch(r"1\.\d+\.\d+", tag), image  # pinned 1.x
    for sname, svc in services.items():
        cmd = [unescape(a) for a in svc["command"]]
        if sname != "router":
            assert svc["build"] == "." and cmd[0] in scripts, (sname, cmd[0])
        path = host_path(svc, config_arg(cmd))
        assert path.is_file() and path.is_relative_to(ROOT / "deploy"), path
        conf = zenoh.Config.from_file(str(path))  # the file is a valid Zenoh config
        assert json.loads(conf.get_json("scouting/multicast/enabled")) is False, path
        mode = json.loads(conf.get_json("mode"))
        if sname == "router":
            assert mode == "router"
            assert json.loads(conf.get_json("listen/endpoints")) == ["tcp/0.0.0.0:7447"]
        else:
            assert mode == "client"
            assert json.loads(conf.get_json("connect/endpoints")) == ["tcp/router:7447"]
            assert "router" in svc["depends_on"] or set(svc["depends_on"]) == set(SHARDS)
    for shard in SHARDS:  # the shards' options are the service's options
        args = service_cli.parser().parse_args(
            [unescape(a) for a in services[shard]["command"][1:]])
        assert args.instance == shard and args.meas
    feed = feed_cli.parser().parse_args(services["feed"]["command"][1:])
    assert feed.trackers == len(SHARDS)


def test_partition_tracks_every_id_exactly_once():
    services = compose()
    exprs = {s: [zenoh.KeyExpr(e) for e in meas_exprs(services[s]["command"])]
             for s in SHARDS}
    ids = [f"swarm-{i:05d}" for i in range(200)] + ["radar3d-007", "display-000", "x1"]
    for target in ids:
        key = zenoh.KeyExpr(Keys().meas("radar-a", target))
        owners = [s for s, es in exprs.items() if any(e.intersects(key) for e in es)]
        assert len(owners) == 1, (target, owners)
    keys = [e for es in exprs.values() for e in es]
    assert all(str(e).startswith("track/meas/") for e in keys)


# ---------------------------------------------------------------- loopback mirror
ROUTER = """
import json, sys, zenoh
conf = zenoh.Config.from_file(sys.argv[1])
conf.insert_json5("listen/endpoints", json.dumps([sys.argv[2]]))
session = zenoh.open(conf)
print("ready", flush=True)
sys.stdin.read()  # until the test closes our stdin
session.close()
"""


def observer(endpoint: str) -> zenoh.Session:
    conf = zenoh.Config.from_file(str(ROOT / "deploy" / "client.json5"))
    conf.insert_json5("connect/endpoints", json.dumps([endpoint]))
    return zenoh.open(conf)


def get_all(session: zenoh.Session, selector: str) -> list[tuple[str, dict]]:
    """Every reply (replier id, body): no consolidation, every matching queryable."""
    replies = session.get(selector, target=zenoh.QueryTarget.ALL,
                          consolidation=zenoh.ConsolidationMode.NONE, timeout=10)
    return [(str(r.replier_id), unpack(r.ok.payload.to_bytes())) for r in replies]


@pytest.mark.slow
def test_loopback_mirror_tracks_every_target_once():
    services = compose()
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    # a namespace of this run only: the compose file's `track/...` expressions moved to it
    ns = f"compose{uuid.uuid4().hex[:8]}"
    keys = Keys(ns)
    procs: list[subprocess.Popen] = []
    shards: list[ServiceProcess] = []
    session = None
    n_targets, duration = 40, 4.0
    names = {f"swarm-{i:05d}" for i in range(n_targets)}
    try:
        router = subprocess.Popen(
            [sys.executable, "-c", ROUTER, str(ROOT / "deploy" / "router.json5"), endpoint],
            stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
        procs.append(router)
        line = router.stdout.readline().strip()
        assert line == "ready", f"router did not start: {line!r}"
        for shard in SHARDS:
            svc = services[shard]
            cmd = [unescape(a) for a in svc["command"][1:]]
            cmd[cmd.index("-c") + 1] = str(host_path(svc, config_arg(cmd)))
            cmd = [re.sub(r"^track/", f"{ns}/", a) for a in cmd]
            shards.append(ServiceProcess(*cmd, ns=ns, connect=endpoint))  # lockstep
        session = observer(endpoint)
        display = Collector(session, keys.space("display"))
        frames = Collector(session, keys.frame)
        assert wait_for_tracker(session, keys, len(SHARDS), timeout=20), "shards not up"
        pictures: list = []  # the client library's merge of the shards' frames
        picture = Client(session, ns, own=False).picture(on_frame=pictures.append)
        feed = services["feed"]
        subprocess.run([sys.executable, "-m", "zenoh_track.clients.feeds.feed", "swarm",
                       "--targets",
                        str(n_targets), "--duration", str(duration), "--trackers", "2",
                        "-c", str(host_path(feed, config_arg(feed["command"]))),
                        "-e", endpoint, "--ns", ns],
                       capture_output=True, text=True, timeout=60, check=True)
        # the feed's closing clock message releases every instant before duration + 1 s
        t_last = duration + 29 / 30 - 1e-9
        shown_last = lambda ss: {k.rsplit("/", 1)[1] for k, _, b in ss  # noqa: E731
                                 if b and b["t"] >= t_last}
        assert display.wait_for(lambda ss: shown_last(ss) == names, timeout=20), \
            sorted(names - shown_last(display.samples))

        tracks = get_all(session, keys.space("tracks"))
        by_id: dict[str, list[str]] = {}
        for replier, body in tracks:
            by_id.setdefault(body["id"], []).append(replier)
        assert set(by_id) == names, sorted(names ^ set(by_id))
        assert all(len(r) == 1 for r in by_id.values()), by_id
        repliers = {r[0] for r in by_id.values()}
        assert len(repliers) == 2, by_id  # each shard holds its half: even / odd last digit
        for rid in repliers:
            parity = {int(t[-1]) % 2 for t, r in by_id.items() if r[0] == rid}
            assert len(parity) == 1

        status = [b for _, b in get_all(session, keys.status)]
        assert sorted(s["instance"] for s in status) == list(SHARDS), status  # one per shard
        assert sum(s["tracks"] for s in status) == n_targets
        scans = int(duration) + 1
        assert all(s["tracks"] == n_targets // 2 and s["meas_rejected"] == 0
                   and s["meas_accepted"] == n_targets // 2 * scans for s in status), status

        # display/<target> is one coherent key space: each (target, instant) once
        shown = [(k, round(b["t"], 6)) for k, kind, b in display.samples if kind == "PUT"]
        assert len(shown) == len(set(shown))
        # while each shard's frame holds only its own tracks
        last = [set(b["ids"]) for b in frames.bodies() if abs(b["t"] - duration) < 1e-9]
        assert len(last) == 2 and not last[0] & last[1] and last[0] | last[1] == names, last
        # the library's picture: one per instant, every shard's tracks in each once both
        # shards hold all of theirs (lockstep: the instants wait for both)
        picture.wait_for(lambda f: f.t >= t_last, timeout=20)
        picture.close()
        whole = next(k for k, f in enumerate(pictures) if set(f.id_list) == names)
        assert all(set(f.id_list) == names and len(f) == n_targets
                   for f in pictures[whole:]), [len(f) for f in pictures[whole:]]
        ts = [f.t for f in pictures[whole:]]
        assert ts == sorted(set(ts)) and ts[-1] >= t_last
    finally:
        if session is not None:
            session.close()
        # last-started first, each waited for before the next: the shards close their
        # sessions while the router is still there
        for svc in shards:
            svc.stop()
        for p in reversed(procs):
            stop(p)
