"""The pytest11 entry point of zenoh-track-service: it adds one ini option and nothing
else, so installing the package changes no one's test run. `zenoh_track = true` in a
project's pytest settings loads the plugin (`zenoh_track.clients.pytest_plugin`), as
`pytest_plugins = [...]` in a conftest.py or `-p` on the command line do."""

from __future__ import annotations

import pytest

PLUGIN = "zenoh_track.clients.pytest_plugin"


def pytest_addoption(parser: pytest.Parser) -> None:
    parser.addini("zenoh_track", type="bool", default=False,
                  help="load the zenoh-track-service fixtures (track_service, track, ...)")


def pytest_configure(config: pytest.Config) -> None:
    if config.getini("zenoh_track"):
        config.pluginmanager.import_plugin(PLUGIN)
