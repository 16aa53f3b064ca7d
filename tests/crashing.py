"""Worker functions for the batch tests: they kill their own process on files named crash*.off,
and the first raises an error that is not cfsig's on files named oops*.off.

It lives in a module of its own so that spawned worker processes can import it by name.
"""

import os

from cfsig.descriptors.parts import partial_file
from cfsig.descriptors.signature import signature_file


def signature_or_crash(path, params, solver):
    """`signature_file`, except on files whose names start with "crash" or "oops"."""
    if os.path.basename(path).startswith("crash"):
        os._exit(3)
    if os.path.basename(path).startswith("oops"):
        raise RuntimeError("not a cfsig error")
    return signature_file(path, params, solver)


def part_or_crash(path, params, solver):
    """`partial_file`, except that it kills its process on files named crash*.off."""
    if os.path.basename(path).startswith("crash"):
        os._exit(3)
    return partial_file(path, params)
