"""Mesh files: finding them under folders, naming them, and labelling them by their folder.

Free of NumPy and SciPy, so that the process that walks the folders and writes the index, which
computes no signature (its workers do, `cfsig.batch`), need not load SciPy.
"""

from __future__ import annotations

import os
from collections.abc import Iterable, Iterator
from pathlib import Path

# Binary glTF (.glb) is how most models on the web ship; a glTF or 3MF file is a scene of parts.
MESH_SUFFIXES = (".off", ".obj", ".ply", ".stl", ".glb", ".gltf", ".3mf", ".dae")


def find_meshes(paths: Iterable[str | os.PathLike]) -> Iterator[tuple[Path, str]]:
    """Mesh files under some files and folders, in a stable order, with their names.

    Folders are walked recursively (sorted, hidden entries skipped) for the `MESH_SUFFIXES`
    files, following symbolic links to folders and files; a folder reached again (through a
    link cycle, or two links to it) is walked once. A file given directly is taken whatever its
    extension, so that reading it reports what is wrong with it.

    Parameters
    ----------
    paths : iterable of str or path-like
        Files and folders.

    Yields
    ------
    path : Path
        A mesh file.
    name : str
        Its path relative to the folder given (POSIX separators), or its file name when it was
        given directly.
    """
    for root in map(Path, paths):
        if not root.is_dir():
            yield root, root.name
            continue
        seen: set[tuple[int, int]] = set()  # (device, inode) of the folders walked
        for folder, dirs, files in os.walk(root, followlinks=True):
            status = os.stat(folder)
            if (status.st_dev, status.st_ino) in seen:
                dirs[:] = []
                continue
            seen.add((status.st_dev, status.st_ino))
            dirs[:] = sorted(d for d in dirs if not d.startswith("."))
            for file in sorted(files):
                if Path(file).suffix.lower() in MESH_SUFFIXES and not file.startswith("."):
                    path = Path(folder) / file
                    yield path, path.relative_to(root).as_posix()


def mesh_label(path: str | os.PathLike) -> str:
    """The class label of a mesh file: the name of the folder that holds it.

    Parameters
    ----------
    path : str or path-like
        A mesh file, e.g. ``shrec07/ant/81.off``.

    Returns
    -------
    label : str
        E.g. ``ant``; empty for a relative path without a folder.
    """
    return Path(path).parent.name
