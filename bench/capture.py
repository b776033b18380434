"""Serial capture throughput (issue 3, point 8).

A 1000 Hz stream of 7 fields (``t,ax,ay,az,gx,gy,gz``) from the virtual serial IMU
(``imucal simulate --serve``, paced to 921600 baud) into ``imucal capture --no-prompt`` for
60 s (``--quick``: 10 s), through the real tty layer:

* lines received (samples in the session) against lines the server wrote (target: none lost);
* CPU time (user + system, from the capture process's rusage, startup included) over its wall
  time (target: under 25 % of one core).
"""

from __future__ import annotations

import os
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from rich.console import Console
from rich.table import Table

from imucal_cli.formats.session import read_session

RATE_HZ = 1000
BAUD = 921600
CPU_TARGET = 0.25


def run(console: Console, quick: bool = False) -> bool:
    """Run the benchmark, print its table; return whether both targets are met."""
    duration = 10 if quick else 60
    cli = [sys.executable, "-m", "imucal_cli"]
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "bench.h5"
        server = subprocess.Popen(
            [*cli, "simulate", "--serve", "--plan", "six", "--loop", "--rate", str(RATE_HZ),
             "--baud", str(BAUD), "--no-temp", "--duration", str(duration)],
            stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True,
        )  # fmt: skip
        path = server.stdout.readline().strip()
        cap = subprocess.Popen(
            [*cli, "capture", "--port", path, "--baud", str(BAUD), "--no-prompt",
             "--duration", str(duration + 30), "--columns", "t,ax,ay,az,gx,gy,gz",
             "--output", str(out)],
            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
        )  # fmt: skip
        t0 = time.monotonic()
        _, status, usage = os.wait4(cap.pid, 0)
        wall = time.monotonic() - t0
        cap.returncode = os.waitstatus_to_exitcode(status)
        cap_out = cap.stdout.read()
        cap_err = cap.stderr.read()
        server_out, _ = server.communicate(timeout=30)
        m = re.search(r"# sent (\d+) lines", server_out)
        sent = int(m[1]) if m else -1
        try:
            received = len(read_session(out).time)
        except Exception as exc:  # noqa: BLE001 - reported in the table
            console.print(f"[red]capture failed[/]: {exc}\n{cap_out}{cap_err}")
            return False
    cpu = usage.ru_utime + usage.ru_stime
    share = cpu / wall
    lost = sent - received
    ok_lost, ok_cpu = lost == 0 and sent > 0, share < CPU_TARGET

    def verdict(ok: bool) -> str:
        return "[green]PASS[/]" if ok else "[red]FAIL[/]"

    table = Table(title=f"capture: {RATE_HZ} Hz, 7 fields, {BAUD} baud, {duration} s "
                        "(virtual serial port)")  # fmt: skip
    table.add_column("measure")
    table.add_column("value", justify="right")
    table.add_column("target", justify="right")
    table.add_column("", justify="center")
    table.add_row("lines sent", f"{sent}", "", "")
    table.add_row("lines received (session samples)", f"{received}", "", "")
    table.add_row("lines lost", f"{lost}", "0", verdict(ok_lost))
    table.add_row("capture CPU (user + sys)", f"{cpu:.2f} s", "", "")
    table.add_row("capture wall time", f"{wall:.2f} s", "", "")
    table.add_row("capture CPU / wall", f"{100 * share:.1f} %", f"< {100 * CPU_TARGET:.0f} %",
                  verdict(ok_cpu))  # fmt: skip
    console.print(table)
    console.print(f"capture exit status {cap.returncode} (3: the device went away at the end)")
    return ok_lost and ok_cpu
