"""Start-up time: ``cfsig --help``, one small ``cfsig compute`` and ``cfsig index`` against
``import numpy``.

Each command runs ``--repeat`` times in a fresh interpreter, the commands taking turns so that
a change in the machine's load falls on all of them alike, after one unmeasured warm-up run of
each that fills the page cache; the table gives the median wall time and its ratio to
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


def walls(commands: dict[str, list[str]], repeat: int) -> dict[str, float]:
    """The median wall seconds of each command over ``repeat`` runs taken in turns."""
    times: dict[str, list[float]] = {name: [] for name in commands}
    for run in range(repeat + 1):
        for name, command in commands.items():
            start = time.perf_counter()
            subprocess.run(command, check=True, capture_output=True)
            if run:  # run 0 is the warm-up
                times[name].append(time.perf_counter() - start)
    return {name: common.median(values) for name, values in times.items()}


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
        index = Path(folder) / "index"
        commands = {
            'python -c "import numpy"': [sys.executable, "-c", "import numpy"],
            "cfsig --help": [cfsig, "--help"],
            "cfsig compute ball.off (162 vertices)": [cfsig, "compute", str(mesh)],
            # a new index each time: the main process, one worker process, one mesh
            "cfsig index ball.off --jobs 1 (a new index)": [
                "sh",
                "-c",
                f'rm -rf "{index}" && "{cfsig}" index "{mesh}" -o "{index}" --jobs 1',
            ],
        }
        seconds = walls(commands, args.repeat)
    base = seconds['python -c "import numpy"']
    rows = [[name, f"{s:.3f}", f"{s / base:.2f}"] for name, s in seconds.items()]
    print(common.table(["command", "median wall s", "x import numpy"], rows))
    common.save_rows(args.json, [{"command": name, "seconds": s} for name, s in seconds.items()])


if __name__ == "__main__":
    main()
