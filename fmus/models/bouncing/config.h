/*
 * config.h -- a ball falling under gravity and bouncing on the ground (Float64 outputs
 * h, v), written for the tests of `diffbot fmu-node` in the style of the Modelica
 * Reference-FMUs' BouncingBall (it is not that FMU). FMI 3.0 co-simulation.
 */
#ifndef BOUNCING_CONFIG_H
#define BOUNCING_CONFIG_H

#define MODEL_IDENTIFIER     bouncing
#define MODEL_NAME           "bouncing"
#define INSTANTIATION_TOKEN  "{0d6c3a52-8e1f-4b7a-a9c4-3f25e6d71b08}"

#define NX 2
#define NZ 0

typedef enum {
    vr_time = 0,   /* independent variable, s                     */
    vr_h    = 1,   /* output + state: height, m                   */
    vr_v    = 2,   /* output + state: vertical speed, m/s (up +)  */
    vr_g    = 3,   /* fixed parameter: gravity, m/s2              */
    vr_e    = 4,   /* tunable parameter: coefficient of restitution (0 .. 1) */
    vr_h0   = 5,   /* fixed parameter: start height, m            */
    NUMBER_OF_VARIABLES = 6
} ValueReference;

/* internal integration step, s (explicit Euler, bounce at the ground) */
#define FIXED_STEP 1e-3
/* below this speed after a bounce the ball lies still */
#define V_MIN 0.1

typedef struct {
    double h, v, g, e, h0;
} ModelData;

#endif
