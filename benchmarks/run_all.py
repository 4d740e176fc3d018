"""Run every ``benchmarks/bench_*.py`` in its own process and print its output.

Syntax::

    .venv/bin/python benchmarks/run_all.py [ARGS...]     # (``make benchmark``)

Extra arguments are passed to every benchmark (e.g. ``--quick``). The exit status is
non-zero if a benchmark failed to run; the timings themselves are never judged.
"""
import subprocess
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent


def main(argv=None):
    argv = sys.argv[1:] if argv is None else argv
    failed = []
    for script in sorted(HERE.glob("bench_*.py")):
        print(f"=== {script.name}", flush=True)
        t = time.perf_counter()
        r = subprocess.run([sys.executable, str(script), *argv])
        print(f"=== {script.name}: {'ok' if r.returncode == 0 else f'FAILED ({r.returncode})'} "
              f"in {time.perf_counter() - t:.0f} s", flush=True)
        if r.returncode != 0:
            failed.append(script.name)
    if failed:
        print(f"failed: {', '.join(failed)}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
