"""The compiled core (issue 28; docs/install.md): built where a C compiler and the Python
headers exist, skipped (with setuptools' warning) where they do not, since the Python code
does the same work (mousedom/core.py says which runs).  Everything else is pyproject.toml."""

from setuptools import Extension, setup

# One file per idea (csrc/core.h says which); the header is listed so that a change to it
# rebuilds, and MANIFEST.in puts it in the sdist.
SOURCES = [f"csrc/{name}.c" for name in ("core", "decode", "knots", "onewindow", "steady")]
HEADERS = ["csrc/core.h"]
# -ffp-contract=off: no fused multiply-add, so every float is the one Python computes.
CFLAGS = ["-O2", "-Wall", "-Wextra", "-ffp-contract=off", "-fno-strict-aliasing"]

setup(
    ext_modules=[
        Extension(
            "mousedom._core", SOURCES, depends=HEADERS, extra_compile_args=CFLAGS, optional=True
        )
    ]
)
