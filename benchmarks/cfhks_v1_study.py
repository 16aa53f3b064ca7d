"""Version 1 of ``cfhks`` on SHREC 2007: the study behind it and its comparison with the paper's CF.

Stages (run in this order; each prints Markdown for docs/descriptors.md):

    python benchmarks/cfhks_v1_study.py channels   # per-mesh channels of every variant -> cache
    python benchmarks/cfhks_v1_study.py cost       # CPU time of k eigenpairs against the CF
    python benchmarks/cfhks_v1_study.py study      # variants, ablations, leave-one-class-out CV
    python benchmarks/cfhks_v1_study.py scales     # label-free medians (cfhks.DESIGNS[1])
    python benchmarks/cfhks_v1_study.py compare    # cf vs cfhks from the library: measures, time

``channels`` computes, once per mesh, the conformal factor, 50 Laplace-Beltrami eigenpairs and
from them every channel variant the study compares, and caches them in a .npz file (under /tmp
by default; never commit it). ``study`` and ``scales`` only read that cache. ``compare``
computes both descriptors with the library, mesh by mesh in one process, alternating which goes
first, and times each (CPU seconds of the process, reading the file included).
"""

from __future__ import annotations

import argparse
import collections
import os
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ[_var] = "1"

import numpy as np  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from cfsig.descriptors import intrinsic as cfhks
from cfsig.descriptors.signature import sample_phi, signature_file, signature_of  # noqa: E402
from cfsig.evaluation.measures import evaluate_distances  # noqa: E402
from cfsig.files.mesh import read_mesh  # noqa: E402
from cfsig.operators.conformal import conformal_factor  # noqa: E402
from cfsig.operators.spectrum import heat_kernel_signature, laplace_spectrum  # noqa: E402
from cfsig.params import Params  # noqa: E402
from cfsig.search.nearest import l1_distances  # noqa: E402

DATA = ROOT.parent / "shared" / "data" / "shrec07"
CACHE = Path("/tmp/cfsig-descriptor-channels.npz")
MAX_PAIRS = 50
PAIRS = (20, 30, 50)
AFFORDABLE = (20, 30)  # eigenpairs within the 5x time budget (the `cost` stage measures it)
TAUS = 0.0025 * 2.0 ** np.arange(10)  # diffusion times / area
Q = cfhks.QUANTILES
V1 = cfhks.DESIGNS[1]


def _paths(data: Path) -> list[Path]:
    """SHREC 2007's meshes in the order of their numbers."""
    return sorted(data.glob("*/*.off"), key=lambda p: int(p.stem))


def _channels_of(path: Path) -> dict[str, np.ndarray]:
    """Every channel variant of one mesh."""
    mesh = read_mesh(path)
    cf = conformal_factor(mesh, Params().mollify)
    out = {"cf": signature_of(mesh, cf.operators, Params(), cf)}
    samples = sample_phi(mesh.faces, cf.operators.face_areas, cf.phi, 5 * len(mesh.faces), 0)
    out["phi_sampled"] = np.quantile(np.concatenate([samples, cf.phi]), (np.arange(Q) + 0.5) / Q)
    area = cf.operators.vertex_area.sum()
    weights = cf.operators.vertex_area / area
    out["phi"] = cfhks.weighted_quantiles(cf.phi, weights, Q)
    lo, hi = cf.phi.min(), cf.phi.max()
    out["phi_unit"] = cfhks.weighted_quantiles((cf.phi - lo) / (hi - lo), weights, Q)
    full = laplace_spectrum(
        cf.operators.laplacian, cf.operators.vertex_area, cf.operators.labels, cf.solve, MAX_PAIRS
    )
    out["spectrum"] = np.log(full.eigenvalues * area)
    for k in PAIRS:
        part = type(full)(
            full.eigenvalues[:k], full.eigenvectors[:, :k], full.vertex_area, full.labels
        )
        hks = heat_kernel_signature(part, TAUS * area)
        out[f"heat{k}"] = np.array(
            [cfhks.weighted_quantiles(np.log(area * h), weights, Q) for h in hks.T]
        )
    return out


