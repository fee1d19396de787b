"""`track-display`: the live track table in a terminal, for thousands of tracks.

Draws every track of the latest `<ns>/frame` (position, range, speed, heading, sigma,
status; age since its last `tracks/` update), sorted, filtered by id and paged, under a
line of service health: the trackers alive (liveliness tokens), and from `<ns>/status`
asked every second: clock, uptime, accepted and rejected measurements with rejects per
second, frames per second, queue. At start it asks for the latest frame and the tracks'
states, so the table is full at once even when the picture is paused.

Keys: s next sort column, 1-9 and 0 sort by that column (again: reverse), r reverse,
/ filter by id (Enter applies, Esc cancels), c clear the filter, n / space / PgDn next
page, p / PgUp previous page, g / G first / last page, q quit.

With `--once`, or when stdout is not a terminal, it prints the table as plain text
instead: once (after the first frame and two status replies) with `--once`, else at
every refresh.
"""

from __future__ import annotations

import argparse
import contextlib
import os
import queue
import select
import sys
import threading
import time
from collections.abc import Iterator

import zenoh
from rich import box
from rich.console import Console, Group
from rich.live import Live
from rich.table import Table as RichTable
from rich.text import Text

from zenoh_track.clients.display.model import (
    COLUMNS,
    SORTS,
    Frame,
    Health,
    Table,
    fmt_int,
    fmt_t,
)
from zenoh_track.clients.lib import Client
from zenoh_track.wire import Keys, add_zenoh_args, on_signals, open_session, unpack

STATUS_STYLE = {"confirmed": "green", "tentative": "yellow", "coasting": "bright_black"}
HELP = ("s sort · 1-0 column · r reverse · / filter · c clear · n/p page · g/G first/last "
        "· q quit")


def parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="track-display", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--hz", type=float, default=4.0, help="screen refreshes per second")
    p.add_argument("--sort", choices=SORTS, default="id", help="sort column at start")
    p.add_argument("--reverse", action="store_true", help="sort in descending order")
    p.add_argument("--filter", default="", metavar="TEXT",
                   help="show only tracks whose id contains TEXT")
    p.add_argument("--rows", type=int, default=None, metavar="N",
                   help="rows per page (default: as many as the terminal holds; 40 in text)")
    p.add_argument("--page", type=int, default=1, metavar="N", help="page to show at start")
    p.add_argument("--once", action="store_true",
                   help="print the table and the service's health once, as text, and exit")
    p.add_argument("--wait", type=float, default=10.0, metavar="S",
                   help="--once: wait at most this long for a frame")
    add_zenoh_args(p)
    return p


