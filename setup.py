"""The compiled core (issue 28; docs/install.md): built where a C compiler and the Python
headers exist, skipped (with setuptools' warning) where they do not, since the Python code
does the same work (mousedom/core.py says which runs).  Everything else is pyproject.toml."""

from setuptools import Extension, setup

# One file per idea (csrc/core.h says which); the header is listed so that a change to it
# rebuilds, and MANIFEST.in puts it in the sdist.
SOURCES = [
    f"csrc/{name}.c"
    for name in ("core", "decode", "knots", "onewindow", "steady", "poseline", "evemu")
]
HEADERS = ["csrc/core.h"]
# -ffp-contract=off: no fused multiply-add, so every float is the one Python computes.
# -fno-builtin-sin/cos: libm's sin and cos, as math.sin and math.cos call them (gcc would
# otherwise merge a sin and a cos of one angle into one sincos call).
FLOATS = ["-ffp-contract=off", "-fno-builtin-sin", "-fno-builtin-cos"]
CFLAGS = ["-O2", "-Wall", "-Wextra", *FLOATS, "-fno-strict-aliasing"]

setup(
    ext_modules=[
        Extension(
            "mousedom._core", SOURCES, depends=HEADERS, extra_compile_args=CFLAGS, optional=True
        )
    ]
)
