"""Calibration and evaluation: CPI, mouse distance, mount positions, UMBmark.

Every module here is pure (arrays in, results out, no I/O) except ``calfile`` (the
calibration YAML) and ``reference`` / ``umbmark`` readers, which only parse files.  The
CLI layers are ``mousedom/commands/calibrate.py`` and ``mousedom/commands/umbmark.py``.

- ``counts``: counts -> metres in the mouse's own frame and in the body frame.
- ``runs``: cutting recordings into runs at idle gaps, and into time windows.
- ``cpi``: Bonarini et al. (2004) section 4.2, straight pushes of known length.
- ``distance``: Bonarini eqs. (18)-(19), a turn by a known angle.
- ``mounts``: Kim & Lee section IV (linearised), and an exact per-mouse fit.
- ``reference``: the REF.csv reader (body twist or wheel ticks, McGill model).
- ``umbmark``: Borenstein & Feng's UMBmark figures.
- ``synth``: exact synthetic rigs for the tests and the benchmark.
"""
