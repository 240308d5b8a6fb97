/* A body written in C: the ideal kinematic arm of components/body/variants.py as a co-simulation FMU,
 * meeting the body contract of docs/design.md, for FMI 2.0 or FMI 3.0 from this one source: compile with
 * -DFMI_VERSION=3 for FMI 3.0 (default 2), as the Modelica Reference FMUs do. The model below is shared, so
 * the two builds compute the same numbers by the same instructions.
 *
 * Free: the joints follow the command exactly, q(t + h) = q(t) + h u.
 * Held: the joints do not move; the hand force is the statics of the servo, tau = clip(K u, +-limit)
 * (u in rad/s) balanced at the clamped hand, F = J^-T tau, J = d(hand)/d(angles) in m/rad.
 * Geometry (docs/design.md): shoulder at (-0.20, 0), upper arm 0.3595 m, forearm 0.3694 m; angles in deg,
 * the shoulder from +x, the elbow relative to the upper arm.
 *
 * Built by master/export/c_body.py with the FMI headers that fmpy ships. One instance is one trial.
 */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#ifndef FMI_VERSION
#define FMI_VERSION 2
#endif
#if FMI_VERSION == 3
#include "fmi3Functions.h"
#elif FMI_VERSION == 2
#include "fmi2Functions.h"
#else
#error "FMI_VERSION must be 2 or 3"
#endif

#define SHOULDER_X (-0.20)
#define SHOULDER_Y 0.0
#define UPPER_ARM 0.3595
#define FOREARM 0.3694
#define PI 3.14159265358979323846

/* Value references: the declaration order of the Python KinematicArm, from which the builder writes
 * modelDescription.xml (8 is the Boolean `held`). Start values come from the same declarations, as
 * -D definitions: START_Q0_SHOULDER, START_Q0_ELBOW, START_SERVO_GAIN, START_TORQUE_LIMIT, START_HELD.
 * In FMI 3.0 each pair (u, q, hand, force) is one Float64 array whose value reference is its first element's. */
enum { U_SHOULDER, U_ELBOW, Q_SHOULDER, Q_ELBOW, HAND_X, HAND_Y, FORCE_X, FORCE_Y, HELD,
       Q0_SHOULDER, Q0_ELBOW, SERVO_GAIN, TORQUE_LIMIT, N_REFERENCES };

typedef struct {
    double real[N_REFERENCES];  /* by value reference; [HELD] unused */
    int held;
    double time;                /* FMI 3.0's independent variable: the last communication point */
#if FMI_VERSION == 3
    fmi3LogMessageCallback log;
    fmi3InstanceEnvironment environment;
#else
    fmi2CallbackFunctions callbacks;
#endif
    char *name;
} Arm;

static void log_error(Arm *arm, const char *message) {
#if FMI_VERSION == 3
    if (arm->log) arm->log(arm->environment, fmi3Error, "logStatusError", message);
#else
    if (arm->callbacks.logger)
        arm->callbacks.logger(arm->callbacks.componentEnvironment, arm->name, fmi2Error, "error", "%s", message);
#endif
}

/* Hand position (m) and its Jacobian (m/rad, rows x and y, columns shoulder and elbow) at the angles in deg. */
static void kinematics(double shoulder_deg, double elbow_deg, double hand[2], double jacobian[2][2]) {
    double shoulder = shoulder_deg * PI / 180.0, forearm = shoulder + elbow_deg * PI / 180.0;
    hand[0] = SHOULDER_X + UPPER_ARM * cos(shoulder) + FOREARM * cos(forearm);
    hand[1] = SHOULDER_Y + UPPER_ARM * sin(shoulder) + FOREARM * sin(forearm);
    jacobian[0][1] = -FOREARM * sin(forearm);
    jacobian[1][1] = FOREARM * cos(forearm);
    jacobian[0][0] = -UPPER_ARM * sin(shoulder) + jacobian[0][1];
    jacobian[1][0] = UPPER_ARM * cos(shoulder) + jacobian[1][1];
}

static double clip(double value, double limit) { return value > limit ? limit : value < -limit ? -limit : value; }

/* Outputs from the joint angles and the command: hand position, and the held arm's static hand force
 * (zero before the first step, as in the Python arm: no command has acted yet). */
