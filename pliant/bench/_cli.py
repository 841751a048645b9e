"""CLI start-up benchmark: wall time of ``pliant --help`` in a fresh interpreter (Warp is not loaded)."""

from __future__ import annotations

import statistics
import subprocess
import sys
import time

#: Run in a fresh interpreter: the help text, then whether Warp got imported (it must not).
_CODE = (
    "import contextlib, io, sys\n"
    "import pliant.cli\n"
    "with contextlib.redirect_stdout(io.StringIO()):\n"
    "    try:\n"
    "        pliant.cli.main(['--help'])\n"
    "    except SystemExit:\n"
    "        pass\n"
    "print('warp' in sys.modules)\n"
)


def cli_help(quick: bool = False) -> dict:
    """``python -c 'pliant.cli.main(["--help"])'`` 3 times (10 without quick); median wall seconds, with
    the bare interpreter's start-up for comparison."""
    runs = 3 if quick else 10

    def timed(code: str) -> tuple[float, str]:
        t0 = time.perf_counter()
        out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
        return time.perf_counter() - t0, out.stdout.strip()

    help_s, outs = zip(*(timed(_CODE) for _ in range(runs)), strict=True)
    bare_s = [timed("pass")[0] for _ in range(runs)]
    return {
        "scene": "pliant --help",
        "device": "cpu",
        "runs": runs,
        "wall_s": round(statistics.median(help_s), 4),
        "python_startup_s": round(statistics.median(bare_s), 4),
        "sanity_warp_imported": outs[-1] == "True",
    }


BENCHMARKS = {"cli_help": cli_help}
