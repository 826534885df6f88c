/* CountFunction's knot loops (mousedom/fusion/countfunction.py) compiled. */
#include "core.h"

/* ---------------------------------------------------------------- reports -> knots */

/* One axis's counts: whole numbers summed as int64 (as Python sums its ints, exactly) or
 * floats summed as doubles, each in the list's order. */
typedef struct {
    int is_int;
    int64_t ci; /* the running sum, whole counts */
    double cf;  /* the running sum, float counts */
} Axis;

/* Checks one axis's list and that every prefix sum fits: 1 fine, 0 decline, -1 error. */
static int axis_check(PyObject *list, Py_ssize_t n, int *is_int) {
    PyObject *first = PyList_GET_ITEM(list, 0);
    *is_int = PyLong_CheckExact(first);
    if (!*is_int && !PyFloat_CheckExact(first)) return 0;
    int64_t sum = 0;
    for (Py_ssize_t k = 0; k < n; k++) {
        PyObject *o = PyList_GET_ITEM(list, k);
        if (*is_int) {
            if (!PyLong_CheckExact(o)) return 0;
            int ovf = 0;
            long long v = PyLong_AsLongLongAndOverflow(o, &ovf);
            if (v == -1 && PyErr_Occurred()) return -1;
            if (ovf || __builtin_add_overflow(sum, (int64_t)v, &sum)) return 0;
        } else if (!PyFloat_CheckExact(o)) {
            return 0;
        }
    }
    return 1;
}

/* The count at k added to the axis; returns the count as a double (Python's float(a)). */
static double axis_add(Axis *ax, PyObject *o, int first) {
    if (ax->is_int) {
        int64_t v = (int64_t)PyLong_AsLongLong(o); /* checked to fit by axis_check */
        ax->ci = first ? v : ax->ci + v;
        return (double)v;
    }
    double v = PyFloat_AS_DOUBLE(o);
    ax->cf = first ? v : ax->cf + v;
    return v;
}

static double axis_sum(const Axis *ax) { return ax->is_int ? (double)ax->ci : ax->cf; }

static PyObject *axis_object(const Axis *ax) {
    return ax->is_int ? PyLong_FromLongLong(ax->ci) : PyFloat_FromDouble(ax->cf);
}

static int append_two(PyObject *list, double a, double b) {
    PyObject *oa = PyFloat_FromDouble(a), *ob = PyFloat_FromDouble(b);
    int bad = oa == NULL || ob == NULL || PyList_Append(list, oa) < 0 ||
              PyList_Append(list, ob) < 0;
    Py_XDECREF(oa);
    Py_XDECREF(ob);
    return bad ? -1 : 0;
}

static double last_float(PyObject *list, Py_ssize_t back) {
    return PyFloat_AsDouble(PyList_GET_ITEM(list, PyList_GET_SIZE(list) - back));
}

const char core_ingest_small_doc[] = PyDoc_STR(
"ingest_small(t, dx, dy, kt, kx, ky, knot_t, edge, period, bridge, join)\n"
"    -> (cx, cy, backwards, late, knot_t) or None\n\n"
"CountFunction.ingest_small's loop: the reports (t, dx, dy lists) become knots appended\n"
"to the lists kt, kx, ky (changed in place); returns the counts' sums (int where the\n"
"counts are ints, else float), the reports stamped backwards and behind the edge, and\n"
"the last report's stamp.  None, with the lists untouched, where the lists hold other\n"
"than float times and all-int or all-float counts per axis, or an int sum would leave\n"
"int64 (the caller runs the Python).");

