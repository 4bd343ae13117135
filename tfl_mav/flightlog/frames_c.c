/* The recorder's frame hot path (issue #13): see frames_c.py for why and how it is held
   to the Python path's bytes. A CPython extension built by tfl_mav.native.obtain_c, which
   defines MODULE_NAME and MODULE_INIT. */
#define PY_SSIZE_T_CLEAN
#include <Python.h>
#include <string.h>
#include <stdint.h>
#include <math.h>

/* The text of one JSON record in progress. */
typedef struct { char *p; Py_ssize_t n, cap; } Text;

static int text_room(Text *t, Py_ssize_t more) {
    if (t->n + more <= t->cap) return 0;
    Py_ssize_t cap = t->cap ? t->cap : 1024;
    while (cap < t->n + more) cap *= 2;
    char *p = PyMem_Realloc(t->p, cap);
    if (!p) { PyErr_NoMemory(); return -1; }
    t->p = p; t->cap = cap;
    return 0;
}

static int text_put(Text *t, const char *s, Py_ssize_t n) {
    if (text_room(t, n) < 0) return -1;
    memcpy(t->p + t->n, s, n);
    t->n += n;
    return 0;
}

static Text out_json = {0, 0, 0};
static Text out_raw = {0, 0, 0};

static uint64_t rd(const unsigned char *p, int size) {
    uint64_t v = 0;
    for (int k = size - 1; k >= 0; k--) v = (v << 8) | p[k];
    return v;
}

static int code_size(char c) {
    switch (c) {
    case 'B': case 'b': return 1;
    case 'H': case 'h': return 2;
    case 'I': case 'i': case 'f': return 4;
    case 'Q': case 'q': case 'd': return 8;
    }
    return 0;
}

/* A value's number: a new reference (a float for f/d, else an int); *bad = 1 if the
   float is NaN/inf. */
static PyObject *number(char c, const unsigned char *p, int *bad) {
    switch (c) {
    case 'B': return PyLong_FromLong(p[0]);
    case 'b': return PyLong_FromLong((int8_t)p[0]);
    case 'H': return PyLong_FromLong((long)rd(p, 2));
    case 'h': return PyLong_FromLong((int16_t)(uint16_t)rd(p, 2));
    case 'I': return PyLong_FromUnsignedLongLong(rd(p, 4));
    case 'i': return PyLong_FromLong((int32_t)(uint32_t)rd(p, 4));
    case 'Q': return PyLong_FromUnsignedLongLong(rd(p, 8));
    case 'q': return PyLong_FromLongLong((long long)rd(p, 8));
    case 'f': { uint32_t u = (uint32_t)rd(p, 4); float f; memcpy(&f, &u, 4);
                if (!isfinite(f)) *bad = 1;
                return PyFloat_FromDouble((double)f); }
    case 'd': { uint64_t u = rd(p, 8); double d; memcpy(&d, &u, 8);
                if (!isfinite(d)) *bad = 1;
                return PyFloat_FromDouble(d); }
    }
    PyErr_SetString(PyExc_ValueError, "layout: type code");
    return NULL;
}

/* A printed number msgspec writes otherwise than repr: an exponent (1e-9 vs 1e-09), or
   positional below 1e-4 (0.00001234 vs 1.234e-05). */
static int odd_text(const char *s, Py_ssize_t n) {
    if (memchr(s, 'e', (size_t)n)) return 1;
    if (n && s[0] == '-') { s++; n--; }
    return n >= 6 && memcmp(s, "0.0000", 6) == 0;
}

/* The message's JSON object from its payload, by the layout (see layout() in Python):
   the numbers printed by one call of msgspec's encoder (``enc``: shortest round-trip
   digits, ~10x faster than repr's dtoa a float), each in repr's notation (re-printed by
   repr where msgspec's differs), between the keys. 1: a NaN/inf value. */
