/* The screen's common case for one window (mousedom/fusion/steady.py) compiled, with the
 * shortfall's rule it applies (mousedom/fusion/shortfall.py). */
#include "core.h"

#define MAX_MICE 64

/* shortfall.py's constants (tests/test_core_window.py holds them equal). */
#define SHORT 0.75
#define SHORT_OF_ALL 0.9
#define SHORT_ALONE 0.25

/* shortfall.reads_short: whether any considered mouse reads short of its motion.  d: the
 * readings (x1, y1, ...); p: the predictions, the same layout; gains: four per mouse. */
static int any_short(Py_ssize_t n, const double *d, const double *p, const double *gains,
                     const int *considered, const int *used) {
    int any_alone = 0, odd_short = 0;
    double odd_by = 0.0;
    for (Py_ssize_t i = 0; i < n; i++) {
        if (!considered[i]) continue;
        double dx = d[2 * i], dy = d[2 * i + 1], px = p[2 * i], py = p[2 * i + 1];
        double along = dx * px + dy * py, p2 = px * px + py * py;
        if (along < SHORT_ALONE * p2) any_alone = 1;
        const double *g = gains + 4 * i;
        /* Python's truth of a float: not zero (a NaN is true) */
        if (!used[i] || !(g[0] != 0.0 || g[1] != 0.0 || g[2] != 0.0 || g[3] != 0.0)) continue;
        double rx = dx - px, ry = dy - py;
        double ox = dx - (g[0] * rx + g[1] * ry), oy = dy - (g[2] * rx + g[3] * ry);
        double o2 = ox * ox + oy * oy;
        if (!(o2 > 0.0)) continue;
        double ratio = (dx * ox + dy * oy) / o2;
        double by = INFINITY;
        if (ratio > 0.0) {
            double inv = 1.0 / ratio;
            by = inv > ratio ? inv : ratio; /* max(): the first unless the second is more */
        }
        if (by > odd_by) {
            odd_by = by;
            odd_short = ratio < SHORT && along < SHORT_OF_ALL * p2;
        }
    }
    return any_alone || odd_short;
}

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
"steady_window(d, q, live, rig, threshold, dof, leverage, gains, spans, median_chi2)\n"
"    -> (prev, by_floor, by_prop, heard), None or False\n\n"
"steady.steady_window: None where the screen must decide, else the predictions, the\n"
"noise model's samples and the mice heard.  False (declined: the caller runs the Python)\n"
"where an argument is not of the types and shapes the Python is handed.");

PyObject *core_steady_window(PyObject *self, PyObject *args) {
    (void)self;
    PyObject *od, *oq, *olive, *orig, *olev, *othreshold, *odof, *ogains, *ospans;
    double threshold, median_chi2;
    if (!PyArg_ParseTuple(args, "OOOOOOOOOd", &od, &oq, &olive, &orig, &othreshold, &odof, &olev,
                          &ogains, &ospans, &median_chi2))
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
    double gains[4 * MAX_MICE];
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
    if (!PyList_CheckExact(ogains) || PyList_GET_SIZE(ogains) != n) Py_RETURN_FALSE;
    for (Py_ssize_t i = 0; i < n; i++)
        if (!core_floats_of(PyList_GET_ITEM(ogains, i), gains + 4 * i, 4)) Py_RETURN_FALSE;
    /* each mouse's long report span the window's edges cut (> 0), or None: none cut */
    double spans[MAX_MICE];
    int cut_any = ospans != Py_None;
    if (cut_any && !core_floats_of(ospans, spans, n)) Py_RETURN_FALSE;
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
        double fx, fy;
        if (cut_any && spans[i] > 0) {
            /* the change of motion from what the others moved it (shortfall.others_word) */
            const double *g = gains + 4 * i;
            if (!(g[0] != 0.0 || g[1] != 0.0 || g[2] != 0.0 || g[3] != 0.0))
                Py_RETURN_NONE; /* the others cannot place it: decide */
            double rx = dx - px, ry = dy - py;
            double ox = dx - (g[0] * rx + g[1] * ry), oy = dy - (g[2] * rx + g[3] * ry);
            fx = ox - prev[2 * i];
            fy = oy - prev[2 * i + 1];
        } else {
            fx = px - prev[2 * i];
            fy = py - prev[2 * i + 1];
        }
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
    double p[2 * MAX_MICE];
    int heard[MAX_MICE];
    for (Py_ssize_t i = 0; i < n; i++) {
        double x = xy[2 * i], y = xy[2 * i + 1];
        double px = ux - a * y, py = uy + a * x;
        p[2 * i] = px;
        p[2 * i + 1] = py;
        heard[i] = live[i] && px * px + py * py > sig2[i];
    }
    if (any_short(n, d, p, gains, heard, live)) {
        Py_DECREF(by_floor);
        Py_DECREF(by_prop);
        Py_DECREF(preds);
        Py_RETURN_NONE; /* short of its motion: decide (the screen's shortfall) */
    }
    PyObject *oheard = PyList_New(n);
    if (oheard == NULL) goto fail;
    for (Py_ssize_t i = 0; i < n; i++) {
        PyObject *pair = core_float_list(p + 2 * i, 2);
        if (pair == NULL) {
            Py_DECREF(oheard);
            goto fail;
        }
        PyList_SET_ITEM(preds, i, pair);
        PyList_SET_ITEM(oheard, i, PyBool_FromLong(heard[i]));
    }
    return Py_BuildValue("(NNNN)", preds, by_floor, by_prop, oheard);
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
