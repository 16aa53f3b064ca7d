"""Descriptors: a vector per mesh whose L1 distance compares shapes.

Each descriptor is a module of this package that defines ``DESCRIPTOR``, a
`cfsig.descriptors.base.Descriptor`, and one entry of `_MODULES`. Modules are imported when a
descriptor is first asked for, so that listing the names loads no numerical library.
"""

from __future__ import annotations

from importlib import import_module
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from cfsig.descriptors.base import Descriptor
    from cfsig.params import Layout, Params

_MODULES = {
    "intrinsic": "cfsig.descriptors.intrinsic",
    "cf": "cfsig.descriptors.cf",
    "sh": "cfsig.descriptors.sh",
    "gps": "cfsig.descriptors.gps",
    "lf": "cfsig.descriptors.lf",
    "rigid": "cfsig.descriptors.rigid",
    "amrg": "cfsig.descriptors.amrg",
}
NAMES = tuple(_MODULES)  # the default first


def get(name: str) -> Descriptor:
    """The descriptor of a name.

    Parameters
    ----------
    name : str
        One of `NAMES`.

    Returns
    -------
    descriptor : Descriptor

    Raises
    ------
    ValueError
        No descriptor has that name.
    """
    if name not in _MODULES:
        raise ValueError(f"unknown descriptor {name!r}; choose from {', '.join(NAMES)}")
    descriptor: Descriptor = import_module(_MODULES[name]).DESCRIPTOR
    return descriptor


def layout(params: Params) -> Layout:
    """What an index keeps per row for the signatures of ``params``.

    Parameters
    ----------
    params : Params
        Signature parameters.

    Returns
    -------
    layout : Layout

    Raises
    ------
    ValueError
        ``params.descriptor`` is not one of `NAMES`.
    """
    return get(params.descriptor).layout(params)
