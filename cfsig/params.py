"""The parameters of a signature: one frozen dataclass, stored in every index."""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass, fields, replace

DESCRIPTORS = ("cf", "cfhks")
# The versions of each descriptor (docs/descriptors.md), and the one made by default: cfhks
# version 10 adds fine curvature cells for partial queries to version 9's vector, at a cost in
# disk and in partial queries over large indexes (docs/partial.md), so it is asked for by name.
VERSIONS = {"cf": (1,), "cfhks": (1, 2, 3, 4, 5, 6, 7, 8, 9, 10)}
DEFAULT_VERSIONS = {"cf": 1, "cfhks": 9}
REPAIR_MODES = ("auto", "off", "proxy")
# The length of the cfhks vector per version, `cfsig.descriptors.intrinsic.DESIGNS[version].length`
# (tests/test_cfhks.py checks that the two agree), here so that an index needs no SciPy.
CFHKS_LENGTHS = {
    1: 64 + 30 + 64 * 4,
    2: 30 + 64 * 8,
    3: 30 + 64 * 8 + 48 * 4,
    4: 30 + 64 * 8 + 48 * 4,
    5: 30 + 64 * 8 + 49 * 4,
    6: 30 + 64 * 8 + 49 * 4,
    7: 60 + 64 * 8 + 49 * 4,
    8: 45 + 64 * 8 + 49 * 4,
    9: 45 + 64 * 8 + 3 * 17 * 5,
    10: 45 + 64 * 8 + 3 * 17 * 5,
}
# The width of its curvature channel, the vector's last columns (`cfsig.descriptors.intrinsic.channel_columns`),
# for the versions that have one.
CFHKS_CURVATURE = {
    **dict.fromkeys((3, 4), 48 * 4),
    **dict.fromkeys((5, 6, 7, 8), 49 * 4),
    **dict.fromkeys((9, 10), 3 * 17 * 5),
}
# The fine curvature cells kept per row beside the vector, `cfsig.descriptors.cells.SLOTS`, by the versions
# that keep them (`cfsig.descriptors.intrinsic.Design.fine`).
CFHKS_CELLS = {10: 1024}
SOLVERS = (
    "auto",
    "cholmod",
    "eigen",
    "scipy",
)  # sparse solver backends (`cfsig.operators.conformal`)


@dataclass(frozen=True)
class Params:
    """Everything that decides a signature's values.

    Two signatures are comparable only when they were made with equal parameters, so an index
    stores these and a query recomputes with the index's own.

    Attributes
    ----------
    descriptor : str
        What the signature is (one of `DESCRIPTORS`; docs/descriptors.md): ``"cf"``, the
        paper's histogram of phi, to which every other attribute applies; ``"cfhks"``, the
        low Laplace-Beltrami spectrum and heat kernel signatures (version 1 also the quantiles
        of phi, version 3 and later also the curvature at four scales), whose constants are
        fixed per version in `cfsig.descriptors.intrinsic` and which uses only ``mollify`` and ``repair`` of
        the others.
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
        `cfsig.repair.stage.repair_mesh`): ``"auto"`` repairs it locally or replaces it by a proxy
        of its outer surface, ``"proxy"`` always takes the proxy, ``"off"`` solves each part
        as read. Clean closed manifolds are never changed.
    """

    descriptor: str = "cf"
    bins: int = 200
    low: float = -99.5
    high: float = 100.5
    samples_per_face: int = 5
    seed: int = 0
    normalize: bool = False
    mollify: float = 1e-5
    repair: str = "auto"
    version: int | None = None

    def __post_init__(self) -> None:
        if self.bins < 1 or self.samples_per_face < 0 or not self.low < self.high:
            raise ValueError(f"invalid parameters: {self}")
        if self.mollify < 0:
            raise ValueError("mollify must be >= 0")
        if self.repair not in REPAIR_MODES:
            raise ValueError(
                f"unknown repair mode {self.repair!r}; choose from {', '.join(REPAIR_MODES)}"
            )
        if self.descriptor not in DESCRIPTORS:
            raise ValueError(
                f"unknown descriptor {self.descriptor!r}; choose from {', '.join(DESCRIPTORS)}"
            )
        versions = VERSIONS[self.descriptor]
        if self.version is None:
            object.__setattr__(self, "version", DEFAULT_VERSIONS[self.descriptor])  # frozen
        elif self.version not in versions:
            raise ValueError(
                f"{self.descriptor} has no version {self.version}; this cfsig computes "
                f"{', '.join(map(str, versions))}"
            )

    def with_descriptor(self, descriptor: str) -> Params:
        """The same parameters for ``descriptor``, at its default version when it is another one.

        Parameters
        ----------
        descriptor : str
            One of `DESCRIPTORS`.

        Returns
        -------
        params : Params
        """
        if descriptor == self.descriptor:
            return self
        return replace(self, descriptor=descriptor, version=None)

    @property
    def edges(self) -> tuple[float, float]:
        """The histogram's outer edges (low, high) actually used."""
        return (0.0, 1.0) if self.normalize else (self.low, self.high)

    def to_json(self) -> str:
        """Serialise to a JSON object with sorted keys."""
        return json.dumps(asdict(self), sort_keys=True)

    @classmethod
    def from_json(cls, text: str) -> Params:
        """Parse what `to_json` wrote; unknown keys raise ``ValueError``.

        An index written before descriptors had names holds the paper's ``"cf"``, the default;
        one written before the repair stage existed was made without it, ``repair="off"``; one
        written before descriptors had versions holds version 1.
        """
        data = json.loads(text)
        data.setdefault("repair", "off")
        data.setdefault("version", 1)
        known = {f.name for f in fields(cls)}
        unknown = set(data) - known
        if unknown:
            raise ValueError(f"unknown parameters {sorted(unknown)}")
        return cls(**data)


def signature_length(params: Params) -> int:
    """Length of the signature vectors that ``params`` make.

    Parameters
    ----------
    params : Params
        Signature parameters.

    Returns
    -------
    length : int
        ``params.bins`` for ``cf``; the fixed length of the version of ``cfhks`` otherwise.
    """
    if params.descriptor == "cf":
        return params.bins
    assert params.version is not None  # resolved by Params.__post_init__
    return CFHKS_LENGTHS[params.version]


def curvature_slice(params: Params) -> slice | None:
    """Where the curvature channel lies in the signature vectors that ``params`` make.

    Parameters
    ----------
    params : Params
        Signature parameters.

    Returns
    -------
    columns : slice or None
        The last columns of the vector for ``cfhks`` version 3 and later; None for descriptors
        without that channel.
    """
    width = CFHKS_CURVATURE.get(params.version or 0) if params.descriptor == "cfhks" else None
    if width is None:
        return None
    length = signature_length(params)
    return slice(length - width, length)


def cell_slots(params: Params) -> int | None:
    """How many fine curvature cells the signatures that ``params`` make keep per row.

    Parameters
    ----------
    params : Params
        Signature parameters.

    Returns
    -------
    slots : int or None
        `cfsig.descriptors.cells.SLOTS` for ``cfhks`` version 10 and later; None for descriptors that keep
        none.
    """
    return CFHKS_CELLS.get(params.version or 0) if params.descriptor == "cfhks" else None
