/* One window's solve and pose on floats (mousedom/fusion/onewindow.py) compiled: the
 * body-frame counts, the linear solve, and the pose and covariance carried on. */
#include "core.h"

static PyObject *matrix3_list(double m[3][3]) {
    PyObject *rows = PyList_New(3);
    if (rows == NULL) return NULL;
    for (int i = 0; i < 3; i++) {
        PyObject *row = core_float_list(m[i], 3);
        if (row == NULL) {
            Py_DECREF(rows);
            return NULL;
        }
        PyList_SET_ITEM(rows, i, row);
    }
    return rows;
}

/* ------------------------------------------------------------------ the solve */

const char core_body_counts_doc[] = PyDoc_STR(
"body_counts(to_body, counts) -> list or None\n\n"
"onewindow.body_counts: every mouse's counts (pairs of floats) through its 2x2 counts\n"
"matrix, flattened (x1, y1, x2, ...).  None where the shapes or types differ.");

PyObject *core_body_counts(PyObject *self, PyObject *args) {
    (void)self;
    PyObject *to_body, *counts;
    if (!PyArg_ParseTuple(args, "OO", &to_body, &counts)) return NULL;
    if (!PyList_CheckExact(to_body) || !PyList_CheckExact(counts)) Py_RETURN_NONE;
    Py_ssize_t n = PyList_GET_SIZE(to_body);
    if (PyList_GET_SIZE(counts) != n) Py_RETURN_NONE;
    PyObject *d = PyList_New(2 * n);
    if (d == NULL) return NULL;
    for (Py_ssize_t i = 0; i < n; i++) {
        double m[2][2], c[2];
        PyObject *mi = PyList_GET_ITEM(to_body, i);
        if (!PyList_CheckExact(mi) || PyList_GET_SIZE(mi) != 2 ||
            !core_floats_of(PyList_GET_ITEM(mi, 0), m[0], 2) ||
            !core_floats_of(PyList_GET_ITEM(mi, 1), m[1], 2) ||
            !core_floats_of(PyList_GET_ITEM(counts, i), c, 2)) {
            Py_DECREF(d);
            Py_RETURN_NONE;
        }
        for (int r = 0; r < 2; r++) {
            PyObject *o = PyFloat_FromDouble(m[r][0] * c[0] + m[r][1] * c[1]);
            if (o == NULL) {
                Py_DECREF(d);
                return NULL;
            }
            PyList_SET_ITEM(d, 2 * i + r, o);
        }
    }
    return d;
}

/* The running sum of builtin sum() over floats, started from its int 0: plain additions
 * up to Python 3.11, Neumaier's compensated sum from 3.12. */
typedef struct {
    double sum, c;
    int any;
} Sum;

static void sum_add(Sum *s, double x) {
    if (!s->any) { /* int 0 + x is float(0) + x: -0.0 becomes 0.0 */
        s->sum = 0.0 + x;
        s->any = 1;
        return;
    }
#if PY_VERSION_HEX >= 0x030C0000
    double t = s->sum + x;
    if (fabs(s->sum) >= fabs(x))
        s->c += (s->sum - t) + x;
    else
        s->c += (x - t) + s->sum;
    s->sum = t;
#else
    s->sum += x;
#endif
}

static double sum_value(const Sum *s) {
#if PY_VERSION_HEX >= 0x030C0000
    if (s->c != 0.0 && isfinite(s->c)) return s->sum + s->c;
#endif
    return s->sum;
}

/* sum(map(mul, row, v)) for a row of n floats. */
static double dot(const double *row, const double *v, Py_ssize_t n) {
    Sum s = {0.0, 0.0, 0};
    for (Py_ssize_t k = 0; k < n; k++) sum_add(&s, row[k] * v[k]);
    return sum_value(&s);
}

/* The rows of a list of lists of m floats each into a (PyMem) array; NULL with *bad set
 * where it is not one, NULL without on a memory error. */
static double *rows_of(PyObject *rows, Py_ssize_t m, Py_ssize_t *count, int *bad) {
    *bad = 0;
    if (!PyList_CheckExact(rows)) {
        *bad = 1;
        return NULL;
    }
    Py_ssize_t r = PyList_GET_SIZE(rows);
    double *v = PyMem_Malloc((size_t)(r * m + 1) * sizeof(double));
    if (v == NULL) return NULL;
    for (Py_ssize_t i = 0; i < r; i++)
        if (!core_floats_of(PyList_GET_ITEM(rows, i), v + i * m, m)) {
            PyMem_Free(v);
            *bad = 1;
            return NULL;
        }
    *count = r;
    return v;
}

const char core_linear_doc[] = PyDoc_STR(
"linear(d, a_rows, b_rows) -> (qk, residual) or None\n\n"
"onewindow.linear: qk = B d and the residual d - A qk, with builtin sum's additions.\n"
"None where the rows are not lists of floats of the lengths the product needs.");

