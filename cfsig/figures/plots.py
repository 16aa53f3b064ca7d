"""Pictures: meshes coloured by phi, signature histograms, precision/recall curves, result grids.

The meshes are drawn by `cfsig.figures.raster`; matplotlib (Agg, imported inside the functions that
need
it) only lays out and draws images, text, colour bars and plots, and Pillow (which matplotlib
installs) writes them as RGB PNG files. `write_ply` exports phi on a mesh through trimesh, for
MeshLab or Blender. Same input, same bytes: nothing depends on the time, the display or the
random state, and the files carry no metadata.
"""

from __future__ import annotations

import os
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from cfsig.errors import CfsigError
from cfsig.figures.raster import (
    CMAP,
    colormap,
    default_view,
    require_matplotlib,
    shade_mesh,
    unit_interval,
)
from cfsig.files.mesh import Mesh, read_mesh

if TYPE_CHECKING:
    from cfsig.evaluation.measures import RetrievalReport

_DPI = 100
_PANEL, _CAPTION, _COLORBAR = 480, 40, 110  # pixels of `render_phi`
_TILE, _TILE_CAPTION, _FRAME = 160, 34, 5  # pixels of `render_grid`
_FRAMES = {
    "query": (0.58, 0.25, 0.75),
    "right": (0.18, 0.66, 0.25),
    "wrong": (1.0, 0.55, 0.0),
    "result": (0.85, 0.85, 0.85),
}
_PR_PANEL = (260, 230)  # pixels of one `plot_precision_recall` panel
_PR_COLUMNS = 5


@dataclass(frozen=True)
class Thumb:
    """One tile of a result grid.

    Attributes
    ----------
    path : str
        The mesh file; a file that cannot be read is drawn as a placeholder.
    caption : str
        Text under the tile (may hold a newline).
    role : {"query", "right", "wrong", "result"}
        Frame colour: purple for the query, green for a result of the query's class, orange
        for one of another class, light grey when classes are unknown.
    """

    path: str
    caption: str
    role: str = "result"


def phi_colors(phi: np.ndarray, cmap: str = CMAP) -> np.ndarray:
    """Colour per vertex: phi normalised to [0, 1] through a colour map.

    Parameters
    ----------
    phi : (n,) float
        Conformal factor per vertex.
    cmap : str
        A matplotlib colour map; the largest phi gets its top colour, the smallest its bottom.

    Returns
    -------
    colors : (n, 4) uint8
        RGBA, alpha 255.

    Raises
    ------
    MissingDependencyError
        matplotlib is not installed.
    """
    rgba = colormap(cmap)(unit_interval(phi))
    return np.round(rgba * 255).astype(np.uint8)


def render_phi(
    items: Sequence[tuple[Mesh, np.ndarray | None, str]],
    out: str | os.PathLike,
    panel: int = _PANEL,
    cmap: str = CMAP,
    views: Sequence[np.ndarray | None] | None = None,
) -> None:
    """Draw meshes side by side coloured by phi, each normalised to [0, 1], with a colour bar.

    The picture of the paper's Figures 1 and 2. The image is ``len(items) * panel + 110``
    pixels wide and ``panel + 40`` high.

    Parameters
    ----------
    items : sequence of (Mesh, (n,) float or None, str)
        Each mesh, its phi per vertex (None: plain clay, e.g. a mesh as read beside what the
        repair stage made of it) and a caption.
    out : str or path-like
        The PNG file to write.
    panel : int
        Pixel size of each mesh's square panel.
    cmap : str
        A matplotlib colour map.
    views : sequence of (3, 3) float or None, optional
        Each mesh's rotation, as `cfsig.figures.raster.default_view` returns (None: its own
        default view), so that two meshes of one shape can be seen from the same side.

    Raises
    ------
    MissingDependencyError
        matplotlib is not installed.
    """
    width, height = len(items) * panel + _COLORBAR, panel + _CAPTION
    fig = _figure(width, height)
    for i, (mesh, phi, caption) in enumerate(items):
        values = None if phi is None else unit_interval(phi)
        view = None if views is None else views[i]
        image = shade_mesh(mesh, values, view, size=(panel, panel), cmap=cmap)
        ax = fig.add_axes(_box(i * panel, _CAPTION, panel, panel, width, height))
        ax.imshow(_on_white(image), interpolation="nearest")
        ax.set_axis_off()
        if phi is not None:
            caption += f"\nφ in [{float(np.min(phi)):.3g}, {float(np.max(phi)):.3g}]"
        fig.text(
            (i + 0.5) * panel / width, (_CAPTION - 2) / height, caption,
            ha="center", va="top", fontsize=9,
        )  # fmt: skip
    bar = fig.add_axes(_box(len(items) * panel + 20, _CAPTION + panel * 0.15, 18, panel * 0.7,
                            width, height))  # fmt: skip
    fig.colorbar(_scalar_mappable(cmap), cax=bar, ticks=[0, 0.25, 0.5, 0.75, 1])
    bar.set_ylabel("φ, scaled to [0, 1]", fontsize=9)
    bar.tick_params(labelsize=8)
    _save(fig, out)


