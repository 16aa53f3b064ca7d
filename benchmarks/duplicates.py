"""Near-duplicates: does `cfsig duplicates` find copies of a model, and only them?

    python benchmarks/duplicates.py --data DATA/shrec07 --every 10 [--below D]

In a temporary folder: links to every mesh of DATA (``<class>/<file>``), and for every k-th
mesh (``--every``: 40 of SHREC 2007's 400) a copy ``<class>/<stem>-copy.ply`` re-saved as
binary PLY, rotated at random and scaled by a random factor in [0.5, 2]. Indexes it all with
the default descriptor (``cfsig index``, one job), runs ``cfsig duplicates --json`` (default
threshold, or ``--below``) and checks that every copy is grouped with its original and no
group holds two of the originals copied. Prints, to choose the threshold by, the distance of
each copy to its original and the distance of each mesh of DATA to its nearest other mesh of
DATA (quantiles), the threshold where the share of copies farther than it equals the share of
meshes of DATA with another nearer than it (the equal error threshold), what
`cfsig.search.duplicates.duplicate_groups` finds at thresholds around it, and the groups that
join meshes of DATA themselves.
"""

from __future__ import annotations

import json
import subprocess
import sys
import tempfile
from pathlib import Path

import igl
import numpy as np
from common import arguments, meshes, table
from scipy.spatial.transform import Rotation

import cfsig
from cfsig.search.duplicates import duplicate_groups
from cfsig.search.nearest import distances

QUANTILES = (0.0, 0.05, 0.1, 0.5, 0.9)
SWEEP = (0.2, 0.3, 0.4, 0.45, 0.5, 0.6, 0.7, 1.0, 1.4)


def write_copy(source: Path, target: Path, rng: np.random.Generator) -> None:
    """Write ``source`` rotated at random and scaled in [0.5, 2] as a binary PLY file."""
    vertices, faces = igl.read_triangle_mesh(str(source))
    moved = vertices @ Rotation.random(random_state=rng).as_matrix().T * rng.uniform(0.5, 2)
    header = (
        f"ply\nformat binary_little_endian 1.0\nelement vertex {len(moved)}\n"
        "property float x\nproperty float y\nproperty float z\n"
        f"element face {len(faces)}\nproperty list uchar int vertex_indices\nend_header\n"
    )
    rows = np.zeros(len(faces), [("n", "u1"), ("v", "<i4", 3)])
    rows["n"], rows["v"] = 3, faces
    target.write_bytes(header.encode() + moved.astype("<f4").tobytes() + rows.tobytes())


def cfsig_run(*args: object) -> str:
    """Run ``python -m cfsig ARGS``; its standard output."""
    command = [sys.executable, "-m", "cfsig", *map(str, args)]
    return subprocess.run(command, check=True, capture_output=True, text=True).stdout


def main() -> None:
    """Make the copies, index, find the groups, check them, print the distances."""
    parser = arguments(__doc__.splitlines()[0])
    parser.add_argument("--below", type=float, help="threshold [cfsig's default]")
    args = parser.parse_args()
    files = meshes(args.data)
    copied = files[:: args.every]
    rng = np.random.default_rng(0)
    with tempfile.TemporaryDirectory() as tmp:
        folder, index = Path(tmp) / "meshes", Path(tmp) / "index"
        for path in files:
            (folder / path.parent.name).mkdir(parents=True, exist_ok=True)
            (folder / path.parent.name / path.name).symlink_to(path.resolve())
        for path in copied:
            write_copy(path, folder / path.parent.name / f"{path.stem}-copy.ply", rng)
        cfsig_run("index", folder, "-o", index, "--jobs", 1)
        below = ["--below", args.below] if args.below else []
        groups = json.loads(cfsig_run("duplicates", index, "--json", *below))
        originals = [f"{p.parent.name}/{p.name}" for p in copied]
        copies = [f"{p.parent.name}/{p.stem}-copy.ply" for p in copied]
        with cfsig.IndexReader(index) as reader:
            names = list(reader.column("names"))
            vectors = reader.signatures[:]
            params = reader.params
            sweep = []
            for below_t in SWEEP:
                named = [[e.name for e in g.entries] for g in duplicate_groups(reader, below_t)]
                sweep.append([below_t, *judge(named, originals, copies)])
    row = {name: i for i, name in enumerate(names)}
    found, mixed = judge([g["names"] for g in groups], originals, copies)
    own = [g for g in groups if all(not n.endswith("-copy.ply") for n in g["names"])]
    pairs = distances(params.descriptor, vectors[[row[c] for c in copies]], vectors)
    to_original = pairs[np.arange(len(copies)), [row[o] for o in originals]]
    data = [row[f"{p.parent.name}/{p.name}"] for p in files]
    among = distances(params.descriptor, vectors[data], vectors[data])
    np.fill_diagonal(among, np.inf)
    nearest = among.min(axis=1)
    print(f"{len(files)} meshes of {args.data}, {len(copies)} copied; threshold "
          f"{args.below or 'default'}\n")  # fmt: skip
    heads = ["distances", *(f"q{q:g}" for q in QUANTILES), "max"]
    print(table(heads, [
        ["copy to its original", *np.quantile(to_original, QUANTILES), to_original.max()],
        ["mesh to its nearest other", *np.quantile(nearest, QUANTILES), nearest.max()],
    ]))  # fmt: skip
    candidates = np.sort(np.concatenate([to_original, nearest]))
    gaps = [abs((to_original >= t).mean() - (nearest < t).mean()) for t in candidates]
    equal = candidates[int(np.argmin(gaps))]
    print(f"\nequal error threshold: {equal:.3f} ({(to_original >= equal).mean():.1%} of the "
          f"copies farther, {(nearest < equal).mean():.1%} of the meshes nearer)\n")  # fmt: skip
    heads = ["threshold", "copies grouped with their original", "groups of two originals"]
    print(table(heads, sweep))
    print(f"\ncopies grouped with their original: {found} of {len(copies)}")
    print(f"groups holding two originals copied: {mixed}")
    print(f"groups of meshes of {args.data.name} alone: {len(own)}")
    for g in own:
        print(f"  {', '.join(g['names'])} (joined below {g['distance']:.4f})")
    if found < len(copies) or mixed:
        sys.exit("FAILED")


def judge(groups: list[list[str]], originals: list[str], copies: list[str]) -> tuple[int, int]:
    """Copies grouped with their original, and groups holding two of the originals."""
    group_of = {name: i for i, names in enumerate(groups) for name in names}
    found = sum(
        o in group_of and group_of.get(c) == group_of[o]
        for o, c in zip(originals, copies, strict=True)
    )
    return found, sum(len(set(names) & set(originals)) > 1 for names in groups)


if __name__ == "__main__":
    main()