PyObject *core_ingest_small(PyObject *self, PyObject *args) {
    (void)self;
    PyObject *t, *dx, *dy, *kt, *kx, *ky;
    double knot_t, edge, period, bridge, join;
    if (!PyArg_ParseTuple(args, "OOOOOOddddd", &t, &dx, &dy, &kt, &kx, &ky, &knot_t, &edge,
                          &period, &bridge, &join))
        return NULL;
    if (!PyList_CheckExact(t) || !PyList_CheckExact(dx) || !PyList_CheckExact(dy) ||
        !PyList_CheckExact(kt) || !PyList_CheckExact(kx) || !PyList_CheckExact(ky))
        Py_RETURN_NONE; /* (a subclass may change what indexing and += do) */
    Py_ssize_t n = PyList_GET_SIZE(t), nk = PyList_GET_SIZE(kt);
    if (n == 0 || PyList_GET_SIZE(dx) != n || PyList_GET_SIZE(dy) != n ||
        PyList_GET_SIZE(kx) != nk || PyList_GET_SIZE(ky) != nk)
        Py_RETURN_NONE;
    if (!core_all_floats(t) || !core_all_floats(kt) || !core_all_floats(kx) ||
        !core_all_floats(ky))
        Py_RETURN_NONE;
    Axis ax = {0, 0, 0.0}, ay = {0, 0, 0.0};
    int ok = axis_check(dx, n, &ax.is_int);
    if (ok == 1) ok = axis_check(dy, n, &ay.is_int);
    if (ok < 0) return NULL;
    if (ok == 0) Py_RETURN_NONE;

    double lx = 0.0, ly = 0.0;
    if (nk) {
        lx = last_float(kx, 1);
        ly = last_float(ky, 1);
    }
    double run = knot_t, prev = knot_t;
    long long backwards = 0, late = 0;
    for (Py_ssize_t k = 0; k < n; k++) {
        double a = axis_add(&ax, PyList_GET_ITEM(dx, k), k == 0);
        double b = axis_add(&ay, PyList_GET_ITEM(dy, k), k == 0);
        double ti = PyFloat_AS_DOUBLE(PyList_GET_ITEM(t, k));
        if (run > ti)
            backwards++;
        else
            run = ti;
        ti = run;
        if (ti < edge) {
            late++;
            ti = edge;
        }
        double x = axis_sum(&ax) + lx, y = axis_sum(&ay) + ly;
        double gap = ti - prev;
        Py_ssize_t m = PyList_GET_SIZE(kt);
        if (gap < join && m >= 2 && last_float(kt, 1) == prev && prev > edge &&
            ti - last_float(kt, 2) <= bridge) {
            /* held up on its way: the previous report's span stretches to take it */
            if (core_set_float(kt, m - 1, ti) < 0 || core_set_float(kx, m - 1, x) < 0 ||
                core_set_float(ky, m - 1, y) < 0)
                return NULL;
            prev = ti;
            continue;
        }
        /* the span: since the previous report within the bridge, else one period */
        double start = gap <= bridge ? prev : ti - period;
        if (edge > start) start = edge;
        if (append_two(kt, start, ti) < 0 || append_two(kx, x - a, x) < 0 ||
            append_two(ky, y - b, y) < 0)
            return NULL;
        prev = ti;
    }
    PyObject *ox = axis_object(&ax), *oy = axis_object(&ay);
    if (ox == NULL || oy == NULL) {
        Py_XDECREF(ox);
        Py_XDECREF(oy);
        return NULL;
    }
    return Py_BuildValue("(NNLLd)", ox, oy, backwards, late, prev);
}

/* ---------------------------------------------------------------- knots -> a window */

/* bisect.bisect_right and bisect_left: the same comparisons in the same order. */
static Py_ssize_t bisect_right(const double *a, Py_ssize_t n, double x) {
    Py_ssize_t lo = 0, hi = n;
    while (lo < hi) {
        Py_ssize_t mid = (lo + hi) / 2;
        if (x < a[mid])
            hi = mid;
        else
            lo = mid + 1;
    }
    return lo;
}

static Py_ssize_t bisect_left(const double *a, Py_ssize_t n, double x) {
    Py_ssize_t lo = 0, hi = n;
    while (lo < hi) {
        Py_ssize_t mid = (lo + hi) / 2;
        if (a[mid] < x)
            lo = mid + 1;
        else
            hi = mid;
    }
    return lo;
}

/* countfunction.interp_at (n >= 1). */
static double interp_at(double x, const double *xp, const double *fp, Py_ssize_t n) {
    if (x > xp[n - 1]) return fp[n - 1];
    if (x < xp[0]) return fp[0];
    Py_ssize_t j = bisect_right(xp, n, x) - 1;
    if (j == n - 1 || xp[j] == x) return fp[j];
    double slope = (fp[j + 1] - fp[j]) / (xp[j + 1] - xp[j]);
    return slope * (x - xp[j]) + fp[j];
}

