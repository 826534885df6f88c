"""Calibration and evaluation: CPI, mouse distance, mount positions, UMBmark.

The algorithms are pure (arrays in, results out, no I/O); ``calfile``, ``inputs`` and
``live`` do the file and device I/O, and ``reference.read_reference`` reads one file.  The
CLI layers are ``mousedom/commands/calibrate.py`` and ``mousedom/commands/umbmark.py``.

- ``counts``: counts -> metres in the mouse's own frame and in the body frame.
- ``runs``: cutting recordings into runs at idle gaps, and into time windows.
- ``cpi``: Bonarini et al. (2004) section 4.2, straight pushes of known length.
- ``distance``: Bonarini eqs. (18)-(19), a turn by a known angle.
- ``mounts``: Kim & Lee section IV (linearised), and an exact per-mouse fit.
- ``reference``: the REF.csv reader (body twist or wheel ticks, McGill model).
- ``umbmark``: Borenstein & Feng's UMBmark figures.
- ``csvtext``: what the REF.csv and RUNS.csv readers share (lines, fields, finite numbers).
- ``synth``: exact synthetic rigs for the tests and the benchmark.
- ``inputs``: ``--capture`` arguments to per-mouse reports (via ``mousedom.capture``).
- ``live``: interactive runs from live mice (Enter starts and stops a run).
- ``session``: recording + config -> results (the glue the commands call).
- ``report``: readable text of the results.
- ``calfile``: reading, merging and atomically writing the calibration YAML.
"""
