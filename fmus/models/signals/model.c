/* model.c -- see config.h. */
#include <stdio.h>
#include <string.h>

#include "model.h"

#define M(v) (comp->modelData.v)

static const char *const variableNames[NUMBER_OF_VARIABLES] = {
    "time", "enable", "u", "prefix", "gain", "y", "label", "count"
};

const char *variableName(unsigned int vr) {
    return vr < NUMBER_OF_VARIABLES ? variableNames[vr] : NULL;
}

void setStartValues(ModelInstance *comp) {
    int k;
    M(enable) = true;
    for (k = 0; k < N; k++) {
        M(u)[k] = k + 1.0;
        M(y)[k] = 0.0;
    }
    strcpy(M(prefix), "ball ");
    M(gain)  = 2.0;
    M(count) = 0;
    comp->isDirtyValues = true;
}

Status calculateValues(ModelInstance *comp) {
    snprintf(M(label), sizeof M(label), "%s%s", M(prefix), M(enable) ? "on" : "off");
    comp->isDirtyValues = false;
    return OK;
}

size_t float64Size(unsigned int vr) {
    return (vr == vr_u || vr == vr_y) ? N : 1;
}

Status getFloat64(ModelInstance *comp, unsigned int vr, double *value) {
    return getFloat64Element(comp, vr, 0, value);
}

Status getFloat64Element(ModelInstance *comp, unsigned int vr, size_t k, double *value) {
    switch ((ValueReference)vr) {
        case vr_time: *value = comp->time; return OK;
        case vr_u:    *value = M(u)[k];    return OK;
        case vr_gain: *value = M(gain);    return OK;
        case vr_y:    *value = M(y)[k];    return OK;
        default:
            logError(comp, "Variable %u is not a Float64.", vr);
            return Error;
    }
}

Status setFloat64(ModelInstance *comp, unsigned int vr, double value) {
    return setFloat64Element(comp, vr, 0, value);
}

Status setFloat64Element(ModelInstance *comp, unsigned int vr, size_t k, double value) {
    switch ((ValueReference)vr) {
        case vr_u:    M(u)[k] = value; break;
        case vr_gain: M(gain) = value; break;
        default:
            logError(comp, "Variable %u cannot be set.", vr);
            return Error;
    }
    comp->isDirtyValues = true;
    return OK;
}

Status getInt32(ModelInstance *comp, unsigned int vr, int *value) {
    if (vr != vr_count) {
        logError(comp, "Variable %u is not an Int32.", vr);
        return Error;
    }
    *value = M(count);
    return OK;
}

Status setInt32(ModelInstance *comp, unsigned int vr, int value) {
    (void)value;
    logError(comp, "Variable %u cannot be set.", vr);
    return Error;
}

Status getBoolean(ModelInstance *comp, unsigned int vr, bool *value) {
    if (vr != vr_enable) {
        logError(comp, "Variable %u is not a Boolean.", vr);
        return Error;
    }
    *value = M(enable);
    return OK;
}

Status setBoolean(ModelInstance *comp, unsigned int vr, bool value) {
    if (vr != vr_enable) {
        logError(comp, "Variable %u cannot be set.", vr);
        return Error;
    }
    M(enable) = value;
    comp->isDirtyValues = true;
    return OK;
}

Status getString(ModelInstance *comp, unsigned int vr, const char **value) {
    if (comp->isDirtyValues) {
        calculateValues(comp);
    }
    switch ((ValueReference)vr) {
        case vr_prefix: *value = M(prefix); return OK;
        case vr_label:  *value = M(label);  return OK;
        default:
            logError(comp, "Variable %u is not a String.", vr);
            return Error;
    }
}

Status setString(ModelInstance *comp, unsigned int vr, const char *value) {
    if (vr != vr_prefix || !value || strlen(value) >= LABEL_SIZE) {
        logError(comp, "Variable %u cannot be set to that.", vr);
        return Error;
    }
    strcpy(M(prefix), value);
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
    int k;
    if (M(enable)) {
        for (k = 0; k < N; k++) {
            M(y)[k] += M(gain) * M(u)[k] * h;
        }
    }
    M(count)++;
    comp->isDirtyValues = true;
    return OK;
}
