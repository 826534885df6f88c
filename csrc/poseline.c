/* The daemon's POSE line (mousedom/service/protocol.py encode_pose) compiled: the same
 * bytes, floats written as float.__repr__ writes them (PyOS_double_to_string, 'r': what
 * repr() and %r call), where every number is finite and there is no gyro. */
#include "core.h"

/* The line's text around its values, in order; a value goes after each. */
static const char *const TEXT[] = {
    "{\"class\":\"POSE\",\"t\":", ",\"x\":", ",\"y\":", ",\"theta\":", ",\"vx\":",
    ",\"vy\":", ",\"omega\":", ",\"cov\":[[", ",", ",", "],[", ",", ",", "],[", ",", ",",
    "]],\"used\":", ",\"updating\":", ",\"missing\":", ",\"excluded\":", ",\"suspect\":",
    ",\"consistent\":", "}\n",
};
enum { N_FLOATS = 16, N_TEXT = sizeof(TEXT) / sizeof(TEXT[0]) };

typedef struct {
    char *at, *end;
} Out;

/* Appends n bytes; -1 where they would not fit (the caller sized the buffer: a bug). */
static int put(Out *o, const char *s, size_t n) {
    if ((size_t)(o->end - o->at) < n) return -1;
    memcpy(o->at, s, n);
    o->at += n;
    return 0;
}

/* A float as repr writes it; -1 on error (memory, or no room). */
static int put_repr(Out *o, double v) {
    char *s = PyOS_double_to_string(v, 'r', 0, Py_DTSF_ADD_DOT_0, NULL);
    if (s == NULL) return -1;
    int bad = put(o, s, strlen(s));
    PyMem_Free(s);
    return bad;
}

/* A str's UTF-8 (what str.encode gives) into *s, *n: 1, or 0 where it is not a str
 * (exactly) or cannot be encoded (the Python's encode would raise). */
static int utf8_of(PyObject *o, const char **s, Py_ssize_t *n) {
    if (!PyUnicode_CheckExact(o)) return 0;
    *s = PyUnicode_AsUTF8AndSize(o, n);
    if (*s == NULL) {
        PyErr_Clear();
        return 0;
    }
    return 1;
}

const char core_pose_line_doc[] = PyDoc_STR(
"pose_line(t, pose, twist, cov, used, updating, missing, excluded, suspect, consistent)\n"
"    -> bytes or None\n\n"
"protocol.encode_pose's line without a gyro, t already rounded; missing, excluded and\n"
"suspect as JSON text (protocol._json_names).  None (declined: the caller runs the\n"
"Python) where a number is not finite (the Python writes null) or an argument is not of\n"
"the types the daemon hands it: exact floats, 3-lists or tuples, an exact int, bools.");

PyObject *core_pose_line(PyObject *self, PyObject *args) {
    (void)self;
    PyObject *ot, *opose, *otwist, *ocov, *oused, *oupdating, *onames[3], *oconsistent;
    if (!PyArg_ParseTuple(args, "OOOOOOOOOO", &ot, &opose, &otwist, &ocov, &oused, &oupdating,
                          &onames[0], &onames[1], &onames[2], &oconsistent))
        return NULL;
    double v[N_FLOATS];
    if (!core_float_of(ot, &v[0]) || !core_floats_of(opose, v + 1, 3) ||
        !core_floats_of(otwist, v + 4, 3))
        Py_RETURN_NONE;
    double cov[3][3];
    if (!core_matrix3_of(ocov, cov)) Py_RETURN_NONE;
    memcpy(v + 7, cov, sizeof cov);
    for (int k = 0; k < N_FLOATS; k++)
        if (!isfinite(v[k])) Py_RETURN_NONE;
    if (!PyLong_CheckExact(oused) || !PyBool_Check(oupdating) || !PyBool_Check(oconsistent))
        Py_RETURN_NONE;
    int ovf = 0;
    long long used = PyLong_AsLongLongAndOverflow(oused, &ovf);
    if (ovf || (used == -1 && PyErr_Occurred())) {
        PyErr_Clear();
        Py_RETURN_NONE;
    }
    const char *names[3];
    Py_ssize_t lengths[3];
    size_t size = 0;
    for (int k = 0; k < 3; k++) {
        if (!utf8_of(onames[k], &names[k], &lengths[k])) Py_RETURN_NONE;
        size += (size_t)lengths[k];
    }
    /* The fixed text, 16 floats of at most 24 characters, an int64, two bools */
    size += 512 + N_FLOATS * 32;
    char *buf = PyMem_Malloc(size);
    if (buf == NULL) return PyErr_NoMemory();
    Out o = {buf, buf + size};
    char used_text[24];
    int used_n = snprintf(used_text, sizeof used_text, "%lld", used);
    int bad = 0;
    for (int k = 0; k < N_TEXT && !bad; k++) {
        bad = put(&o, TEXT[k], strlen(TEXT[k]));
        if (bad) break;
        if (k < N_FLOATS) {
            bad = put_repr(&o, v[k]);
        } else if (k == N_FLOATS) {
            bad = put(&o, used_text, (size_t)used_n);
        } else if (k == N_FLOATS + 1) {
            bad = put(&o, oupdating == Py_True ? "true" : "false", oupdating == Py_True ? 4 : 5);
        } else if (k < N_FLOATS + 5) {
            int j = k - N_FLOATS - 2;
            bad = put(&o, names[j], (size_t)lengths[j]);
        } else if (k == N_FLOATS + 5) {
            bad = put(&o, oconsistent == Py_True ? "true" : "false",
                      oconsistent == Py_True ? 4 : 5);
        }
    }
    PyObject *line = NULL;
    if (!bad)
        line = PyBytes_FromStringAndSize(buf, o.at - buf);
    else if (!PyErr_Occurred())
        PyErr_SetString(PyExc_SystemError, "pose_line: the buffer was sized too small");
    PyMem_Free(buf);
    return line;
}
