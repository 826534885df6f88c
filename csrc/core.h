/* mousedom._core: the compiled core (issue 28).  Optional: where it is not built, or
 * MOUSEDOM_CORE=python, the Python code runs instead, and that code is the specification
 * (mousedom/core.py says which runs).  Each function here names the Python function it
 * must equal, bit for bit; tests/test_core.py and tests/test_core_window.py hold them
 * equal on generated and hostile input, and tests/test_core_sanitized.py drives a build
 * with AddressSanitizer and UBSan.
 *
 * Build rules that keep the floats equal to Python's: no contraction of a*b+c into a fused
 * multiply-add (-ffp-contract=off, setup.py), every float operation in the order the
 * Python writes it, and libm's sin and cos (what math.sin and math.cos call).  Integers:
 * Python's are unbounded, these are int64; a sum that would overflow makes the function
 * return None, and the caller runs the Python instead (no real device gets there: it
 * takes 2^32 reports of the largest count without a frame end).
 *
 * One file per idea: decode.c (input_event records -> frames), knots.c (reports -> a
 * count function's knots, and a window's counts out of them), onewindow.c (one window's
 * solve and pose on floats), steady.c (the screen's common case), poseline.c (the POSE
 * line), evemu.c (evemu event lines into columns); core.c holds the module's table.
 */
#ifndef MOUSEDOM_CORE_H
#define MOUSEDOM_CORE_H

#define PY_SSIZE_T_CLEAN
#include <Python.h>
#include <math.h>
#include <stdint.h>
#include <string.h>

#define CORE_FUNCTION(name)                                  \
    extern const char core_##name##_doc[];                   \
    PyObject *core_##name(PyObject *self, PyObject *args)

CORE_FUNCTION(feed_bytes);
CORE_FUNCTION(forward_list);
CORE_FUNCTION(ingest_small);
CORE_FUNCTION(close_knots);
CORE_FUNCTION(body_counts);
CORE_FUNCTION(linear);
CORE_FUNCTION(advance);
CORE_FUNCTION(steady_window);
CORE_FUNCTION(pose_line);
CORE_FUNCTION(evemu_events);

/* Sets list[i] to a new float (the list takes the reference and drops the old item's);
 * -1 on error. */
int core_set_float(PyObject *list, Py_ssize_t i, double v);

/* A new list of n floats from v; NULL on error. */
PyObject *core_float_list(const double *v, Py_ssize_t n);

/* An exact float's value into *v: 1, or 0 where o is not one (an int, a subclass): the
 * Python would compute with the object itself, and an int may give a different result. */
int core_float_of(PyObject *o, double *v);

/* A list or tuple (exactly) of n exact floats into v: 1, or 0 where it is not one. */
int core_floats_of(PyObject *seq, double *v, Py_ssize_t n);

/* A 3x3 matrix as a list or tuple of three such rows of three floats into m: 1, or 0
 * where it is not one. */
int core_matrix3_of(PyObject *seq, double m[3][3]);

/* Whether every item of the list is exactly a float (not a subclass, not an int). */
int core_all_floats(PyObject *list);

#endif
