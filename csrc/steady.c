/* The screen's common case for one window (mousedom/fusion/steady.py) compiled. */
#include "core.h"

#define MAX_MICE 64

/* A list of n pairs (of two floats each) into v[2k], v[2k + 1]. */
static int list_pairs(PyObject *list, double *v, Py_ssize_t n) {
    if (!PyList_CheckExact(list) || PyList_GET_SIZE(list) != n) return 0;
    for (Py_ssize_t k = 0; k < n; k++)
        if (!core_floats_of(PyList_GET_ITEM(list, k), v + 2 * k, 2)) return 0;
    return 1;
}

/* The Rig fields in steady.Rig's order. */
enum { XY, MAX2, PREV, FLOOR, RHO2, GRAN2, SIG2, LAM_R, RIG_N };

/* Appends (i, v) to list; -1 on error. */
static int append_sample(PyObject *list, Py_ssize_t i, double v) {
    PyObject *item = Py_BuildValue("(nd)", i, v);
    if (item == NULL) return -1;
    int bad = PyList_Append(list, item);
    Py_DECREF(item);
    return bad;
}

const char core_steady_window_doc[] = PyDoc_STR(
"steady_window(d, q, live, rig, threshold, dof, leverage, median_chi2)\n"
"    -> (prev, by_floor, by_prop), None or False\n\n"
"steady.steady_window: None where the screen must decide, else the predictions and the\n"
"noise model's samples.  False (declined: the caller runs the Python) where an argument\n"
"is not of the types and shapes the Python is handed.");

PyObject *core_steady_window(PyObject *self, PyObject *args) {
    (void)self;
    PyObject *od, *oq, *olive, *orig, *olev, *othreshold, *odof;
    double threshold, median_chi2;
    if (!PyArg_ParseTuple(args, "OOOOOOOd", &od, &oq, &olive, &orig, &othreshold, &odof, &olev,
                          &median_chi2))
        return NULL;
    if (!core_float_of(othreshold, &threshold) || !PyLong_CheckExact(odof)) Py_RETURN_FALSE;
    int ovf = 0;
    long long dof = PyLong_AsLongLongAndOverflow(odof, &ovf);
    if (ovf) Py_RETURN_FALSE;
    if (!PyTuple_Check(orig) || PyTuple_GET_SIZE(orig) != RIG_N || !PyTuple_CheckExact(olive))
        Py_RETURN_FALSE;
    Py_ssize_t n = PyTuple_GET_SIZE(olive);
    double d[2 * MAX_MICE], q[3], xy[2 * MAX_MICE], prev[2 * MAX_MICE], lev[MAX_MICE];
    double max2[MAX_MICE], floor_[MAX_MICE], rho2[MAX_MICE], gran2[MAX_MICE];
    double sig2[MAX_MICE], lam_r[MAX_MICE];
    int live[MAX_MICE];
    if (n < 1 || n > MAX_MICE || !core_floats_of(od, d, 2 * n) || !core_floats_of(oq, q, 3) ||
        !list_pairs(PyTuple_GET_ITEM(orig, XY), xy, n) ||
        !core_floats_of(PyTuple_GET_ITEM(orig, MAX2), max2, n) ||
        !list_pairs(PyTuple_GET_ITEM(orig, PREV), prev, n) ||
        !core_floats_of(PyTuple_GET_ITEM(orig, FLOOR), floor_, n) ||
        !core_floats_of(PyTuple_GET_ITEM(orig, RHO2), rho2, n) ||
        !core_floats_of(PyTuple_GET_ITEM(orig, GRAN2), gran2, n) ||
        !core_floats_of(PyTuple_GET_ITEM(orig, SIG2), sig2, n) ||
        !core_floats_of(PyTuple_GET_ITEM(orig, LAM_R), lam_r, n))
        Py_RETURN_FALSE;
    int use_lev = dof > 0 && olev != Py_None;
    if (use_lev && !core_floats_of(olev, lev, n)) Py_RETURN_FALSE;
    for (Py_ssize_t i = 0; i < n; i++) {
        PyObject *o = PyTuple_GET_ITEM(olive, i);
        if (o != Py_True && o != Py_False) Py_RETURN_FALSE;
        live[i] = o == Py_True;
    }
    double ux = q[0], uy = q[1], a = q[2];
    double total = 0.0, r2s[MAX_MICE], props[MAX_MICE], m2s[MAX_MICE];
    for (Py_ssize_t i = 0; i < n; i++) {
        if (!live[i]) continue;
        double x = xy[2 * i], y = xy[2 * i + 1];
        double px = ux - a * y, py = uy + a * x;
        double dx = d[2 * i], dy = d[2 * i + 1];
        double seen = dx * dx + dy * dy, said = px * px + py * py;
        double m2 = said > seen ? said : seen; /* max(): the first unless the second is more */
        if (m2 >= max2[i]) Py_RETURN_NONE;     /* saturated: decide */
        double fx = px - prev[2 * i], fy = py - prev[2 * i + 1];
        double prop = rho2[i] * m2 + gran2[i] * (fx * fx + fy * fy);
        double rx = dx - px, ry = dy - py;
        double r2 = rx * rx + ry * ry;
        if (floor_[i] + prop == 0.0) Py_RETURN_FALSE; /* Python's ZeroDivisionError */
        total += r2 / (floor_[i] + prop);
        r2s[i] = r2;
        props[i] = prop;
        m2s[i] = m2;
    }
    if (dof > 0 && total > threshold) Py_RETURN_NONE;
    PyObject *by_floor = PyList_New(0), *by_prop = PyList_New(0), *preds = PyList_New(n);
    if (by_floor == NULL || by_prop == NULL || preds == NULL) goto fail;
    for (Py_ssize_t i = 0; use_lev && i < n; i++) {
        if (!live[i] || !(m2s[i] > sig2[i])) continue;
        /* noisemodel.sample_values */
        double floor = floor_[i], prop = props[i];
        double expected = median_chi2 * (1.0 - 0.5 * lev[i]);
        if (expected <= 0) continue;
        double v = r2s[i] / expected;
        if (4.0 * floor >= prop) {
            if (sig2[i] == 0.0) goto decline; /* Python's ZeroDivisionError */
            if (append_sample(by_floor, i, (v - prop) / sig2[i]) < 0) goto fail;
        }
        if (4.0 * prop >= floor && prop > 0) {
            if (lam_r[i] == 0.0 || prop / lam_r[i] == 0.0) goto decline;
            if (append_sample(by_prop, i, (v - floor) / (prop / lam_r[i])) < 0) goto fail;
        }
    }
    for (Py_ssize_t i = 0; i < n; i++) {
        double x = xy[2 * i], y = xy[2 * i + 1];
        double p[2] = {ux - a * y, uy + a * x};
        PyObject *pair = core_float_list(p, 2);
        if (pair == NULL) goto fail;
        PyList_SET_ITEM(preds, i, pair);
    }
    return Py_BuildValue("(NNN)", preds, by_floor, by_prop);
decline:
    Py_DECREF(by_floor);
    Py_DECREF(by_prop);
    Py_DECREF(preds);
    Py_RETURN_FALSE;
fail:
    Py_XDECREF(by_floor);
    Py_XDECREF(by_prop);
    Py_XDECREF(preds);
    return NULL;
}
