/*
 * config.h -- a counter that steps up by one every `period` seconds (an Integer output),
 * written for the tests of `diffbot fmu-node` in the style of the Modelica Reference-FMUs'
 * Stair (it is not that FMU). FMI 2.0 co-simulation.
 */
#ifndef STAIRS_CONFIG_H
#define STAIRS_CONFIG_H

#define MODEL_IDENTIFIER     stairs
#define MODEL_NAME           "stairs"
#define INSTANTIATION_TOKEN  "{5b1d8f0e-2c47-4a51-9d3e-7f6a0c1b2e41}"
#define HAS_INT32            1

#define NX 0
#define NZ 0

typedef enum {
    vr_time    = 0,   /* independent variable, s                        */
    vr_period  = 1,   /* fixed parameter, s (0.1 .. 10)                 */
    vr_maximum = 2,   /* fixed Integer parameter: the counter stops there */
    vr_counter = 3,   /* Integer output: 1 + floor(time / period), capped */
    NUMBER_OF_VARIABLES = 4
} ValueReference;

typedef struct {
    double period;
    int    maximum;
    int    counter;
} ModelData;

#endif
