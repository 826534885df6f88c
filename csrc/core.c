/* mousedom._core: the compiled core (issue 28).  Optional: where it is not built, or
 * MOUSEDOM_CORE=python, the Python code runs instead, and that code is the specification
 * (mousedom/core.py says which runs).  Each function here names the Python function it
 * must equal, bit for bit; tests/test_core.py holds them equal on generated and hostile
 * input, and tests/test_core_sanitized.py drives a build with AddressSanitizer and UBSan.
 *
 * Build rules that keep the floats equal to Python's: no contraction of a*b+c into a fused
 * multiply-add (-ffp-contract=off, setup.py), every float operation in the order the
 * Python writes it.  Integers: Python's are unbounded, these are int64; a sum that would
 * overflow makes the function return None, and the caller runs the Python instead (no
 * real device gets there: it takes 2^32 reports of the largest count without a frame end).
 */
#define PY_SSIZE_T_CLEAN
#include <Python.h>
#include <stdint.h>
#include <string.h>

/* struct input_event on 64-bit Linux: two int64 (tv_sec, tv_usec), u16 type, u16 code,
 * s32 value; little-endian on every host mousedom runs on, read byte by byte here so the
 * host's order does not matter (events.py: EVENT_DTYPE). */
#define EVENT_SIZE 24
#define KEY_SYN_REPORT 0x00000000u
#define KEY_SYN_DROPPED 0x00030000u /* EV_SYN | SYN_DROPPED << 16 */
#define KEY_REL_X 0x00000002u       /* EV_REL | REL_X << 16 */
#define KEY_REL_Y 0x00010002u       /* EV_REL | REL_Y << 16 */
#define EV_SYN 0x0000u

static int64_t le64(const unsigned char *p) {
    uint64_t v = 0;
    for (int i = 7; i >= 0; i--) v = (v << 8) | p[i];
    return (int64_t)v; /* two's complement, as the kernel wrote it */
}

static uint32_t le32(const unsigned char *p) {
    return (uint32_t)p[0] | (uint32_t)p[1] << 8 | (uint32_t)p[2] << 16 | (uint32_t)p[3] << 24;
}

/* The frame open at the start or the end of a read: FrameAssembler's _open_* fields. */
typedef struct {
    int64_t dx, dy;
    int motion, dropped;
    int64_t events, nonsyn;
    double t;
} OpenFrame;

/* What one read adds to AssemblerStats, in its field order. */
enum {
    ST_EVENTS, ST_FRAMES, ST_MOTION_FRAMES, ST_SKIPPED, ST_SYN_DROPPED, ST_DROPPED_FRAMES,
    ST_DROPPED_DX, ST_DROPPED_DY, ST_DROPPED_EVENTS, ST_REL_X_IN, ST_REL_Y_IN, ST_N
};

#define ADD(a, b) if (__builtin_add_overflow((a), (b), &(a))) goto overflow
#define SUB(a, b) if (__builtin_sub_overflow((a), (b), &(a))) goto overflow

/* Appends one motion frame to the three lists; -1 on a Python error. */
static int append_frame(PyObject *lt, PyObject *lx, PyObject *ly, double t, int64_t dx,
                        int64_t dy) {
    PyObject *ot = PyFloat_FromDouble(t);
    PyObject *ox = PyLong_FromLongLong(dx);
    PyObject *oy = PyLong_FromLongLong(dy);
    int bad = ot == NULL || ox == NULL || oy == NULL || PyList_Append(lt, ot) < 0 ||
              PyList_Append(lx, ox) < 0 || PyList_Append(ly, oy) < 0;
    Py_XDECREF(ot);
    Py_XDECREF(ox);
    Py_XDECREF(oy);
    return bad ? -1 : 0;
}

/* FrameAssembler._feed_loop over the whole records of buf (FrameAssembler.feed_bytes),
 * with the open frame ``of`` carried in and out and the statistics added to ``st``.
 * Returns 1 when done, 0 on an int64 overflow (nothing to use), -1 on a Python error. */
