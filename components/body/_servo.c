/* The arm plant's sub-step loop (components/body/plant.py, ArmPlant.step) in C: the servo law of plant.py's module
 * docstring, the load cells' impulses summed, and Chipmunk's step, for every arm of one pymunk space.
 *
 * Chipmunk is reached through function pointers taken from pymunk's cffi module (bind), so no Chipmunk header
 * or library is needed to build this, and the library called is the one pymunk loaded. The arithmetic is the
 * numpy loop's (ArmPlant._substeps_numpy), operation by operation in the same order, as plain IEEE doubles:
 * built with -ffp-contract=off and without -ffast-math, so nothing is fused or reordered, and the numbers are
 * the same bits (tests/test_body_cloop.py).
 */
#define PY_SSIZE_T_CLEAN
#include <Python.h>
#include <math.h>
#include <stdint.h>

#if UINTPTR_MAX != UINT64_MAX
#error "the plant passes addresses as uint64 (a failed build leaves the plant on its numpy loop)"
#endif

typedef void (*step_fn)(void *space, double dt);
typedef double (*get_fn)(void *object);
typedef void (*set_fn)(void *body, double value);

static step_fn space_step;        /* cpSpaceStep */
static get_fn angular_velocity;   /* cpBodyGetAngularVelocity */
static set_fn set_torque;         /* cpBodySetTorque */
static get_fn impulse;            /* cpConstraintGetImpulse */

/* np.maximum and np.minimum on x86-64 (numpy's SSE/AVX kernels, MAXPD/MINPD): a NaN first operand is returned,
 * else the first if strictly greater (less), else the second -- so of two equal operands (+0 and -0) the
 * second. plant.py checks numpy does so on this machine before it uses this module. */
static inline double np_maximum(double a, double b) { return isnan(a) ? a : (a > b ? a : b); }
static inline double np_minimum(double a, double b) { return isnan(a) ? a : (a < b ? a : b); }

static PyObject *bind(PyObject *self, PyObject *args)
{
    unsigned long long step, get_w, set_t, get_impulse;
    if (!PyArg_ParseTuple(args, "KKKK:bind", &step, &get_w, &set_t, &get_impulse))
        return NULL;
    space_step = (step_fn)(uintptr_t)step;
    angular_velocity = (get_fn)(uintptr_t)get_w;
    set_torque = (set_fn)(uintptr_t)set_t;
    impulse = (get_fn)(uintptr_t)get_impulse;
    Py_RETURN_NONE;
}

static int sized(Py_buffer *buffer, Py_ssize_t count, Py_ssize_t item, const char *name)
{
    if (buffer->len == count * item)
        return 1;
    PyErr_Format(PyExc_ValueError, "substeps: %s has %zd bytes, not %zd", name, buffer->len, count * item);
    return 0;
}

static PyObject *substeps(PyObject *self, PyObject *args)
{
    unsigned long long space, still;
    Py_buffer bodies, want, gain, cap, springs, impulses;
    Py_ssize_t count;
    double dt;
    PyObject *result = NULL;
    if (!space_step) {
        PyErr_SetString(PyExc_RuntimeError, "substeps: bind() was not called");
        return NULL;
    }
    if (!PyArg_ParseTuple(args, "KKy*y*y*y*y*w*nd:substeps", &space, &still, &bodies, &want, &gain, &cap,
                          &springs, &impulses, &count, &dt))
        return NULL;
    Py_ssize_t trials = gain.len / (Py_ssize_t)sizeof(double), cells = springs.len / (Py_ssize_t)sizeof(uint64_t);
    if (sized(&bodies, 2 * trials, sizeof(uint64_t), "bodies") && sized(&want, 2 * trials, sizeof(double), "want")
            && sized(&cap, trials, sizeof(double), "cap") && sized(&impulses, cells, sizeof(double), "impulses")) {
        void **body = (void **)bodies.buf, **spring = (void **)springs.buf;
        const double *a = want.buf, *k = gain.buf, *limit = cap.buf;
        double *total = impulses.buf;
        Py_BEGIN_ALLOW_THREADS  /* Chipmunk's own C from here on; a Python callback of pymunk's takes the GIL */
        for (Py_ssize_t sub = 0; sub < count; sub++) {
            for (Py_ssize_t n = 0; n < trials; n++) {
                double w_upper = angular_velocity(body[2 * n]), w_forearm = angular_velocity(body[2 * n + 1]);
                /* shoulder: a - w_upper; elbow: a - (w_forearm - w_upper); each clip(K e, +-limit) */
                double shoulder = k[n] * (a[2 * n] - w_upper), elbow = k[n] * (a[2 * n + 1] - (w_forearm - w_upper));
                shoulder = np_minimum(np_maximum(shoulder, -limit[n]), limit[n]);
                elbow = np_minimum(np_maximum(elbow, -limit[n]), limit[n]);
                set_torque(body[2 * n], shoulder - elbow);  /* the elbow motor pushes back on the upper arm */
                set_torque(body[2 * n + 1], elbow);
            }
            set_torque((void *)(uintptr_t)still, 0.0);  /* as pymunk's batch call writes every body of the space */
            space_step((void *)(uintptr_t)space, dt);
            for (Py_ssize_t c = 0; c < cells; c++)
                total[c] += impulse(spring[c]);
        }
        Py_END_ALLOW_THREADS
        result = Py_None;
        Py_INCREF(result);
    }
    PyBuffer_Release(&bodies); PyBuffer_Release(&want); PyBuffer_Release(&gain); PyBuffer_Release(&cap);
    PyBuffer_Release(&springs); PyBuffer_Release(&impulses);
    return result;
}

static PyMethodDef methods[] = {
    {"bind", bind, METH_VARARGS,
     "bind(step, get_angular_velocity, set_torque, get_impulse): the addresses of cpSpaceStep, "
     "cpBodyGetAngularVelocity, cpBodySetTorque and cpConstraintGetImpulse."},
    {"substeps", substeps, METH_VARARGS,
     "substeps(space, static_body, bodies, want, gain, cap, springs, impulses, count, dt): count sub-steps of dt "
     "under the servo; bodies (upper arm, forearm) per trial and springs as uint64 addresses, want (rad/s) per "
     "trial and joint, gain and cap per trial, the springs' impulses added to impulses."},
    {NULL, NULL, 0, NULL},
};

static struct PyModuleDef module = {PyModuleDef_HEAD_INIT, "_servo", "The arm plant's sub-step loop in C.", -1,
                                    methods};

PyMODINIT_FUNC PyInit__servo(void) { return PyModule_Create(&module); }
