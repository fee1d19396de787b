"""Progress bars of the long-running tools (tqdm, on stderr): shown only when stderr is a
terminal and the user did not pass --quiet, so logs and pipes stay clean."""

from __future__ import annotations

import argparse
import sys
from typing import Any

from tqdm import tqdm


def add_quiet_arg(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("-q", "--quiet", action="store_true",
                        help="no progress bar (none is drawn either when stderr is not a "
                             "terminal)")


def bar(total: float | None = None, desc: str = "", unit: str = "it", quiet: bool = False,
        **kw: Any) -> tqdm:
    """A tqdm bar on stderr, disabled when `quiet` or when stderr is not a terminal."""
    return tqdm(total=total, desc=desc, unit=unit, file=sys.stderr, dynamic_ncols=True,
                disable=quiet or not sys.stderr.isatty(), **kw)
