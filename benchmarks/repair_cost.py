"""What the repair stage costs and changes on clean closed meshes: nothing, measured.

Usage: python benchmarks/repair_cost.py [--data SHREC07_FOLDER] [--every K] [--json FILE]

For each mesh (read once), in one run and interleaved: the signature through the whole library
(`compute_signature`, whose first step is the repair stage's check) and the same signature made
without the stage (`conformal_factor` and `signature_of` directly, the pipeline before it
existed), for `cf` and `cfhks`. Prints how many vectors and phi are bit-identical, and the
median ratio of the two times (best of 3 each, taken in turns). Every mesh must take the route
``clean``.
"""

from __future__ import annotations

import time

import common
import numpy as np

from cfsig.descriptors.signature import compute_signature, signature_of
from cfsig.files.mesh import Mesh, read_mesh
from cfsig.operators.conformal import conformal_factor
from cfsig.params import Params


def bare(mesh: Mesh, params: Params) -> tuple[np.ndarray, np.ndarray]:
    """Phi and signature without the repair stage: the pipeline before it existed."""
    cf = conformal_factor(mesh, params.mollify)
    return cf.phi, signature_of(mesh, cf.operators, params, cf)


def staged(mesh: Mesh, params: Params) -> tuple[np.ndarray, np.ndarray]:
    """Phi and signature through the library, the repair stage first."""
    sig = compute_signature(mesh, params)
    assert sig.route == "clean", "benchmarks/repair_cost.py measures clean meshes"
    return sig.phi, sig.vector


def interleaved(mesh: Mesh, params: Params, repeat: int = 3) -> tuple[bool, float]:
    """Whether both give the same bits, and the ratio of their best times, taken in turns."""
    best = {bare: np.inf, staged: np.inf}
    results = {}
    for _ in range(repeat):
        for func in best:
            start = time.perf_counter()
            results[func] = func(mesh, params)
            best[func] = min(best[func], time.perf_counter() - start)
    (phi, vector), (phi2, vector2) = results[bare], results[staged]
    same = np.array_equal(phi, phi2) and np.array_equal(vector, vector2)
    return bool(same), best[staged] / best[bare]


def main() -> None:
    """Time and compare both pipelines on every mesh; print a summary table."""
    args = common.arguments(__doc__.splitlines()[0]).parse_args()
    rows = []
    for path in common.meshes(args):
        mesh = read_mesh(path)
        for descriptor in ("cf", "cfhks"):
            same, ratio = interleaved(mesh, Params(descriptor=descriptor))
            name = f"{path.parent.name}/{path.name}"
            rows.append({"mesh": name, "descriptor": descriptor, "identical": same, "ratio": ratio})
    common.save_rows(args.json, rows)
    table = []
    for descriptor in ("cf", "cfhks"):
        mine = [r for r in rows if r["descriptor"] == descriptor]
        table.append(
            [
                descriptor,
                len(mine),
                sum(r["identical"] for r in mine),
                common.median([r["ratio"] for r in mine]),
            ]
        )
    headers = ["descriptor", "meshes", "bit-identical", "median time ratio"]
    print(common.table(headers, table))


if __name__ == "__main__":
    main()
