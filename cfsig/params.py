"""The parameters of a signature, one frozen dataclass stored in every index, and the layout of
the rows an index keeps for them."""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass, fields

REPAIR_MODES = ("auto", "off", "proxy")
SOLVERS = ("auto", "cholmod", "eigen", "scipy")  # sparse solver backends (`cfsig.operators`)


@dataclass(frozen=True)
class Params:
    """Everything that decides a signature's values.

    Two signatures are comparable only when they were made with equal parameters, so an index
    stores these and a query recomputes with the index's own.

    Attributes
    ----------
    descriptor : str
        What the signature is, a name of `cfsig.descriptors.NAMES`: ``"intrinsic"``, the
        default (the spectrum, heat kernel signatures and curvature at scales); ``"cf"``, the
        paper's histogram of phi; ``"sh"``, ``"gps"``, ``"lf"`` and ``"amrg"``, the spherical
        harmonic descriptor, the global point signature, the light field descriptor and the
        augmented multiresolution Reeb graph the paper compares with; ``"rigid"``, for rigid
        objects: ``intrinsic``'s channels, panoramic projections and ``lf``'s silhouettes weighed
        together. ``bins`` to ``normalize`` apply to ``cf`` only, ``seed`` also to ``sh``, ``gps``
        and ``rigid``.
    bins : int
        Number of histogram bins (paper section 2.3: 200).
    low, high : float
        Outer edges of the histogram. The default bins are centred on the integers -99..100,
        the paper's "200 uniform bins spanning [-99, 100]" read as Matlab's ``hist(x, -99:100)``.
        Ignored when ``normalize`` is set, which uses [0, 1].
    samples_per_face : int
        Random surface samples per face (paper: 5|F|).
    seed : int
        Seed of the sampling, so one mesh always gives the same signature bit for bit.
    normalize : bool
        Normalise phi to [0, 1] before the histogram (the variant of paper section 3.1).
    mollify : float
        Intrinsic mollification of degenerate triangles, relative to the mean edge length
        (Sharp and Crane 2020); 0 disables it.
    repair : str
        What to do with a mesh that is not one closed manifold (one of `REPAIR_MODES`;
        `cfsig.repair.stage.repair_mesh`): ``"auto"`` repairs it locally or replaces it by a
        proxy of its outer surface, ``"proxy"`` always takes the proxy, ``"off"`` solves each
        part as read. A closed manifold is left as it is, but for reversed faces, which all
        modes but ``"off"`` turn.
    partial_cells : bool
        ``intrinsic`` only: keep each mesh's fine curvature cells beside its vector, so that
        partial queries of the index rank by them (`cfsig.descriptors.cells`).
    """

    descriptor: str = "intrinsic"
    bins: int = 200
    low: float = -99.5
    high: float = 100.5
    samples_per_face: int = 5
    seed: int = 0
    normalize: bool = False
    mollify: float = 1e-5
    repair: str = "auto"
    partial_cells: bool = False

    def __post_init__(self) -> None:
        if self.bins < 1 or self.samples_per_face < 0 or not self.low < self.high:
            raise ValueError(f"invalid parameters: {self}")
        if self.mollify < 0:
            raise ValueError("mollify must be >= 0")
        if self.repair not in REPAIR_MODES:
            raise ValueError(
                f"unknown repair mode {self.repair!r}; choose from {', '.join(REPAIR_MODES)}"
            )
        if self.partial_cells and self.descriptor != "intrinsic":
            raise ValueError("partial cells are kept by the intrinsic descriptor only")

    @property
    def edges(self) -> tuple[float, float]:
        """The histogram's outer edges (low, high) actually used."""
        return (0.0, 1.0) if self.normalize else (self.low, self.high)

    def to_json(self) -> str:
        """Serialise to a JSON object with sorted keys."""
        return json.dumps(asdict(self), sort_keys=True)

    @classmethod
    def from_json(cls, text: str) -> Params:
        """Parse what `to_json` wrote.

        Raises
        ------
        ValueError
            Unknown or invalid keys, as the parameters of a removed descriptor hold.
        """
        data = json.loads(text)
        unknown = set(data) - {f.name for f in fields(cls)}
        if unknown:
            raise ValueError(f"unknown parameters {sorted(unknown)}")
        return cls(**data)


@dataclass(frozen=True)
class Layout:
    """What an index keeps per row for a descriptor, which the descriptor declares
    (`cfsig.descriptors.layout`) and the index stores without knowing the descriptor.

    Attributes
    ----------
    length : int
        Entries of the signature vector.
    groups : tuple of (str, int, int)
        Named column groups ``(name, start, stop)`` of the vector that the index also stores on
        their own, for searches that read only them (``"curvature"``: partial queries).
    cells : int
        Fine curvature cells kept per row beside the vector (`Params.partial_cells`); 0: none.
    """

    length: int
    groups: tuple[tuple[str, int, int], ...] = ()
    cells: int = 0

    def group(self, name: str) -> slice | None:
        """The columns of the group ``name``, or None when the layout has no such group."""
        for group, start, stop in self.groups:
            if group == name:
                return slice(start, stop)
        return None

    def to_json(self) -> str:
        """Serialise to a JSON object with sorted keys."""
        return json.dumps(asdict(self), sort_keys=True)

    @classmethod
    def from_json(cls, text: str) -> Layout:
        """Parse what `to_json` wrote."""
        data = json.loads(text)
        groups = tuple((str(n), int(a), int(b)) for n, a, b in data.pop("groups"))
        return cls(groups=groups, **data)
