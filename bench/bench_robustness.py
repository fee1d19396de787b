"""Generated inputs, valid and invalid, through the running service: the run of
tests/test_robustness.py with many more examples (docs/robustness.md).

    python bench/bench_robustness.py --examples 2000          # about 11,000 messages
    python bench/bench_robustness.py --examples 2000 --random  # a fresh random seed

Prints the figures: messages, applied and rejected inputs, the service's counters by
reason, frames, and the good tracks' error against a tracker fed the good feed alone.
Any broken promise fails with the input that broke it.
"""

from __future__ import annotations

import argparse
import pathlib
import sys

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[1] / "tests"))

from test_robustness import report, run_examples  # noqa: E402


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--examples", type=int, default=2000)
    p.add_argument("--random", action="store_true",
                   help="a random run (default: hypothesis's derandomized one)")
    args = p.parse_args()
    fig = run_examples(args.examples, derandomize=not args.random)
    print(report(fig))
    if fig["good_rmse_served"] != fig["good_rmse_reference"]:
        print(f"good tracks differ by {fig['good_rmse_served'] - fig['good_rmse_reference']:g}"
              " m from the reference")


if __name__ == "__main__":
    main()