static void publish(Arm *arm, int acted) {
    double *r = arm->real, hand[2], j[2][2];
    kinematics(r[Q_SHOULDER], r[Q_ELBOW], hand, j);
    r[HAND_X] = hand[0];
    r[HAND_Y] = hand[1];
    if (arm->held && acted) {
        double tau0 = clip(r[SERVO_GAIN] * r[U_SHOULDER] * PI / 180.0, r[TORQUE_LIMIT]);
        double tau1 = clip(r[SERVO_GAIN] * r[U_ELBOW] * PI / 180.0, r[TORQUE_LIMIT]);
        /* J^T F = tau: J^T = [[j00, j10], [j01, j11]], solved by Cramer's rule. */
        double det = j[0][0] * j[1][1] - j[1][0] * j[0][1];
        r[FORCE_X] = (tau0 * j[1][1] - j[1][0] * tau1) / det;
        r[FORCE_Y] = (j[0][0] * tau1 - j[0][1] * tau0) / det;
    } else {
        r[FORCE_X] = r[FORCE_Y] = 0.0;
    }
}

static void start_values(Arm *arm) {
    double *r = arm->real;
    memset(r, 0, sizeof(arm->real));
    r[Q0_SHOULDER] = START_Q0_SHOULDER;
    r[Q0_ELBOW] = START_Q0_ELBOW;
    r[SERVO_GAIN] = START_SERVO_GAIN;
    r[TORQUE_LIMIT] = START_TORQUE_LIMIT;
    r[Q_SHOULDER] = r[Q0_SHOULDER];
    r[Q_ELBOW] = r[Q0_ELBOW];
    arm->held = START_HELD;
    arm->time = 0.0;
    publish(arm, 0);
}

static Arm *new_arm(const char *name) {
    Arm *arm = calloc(1, sizeof(Arm));
    if (!arm) return NULL;
    if (!name) name = "arm";
    arm->name = malloc(strlen(name) + 1);
    if (!arm->name) { free(arm); return NULL; }
    strcpy(arm->name, name);
    start_values(arm);
    return arm;
}

static void free_arm(Arm *arm) {
    if (!arm) return;
    free(arm->name);
    free(arm);
}

static void initialize(Arm *arm) {  /* the parameters are in: the arm starts at q0 */
    arm->real[Q_SHOULDER] = arm->real[Q0_SHOULDER];
    arm->real[Q_ELBOW] = arm->real[Q0_ELBOW];
    publish(arm, 0);
}

/* One communication step of h seconds; 0, or -1 (logged) if the command is not finite. */
static int step(Arm *arm, double h) {
    double *r = arm->real;
    if (!isfinite(r[U_SHOULDER]) || !isfinite(r[U_ELBOW])) {
        log_error(arm, "commanded velocity is not finite");
        return -1;
    }
    if (!arm->held) {
        r[Q_SHOULDER] += h * r[U_SHOULDER];
        r[Q_ELBOW] += h * r[U_ELBOW];
    }
    publish(arm, 1);
    return 0;
}

/* Inputs and parameters may be set; outputs (Q_SHOULDER..FORCE_Y) and the Boolean HELD not as reals. */
static int settable_real(unsigned reference) { return reference < N_REFERENCES && !(reference >= Q_SHOULDER &&
                                                                                      reference <= HELD); }

#if FMI_VERSION == 3
/* ---- FMI 3.0 co-simulation ------------------------------------------------------------------ */
#ifndef VARIABLE_SIZES
#error "the builder defines VARIABLE_SIZES: elements per value reference, 0 inside an array"
#endif
static const int SIZE[N_REFERENCES] = VARIABLE_SIZES;
#define TIME N_REFERENCES  /* the independent variable's value reference (the builder's description says so) */

const char *fmi3GetVersion(void) { return fmi3Version; }
fmi3Status fmi3SetDebugLogging(fmi3Instance c, fmi3Boolean on, size_t n, const fmi3String categories[]) {
    return fmi3OK;
}