static int put_object(Text *t, const unsigned char *lay, Py_ssize_t lay_n,
                      const unsigned char *pay, PyObject *enc) {
    Py_ssize_t total = 0, i = 0;
    while (i + 6 <= lay_n) {
        int kn = lay[i + 5];
        if (!code_size((char)lay[i])) return 1;
        total += lay[i + 1] | lay[i + 2] << 8;
        i += 6 + kn;
    }
    PyObject *vals = PyTuple_New(total);
    if (!vals) return -1;
    int bad = 0;
    Py_ssize_t j = 0;
    for (i = 0; i + 6 <= lay_n; i += 6 + lay[i + 5]) {
        char c = (char)lay[i];
        int count = lay[i + 1] | lay[i + 2] << 8, off = lay[i + 3] | lay[i + 4] << 8;
        int size = code_size(c);
        for (int k = 0; k < count; k++) {
            PyObject *v = number(c, pay + off + k * size, &bad);
            if (!v) { Py_DECREF(vals); return -1; }
            PyTuple_SET_ITEM(vals, j++, v);
        }
    }
    if (bad) { Py_DECREF(vals); return 1; }
    PyObject *out = PyObject_CallOneArg(enc, vals);
    if (!out || !PyBytes_Check(out)) {
        Py_DECREF(vals); Py_XDECREF(out);
        if (!PyErr_Occurred()) PyErr_SetString(PyExc_TypeError, "encoder: not bytes");
        return -1;
    }
    const char *s = PyBytes_AS_STRING(out), *e = s + PyBytes_GET_SIZE(out);
    int rc = 0;
    if (s < e && *s == '[') s++;
    j = 0;
    for (i = 0; i + 6 <= lay_n && rc == 0; i += 6 + lay[i + 5]) {
        char c = (char)lay[i];
        int count = lay[i + 1] | lay[i + 2] << 8;
        rc = text_put(t, (const char *)lay + i + 6, lay[i + 5]);
        if (rc == 0 && count > 1) rc = text_put(t, "[", 1);
        /* the field's values: one span of msgspec's text */
        const char *q = s;
        int odd = 0;
        for (int k = 0; k < count; k++) {
            if (k) q++;
            if (e - q > 7 && odd_text(q, q[0] == '-' ? 7 : 6)) odd = 1;
            for (; q < e; q++) {
                char ch = *q;
                if (ch == ',' || ch == ']') break;
                if (ch == 'e') odd = 1;
            }
        }
        if (q <= s || q >= e) { rc = 1; break; }       /* not msgspec's list */
        if (rc) break;
        if (!(odd && (c == 'f' || c == 'd'))) {
            rc = text_put(t, s, q - s);                 /* usually: as repr prints them */
            s = q + 1;
            j += count;
        }
        /* else value by value, re-printing by repr those msgspec writes otherwise */
        for (int k = 0; s < q && k < count && rc == 0; k++, j++) {
            const char *v = s;
            while (v < q && *v != ',') v++;
            if (k) rc = text_put(t, ",", 1);
            if (rc) break;
            if (odd_text(s, v - s)) {
                char *r = PyOS_double_to_string(PyFloat_AS_DOUBLE(PyTuple_GET_ITEM(vals, j)),
                                                'r', 0, Py_DTSF_ADD_DOT_0, NULL);
                if (!r) { rc = -1; break; }
                rc = text_put(t, r, (Py_ssize_t)strlen(r));
                PyMem_Free(r);
            } else {
                rc = text_put(t, s, v - s);
            }
            s = v + 1;
        }
        if (rc == 0 && count > 1) rc = text_put(t, "]", 1);
    }
    if (rc == 0 && j != total) rc = 1;
    Py_DECREF(out);
    Py_DECREF(vals);
    return rc == 0 ? text_put(t, "}", 1) : rc;
}

static const char B64[] =
    "ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";

static int put_base64(Text *t, const unsigned char *s, Py_ssize_t n) {
    if (text_room(t, 4 * ((n + 2) / 3)) < 0) return -1;
    char *o = t->p + t->n;
    Py_ssize_t i = 0;
    for (; i + 3 <= n; i += 3) {
        unsigned v = s[i] << 16 | s[i + 1] << 8 | s[i + 2];
        *o++ = B64[v >> 18]; *o++ = B64[(v >> 12) & 63];
        *o++ = B64[(v >> 6) & 63]; *o++ = B64[v & 63];
    }
    if (n - i == 1) {
        unsigned v = s[i] << 16;
        *o++ = B64[v >> 18]; *o++ = B64[(v >> 12) & 63]; *o++ = '='; *o++ = '=';
    } else if (n - i == 2) {
        unsigned v = s[i] << 16 | s[i + 1] << 8;
        *o++ = B64[v >> 18]; *o++ = B64[(v >> 12) & 63]; *o++ = B64[(v >> 6) & 63];
        *o++ = '=';
    }
    t->n = o - t->p;
    return 0;
}

