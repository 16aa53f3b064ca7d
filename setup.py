"""The compiled fine-cell kernel (`cfsig/search/cells_compiled.pyx`); everything else is in
pyproject.toml."""

import platform

from setuptools import Extension, setup

# -O3 lets gcc vectorise the kernel's 16-bit sums; no fused multiply-adds, so that its float64
# scores are NumPy's to the last bit; x86-64-v2 (SSE4.1, every x86-64 processor since 2009)
# has the unsigned 16-bit minimum the sums take.
ARGS = ["-O3", "-ffp-contract=off"]
if platform.machine().lower() in ("x86_64", "amd64"):
    ARGS.append("-march=x86-64-v2")

setup(
    ext_modules=[
        Extension(
            "cfsig.search.cells_compiled",
            ["cfsig/search/cells_compiled.pyx"],
            extra_compile_args=ARGS,
            optional=True,  # without a C compiler, cfsig installs and NumPy's kernel serves
        )
    ]
)