PyObject *core_linear(PyObject *self, PyObject *args) {
    (void)self;
    PyObject *ld, *la, *lb, *result = NULL, *oq = NULL, *orr = NULL;
    if (!PyArg_ParseTuple(args, "OOO", &ld, &la, &lb)) return NULL;
    if (!PyList_CheckExact(ld)) Py_RETURN_NONE;
    Py_ssize_t m = PyList_GET_SIZE(ld), nb = 0, na = 0;
    double *d = NULL, *b = NULL, *a = NULL, *q = NULL, *res = NULL;
    int bad = 0;
    d = PyMem_Malloc((size_t)(m + 1) * sizeof(double));
    if (d == NULL) return PyErr_NoMemory();
    if (m == 0 || !core_floats_of(ld, d, m)) goto decline; /* (sum of nothing is the int 0) */
    b = rows_of(lb, m, &nb, &bad);
    if (b == NULL) goto fail;
    a = rows_of(la, nb, &na, &bad);
    if (a == NULL) goto fail;
    if (na != m) goto decline;
    q = PyMem_Malloc((size_t)(nb + 1) * sizeof(double));
    res = PyMem_Malloc((size_t)(m + 1) * sizeof(double));
    if (q == NULL || res == NULL) {
        PyErr_NoMemory();
        goto done;
    }
    for (Py_ssize_t k = 0; k < nb; k++) q[k] = dot(b + k * m, d, m);
    for (Py_ssize_t k = 0; k < m; k++) res[k] = d[k] - dot(a + k * nb, q, nb);
    oq = core_float_list(q, nb);
    orr = core_float_list(res, m);
    if (oq != NULL && orr != NULL) result = PyTuple_Pack(2, oq, orr);
    goto done;
fail:
    if (!bad) {
        PyErr_NoMemory();
        goto done;
    }
decline:
    result = Py_NewRef(Py_None);
done:
    Py_XDECREF(oq);
    Py_XDECREF(orr);
    PyMem_Free(d);
    PyMem_Free(b);
    PyMem_Free(a);
    PyMem_Free(q);
    PyMem_Free(res);
    return result;
}

/* ------------------------------------------------------------------ the pose */

/* The series of sinc and of its derivative below the switch (integrate._SINC_COEF,
 * _DSINC_COEF, _SINC_SWITCH), handed in by the caller: Python's correctly rounded
 * quotients of factorials, which C's arithmetic would not reproduce. */
typedef struct {
    double sinc[32], dsinc[32], sw;
    Py_ssize_t n_sinc, n_dsinc;
} Series;

static double horner(double h2, const double *coef, Py_ssize_t n) {
    double acc = coef[n - 1];
    for (Py_ssize_t k = n - 2; k >= 0; k--) acc = acc * h2 + coef[k];
    return acc;
}

static double sinc(const Series *s, double h) {
    if (fabs(h) < s->sw) return horner(h * h, s->sinc, s->n_sinc);
    return sin(h) / h;
}

static double dsinc(const Series *s, double h) {
    if (fabs(h) < s->sw) return h * horner(h * h, s->dsinc, s->n_dsinc);
    return (h * cos(h) - sin(h)) / (h * h);
}

enum { EXACT, TAYLOR, EULER, MIDPOINT };

/* onewindow.body_step. */
static void body_step(const Series *s, double ux, double uy, double a, int method,
                      double *sx, double *sy) {
    double cs, sn;
    if (method == EXACT) {
        double h = 0.5 * a, k = sinc(s, h);
        cs = k * cos(h);
        sn = k * sin(h);
    } else if (method == TAYLOR) {
        cs = 1.0 - a * a / 6.0;
        sn = 0.5 * a;
    } else if (method == EULER) {
        cs = cos(a);
        sn = sin(a);
    } else {
        cs = cos(0.5 * a);
        sn = sin(0.5 * a);
    }
    *sx = ux * cs - uy * sn;
    *sy = ux * sn + uy * cs;
}

/* onewindow._mul (t = 0) and _mul_t (t = 1): a @ b or a @ b.T. */
static void mul3(double a[3][3], double b[3][3], int t, double out[3][3]) {
    for (int i = 0; i < 3; i++)
        for (int j = 0; j < 3; j++) {
            double b0 = t ? b[j][0] : b[0][j], b1 = t ? b[j][1] : b[1][j];
            double b2 = t ? b[j][2] : b[2][j];
            out[i][j] = a[i][0] * b0 + a[i][1] * b1 + a[i][2] * b2;
        }
}

/* onewindow.noise. */
static void step_noise(const Series *s, double th, double ux, double uy, double a,
                       double qc[3][3], double g[3][3]) {
    double h = 0.5 * a;
    double sn = sinc(s, h), dsn = dsinc(s, h);
    double ch = cos(h), sh = sin(h);
    double ss = sn * ch, c = sn * sh;
    double ds = 0.5 * (dsn * ch - sn * sh);
    double dc = 0.5 * (dsn * sh + sn * ch);
    double j02 = ux * ds - uy * dc, j12 = ux * dc + uy * ds;
    double ct = cos(th), st = sin(th);
    double m[3][3] = {
        {ct * ss - st * c, -ct * c - st * ss, ct * j02 - st * j12},
        {st * ss + ct * c, -st * c + ct * ss, st * j02 + ct * j12},
        {0.0, 0.0, 1.0},
    };
    double mq[3][3];
    mul3(m, qc, 0, mq);
    mul3(mq, m, 1, g);
}