def channels(args: argparse.Namespace) -> None:
    """Compute and cache every channel variant of every mesh."""
    paths = _paths(args.data)
    with ProcessPoolExecutor(args.jobs) as pool:
        rows = list(pool.map(_channels_of, paths, chunksize=4))
    arrays = {key: np.array([row[key] for row in rows]) for key in rows[0]}
    np.savez(args.cache, labels=[p.parent.name for p in paths], **arrays)
    print(f"{len(paths)} meshes -> {args.cache}")


def _w1(x: np.ndarray) -> np.ndarray:
    """All-pairs mean absolute difference of rows (the 1-Wasserstein distance of quantiles)."""
    return np.abs(x[:, None, :] - x[None, :, :]).mean(axis=-1)


def _by_median(d: np.ndarray) -> np.ndarray:
    """A distance matrix divided by its median over all pairs (no labels involved)."""
    return d / np.median(d[np.triu_indices(len(d), 1)])


class _Study:
    """Distance matrices of the cached channels."""

    def __init__(self, cache: Path) -> None:
        z = np.load(cache)
        self.labels = [str(s) for s in z["labels"]]
        self.z = z
        self.memo: dict[str, np.ndarray] = {}

    def channel(self, name: str) -> np.ndarray:
        """A median-normalised channel distance: ``phi``, ``spectrumK``, ``heatK_J``..."""
        if name not in self.memo:
            if name.startswith("spectrum"):
                d = _w1(self.z["spectrum"][:, : int(name[8:])])
            elif name.startswith("heat"):
                k, j = name[4:].split("_")
                d = _w1(self.z[f"heat{k}"][:, int(j)])
            elif name == "cf":
                d = l1_distances(self.z["cf"], self.z["cf"])
            else:
                d = _w1(self.z[name])
            self.memo[name] = _by_median(d)
        return self.memo[name]

    def heat(self, k: int, first: int, count: int) -> np.ndarray:
        """The heat channel: per-time distances, each by its median, summed, by the median."""
        return _by_median(sum(self.channel(f"heat{k}_{j}") for j in range(first, first + count)))

    def combined(self, k: int, first: int, count: int, parts=("phi", "spectrum", "heat")):
        """Equal-weight sum of median-normalised channels."""
        terms = {
            "phi": lambda: self.channel("phi"),
            "spectrum": lambda: self.channel(f"spectrum{k}"),
            "heat": lambda: self.heat(k, first, count),
        }
        return sum(terms[p]() for p in parts)


def _row(name: str, report, seconds: str = "") -> str:
    """One Markdown table row of measures."""
    m = report.measures
    return f"| {name} | {m['NN']:.3f} | {m['FT']:.3f} | {m['ST']:.3f} | {m['mAP']:.3f} |{seconds}"


def study(args: argparse.Namespace) -> None:
    """Single channels, ablations, the (k, times) grid and leave-one-class-out selection."""
    s = _Study(args.cache)
    labels = s.labels
    print("| channel (distance) | NN | FT | ST | mAP |\n|---|---|---|---|---|")
    singles = ["cf", "phi_sampled", "phi", "phi_unit", *[f"spectrum{k}" for k in (10, *PAIRS)]]
    for name in singles:
        print(_row(name, evaluate_distances(s.channel(name), labels)))
    for k in (20, 50):
        for j, tau in enumerate(TAUS):
            report = evaluate_distances(s.channel(f"heat{k}_{j}"), labels)
            print(_row(f"heat{k} tau={tau:g}", report))
    k, first, count = cfhks.EIGENPAIRS, _time_index(V1.times[0]), len(V1.times)
    print("\n| ablation of cfhks | NN | FT | ST | mAP |\n|---|---|---|---|---|")
    ablations = [
        ("phi", "spectrum", "heat"),
        ("spectrum", "heat"),
        ("phi", "heat"),
        ("phi", "spectrum"),
        ("heat",),
    ]
    for parts in ablations:
        report = evaluate_distances(s.combined(k, first, count, parts), labels)
        print(_row(" + ".join(parts), report))
    print(
        "\n| weight of one cfhks channel (others 1) | NN | FT | ST | mAP |\n|---|---|---|---|---|"
    )
    parts = {
        "phi": s.channel("phi"),
        "spectrum": s.channel(f"spectrum{k}"),
        "heat": s.heat(k, first, count),
    }
    for name in parts:
        for weight in (0.5, 2.0):
            d = sum(m * (weight if n == name else 1.0) for n, m in parts.items())
            print(_row(f"{name} x{weight:g}", evaluate_distances(d, labels)))
    grid = {
        (k, f, c): s.combined(k, f, c)
        for k in PAIRS
        for f in range(6)
        for c in range(1, 7)
        if f + c <= len(TAUS)
    }
    reports = {key: evaluate_distances(d, labels) for key, d in grid.items()}
    print("\nNN / FT / mAP of phi + spectrum + heat by eigenpairs k, first time, number of times")
    print("\n| k | first tau | " + " | ".join(f"{c} times" for c in range(1, 7)) + " |")
    print("|---" * 8 + "|")
    for k in PAIRS:
        for f in range(6):
            cells = [
                reports[(k, f, c)].measures if (k, f, c) in reports else None for c in range(1, 7)
            ]
            text = " | ".join(
                f"{m['NN']:.3f} / {m['FT']:.3f} / {m['mAP']:.3f}" if m else "" for m in cells
            )
            print(f"| {k} | {TAUS[f]:g} | {text} |")
    affordable = {key: d for key, d in grid.items() if key[0] in AFFORDABLE}
    _leave_one_class_out(affordable, reports, labels)


