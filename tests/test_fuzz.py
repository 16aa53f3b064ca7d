"""Property-based tests: whatever the bytes or the triangles, a finite signature or a typed error.

Random triangle soups (as OFF, OBJ, PLY and STL files) and random bytes go through the readers
and the whole pipeline. The budget is bounded (a fixed number of examples, no deadline per
example, no example database) so that the module runs in well under a minute.
"""

from __future__ import annotations

import io

import numpy as np
import pytest
import trimesh
from hypothesis import HealthCheck, event, given, settings
from hypothesis import strategies as st

from cfsig.descriptors.signature import compute_signature, signature_file
from cfsig.errors import CfsigError
from cfsig.files.mesh import parse_mesh
from cfsig.params import Params
from tests.helpers import off_text

# No input may make NumPy warn: numerical trouble is a repair or a typed error.
pytestmark = pytest.mark.filterwarnings("error::RuntimeWarning")
BUDGET = settings(
    max_examples=60,
    derandomize=True,  # the same examples in every run: CI is not flaky
    deadline=None,
    database=None,
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture],
)
SUFFIXES = (".off", ".obj", ".ply", ".stl")
# Random bytes, alone or after the start of a plausible OFF file.
_BYTES = st.one_of(
    st.binary(max_size=600),
    st.binary(max_size=200).map(lambda tail: b"OFF\n3 1 0\n0 0 0\n1 0 0\n" + tail),
)
# Coordinates mostly from a small grid, so that soups repeat vertices, faces and edges (the
# cases the repairs handle), or anywhere in a box.
_COORDINATE = st.one_of(st.integers(-2, 2).map(float), st.floats(-2, 2, allow_nan=False))
# What may go wrong with a soup besides its shape: nothing, mostly.
_FAULTS = st.sampled_from([None] * 6 + ["nan", "inf", "huge", "tiny", "index -1", "index n"])


@st.composite
def soups(draw: st.DrawFn) -> tuple[np.ndarray, np.ndarray]:
    """A triangle soup: 3 to 12 vertices, 1 to 24 faces of any of them, and maybe one fault."""
    n = draw(st.integers(3, 12))
    vertices = np.array(draw(st.lists(st.tuples(*[_COORDINATE] * 3), min_size=n, max_size=n)))
    index = st.integers(0, n - 1)
    faces = np.array(draw(st.lists(st.tuples(index, index, index), min_size=1, max_size=24)))
    fault = draw(_FAULTS)
    if fault in ("nan", "inf", "huge", "tiny"):
        value = {"nan": np.nan, "inf": np.inf, "huge": 1e300, "tiny": 1e-300}[fault]
        vertices[draw(st.integers(0, n - 1)), draw(st.integers(0, 2))] = value
    elif fault is not None:
        faces[draw(st.integers(0, len(faces) - 1)), 0] = -1 if fault == "index -1" else n
    return vertices, faces


def _finite_or_typed(compute, phi: bool = True) -> None:
    """Run ``compute()``: it returns a signature with a finite vector (and a finite phi when its
    descriptor solves phi), or raises CfsigError."""
    try:
        sig = compute()
    except CfsigError as exc:
        event(f"typed error: {type(exc).__name__}")
        return
    event("signature")
    assert np.isfinite(sig.vector).all()
    assert (sig.phi is not None) == phi
    assert not phi or np.isfinite(sig.phi).all()


@BUDGET
@given(data=_BYTES, suffix=st.sampled_from(SUFFIXES))
def test_random_bytes_read_as_a_mesh_or_a_typed_error(data, suffix):
    try:
        mesh = parse_mesh(data, f"random{suffix}")
    except CfsigError:
        return
    assert np.isfinite(mesh.vertices).all() and len(mesh.faces)


@BUDGET
@given(data=_BYTES, suffix=st.sampled_from(SUFFIXES))
def test_random_bytes_give_a_signature_or_a_typed_error(tmp_path, data, suffix):
    path = tmp_path / f"random{suffix}"
    path.write_bytes(data)
    _finite_or_typed(lambda: signature_file(path, Params(descriptor="cf")))


@BUDGET
@given(soup=soups(), descriptor=st.sampled_from(["cf", "intrinsic"]))
def test_random_soup_off_gives_a_signature_or_a_typed_error(soup, descriptor):
    vertices, faces = soup

    def compute():
        mesh = parse_mesh(off_text(vertices, faces).encode(), "soup.off")
        return compute_signature(mesh, Params(descriptor=descriptor))

    _finite_or_typed(compute, phi=descriptor == "cf")


@pytest.mark.parametrize("suffix", [".obj", ".ply", ".stl"])
@BUDGET
@given(soup=soups())
def test_random_soup_through_trimesh_formats(suffix, soup):
    vertices, faces = soup
    if not np.isfinite(vertices).all() or faces.min() < 0 or faces.max() >= len(vertices):
        return  # trimesh writes only valid arrays; the OFF test covers the faults
    buffer = io.BytesIO()
    with np.errstate(over="ignore"):  # writing huge coordinates as float32 (the test's side)
        trimesh.Trimesh(vertices, faces, process=False).export(buffer, file_type=suffix[1:])

    def compute():
        return compute_signature(
            parse_mesh(buffer.getvalue(), f"soup{suffix}"), Params(descriptor="cf")
        )

    _finite_or_typed(compute)
