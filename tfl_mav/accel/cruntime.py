"""The C the translated functions call (:mod:`ctranslate`): reading arguments, and CPython's
own answers where libm's differ.

* ``tfl_double``: a number argument's value (an int's or a bool's without a float made).
* ``tfl_fast``, ``tfl_unpack``: a sequence argument's floats, read in place from a tuple (a
  NamedTuple too) or list, through the buffer of a float64 array, or through
  ``PySequence_Fast``; anything else declines (the Python then runs).
* ``tfl_atan2``: CPython's ``math.atan2`` (its answers for NaN, ±inf and ±0, libm's
  otherwise).
* ``tfl_hypot``: ``math.hypot`` itself, called (CPython's vector_norm is not libm's hypot).
* ``tfl_frozen``: an argument whose numbers cannot change (its unpacking remembered).
* ``tfl_float``: a result's float object; +0.0 and 1.0 (a third of a TFL tick's ~100
  results: flags, idle observers) are one shared object each instead of a new one per call.
"""

from __future__ import annotations

__all__ = ["PRELUDE"]

PRELUDE = r"""
/* The float objects +0.0 and 1.0, made once by the module's init (tfl_init_floats). Floats
   are immutable: a shared one is the same value as a new one; only its identity differs. */
static PyObject *tfl_zero = NULL;
static PyObject *tfl_one = NULL;

static int
tfl_init_floats(void)
{
    tfl_zero = PyFloat_FromDouble(0.0);
    tfl_one = PyFloat_FromDouble(1.0);
    return tfl_zero != NULL && tfl_one != NULL ? 0 : -1;
}

/* A result's float: the shared +0.0 or 1.0 (−0.0, which compares equal to 0.0, is made
   apart: its sign bit is part of the value), else a new float. */
static inline PyObject *
tfl_float(double x)
{
    if (x == 0.0 && !signbit(x)) {
        Py_INCREF(tfl_zero);
        return tfl_zero;
    }
    if (x == 1.0) {
        Py_INCREF(tfl_one);
        return tfl_one;
    }
    return PyFloat_FromDouble(x);
}

/* math.hypot is CPython's own algorithm (vector_norm), not libm's hypot: call it. */
static PyObject *tfl_py_hypot = NULL;

static int
tfl_hypot(double a, double b, double *out)
{
    PyObject *args[2] = {PyFloat_FromDouble(a), PyFloat_FromDouble(b)};
    PyObject *r = NULL;
    if (args[0] != NULL && args[1] != NULL)
        r = PyObject_Vectorcall(tfl_py_hypot, args, 2, NULL);
    Py_XDECREF(args[0]);
    Py_XDECREF(args[1]);
    if (r == NULL) {
        PyErr_Clear();
        return -1;
    }
    *out = PyFloat_AsDouble(r);
    Py_DECREF(r);
    return 0;
}

/* A number's value as a double: a float's own, an int's (a bool's) without the float
   object int.__float__ would make, anything else through __float__ (an error set if none). */
static inline double
tfl_double(PyObject *x)
{
    if (PyFloat_CheckExact(x))
        return PyFloat_AS_DOUBLE(x);
    if (PyLong_Check(x))
        return PyLong_AsDouble(x);
    return PyFloat_AsDouble(x);
}

/* The class ``qualname`` of module ``module``: a tuple subclass (a NamedTuple a result is
   returned as), or NULL with ImportError set. */
static PyObject *
tfl_class(const char *module, const char *qualname)
{
    PyObject *obj = PyImport_ImportModule(module);
    char part[256];
    const char *p = qualname;
    while (obj != NULL && *p) {
        size_t n = strcspn(p, ".");
        if (n >= sizeof part)
            n = sizeof part - 1;
        memcpy(part, p, n);
        part[n] = 0;
        PyObject *next = PyObject_GetAttrString(obj, part);
        Py_DECREF(obj);
        obj = next;
        p += n + (p[n] == '.');
    }
    if (obj != NULL && !(PyType_Check(obj)
                         && PyType_IsSubtype((PyTypeObject *)obj, &PyTuple_Type))) {
        Py_DECREF(obj);
        obj = NULL;
    }
    if (obj == NULL && !PyErr_Occurred())
        PyErr_Format(PyExc_ImportError, "%s:%s is not a tuple class", module, qualname);
    return obj;
}

/* A tuple (a NamedTuple too: its items are a tuple's) as it is, any other sequence through
   PySequence_Fast (a new reference; NULL with an exception set if it is none). */
static PyObject *
tfl_fast(PyObject *o)
{
    if (PyTuple_Check(o)) {
        Py_INCREF(o);
        return o;
    }
    return PySequence_Fast(o, "");
}

/* n floats from a tuple (a NamedTuple too) or list, a 1-D float64 buffer (a numpy array) or
   any sequence of numbers; nonzero (no exception set) when it is none of those or holds
   another count. */
static int
tfl_unpack(PyObject *o, double *out, Py_ssize_t n)
{
    if (PyTuple_Check(o) || PyList_CheckExact(o)) {
        if (Py_SIZE(o) != n)
            return -1;
        PyObject **items = PyTuple_Check(o) ? ((PyTupleObject *)o)->ob_item
                                            : ((PyListObject *)o)->ob_item;
        for (Py_ssize_t k = 0; k < n; k++) {
            PyObject *x = items[k];
            out[k] = tfl_double(x);
        }
    }
    else if (PyObject_CheckBuffer(o)) {
        Py_buffer view;
        if (PyObject_GetBuffer(o, &view, PyBUF_FORMAT | PyBUF_ND) != 0) {
            PyErr_Clear();
            return -1;
        }
        int ok = view.ndim == 1 && view.shape[0] == n && view.format != NULL
                 && view.format[0] == 'd' && view.format[1] == 0;
        if (ok)
            memcpy(out, view.buf, (size_t)n * sizeof(double));
        PyBuffer_Release(&view);
        if (!ok)
            return -1;
    }
    else {
        PyObject *s = PySequence_Fast(o, "");
        if (s == NULL) {
            PyErr_Clear();
            return -1;
        }
        if (PySequence_Fast_GET_SIZE(s) != n) {
            Py_DECREF(s);
            return -1;
        }
        for (Py_ssize_t k = 0; k < n; k++)
            out[k] = tfl_double(PySequence_Fast_GET_ITEM(s, k));
        Py_DECREF(s);
    }
    if (PyErr_Occurred()) {
        PyErr_Clear();
        return -1;
    }
    return 0;
}
/* 1 when o's numbers can never change: a number (a float or an int, subclasses too: their
   value is fixed at creation, and read without calling them) or a tuple of such, nested. */
static int
tfl_frozen(PyObject *o)
{
    if (PyFloat_Check(o) || PyLong_Check(o))
        return 1;
    if (!PyTuple_Check(o))
        return 0;
    for (Py_ssize_t k = 0; k < PyTuple_GET_SIZE(o); k++)
        if (!tfl_frozen(PyTuple_GET_ITEM(o, k)))
            return 0;
    return 1;
}

/* CPython's math.atan2 (Modules/mathmodule.c, m_atan2): its own answers for NaN, ±inf and
   ±0 (C99 Annex F's, spelled out), libm's atan2 otherwise. */
static double
tfl_atan2(double y, double x)
{
    if (isnan(x) || isnan(y))
        return Py_NAN;
    if (isinf(y)) {
        if (isinf(x)) {
            if (copysign(1., x) == 1.)
                return copysign(0.25*Py_MATH_PI, y);
            else
                return copysign(0.75*Py_MATH_PI, y);
        }
        return copysign(0.5*Py_MATH_PI, y);
    }
    if (isinf(x) || y == 0.) {
        if (copysign(1., x) == 1.)
            return copysign(0., y);
        else
            return copysign(Py_MATH_PI, y);
    }
    return atan2(y, x);
}
"""
