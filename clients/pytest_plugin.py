"""pytest plugin: a real track service for a test, on loopback (docs/client.md).

Enable it where it is wanted, in a conftest.py (or `-p zenoh_track.clients.pytest_plugin`,
or `zenoh_track = true` in the pytest ini options):

    pytest_plugins = ["zenoh_track.clients.pytest_plugin"]

Fixtures, in the manner of pytest-postgresql: `track_service` (the process: lockstep, a
free 127.0.0.1 port, a namespace of its own, options from the `track_service` marker),
`track_client` (a Client of it), `track_feed` and `track_picture`, `track` (all of them,
with `advance(t)` and `wait_for(condition)`), `track_service_factory` (start more, other
options), and `service_proc(...)` / `client(...)` to declare fixtures of other options or
scopes. A failing test's report carries the log of every service it used. Importing this
module loads neither Zenoh nor NumPy.
"""

from __future__ import annotations

import uuid
from collections.abc import Callable, Generator, Iterator
from contextlib import nullcontext
from functools import partial
from typing import TYPE_CHECKING, Any, Literal

import pytest

if TYPE_CHECKING:
    from zenoh_track.clients.lib import Client, Feed, Frame, Picture, ServiceProcess

STARTED = pytest.StashKey[list["ServiceProcess"]]()
Scope = Literal["session", "package", "module", "class", "function"]
WAIT = 60.0  # s: the most a service may take to come up (the first start compiles kernels)
PORT_TRIES = 3  # starts of a service whose free port another process took first


def pytest_configure(config: pytest.Config) -> None:
    config.addinivalue_line(
        "markers", "track_service(*args, clock='lockstep', ns=None): the options of the "
                   "track_service fixture's service (track-service's command line)")


def unique_ns() -> str:
    return f"test{uuid.uuid4().hex[:10]}"


def start(node: pytest.Item | pytest.Collector | None, *args: str, ns: str | None = None,
          clock: str | None = "lockstep", wait: float = WAIT,
          config: pytest.Config | None = None) -> ServiceProcess:
    """A ServiceProcess of these options, alive (or the test fails with its log)."""
    from zenoh_track.clients.lib import ServiceProcess

    ns = ns or unique_ns()
    for attempt in range(PORT_TRIES):
        svc = ServiceProcess(*args, ns=ns, clock=clock)
        if node is not None:
            node.stash.setdefault(STARTED, []).append(svc)
        try:
            svc.wait(wait, notice=None if config is None else partial(say, config))
        except RuntimeError as exc:
            svc.stop()
            # the free port it was given was taken before it could listen: another one
            if "address already in use" in str(exc) and "-l" not in args \
                    and attempt + 1 < PORT_TRIES:
                continue
            pytest.fail(str(exc), pytrace=False)
        return svc
    raise AssertionError("unreachable")


def say(config: pytest.Config, line: str) -> None:
    """A line on the terminal now, through pytest's capture (a first start's compile is
    half a minute of silence otherwise)."""
    capture = config.pluginmanager.getplugin("capturemanager")
    reporter = config.pluginmanager.getplugin("terminalreporter")
    if reporter is None:
        return
    with capture.global_and_fixture_disabled() if capture else nullcontext():
        reporter.write_line(f"[zenoh_track] {line}")


@pytest.hookimpl(wrapper=True)
def pytest_runtest_makereport(item: pytest.Item,
                              call: pytest.CallInfo[None]) -> Generator[None, Any, Any]:
    report = yield
    if report.failed:
        from zenoh_track.clients.lib import ServiceProcess

        started: list[ServiceProcess] = item.stash.get(STARTED, [])
        used = list(started)
        for value in getattr(item, "funcargs", {}).values():
            svc = getattr(value, "service", value)
            if isinstance(svc, ServiceProcess) and svc not in used:
                used.append(svc)
        for svc in used:
            report.sections.append((f"track-service {svc.ns} log", svc.log()[-20_000:]))
    return report