def _time_index(tau: float) -> int:
    """Index of a diffusion time in the study's grid."""
    return int(np.argmin(np.abs(TAUS - tau)))


def _leave_one_class_out(grid: dict, reports: dict, labels: list[str]) -> None:
    """Choose (k, first, count) by mAP on 19 classes, score the 20th; print the estimate."""
    labels_arr = np.asarray(labels)
    held, chosen = collections.defaultdict(list), []
    for cls in sorted(set(labels)):
        rest = np.flatnonzero(labels_arr != cls)
        sub = [labels[i] for i in rest]
        best = max(
            grid,
            key=lambda key: evaluate_distances(grid[key][np.ix_(rest, rest)], sub).measures["mAP"],
        )
        chosen.append(best)
        for m, v in reports[best].per_class[cls].items():
            held[m].append(v)
    estimate = {m: float(np.mean(v)) for m, v in held.items()}
    print("\nleave-one-class-out: configuration chosen by mAP on the other 19 classes, scored on")
    scores = ", ".join(f"{m} {estimate[m]:.3f}" for m in ("NN", "FT", "ST", "mAP"))
    print(f"the held-out class's queries: {scores}")
    for (k, f, c), n in collections.Counter(chosen).most_common():
        print(f"- k={k}, first tau={TAUS[f]:g}, {c} time(s): chosen in {n} fold(s)")
    k, f, c = max(grid, key=lambda key: reports[key].measures["mAP"])
    print(f"\nchosen on all 20 classes (cfhks): k={k}, first tau={TAUS[f]:g}, {c} time(s)")


def cost(args: argparse.Namespace) -> None:
    """CPU seconds of the paper's CF and of k eigenpairs, on every tenth mesh, in one process."""
    times = collections.defaultdict(list)
    for path in _paths(args.data)[::10]:
        start = time.process_time()
        mesh = read_mesh(path)
        cf = conformal_factor(mesh, Params().mollify)
        signature_of(mesh, cf.operators, Params(), cf)
        times["cf"].append(time.process_time() - start)
        for k in PAIRS:
            start = time.process_time()
            laplace_spectrum(
                cf.operators.laplacian, cf.operators.vertex_area, cf.operators.labels, cf.solve, k
            )
            times[k].append(time.process_time() - start)
    base = np.array(times["cf"])
    print(f"{len(base)} meshes; CF (reading, solve, histogram): median {np.median(base):.4f} s")
    print("\n| eigenpairs k | median s | median of (CF + eigenpairs) / CF |\n|---|---|---|")
    for k in PAIRS:
        t = np.array(times[k])
        print(f"| {k} | {np.median(t):.4f} | {np.median((base + t) / base):.2f} |")


