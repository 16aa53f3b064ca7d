"""Princeton Shape Benchmark classification (``.cla``) files: model ids and their classes."""

from __future__ import annotations

import os
from collections.abc import Mapping, Sequence
from pathlib import Path


def _int(token: str, where: str) -> int:
    """Parse a non-negative integer count or raise a ValueError naming its location."""
    try:
        value = int(token)
    except ValueError:
        raise ValueError(f"{where}: expected an integer, got {token!r}") from None
    if value < 0:
        raise ValueError(f"{where}: expected a non-negative integer, got {value}")
    return value


def read_cla(path: str | os.PathLike) -> dict[str, str]:
    """Read a Princeton Shape Benchmark classification (``.cla``) file.

    The format is a ``PSB 1`` header line, a ``numClasses numModels`` line, then for each class
    a ``name parentName count`` line followed by ``count`` lines of model ids. Blank lines are
    ignored.

    Parameters
    ----------
    path : str or os.PathLike
        The ``.cla`` file.

    Returns
    -------
    dict[str, str]
        Model id (as written in the file) -> class name, ``numModels`` entries.

    Raises
    ------
    ValueError
        If the header is not ``PSB 1``, a count is not a non-negative integer, a line has the
        wrong number of fields, a model id appears twice, the file ends early or has extra
        lines, or the counts do not add up to the declared numbers.
    """
    with open(path, encoding="utf-8") as f:
        lines = [(i, line.split()) for i, line in enumerate(f, 1) if line.strip()]
    if not lines or lines[0][1] != ["PSB", "1"]:
        raise ValueError(f"{path}: not a PSB classification file (first line must be 'PSB 1')")
    if len(lines) < 2 or len(lines[1][1]) != 2:
        raise ValueError(f"{path}: second line must be 'numClasses numModels'")
    where = f"{path}:{lines[1][0]}"
    num_classes, num_models = (_int(t, where) for t in lines[1][1])
    classes: dict[str, str] = {}
    k = 2
    for _ in range(num_classes):
        if k >= len(lines):
            raise ValueError(f"{path}: file ends before the {num_classes} declared classes")
        lineno, fields = lines[k]
        if len(fields) != 3:
            raise ValueError(f"{path}:{lineno}: expected 'name parentName count', got {fields}")
        name, count = fields[0], _int(fields[2], f"{path}:{lineno}")
        members = lines[k + 1 : k + 1 + count]
        if len(members) < count or any(len(m) != 1 for _, m in members):
            raise ValueError(f"{path}:{lineno}: class {name!r} should list {count} model ids")
        for mline, (model,) in members:
            if model in classes:
                raise ValueError(f"{path}:{mline}: duplicate model id {model!r}")
            classes[model] = name
        k += 1 + count
    if k != len(lines):
        raise ValueError(f"{path}:{lines[k][0]}: extra lines after the {num_classes} classes")
    if len(classes) != num_models:
        raise ValueError(
            f"{path}: header declares {num_models} models, classes list {len(classes)}"
        )
    return classes


def labels_from_cla(names: Sequence[str], classes: Mapping[str, str]) -> list[str | None]:
    """Look up the class of mesh files in a `read_cla` mapping by their numeric id.

    A file's id is its stem (``17`` for ``human/17.off``), or the stem without a leading
    ``m`` as the Princeton Shape Benchmark names its files (``m17.off``).

    Parameters
    ----------
    names : sequence of str
        Mesh file names or paths.
    classes : mapping of str to str
        Model id -> class name.

    Returns
    -------
    labels : list of str or None
        None where the id is not in ``classes``.
    """
    stems = [Path(name).stem for name in names]
    return [classes.get(stem, classes.get(stem.removeprefix("m"))) for stem in stems]
