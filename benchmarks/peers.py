"""The paper's comparison of descriptors (its section 3.5, Figures 7 to 11), on a labelled folder.

    python benchmarks/peers.py --data DATA/shrec07 [--descriptors cf,sh,gps,intrinsic]
        [--classes ant,armadillo,bust] [--cla FILE] [--out docs/figures/peers] [--jobs N]

For each descriptor, the signatures of every mesh ``DATA/<class>/<file>``
(`cfsig.compute_collection`), ranked leave-one-out on the meshes that every descriptor could
compute (`cfsig.evaluate_collections`; the classes are the folders, or ``--cla``'s). Prints the
measures of each descriptor (with ``rigid``, also each of its channels alone, ranked by the
channel's own distance on ``rigid``'s vectors) and the first tier per class drawn, as Markdown,
and writes into
OUT the pictures of `cfsig.figures.report.write_comparison` for the classes drawn (default: all):
``precision_recall.png``, the curves of all queries and of each class, a curve per descriptor,
and per class ``query_<number>_<class>.png``, its first model's nearest, a row per descriptor.
On SHREC 2007 the paper's ants, armadillos and heads are ``ant,armadillo,bust``.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
from common import command, table

import cfsig
from cfsig.descriptors import rigid
from cfsig.evaluation.collections import Evaluation
from cfsig.figures.report import write_comparison
from cfsig.search.l1 import fast_kernel, l1_numpy

MEASURES = ("NN", "FT", "ST", "DCG", "mAP")


def channel_reports(evaluation: Evaluation) -> dict[str, cfsig.RetrievalReport]:
    """Each channel of ``rigid`` alone: its own distance (`rigid.channel_distances`) between the
    ``rigid`` vectors evaluated, ranked leave-one-out."""
    signatures = np.ascontiguousarray(evaluation.collection.signatures, np.float32)
    channels = rigid.channel_distances(signatures, signatures, fast_kernel() or l1_numpy)
    labels = evaluation.collection.labels
    return {name: cfsig.evaluate_distances(d, labels) for name, d in channels.items()}


def main() -> None:
    """Compute, evaluate, print the tables and draw the pictures."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", type=Path, required=True, help="folder of <class>/<file> meshes")
    parser.add_argument("--descriptors", default="cf,sh,gps,intrinsic", help="comma-separated")
    parser.add_argument("--classes", help="comma-separated classes to draw (default: all)")
    parser.add_argument("--cla", type=Path, help="classes from a PSB .cla file")
    parser.add_argument("--out", type=Path, required=True, help="folder of the pictures")
    parser.add_argument("--jobs", type=int, help="worker processes (default: CPU cores)")
    args = parser.parse_args()
    collections = {}
    for name in args.descriptors.split(","):
        params = cfsig.Params(descriptor=name)
        collections[name], failures = cfsig.compute_collection(args.data, params, jobs=args.jobs)
        for line in failures:
            print(f"skipped ({name}): {line}")
    classes = cfsig.read_cla(args.cla) if args.cla else None
    results = cfsig.evaluate_collections(collections, classes)
    first = next(iter(results.values())).report
    asked = args.classes.split(",") if args.classes else list(first.per_class)
    drawn = [cls for cls in asked if cls in first.per_class]
    print(f"Measured by `{command('peers.py')}`: {first.count} queries.\n")
    rows = [
        [f"`{name}`", *(f"{r.report.measures[m]:.3f}" for m in MEASURES), r.seconds_per_mesh]
        for name, r in results.items()
    ]
    if "rigid" in results:
        at = list(results).index("rigid")
        rows[at:at] = [
            [f"`rigid`'s {name} alone", *(f"{report.measures[m]:.3f}" for m in MEASURES), ""]
            for name, report in channel_reports(results["rigid"]).items()
        ]
    print(table(["descriptor", *MEASURES, "s per mesh"], rows), end="\n\n", flush=True)
    per_class = [
        [cls, *(f"{r.report.per_class[cls]['FT']:.3f}" for r in results.values())] for cls in drawn
    ]
    print(table(["class (FT)", *(f"`{name}`" for name in results)], per_class), flush=True)
    for cls in sorted(set(asked) - set(drawn)):
        print(f"not drawn: no class {cls} among the queries")
    for line in write_comparison(args.out, results, drawn):
        print(f"not drawn: {line}")


if __name__ == "__main__":
    main()
