/* The module mousedom._core: its table of functions (core.h says what the core is). */
#include "core.h"

#define ENTRY(name) {#name, core_##name, METH_VARARGS, core_##name##_doc}

static PyMethodDef methods[] = {
    ENTRY(feed_bytes), ENTRY(forward_list), ENTRY(ingest_small), ENTRY(close_knots),
    ENTRY(body_counts), ENTRY(linear), ENTRY(advance), ENTRY(steady_window), ENTRY(pose_line),
    ENTRY(evemu_events),
    {NULL, NULL, 0, NULL},
};

static struct PyModuleDef module = {
    PyModuleDef_HEAD_INIT, "mousedom._core",
    "The compiled core (mousedom.core says whether it runs; the Python is its reference).",
    -1, methods, NULL, NULL, NULL, NULL,
};

PyMODINIT_FUNC PyInit__core(void) { return PyModule_Create(&module); }

int core_set_float(PyObject *list, Py_ssize_t i, double v) {
    PyObject *o = PyFloat_FromDouble(v);
    if (o == NULL) return -1;
    return PyList_SetItem(list, i, o);
}

PyObject *core_float_list(const double *v, Py_ssize_t n) {
    PyObject *list = PyList_New(n);
    if (list == NULL) return NULL;
    for (Py_ssize_t i = 0; i < n; i++) {
        PyObject *o = PyFloat_FromDouble(v[i]);
        if (o == NULL) {
            Py_DECREF(list);
            return NULL;
        }
        PyList_SET_ITEM(list, i, o);
    }
    return list;
}

int core_all_floats(PyObject *list) {
    for (Py_ssize_t k = 0; k < PyList_GET_SIZE(list); k++)
        if (!PyFloat_CheckExact(PyList_GET_ITEM(list, k))) return 0;
    return 1;
}

int core_float_of(PyObject *o, double *v) {
    if (!PyFloat_CheckExact(o)) return 0;
    *v = PyFloat_AS_DOUBLE(o);
    return 1;
}

int core_floats_of(PyObject *seq, double *v, Py_ssize_t n) {
    if (!(PyList_CheckExact(seq) || PyTuple_CheckExact(seq)) || PySequence_Fast_GET_SIZE(seq) != n)
        return 0;
    PyObject **items = PySequence_Fast_ITEMS(seq);
    for (Py_ssize_t k = 0; k < n; k++) {
        if (!PyFloat_CheckExact(items[k])) return 0;
        v[k] = PyFloat_AS_DOUBLE(items[k]);
    }
    return 1;
}

int core_matrix3_of(PyObject *seq, double m[3][3]) {
    if (!(PyList_CheckExact(seq) || PyTuple_CheckExact(seq)) || PySequence_Fast_GET_SIZE(seq) != 3)
        return 0;
    for (int i = 0; i < 3; i++)
        if (!core_floats_of(PySequence_Fast_GET_ITEM(seq, i), m[i], 3)) return 0;
    return 1;
}
