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
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from cfsig.errors import CfsigError
from cfsig.mesh import parse_mesh
from cfsig.params import Params
from cfsig.signature import compute_signature, signature_file
from tests.helpers import off_text

BUDGET = settings(
    max_examples=40,
    deadline=None,
    database=None,
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture],
)
SUFFIXES = (".off", ".obj", ".ply", ".stl")
# Coordinates from a small grid, so that soups repeat vertices, faces and edges (the cases the
# repairs handle), with the occasional huge, tiny or non-finite value.
_COORDINATE = st.one_of(
    st.integers(-3, 3).map(float),
    st.floats(-10, 10, allow_nan=False),
    st.sampled_from([0.0, 1e-12, 1e12, float("nan"), float("inf")]),
)


@st.composite
def soups(draw: st.DrawFn) -> tuple[np.ndarray, np.ndarray]:
    """A triangle soup: a few vertices and faces whose indices may repeat or be out of range."""
    n = draw(st.integers(1, 10))
    vertices = np.array(draw(st.lists(st.tuples(*[_COORDINATE] * 3), min_size=n, max_size=n)))
    index = st.integers(-1, n)  # one past each end: out of range
    faces = np.array(draw(st.lists(st.tuples(index, index, index), min_size=1, max_size=16)))
    return vertices.reshape(n, 3), faces.reshape(-1, 3)


def _finite_or_typed(compute) -> None:
    """Run ``compute()``: it returns a signature with a finite vector, or raises CfsigError."""
    try:
        sig = compute()
    except CfsigError:
        return
    assert np.isfinite(sig.vector).all() and np.isfinite(sig.phi).all()


@BUDGET
@given(data=st.binary(max_size=600), suffix=st.sampled_from(SUFFIXES))
def test_random_bytes_read_as_a_mesh_or_a_typed_error(data, suffix):
    try:
        mesh = parse_mesh(data, f"random{suffix}")
    except CfsigError:
        return
    assert np.isfinite(mesh.vertices).all() and len(mesh.faces)


@BUDGET
@given(data=st.binary(max_size=600), suffix=st.sampled_from(SUFFIXES))
def test_random_bytes_give_a_signature_or_a_typed_error(tmp_path, data, suffix):
    path = tmp_path / f"random{suffix}"
    path.write_bytes(data)
    _finite_or_typed(lambda: signature_file(path, Params()))


@BUDGET
@given(soup=soups(), descriptor=st.sampled_from(["cf", "cfhks"]))
def test_random_soup_off_gives_a_signature_or_a_typed_error(soup, descriptor):
    vertices, faces = soup

    def compute():
        mesh = parse_mesh(off_text(vertices, faces).encode(), "soup.off")
        return compute_signature(mesh, Params(descriptor=descriptor))

    _finite_or_typed(compute)


@pytest.mark.parametrize("suffix", [".obj", ".ply", ".stl"])
@BUDGET
@given(soup=soups())
def test_random_soup_through_trimesh_formats(suffix, soup):
    vertices, faces = soup
    if not np.isfinite(vertices).all() or faces.min() < 0 or faces.max() >= len(vertices):
        return  # trimesh writes only valid arrays; the OFF test covers the others
    buffer = io.BytesIO()
    trimesh.Trimesh(vertices, faces, process=False).export(buffer, file_type=suffix[1:])

    def compute():
        return compute_signature(parse_mesh(buffer.getvalue(), f"soup{suffix}"), Params())

    _finite_or_typed(compute)
