"""Retrieval measures of cfsig's descriptors on labelled collections: docs/results.md.

    python benchmarks/results.py --data-root DATA [--doc docs/results.md]
        [--collections shrec07,mcgill,faust] [--jobs N] [--every K]

``DATA/NAME/<class>/<file>.off`` holds each collection (``../shared/data/unpack all DATA``);
``--every K`` takes every k-th mesh in sorted order (a quick look).

Whole shapes: for each collection, ``cf`` and ``intrinsic`` signatures of every mesh
(`cfsig.compute_collection`), ranked leave-one-out (`cfsig.evaluate_collections`): NN, FT, ST,
DCG, mAP and the median wall seconds per mesh (reading included, in a worker). The classes
are the folders, or for ``psb-train`` (not measured by default: ``benchmarks/peers.py``
measures it beside the descriptors for rigid objects) PSB's own ``DATA/psb-train.cla`` when it
is there.

Partial queries, scans and noisy copies: ``benchmarks/world.py``.

With ``--doc``, everything after the line
``<!-- measured: what follows is written by benchmarks/results.py -->`` of that file is replaced
by the tables, preceded by a line naming the command.
"""

from __future__ import annotations

import sys
import tempfile
from pathlib import Path

from common import collection_parser, command, table

import cfsig

COLLECTIONS = ("shrec07", "mcgill", "faust")
DESCRIPTORS = ("cf", "intrinsic")
WHOLE_MEASURES = ("NN", "FT", "ST", "DCG", "mAP")
MARKER = "<!-- measured: what follows is written by benchmarks/results.py -->"


# --- measures -------------------------------------------------------------------------------


def wholes(data: Path, every: int, folder: Path) -> list[Path]:
    """Link every k-th mesh ``data/<class>/<file>.off`` (sorted) into ``folder``; the meshes."""
    paths = sorted(data.glob("*/*.off"))[::every]
    if not paths:
        sys.exit(f"no meshes under {data}: expected {data}/<class>/<file>.off")
    for path in paths:
        (folder / path.parent.name).mkdir(parents=True, exist_ok=True)
        (folder / path.parent.name / path.name).symlink_to(path.resolve())
    return paths


def whole_rows(name: str, folder: Path, data_root: Path, jobs: int) -> list[list]:
    """Leave-one-out measures of each descriptor on one collection: one row each."""
    cla = data_root / f"{name}.cla"
    classes = cfsig.read_cla(cla) if name == "psb-train" and cla.exists() else None
    found = {}
    for descriptor in DESCRIPTORS:
        params = cfsig.Params(descriptor=descriptor)
        found[descriptor], failures = cfsig.compute_collection(folder, params, jobs=jobs)
        for line in failures:
            print(f"{name}, {descriptor}: {line}", file=sys.stderr)
    rows = []
    for descriptor, evaluation in cfsig.evaluate_collections(found, classes).items():
        report = evaluation.report
        rows.append(
            [name, f"`{descriptor}`", report.count]
            + [f"{report.measures[m]:.3f}" for m in WHOLE_MEASURES]
            + [evaluation.seconds_per_mesh]
        )
    return rows


def main() -> None:
    """Measure every collection asked for, print the tables and write them into ``--doc``."""
    args = collection_parser(__doc__.splitlines()[0], COLLECTIONS).parse_args()
    if args.doc is not None and MARKER not in args.doc.read_text():
        sys.exit(f"{args.doc}: no line {MARKER}")
    whole = []
    for name in args.collections.split(","):
        with tempfile.TemporaryDirectory(prefix=f"cfsig-results-{name}-") as tmp:
            folder = Path(tmp) / "wholes"
            paths = wholes(args.data_root / name, args.every, folder)
            whole += whole_rows(name, folder, args.data_root, args.jobs)
        print(f"{name}: {len(paths)} meshes measured", file=sys.stderr, flush=True)
    lines = [
        "### Whole shapes, leave-one-out",
        "",
        table(["collection", "descriptor", "queries", *WHOLE_MEASURES, "s per mesh"], whole),
    ]
    text = "\n".join([f"Measured by `{command('results.py')}`.", "", *lines])
    print(text)
    if args.doc is not None:
        head = args.doc.read_text().split(MARKER)[0]
        args.doc.write_text(f"{head}{MARKER}\n\n{text}\n")


if __name__ == "__main__":
    main()
