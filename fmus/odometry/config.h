/*
 * config.h -- model-specific configuration of the kinematic odometry FMU.
 *
 * The generic FMI wrappers (wrapper/fmi2Functions.c, wrapper/fmi3Functions.c)
 * include this file through model.h; everything odometry-specific that they
 * need (identifier, token, sizes, the ModelData layout) lives here.
 *
 * The GUID / instantiationToken below must equal the one in
 * modelDescription2.xml and modelDescription3.xml (fmus/build.py checks it).
 */
#ifndef ODOMETRY_CONFIG_H
#define ODOMETRY_CONFIG_H

#define MODEL_IDENTIFIER     odometry
#define MODEL_NAME           "odometry"
#define INSTANTIATION_TOKEN  "{88c50c21-a284-4ff3-b41a-9ebe1bbb929c}"

/* number of continuous states and of event indicators */
#define NX 3
#define NZ 0

/* value references (identical in FMI 2 and FMI 3) */
typedef enum {
    vr_time             = 0,   /* independent variable, s                 */
    vr_omega_left       = 1,   /* input,  rad/s                           */
    vr_omega_right      = 2,   /* input,  rad/s                           */
    vr_wheel_radius     = 3,   /* fixed parameter, m                      */
    vr_wheel_separation = 4,   /* fixed parameter, m                      */
    vr_x0               = 5,   /* fixed parameter, m                      */
    vr_y0               = 6,   /* fixed parameter, m                      */
    vr_theta0           = 7,   /* fixed parameter, rad                    */
    vr_x                = 8,   /* output + continuous state, m            */
    vr_y                = 9,   /* output + continuous state, m            */
    vr_theta            = 10,  /* output + continuous state, rad          */
    vr_der_x            = 11,  /* der(x), m/s                             */
    vr_der_y            = 12,  /* der(y), m/s                             */
    vr_der_theta        = 13,  /* der(theta), rad/s                       */
    vr_v                = 14,  /* output, forward speed, m/s              */
    vr_omega            = 15,  /* output, yaw rate, rad/s                 */
    NUMBER_OF_VARIABLES = 16
} ValueReference;

/* start values */
#define START_WHEEL_RADIUS      0.12
#define START_WHEEL_SEPARATION  0.36

typedef struct {
    /* inputs */
    double omega_left;
    double omega_right;
    /* parameters */
    double wheel_radius;
    double wheel_separation;
    double x0;
    double y0;
    double theta0;
    /* continuous states */
    double x;
    double y;
    double theta;
    /* calculated values (see calculateValues in model.c) */
    double der_x;
    double der_y;
    double der_theta;
    double v;
    double omega;
} ModelData;

#endif /* ODOMETRY_CONFIG_H */
