"""The daemon's ODOMETRY → paper-frame conversion compiled to C (:mod:`native`).

:func:`~tfl_mav.frames.paper_from_odometry_fields` runs on every state the daemon receives:
~300 bytecodes (~3 µs a tick in the daemon's loop). Here the same operations, in the same
order, are one C function of the link's ODOMETRY tuple (:func:`~tfl_mav.link.codec
.rx_lite_class`: its fields in wire order) and the :class:`~tfl_mav.state.State` class,
returning the State itself: its slots set as its ``__init__`` sets them (the same values;
no Python runs).

The body-FRD velocity rotated by R(q) is each row's products summed left to right, as in
Python, built with ``-ffp-contract=off`` (:data:`native.CFLAGS`: no multiply-add is fused)
so every operation rounds as Python's does. The compiled function is used only after it
gave the Python function's bits on :data:`_CHECKS` (vectors that tell a fused or reordered
sum apart) in this process, so a compiler that fused anyway would only cost speed; else the
Python path flies, with one warning.

Every case the fast path does not cover returns None and the caller runs the Python
function, which decides as before (and raises its errors): a value that is not a Python
float (an int, a numpy scalar), a frame other than LOCAL_NED/BODY_FRD, a non-finite value, a
quaternion that is not (close to) unit length, a tuple of another shape.
"""

from __future__ import annotations

import logging
import math
import random
from collections.abc import Callable
from typing import Any

from tfl_mav import native
from tfl_mav.frames import MAV_FRAME_BODY_FRD, MAV_FRAME_LOCAL_NED, paper_from_odometry_fields
from tfl_mav.state import State

__all__ = ["C_SOURCE", "attach", "verified"]

log = logging.getLogger(__name__)

_SQRT1_2 = math.sqrt(0.5)       # frames._SQRT1_2, the same double

C_SOURCE = r"""
#define PY_SSIZE_T_CLEAN
#include <Python.h>
#include <structmember.h>
#include <math.h>

/* The State class and where its five slots live (its member descriptors' offsets), found
   on the first call with it: a State is then made as State.__init__ makes it (each slot
   set once), without running Python. */
static PyTypeObject *state_type = NULL;
static Py_ssize_t state_offset[5];
static const char *state_fields[5] = {
    "position_m", "velocity_mps", "quaternion_wxyz", "body_rates_radps", "time_usec"};

static int find_slots(PyObject *type) {
    if (!PyType_Check(type))
        return -1;
    for (int k = 0; k < 5; k++) {
        PyObject *d = PyObject_GetAttrString(type, state_fields[k]);
        if (d == NULL) {
            PyErr_Clear();
            return -1;
        }
        int ok = Py_IS_TYPE(d, &PyMemberDescr_Type)
                 && ((PyMemberDescrObject *)d)->d_member->type == T_OBJECT_EX;
        if (ok)
            state_offset[k] = ((PyMemberDescrObject *)d)->d_member->offset;
        Py_DECREF(d);
        if (!ok)
            return -1;
    }
    Py_XDECREF(state_type);
    Py_INCREF(type);
    state_type = (PyTypeObject *)type;
    return 0;
}

/* One row of R v, as frames.py sums it: (r0 x0 + r1 x1) + r2 x2, no fused multiply-add. */
static double row(double r0, double r1, double r2, double x0, double x1, double x2) {
    return r0 * x0 + r1 * x1 + r2 * x2;
}

static PyObject *
odometry(PyObject *self, PyObject *const *args, Py_ssize_t nargs)
{
    if (nargs != 2) {
        PyErr_SetString(PyExc_TypeError, "odometry() takes the ODOMETRY tuple and State");
        return NULL;
    }
    PyObject *m = args[0];
    if ((PyObject *)state_type != args[1] && find_slots(args[1]) != 0)
        Py_RETURN_NONE;
    if (!PyTuple_Check(m) || PyTuple_GET_SIZE(m) < 16)
        Py_RETURN_NONE;
    double v[13];
    for (int k = 0; k < 13; k++) {
        PyObject *o = PyTuple_GET_ITEM(m, k + 1);
        if (!PyFloat_CheckExact(o))
            Py_RETURN_NONE;
        v[k] = PyFloat_AS_DOUBLE(o);
    }
    PyObject *frame = PyTuple_GET_ITEM(m, 14), *child = PyTuple_GET_ITEM(m, 15);
    if (!PyLong_CheckExact(frame) || !PyLong_CheckExact(child)
        || PyLong_AsLong(frame) != FRAME_LOCAL_NED || PyLong_AsLong(child) != FRAME_BODY_FRD) {
        PyErr_Clear();
        Py_RETURN_NONE;
    }
    double px = v[0], py = v[1], pz = v[2], qw = v[3], qx = v[4], qy = v[5], qz = v[6];
    double vx = v[7], vy = v[8], vz = v[9], p = v[10], q = v[11], r = v[12];
    if (!isfinite(px + py + pz + vx + vy + vz + p + q + r))
        Py_RETURN_NONE;
    if (!(isfinite(qw) && isfinite(qx) && isfinite(qy) && isfinite(qz)))
        Py_RETURN_NONE;
    double norm = sqrt(qw * qw + qx * qx + qy * qy + qz * qz);
    if (!(fabs(norm - 1.0) <= 1e-3))
        Py_RETURN_NONE;
    double w = qw / norm, x = qx / norm, y = qy / norm, z = qz / norm;
    double s = SQRT1_2;
    double q0 = s * (w + z), q1 = s * (x + y), q2 = s * (x - y), q3 = s * (w - z);
    double n = sqrt(q0 * q0 + q1 * q1 + q2 * q2 + q3 * q3);
    if (n == 0.0)
        Py_RETURN_NONE;
    double a = q0 / n, b = q1 / n, c = q2 / n, d = q3 / n;
    double x0 = vx, x1 = -vy, x2 = -vz;
    double v0 = row(1.0 - 2.0 * (c * c + d * d), 2.0 * (b * c - a * d), 2.0 * (b * d + a * c),
                    x0, x1, x2);
    double v1 = row(2.0 * (b * c + a * d), 1.0 - 2.0 * (b * b + d * d), 2.0 * (c * d - a * b),
                    x0, x1, x2);
    double v2 = row(2.0 * (b * d - a * c), 2.0 * (c * d + a * b), 1.0 - 2.0 * (b * b + c * c),
                    x0, x1, x2);
    PyObject *time_usec = PyTuple_GET_ITEM(m, 0);
    PyObject *vals[5] = {Py_BuildValue("(ddd)", py, px, -pz), Py_BuildValue("[ddd]", v0, v1, v2),
                         Py_BuildValue("(dddd)", q0, q1, q2, q3),
                         Py_BuildValue("(ddd)", p, -q, -r), time_usec};
    Py_INCREF(time_usec);
    PyObject *state = NULL;
    if (vals[0] && vals[1] && vals[2] && vals[3])
        state = state_type->tp_alloc(state_type, 0);
    if (state == NULL) {
        for (int k = 0; k < 5; k++)
            Py_XDECREF(vals[k]);
        return NULL;
    }
    for (int k = 0; k < 5; k++)         /* the references move into the slots */
        *(PyObject **)((char *)state + state_offset[k]) = vals[k];
    return state;
}

static PyMethodDef methods[] = {
    {"odometry", (PyCFunction)(void (*)(void))odometry, METH_FASTCALL, "ODOMETRY -> State"},
    {NULL, NULL, 0, NULL}
};

static struct PyModuleDef module = {PyModuleDef_HEAD_INIT, MODULE_NAME, NULL, -1, methods};

PyMODINIT_FUNC MODULE_INIT(void) { return PyModule_Create(&module); }
""".replace("SQRT1_2", float.hex(_SQRT1_2)).replace(
    "FRAME_LOCAL_NED", str(MAV_FRAME_LOCAL_NED)).replace("FRAME_BODY_FRD", str(MAV_FRAME_BODY_FRD))


