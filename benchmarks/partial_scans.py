"""What lowers a scanned part's partial query: remeshing, noise, smoothing (docs/partial-scans.md).

    python benchmarks/partial_scans.py --data-root /work/data --doc docs/partial-scans.md

``benchmarks/partial.py``'s ``scan`` parts (a cut, remeshed to half its faces, every vertex moved
by Gaussian noise of a tenth of the mean edge length) rank far below its cuts. This script takes
one cut of every mesh of SHREC 2007, McGill and FAUST (`partial.cut`, seeded by the mesh's
position) and changes it one way at a time: remeshed alone (`messy.remesh`), noise alone (3%
and 10% of the mean edge length, the same draws scaled), both (a scan), and the scan smoothed by
``k`` iterations of Taubin's lambda-mu filter on the uniform Laplacian (lambda 0.6307, mu
-0.6732: G. Taubin, "A signal processing approach to fair surface design", SIGGRAPH 1995); and,
for what smoothing costs a part without noise, the cut smoothed once. Each is a partial query
against the whole collection, its own whole among it, on an index of the default ``cfhks``
(version 9: the part's curvature channel) and of version 10 (its fine cells), each measured by
`cfsig.search.partial.measure_part`: NN and own whole first by the partial distance, FT as
``cfsig query --partial`` ranks (`cfsig.search.partial.expanded_distances`).
"""

from __future__ import annotations

import os

os.environ.update(
    dict.fromkeys(["OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"], "1")
)

from collections.abc import Callable
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import messy
import numpy as np
import scipy.sparse as sp
from common import report_measured, study_parser
from descriptors import collection_paths
from partial import COLLECTIONS, DEFAULT, FINE, cut

from cfsig.descriptors.signature import compute_signature
from cfsig.evaluation.measures import evaluate_queries
from cfsig.files.elements import mesh_edges
from cfsig.files.mesh import Mesh, clean_mesh, read_mesh
from cfsig.search.partial import expanded_distances, measure_part, partial_distances

SMOOTHING = (1, 2, 5)  # Taubin iterations tried on the scans
MARKER = "<!-- measured: what follows is written by benchmarks/partial_scans.py -->"


def taubin(mesh: Mesh, iterations: int) -> Mesh:
    """``iterations`` pairs of Taubin's steps, forward 0.6307 and back -0.6732."""
    n = len(mesh.vertices)
    i, j = mesh_edges(mesh.faces, n).ends.T
    adjacency = sp.coo_matrix((np.ones(2 * len(i)), (np.r_[i, j], np.r_[j, i])), (n, n)).tocsr()
    average = sp.diags(1 / np.asarray(adjacency.sum(axis=1)).ravel()) @ adjacency
    vertices = mesh.vertices
    for _ in range(iterations):
        for weight in (0.6307, -0.6732):
            vertices = vertices + weight * (average @ vertices - vertices)
    return clean_mesh(vertices, mesh.faces)


def variants(mesh: Mesh, seed: int) -> dict[str, Mesh]:
    """One cut of a mesh, changed each way the script measures; both levels of noise scale the
    same draws."""
    part = cut(mesh, np.random.default_rng(seed))
    remeshed = clean_mesh(*messy.remesh((part.vertices, part.faces), None))

    def noisy(surface: Mesh, level: Callable) -> Mesh:
        draws = np.random.default_rng([seed, 1])
        return clean_mesh(*level((surface.vertices, surface.faces), draws))

    scan = noisy(remeshed, messy.noise)
    return {
        "cut": part,
        "cut, remeshed": remeshed,
        "cut, noise 3%": noisy(part, messy.light_noise),
        "cut, noise 10%": noisy(part, messy.noise),
        "scan: remeshed, noise 3%": noisy(remeshed, messy.light_noise),
        "scan: remeshed, noise 10%": scan,
        **{f"scan, Taubin {k}": taubin(scan, k) for k in SMOOTHING},
        "cut, Taubin 1": taubin(part, 1),
    }


def _one(item: tuple[Path, int]) -> tuple[np.ndarray, tuple, dict]:
    """A whole's version 10 vector (the default's) and cells, and its changed cuts measured as
    parts of each version."""
    path, seed = item
    mesh = read_mesh(path)
    whole = compute_signature(mesh, FINE)
    parts = {
        (kind, params): measure_part(part, params)
        for kind, part in variants(mesh, seed).items()
        for params in (DEFAULT, FINE)
    }
    return whole.vector, whole.cells, parts


def measure(name: str, data_root: Path, jobs: int, every: int) -> list[str]:
    """The table's rows of one collection."""
    paths = collection_paths(data_root, name)[::every]
    with ProcessPoolExecutor(jobs) as pool:
        rows = list(pool.map(_one, [(p, i) for i, p in enumerate(paths)], chunksize=2))
    labels = [p.parent.name for p in paths]
    wholes = np.array([r[0] for r in rows])
    cells = np.array([r[1][0] for r in rows]), np.array([r[1][1] for r in rows])
    lines = []
    for kind, params in rows[0][2]:
        parts = [r[2][kind, params] for r in rows]
        nearest = np.array([partial_distances(p, wholes, params, cells) for p in parts])
        ranked = np.array([expanded_distances(p, wholes, params, cells) for p in parts])
        nn = evaluate_queries(nearest, labels, labels).measures["NN"]
        ft = evaluate_queries(ranked, labels, labels).measures["FT"]
        own = np.mean(nearest.argmin(axis=1) == np.arange(len(rows)))
        row = f"{kind} | {params.version} | {nn:.3f} | {ft:.3f} | {own:.3f}"
        lines.append(f"| {name} | {row} |")
    return lines


def main() -> None:
    """Measure, print and write the Markdown."""
    parser = study_parser(__doc__.splitlines()[0])
    args = parser.parse_args()
    lines = [
        "| collection | part | version | NN | FT (--partial) | own whole first |",
        "|---|---|---|---|---|---|",
    ]
    for name in COLLECTIONS:
        lines += measure(name, args.data_root, args.jobs, args.every)
        print(lines[-1], flush=True)
    report_measured(args, "partial_scans.py", MARKER, lines)


if __name__ == "__main__":
    main()
