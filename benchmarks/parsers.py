"""How fast the numbers of an ASCII OFF file can be parsed: NumPy's readers and a compiled floor.

Reading is the largest stage of a mesh's signature after the solve (docs/performance.md). For
every mesh, the vertex block (floats) and the face block (integers) of the file, each parsed by:
``numpy.fromstring`` (cfsig's parser before), ``numpy.loadtxt`` (cfsig's vertex parser now) and,
when numba is installed (the ``bench`` extra), a compiled loop that takes the exact fast path of
Clinger's algorithm (mantissa below 2**53, power of ten up to 22: one correctly rounded
multiplication or division) and gives up on anything else. The compiled parser is not part of
cfsig (docs/performance.md says why): it measures what compiled code would save. Every parser's
numbers are checked to equal ``numpy.fromstring``'s bit for bit. CPU seconds, median of three
runs per block, then the median over the meshes.

    python benchmarks/parsers.py [--every K] [--json out.json]
"""

from __future__ import annotations

import io
from pathlib import Path

import common
import numpy as np

_POWERS = 10.0 ** np.arange(23)
PARSERS = {"floats": ("fromstring", "loadtxt", "compiled"), "ints": ("fromstring", "compiled")}


def _compiled_parser():
    """The numba parser, or None without numba."""
    try:
        import numba
    except ImportError:
        return None

    @numba.njit(cache=True)
    def parse(buf, out, powers):
        """Parse whitespace-separated decimals into ``out``; their count, or -1 to give up."""
        n, i, k = len(buf), 0, 0
        while i < n:
            if buf[i] <= 32:
                i += 1
                continue
            negative = buf[i] == 45
            if buf[i] == 45 or buf[i] == 43:
                i += 1
            mantissa, digits, fraction, dot = 0, 0, 0, False
            while i < n and ((48 <= buf[i] <= 57) or (buf[i] == 46 and not dot)):
                if buf[i] == 46:
                    dot = True
                else:
                    mantissa, digits = mantissa * 10 + (buf[i] - 48), digits + 1
                    fraction += dot
                    if digits > 15:
                        return -1
                i += 1
            exponent = 0
            if i < n and (buf[i] == 101 or buf[i] == 69):
                i += 1
                sign = -1 if i < n and buf[i] == 45 else 1
                if i < n and (buf[i] == 45 or buf[i] == 43):
                    i += 1
                start = i
                while i < n and 48 <= buf[i] <= 57 and i - start < 4:
                    exponent = exponent * 10 + (buf[i] - 48)
                    i += 1
                if i == start:
                    return -1
                exponent *= sign
            exponent -= fraction
            if digits == 0 or (i < n and buf[i] > 32) or abs(exponent) > 22 or k == len(out):
                return -1
            value = mantissa / powers[-exponent] if exponent < 0 else mantissa * powers[exponent]
            out[k] = -value if negative else value
            k += 1
        return k

    return parse


def _blocks(data: bytes) -> tuple[bytes, bytes]:
    """The vertex and face blocks of a plain OFF file (one vertex per line)."""
    lines = np.flatnonzero(np.frombuffer(data, dtype=np.uint8) == ord("\n"))
    n_v = int(data[lines[0] + 1 : lines[1]].split()[0])
    return data[lines[1] + 1 : lines[n_v + 1] + 1], data[lines[n_v + 1] + 1 :]


def _cpu(func) -> tuple[object, float]:
    """A function's result and its median CPU seconds over three runs."""
    runs = [common.timed(func) for _ in range(3)]
    return runs[0][0], common.median([cpu for _, cpu, _ in runs])


def measure(path: Path, compiled) -> dict:
    """CPU seconds of each parser on one file's blocks, each checked against fromstring."""
    vertex_block, face_block = _blocks(path.read_bytes())
    row = {"mesh": f"{path.parent.name}/{path.name}"}
    floats, row["fromstring floats"] = _cpu(lambda: np.fromstring(vertex_block, sep=" "))
    ints, row["fromstring ints"] = _cpu(lambda: np.fromstring(face_block, np.int64, sep=" "))
    rows, row["loadtxt floats"] = _cpu(
        lambda: np.loadtxt(io.BytesIO(vertex_block), comments=None, ndmin=2)
    )
    if not np.array_equal(rows.ravel(), floats):
        raise SystemExit(f"{path}: loadtxt differs from fromstring")
    row["vertices"] = len(rows)
    if compiled is not None:
        for kind, block, expected in (("floats", vertex_block, floats), ("ints", face_block, ints)):
            buf, out = np.frombuffer(block, dtype=np.uint8), np.empty(len(expected))
            count, row[f"compiled {kind}"] = _cpu(lambda b=buf, o=out: compiled(b, o, _POWERS))
            if count != len(expected) or not np.array_equal(out, expected):
                raise SystemExit(f"{path}: the compiled parser differs from fromstring")
    return row


def main() -> None:
    """Parse the options, time every parser on every mesh, print the table."""
    args = common.arguments(__doc__.splitlines()[0]).parse_args()
    files, compiled = common.meshes(args), _compiled_parser()
    measure(files[0], compiled)  # compile (or load the cached machine code) before timing
    rows = [measure(path, compiled) for path in files]
    med = common.median
    body = []
    for kind, names in PARSERS.items():
        for name in names:
            key = f"{name} {kind}"
            if key in rows[0]:
                ratio = med([r[f"fromstring {kind}"] / r[key] for r in rows])
                body.append([f"{kind[:-1]} block", name, med([r[key] for r in rows]), ratio])
    vertices = int(med([r["vertices"] for r in rows]))
    print(f"{len(files)} meshes from {args.data} (median {vertices} vertices), one thread;")
    print("every parser's numbers equal numpy.fromstring's bit for bit\n")
    head = ["block", "parser", "CPU s (median)", "speed-up over fromstring (median)"]
    print(common.table(head, body))
    common.save_rows(args.json, rows)


if __name__ == "__main__":
    main()