def phi_panels(
    shown: Sequence[tuple[str | os.PathLike, str, Mesh, np.ndarray, str]],
) -> tuple[list[tuple[Mesh, np.ndarray | None, str]], list[np.ndarray | None]]:
    """The panels and views of `render_phi` for meshes through the repair stage.

    A mesh the repair stage changed (any route but ``"clean"``) is shown twice from the same
    side: as read, in plain clay, then as repaired, coloured by phi, so that what was changed
    can be seen.

    Parameters
    ----------
    shown : sequence of (path, str, Mesh, (n,) float, str)
        Each mesh's file, caption, repaired mesh, phi on it and route.

    Returns
    -------
    items : list of (Mesh, (n,) float or None, str)
        The panels, for `render_phi`.
    views : list of (3, 3) float or None
        Their views, for `render_phi`.

    Raises
    ------
    MeshError
        A file changed since it was read and can no longer be.
    """
    items: list[tuple[Mesh, np.ndarray | None, str]] = []
    views: list[np.ndarray | None] = []
    for path, caption, mesh, phi, route in shown:
        if route == "clean":
            items.append((mesh, phi, caption))
            views.append(None)
            continue
        as_read = read_mesh(path)
        view = default_view(as_read.vertices)
        items += [(as_read, None, f"{caption} as read"), (mesh, phi, f"{caption}, {route}")]
        views += [view, view]
    return items, views


def write_ply(mesh: Mesh, phi: np.ndarray, out: str | os.PathLike, cmap: str = CMAP) -> None:
    """Write a binary PLY with per-vertex colours (phi normalised to [0, 1]) and phi itself.

    Written by trimesh. MeshLab and Blender show the ``red``, ``green``, ``blue``, ``alpha``
    vertex colours; phi is also stored as the vertex property ``quality``, which MeshLab reads
    as vertex quality.

    Parameters
    ----------
    mesh : Mesh
        The mesh, with n vertices and m faces.
    phi : (n,) float
        Conformal factor per vertex.
    out : str or path-like
        The file to write.
    cmap : str
        A matplotlib colour map.

    Raises
    ------
    MissingDependencyError
        matplotlib (for the colour map) is not installed.
    """
    import trimesh

    colors = phi_colors(phi, cmap)
    coloured = trimesh.Trimesh(mesh.vertices, mesh.faces, vertex_colors=colors, process=False)
    coloured.vertex_attributes["quality"] = np.asarray(phi, dtype=np.float32)
    coloured.export(os.fspath(out), file_type="ply")