class Picture:
    """The Zenoh side: the picture of every instance (the client library's merge),
    track updates, liveliness and status into a Table and a Health, under one lock."""

    def __init__(self, session: zenoh.Session, keys: Keys, table: Table) -> None:
        self.session, self.keys = session, keys
        self.table, self.health = table, Health()
        self.lock = threading.Lock()
        self.got_frame = threading.Event()
        self.statuses = 0
        self.stop = threading.Event()
        self.subs = [
            session.declare_subscriber(keys.space("tracks"), self._on_track),
            session.liveliness().declare_subscriber(keys.alive("*"), self._on_token,
                                                    history=True),
        ]
        self.client = Client(session, keys.ns, own=False)
        # asks every instance for its latest frame at once: the table is full at once
        # even when a lockstep picture is paused
        self.picture = self.client.picture(maxlen=1, on_frame=self._on_frame)
        threading.Thread(target=self._catch_up, daemon=True).start()
        threading.Thread(target=self._poll_status, daemon=True).start()

    def _on_frame(self, frame: Frame) -> None:
        """A picture drawn (frames that are not frames are left out by the library: the
        table keeps the last one)."""
        with self.lock:
            self.table.on_frame(frame)
            self.health.serving = frame.instances
            self.health.frame_walls.append(time.monotonic())
        self.got_frame.set()

    def _on_track(self, s: zenoh.Sample) -> None:
        if s.kind == zenoh.SampleKind.DELETE:
            return  # the next frame leaves it out
        try:
            msg = unpack(s.payload.to_bytes())
            tid, t = str(s.key_expr).rsplit("/", 1)[-1], float(msg["t"])
        except (ValueError, KeyError, TypeError, AttributeError):
            return
        with self.lock:
            self.table.on_update(tid, t)

    def _on_token(self, s: zenoh.Sample) -> None:
        name = str(s.key_expr).rsplit("/", 1)[-1]
        with self.lock:
            if s.kind == zenoh.SampleKind.PUT:
                self.health.alive.add(name)
            else:
                self.health.alive.discard(name)

    def _catch_up(self) -> None:
        """Every track's state at once: a paused lockstep picture may publish nothing
        for long."""
        for reply in self.session.get(self.keys.space("tracks"), target=zenoh.QueryTarget.ALL,
                                      timeout=5):
            if reply.ok is not None:
                self._on_track(reply.ok)

    def _poll_status(self, period: float = 1.0) -> None:
        """Every instance's status, once a period."""
        while not self.stop.is_set():
            asked = time.monotonic()
            try:
                statuses = self.client.statuses(timeout=period * 0.9)
            except (ValueError, zenoh.ZError):
                statuses = []
            if statuses:
                with self.lock:
                    self.health.on_statuses(statuses)
                    self.statuses += 1
            self.stop.wait(max(period - (time.monotonic() - asked), 0.0))

    def close(self) -> None:
        self.stop.set()
        self.client.close()
        for sub in self.subs:
            sub.undeclare()


def render(pic: Picture, ns: str, editing: str | None = None, keys: bool = True) -> Group:
    """The screen: title, health, the page of the table, and (`keys`) the keys."""
    with pic.lock:
        view = pic.table.view()
        t = pic.table.frame.t if pic.table.frame is not None else None
        health, ok = pic.health.line(ns)
        table = pic.table
        sort, reverse, filt = table.sort, table.reverse, table.filter
    shown = f"{view.first + 1}-{view.first + len(view.rows)}" if view.rows else "0"
    title = Text.assemble(
        ("track-display", "bold"), f"  ns={ns}  t={fmt_t(t)}  tracks={view.total}  ",
        f"shown {shown} of {fmt_int(view.matched)}  page {view.page + 1}/{view.pages}  ",
        f"sort {sort} {'↓' if reverse else '↑'}  ",
        f"filter {filt!r}" if filt else "no filter")
    grid = RichTable(box=box.SIMPLE_HEAD, pad_edge=False, expand=False)
    for name, (head, justify) in COLUMNS.items():
        grid.add_column(head + (" ↓" if reverse else " ↑") * (name == sort),
                        justify=justify, no_wrap=True)
    for row in view.rows:
        grid.add_row(*(row[c] for c in COLUMNS),
                     style=STATUS_STYLE.get(row["status"]))
    footer = Text(f"filter: {editing}█  (Enter apply, Esc cancel)" if editing is not None
                  else HELP, style="dim")
    parts = [title, Text(health, style=None if ok else "bold red"), grid]
    return Group(*parts, footer) if keys else Group(*parts)