fmi3Instance fmi3InstantiateCoSimulation(fmi3String name, fmi3String token, fmi3String resources, fmi3Boolean visible,
                                         fmi3Boolean logging, fmi3Boolean event_mode, fmi3Boolean early_return,
                                         const fmi3ValueReference intermediate[], size_t n_intermediate,
                                         fmi3InstanceEnvironment environment, fmi3LogMessageCallback log,
                                         fmi3IntermediateUpdateCallback update) {
    Arm *arm = new_arm(name);
    if (!arm) return NULL;
    arm->log = log;
    arm->environment = environment;
    return arm;
}
fmi3Instance fmi3InstantiateModelExchange(fmi3String name, fmi3String token, fmi3String resources,
                                          fmi3Boolean visible, fmi3Boolean logging,
                                          fmi3InstanceEnvironment environment, fmi3LogMessageCallback log) {
    return NULL;  /* co-simulation only, as the description says */
}
fmi3Instance fmi3InstantiateScheduledExecution(fmi3String name, fmi3String token, fmi3String resources,
                                               fmi3Boolean visible, fmi3Boolean logging,
                                               fmi3InstanceEnvironment environment, fmi3LogMessageCallback log,
                                               fmi3ClockUpdateCallback clock, fmi3LockPreemptionCallback lock,
                                               fmi3UnlockPreemptionCallback unlock) { return NULL; }
void fmi3FreeInstance(fmi3Instance c) { free_arm(c); }

fmi3Status fmi3EnterInitializationMode(fmi3Instance c, fmi3Boolean tolerance_defined, fmi3Float64 tolerance,
                                       fmi3Float64 start, fmi3Boolean stop_defined, fmi3Float64 stop) {
    ((Arm *)c)->time = start;
    initialize(c);
    return fmi3OK;
}
fmi3Status fmi3ExitInitializationMode(fmi3Instance c) { initialize(c); return fmi3OK; }
fmi3Status fmi3EnterEventMode(fmi3Instance c) { return fmi3Error; }
fmi3Status fmi3Terminate(fmi3Instance c) { return fmi3OK; }
fmi3Status fmi3Reset(fmi3Instance c) { start_values(c); return fmi3OK; }
fmi3Status fmi3EnterStepMode(fmi3Instance c) { return fmi3OK; }

/* Float64 values of the variables in vr, each array's elements in order; nValues must be their total. */
fmi3Status fmi3GetFloat64(fmi3Instance c, const fmi3ValueReference vr[], size_t n, fmi3Float64 value[],
                          size_t n_values) {
    Arm *arm = c;
    size_t at = 0;
    for (size_t i = 0; i < n; i++) {
        if (vr[i] == TIME && at < n_values) { value[at++] = arm->time; continue; }
        if (vr[i] >= N_REFERENCES || vr[i] == HELD || !SIZE[vr[i]] || at + SIZE[vr[i]] > n_values) {
            log_error(arm, "fmi3GetFloat64: not a Float64 value reference, or nValues too small");
            return fmi3Error;
        }
        for (int k = 0; k < SIZE[vr[i]]; k++) value[at++] = arm->real[vr[i] + k];
    }
    if (at != n_values) { log_error(arm, "fmi3GetFloat64: nValues is not the number of elements"); return fmi3Error; }
    return fmi3OK;
}

fmi3Status fmi3SetFloat64(fmi3Instance c, const fmi3ValueReference vr[], size_t n, const fmi3Float64 value[],
                          size_t n_values) {
    Arm *arm = c;
    size_t at = 0;
    for (size_t i = 0; i < n; i++) {
        if (!settable_real(vr[i]) || !SIZE[vr[i]] || at + SIZE[vr[i]] > n_values) {
            log_error(arm, "fmi3SetFloat64: not an input or parameter, or nValues too small");
            return fmi3Error;
        }
        for (int k = 0; k < SIZE[vr[i]]; k++) arm->real[vr[i] + k] = value[at++];
    }
    if (at != n_values) { log_error(arm, "fmi3SetFloat64: nValues is not the number of elements"); return fmi3Error; }
    return fmi3OK;
}

/* The only Boolean is HELD, a scalar: 1 (logged) unless every reference is HELD and nValues their number. */
static int not_booleans(Arm *arm, const fmi3ValueReference vr[], size_t n, size_t n_values, const char *message) {
    for (size_t i = 0; i < n; i++)
        if (vr[i] != HELD || n != n_values) { log_error(arm, message); return 1; }
    return 0;
}

fmi3Status fmi3GetBoolean(fmi3Instance c, const fmi3ValueReference vr[], size_t n, fmi3Boolean value[],
                          size_t n_values) {
    if (not_booleans(c, vr, n, n_values, "fmi3GetBoolean: not a Boolean value reference")) return fmi3Error;
    for (size_t i = 0; i < n; i++) value[i] = ((Arm *)c)->held;
    return fmi3OK;
}

