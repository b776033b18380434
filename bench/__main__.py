"""``python -m bench [--seeds N]``: run every benchmark and print its tables."""

from __future__ import annotations

import argparse

from rich.console import Console

from bench import gravity


def main() -> None:
    parser = argparse.ArgumentParser(prog="python -m bench", description=__doc__)
    parser.add_argument("--seeds", type=int, default=200, help="Monte-Carlo seeds per benchmark")
    args = parser.parse_args()
    console = Console(width=110)
    ok = gravity.run(console, n_seeds=args.seeds)
    raise SystemExit(0 if ok else 1)


if __name__ == "__main__":
    main()