/* onewindow.propagate. */
static void propagate(double cov[3][3], const double prev[2], const double pos[2],
                      double g[3][3], double out[3][3]) {
    double u = prev[1] - pos[1], v = pos[0] - prev[0];
    double sp[3][3], p[3][3];
    for (int j = 0; j < 3; j++) {
        sp[0][j] = cov[0][j] + u * cov[2][j];
        sp[1][j] = cov[1][j] + v * cov[2][j];
        sp[2][j] = cov[2][j];
    }
    for (int i = 0; i < 3; i++) {
        p[i][0] = sp[i][0] + sp[i][2] * u + g[i][0];
        p[i][1] = sp[i][1] + sp[i][2] * v + g[i][1];
        p[i][2] = sp[i][2] + g[i][2];
    }
    for (int i = 0; i < 3; i++)
        for (int j = 0; j < 3; j++) out[i][j] = 0.5 * (p[i][j] + p[j][i]);
}

const char core_advance_doc[] = PyDoc_STR(
"advance(pose, cov, at, q, owed, c3, method, sinc, dsinc, switch) -> (pose, cov) or None\n\n"
"onewindow.advance: the pose (x, y, theta) and its covariance about ``at`` carried over\n"
"one window's twist q = (ux, uy, a) (plus ``owed`` radians of heading) of covariance c3,\n"
"with the integrator ``method``; ``sinc``, ``dsinc`` and ``switch`` are integrate's\n"
"series.  None where an argument is not floats of its shape or the method is unknown.");

PyObject *core_advance(PyObject *self, PyObject *args) {
    (void)self;
    PyObject *opose, *ocov, *oat, *oq, *oowed, *oc3, *oname, *osinc, *odsinc, *osw;
    double owed, pose[3], cov[3][3], at[2], q[3], c3[3][3];
    Series s;
    if (!PyArg_ParseTuple(args, "OOOOOOOOOO", &opose, &ocov, &oat, &oq, &oowed, &oc3, &oname,
                          &osinc, &odsinc, &osw))
        return NULL;
    const char *name = PyUnicode_CheckExact(oname) ? PyUnicode_AsUTF8(oname) : NULL;
    if (name == NULL) {
        PyErr_Clear(); /* (a string that is not UTF-8: the Python says it is unknown) */
        Py_RETURN_NONE;
    }
    if (!core_float_of(oowed, &owed) || !core_float_of(osw, &s.sw)) Py_RETURN_NONE;
    int method = strcmp(name, "exact") == 0      ? EXACT
                 : strcmp(name, "taylor") == 0   ? TAYLOR
                 : strcmp(name, "euler") == 0    ? EULER
                 : strcmp(name, "midpoint") == 0 ? MIDPOINT
                                                 : -1;
    s.n_sinc = PyList_CheckExact(osinc) ? PyList_GET_SIZE(osinc) : 0;
    s.n_dsinc = PyList_CheckExact(odsinc) ? PyList_GET_SIZE(odsinc) : 0;
    if (method < 0 || s.n_sinc < 1 || s.n_sinc > 32 || s.n_dsinc < 1 || s.n_dsinc > 32 ||
        !core_floats_of(osinc, s.sinc, s.n_sinc) || !core_floats_of(odsinc, s.dsinc, s.n_dsinc) ||
        !core_floats_of(opose, pose, 3) || !core_matrix3_of(ocov, cov) || !core_floats_of(oat, at, 2) ||
        !core_floats_of(oq, q, 3) || !core_matrix3_of(oc3, c3))
        Py_RETURN_NONE;
    double ux = q[0], uy = q[1], a = q[2], turn = a + owed;
    /* math.sin and math.cos refuse infinities (ValueError): the Python says so */
    if (isinf(pose[2]) || isinf(turn)) Py_RETURN_NONE;
    double sx, sy;
    body_step(&s, ux, uy, turn, method, &sx, &sy);
    double x0 = pose[0], y0 = pose[1], th0 = pose[2];
    double cb = cos(th0), sb = sin(th0);
    double xy[2] = {x0 + (cb * sx - sb * sy), y0 + (sb * sx + cb * sy)};
    double now[3] = {xy[0], xy[1], th0 + a + owed};
    double g[3][3], out[3][3];
    step_noise(&s, th0, ux, uy, turn, c3, g);
    propagate(cov, at, xy, g, out);
    PyObject *op = core_float_list(now, 3), *oc = matrix3_list(out);
    if (op == NULL || oc == NULL) {
        Py_XDECREF(op);
        Py_XDECREF(oc);
        return NULL;
    }
    return Py_BuildValue("(NN)", op, oc);
}
