/* The batched arm's sub-steps (components/body/batched.py, substep) in C: every trial's `count` sub-steps in one
 * call, a trial at a time (the trials are independent), the arithmetic of the numpy reference operation by
 * operation in the same order, as plain IEEE doubles (built with -ffp-contract=off, without -ffast-math), so the
 * two agree to the last bits of libm's sin and cos (tests/test_body_batched.py).
 *
 * Equations (their sources are in batched.py's docstrings): the two-link arm's joint-space inertia and velocity
 * forces (Spong, Hutchinson & Vidyasagar 2006, sec. 7.4.1), the pymunk plant's servo, Chipmunk's damped spring.
 */
#define PY_SSIZE_T_CLEAN
#include <Python.h>
#include <math.h>

/* np.maximum and np.minimum (as np.clip applies them): a NaN first operand is returned, else the first if
 * strictly greater (less), else the second. */
static inline double np_maximum(double a, double b) { return isnan(a) ? a : (a > b ? a : b); }
static inline double np_minimum(double a, double b) { return isnan(a) ? a : (a < b ? a : b); }

static double upper_arm, forearm, shoulder_x, shoulder_y, cell_arm;  /* set by geometry() */

static PyObject *geometry(PyObject *self, PyObject *args)
{
    if (!PyArg_ParseTuple(args, "ddddd:geometry", &upper_arm, &forearm, &shoulder_x, &shoulder_y, &cell_arm))
        return NULL;
    Py_RETURN_NONE;
}

static int sized(Py_buffer *buffer, Py_ssize_t count, const char *name)
{
    if (buffer->len == count * (Py_ssize_t)sizeof(double))
        return 1;
    PyErr_Format(PyExc_ValueError, "substeps: %s has %zd bytes, not %zd", name, buffer->len,
                 count * (Py_ssize_t)sizeof(double));
    return 0;
}

static void trial_substeps(double *s, const double *p, double *impulse, Py_ssize_t count, double dt)
{
    /* s: q1, q2, w1, w2; p: a1, a2, gain, limit, upper mass, forearm mass, stiffness, damping,
     * anchor_x (x, y), anchor_y (x, y); impulse: x spring, y spring (added to) */
    double q1 = s[0], q2 = s[1], w1 = s[2], w2 = s[3];
    const double a1 = p[0], a2 = p[1], gain = p[2], limit = p[3], m_upper = p[4], m_fore = p[5], k = p[6], c = p[7];
    const double axx = p[8], axy = p[9], ayx = p[10], ayy = p[11];
    const double coupling = m_fore * upper_arm * forearm / 2, fore = m_fore * (forearm * forearm) / 3;
    const double upper_inertia = m_upper * (upper_arm * upper_arm) / 3 + m_fore * (upper_arm * upper_arm) + fore;
    const double h_coupling = -m_fore * upper_arm * forearm / 2;
    const double drag = dt * c;
    double jx_total = 0.0, jy_total = 0.0;
    for (Py_ssize_t sub = 0; sub < count; sub++) {
        q1 += w1 * dt;
        q2 += w2 * dt;
        double tau1 = np_minimum(np_maximum(gain * (a1 - w1), -limit), limit);
        double tau2 = np_minimum(np_maximum(gain * (a2 - w2), -limit), limit);
        double cos_e = cos(q2), sin_e = sin(q2);
        double m11 = upper_inertia + 2 * coupling * cos_e, m12 = fore + coupling * cos_e, m22 = fore;
        double h = h_coupling * sin_e;
        double c1 = h * (2 * w1 * w2 + w2 * w2), c2 = -h * (w1 * w1);
        double angle = q1 + q2;
        double cos_s = cos(q1), sin_s = sin(q1), cos_f = cos(angle), sin_f = sin(angle);
        double x_e = forearm * cos_f, y_e = forearm * sin_f;
        double x = shoulder_x + upper_arm * cos_s + x_e, y = shoulder_y + upper_arm * sin_s + y_e;
        double jxs = -upper_arm * sin_s - y_e, jxe = -y_e, jys = upper_arm * cos_s + x_e, jye = x_e;
        double dxx = x - axx, dxy = y - axy, length_x = sqrt(dxx * dxx + dxy * dxy);
        double fx = k * (cell_arm - length_x), nxx = dxx / length_x, nxy = dxy / length_x;
        double dyx = x - ayx, dyy = y - ayy, length_y = sqrt(dyx * dyx + dyy * dyy);
        double fy = k * (cell_arm - length_y), nyx = dyx / length_y, nyy = dyy / length_y;
        double gxs = jxs * nxx + jys * nxy, gxe = jxe * nxx + jye * nxy;
        double gys = jxs * nyx + jys * nyy, gye = jxe * nyx + jye * nyy;
        double a11 = m11 + drag * (gxs * gxs + gys * gys), a12 = m12 + drag * (gxs * gxe + gys * gye);
        double a22 = m22 + drag * (gxe * gxe + gye * gye);
        double b1 = m11 * w1 + m12 * w2 + dt * (tau1 - c1 + gxs * fx + gys * fy);
        double b2 = m12 * w1 + m22 * w2 + dt * (tau2 - c2 + gxe * fx + gye * fy);
        double determinant = a11 * a22 - a12 * a12;
        w1 = (a22 * b1 - a12 * b2) / determinant;
        w2 = (a11 * b2 - a12 * b1) / determinant;
        jx_total += dt * fx - drag * (gxs * w1 + gxe * w2);
        jy_total += dt * fy - drag * (gys * w1 + gye * w2);
    }
    s[0] = q1; s[1] = q2; s[2] = w1; s[3] = w2;
    impulse[0] = jx_total;
    impulse[1] = jy_total;
}

static PyObject *substeps(PyObject *self, PyObject *args)
{
    Py_buffer state, parameters, impulses;
    Py_ssize_t count, trials;
    double dt;
    if (!PyArg_ParseTuple(args, "w*y*w*nnd:substeps", &state, &parameters, &impulses, &trials, &count, &dt))
        return NULL;
    PyObject *result = NULL;
    if (sized(&state, 4 * trials, "state") && sized(&parameters, 12 * trials, "parameters")
            && sized(&impulses, 2 * trials, "impulses")) {
        double *s = state.buf, *j = impulses.buf;
        const double *p = parameters.buf;
        Py_BEGIN_ALLOW_THREADS
        for (Py_ssize_t n = 0; n < trials; n++)
            trial_substeps(s + 4 * n, p + 12 * n, j + 2 * n, count, dt);
        Py_END_ALLOW_THREADS
        result = Py_None;
        Py_INCREF(result);
    }
    PyBuffer_Release(&state); PyBuffer_Release(&parameters); PyBuffer_Release(&impulses);
    return result;
}

static PyMethodDef methods[] = {
    {"geometry", geometry, METH_VARARGS,
     "geometry(upper_arm, forearm, shoulder_x, shoulder_y, cell_arm): the arm's lengths and shoulder, m."},
    {"substeps", substeps, METH_VARARGS,
     "substeps(state, parameters, impulses, trials, count, dt): count sub-steps of dt for every trial; state "
     "(trials, 4) q1, q2, w1, w2 updated, parameters (trials, 12), impulses (trials, 2) the springs' sums."},
    {NULL, NULL, 0, NULL},
};

static struct PyModuleDef module = {PyModuleDef_HEAD_INIT, "_arm", "The batched arm's sub-steps in C.", -1, methods};

PyMODINIT_FUNC PyInit__arm(void) { return PyModule_Create(&module); }