fmi3Status fmi3SetBoolean(fmi3Instance c, const fmi3ValueReference vr[], size_t n, const fmi3Boolean value[],
                          size_t n_values) {
    if (not_booleans(c, vr, n, n_values, "fmi3SetBoolean: not a Boolean value reference")) return fmi3Error;
    for (size_t i = 0; i < n; i++) ((Arm *)c)->held = value[i];
    return fmi3OK;
}

fmi3Status fmi3DoStep(fmi3Instance c, fmi3Float64 t, fmi3Float64 h, fmi3Boolean no_prior_state,
                      fmi3Boolean *event_needed, fmi3Boolean *terminate, fmi3Boolean *early_return,
                      fmi3Float64 *last_successful_time) {
    Arm *arm = c;
    *event_needed = *terminate = *early_return = fmi3False;
    *last_successful_time = t;
    if (step(arm, h)) return fmi3Error;
    arm->time = *last_successful_time = t + h;
    return fmi3OK;
}

/* What this FMU does not offer (no other types, states, derivatives, clocks, events; the description says so):
 * a get or set of no values succeeds, any other call is an error. */
#define NO_GET(T) fmi3Status fmi3Get##T(fmi3Instance c, const fmi3ValueReference vr[], size_t n, fmi3##T v[], \
                                        size_t nv) { return n ? fmi3Error : fmi3OK; }
#define NO_SET(T) fmi3Status fmi3Set##T(fmi3Instance c, const fmi3ValueReference vr[], size_t n, const fmi3##T v[], \
                                        size_t nv) { return n ? fmi3Error : fmi3OK; }
#define NO_VALUES(T) NO_GET(T) NO_SET(T)
NO_VALUES(Float32) NO_VALUES(Int8) NO_VALUES(UInt8) NO_VALUES(Int16) NO_VALUES(UInt16) NO_VALUES(Int32)
NO_VALUES(UInt32) NO_VALUES(Int64) NO_VALUES(UInt64) NO_VALUES(String)
#define ERROR3(F, ...) fmi3Status F(fmi3Instance c, __VA_ARGS__) { return fmi3Error; }
#define VRS const fmi3ValueReference vr[], size_t n
ERROR3(fmi3GetBinary, VRS, size_t sizes[], fmi3Binary v[], size_t nv)
ERROR3(fmi3SetBinary, VRS, const size_t sizes[], const fmi3Binary v[], size_t nv)
ERROR3(fmi3GetClock, VRS, fmi3Clock v[]) ERROR3(fmi3SetClock, VRS, const fmi3Clock v[])
ERROR3(fmi3GetNumberOfVariableDependencies, fmi3ValueReference vr, size_t *n)
ERROR3(fmi3GetVariableDependencies, fmi3ValueReference dependent, size_t element[],
       fmi3ValueReference independents[], size_t independent_element[], fmi3DependencyKind kinds[], size_t n)
ERROR3(fmi3GetFMUState, fmi3FMUState *s) ERROR3(fmi3SetFMUState, fmi3FMUState s)
ERROR3(fmi3FreeFMUState, fmi3FMUState *s) ERROR3(fmi3SerializedFMUStateSize, fmi3FMUState s, size_t *n)
ERROR3(fmi3SerializeFMUState, fmi3FMUState s, fmi3Byte b[], size_t n)
ERROR3(fmi3DeserializeFMUState, const fmi3Byte b[], size_t n, fmi3FMUState *s)
#define DERIVATIVE VRS, const fmi3ValueReference k[], size_t nk, const fmi3Float64 seed[], size_t ns, \
                   fmi3Float64 d[], size_t nd
