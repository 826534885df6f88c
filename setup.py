"""The compiled core (issue 28; docs/install.md): built where a C compiler and the Python
headers exist, skipped (with setuptools' warning) where they do not, since the Python code
does the same work (mousedom/core.py says which runs).  Everything else is pyproject.toml."""

from setuptools import Extension, setup

# -ffp-contract=off: no fused multiply-add, so every float is the one Python computes.
CFLAGS = ["-O2", "-Wall", "-Wextra", "-ffp-contract=off", "-fno-strict-aliasing"]

setup(
    ext_modules=[
        Extension("mousedom._core", ["csrc/core.c"], extra_compile_args=CFLAGS, optional=True)
    ]
)
