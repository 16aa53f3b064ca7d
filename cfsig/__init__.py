"""cfsig: pose-invariant 3D shape retrieval with conformal-factor signatures."""

from importlib.metadata import PackageNotFoundError, version

try:
    __version__ = version("cfsig")
except PackageNotFoundError:  # running from a source tree that was not installed
    __version__ = "0.0.0"
