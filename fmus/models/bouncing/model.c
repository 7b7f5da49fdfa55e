/*
 * model.c -- der(h) = v, der(v) = -g; at h <= 0 going down: v = -e v (and the ball
 * stays on the ground once the rebound is slower than V_MIN). Co-simulation integrates
 * with explicit Euler at FIXED_STEP (the last sub-step shorter) inside each doStep.
 */
#include <math.h>

#include "model.h"

#define M(v) (comp->modelData.v)

static const char *const variableNames[NUMBER_OF_VARIABLES] = {
    "time", "h", "v", "g", "e", "h0"
};

const char *variableName(unsigned int vr) {
    return vr < NUMBER_OF_VARIABLES ? variableNames[vr] : NULL;
}

void setStartValues(ModelInstance *comp) {
    M(h0) = 1.0;
    M(h)  = 1.0;
    M(v)  = 0.0;
    M(g)  = 9.81;
    M(e)  = 0.7;
    comp->isDirtyValues = true;
}

Status calculateValues(ModelInstance *comp) {
    if (comp->state & (Instantiated | InitializationMode)) {
        M(h) = M(h0);
        M(v) = 0.0;
    }
    comp->isDirtyValues = false;
    return OK;
}

Status getFloat64(ModelInstance *comp, unsigned int vr, double *value) {
    if (comp->isDirtyValues) {
        calculateValues(comp);
    }
    switch ((ValueReference)vr) {
        case vr_time: *value = comp->time; return OK;
        case vr_h:    *value = M(h);       return OK;
        case vr_v:    *value = M(v);       return OK;
        case vr_g:    *value = M(g);       return OK;
        case vr_e:    *value = M(e);       return OK;
        case vr_h0:   *value = M(h0);      return OK;
        default:
            logError(comp, "Unknown value reference %u.", vr);
            return Error;
    }
}

Status setFloat64(ModelInstance *comp, unsigned int vr, double value) {
    bool init = (comp->state & (Instantiated | InitializationMode)) != 0;
    switch ((ValueReference)vr) {
        case vr_g:
        case vr_h0:
            if (!init) {
                logError(comp, "Variable \"%s\" is a fixed parameter.", variableName(vr));
                return Error;
            }
            if (vr == vr_g) M(g) = value; else M(h0) = value;
            break;
        case vr_e:
            if (!(value >= 0.0 && value <= 1.0)) {
                logError(comp, "e = %g is outside [0, 1].", value);
                return Error;
            }
            M(e) = value;
            break;
        default:
            logError(comp, "Variable %u cannot be set.", vr);
            return Error;
    }
    comp->isDirtyValues = true;
    return OK;
}

void getContinuousStates(ModelInstance *comp, double x[], size_t nx) {
    (void)nx;
    x[0] = M(h);
    x[1] = M(v);
}

Status setContinuousStates(ModelInstance *comp, const double x[], size_t nx) {
    (void)nx;
    M(h) = x[0];
    M(v) = x[1];
    return OK;
}

void getNominalsOfContinuousStates(ModelInstance *comp, double nominals[], size_t nx) {
    size_t i;
    (void)comp;
    for (i = 0; i < nx; i++) nominals[i] = 1.0;
}

void getDerivatives(ModelInstance *comp, double dx[], size_t nx) {
    (void)nx;
    dx[0] = M(v);
    dx[1] = -M(g);
}

Status doStep(ModelInstance *comp, double h) {
    double done = 0.0;
    if (comp->isDirtyValues) {
        calculateValues(comp);
    }
    while (done < h) {
        double dt = h - done < FIXED_STEP * 1.000001 ? h - done : FIXED_STEP;
        M(h) += M(v) * dt;
        M(v) -= M(g) * dt;
        if (M(h) <= 0.0 && M(v) < 0.0) {
            M(h) = 0.0;
            M(v) = -M(e) * M(v);
            if (M(v) < V_MIN) {
                M(v) = 0.0;
                M(g) = 0.0;     /* lies still */
            }
        }
        done += dt;
    }
    return OK;
}