static int feed_records(const unsigned char *buf, Py_ssize_t n, OpenFrame *of, int64_t *st,
                        PyObject *lt, PyObject *lx, PyObject *ly) {
    int64_t dx0 = of->dx, dy0 = of->dy, dx = of->dx, dy = of->dy;
    int dropped = of->dropped;
    /* the carried frame as _feed_loop holds it: m > 0 and m + other are what count */
    int64_t m = of->motion ? 1 : 0, other = of->nonsyn - m, synx = of->events - of->nonsyn;
    int64_t frames = 0, skipped = 0, lost_x = 0, lost_y = 0, out_n = 0;
    int64_t sum_x = 0, sum_y = 0; /* the frames handed out */
    int64_t sec = 0, usec = 0;
    st[ST_EVENTS] += n;
    for (Py_ssize_t r = 0; r < n; r++) {
        const unsigned char *p = buf + r * EVENT_SIZE;
        uint32_t k = le32(p + 16);
        int64_t v = (int32_t)le32(p + 20);
        sec = le64(p);
        usec = le64(p + 8);
        if (k == KEY_REL_X) {
            ADD(dx, v);
            m++;
        } else if (k == KEY_REL_Y) {
            ADD(dy, v);
            m++;
        } else if (k == KEY_SYN_REPORT) {
            frames++;
            if (dropped) {
                st[ST_DROPPED_FRAMES]++;
                ADD(lost_x, dx);
                ADD(lost_y, dy);
                ADD(st[ST_DROPPED_EVENTS], m + other);
                dropped = 0;
            } else if (m) {
                double t = (double)sec + (double)usec * 1e-6;
                if (append_frame(lt, lx, ly, t, dx, dy) < 0) return -1;
                out_n++;
                ADD(sum_x, dx);
                ADD(sum_y, dy);
            }
            dx = dy = m = other = synx = 0;
        } else if (k == KEY_SYN_DROPPED) {
            st[ST_SYN_DROPPED]++;
            dropped = 1;
            synx++;
        } else {
            skipped++;
            if ((k & 0xFFFFu) != EV_SYN)
                other++;
            else
                synx++;
        }
    }
    st[ST_FRAMES] += frames;
    st[ST_SKIPPED] += skipped;
    st[ST_MOTION_FRAMES] += out_n;
    ADD(st[ST_DROPPED_DX], lost_x);
    ADD(st[ST_DROPPED_DY], lost_y);
    /* every REL_X count fed lands once: a frame handed out, a dropped one, or the open one */
    int64_t in_x = sum_x, in_y = sum_y;
    ADD(in_x, lost_x);
    ADD(in_x, dx);
    SUB(in_x, dx0);
    ADD(in_y, lost_y);
    ADD(in_y, dy);
    SUB(in_y, dy0);
    st[ST_REL_X_IN] = in_x;
    st[ST_REL_Y_IN] = in_y;
    of->dx = dx;
    of->dy = dy;
    of->motion = m > 0;
    of->dropped = dropped;
    of->nonsyn = m + other;
    of->events = m + other + synx;
    if (n > 0 && of->events) /* then the last record read belongs to the open frame */
        of->t = (double)sec + (double)usec * 1e-6;
    return 1;
overflow:
    return 0;
}

PyDoc_STRVAR(feed_bytes_doc,
"feed_bytes(buf, open) -> (t, dx, dy, rest, open, stats) or None\n\n"
"FrameAssembler.feed_bytes's rules over one read: ``open`` is the frame left open\n"
"(dx, dy, motion, dropped, events, nonsyn, t); returns the motion frames closed in buf\n"
"as three lists, the bytes of a trailing partial record, the frame now open, and what\n"
"to add to each AssemblerStats field in its order.  None where an int64 would overflow\n"
"(the caller runs the Python).");

static PyObject *feed_bytes(PyObject *self, PyObject *args) {
    (void)self;
    Py_buffer view;
    PyObject *open;
    if (!PyArg_ParseTuple(args, "y*O!", &view, &PyTuple_Type, &open)) return NULL;
    PyObject *result = NULL, *lt = NULL, *lx = NULL, *ly = NULL;
    OpenFrame of;
    int motion, dropped, ovf[4] = {0, 0, 0, 0};
    long long odx, ody, oev, ons;
    if (PyTuple_GET_SIZE(open) != 7) {
        PyErr_SetString(PyExc_ValueError, "open: expected 7 fields");
        goto done;
    }
    odx = PyLong_AsLongLongAndOverflow(PyTuple_GET_ITEM(open, 0), &ovf[0]);
    ody = PyLong_AsLongLongAndOverflow(PyTuple_GET_ITEM(open, 1), &ovf[1]);
    motion = PyObject_IsTrue(PyTuple_GET_ITEM(open, 2));
    dropped = PyObject_IsTrue(PyTuple_GET_ITEM(open, 3));
    oev = PyLong_AsLongLongAndOverflow(PyTuple_GET_ITEM(open, 4), &ovf[2]);
    ons = PyLong_AsLongLongAndOverflow(PyTuple_GET_ITEM(open, 5), &ovf[3]);
    of.t = PyFloat_AsDouble(PyTuple_GET_ITEM(open, 6));
    if (PyErr_Occurred() || motion < 0 || dropped < 0) goto done;
    if (ovf[0] || ovf[1] || ovf[2] || ovf[3]) {
        result = Py_NewRef(Py_None);
        goto done;
    }
    of.dx = odx;
    of.dy = ody;
    of.motion = motion;
    of.dropped = dropped;
    of.events = oev;
    of.nonsyn = ons;

    const unsigned char *buf = view.buf;
    Py_ssize_t n = view.len / EVENT_SIZE, whole = n * EVENT_SIZE;
    int64_t st[ST_N];
    memset(st, 0, sizeof st);
    lt = PyList_New(0);
    lx = PyList_New(0);
    ly = PyList_New(0);
    if (lt == NULL || lx == NULL || ly == NULL) goto done;
    int ok = feed_records(buf, n, &of, st, lt, lx, ly);
    if (ok < 0) goto done;
    if (ok == 0) {
        result = Py_NewRef(Py_None);
        goto done;
    }
    PyObject *stats = PyTuple_New(ST_N);
    if (stats == NULL) goto done;
    for (int i = 0; i < ST_N; i++) {
        PyObject *v = PyLong_FromLongLong(st[i]);
        if (v == NULL) {
            Py_DECREF(stats);
            goto done;
        }
        PyTuple_SET_ITEM(stats, i, v);
    }
    result = Py_BuildValue("(OOOy#(LLOOLLd)N)", lt, lx, ly, (const char *)buf + whole,
                           view.len - whole, (long long)of.dx, (long long)of.dy,
                           of.motion ? Py_True : Py_False, of.dropped ? Py_True : Py_False,
                           (long long)of.events, (long long)of.nonsyn, of.t, stats);
done:
    Py_XDECREF(lt);
    Py_XDECREF(lx);
    Py_XDECREF(ly);
    PyBuffer_Release(&view);
    return result;
}

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

