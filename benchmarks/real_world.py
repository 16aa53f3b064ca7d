"""Real models from the web: PSB's training half through `cfsig evaluate`, as a user runs it.

Usage: python benchmarks/real_world.py [FOLDER] [--doc docs/real-world.md]
(FOLDER: `../shared/data/unpack psb-train DEST` makes DEST/psb-train, one folder per class.)

Runs `cfsig evaluate FOLDER --json` in a subprocess with the default descriptor and repair, and
reports the retrieval measures, how many models took each repair route, the models skipped
with their reasons, the median seconds per model (reading and repair included), the wall time,
and the number of Python warning lines on standard error (which must be 0).
"""

from __future__ import annotations

import argparse
import json
import re
import shlex
import subprocess
import sys
import time
from pathlib import Path

import common

SHARED = Path(__file__).resolve().parents[2] / "shared" / "data" / "psb-train"
WARNING = re.compile(r"\b\w*Warning\b: ")  # how Python prints a warning


def main() -> None:
    """Evaluate the folder through the CLI and print (or write) the report."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("folder", nargs="?", type=Path, default=SHARED)
    parser.add_argument("--jobs", type=int, default=2)
    parser.add_argument("--doc", type=Path, help="write the report as Markdown here")
    args = parser.parse_args()
    if not args.folder.is_dir():
        sys.exit(f"no collection at {args.folder}: run ../shared/data/unpack psb-train first")
    cmd = [sys.executable, "-m", "cfsig", "evaluate", str(args.folder), "--json"]
    cmd += ["-j", str(args.jobs)]
    start = time.perf_counter()
    done = subprocess.run(cmd, capture_output=True, text=True)
    wall = time.perf_counter() - start
    if done.returncode not in (0, 3):
        sys.exit(f"cfsig evaluate failed ({done.returncode}): {done.stderr[-2000:]}")
    report = json.loads(done.stdout)
    lines = done.stderr.replace("\r", "\n").splitlines()
    warnings = [line for line in lines if WARNING.search(line)]
    listed = [i for i, line in enumerate(lines) if line.startswith("Skipped ")]
    skipped = [line.strip() for line in lines[listed[0] + 1 :]] if listed else []
    measures = report["measures"]
    text = "\n".join(
        [
            "# Real models from the web: PSB's training half",
            "",
            f"Measured with `python benchmarks/real_world.py {shlex.join(sys.argv[1:])}`, which "
            f"runs `cfsig evaluate FOLDER --json -j {args.jobs}` (default descriptor and repair) "
            "and reads its output.",
            "",
            common.table(list(measures), [list(measures.values())]),
            "",
            f"- Models evaluated: {report['count']}; skipped: {len(skipped)}.",
            "- Repair routes: "
            + ", ".join(f"{count} {route}" for route, count in sorted(report["repair"].items())),
            f"- Median seconds per model (reading and repair included): "
            f"{report['seconds_per_mesh']:.3f}; wall time {wall:.0f} s with {args.jobs} jobs.",
            f"- Python warning lines on standard error: {len(warnings)}.",
            "",
            "Skipped models:",
            "",
            *(f"- {line}" for line in skipped or ["none"]),
            *(["", "Warnings:", "", *(f"- {line}" for line in warnings[:20])] if warnings else []),
        ]
    )
    print(text)
    if args.doc:
        args.doc.write_text(text + "\n")


if __name__ == "__main__":
    main()