class Loopback:
    """A service with a connected client, feed and picture; `advance` its lockstep clock,
    `wait_for` a condition on its picture."""

    def __init__(self, service: ServiceProcess, sensor: str = "feed") -> None:
        self.service = service
        self.client: Client = service.client if service.client else service.wait()
        self.feed: Feed = self.client.feed(sensor)
        self.picture: Picture = self.client.picture()
        self._rate: float | None = None

    def advance(self, t: float, timeout: float = 30.0) -> Frame:
        """Move the lockstep clock to `t` (after the measurements sent before it) and
        return the frame of the last display instant at or before `t`, once it is out.

        A lockstep service publishes the instants before its clock's time (docs/protocol.md
        section 6); the clock goes to `t` + 2 us, so that the instant at `t` is one of them."""
        if self._rate is None:
            self._rate = float(self.client.status(timeout)["rate"])
        self.feed.clock(t + 2e-6)
        due = t - 1.0 / self._rate + 1e-9
        return self.picture.wait_for(lambda f: f.t > due, timeout)

    def wait_for(self, condition: Callable[[Frame], Any], timeout: float = 30.0) -> Frame:
        """The first frame seen for which `condition(frame)` is true (TimeoutError)."""
        return self.picture.wait_for(condition, timeout)


@pytest.fixture
def track_service_factory(request: pytest.FixtureRequest
                          ) -> Iterator[Callable[..., ServiceProcess]]:
    """`factory(*args, ns=None, clock="lockstep", wait=60)`: start a service of these
    options (alive when it returns); all are stopped at teardown."""
    started: list[ServiceProcess] = []

    def factory(*args: str, ns: str | None = None, clock: str | None = "lockstep",
                wait: float = WAIT) -> ServiceProcess:
        svc = start(request.node, *args, ns=ns, clock=clock, wait=wait,
                    config=request.config)
        started.append(svc)
        return svc

    yield factory
    for svc in reversed(started):
        svc.stop()


@pytest.fixture
def track_service(request: pytest.FixtureRequest,
                  track_service_factory: Callable[..., ServiceProcess]) -> ServiceProcess:
    """A lockstep service of its own for the test; `@pytest.mark.track_service("--filter",
    "cv", clock="realtime")` gives it other options."""
    mark = request.node.get_closest_marker("track_service")
    args, kwargs = (mark.args, mark.kwargs) if mark else ((), {})
    return track_service_factory(*args, **kwargs)


@pytest.fixture
def track_client(track_service: ServiceProcess) -> Client:
    """A Client connected to `track_service` (closed with it)."""
    return track_service.client if track_service.client else track_service.wait()


@pytest.fixture
def track_feed(track_client: Client) -> Feed:
    """A Feed of `track_client`, sensor `feed`."""
    return track_client.feed("feed")


@pytest.fixture
def track_picture(track_client: Client) -> Picture:
    """A Picture of `track_service`'s frames."""
    return track_client.picture()


@pytest.fixture
def track(track_service: ServiceProcess) -> Loopback:
    """The service, a client, a feed (sensor `feed`) and a picture, with `advance(t)`
    and `wait_for(condition, timeout)`."""
    return Loopback(track_service)


def service_proc(*args: str, clock: str | None = "lockstep", ns: str | None = None,
                 scope: Scope = "function") -> Any:
    """A fixture of a service of other options or another scope, in a conftest:
    `cv_service = service_proc("--filter", "cv", scope="module")`."""
    @pytest.fixture(scope=scope)
    def fixture(request: pytest.FixtureRequest) -> Iterator[ServiceProcess]:
        svc = start(request.node if scope == "function" else None, *args, ns=ns, clock=clock,
                    config=request.config)
        yield svc
        svc.stop()

    return fixture


def client(service_fixture: str, scope: Scope = "function") -> Any:
    """A fixture of a Client of another service fixture: `cv_client = client("cv_service")`."""
    @pytest.fixture(scope=scope)
    def fixture(request: pytest.FixtureRequest) -> Iterator[Client]:
        svc: ServiceProcess = request.getfixturevalue(service_fixture)
        from zenoh_track.clients.lib import connect

        with connect(svc.endpoint, ns=svc.ns, wait=WAIT) as c:
            yield c

    return fixture
