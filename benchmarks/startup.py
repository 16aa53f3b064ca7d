"""Start-up time: ``cfsig --help`` and one small ``cfsig compute`` against ``import numpy``.

Each command runs ``--repeat`` times in a fresh interpreter (after one unmeasured warm-up run
that fills the page cache); the table gives the median wall time and its ratio to
``python -c "import numpy"``. The target of issue 13: ``cfsig --help`` within 1.5 times it.

    python benchmarks/startup.py --repeat 5
"""

from __future__ import annotations

import argparse
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import common

ROOT = Path(__file__).resolve().parents[1]


def wall(command: list[str], repeat: int) -> float:
    """The median wall seconds of ``command`` over ``repeat`` runs, after one warm-up."""
    subprocess.run(command, check=True, capture_output=True)
    times = []
    for _ in range(repeat):
        start = time.perf_counter()
        subprocess.run(command, check=True, capture_output=True)
        times.append(time.perf_counter() - start)
    return common.median(times)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=5, help="runs per command [5]")
    parser.add_argument("--json", type=Path, help="also write every measurement here")
    args = parser.parse_args()
    cfsig = shutil.which("cfsig", path=str(Path(sys.executable).parent)) or "cfsig"
    sys.path.insert(0, str(ROOT))
    from tests.helpers import icosphere, write_off

    with tempfile.TemporaryDirectory() as folder:
        mesh = write_off(Path(folder) / "ball.off", *icosphere(2))
        commands = {
            'python -c "import numpy"': [sys.executable, "-c", "import numpy"],
            "cfsig --help": [cfsig, "--help"],
            "cfsig compute ball.off (162 vertices)": [cfsig, "compute", str(mesh)],
        }
        seconds = {name: wall(command, args.repeat) for name, command in commands.items()}
    base = seconds['python -c "import numpy"']
    rows = [[name, f"{s:.3f}", f"{s / base:.2f}"] for name, s in seconds.items()]
    print(common.table(["command", "median wall s", "x import numpy"], rows))
    common.save_rows(args.json, [{"command": name, "seconds": s} for name, s in seconds.items()])


if __name__ == "__main__":
    main()
