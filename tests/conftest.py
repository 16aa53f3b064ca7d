"""Fixtures shared by the tests; the functions they use are in tests/helpers.py."""

from __future__ import annotations

from pathlib import Path

import pytest

from tests import helpers

SHREC = Path(__file__).resolve().parents[2] / "shared" / "data" / "shrec07"


@pytest.fixture
def sphere():
    """An icosphere with 642 vertices."""
    return helpers.icosphere(3)


@pytest.fixture(scope="session")
def body():
    """A body with three limbs, in its rest pose (`cfsig.files.demo.limbed_body`)."""
    from cfsig.files.demo import limbed_body

    return limbed_body(3, 0)


@pytest.fixture
def shrec07():
    """The SHREC 2007 folder, or a skip when it is not unpacked beside the project."""
    if not (SHREC / "ant" / "81.off").exists():
        pytest.skip(f"SHREC07 not unpacked at {SHREC} (run ../shared/data/unpack-shrec07)")
    return SHREC


@pytest.fixture
def build_index():
    """`helpers.build_index`: ``build_index(path, n, params)`` writes an index of ``n`` random
    signatures and returns their vectors."""
    return helpers.build_index


@pytest.fixture(params=["numpy", "faiss"])
def kernel(request, monkeypatch):
    """Force one L1 kernel on every scan (faiss: skipped when it is not installed)."""
    import cfsig.search.l1

    if request.param == "faiss":
        pytest.importorskip("faiss")
        monkeypatch.setattr(cfsig.search.l1, "FAST_MIN_WORK", 0)
    else:
        monkeypatch.setattr(cfsig.search.l1, "fast_kernel", lambda: None)
    return request.param
