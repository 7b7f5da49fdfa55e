/*
 * model.c -- kinematic odometry of a differential-drive robot.
 *
 * Convention: x forward, y left, theta counter-clockwise (right-handed,
 * z up); theta is NOT wrapped to (-pi, pi].
 *
 *   v     = r (omega_right + omega_left) / 2         forward speed, m/s
 *   omega = r (omega_right - omega_left) / d         yaw rate, rad/s
 *
 *   der(x)     = v cos(theta)
 *   der(y)     = v sin(theta)
 *   der(theta) = omega
 *
 * with r = wheel_radius, d = wheel_separation, omega_left / omega_right the
 * wheel angular velocities (inputs, rad/s).
 *
 * Model exchange exposes (x, y, theta) as continuous states and the right-hand
 * side above. Co-simulation integrates the arc exactly for inputs held over
 * the step h (see doStep), so any step size is exact.
 */
#include <math.h>

#include "model.h"

#define M(v) (comp->modelData.v)

static const char *const variableNames[NUMBER_OF_VARIABLES] = {
    "time",
    "omega_left",
    "omega_right",
    "wheel_radius",
    "wheel_separation",
    "x0",
    "y0",
    "theta0",
    "x",
    "y",
    "theta",
    "der(x)",
    "der(y)",
    "der(theta)",
    "v",
    "omega"
};

const char *variableName(unsigned int vr) {
    return vr < NUMBER_OF_VARIABLES ? variableNames[vr] : NULL;
}

void setStartValues(ModelInstance *comp) {
    M(omega_left)       = 0.0;
    M(omega_right)      = 0.0;
    M(wheel_radius)     = START_WHEEL_RADIUS;
    M(wheel_separation) = START_WHEEL_SEPARATION;
    M(x0)               = 0.0;
    M(y0)               = 0.0;
    M(theta0)           = 0.0;
    M(x)                = 0.0;
    M(y)                = 0.0;
    M(theta)            = 0.0;
    comp->isDirtyValues = true;
}

Status calculateValues(ModelInstance *comp) {

    if (comp->state & (Instantiated | InitializationMode)) {
        /* the states are "calculated" from their initial-value parameters */
        M(x)     = M(x0);
        M(y)     = M(y0);
        M(theta) = M(theta0);
    }

    M(v)         = M(wheel_radius) * (M(omega_right) + M(omega_left)) / 2.0;
    M(omega)     = M(wheel_radius) * (M(omega_right) - M(omega_left)) / M(wheel_separation);
    M(der_x)     = M(v) * cos(M(theta));
    M(der_y)     = M(v) * sin(M(theta));
    M(der_theta) = M(omega);

    comp->isDirtyValues = false;
    return OK;
}

Status getFloat64(ModelInstance *comp, unsigned int vr, double *value) {

    if (vr >= NUMBER_OF_VARIABLES) {
        logError(comp, "Unknown value reference %u.", vr);
        return Error;
    }

    if (comp->isDirtyValues) {
        calculateValues(comp);
    }

    switch ((ValueReference)vr) {
        case vr_time:             *value = comp->time;        break;
        case vr_omega_left:       *value = M(omega_left);       break;
        case vr_omega_right:      *value = M(omega_right);      break;
        case vr_wheel_radius:     *value = M(wheel_radius);     break;
        case vr_wheel_separation: *value = M(wheel_separation); break;
        case vr_x0:               *value = M(x0);               break;
        case vr_y0:               *value = M(y0);               break;
        case vr_theta0:           *value = M(theta0);           break;
        case vr_x:                *value = M(x);                break;
        case vr_y:                *value = M(y);                break;
        case vr_theta:            *value = M(theta);            break;
        case vr_der_x:            *value = M(der_x);            break;
        case vr_der_y:            *value = M(der_y);            break;
        case vr_der_theta:        *value = M(der_theta);        break;
        case vr_v:                *value = M(v);                break;
        case vr_omega:            *value = M(omega);            break;
        default:
            logError(comp, "Unknown value reference %u.", vr);
            return Error;
    }

    return OK;
}

static bool isFinite(double value) {
    return !isnan(value) && !isinf(value);
}

