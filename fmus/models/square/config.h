/*
 * config.h -- the square-path controller (controllers/square_path.py) as an FMU, for the
 * plant FMU's example SSP (fmus/plant_ssp.py): it reads the odometry FMU's pose and
 * commands the plant's v, w. FMI 2.0 and 3.0 co-simulation.
 */
#ifndef SQUARE_CONFIG_H
#define SQUARE_CONFIG_H

#define MODEL_IDENTIFIER     square
#define MODEL_NAME           "square"
#define INSTANTIATION_TOKEN  "{3f6d2a9c-8b41-4e07-a5d2-6c1e9b7f0a58}"

#define NX 0
#define NZ 0

typedef enum {
    vr_time      = 0,   /* independent variable, s                         */
    vr_x         = 1,   /* input: odometry x, m                            */
    vr_y         = 2,   /* input: odometry y, m                            */
    vr_theta     = 3,   /* input: odometry heading, rad                    */
    vr_side      = 4,   /* parameter: side length, m                       */
    vr_speed     = 5,   /* parameter: forward speed, m/s                   */
    vr_turn_rate = 6,   /* parameter: turn rate, rad/s                     */
    vr_v         = 7,   /* output: commanded linear velocity, m/s          */
    vr_w         = 8,   /* output: commanded angular velocity, rad/s       */
    vr_done      = 9,   /* output: 1 once the square is driven, else 0     */
    NUMBER_OF_VARIABLES = 10
} ValueReference;

typedef struct {
    double x, y, theta;             /* inputs */
    double side, speed, turn_rate;  /* parameters */
    double v, w, done;              /* outputs */
    int started, leg, turning;      /* where the square is */
    double heading0, start_x, start_y;
} ModelData;

#endif