ERROR3(fmi3GetDirectionalDerivative, DERIVATIVE) ERROR3(fmi3GetAdjointDerivative, DERIVATIVE)
fmi3Status fmi3EnterConfigurationMode(fmi3Instance c) { return fmi3Error; }
fmi3Status fmi3ExitConfigurationMode(fmi3Instance c) { return fmi3Error; }
ERROR3(fmi3GetIntervalDecimal, VRS, fmi3Float64 v[], fmi3IntervalQualifier q[])
ERROR3(fmi3GetIntervalFraction, VRS, fmi3UInt64 v[], fmi3UInt64 r[], fmi3IntervalQualifier q[])
ERROR3(fmi3GetShiftDecimal, VRS, fmi3Float64 v[]) ERROR3(fmi3GetShiftFraction, VRS, fmi3UInt64 v[], fmi3UInt64 r[])
ERROR3(fmi3SetIntervalDecimal, VRS, const fmi3Float64 v[])
ERROR3(fmi3SetIntervalFraction, VRS, const fmi3UInt64 v[], const fmi3UInt64 r[])
ERROR3(fmi3SetShiftDecimal, VRS, const fmi3Float64 v[])
ERROR3(fmi3SetShiftFraction, VRS, const fmi3UInt64 v[], const fmi3UInt64 r[])
fmi3Status fmi3EvaluateDiscreteStates(fmi3Instance c) { return fmi3Error; }
ERROR3(fmi3UpdateDiscreteStates, fmi3Boolean *update, fmi3Boolean *terminate, fmi3Boolean *nominals,
       fmi3Boolean *values, fmi3Boolean *next_defined, fmi3Float64 *next)
fmi3Status fmi3EnterContinuousTimeMode(fmi3Instance c) { return fmi3Error; }
ERROR3(fmi3CompletedIntegratorStep, fmi3Boolean no_prior, fmi3Boolean *event, fmi3Boolean *terminate)
ERROR3(fmi3SetTime, fmi3Float64 t) ERROR3(fmi3SetContinuousStates, const fmi3Float64 v[], size_t n)
ERROR3(fmi3GetContinuousStateDerivatives, fmi3Float64 v[], size_t n)
ERROR3(fmi3GetEventIndicators, fmi3Float64 v[], size_t n) ERROR3(fmi3GetContinuousStates, fmi3Float64 v[], size_t n)
ERROR3(fmi3GetNominalsOfContinuousStates, fmi3Float64 v[], size_t n)
fmi3Status fmi3GetNumberOfEventIndicators(fmi3Instance c, size_t *n) { *n = 0; return fmi3OK; }
fmi3Status fmi3GetNumberOfContinuousStates(fmi3Instance c, size_t *n) { *n = 0; return fmi3OK; }
ERROR3(fmi3GetOutputDerivatives, VRS, const fmi3Int32 order[], fmi3Float64 v[], size_t nv)
ERROR3(fmi3ActivateModelPartition, fmi3ValueReference clock, fmi3Float64 t)

#else
/* ---- FMI 2.0 co-simulation ------------------------------------------------------------------ */
const char *fmi2GetTypesPlatform(void) { return fmi2TypesPlatform; }
const char *fmi2GetVersion(void) { return fmi2Version; }
fmi2Status fmi2SetDebugLogging(fmi2Component c, fmi2Boolean on, size_t n, const fmi2String categories[]) {
    return fmi2OK;
}

fmi2Component fmi2Instantiate(fmi2String name, fmi2Type type, fmi2String guid, fmi2String resources,
                              const fmi2CallbackFunctions *callbacks, fmi2Boolean visible, fmi2Boolean logging) {
    if (type != fmi2CoSimulation) return NULL;
    Arm *arm = new_arm(name);
    if (!arm) return NULL;
    arm->callbacks = *callbacks;
    return arm;
}

void fmi2FreeInstance(fmi2Component c) { free_arm(c); }

fmi2Status fmi2SetupExperiment(fmi2Component c, fmi2Boolean tolerance_defined, fmi2Real tolerance,
                               fmi2Real start, fmi2Boolean stop_defined, fmi2Real stop) { return fmi2OK; }
fmi2Status fmi2EnterInitializationMode(fmi2Component c) { initialize(c); return fmi2OK; }
fmi2Status fmi2ExitInitializationMode(fmi2Component c) { initialize(c); return fmi2OK; }
fmi2Status fmi2Terminate(fmi2Component c) { return fmi2OK; }
fmi2Status fmi2Reset(fmi2Component c) { start_values(c); return fmi2OK; }

fmi2Status fmi2GetReal(fmi2Component c, const fmi2ValueReference vr[], size_t n, fmi2Real value[]) {
    Arm *arm = c;
    for (size_t i = 0; i < n; i++) {
        if (vr[i] >= N_REFERENCES || vr[i] == HELD) {
            log_error(arm, "fmi2GetReal: not a Real value reference");
            return fmi2Error;
        }
        value[i] = arm->real[vr[i]];
    }
    return fmi2OK;
}

