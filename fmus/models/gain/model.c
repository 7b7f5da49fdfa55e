/* model.c -- y = k u, with direct feed-through (no state). */
#include "model.h"

#define M(v) (comp->modelData.v)

static const char *const variableNames[NUMBER_OF_VARIABLES] = { "time", "u", "k", "y" };

const char *variableName(unsigned int vr) {
    return vr < NUMBER_OF_VARIABLES ? variableNames[vr] : NULL;
}

void setStartValues(ModelInstance *comp) {
    M(u) = 0.0;
    M(k) = 1.0;
    comp->isDirtyValues = true;
}

Status calculateValues(ModelInstance *comp) {
    M(y) = M(k) * M(u);
    comp->isDirtyValues = false;
    return OK;
}

Status getFloat64(ModelInstance *comp, unsigned int vr, double *value) {
    if (comp->isDirtyValues) {
        calculateValues(comp);
    }
    switch ((ValueReference)vr) {
        case vr_time: *value = comp->time; return OK;
        case vr_u:    *value = M(u);       return OK;
        case vr_k:    *value = M(k);       return OK;
        case vr_y:    *value = M(y);       return OK;
        default:
            logError(comp, "Unknown value reference %u.", vr);
            return Error;
    }
}

Status setFloat64(ModelInstance *comp, unsigned int vr, double value) {
    switch ((ValueReference)vr) {
        case vr_u: M(u) = value; break;
        case vr_k: M(k) = value; break;
        default:
            logError(comp, "Variable %u cannot be set.", vr);
            return Error;
    }
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
    (void)h;
    calculateValues(comp);
    return OK;
}
