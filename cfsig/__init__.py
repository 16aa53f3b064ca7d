"""cfsig: pose-invariant 3D shape retrieval with conformal-factor signatures.

The names below are the library's public API, so that ``import cfsig`` is enough::

    with cfsig.IndexReader("shrec07.h5") as index:
        query = cfsig.signature_file("ant/81.off", index.params).vector
        hits = cfsig.search(index, query[None], k=20)[0]

Each is imported from its module on first use (PEP 562), so that importing the package loads
neither SciPy nor matplotlib.
"""

from __future__ import annotations

from importlib import import_module
from typing import TYPE_CHECKING, Any

# Public name -> the module that defines it.
_EXPORTS = {
    "Params": "params",
    "Signature": "signature",
    "signature_file": "signature",
    "compute_signature": "signature",
    "read_mesh": "mesh",
    "Entry": "index",
    "IndexReader": "index",
    "IndexWriter": "index",
    "index_meshes": "batch",
    "compute_many": "batch",
    "Hit": "nearest",
    "search": "nearest",
    "partial_file": "parts",
    "partial_search": "parts",
    "evaluate_partial": "evaluate",
    "evaluate_queries": "measures",
    "Collection": "evaluate",
    "compute_collection": "evaluate",
    "collection_from_index": "evaluate",
    "evaluate_collections": "evaluate",
    "evaluate_distances": "measures",
    "RetrievalReport": "measures",
    "read_cla": "cla",
    "CfsigError": "errors",
}
__all__ = [
    "CfsigError",
    "Collection",
    "Entry",
    "Hit",
    "IndexReader",
    "IndexWriter",
    "Params",
    "RetrievalReport",
    "Signature",
    "__version__",
    "collection_from_index",
    "compute_collection",
    "compute_many",
    "compute_signature",
    "evaluate_collections",
    "evaluate_distances",
    "evaluate_partial",
    "evaluate_queries",
    "index_meshes",
    "read_cla",
    "partial_file",
    "partial_search",
    "read_mesh",
    "search",
    "signature_file",
]  # the keys of _EXPORTS and __version__ (tests/test_api.py checks)

if TYPE_CHECKING:
    from .batch import compute_many, index_meshes
    from .cla import read_cla
    from .errors import CfsigError
    from .evaluate import (
        Collection,
        collection_from_index,
        compute_collection,
        evaluate_collections,
        evaluate_partial,
    )
    from .index import Entry, IndexReader, IndexWriter
    from .measures import RetrievalReport, evaluate_distances, evaluate_queries
    from .mesh import read_mesh
    from .nearest import Hit, search
    from .params import Params
    from .parts import partial_file, partial_search
    from .signature import Signature, compute_signature, signature_file

    __version__: str


def __getattr__(name: str) -> Any:
    """Import a public name from its module on first use, and ``__version__`` from metadata."""
    if name == "__version__":
        from importlib.metadata import PackageNotFoundError, version

        try:
            value = version("cfsig")
        except PackageNotFoundError:  # running from a source tree that was not installed
            value = "0.0.0"
    elif name in _EXPORTS:
        value = getattr(import_module(f".{_EXPORTS[name]}", __name__), name)
    else:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    """The public names, for completion."""
    return sorted({*globals(), *__all__})