fmi2Status fmi2SetReal(fmi2Component c, const fmi2ValueReference vr[], size_t n, const fmi2Real value[]) {
    Arm *arm = c;
    for (size_t i = 0; i < n; i++) {
        if (!settable_real(vr[i])) {
            log_error(arm, "fmi2SetReal: not an input or parameter");
            return fmi2Error;
        }
        arm->real[vr[i]] = value[i];
    }
    return fmi2OK;
}

fmi2Status fmi2GetBoolean(fmi2Component c, const fmi2ValueReference vr[], size_t n, fmi2Boolean value[]) {
    Arm *arm = c;
    for (size_t i = 0; i < n; i++) {
        if (vr[i] != HELD) { log_error(arm, "fmi2GetBoolean: unknown value reference"); return fmi2Error; }
        value[i] = arm->held;
    }
    return fmi2OK;
}

fmi2Status fmi2SetBoolean(fmi2Component c, const fmi2ValueReference vr[], size_t n, const fmi2Boolean value[]) {
    Arm *arm = c;
    for (size_t i = 0; i < n; i++) {
        if (vr[i] != HELD) { log_error(arm, "fmi2SetBoolean: unknown value reference"); return fmi2Error; }
        arm->held = value[i];
    }
    return fmi2OK;
}

fmi2Status fmi2DoStep(fmi2Component c, fmi2Real t, fmi2Real h, fmi2Boolean no_prior_state) {
    return step(c, h) ? fmi2Error : fmi2OK;
}

/* What this FMU does not offer (canGetAndSetFMUstate etc. are false in its description): a get or set of no
 * values succeeds, any other call is an error. */
#define NO_VALUES2(T, V) \
    fmi2Status fmi2Get##T(fmi2Component c, const fmi2ValueReference vr[], size_t n, V v[]) { \
        return n ? fmi2Error : fmi2OK; } \
    fmi2Status fmi2Set##T(fmi2Component c, const fmi2ValueReference vr[], size_t n, const V v[]) { \
        return n ? fmi2Error : fmi2OK; }
NO_VALUES2(Integer, fmi2Integer) NO_VALUES2(String, fmi2String)
#define ERROR2(F, ...) fmi2Status F(fmi2Component c, __VA_ARGS__) { return fmi2Error; }
ERROR2(fmi2GetFMUstate, fmi2FMUstate *s) ERROR2(fmi2SetFMUstate, fmi2FMUstate s)
ERROR2(fmi2FreeFMUstate, fmi2FMUstate *s) ERROR2(fmi2SerializedFMUstateSize, fmi2FMUstate s, size_t *n)
ERROR2(fmi2SerializeFMUstate, fmi2FMUstate s, fmi2Byte b[], size_t n)
ERROR2(fmi2DeSerializeFMUstate, const fmi2Byte b[], size_t n, fmi2FMUstate *s)
ERROR2(fmi2GetDirectionalDerivative, const fmi2ValueReference u[], size_t nu, const fmi2ValueReference z[], size_t nz,
       const fmi2Real dv[], fmi2Real dz[])
ERROR2(fmi2SetRealInputDerivatives, const fmi2ValueReference vr[], size_t n, const fmi2Integer order[],
       const fmi2Real value[])
ERROR2(fmi2GetRealOutputDerivatives, const fmi2ValueReference vr[], size_t n, const fmi2Integer order[],
       fmi2Real value[])
fmi2Status fmi2CancelStep(fmi2Component c) { return fmi2Error; }
fmi2Status fmi2GetStatus(fmi2Component c, const fmi2StatusKind k, fmi2Status *v) { return fmi2Discard; }
fmi2Status fmi2GetRealStatus(fmi2Component c, const fmi2StatusKind k, fmi2Real *v) { return fmi2Discard; }
fmi2Status fmi2GetIntegerStatus(fmi2Component c, const fmi2StatusKind k, fmi2Integer *v) { return fmi2Discard; }
fmi2Status fmi2GetBooleanStatus(fmi2Component c, const fmi2StatusKind k, fmi2Boolean *v) { return fmi2Discard; }
fmi2Status fmi2GetStringStatus(fmi2Component c, const fmi2StatusKind k, fmi2String *v) { return fmi2Discard; }
#endif