static void le(unsigned char *p, uint64_t v, int size) {
    for (int k = 0; k < size; k++) { p[k] = (unsigned char)(v & 255); v >>= 8; }
}

/* One MCAP message record (FastWriter.add_message's bytes) and its index entry. */
static int add_record(PyObject *buf, PyObject *index, long cid, long long log_ns,
                      long long pub_ns, const Text *data) {
    Py_ssize_t at = PyByteArray_GET_SIZE(buf);
    PyObject *key = PyLong_FromLong(cid);
    if (!key) return -1;
    PyObject *flat = PyDict_GetItemWithError(index, key);
    if (!flat) {
        if (PyErr_Occurred()) { Py_DECREF(key); return -1; }
        flat = PyList_New(0);
        if (!flat || PyDict_SetItem(index, key, flat) < 0) {
            Py_XDECREF(flat); Py_DECREF(key); return -1;
        }
        Py_DECREF(flat);       /* the dict holds it */
    }
    Py_DECREF(key);
    if (!PyList_Check(flat)) { PyErr_SetString(PyExc_TypeError, "index entry"); return -1; }
    PyObject *a = PyLong_FromLongLong(log_ns), *b = PyLong_FromSsize_t(at);
    int rc = (!a || !b) ? -1 : PyList_Append(flat, a);
    if (rc == 0) rc = PyList_Append(flat, b);
    Py_XDECREF(a); Py_XDECREF(b);
    if (rc < 0) return -1;
    if (PyByteArray_Resize(buf, at + 31 + data->n) < 0) return -1;
    unsigned char *o = (unsigned char *)PyByteArray_AS_STRING(buf) + at;
    o[0] = 0x05;                               /* opcode: Message */
    le(o + 1, (uint64_t)(22 + data->n), 8);    /* record length */
    le(o + 9, (uint64_t)cid, 2);               /* channel id */
    le(o + 11, 0, 4);                          /* sequence */
    le(o + 15, (uint64_t)log_ns, 8);
    le(o + 23, (uint64_t)pub_ns, 8);
    memcpy(o + 31, data->p, data->n);
    return 0;
}

/* After a record: past the chunk limit, end the chunk and re-read buf and index. */
static int chunk_check(PyObject **buf, PyObject **index, PyObject *chunk,
                       PyObject *end_chunk, Py_ssize_t limit) {
    if (PyByteArray_GET_SIZE(*buf) <= limit) return 0;
    PyObject *r = PyObject_CallNoArgs(end_chunk);
    if (!r) return -1;
    Py_DECREF(r);
    PyObject *b = PyObject_GetAttrString(chunk, "buf");
    PyObject *x = b ? PyObject_GetAttrString(chunk, "index") : NULL;
    if (!x || !PyByteArray_Check(b) || !PyDict_Check(x)) {
        Py_XDECREF(b); Py_XDECREF(x);
        if (!PyErr_Occurred()) PyErr_SetString(PyExc_TypeError, "chunk buf/index");
        return -1;
    }
    Py_SETREF(*buf, b);
    Py_SETREF(*index, x);
    return 0;
}

#define MAX_NS 9223372036854775807LL


/* frames(items, start, fast, chunk, end_chunk, limit, state, enc, decoded_next) -> index of
   the first item not written (len(items) when all were). items: (any, time_s, direction,
   raw, accepted); fast: frame key -> (layout, head, rx, raw_cid, cid, time_off, size);
   state: [sim_ns, sim_known, n_rx, n_tx, i, epoch_ns, sim_timeline, period_ns, decoded],
   updated after every frame written; when an error is raised state[4] is the frame it was
   raised on (the caller's counts stay right). sim_timeline 1: once sim time is known,
   log_time = epoch_ns + sim time, epoch_ns (-1: not yet) set from the first such frame's
   receipt time (McapOutput._on_timeline). decoded_next: cid -> sim ns from which its next
   decoded record may be written (then + period_ns); before sim time is known, always
   (FrameRecorder._frames_py, the same decisions). */