class KeyReader:
    """Keys pressed on the terminal (cbreak mode while it runs), as names."""

    SEQUENCES = {"\x1b[5~": "pgup", "\x1b[6~": "pgdn", "\x1b[H": "home", "\x1b[F": "end",
                 "\x1b[C": "pgdn", "\x1b[D": "pgup", "\r": "enter", "\n": "enter",
                 "\x7f": "backspace", "\x08": "backspace", "\x1b": "esc"}

    def __init__(self) -> None:
        self.keys: queue.SimpleQueue[str] = queue.SimpleQueue()
        self.stop = threading.Event()

    @contextlib.contextmanager
    def running(self) -> Iterator[KeyReader]:
        import termios
        import tty

        fd = sys.stdin.fileno()
        saved = termios.tcgetattr(fd)
        tty.setcbreak(fd)
        thread = threading.Thread(target=self._read, args=(fd,), daemon=True)
        thread.start()
        try:
            yield self
        finally:
            self.stop.set()
            thread.join(timeout=1)
            termios.tcsetattr(fd, termios.TCSADRAIN, saved)

    def _read(self, fd: int) -> None:
        while not self.stop.is_set():
            ready, _, _ = select.select([fd], [], [], 0.1)
            if not ready:
                continue
            data = os.read(fd, 64).decode(errors="ignore")
            while data:
                for seq in sorted(self.SEQUENCES, key=len, reverse=True):
                    if data.startswith(seq) and (seq != "\x1b" or len(data) == 1
                                                 or data[1] not in "[O"):
                        self.keys.put(self.SEQUENCES[seq])
                        data = data[len(seq):]
                        break
                else:
                    if data.startswith("\x1b"):  # an escape sequence we do not use
                        data = data[3:]
                        continue
                    self.keys.put(data[0])
                    data = data[1:]


def handle(key: str, table: Table, editing: str | None) -> tuple[str | None, bool]:
    """Apply one key: the filter text being edited (None: not editing), and whether to
    quit."""
    if editing is not None:
        if key == "enter":
            table.set_filter(editing)
            return None, False
        if key == "esc":
            return None, False
        if key == "backspace":
            return editing[:-1], False
        return (editing + key if len(key) == 1 and key.isprintable() else editing), False
    if key == "q":
        return None, True
    if key == "/":
        return table.filter, False
    if key == "c":
        table.set_filter("")
    elif key == "s":
        table.cycle_sort()
    elif key == "r":
        table.reverse = not table.reverse
    elif key in "1234567890" and len(key) == 1:
        table.set_sort(SORTS[(int(key) - 1) % 10])
    elif key in ("n", " ", "pgdn"):
        table.turn(1)
    elif key in ("p", "pgup"):
        table.turn(-1)
    elif key in ("g", "home"):
        table.page = 0
    elif key in ("G", "end"):
        table.page = 10**9  # clamped to the last page
    return None, False


def interactive(pic: Picture, args: argparse.Namespace) -> None:
    console = Console()
    editing: str | None = None
    with KeyReader().running() as reader, Live(console=console, screen=True,
                                               auto_refresh=False) as live:
        while True:
            if args.rows is None:
                with pic.lock:
                    pic.table.page_size = max(console.size.height - 9, 5)
            live.update(render(pic, args.ns, editing), refresh=True)
            deadline = time.monotonic() + 1.0 / args.hz
            while (wait := deadline - time.monotonic()) > 0:
                try:
                    key = reader.keys.get(timeout=wait)
                except queue.Empty:
                    break
                with pic.lock:
                    editing, quit_ = handle(key, pic.table, editing)
                if quit_:
                    return
                break  # redraw at once after a key


def text(pic: Picture, args: argparse.Namespace) -> None:
    """Plain text on stdout: once (--once), else at every refresh."""
    console = Console(width=max(Console().size.width, 120), no_color=True, highlight=False)
    if args.once:
        pic.got_frame.wait(args.wait)
        deadline = time.monotonic() + 3.0  # two status replies give the rates
        while pic.statuses < 2 and time.monotonic() < deadline:
            time.sleep(0.05)
    while True:
        console.print(render(pic, args.ns, keys=False))
        sys.stdout.flush()
        if args.once:
            return
        time.sleep(1.0 / args.hz)


def main(argv: list[str] | None = None) -> None:
    args = parser().parse_args(argv)
    on_signals(interrupt=True)
    table = Table(sort=args.sort, reverse=args.reverse, filter=args.filter,
                  page=max(args.page - 1, 0), page_size=args.rows or 40)
    session = open_session(args, log=True)
    pic = Picture(session, Keys(args.ns), table)
    try:
        if args.once or not sys.stdout.isatty() or not sys.stdin.isatty():
            text(pic, args)
        else:
            interactive(pic, args)
    except KeyboardInterrupt:
        pass
    finally:
        pic.close()
        session.close()


if __name__ == "__main__":
    main()


