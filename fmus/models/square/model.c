/* model.c -- the square-path controller (controllers/square_path.py, one lap, left turns):
 * straight legs hold the heading the leg started with (proportional steering) and slow down
 * before the corner; corners turn in place to the next multiple of 90 degrees from the start
 * heading. Each step's command is decided at the step's start from the pose then (the
 * inputs) and is the output from the step's end on: one step of delay, as a bus controller
 * answering the plant's tick. */
#include <math.h>

#include "model.h"

#ifndef M_PI
#define M_PI 3.14159265358979323846
#endif

#define M(v) (comp->modelData.v)
#define LEGS 4

static const char *const variableNames[NUMBER_OF_VARIABLES] = {
    "time", "x", "y", "theta", "side", "speed", "turn_rate", "v", "w", "done" };

const char *variableName(unsigned int vr) {
    return vr < NUMBER_OF_VARIABLES ? variableNames[vr] : NULL;
}

void setStartValues(ModelInstance *comp) {
    M(x) = M(y) = M(theta) = 0.0;
    M(side) = 1.5;
    M(speed) = 0.2;
    M(turn_rate) = 0.5;
    M(v) = M(w) = M(done) = 0.0;
    M(started) = M(leg) = M(turning) = 0;
    M(heading0) = M(start_x) = M(start_y) = 0.0;
    comp->isDirtyValues = true;
}

Status calculateValues(ModelInstance *comp) {
    comp->isDirtyValues = false;    /* the outputs change in doStep only */
    return OK;
}

Status getFloat64(ModelInstance *comp, unsigned int vr, double *value) {
    switch ((ValueReference)vr) {
        case vr_time:      *value = comp->time;   return OK;
        case vr_x:         *value = M(x);         return OK;
        case vr_y:         *value = M(y);         return OK;
        case vr_theta:     *value = M(theta);     return OK;
        case vr_side:      *value = M(side);      return OK;
        case vr_speed:     *value = M(speed);     return OK;
        case vr_turn_rate: *value = M(turn_rate); return OK;
        case vr_v:         *value = M(v);         return OK;
        case vr_w:         *value = M(w);         return OK;
        case vr_done:      *value = M(done);      return OK;
        default:
            logError(comp, "Unknown value reference %u.", vr);
            return Error;
    }
}

Status setFloat64(ModelInstance *comp, unsigned int vr, double value) {
    if (!isfinite(value)) {
        logError(comp, "%s = %g: not a finite number.", variableName(vr) ? variableName(vr) : "?",
                 value);
        return Error;
    }
    switch ((ValueReference)vr) {
        case vr_x:     M(x) = value;     return OK;
        case vr_y:     M(y) = value;     return OK;
        case vr_theta: M(theta) = value; return OK;
        case vr_side: case vr_speed: case vr_turn_rate:
            if (comp->state != Instantiated && comp->state != InitializationMode) {
                logError(comp, "%s is a fixed parameter: set it before initialization ends.",
                         variableNames[vr]);
                return Error;
            }
            if (value <= 0) {
                logError(comp, "%s = %g: it must be positive.", variableNames[vr], value);
                return Error;
            }
            if (vr == vr_side) M(side) = value;
            else if (vr == vr_speed) M(speed) = value;
            else M(turn_rate) = value;
            return OK;
        default:
            logError(comp, "Variable %u cannot be set.", vr);
            return Error;
    }
}

void getContinuousStates(ModelInstance *comp, double x[], size_t nx) {
    (void)comp; (void)x; (void)nx;
}

Status setContinuousStates(ModelInstance *comp, const double x[], size_t nx) {
    (void)comp; (void)x; (void)nx;
    return OK;
}

void getNominalsOfContinuousStates(ModelInstance *comp, double nominals[], size_t nx) {
    (void)comp; (void)nominals; (void)nx;
}

void getDerivatives(ModelInstance *comp, double dx[], size_t nx) {
    (void)comp; (void)dx; (void)nx;
}

static double wrap(double a) {
    double r = fmod(a + M_PI, 2 * M_PI);
    if (r < 0) r += 2 * M_PI;
    return r - M_PI;
}

static double clamp(double v, double lo, double hi) {
    return v < lo ? lo : v > hi ? hi : v;
}

Status doStep(ModelInstance *comp, double h) {
    (void)h;
    if (M(done) > 0) {
        M(v) = M(w) = 0.0;
        return OK;
    }
    if (!M(started)) {
        M(started) = 1;
        M(heading0) = M(theta);
        M(start_x) = M(x);
        M(start_y) = M(y);
    }
    if (!M(turning)) {
        double remaining = M(side) - hypot(M(x) - M(start_x), M(y) - M(start_y));
        if (remaining <= 0.0005) {
            M(turning) = 1;
            if (M(leg) == LEGS - 1) M(done) = 1.0;
            M(v) = M(w) = 0.0;
            return OK;
        }
        M(v) = clamp(1.5 * remaining, 0.02, M(speed));
        M(w) = 2.0 * wrap(M(heading0) + M(leg) * M_PI / 2 - M(theta));
        return OK;
    }
    {
        double err = wrap(M(heading0) + (M(leg) + 1) * M_PI / 2 - M(theta));
        if (fabs(err) < 0.001) {
            M(leg) += 1;
            M(turning) = 0;
            M(start_x) = M(x);
            M(start_y) = M(y);
            M(v) = M(w) = 0.0;
            return OK;
        }
        M(v) = 0.0;
        M(w) = copysign(clamp(2.0 * fabs(err), 0.05, M(turn_rate)), err);
    }
    return OK;
}
