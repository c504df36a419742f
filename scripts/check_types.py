"""Type-check voxlidar, tlsvox and clsim with mypy against a baseline.

The baseline (``scripts/mypy-baseline.txt``) holds the errors the tree had when
type checking began, one ``path: message  [code]`` line each, without line
numbers so that unrelated edits do not move them. A run fails on any error not
in the baseline; errors fixed since are reported so the baseline can shrink
(``--update`` rewrites it).

    .venv/bin/python scripts/check_types.py [--update]
"""

from __future__ import annotations

import argparse
import re
import subprocess
import sys
from collections import Counter
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
BASELINE = ROOT / "scripts" / "mypy-baseline.txt"
LINE = re.compile(r"^(?P<path>[^:]+\.py):\d+:(?:\d+:)? error: (?P<msg>.*)$")


def errors() -> Counter:
    run = subprocess.run([sys.executable, "-m", "mypy", "--no-error-summary", "--no-pretty"], cwd=ROOT,
                         capture_output=True, text=True)
    if run.returncode not in (0, 1):
        sys.exit(f"mypy failed to run:\n{run.stderr or run.stdout}")
    out = Counter()
    for line in run.stdout.splitlines():
        m = LINE.match(line)
        if m:
            out[f"{m['path']}: {m['msg']}"] += 1
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--update", action="store_true", help="rewrite the baseline with the errors found now")
    args = ap.parse_args(argv)
    found = errors()
    if args.update:
        BASELINE.write_text("".join(f"{k}\n" * n for k, n in sorted(found.items())))
        print(f"check_types: baseline written, {sum(found.values())} error(s)")
        return 0
    base = Counter(BASELINE.read_text().splitlines()) if BASELINE.exists() else Counter()
    new, fixed = found - base, base - found
    if fixed:
        print(f"check_types: {sum(fixed.values())} baseline error(s) fixed; shrink the baseline with --update")
    if new:
        print(f"check_types: {sum(new.values())} new type error(s) (not in {BASELINE.relative_to(ROOT)}):")
        for k in sorted(new):
            print(f"  {k}")
        return 1
    print(f"check_types: no new type errors ({sum(found.values())} in the baseline)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
