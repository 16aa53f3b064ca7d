"""Typed exceptions raised by the library; the CLI turns them into one-line messages."""


class CfsigError(Exception):
    """Base class of every error cfsig raises on purpose."""


class MeshError(CfsigError):
    """A mesh file cannot be read, or its contents cannot give a signature."""


class SolverError(CfsigError):
    """The linear system for the conformal factor could not be solved."""


class IndexFileError(CfsigError):
    """An index file is missing, corrupt, foreign, busy or incompatible."""


class MissingDependencyError(CfsigError):
    """An optional dependency needed for the requested feature is not installed."""


class ClusterError(CfsigError):
    """A Dask cluster cannot be reached."""


class StageLimitError(MeshError):
    """An isolated stage (`cfsig.isolate`) ran out of time or memory, crashed or failed."""


class PartialError(CfsigError):
    """A partial query was asked of an index whose descriptor has no channel for it."""


class UnknownNameError(CfsigError):
    """A name asked of an index is not one of its entries."""


class EmptyPathError(CfsigError):
    """A folder given to index holds no mesh file."""