static PyObject *frames(PyObject *self, PyObject *const *args, Py_ssize_t nargs) {
    if (nargs != 9) { PyErr_SetString(PyExc_TypeError, "frames: 9 arguments"); return NULL; }
    PyObject *items = args[0], *fast = args[2], *chunk = args[3], *end_chunk = args[4];
    PyObject *state = args[6], *enc = args[7], *next = args[8];
    Py_ssize_t i = PyLong_AsSsize_t(args[1]), limit = PyLong_AsSsize_t(args[5]);
    if (PyErr_Occurred()) return NULL;
    if (!PyList_Check(items) && !PyTuple_Check(items)) {
        PyErr_SetString(PyExc_TypeError, "frames: items"); return NULL;
    }
    if (!PyDict_Check(fast) || !PyDict_Check(next) || !PyList_Check(state)
        || PyList_GET_SIZE(state) != 9) {
        PyErr_SetString(PyExc_TypeError, "frames: fast or state"); return NULL;
    }
    long long sim_ns = PyLong_AsLongLong(PyList_GET_ITEM(state, 0));
    if (sim_ns == -1 && PyErr_Occurred()) return NULL;
    long long epoch_ns = PyLong_AsLongLong(PyList_GET_ITEM(state, 5));
    if (epoch_ns == -1 && PyErr_Occurred()) return NULL;
    long sim_timeline = PyLong_AsLong(PyList_GET_ITEM(state, 6));
    if (sim_timeline == -1 && PyErr_Occurred()) return NULL;
    long long period_ns = PyLong_AsLongLong(PyList_GET_ITEM(state, 7));
    if (period_ns == -1 && PyErr_Occurred()) return NULL;
    PyObject *buf = PyObject_GetAttrString(chunk, "buf");
    PyObject *index = buf ? PyObject_GetAttrString(chunk, "index") : NULL;
    if (!index || !PyByteArray_Check(buf) || !PyDict_Check(index)) {
        Py_XDECREF(buf); Py_XDECREF(index);
        if (!PyErr_Occurred()) PyErr_SetString(PyExc_TypeError, "frames: chunk");
        return NULL;
    }
    Py_ssize_t n_items = PySequence_Fast_GET_SIZE(items);
    PyObject **item = PySequence_Fast_ITEMS(items);
    int failed = 0;
    unsigned char pay[256];
    for (; i < n_items; i++) {
        PyObject *f = item[i];
        if (!PyTuple_Check(f) || PyTuple_GET_SIZE(f) != 5) break;
        PyObject *ts = PyTuple_GET_ITEM(f, 1), *dir = PyTuple_GET_ITEM(f, 2);
        PyObject *raw = PyTuple_GET_ITEM(f, 3), *acc = PyTuple_GET_ITEM(f, 4);
        if (!PyFloat_CheckExact(ts) || !PyBytes_CheckExact(raw) || !PyUnicode_Check(dir))
            break;
        int ok = PyObject_IsTrue(acc);
        if (ok < 0) { failed = 1; break; }
        if (!ok) break;
        int rx;
        if (PyUnicode_CompareWithASCIIString(dir, "rx") == 0) rx = 1;
        else if (PyUnicode_CompareWithASCIIString(dir, "tx") == 0) rx = 0;
        else break;
        const unsigned char *r = (const unsigned char *)PyBytes_AS_STRING(raw);
        Py_ssize_t n = PyBytes_GET_SIZE(raw);
        if (n < 12) break;
        long long key = rx | r[5] << 1 | (long long)r[6] << 9
                        | (long long)(r[7] | r[8] << 8 | r[9] << 16) << 17;
        PyObject *k = PyLong_FromLongLong(key);
        if (!k) { failed = 1; break; }
        PyObject *e = PyDict_GetItemWithError(fast, k);
        Py_DECREF(k);
        if (!e) { if (PyErr_Occurred()) failed = 1; break; }
        if (!PyTuple_Check(e) || PyTuple_GET_SIZE(e) != 7) break;
        PyObject *lay = PyTuple_GET_ITEM(e, 0), *head = PyTuple_GET_ITEM(e, 1);
        if (!PyBytes_Check(lay) || !PyBytes_Check(head)) break;
        long raw_cid = PyLong_AsLong(PyTuple_GET_ITEM(e, 3));
        long cid = PyLong_AsLong(PyTuple_GET_ITEM(e, 4));
        long time_off = PyLong_AsLong(PyTuple_GET_ITEM(e, 5));
        long size = PyLong_AsLong(PyTuple_GET_ITEM(e, 6));
        if (PyErr_Occurred()) { PyErr_Clear(); break; }
        if (size < 0 || size > (long)sizeof pay || raw_cid < 0 || raw_cid > 65535
            || cid < 0 || cid > 65535) break;
        /* the payload, as raw[10:n - 15 if signed else n - 2], zero-padded to size */
        Py_ssize_t end = n - ((r[2] & 1) ? 15 : 2);
        if (end < 0) end += n;
        if (end < 0) end = 0;
        Py_ssize_t plen = end > 10 ? end - 10 : 0;
        if (plen > size) plen = size;
        memset(pay, 0, (size_t)size);
        memcpy(pay, r + 10, (size_t)plen);
        double v = PyFloat_AS_DOUBLE(ts) * 1e9;
        if (!(v > -1.0 && v < 9223372036854775808.0)) break;
        long long log_ns = (long long)v;
        if (time_off >= 0) {
            if (time_off + 8 > size) break;
            uint64_t usec = rd(pay + time_off, 8);
            if (usec <= (uint64_t)(MAX_NS / 1000)) {
                sim_ns = (long long)usec * 1000;
                PyObject *s = PyLong_FromLongLong(sim_ns);
                if (!s) { failed = 1; break; }
                PyList_SetItem(state, 0, s);
                Py_INCREF(Py_True);
                PyList_SetItem(state, 1, Py_True);
            }
        }
        if (sim_timeline && PyList_GET_ITEM(state, 1) == Py_True) {
            if (epoch_ns < 0) {
                epoch_ns = log_ns - sim_ns;
                PyObject *ep = PyLong_FromLongLong(epoch_ns);
                if (!ep) { failed = 1; break; }
                PyList_SetItem(state, 5, ep);
            }
            __int128 t = (__int128)epoch_ns + sim_ns;     /* as Python: no overflow */
            log_ns = t < 0 ? 0 : t > MAX_NS ? MAX_NS : (long long)t;
        }
        /* the decoded record at most once a period of sim time (the raw one always) */
        int keep = PyList_GET_ITEM(state, 1) != Py_True;
        PyObject *cid_obj = PyTuple_GET_ITEM(e, 4);
        if (!keep) {
            PyObject *nx = PyDict_GetItemWithError(next, cid_obj);
            if (!nx && PyErr_Occurred()) { failed = 1; break; }
            long long due = nx ? PyLong_AsLongLong(nx) : -1;
            if (due == -1 && PyErr_Occurred()) { failed = 1; break; }
            keep = sim_ns >= due;
        }
        if (keep) {
            out_json.n = 0;
            int rc = put_object(&out_json, (const unsigned char *)PyBytes_AS_STRING(lay),
                                PyBytes_GET_SIZE(lay), pay, enc);
            if (rc < 0) { failed = 1; break; }
            if (rc > 0) break;                  /* NaN/inf: the Python plan's */
        }
        out_raw.n = 0;
        char num[64];
        int m = snprintf(num, sizeof num, "%d,\"len\":%zd,\"data\":\"", r[4], n);
        if (text_put(&out_raw, PyBytes_AS_STRING(head), PyBytes_GET_SIZE(head)) < 0
            || text_put(&out_raw, num, m) < 0 || put_base64(&out_raw, r, n) < 0
            || text_put(&out_raw, "\"}", 2) < 0) { failed = 1; break; }
        if (add_record(buf, index, raw_cid, log_ns, sim_ns, &out_raw) < 0
            || chunk_check(&buf, &index, chunk, end_chunk, limit) < 0) {
            failed = 1; break;
        }
        if (keep) {
            if (add_record(buf, index, cid, log_ns, sim_ns, &out_json) < 0
                || chunk_check(&buf, &index, chunk, end_chunk, limit) < 0) {
                failed = 1; break;
            }
            __int128 nxt = (__int128)sim_ns + period_ns;      /* as Python: min(., MAX) */
            PyObject *due = PyLong_FromLongLong(nxt > MAX_NS ? MAX_NS : (long long)nxt);
            if (!due || PyDict_SetItem(next, cid_obj, due) < 0) {
                Py_XDECREF(due); failed = 1; break;
            }
            Py_DECREF(due);
            long long nd = PyLong_AsLongLong(PyList_GET_ITEM(state, 8));
            PyObject *d = (nd == -1 && PyErr_Occurred()) ? NULL : PyLong_FromLongLong(nd + 1);
            if (!d) { failed = 1; break; }
            PyList_SetItem(state, 8, d);
        }
        Py_ssize_t slot = rx ? 2 : 3;
        long long count = PyLong_AsLongLong(PyList_GET_ITEM(state, slot));
        PyObject *c = (count == -1 && PyErr_Occurred()) ? NULL
                      : PyLong_FromLongLong(count + 1);
        if (!c) { failed = 1; break; }
        PyList_SetItem(state, slot, c);
    }
    Py_DECREF(buf);
    Py_DECREF(index);
    if (failed) {
        PyObject *t, *v, *tb;                  /* the error stays raised */
        PyErr_Fetch(&t, &v, &tb);
        PyObject *at = PyLong_FromSsize_t(i);
        if (at) PyList_SetItem(state, 4, at);
        else PyErr_Clear();
        PyErr_Restore(t, v, tb);
        return NULL;
    }
    return PyLong_FromSsize_t(i);
}