/* Sets list[i] to a new float (the list takes the reference and drops the old item's);
 * -1 on error. */
static int set_float(PyObject *list, Py_ssize_t i, double v) {
    PyObject *o = PyFloat_FromDouble(v);
    if (o == NULL) return -1;
    return PyList_SetItem(list, i, o);
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

PyDoc_STRVAR(ingest_small_doc,
"ingest_small(t, dx, dy, kt, kx, ky, knot_t, edge, period, bridge, join)\n"
"    -> (cx, cy, backwards, late, knot_t) or None\n\n"
"CountFunction.ingest_small's loop: the reports (t, dx, dy lists) become knots appended\n"
"to the lists kt, kx, ky (changed in place); returns the counts' sums (int where the\n"
"counts are ints, else float), the reports stamped backwards and behind the edge, and\n"
"the last report's stamp.  None, with the lists untouched, where the lists hold other\n"
"than float times and all-int or all-float counts per axis, or an int sum would leave\n"
"int64 (the caller runs the Python).");

static PyObject *ingest_small(PyObject *self, PyObject *args) {
    (void)self;
    PyObject *t, *dx, *dy, *kt, *kx, *ky;
    double knot_t, edge, period, bridge, join;
    if (!PyArg_ParseTuple(args, "O!O!O!O!O!O!ddddd", &PyList_Type, &t, &PyList_Type, &dx,
                          &PyList_Type, &dy, &PyList_Type, &kt, &PyList_Type, &kx,
                          &PyList_Type, &ky, &knot_t, &edge, &period, &bridge, &join))
        return NULL;
    Py_ssize_t n = PyList_GET_SIZE(t), nk = PyList_GET_SIZE(kt);
    if (n == 0 || PyList_GET_SIZE(dx) != n || PyList_GET_SIZE(dy) != n ||
        PyList_GET_SIZE(kx) != nk || PyList_GET_SIZE(ky) != nk)
        Py_RETURN_NONE;
    for (Py_ssize_t k = 0; k < n; k++)
        if (!PyFloat_CheckExact(PyList_GET_ITEM(t, k))) Py_RETURN_NONE;
    for (Py_ssize_t k = 0; k < nk; k++)
        if (!PyFloat_CheckExact(PyList_GET_ITEM(kt, k)) ||
            !PyFloat_CheckExact(PyList_GET_ITEM(kx, k)) ||
            !PyFloat_CheckExact(PyList_GET_ITEM(ky, k)))
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
            if (set_float(kt, m - 1, ti) < 0 || set_float(kx, m - 1, x) < 0 ||
                set_float(ky, m - 1, y) < 0)
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

static PyMethodDef methods[] = {
    {"feed_bytes", feed_bytes, METH_VARARGS, feed_bytes_doc},
    {"ingest_small", ingest_small, METH_VARARGS, ingest_small_doc},
    {NULL, NULL, 0, NULL},
};

static struct PyModuleDef module = {
    PyModuleDef_HEAD_INIT, "mousedom._core",
    "The compiled core (mousedom.core says whether it runs; the Python is its reference).",
    -1, methods, NULL, NULL, NULL, NULL,
};

PyMODINIT_FUNC PyInit__core(void) { return PyModule_Create(&module); }
