/*
 * model.c -- counter = min(maximum, 1 + floor(time / period)): it steps up by one at
 * every multiple of `period` (a time event; co-simulation only, so the step is taken at
 * the first communication point at or after the event).
 */
#include <math.h>

#include "model.h"

#define M(v) (comp->modelData.v)

static const char *const variableNames[NUMBER_OF_VARIABLES] = {
    "time", "period", "maximum", "counter"
};

const char *variableName(unsigned int vr) {
    return vr < NUMBER_OF_VARIABLES ? variableNames[vr] : NULL;
}

void setStartValues(ModelInstance *comp) {
    M(period)  = 1.0;
    M(maximum) = 10;
    M(counter) = 1;
    comp->isDirtyValues = true;
}

static int counterAt(ModelInstance *comp, double t) {
    /* the 1e-9 keeps t = k * period (up to rounding) on the step it starts */
    int n = 1 + (int)floor(t / M(period) + 1e-9);
    return n < M(maximum) ? n : M(maximum);
}

Status calculateValues(ModelInstance *comp) {
    if (comp->state & (Instantiated | InitializationMode)) {
        M(counter) = counterAt(comp, comp->time);
    }
    comp->isDirtyValues = false;
    return OK;
}

Status getFloat64(ModelInstance *comp, unsigned int vr, double *value) {
    switch ((ValueReference)vr) {
        case vr_time:   *value = comp->time; return OK;
        case vr_period: *value = M(period);  return OK;
        default:
            logError(comp, "Unknown Real value reference %u.", vr);
            return Error;
    }
}

Status setFloat64(ModelInstance *comp, unsigned int vr, double value) {
    if (vr != vr_period || !(comp->state & (Instantiated | InitializationMode))) {
        logError(comp, "Variable %u cannot be set now.", vr);
        return Error;
    }
    if (!(value >= 0.1 && value <= 10.0)) {
        logError(comp, "period = %g is outside [0.1, 10].", value);
        return Error;
    }
    M(period) = value;
    comp->isDirtyValues = true;
    return OK;
}

Status getInt32(ModelInstance *comp, unsigned int vr, int *value) {
    if (comp->isDirtyValues) {
        calculateValues(comp);
    }
    switch ((ValueReference)vr) {
        case vr_maximum: *value = M(maximum); return OK;
        case vr_counter: *value = M(counter); return OK;
        default:
            logError(comp, "Unknown Integer value reference %u.", vr);
            return Error;
    }
}

Status setInt32(ModelInstance *comp, unsigned int vr, int value) {
    if (vr != vr_maximum || !(comp->state & (Instantiated | InitializationMode))) {
        logError(comp, "Variable %u cannot be set now.", vr);
        return Error;
    }
    M(maximum) = value;
    comp->isDirtyValues = true;
    return OK;
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

Status doStep(ModelInstance *comp, double h) {
    M(counter) = counterAt(comp, comp->time + h);
    return OK;
}
