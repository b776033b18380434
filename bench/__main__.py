"""``python -m bench [--seeds N] [--only NAME] [--quick]``: run benchmarks, print tables."""

from __future__ import annotations

import argparse

from rich.console import Console

from bench import (
    capture,
    factorization,
    gravity,
    gyro,
    gyro_speed,
    labelled,
    mad,
    mag,
    multi,
    reliability,
    speed,
    temperature,
    trust,
    trust_gyro,
)

BENCHMARKS = (
    "gravity",
    "labelled",
    "factorization",
    "gyro",
    "gyro-speed",
    "trust",
    "trust-gyro",
    "mad",
    "capture",
    "speed",
    "mag",
    "reliability",
    "temperature",
    "multi",
)


def main() -> None:
    parser = argparse.ArgumentParser(prog="python -m bench", description=__doc__)
    parser.add_argument("--seeds", type=int, default=200, help="Monte-Carlo seeds per benchmark")
    parser.add_argument("--only", choices=BENCHMARKS, help="run only this benchmark")
    parser.add_argument(
        "--quick",
        action="store_true",
        help="capture: 10 s instead of 60 s; reliability: 1,000 fuzzed import files, not 10,000",
    )
    parser.add_argument("--runs", type=int, default=5, help="speed: runs per figure (median)")
    parser.add_argument("--sessions", type=int, default=500, help="speed: production-line size")
    args = parser.parse_args()
    console = Console(width=160)
    ok = True
    if args.only in (None, "gravity"):
        ok = gravity.run(console, n_seeds=args.seeds) and ok
    if args.only in (None, "labelled"):
        ok = labelled.run(console, n_seeds=args.seeds) and ok
    if args.only in (None, "factorization"):
        ok = factorization.run(console, n_seeds=args.seeds) and ok
    if args.only in (None, "gyro"):
        ok = gyro.run(console, n_seeds=max(20, args.seeds // 2)) and ok
    if args.only in (None, "gyro-speed"):
        ok = gyro_speed.run(console) and ok
    if args.only in (None, "trust"):
        ok = trust.run(console, n_seeds=max(5, args.seeds // 20)) and ok
    if args.only in (None, "trust-gyro"):
        ok = trust_gyro.run(console, n_seeds=max(5, args.seeds // 20)) and ok
    if args.only in (None, "mad"):
        ok = mad.run(console) and ok
    if args.only in (None, "capture"):
        ok = capture.run(console, quick=args.quick) and ok
    if args.only in (None, "mag"):
        ok = mag.run(console, n_seeds=max(20, args.seeds // 5)) and ok
    if args.only in (None, "speed"):
        ok = speed.run(console, runs=args.runs, n_sessions=args.sessions) and ok
    if args.only in (None, "reliability"):
        ok = reliability.run(console, quick=args.quick) and ok
    if args.only in (None, "temperature"):
        ok = temperature.run(console, n_seeds=max(2, args.seeds // 50)) and ok
    if args.only in (None, "multi"):
        ok = multi.run(console, n_seeds=max(20, args.seeds // 2)) and ok
    raise SystemExit(0 if ok else 1)


if __name__ == "__main__":
    main()
