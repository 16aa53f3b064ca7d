"""Time a grid of 20 thumbnails of about 10k-vertex meshes, as `cfsig query --png` draws it.

Usage: python benchmarks/render_grid.py [SHREC07_FOLDER] [--repeat 5]

Takes the 20 SHREC 2007 meshes whose vertex counts are nearest 10,000 and times, in one run:
reading them; shading their thumbnails, with and without back-face culling;
`figures.render_grid` (reading, the numpy z-buffer rasteriser, matplotlib layout and the PNG
file); the same grid drawn the other way the task suggested, matplotlib `PolyCollection`s with
faces sorted back to front (painter's algorithm); and the whole grid in a fresh Python process
(imports included), as a command pays it. Prints a Markdown table of medians for
docs/performance.md.
"""

from __future__ import annotations

import argparse
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from cfsig.figures import plots as figures
from cfsig.figures import raster
from cfsig.files.mesh import read_mesh

SHREC = Path(__file__).resolve().parents[2] / "shared" / "data" / "shrec07"
COLUMNS, TILE = 5, 160


def nearest_10k(folder: Path, count: int = 20) -> list[tuple[Path, int]]:
    """The ``count`` OFF files whose vertex counts (from their headers) are nearest 10,000."""
    sizes = []
    for path in sorted(folder.glob("*/*.off")):
        with open(path) as f:
            header = f.readline().split()[1:] or f.readline().split()
        sizes.append((abs(int(header[0]) - 10_000), str(path), int(header[0])))
    return [(Path(p), n) for _, p, n in sorted(sizes)[:count]]


def zbuffer_grid(paths: list[Path], out: Path) -> None:
    """The grid as cfsig draws it."""
    thumbs = [figures.Thumb(str(p), f"{p.parent.name}/{p.name}") for p in paths]
    rows = [thumbs[i : i + COLUMNS] for i in range(0, len(thumbs), COLUMNS)]
    figures.render_grid(rows, out, tile=TILE)


def painter_grid(paths: list[Path], out: Path) -> None:
    """The same grid with one PolyCollection per mesh, faces sorted back to front."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.collections import PolyCollection
    from matplotlib.figure import Figure

    rows = -(-len(paths) // COLUMNS)
    fig = Figure(figsize=(COLUMNS * TILE / 100, rows * TILE / 100), dpi=100)
    FigureCanvasAgg(fig)
    for i, path in enumerate(paths):
        mesh = read_mesh(path)
        row, column = divmod(i, COLUMNS)
        ax = fig.add_axes((column / COLUMNS, 1 - (row + 1) / rows, 1 / COLUMNS, 1 / rows))
        ax.set_axis_off()
        view = raster.default_view(mesh.vertices)
        corners = raster.screen_coordinates(mesh.vertices, view, (TILE, TILE))[mesh.faces]
        normals = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
        normals /= np.maximum(np.linalg.norm(normals, axis=1, keepdims=True), 1e-300)
        normals[:, 1] *= -1  # screen rows grow downwards
        light = 0.3 + 0.7 * np.abs(normals @ raster.LIGHT)
        order = np.argsort(corners[:, :, 2].mean(axis=1), kind="stable")
        colors = np.column_stack([np.outer(light, [0.78, 0.76, 0.72]), np.ones(len(light))])
        ax.add_collection(
            PolyCollection(
                corners[order, :, :2],
                facecolors=colors[order],
                edgecolors="none",
                antialiaseds=False,
            )  # fmt: skip
        )
        ax.set_xlim(0, TILE)
        ax.set_ylim(TILE, 0)
    fig.savefig(out, format="png", metadata={"Software": None})


def without_culling(meshes: list) -> None:
    """Shade the thumbnails with every face rasterised, as for an open mesh."""
    visible = raster._visible_faces
    raster._visible_faces = lambda mesh, toward: mesh.faces
    try:
        for mesh in meshes:
            raster.shade_mesh(mesh, size=(TILE, TILE))
    finally:
        raster._visible_faces = visible


def fresh_process(paths: list[Path], out: Path) -> float:
    """Wall time of a new interpreter that imports cfsig's renderer and draws the grid."""
    code = (
        "import sys; sys.path.insert(0, sys.argv[1]); import render_grid as b;"
        "from pathlib import Path;"
        "b.zbuffer_grid([Path(p) for p in sys.argv[3:]], Path(sys.argv[2]))"
    )
    start = time.perf_counter()
    here = str(Path(__file__).parent)
    subprocess.run([sys.executable, "-c", code, here, str(out), *map(str, paths)], check=True)
    return time.perf_counter() - start


def timed(func, repeat: int) -> list[float]:
    """Wall times of ``repeat`` calls after one warm-up call."""
    func()
    times = []
    for _ in range(repeat):
        start = time.perf_counter()
        func()
        times.append(time.perf_counter() - start)
    return times


def main() -> None:
    """Run the timings and print the table."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("folder", nargs="?", type=Path, default=SHREC)
    parser.add_argument("--repeat", type=int, default=5)
    args = parser.parse_args()
    if not (args.folder / "ant").is_dir():
        sys.exit(f"SHREC07 not found at {args.folder}: run ../shared/data/unpack-shrec07 first")
    chosen = nearest_10k(args.folder)
    paths = [p for p, _ in chosen]
    vertices = [n for _, n in chosen]
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp)
        meshes = [read_mesh(p) for p in paths]
        results = {
            "read the 20 meshes": timed(lambda: [read_mesh(p) for p in paths], args.repeat),
            "shade the 20 thumbnails (`shade_mesh`)": timed(
                lambda: [raster.shade_mesh(m, size=(TILE, TILE)) for m in meshes], args.repeat
            ),
            "the same without back-face culling": timed(
                lambda: without_culling(meshes), args.repeat
            ),
            "cfsig `render_grid` (z-buffer), incl. reading": timed(
                lambda: zbuffer_grid(paths, out / "z.png"), args.repeat
            ),
            "painter's algorithm (PolyCollection), incl. reading": timed(
                lambda: painter_grid(paths, out / "p.png"), args.repeat
            ),
            "cfsig grid in a fresh process (imports included)": [
                fresh_process(paths, out / "f.png") for _ in range(args.repeat)
            ],
        }
    base = statistics.median(results["cfsig `render_grid` (z-buffer), incl. reading"])
    print(
        f"20 meshes, {min(vertices)}-{max(vertices)} vertices (median "
        f"{statistics.median(vertices):.0f}), {COLUMNS}x4 tiles of {TILE} px, "
        f"{args.repeat} runs each\n"
    )
    print("| step | median (s) | min-max (s) | ratio to cfsig grid |")
    print("|---|---|---|---|")
    for name, times in results.items():
        median = statistics.median(times)
        print(
            f"| {name} | {median:.2f} | {min(times):.2f}-{max(times):.2f} | {median / base:.2f} |"
        )


if __name__ == "__main__":
    main()