def _checks() -> list[tuple[Any, ...]]:
    """ODOMETRY tuples whose velocity rows tell fused and plain multiply-adds apart (and
    their orders), signed zeros included: random unit quaternions and velocities over many
    magnitudes, and exact zeros."""
    rng = random.Random(13)
    out = []
    for k in range(64):
        q = [rng.gauss(0.0, 1.0) for _ in range(4)]
        nq = math.sqrt(sum(c * c for c in q))
        mag = 10.0 ** rng.uniform(-3.0, 3.0)
        vel = [rng.gauss(0.0, mag) for _ in range(3)] if k % 8 else [0.0, -0.0, 0.0]
        out.append((k * 1000, rng.uniform(-5, 5), rng.uniform(-5, 5), rng.uniform(-9, 0),
                    *(c / nq for c in q), *vel, rng.gauss(0, 1), rng.gauss(0, 1),
                    rng.gauss(0, 30), MAV_FRAME_LOCAL_NED, MAV_FRAME_BODY_FRD))
    out.append((0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, -0.0, -0.0, -0.0, 0.0, -0.0, 0.0,
                MAV_FRAME_LOCAL_NED, MAV_FRAME_BODY_FRD))
    return out


_CHECKS = _checks()


def _bits(values: Any) -> list[str]:
    return [float.hex(float(v)) if isinstance(v, float) else repr(v) for v in values]


def verified(core: Callable[[Any], Any]) -> bool:
    """Whether ``core`` gives :func:`paper_from_odometry_fields`'s values, bit for bit, on
    :data:`_CHECKS`."""
    for msg in _CHECKS:
        res = core(msg, State)
        if type(res) is not State:
            return False
        ref = paper_from_odometry_fields(*msg)
        pos, vel, quat, rates, t_usec = (res.position_m, res.velocity_mps, res.quaternion_wxyz,
                                         res.body_rates_radps, res.time_usec)
        if (t_usec != ref.time_usec or type(vel) is not list or type(pos) is not tuple
                or any(_bits(a) != _bits(b) for a, b in (
                    (pos, ref.position_m), (vel, ref.velocity_mps),
                    (quat, ref.quaternion_wxyz), (rates, ref.body_rates_radps)))):
            return False
    return True


def attach(ready: Callable[[Callable[[Any], Any]], None]) -> None:
    """``ready(core)`` with the compiled conversion once it is built (now if it is cached,
    or with ``TFL_MAV_NATIVE=sync``; else from a background build) and has given the
    Python function's bits on this machine; never, with one warning, if it does not."""
    def check(core: Callable[[Any], Any]) -> None:
        if verified(core):
            ready(core)
        else:
            native.warn_once("the compiled ODOMETRY conversion does not give the Python "
                             "conversion's velocity bits")

    core = native.obtain_c(C_SOURCE, "odometry", check)
    if core is not None:
        check(core)
