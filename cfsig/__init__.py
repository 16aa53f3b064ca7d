"""cfsig: pose-invariant 3D shape retrieval with conformal-factor signatures.

The names below are the library's public API, so that ``import cfsig`` is enough::

    with cfsig.IndexReader("shrec07-index") as index:
        query = cfsig.signature_file("ant/81.off", index.params).vector
        hits = cfsig.query(index, query[None], k=20)[0]

Each is imported from its module on first use (PEP 562), so that importing the package loads
neither SciPy nor matplotlib.
"""

from __future__ import annotations

from importlib import import_module
from typing import TYPE_CHECKING, Any

# Public name -> the module that defines it.
_EXPORTS = {
    "Params": "params",
    "layout": "descriptors",
    "Signature": "descriptors.signature",
    "signature_file": "descriptors.signature",
    "compute_signature": "descriptors.signature",
    "read_mesh": "files.mesh",
    "Entry": "index.store",
    "IndexReader": "index.store",
    "IndexWriter": "index.store",
    "index_info": "index.store",
    "index_meshes": "batch",
    "compute_many": "batch",
    "Hit": "search.nearest",
    "query": "search.nearest",
    "query_names": "search.nearest",
    "nearest_all": "search.duplicates",
    "duplicate_groups": "search.duplicates",
    "partial_file": "descriptors.parts",
    "query_part": "search.partial",
    "evaluate_partial": "evaluation.collections",
    "evaluate_queries": "evaluation.measures",
    "Collection": "evaluation.collections",
    "compute_collection": "evaluation.collections",
    "collection_from_index": "evaluation.collections",
    "evaluate_collections": "evaluation.collections",
    "evaluate_distances": "evaluation.measures",
    "RetrievalReport": "evaluation.measures",
    "read_cla": "files.cla",
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
    "duplicate_groups",
    "evaluate_collections",
    "evaluate_distances",
    "evaluate_partial",
    "evaluate_queries",
    "index_info",
    "index_meshes",
    "layout",
    "nearest_all",
    "read_cla",
    "partial_file",
    "query_part",
    "read_mesh",
    "query",
    "query_names",
    "signature_file",
]  # the keys of _EXPORTS and __version__ (tests/test_api.py checks)

if TYPE_CHECKING:
    from cfsig.batch import compute_many, index_meshes
    from cfsig.descriptors import layout
    from cfsig.descriptors.parts import partial_file
    from cfsig.descriptors.signature import Signature, compute_signature, signature_file
    from cfsig.errors import CfsigError
    from cfsig.evaluation.collections import (
        Collection,
        collection_from_index,
        compute_collection,
        evaluate_collections,
        evaluate_partial,
    )
    from cfsig.evaluation.measures import RetrievalReport, evaluate_distances, evaluate_queries
    from cfsig.files.cla import read_cla
    from cfsig.files.mesh import read_mesh
    from cfsig.index.store import Entry, IndexReader, IndexWriter, index_info
    from cfsig.params import Params
    from cfsig.search.duplicates import duplicate_groups, nearest_all
    from cfsig.search.nearest import Hit, query, query_names
    from cfsig.search.partial import query_part

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
        value = getattr(import_module(f"cfsig.{_EXPORTS[name]}"), name)
    else:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    """The public names, for completion."""
    return sorted({*globals(), *__all__})