/* records(chunk, end_chunk, limit, log_ns, pub_ns, values, layouts, enc) -> records
   written, or None (a value is NaN/inf or not a plain number: nothing written, the
   caller's careful path). values: the numbers (floats and ints, no bools), printed by one
   msgspec call (``enc``) in repr's notation; layouts: per record (channel id, pieces,
   indices): its JSON is pieces[0] + value[indices[0]] + pieces[1] + ... + pieces[-1].
   The records as FastWriter.add_same_time writes them (a chunk may end between them). */
static PyObject *records(PyObject *self, PyObject *const *args, Py_ssize_t nargs) {
    if (nargs != 8) { PyErr_SetString(PyExc_TypeError, "records: 8 arguments"); return NULL; }
    PyObject *chunk = args[0], *end_chunk = args[1], *values = args[5], *layouts = args[6];
    PyObject *enc = args[7];
    Py_ssize_t limit = PyLong_AsSsize_t(args[2]);
    long long log_ns = PyLong_AsLongLong(args[3]), pub_ns = PyLong_AsLongLong(args[4]);
    if (PyErr_Occurred()) return NULL;
    if (!PyTuple_Check(values) || !PyTuple_Check(layouts)) {
        PyErr_SetString(PyExc_TypeError, "records: values, layouts"); return NULL;
    }
    Py_ssize_t n = PyTuple_GET_SIZE(values);
    for (Py_ssize_t k = 0; k < n; k++) {
        PyObject *v = PyTuple_GET_ITEM(values, k);
        if (PyFloat_CheckExact(v)) {
            if (!isfinite(PyFloat_AS_DOUBLE(v))) Py_RETURN_NONE;
        } else if (!PyLong_CheckExact(v)) {
            Py_RETURN_NONE;                      /* bools, numpy values: the careful path */
        }
    }
    PyObject *out = PyObject_CallOneArg(enc, values);
    if (!out) return NULL;
    if (!PyBytes_Check(out)) { Py_DECREF(out); Py_RETURN_NONE; }
    /* each value's text: [start, end) in out, or a repr re-print */
    const char *s = PyBytes_AS_STRING(out), *e = s + PyBytes_GET_SIZE(out);
    Py_ssize_t *span = PyMem_Malloc(sizeof(Py_ssize_t) * 2 * (n ? n : 1));
    char **fixed = PyMem_Calloc(n ? n : 1, sizeof(char *));
    PyObject *result = NULL;
    PyObject *buf = NULL, *index = NULL;
    if (!span || !fixed) { PyErr_NoMemory(); goto done; }
    const char *p = s < e && *s == '[' ? s + 1 : s;
    for (Py_ssize_t k = 0; k < n; k++) {
        const char *q = p;
        while (q < e && *q != ',' && *q != ']') q++;
        if (q == p || q == e) { result = Py_NewRef(Py_None); goto done; }
        span[2 * k] = p - s;
        span[2 * k + 1] = q - s;
        PyObject *v = PyTuple_GET_ITEM(values, k);
        if (PyFloat_CheckExact(v) && odd_text(p, q - p)) {
            fixed[k] = PyOS_double_to_string(PyFloat_AS_DOUBLE(v), 'r', 0,
                                             Py_DTSF_ADD_DOT_0, NULL);
            if (!fixed[k]) goto done;
        }
        p = q + 1;
    }
    buf = PyObject_GetAttrString(chunk, "buf");
    index = buf ? PyObject_GetAttrString(chunk, "index") : NULL;
    if (!index || !PyByteArray_Check(buf) || !PyDict_Check(index)) {
        if (!PyErr_Occurred()) PyErr_SetString(PyExc_TypeError, "records: chunk");
        goto done;
    }
    Py_ssize_t written = 0;
    for (Py_ssize_t r = 0; r < PyTuple_GET_SIZE(layouts); r++) {
        PyObject *lay = PyTuple_GET_ITEM(layouts, r);
        if (!PyTuple_Check(lay) || PyTuple_GET_SIZE(lay) != 3) {
            PyErr_SetString(PyExc_TypeError, "records: layout"); goto done;
        }
        long cid = PyLong_AsLong(PyTuple_GET_ITEM(lay, 0));
        PyObject *pieces = PyTuple_GET_ITEM(lay, 1), *idx = PyTuple_GET_ITEM(lay, 2);
        if (PyErr_Occurred()) goto done;
        if (!PyTuple_Check(pieces) || !PyTuple_Check(idx)
            || PyTuple_GET_SIZE(pieces) != PyTuple_GET_SIZE(idx) + 1) {
            PyErr_SetString(PyExc_TypeError, "records: pieces, indices"); goto done;
        }
        out_json.n = 0;
        for (Py_ssize_t j = 0; j <= PyTuple_GET_SIZE(idx); j++) {
            PyObject *piece = PyTuple_GET_ITEM(pieces, j);
            if (!PyBytes_Check(piece)) {
                PyErr_SetString(PyExc_TypeError, "records: piece"); goto done;
            }
            if (text_put(&out_json, PyBytes_AS_STRING(piece), PyBytes_GET_SIZE(piece)) < 0)
                goto done;
            if (j == PyTuple_GET_SIZE(idx)) break;
            Py_ssize_t k = PyLong_AsSsize_t(PyTuple_GET_ITEM(idx, j));
            if (k < 0 || k >= n) {
                if (!PyErr_Occurred()) PyErr_SetString(PyExc_IndexError, "records: index");
                goto done;
            }
            int rc = fixed[k] ? text_put(&out_json, fixed[k], (Py_ssize_t)strlen(fixed[k]))
                              : text_put(&out_json, s + span[2 * k],
                                         span[2 * k + 1] - span[2 * k]);
            if (rc < 0) goto done;
        }
        if (add_record(buf, index, cid, log_ns, pub_ns, &out_json) < 0
            || chunk_check(&buf, &index, chunk, end_chunk, limit) < 0) goto done;
        written++;
    }
    result = PyLong_FromSsize_t(written);
done:
    if (fixed) for (Py_ssize_t k = 0; k < n; k++) if (fixed[k]) PyMem_Free(fixed[k]);
    PyMem_Free(fixed);
    PyMem_Free(span);
    Py_XDECREF(buf);
    Py_XDECREF(index);
    Py_DECREF(out);
    return result;
}

static PyMethodDef methods[] = {
    {"frames", (PyCFunction)(void (*)(void))frames, METH_FASTCALL, "the frame hot path"},
    {"records", (PyCFunction)(void (*)(void))records, METH_FASTCALL,
     "records of numbers with the same times"},
    {NULL, NULL, 0, NULL}
};

static struct PyModuleDef module = {PyModuleDef_HEAD_INIT, MODULE_NAME, NULL, -1, methods};

PyMODINIT_FUNC MODULE_INIT(void) { return PyModule_Create(&module); }
