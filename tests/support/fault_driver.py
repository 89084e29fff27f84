"""Run ``rigslim ARGS`` with one fault hook, for tests/hostile/test_faults.py (never used outside the tests).

    python tests/support/fault_driver.py MODE MARKER ARGS...

MODE
    ``solve``      the weight solver writes MARKER and sleeps, so the test can signal the run during the solve;
    ``write:NAME`` when the output NAME's temporary file is filled, it is cut to half its length (a write in
                   progress), MARKER is written and the run sleeps, so the test can signal it during that write;
    ``through``    MARKER is written when a device node / FIFO output is about to be opened (a FIFO blocks);
    ``none``       no fault.
The test waits for MARKER, then sends SIGKILL, SIGINT or SIGTERM.
"""

from __future__ import annotations

import os
import sys
import time
from pathlib import Path


def _pause(marker: Path, what: str) -> None:
    marker.write_text(f"{os.getpid()} {what}\n")
    time.sleep(120)


def main() -> int:
    mode, marker, args = sys.argv[1], Path(sys.argv[2]), sys.argv[3:]
    if mode == "solve":
        from rigslim.plugin.host import get_host

        for name in get_host().plugins("weight-solver"):
            plugin = get_host().get("weight-solver", name)
            original = plugin.solve

            def solve(asset, params, ctx, _original=original):
                result = _original(asset, params, ctx)
                _pause(marker, "solve")
                return result

            plugin.solve = solve
    elif mode.startswith("write:"):
        from rigslim.io import atomic

        name = mode.split(":", 1)[1]

        def on_staged(tmp: Path, target: Path) -> None:
            if target.name == name:
                data = tmp.read_bytes()
                tmp.write_bytes(data[: len(data) // 2])
                _pause(marker, f"write {target}")

        atomic.on_staged = on_staged
    elif mode == "through":
        from rigslim.io import atomic

        original = atomic._write_through

        def write_through(tmp, target):
            marker.write_text(f"{os.getpid()} through {target}\n")
            return original(tmp, target)

        atomic._write_through = write_through
    elif mode != "none":
        raise SystemExit(f"unknown mode {mode}")
    from rigslim.commands.cli import main as cli

    return cli(args)


if __name__ == "__main__":
    sys.exit(main())