/* countfunction.cut_span (n >= 1): sets *from and *length. */
static void cut_span(double x, const double *kt, const double *kx, const double *ky,
                     Py_ssize_t n, double cut_from, double *from, double *length) {
    Py_ssize_t j = bisect_right(kt, n, x);
    *from = Py_NAN;
    *length = 0.0;
    if (j == 0 || j >= n || !(kt[j - 1] < x)) return;
    if (j == 1 && cut_from == cut_from) {
        *from = cut_from;
        *length = kt[j] - cut_from;
        return;
    }
    if (fabs(kx[j] - kx[j - 1]) + fabs(ky[j] - ky[j - 1]) <= 0.5) return;
    *from = kt[j - 1];
    *length = kt[j] - kt[j - 1];
}

/* The items of a list of floats (checked by the caller) into v. */
static void read_floats(PyObject *list, double *v) {
    for (Py_ssize_t k = 0; k < PyList_GET_SIZE(list); k++)
        v[k] = PyFloat_AS_DOUBLE(PyList_GET_ITEM(list, k));
}

/* [first, *v[j:]] (subtract 0) or [first, *(x - level for x in v[j:])]: a knot row
 * rebased at the window's edge, built as countfunction.close_knots builds it, in
 * ``row`` (room for n - j + 1). */
static PyObject *rebased(double first, const double *v, Py_ssize_t j, Py_ssize_t n,
                         double level, int subtract, double *row) {
    row[0] = first;
    for (Py_ssize_t k = j; k < n; k++) row[k - j + 1] = subtract ? v[k] - level : v[k];
    return core_float_list(row, n - j + 1);
}

const char core_close_knots_doc[] = PyDoc_STR(
"close_knots(end, kt, kx, ky, cut_from) -> (cut_from, length, fx, fy, kt, kx, ky) or None\n\n"
"countfunction.close_knots: the window ending at ``end`` out of the knots (three lists of\n"
"floats, at least one knot): the rising span the edge cuts (where it began, its length),\n"
"F at the edge, and the knots rebased there (new lists).  None where an argument is not\n"
"a float or the lists are not all floats of one length (the caller runs the Python).");

PyObject *core_close_knots(PyObject *self, PyObject *args) {
    (void)self;
    PyObject *lt, *lx, *ly, *oend, *ocut;
    double end, cut_from;
    if (!PyArg_ParseTuple(args, "OOOOO", &oend, &lt, &lx, &ly, &ocut)) return NULL;
    if (!PyList_CheckExact(lt) || !PyList_CheckExact(lx) || !PyList_CheckExact(ly))
        Py_RETURN_NONE;
    Py_ssize_t n = PyList_GET_SIZE(lt);
    if (!core_float_of(oend, &end) || !core_float_of(ocut, &cut_from) || n == 0 ||
        PyList_GET_SIZE(lx) != n || PyList_GET_SIZE(ly) != n ||
        !core_all_floats(lt) || !core_all_floats(lx) || !core_all_floats(ly))
        Py_RETURN_NONE;
    double small[4 * 64 + 1], *buf = small; /* the knots, and a rebased row */
    if (n > 64) {
        buf = PyMem_Malloc((4 * (size_t)n + 1) * sizeof(double));
        if (buf == NULL) return PyErr_NoMemory();
    }
    double *kt = buf, *kx = buf + n, *ky = buf + 2 * n, *row = buf + 3 * n;
    read_floats(lt, kt);
    read_floats(lx, kx);
    read_floats(ly, ky);
    double from, length;
    cut_span(end, kt, kx, ky, n, cut_from, &from, &length);
    double fx = interp_at(end, kt, kx, n), fy = interp_at(end, kt, ky, n);
    Py_ssize_t j = bisect_left(kt, n, end);
    PyObject *nt = rebased(end, kt, j, n, 0.0, 0, row);
    PyObject *nx = rebased(0.0, kx, j, n, fx, 1, row);
    PyObject *ny = rebased(0.0, ky, j, n, fy, 1, row);
    if (buf != small) PyMem_Free(buf);
    if (nt == NULL || nx == NULL || ny == NULL) {
        Py_XDECREF(nt);
        Py_XDECREF(nx);
        Py_XDECREF(ny);
        return NULL;
    }
    return Py_BuildValue("(ddddNNN)", from, length, fx, fy, nt, nx, ny);
}
