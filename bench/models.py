"""Throughput of the core maths: models.solve per model, the integrators, compose.

Prints windows per second (median of 5 runs) for one million windows of 3 mice (2 for
bonarini) and the ratio to a baseline measured in the same run: the bare matrix product
d @ B^T that any linear model must at least do.  No assertions: figures only.

    python bench/models.py [--windows N]
"""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

# One BLAS thread, set before numpy loads its BLAS: the baseline's matrix product would
# otherwise run on every core while the models (mostly elementwise numpy) run on one, and
# the ratio would compare two machines (a multithreaded baseline once printed 2.69 M
# windows/s where one thread gives 183 M/s).  Printed with the figures.
BLAS_ENV = ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")
for _name in BLAS_ENV:
    os.environ.setdefault(_name, "1")

import numpy as np  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from timing import median_time  # noqa: E402  (bench/timing.py)

from mousedom.fusion import integrate, models  # noqa: E402
from mousedom.fusion.geometry import design_matrix  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--windows", type=int, default=1_000_000)
    n = ap.parse_args().windows
    rng = np.random.default_rng(0)
    pos3 = np.array([[0.1, 0.12], [0.1, -0.12], [-0.15, 0.0]])
    pos2 = pos3[:2]
    q = rng.normal(size=(n, 3)) * [2e-3, 2e-4, 2e-3]
    d3 = (q @ design_matrix(pos3).T).reshape(n, 3, 2) + rng.normal(scale=3e-5, size=(n, 3, 2))
    d2 = np.ascontiguousarray(d3[:, :2])
    mask = rng.random((n, 3)) > 0.05  # 5 % of mouse-windows dropped out
    sigma = 3e-5

    a = design_matrix(pos3)
    b = np.linalg.pinv(a)
    flat = d3.reshape(n, 6)
    base = median_time(lambda: flat @ b.T)

    cases = [
        ("baseline: d @ B^T (3 mice)", lambda: flat @ b.T),
        ("lsq, 3 mice", lambda: models.solve("lsq", d3, pos3, sigma)),
        ("lsq, 3 mice, 5 % dropouts", lambda: models.solve("lsq", d3, pos3, sigma, mask)),
        ("diff-drive, 3 mice", lambda: models.solve("diff-drive", d3, pos3, sigma)),
        ("bonarini, 2 mice (+ FD cov)", lambda: models.solve("bonarini", d2, pos2, sigma)),
        *[(f"body_step {m}", lambda m=m: integrate.body_step(q, m)) for m in integrate.INTEGRATORS],
        ("step_jacobian", lambda: integrate.step_jacobian(q)),
        ("compose", lambda: integrate.compose(np.zeros(3), q)),
    ]
    threads = ", ".join(f"{k}={os.environ[k]}" for k in BLAS_ENV)
    print(f"{n} windows; median of 5 runs; ratio = time / baseline time; BLAS: {threads}")
    print(f"{'case':34s} {'M windows/s':>12s} {'x baseline':>11s}")
    for name, fn in cases:
        t = base if name.startswith("baseline") else median_time(fn)
        print(f"{name:34s} {n / t / 1e6:12.2f} {t / base:11.1f}")


if __name__ == "__main__":
    main()
