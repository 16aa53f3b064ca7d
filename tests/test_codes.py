"""8-bit codes: exact sums, bounds that hold, and searches equal to the float32 scan."""

import numpy as np
import pytest

import cfsig.nearest
from cfsig.codes import code_width, encode, grid, sad, union_grid
from cfsig.index import Entry, IndexReader, IndexWriter
from cfsig.nearest import nearest
from cfsig.params import Params
from cfsig.signature import Signature


@pytest.mark.parametrize("width", [8, 200, 1032, 2056])  # more than one group of words
def test_sad_is_exact(width):
    rng = np.random.default_rng(width)
    codes = rng.integers(0, 256, (50, width), dtype=np.uint8)
    query = rng.integers(0, 256, width, dtype=np.uint8)
    want = np.abs(codes.astype(np.int64) - query).sum(axis=1)
    assert np.array_equal(sad(codes, query), want)


def test_bounds_hold_even_outside_the_grid():
    rng = np.random.default_rng(1)
    rows = rng.random((300, 350)).astype(np.float32) * rng.random(350).astype(np.float32)
    offset, step = grid(rows[:100])  # rows 100... may fall outside the grid: clipped
    queries = rng.random((5, 350)).astype(np.float32) * 1.5
    codes, errors = encode(rows, offset, step)
    query_codes, query_errors = encode(queries, offset, step)
    assert codes.shape == (300, code_width(350)) and not codes[:, 350:].any()
    for q, qc, qe in zip(queries, query_codes, query_errors, strict=True):
        exact = np.abs(rows.astype(np.float64) - q).sum(axis=1)
        approx = sad(codes, qc) * step
        assert (np.abs(exact - approx) <= errors + qe).all()
    wide = union_grid([(offset, step), grid(queries)])
    assert (wide[0] <= offset).all() and wide[1] >= step


def test_search_by_codes_equals_the_float32_scan(tmp_path, monkeypatch):
    rng = np.random.default_rng(2)
    index, vectors = tmp_path / "i", {}
    with IndexWriter(index, Params(bins=64), merge=False) as w:
        for part in range(3):  # segments with different grids, and rows superseded
            rows = rng.random((90, 64)).astype(np.float32) * (part + 1)
            rows[5] = rows[7]  # ties, broken by row number
            if part == 1:
                rows[3] = np.nan  # ranks last, as in the float32 scan
            for i, row in enumerate(rows):
                name = f"m/{(part * 90 + i) % 200}.off"  # the third part replaces some names
                w.add(
                    Entry(name, "m", name),
                    Signature(row, np.zeros(1), 1, 1, 1, 0.0, (), "clean", 0.0, ""),
                )
                vectors[name] = row
            w.commit()
    queries = rng.random((3, 64)).astype(np.float32) * 2
    with IndexReader(index) as r:
        assert len(r) == 200 and all(len(v.dead) for v in r.segments[:1])
        for k in (1, 10, 200):
            by_codes = nearest(r, queries, k)
            monkeypatch.setattr(cfsig.nearest, "CODES_MAX_QUERIES", 0)
            by_rows = nearest(r, queries, k)
            monkeypatch.undo()
            assert np.array_equal(by_codes[0], by_rows[0])
            assert np.allclose(by_codes[1], by_rows[1], rtol=1e-6, equal_nan=True)
