"""Regenerate the pictures in docs/figures/ from SHREC 2007 with the cfsig command line.

Usage: python benchmarks/figures.py [SHREC07_FOLDER] [--out docs/figures]

Each picture is made by one `cfsig` command, printed as it runs (the same list is in
docs/figures.md); the index for the precision/recall plot and the ant query is built in a
temporary folder.
"""

from __future__ import annotations

import argparse
import shlex
import subprocess
import sys
import tempfile
from functools import partial
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SHREC = ROOT.parent / "shared" / "data" / "shrec07"


def run(folder: Path, *args: str) -> None:
    """Run one cfsig command, echoing it with the data folder shown as ``shrec07``."""
    shown = shlex.join(args).replace(str(folder), "shrec07").replace(f"{ROOT}/", "")
    print("cfsig", shown, flush=True)
    subprocess.run([sys.executable, "-m", "cfsig", *args], check=True, stdout=subprocess.DEVNULL)


def main() -> None:
    """Make the pictures and report their sizes."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("folder", nargs="?", type=Path, default=SHREC)
    parser.add_argument("--out", type=Path, default=ROOT / "docs" / "figures")
    args = parser.parse_args()
    if not (args.folder / "ant").is_dir():
        sys.exit(f"SHREC07 not found at {args.folder}: run ../shared/data/unpack-shrec07 first")
    args.out.mkdir(parents=True, exist_ok=True)
    cfsig = partial(run, args.folder)

    def mesh(name: str) -> str:
        return str(args.folder / name)

    def out(name: str) -> str:
        return str(args.out / name)

    cfsig("compute", mesh("hand/181.off"), mesh("human/1.off"), "--png", out("phi.png"))
    poses = [mesh(f"human/{i}.off") for i in (1, 2, 3, 4)]
    poses += [mesh(f"hand/{i}.off") for i in (181, 182)]
    cfsig("compute", *poses, "--hist", out("histograms.png"))
    cfsig("compute", *poses[2:4], poses[5], "--png", out("phi_poses.png"))
    springs = [mesh(f"spring/{i}.off") for i in (263, 273, 270)]
    cfsig("compute", *springs, "--png", out("springs_phi.png"), "--hist", out("springs.png"))
    with tempfile.TemporaryDirectory() as tmp:
        index = str(Path(tmp) / "shrec07.h5")
        cfsig("index", str(args.folder), "-o", index, "--descriptor", "cf")  # the paper's
        cfsig("evaluate", "--index", index, "--plot", out("precision_recall.png"))
        cfsig("query", index, mesh("ant/81.off"), "-k", "20", "--png", out("ant_query.png"))
    for png in sorted(args.out.glob("*.png")):
        print(f"{png.relative_to(ROOT) if png.is_relative_to(ROOT) else png}: "
              f"{png.stat().st_size / 1024:.0f} KB")  # fmt: skip


if __name__ == "__main__":
    main()
