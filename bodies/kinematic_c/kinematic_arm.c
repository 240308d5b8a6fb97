/* A body written in C: the ideal kinematic arm of components/body/variants.py as an FMI 2.0
 * co-simulation FMU, meeting the body contract of docs/design.md.
 *
 * Free: the joints follow the command exactly, q(t + h) = q(t) + h u.
 * Held: the joints do not move; the hand force is the statics of the servo, tau = clip(K u, +-limit)
 * (u in rad/s) balanced at the clamped hand, F = J^-T tau, J = d(hand)/d(angles) in m/rad.
 * Geometry (docs/design.md): shoulder at (-0.20, 0), upper arm 0.3595 m, forearm 0.3694 m; angles in deg,
 * the shoulder from +x, the elbow relative to the upper arm.
 *
 * Built by master/export/c_body.py with the FMI 2.0 headers that fmpy ships. One instance is one trial.
 */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "fmi2Functions.h"

#define SHOULDER_X (-0.20)
#define SHOULDER_Y 0.0
#define UPPER_ARM 0.3595
#define FOREARM 0.3694
#define PI 3.14159265358979323846

/* Value references: the declaration order of the Python KinematicArm, from which the builder writes
 * modelDescription.xml (8 is the Boolean `held`). Start values come from the same declarations, as
 * -D definitions: START_Q0_SHOULDER, START_Q0_ELBOW, START_SERVO_GAIN, START_TORQUE_LIMIT, START_HELD. */
enum { U_SHOULDER, U_ELBOW, Q_SHOULDER, Q_ELBOW, HAND_X, HAND_Y, FORCE_X, FORCE_Y, HELD,
       Q0_SHOULDER, Q0_ELBOW, SERVO_GAIN, TORQUE_LIMIT, N_REFERENCES };

typedef struct {
    fmi2Real real[N_REFERENCES];  /* by value reference; [HELD] unused */
    fmi2Boolean held;
    fmi2CallbackFunctions callbacks;
    char *name;
} Arm;

static void log_error(Arm *arm, const char *message) {
    if (arm->callbacks.logger)
        arm->callbacks.logger(arm->callbacks.componentEnvironment, arm->name, fmi2Error, "error", "%s", message);
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
    publish(arm, 0);
}

/* ---- FMI 2.0 co-simulation ------------------------------------------------------------------ */
const char *fmi2GetTypesPlatform(void) { return fmi2TypesPlatform; }
const char *fmi2GetVersion(void) { return fmi2Version; }
fmi2Status fmi2SetDebugLogging(fmi2Component c, fmi2Boolean on, size_t n, const fmi2String categories[]) {
    return fmi2OK;
}

fmi2Component fmi2Instantiate(fmi2String name, fmi2Type type, fmi2String guid, fmi2String resources,
                              const fmi2CallbackFunctions *callbacks, fmi2Boolean visible, fmi2Boolean logging) {
    if (type != fmi2CoSimulation) return NULL;
    Arm *arm = calloc(1, sizeof(Arm));
    if (!arm) return NULL;
    arm->callbacks = *callbacks;
    if (!name) name = "arm";
    arm->name = malloc(strlen(name) + 1);
    if (!arm->name) { free(arm); return NULL; }
    strcpy(arm->name, name);
    start_values(arm);
    return arm;
}

void fmi2FreeInstance(fmi2Component c) {
    Arm *arm = c;
    if (!arm) return;
    free(arm->name);
    free(arm);
}

fmi2Status fmi2SetupExperiment(fmi2Component c, fmi2Boolean tolerance_defined, fmi2Real tolerance,
                               fmi2Real start, fmi2Boolean stop_defined, fmi2Real stop) { return fmi2OK; }

fmi2Status fmi2EnterInitializationMode(fmi2Component c) {
    Arm *arm = c;  /* the parameters are in: the arm starts at q0 */
    arm->real[Q_SHOULDER] = arm->real[Q0_SHOULDER];
    arm->real[Q_ELBOW] = arm->real[Q0_ELBOW];
    publish(arm, 0);
    return fmi2OK;
}

