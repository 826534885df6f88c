/* FrameAssembler.feed_bytes (mousedom/sources/events.py) compiled: a read of
 * input_event records into motion frames. */
#include "core.h"

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

const char core_feed_bytes_doc[] = PyDoc_STR(
"feed_bytes(buf, open[, stats, fields]) -> (t, dx, dy, rest, open, added) or None\n\n"
"FrameAssembler.feed_bytes's rules over one read: ``open`` is the frame left open\n"
"(dx, dy, motion, dropped, events, nonsyn, t); returns the motion frames closed in buf\n"
"as three lists, the bytes of a trailing partial record, the frame now open, and what\n"
"to add to each AssemblerStats field in its order.  Given ``stats`` (an AssemblerStats)\n"
"and ``fields`` (its field names in that order), adds them to it instead (``added`` is\n"
"then None).  None, with nothing added, where an int64 would overflow (the caller runs\n"
"the Python).");

/* stats.<fields[i]> += st[i] for each st[i] that is not 0; -1 on a Python error. */
static int add_stats(PyObject *stats, PyObject *fields, const int64_t *st) {
    if (!PyTuple_CheckExact(fields) || PyTuple_GET_SIZE(fields) != ST_N) {
        PyErr_SetString(PyExc_ValueError, "fields: expected a tuple of the 11 stats' names");
        return -1;
    }
    for (int i = 0; i < ST_N; i++) {
        if (st[i] == 0) continue;
        PyObject *name = PyTuple_GET_ITEM(fields, i);
        PyObject *old = PyObject_GetAttr(stats, name);
        if (old == NULL) return -1;
        PyObject *add = PyLong_FromLongLong(st[i]);
        PyObject *sum = add == NULL ? NULL : PyNumber_Add(old, add);
        Py_DECREF(old);
        Py_XDECREF(add);
        if (sum == NULL) return -1;
        int bad = PyObject_SetAttr(stats, name, sum);
        Py_DECREF(sum);
        if (bad < 0) return -1;
    }
    return 0;
}

PyObject *core_feed_bytes(PyObject *self, PyObject *args) {
    (void)self;
    Py_buffer view;
    PyObject *open, *target = NULL, *fields = NULL;
    if (!PyArg_ParseTuple(args, "y*O!|OO", &view, &PyTuple_Type, &open, &target, &fields))
        return NULL;
    if ((target == NULL) != (fields == NULL)) {
        PyErr_SetString(PyExc_TypeError, "feed_bytes: stats and fields go together");
        PyBuffer_Release(&view);
        return NULL;
    }
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
    PyObject *stats;
    if (target != NULL) {
        if (add_stats(target, fields, st) < 0) goto done;
        stats = Py_NewRef(Py_None);
    } else {
        stats = PyTuple_New(ST_N);
        if (stats == NULL) goto done;
        for (int i = 0; i < ST_N; i++) {
            PyObject *v = PyLong_FromLongLong(st[i]);
            if (v == NULL) {
                Py_DECREF(stats);
                goto done;
            }
            PyTuple_SET_ITEM(stats, i, v);
        }
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


/* ---------------------------------------------------------------- a read's stamps */

const char core_forward_list_doc[] = PyDoc_STR(
"forward_list(t, now, last, behind, ahead) -> (far, worst, moved) or None\n\n"
"base.forward_list on a list of floats, in place: stamps outside [now - behind, now +\n"
"ahead] (NaN too) re-stamped to ``now`` (how many, the largest distance, inf for a\n"
"NaN), then each raised to at least the one before, from ``last`` (how many).  None,\n"
"with the list untouched, where it holds other than floats or an argument is not one.");

PyObject *core_forward_list(PyObject *self, PyObject *args) {
    (void)self;
    PyObject *t, *onow, *olast, *obehind, *oahead;
    double now, last, behind, ahead;
    if (!PyArg_ParseTuple(args, "OOOOO", &t, &onow, &olast, &obehind, &oahead)) return NULL;
    if (!PyList_CheckExact(t) || !core_float_of(onow, &now) || !core_float_of(olast, &last) ||
        !core_float_of(obehind, &behind) || !core_float_of(oahead, &ahead) ||
        !core_all_floats(t))
        Py_RETURN_NONE;
    double lo = now - behind, hi = now + ahead, worst = 0.0, run = last;
    Py_ssize_t far = 0, moved = 0, n = PyList_GET_SIZE(t);
    for (Py_ssize_t i = 0; i < n; i++) { /* bound_stamps */
        double v = PyFloat_AS_DOUBLE(PyList_GET_ITEM(t, i));
        if (!(lo <= v && v <= hi)) {
            far++;
            double off = fabs(v - now);
            if (off != off) off = INFINITY;
            if (off > worst) worst = off; /* max(worst, off) */
            if (core_set_float(t, i, now) < 0) return NULL;
        }
    }
    for (Py_ssize_t i = 0; i < n; i++) { /* clamp_list */
        double v = PyFloat_AS_DOUBLE(PyList_GET_ITEM(t, i));
        if (v < run) {
            if (core_set_float(t, i, run) < 0) return NULL;
            moved++;
        } else {
            run = v;
        }
    }
    return Py_BuildValue("(ndn)", far, worst, moved);
}
