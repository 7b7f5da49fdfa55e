/*
 * config.h -- y = k u (Float64 input, output and parameter): a test model of
 * `diffbot fmu-node` for chaining FMUs on the bus. FMI 3.0 co-simulation.
 */
#ifndef GAIN_CONFIG_H
#define GAIN_CONFIG_H

#define MODEL_IDENTIFIER     gain
#define MODEL_NAME           "gain"
#define INSTANTIATION_TOKEN  "{8a4e2f17-63b0-4c9d-b5e8-1d7f0a2c94b3}"

#define NX 0
#define NZ 0

typedef enum {
    vr_time = 0,   /* independent variable, s        */
    vr_u    = 1,   /* input                          */
    vr_k    = 2,   /* tunable parameter (-10 .. 10)  */
    vr_y    = 3,   /* output: k u                    */
    NUMBER_OF_VARIABLES = 4
} ValueReference;

typedef struct {
    double u, k, y;
} ModelData;

#endif