def scales(args: argparse.Namespace) -> None:
    """Median distance of each cfhks channel over all pairs (labels unused)."""
    s = _Study(args.cache)
    z = s.z
    k = cfhks.EIGENPAIRS
    idx = [_time_index(t) for t in V1.times]
    iu = np.triu_indices(len(s.labels), 1)
    heat = [_w1(z[f"heat{k}"][:, j]) for j in idx]
    heat_sum = sum(d / np.median(d[iu]) for d in heat)
    found = {
        "phi": np.median(_w1(z["phi"])[iu]),
        "spectrum": np.median(_w1(z["spectrum"][:, :k])[iu]),
        "heat": tuple(float(np.median(d[iu])) for d in heat),
        "heat_sum": np.median(heat_sum[iu]),
    }
    print("SCALES = {" + ", ".join(f'"{key}": {_fmt(v)}' for key, v in found.items()) + "}")


def _fmt(value) -> str:
    """Four significant digits, tuples kept."""
    if isinstance(value, tuple):
        return "(" + ", ".join(f"{v:.4g}" for v in value) + ")"
    return f"{float(value):.4g}"


def compare(args: argparse.Namespace) -> None:
    """Both descriptors by the library, timed mesh by mesh in one process."""
    paths = _paths(args.data)
    names = ("cf", "cfhks")
    params = {n: Params(descriptor=n, version=1) for n in names}
    vectors = {n: [] for n in names}
    seconds = {n: [] for n in names}
    for i, path in enumerate(paths):
        for n in names if i % 2 == 0 else names[::-1]:
            start = time.process_time()
            vectors[n].append(signature_file(path, params[n], args.solver).vector)
            seconds[n].append(time.process_time() - start)
    labels = [p.parent.name for p in paths]
    reports = {}
    for n in names:
        v = np.array(vectors[n])
        reports[n] = evaluate_distances(l1_distances(v, v), labels)
    median = {n: float(np.median(seconds[n])) for n in names}
    ratio = np.median(np.array(seconds["cfhks"]) / np.array(seconds["cf"]))
    print(f"CPU seconds per mesh, reading included, {len(paths)} meshes, solver {args.solver}:")
    print(
        f"median cf {median['cf']:.4f} s, cfhks {median['cfhks']:.4f} s; ratio of medians "
        f"{median['cfhks'] / median['cf']:.2f}, median of per-mesh ratios {ratio:.2f}\n"
    )
    print("| descriptor | NN | FT | ST | mAP | CPU s per mesh (median) |")
    print("|---|---|---|---|---|---|")
    for n in names:
        print(_row(n, reports[n], f" {median[n]:.3f} |"))
    print("\n| class | cf FT | cfhks FT | difference |\n|---|---|---|---|")
    worst = np.inf
    for cls in sorted(reports["cf"].per_class):
        a, b = reports["cf"].per_class[cls]["FT"], reports["cfhks"].per_class[cls]["FT"]
        worst = min(worst, b - a)
        print(f"| {cls} | {a:.3f} | {b:.3f} | {b - a:+.3f} |")
    m = reports["cfhks"].measures
    checks = {
        "FT >= 0.56": m["FT"] >= 0.56,
        "NN >= 0.88": m["NN"] >= 0.88,
        "mAP >= 0.61": m["mAP"] >= 0.61,
        "median time <= 5x cf": median["cfhks"] <= 5 * median["cf"],
        "no class FT more than 0.05 below cf": worst >= -0.05,
    }
    print("\n" + "\n".join(f"- {k}: {'yes' if v else 'NO'}" for k, v in checks.items()))


def main() -> None:
    """Parse the command line and run one stage."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("stage", choices=("channels", "cost", "study", "scales", "compare"))
    parser.add_argument("--data", type=Path, default=DATA, help="SHREC 2007 folder")
    parser.add_argument("--cache", type=Path, default=CACHE, help="channel cache (.npz)")
    parser.add_argument("--jobs", type=int, default=2, help="worker processes for channels")
    parser.add_argument("--solver", default="auto", help="sparse solver for compare")
    args = parser.parse_args()
    if not (args.data / "ant").is_dir():
        sys.exit(f"SHREC 2007 not found at {args.data}")
    stages = {"channels": channels, "cost": cost, "study": study, "scales": scales}
    stages["compare"] = compare
    stages[args.stage](args)


if __name__ == "__main__":
    main()
