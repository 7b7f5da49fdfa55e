/*
 * config.h -- Boolean, String and Float64-array variables, for the tests of
 * `diffbot fmu-node` (FMI 3.0 co-simulation): y[3] integrates gain * u[3] while `enable`
 * is true; `label` is `prefix` followed by "on" or "off"; `count` is the number of steps.
 */
#ifndef SIGNALS_CONFIG_H
#define SIGNALS_CONFIG_H

#define MODEL_IDENTIFIER     signals
#define MODEL_NAME           "signals"
#define INSTANTIATION_TOKEN  "{c3f1a9e4-5d27-4e80-b6a1-92d4e7f03c55}"
#define HAS_INT32            1
#define HAS_BOOLEAN          1
#define HAS_STRING           1
#define HAS_ARRAYS           1

#define NX 0
#define NZ 0
#define N 3            /* elements of u and y */
#define LABEL_SIZE 64

typedef enum {
    vr_time   = 0,   /* independent variable, s       */
    vr_enable = 1,   /* Boolean input                  */
    vr_u      = 2,   /* Float64[3] input               */
    vr_prefix = 3,   /* String input                   */
    vr_gain   = 4,   /* Float64 tunable parameter      */
    vr_y      = 5,   /* Float64[3] output (state)      */
    vr_label  = 6,   /* String output                  */
    vr_count  = 7,   /* Int32 output: steps taken      */
    NUMBER_OF_VARIABLES = 8
} ValueReference;

typedef struct {
    bool   enable;
    double u[N];
    char   prefix[LABEL_SIZE];
    double gain;
    double y[N];
    char   label[LABEL_SIZE + 4];
    int    count;
} ModelData;

#endif
