/* evemu_lines.general_events (mousedom/capture/evemu_lines.py) compiled: a block of whole
 * "E: sec.frac type code value" lines into event columns, in one pass over its bytes.
 * It takes exactly the lines general_events takes and declines (None) every block that
 * one refuses, so that the careful line parser still names the first bad line. */
#include "core.h"

/* general_events' blanks: space, tab, carriage return (_WS). */
static int blank(unsigned char c) { return c == ' ' || c == '\t' || c == '\r'; }

static int hex_digit(unsigned char c) {
    if (c >= '0' && c <= '9') return c - '0';
    if (c >= 'a' && c <= 'f') return c - 'a' + 10;
    if (c >= 'A' && c <= 'F') return c - 'A' + 10;
    return -1;
}

/* _digits for one field b[begin, end): its value in ``base``, or -1 when it is empty,
 * wider than ``width`` or holds a character that is not a digit (widths of at most 12
 * decimal digits: no overflow). */
static int64_t digits(const unsigned char *b, Py_ssize_t begin, Py_ssize_t end, int base,
                      Py_ssize_t width) {
    if (end - begin < 1 || end - begin > width) return -1;
    int64_t v = 0;
    for (Py_ssize_t i = begin; i < end; i++) {
        int d = base == 16 ? hex_digit(b[i]) : (b[i] >= '0' && b[i] <= '9' ? b[i] - '0' : -1);
        if (d < 0) return -1;
        v = v * base + d;
    }
    return v;
}

/* One line b[s, nl) (nl: its newline) into the four columns at row r: 1, or 0 where
 * general_events would refuse it (and so the block). */
static int event_line(const unsigned char *b, Py_ssize_t s, Py_ssize_t nl, double *t,
                      int64_t *typ, int64_t *code, int64_t *value, int *w_usec) {
    if (nl - s < 11 || b[s] != 'E' || b[s + 1] != ':' || b[s + 2] != ' ') return 0;
    /* the first three blanks from s + 3 on, all before the newline and all spaces */
    Py_ssize_t sep[3], k = 0;
    for (Py_ssize_t i = s + 3; i < nl && k < 3; i++)
        if (blank(b[i])) sep[k++] = i;
    if (k < 3) return 0;
    for (int j = 0; j < 3; j++)
        if (b[sep[j]] != ' ') return 0;
    /* the first point from s + 3 on, before the first blank */
    Py_ssize_t dot = -1;
    for (Py_ssize_t i = s + 3; i < sep[0]; i++)
        if (b[i] == '.') {
            dot = i;
            break;
        }
    if (dot < 0) return 0;
    /* the value ends at the next blank or the newline; after it blanks, then optionally
     * a comment from the first "#" on */
    Py_ssize_t vend = sep[2] + 1;
    while (vend < nl && !blank(b[vend])) vend++;
    Py_ssize_t i = vend;
    while (i < nl && blank(b[i])) i++;
    if (i < nl && b[i] != '#') return 0;
    int64_t sec = digits(b, s + 3, dot, 10, 12);
    int64_t frac = digits(b, dot + 1, sep[0], 10, 9);
    int64_t ty = digits(b, sep[0] + 1, sep[1], 16, 4);
    int64_t co = digits(b, sep[1] + 1, sep[2], 16, 4);
    int neg = b[sep[2] + 1] == '-', pos = b[sep[2] + 1] == '+';
    int64_t v = digits(b, sep[2] + 1 + (neg | pos), vend, 10, 10);
    if (sec < 0 || frac < 0 || ty < 0 || co < 0 || v < 0) return 0;
    if (neg) v = -v;
    if (v < -((int64_t)1 << 31) || v >= ((int64_t)1 << 31)) return 0;
    *w_usec = (int)(sep[0] - dot - 1);
    /* sec + usec / 10**w, the numpy operations' order: both exact in a double here */
    static const double pow10[10] = {1e0, 1e1, 1e2, 1e3, 1e4, 1e5, 1e6, 1e7, 1e8, 1e9};
    *t = (double)sec + (double)frac / pow10[*w_usec];
    *typ = ty;
    *code = co;
    *value = v;
    return 1;
}

const char core_evemu_events_doc[] = PyDoc_STR(
"evemu_events(block, t, typ, code, value) -> n or None\n\n"
"evemu_lines.general_events: the block's n lines into the first n items of the float64\n"
"array t and the int64 arrays typ, code and value (each of at least len(block) // 12\n"
"items), or None where general_events refuses the block.");

PyObject *core_evemu_events(PyObject *self, PyObject *args) {
    (void)self;
    Py_buffer in, out[4];
    if (!PyArg_ParseTuple(args, "y*w*w*w*w*", &in, &out[0], &out[1], &out[2], &out[3]))
        return NULL;
    const unsigned char *b = in.buf;
    Py_ssize_t len = in.len, cap = len / 12, n = 0;
    PyObject *result = NULL;
    for (int j = 0; j < 4; j++)
        if (out[j].len / 8 < cap) {
            PyErr_SetString(PyExc_ValueError, "evemu_events: an output array is too short");
            goto done;
        }
    double *t = out[0].buf;
    int64_t *typ = out[1].buf, *code = out[2].buf, *value = out[3].buf;
    /* a block of whole lines: it ends with a newline (line_bounds) */
    if (len == 0 || b[len - 1] != '\n') goto decline;
    int w_usec = 0; /* (usec / 1e6 where all are six digits: the same division) */
    for (Py_ssize_t s = 0; s < len; n++) {
        const unsigned char *end = memchr(b + s, '\n', (size_t)(len - s));
        Py_ssize_t nl = end - b; /* found: the block ends with one */
        if (n >= cap || !event_line(b, s, nl, &t[n], &typ[n], &code[n], &value[n], &w_usec))
            goto decline;
        s = nl + 1;
    }
    result = PyLong_FromSsize_t(n);
    goto done;
decline:
    result = Py_NewRef(Py_None);
done:
    PyBuffer_Release(&in);
    for (int j = 0; j < 4; j++) PyBuffer_Release(&out[j]);
    return result;
}