def plot_histograms(
    histograms: Sequence[np.ndarray],
    labels: Sequence[str],
    edges: tuple[float, float],
    out: str | os.PathLike,
    size: tuple[int, int] = (800, 450),
) -> None:
    """Overlay signature histograms with a legend (the paper's Figures 2 and 3).

    Each histogram has its own colour; those whose labels share a folder (``ant/81.off``,
    ``ant/82.off``) share a line style. The phi axis spans the bins where any histogram is
    non-zero.

    Parameters
    ----------
    histograms : sequence of (bins,) float
        Signatures, each summing to 1.
    labels : sequence of str
        Legend entry of each.
    edges : (float, float)
        Outer edges of the bins (`Params.edges`), in units of phi.
    out : str or path-like
        The PNG file to write.
    size : (int, int)
        Width and height in pixels.

    Raises
    ------
    MissingDependencyError
        matplotlib is not installed.
    """
    hists = np.asarray(histograms, dtype=np.float64)
    bin_edges = np.linspace(edges[0], edges[1], hists.shape[1] + 1)
    used = np.flatnonzero(hists.max(axis=0) > 0)
    first, last = max(used[0] - 2, 0), min(used[-1] + 3, hists.shape[1])
    fig = _figure(*size)
    ax = fig.add_axes(_box(70, 50, size[0] - 90, size[1] - 70, *size))
    groups = list(dict.fromkeys(str(Path(label).parent) for label in labels))
    styles = ["-", "--", ":", "-."]
    for i, (hist, label) in enumerate(zip(hists, labels, strict=True)):
        style = styles[groups.index(str(Path(label).parent)) % len(styles)]
        ax.stairs(hist[first:last], bin_edges[first : last + 1], label=label, linewidth=1.5,
                  color=f"C{i % 10}", linestyle=style)  # fmt: skip
    ax.set_xlabel("φ")
    ax.set_ylabel("fraction of surface samples")
    ax.set_xlim(bin_edges[first], bin_edges[last])
    ax.set_ylim(bottom=0)
    ax.legend(fontsize=8, ncols=1 + len(labels) // 12)
    _save(fig, out)


def plot_precision_recall(
    reports: Mapping[str, RetrievalReport],
    out: str | os.PathLike,
    classes: Sequence[str] | None = None,
) -> None:
    """Precision/recall curves of one or several descriptors side by side (the paper's Figures
    7, 9, 10 and 11): all queries, then one small panel per class, a curve per descriptor.

    Panels are 260 x 230 pixels, five to a row. The first panel's legend names each descriptor
    with its mAP over all queries; with one descriptor, each panel's title holds its mAP.

    Parameters
    ----------
    reports : mapping of str to RetrievalReport
        Descriptor name -> its evaluation, all of the same queries, in the order to draw.
    out : str or path-like
        The PNG file to write.
    classes : sequence of str, optional
        The classes to draw, in order; default: every class of the first report.

    Raises
    ------
    MissingDependencyError
        matplotlib is not installed.
    ValueError
        A class asked for has no curve in every report.
    """
    first = next(iter(reports.values()))
    names = ["all", *(first.per_class if classes is None else classes)]
    missing = [
        c for c in names[1:] if any(c not in r.class_precision_recall for r in reports.values())
    ]
    if missing:
        raise ValueError(f"no precision/recall curve of the classes {', '.join(missing)}")
    recall = first.precision_recall[:, 0]
    rows = -(-len(names) // _PR_COLUMNS)
    columns = min(len(names), _PR_COLUMNS)
    fig = _figure(columns * _PR_PANEL[0], rows * _PR_PANEL[1])
    axes = fig.subplots(rows, columns, squeeze=False, sharex=True, sharey=True)
    for ax, name in zip(axes.flat, names, strict=False):
        for i, (descriptor, report) in enumerate(reports.items()):
            curve = (
                report.precision_recall[:, 1]
                if name == "all"
                else report.class_precision_recall[name]
            )
            label = f"{descriptor} (mAP {report.measures['mAP']:.2f})"
            ax.plot(recall, curve, color=f"C{i % 10}", linewidth=1.8, marker=".", markersize=4,
                    label=label)  # fmt: skip
        mean_ap = first.measures["mAP"] if name == "all" else first.per_class[name]["mAP"]
        ax.set_title(f"{name} (mAP {mean_ap:.2f})" if len(reports) == 1 else name, fontsize=9)
        ax.set_xlim(0, 1)
        ax.set_ylim(0, 1.02)
        ax.grid(color="0.92")
        ax.tick_params(labelsize=7)
    if len(reports) > 1:
        axes.flat[0].legend(fontsize=6, loc="lower left")
    for ax in axes.flat[len(names) :]:
        ax.set_axis_off()
    for ax in axes[-1]:
        ax.set_xlabel("recall", fontsize=8)
    for ax in axes[:, 0]:
        ax.set_ylabel("precision", fontsize=8)
    fig.subplots_adjust(left=0.22 / columns, right=0.98, bottom=0.2 / rows, top=1 - 0.13 / rows,
                        wspace=0.12, hspace=0.35)  # fmt: skip
    _save(fig, out)


def render_grid(
    rows: Sequence[Sequence[Thumb]], out: str | os.PathLike, tile: int = _TILE
) -> list[str]:
    """Draw meshes as framed, captioned clay thumbnails in a grid (the paper's Figures 8, 12).

    The image is ``tile`` pixels per column (as many columns as the longest row) and
    ``tile + 34`` per row.

    Parameters
    ----------
    rows : sequence of sequence of Thumb
        The tiles, row by row.
    out : str or path-like
        The PNG file to write.
    tile : int
        Pixel size of each square thumbnail.

    Returns
    -------
    problems : list of str
        One line ``<file>: <reason>`` for each distinct mesh that could not be drawn (missing
        or unreadable); those tiles show a placeholder saying so.

    Raises
    ------
    MissingDependencyError
        matplotlib is not installed.
    """
    columns = max(len(row) for row in rows)
    width, height = columns * tile, len(rows) * (tile + _TILE_CAPTION)
    canvas = np.ones((height, width, 3))
    meshes: dict[str, Mesh | str] = {}
    labels = []
    for r, row in enumerate(rows):
        for c, thumb in enumerate(row):
            if thumb.path not in meshes:
                meshes[thumb.path] = _load(thumb.path)
            top, left = r * (tile + _TILE_CAPTION), c * tile
            cell = canvas[top : top + tile, left : left + tile]
            mesh = meshes[thumb.path]
            inner = tile - 2 * _FRAME
            if isinstance(mesh, Mesh):
                image = shade_mesh(mesh, size=(inner, inner))
                cell[_FRAME:-_FRAME, _FRAME:-_FRAME] = _on_white(image)
            else:
                cell[_FRAME:-_FRAME, _FRAME:-_FRAME] = 0.93
                labels.append((left + tile / 2, top + tile / 2, mesh.split()[0], 11, "center"))
            _frame(cell, _FRAMES[thumb.role])
            labels.append((left + tile / 2, top + tile + 2, thumb.caption, 7, "top"))
    fig = _figure(width, height)
    ax = fig.add_axes((0, 0, 1, 1))
    ax.imshow(canvas, interpolation="nearest")
    ax.set_axis_off()
    for x, y, text, fontsize, va in labels:
        fig.text(x / width, 1 - y / height, text, ha="center", va=va, fontsize=fontsize)
    _save(fig, out)
    return [f"{path}: {problem}" for path, problem in meshes.items() if isinstance(problem, str)]


def retrieval_row(
    query: tuple[str, str, str | None],
    results: Sequence[tuple[str, str, str | None, float]],
) -> list[Thumb]:
    """Tiles of one query and its results, framed by whether each result is of its class.

    Parameters
    ----------
    query : (str, str, str or None)
        The query's mesh file, caption and class (None when unknown: no green/orange frames).
    results : sequence of (str, str, str or None, float)
        Each result's mesh file, name, class and distance, nearest first.

    Returns
    -------
    thumbs : list of Thumb
        The query tile then one per result captioned with its rank, distance and name.
    """
    path, caption, label = query
    tiles = [Thumb(path, f"query\n{caption}", "query")]
    for rank, (file, name, result_label, distance) in enumerate(results, 1):
        role = "result" if label is None else ("right" if result_label == label else "wrong")
        tiles.append(Thumb(file, f"{rank}: {distance:.4f}\n{name}", role))
    return tiles


def _load(path: str) -> Mesh | str:
    """Read a mesh for a thumbnail, or say why not, starting with the placeholder's word."""
    if not Path(path).is_file():
        return "missing (no such file: moved or deleted since it was indexed?)"
    try:
        return read_mesh(path)
    except CfsigError as exc:
        return f"unreadable ({str(exc).removeprefix(f'{path}: ')})"


def _frame(cell: np.ndarray, color: tuple[float, float, float]) -> None:
    """Paint a border of `_FRAME` pixels around an image cell, in place."""
    cell[:_FRAME], cell[-_FRAME:] = color, color
    cell[:, :_FRAME], cell[:, -_FRAME:] = color, color


def _on_white(image: np.ndarray) -> np.ndarray:
    """Composite an RGBA image over a white background, (h, w, 3)."""
    alpha = image[..., 3:]
    return image[..., :3] * alpha + (1 - alpha)


def _box(left: float, bottom: float, width: float, height: float, fig_w: int, fig_h: int):
    """A rectangle in pixels from the bottom-left corner, as figure fractions."""
    return (left / fig_w, bottom / fig_h, width / fig_w, height / fig_h)


def _scalar_mappable(cmap: str):
    """What a colour bar needs: the colour map over [0, 1]."""
    matplotlib = require_matplotlib()
    return matplotlib.cm.ScalarMappable(matplotlib.colors.Normalize(0, 1), cmap)


def _figure(width: int, height: int):
    """An Agg figure of exactly ``width`` x ``height`` pixels, not registered with pyplot."""
    require_matplotlib()
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(width / _DPI, height / _DPI), dpi=_DPI)
    FigureCanvasAgg(fig)
    return fig


def _save(fig, out: str | os.PathLike) -> None:
    """Write a figure as an RGB PNG (no alpha: a third smaller) with no metadata at all."""
    from PIL import Image  # installed with matplotlib, which needs it

    fig.canvas.draw()
    rgb = np.asarray(fig.canvas.buffer_rgba())[..., :3]
    Image.fromarray(np.ascontiguousarray(rgb)).save(out, format="png")
