"""The package's public API: what the README uses, importable from ``cfsig`` alone, lazily."""

import subprocess
import sys

import pytest

import cfsig
from cfsig.descriptors import layout


def test_every_public_name_resolves_to_its_module():
    assert sorted(cfsig.__all__) == sorted([*cfsig._EXPORTS, "__version__"])
    for name, module in cfsig._EXPORTS.items():
        value = getattr(cfsig, name)
        assert value.__module__ == f"cfsig.{module}", name
    with pytest.raises(AttributeError, match="no attribute 'nothing'"):
        cfsig.nothing  # noqa: B018


def _loaded_after(code: str) -> set[str]:
    """The top-level modules loaded in a fresh interpreter after running ``code``."""
    script = (
        f"import sys\n{code}\nprint(' '.join(sorted({{m.split('.')[0] for m in sys.modules}})))"
    )
    out = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, check=True)
    return set(out.stdout.split())


def test_import_cfsig_and_the_cli_load_neither_scipy_nor_matplotlib():
    for code in ("import cfsig", "import cfsig.cli"):  # `cfsig --help` starts without NumPy
        assert not _loaded_after(code) & {"numpy", "h5py", "scipy", "matplotlib"}, code
    assert not _loaded_after("import cfsig.index.store") & {"scipy", "matplotlib"}
    # the process that hands files to the workers and writes the index
    assert not _loaded_after("import cfsig.batch, cfsig.files.folders") & {
        "scipy",
        "h5py",
        "matplotlib",
    }
    assert "scipy" in _loaded_after("import cfsig\ncfsig.signature_file")  # loaded when used


def test_readme_example_runs_from_the_package(tmp_path):
    from tests.helpers import icosphere, write_off

    path = write_off(tmp_path / "ball" / "1.off", *icosphere(2))
    sig = cfsig.signature_file(path, cfsig.Params(descriptor="cf"))
    with cfsig.IndexWriter(
        tmp_path / "i.h5", cfsig.Params(descriptor="cf"), layout(cfsig.Params(descriptor="cf"))
    ) as writer:
        writer.add(cfsig.Entry("ball/1.off", "ball", str(path)), sig)
    with cfsig.IndexReader(tmp_path / "i.h5") as index:
        hits = cfsig.query(index, sig.vector[None], k=1)[0]
    assert hits[0].entry.name == "ball/1.off" and hits[0].distance == 0