Status setFloat64(ModelInstance *comp, unsigned int vr, double value) {

    const char *name = variableName(vr);

    if (!name) {
        logError(comp, "Unknown value reference %u.", vr);
        return Error;
    }

    switch ((ValueReference)vr) {

        case vr_omega_left:
        case vr_omega_right:
            if (!isFinite(value)) {
                logError(comp, "Variable \"%s\" (value reference %u): value %g is not finite.", name, vr, value);
                return Error;
            }
            if (vr == vr_omega_left) {
                M(omega_left) = value;
            } else {
                M(omega_right) = value;
            }
            break;

        case vr_wheel_radius:
        case vr_wheel_separation:
        case vr_x0:
        case vr_y0:
        case vr_theta0:
            if (!(comp->state & (Instantiated | InitializationMode))) {
                logError(comp, "Variable \"%s\" (value reference %u) is a fixed parameter: "
                         "it can only be set before fmiExitInitializationMode.", name, vr);
                return Error;
            }
            if (!isFinite(value)) {
                logError(comp, "Variable \"%s\" (value reference %u): value %g is not finite.", name, vr, value);
                return Error;
            }
            if ((vr == vr_wheel_radius || vr == vr_wheel_separation) && !(value > 0.0)) {
                logError(comp, "Variable \"%s\" (value reference %u): value %g must be > 0.", name, vr, value);
                return Error;
            }
            switch ((ValueReference)vr) {
                case vr_wheel_radius:     M(wheel_radius)     = value; break;
                case vr_wheel_separation: M(wheel_separation) = value; break;
                case vr_x0:               M(x0)               = value; break;
                case vr_y0:               M(y0)               = value; break;
                default:                  M(theta0)           = value; break;
            }
            break;

        default:
            logError(comp, "Variable \"%s\" (value reference %u) cannot be set.", name, vr);
            return Error;
    }

    comp->isDirtyValues = true;
    return OK;
}

void getContinuousStates(ModelInstance *comp, double x[], size_t nx) {
    (void)nx;
    if (comp->isDirtyValues) {
        calculateValues(comp);
    }
    x[0] = M(x);
    x[1] = M(y);
    x[2] = M(theta);
}

Status setContinuousStates(ModelInstance *comp, const double x[], size_t nx) {
    size_t i;
    (void)nx;
    for (i = 0; i < NX; i++) {
        if (!isFinite(x[i])) {
            logError(comp, "Continuous state %u (\"%s\"): value %g is not finite.",
                     (unsigned int)i, variableName(vr_x + (unsigned int)i), x[i]);
            return Error;
        }
    }
    M(x)     = x[0];
    M(y)     = x[1];
    M(theta) = x[2];
    comp->isDirtyValues = true;
    return OK;
}

void getNominalsOfContinuousStates(ModelInstance *comp, double nominals[], size_t nx) {
    size_t i;
    (void)comp;
    for (i = 0; i < nx; i++) {
        nominals[i] = 1.0;
    }
}

void getDerivatives(ModelInstance *comp, double dx[], size_t nx) {
    (void)nx;
    if (comp->isDirtyValues) {
        calculateValues(comp);
    }
    dx[0] = M(der_x);
    dx[1] = M(der_y);
    dx[2] = M(der_theta);
}

/*
 * Exact integration of the unicycle over [t, t + h] with v and omega held:
 * the robot moves along a circular arc (a straight line for omega = 0), whose
 * chord has length v h sinc(omega h / 2) and heading theta + omega h / 2.
 * The sinc form is numerically stable for omega -> 0 (no division by omega).
 */
Status doStep(ModelInstance *comp, double h) {

    double dtheta, half, s, ds;

    if (comp->isDirtyValues) {
        calculateValues(comp);
    }

    dtheta = M(omega) * h;
    half   = dtheta / 2.0;
    s      = (fabs(half) < 1e-9) ? 1.0 - half * half / 6.0 : sin(half) / half;
    ds     = M(v) * h * s;

    M(x)     += ds * cos(M(theta) + half);
    M(y)     += ds * sin(M(theta) + half);
    M(theta) += dtheta;

    comp->isDirtyValues = true;
    return OK;
}