fmi2Status fmi2ExitInitializationMode(fmi2Component c) { return fmi2EnterInitializationMode(c); }
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
        if (vr[i] >= N_REFERENCES || (vr[i] >= Q_SHOULDER && vr[i] <= HELD)) {
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
    Arm *arm = c;
    double *r = arm->real;
    if (!isfinite(r[U_SHOULDER]) || !isfinite(r[U_ELBOW])) {
        log_error(arm, "commanded velocity is not finite");
        return fmi2Error;
    }
    if (!arm->held) {
        r[Q_SHOULDER] += h * r[U_SHOULDER];
        r[Q_ELBOW] += h * r[U_ELBOW];
    }
    publish(arm, 1);
    return fmi2OK;
}

/* What this FMU does not offer (canGetAndSetFMUstate etc. are false in its description). */
fmi2Status fmi2GetInteger(fmi2Component c, const fmi2ValueReference vr[], size_t n, fmi2Integer v[]) {
    return n ? fmi2Error : fmi2OK;
}
fmi2Status fmi2SetInteger(fmi2Component c, const fmi2ValueReference vr[], size_t n, const fmi2Integer v[]) {
    return n ? fmi2Error : fmi2OK;
}
fmi2Status fmi2GetString(fmi2Component c, const fmi2ValueReference vr[], size_t n, fmi2String v[]) {
    return n ? fmi2Error : fmi2OK;
}
fmi2Status fmi2SetString(fmi2Component c, const fmi2ValueReference vr[], size_t n, const fmi2String v[]) {
    return n ? fmi2Error : fmi2OK;
}
fmi2Status fmi2GetFMUstate(fmi2Component c, fmi2FMUstate *s) { return fmi2Error; }
fmi2Status fmi2SetFMUstate(fmi2Component c, fmi2FMUstate s) { return fmi2Error; }
fmi2Status fmi2FreeFMUstate(fmi2Component c, fmi2FMUstate *s) { return fmi2Error; }
fmi2Status fmi2SerializedFMUstateSize(fmi2Component c, fmi2FMUstate s, size_t *n) { return fmi2Error; }
fmi2Status fmi2SerializeFMUstate(fmi2Component c, fmi2FMUstate s, fmi2Byte b[], size_t n) { return fmi2Error; }
fmi2Status fmi2DeSerializeFMUstate(fmi2Component c, const fmi2Byte b[], size_t n, fmi2FMUstate *s) {
    return fmi2Error;
}
fmi2Status fmi2GetDirectionalDerivative(fmi2Component c, const fmi2ValueReference u[], size_t nu,
                                        const fmi2ValueReference z[], size_t nz, const fmi2Real dv[],
                                        fmi2Real dz[]) { return fmi2Error; }
fmi2Status fmi2SetRealInputDerivatives(fmi2Component c, const fmi2ValueReference vr[], size_t n,
                                       const fmi2Integer order[], const fmi2Real value[]) { return fmi2Error; }
fmi2Status fmi2GetRealOutputDerivatives(fmi2Component c, const fmi2ValueReference vr[], size_t n,
                                        const fmi2Integer order[], fmi2Real value[]) { return fmi2Error; }
fmi2Status fmi2CancelStep(fmi2Component c) { return fmi2Error; }
fmi2Status fmi2GetStatus(fmi2Component c, const fmi2StatusKind k, fmi2Status *v) { return fmi2Discard; }
fmi2Status fmi2GetRealStatus(fmi2Component c, const fmi2StatusKind k, fmi2Real *v) { return fmi2Discard; }
fmi2Status fmi2GetIntegerStatus(fmi2Component c, const fmi2StatusKind k, fmi2Integer *v) { return fmi2Discard; }
fmi2Status fmi2GetBooleanStatus(fmi2Component c, const fmi2StatusKind k, fmi2Boolean *v) { return fmi2Discard; }
fmi2Status fmi2GetStringStatus(fmi2Component c, const fmi2StatusKind k, fmi2String *v) { return fmi2Discard; }
