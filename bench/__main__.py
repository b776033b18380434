"""``python -m bench [--seeds N] [--only NAME] [--quick]``: run benchmarks, print tables."""

from __future__ import annotations

import argparse
from pathlib import Path

from rich.console import Console

from bench import (
    adaptive,
    capture,
    factorization,
    gravity,
    gyro,
    gyro_speed,
    labelled,
    live,
    mad,
    mag,
    multi,
    quantised,
    registry,
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
    "quantised",
    "mad",
    "capture",
    "speed",
    "mag",
    "reliability",
    "temperature",
    "registry",
    "live",
    "adaptive",
    "multi",
)


def main() -> None:
    parser = argparse.ArgumentParser(prog="python -m bench", description=__doc__)
    parser.add_argument(
        "--seeds", type=int, default=None,
        help="Monte-Carlo seeds per benchmark [default: 200; live: 3 (--quick: 2) seeds per plan "
        "and mode, each captured in real time]",
    )  # fmt: skip
    parser.add_argument("--only", choices=BENCHMARKS, help="run only this benchmark")
    parser.add_argument(
        "--quick",
        action="store_true",
        help="capture: 10 s instead of 60 s; reliability: 1,000 fuzzed import files, not 10,000; "
        "live: 3 plans, no file reference beyond the live seeds; adaptive: 5 parts, not 60",
    )
    parser.add_argument(
        "--jobs", type=int, default=3,
        help="live, adaptive: captures at a time (each a device and a capture process, mostly "
        "waiting)",
    )  # fmt: skip
    parser.add_argument("--guided-seeds", type=int, default=None,
                        help="live: seeds of the guided captures [default: twice --seeds]")
    parser.add_argument("--plans", help="live: only these plans (comma-separated --plan names)")
    parser.add_argument("--keep", type=Path, metavar="DIR",
                        help="live: keep the sessions, calibrations and capture logs in DIR")
    parser.add_argument("--regrade", type=Path, metavar="DIR",
                        help="live: calibrate again and grade the captures a --keep DIR holds, "
                        "instead of capturing")  # fmt: skip
    parser.add_argument("--runs", type=int, default=5, help="speed: runs per figure (median)")
    parser.add_argument("--sessions", type=int, default=500, help="speed: production-line size")
    args = parser.parse_args()
    console = Console(width=160)
    live_seeds = args.seeds if args.seeds is not None else (2 if args.quick else 3)
    args.seeds = 200 if args.seeds is None else args.seeds
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
    if args.only in (None, "quantised"):
        ok = quantised.run(console, n_seeds=max(20, args.seeds // 5)) and ok
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
    if args.only in (None, "registry"):
        ok = registry.run(console) and ok
    if args.only in (None, "live"):  # real time: about an hour at 8 seeds
        ok = live.run(console, n_seeds=live_seeds, quick=args.quick, jobs=args.jobs,
                      only=args.plans, keep=args.keep, guided_seeds=args.guided_seeds,
                      regrade_dir=args.regrade) and ok
    if args.only in (None, "adaptive"):
        ok = adaptive.run(console, n_seeds=max(adaptive.SEEDS, args.seeds // 10),
                          quick=args.quick, jobs=args.jobs) and ok
    if args.only in (None, "multi"):
        ok = multi.run(console, n_seeds=max(20, args.seeds // 2)) and ok
    raise SystemExit(0 if ok else 1)


if __name__ == "__main__":
    try:
        main()
    except KeyboardInterrupt:  # the benches' own processes are ended by then (bench live)
        print("bench: interrupted", flush=True)
        raise SystemExit(130) from None
