/*
 * model.h -- the small interface between a model (config.h + model.c) and the
 * generic FMI wrappers (fmi2Functions.c, fmi3Functions.c).
 *
 * The wrappers know nothing about the model: they manage the instance, the
 * FMI state machine and logging, and call the functions declared at the end
 * of this file. A model provides config.h (MODEL_IDENTIFIER,
 * INSTANTIATION_TOKEN, NX, NZ, ValueReference, NUMBER_OF_VARIABLES, ModelData)
 * and model.c (the functions below).
 *
 * C99, no dependency beyond the C standard library and the FMI headers.
 */
#ifndef FMU_MODEL_H
#define FMU_MODEL_H

#include <stdbool.h>
#include <stddef.h>

#include "config.h"

#if !defined(FMU_INTERNAL)
#  if defined(__GNUC__) && !defined(_WIN32)
     /* keep the model interface out of the shared library's exported symbols,
        also when built without -fvisibility=hidden (e.g. by `fmpy compile`) */
#    define FMU_INTERNAL __attribute__((visibility("hidden")))
#  else
#    define FMU_INTERNAL
#  endif
#endif

/* Interface types: an FMU built from these sources offers both. */
typedef enum {
    ModelExchange,
    CoSimulation
} InterfaceType;

/* States of the FMI state machines (FMI 2 and FMI 3 share the names; the
   wrappers map them). One bit each so that a set of allowed states is a mask. */
typedef enum {
    StartAndEnd        = 1 << 0,
    Instantiated       = 1 << 1,
    InitializationMode = 1 << 2,
    EventMode          = 1 << 3,
    ContinuousTimeMode = 1 << 4,
    StepMode           = 1 << 5,  /* FMI 2: "stepComplete" */
    Terminated         = 1 << 6
} ModelState;

/* Same numbers as fmi2Status and fmi3Status (OK .. Fatal). */
typedef enum {
    OK      = 0,
    Warning = 1,
    Discard = 2,
    Error   = 3,
    Fatal   = 4
} Status;

typedef struct ModelInstance {
    char         *instanceName;
    InterfaceType type;
    ModelState    state;
    double        time;
    bool          loggingOn;
    bool          isDirtyValues;   /* calculated values must be recomputed */

    /* set and used by the wrapper only (callbacks of the importer) */
    void         *environment;     /* fmi2ComponentEnvironment / fmi3InstanceEnvironment */
    void        (*logger)(void);   /* fmi2CallbackLogger / fmi3LogMessageCallback, cast back by the wrapper */

    ModelData     modelData;
} ModelInstance;

/* ---- implemented by the wrapper --------------------------------------- */

/* Log an error (always passed to the importer's logger). printf-style. */
FMU_INTERNAL void logError(ModelInstance *comp, const char *format, ...)
#if defined(__GNUC__)
    __attribute__((format(printf, 2, 3)))
#endif
    ;

/* Log an event (only if debug logging is on). printf-style. */
FMU_INTERNAL void logEvent(ModelInstance *comp, const char *format, ...)
#if defined(__GNUC__)
    __attribute__((format(printf, 2, 3)))
#endif
    ;

/* ---- implemented by the model (model.c) -------------------------------- */

/* Set all variables to their start values (instantiation and reset). */
FMU_INTERNAL void setStartValues(ModelInstance *comp);

/* Recompute the calculated variables from inputs, parameters and states.
   In Instantiated / InitializationMode this also sets the states from their
   initial-value parameters. Clears comp->isDirtyValues. */
FMU_INTERNAL Status calculateValues(ModelInstance *comp);

/* Name of a variable, NULL for an unknown value reference. */
FMU_INTERNAL const char *variableName(unsigned int vr);

/* Get / set one Float64 (FMI 2: Real) variable. The model checks the value
   reference, whether the variable may be set in the current state, and the
   value; errors are logged with the variable's name. */
FMU_INTERNAL Status getFloat64(ModelInstance *comp, unsigned int vr, double *value);
FMU_INTERNAL Status setFloat64(ModelInstance *comp, unsigned int vr, double value);

#ifndef HAS_INT32
#define HAS_INT32 0   /* config.h: 1 if the model has Int32 (FMI 2: Integer) variables */
#endif
#if HAS_INT32
/* Get / set one Int32 (FMI 2: Integer) variable, as getFloat64 / setFloat64. */
FMU_INTERNAL Status getInt32(ModelInstance *comp, unsigned int vr, int *value);
FMU_INTERNAL Status setInt32(ModelInstance *comp, unsigned int vr, int value);
#endif

#ifndef HAS_BOOLEAN
#define HAS_BOOLEAN 0   /* config.h: 1 if the model has Boolean variables (FMI 3 wrapper) */
#endif
#ifndef HAS_STRING
#define HAS_STRING 0    /* config.h: 1 if the model has String variables (FMI 3 wrapper) */
#endif
#ifndef HAS_ARRAYS
#define HAS_ARRAYS 0    /* config.h: 1 if the model has Float64 arrays (FMI 3 wrapper) */
#endif
#if HAS_BOOLEAN
FMU_INTERNAL Status getBoolean(ModelInstance *comp, unsigned int vr, bool *value);
FMU_INTERNAL Status setBoolean(ModelInstance *comp, unsigned int vr, bool value);
#endif
#if HAS_STRING
/* the string stays valid until the next call into the FMU */
FMU_INTERNAL Status getString(ModelInstance *comp, unsigned int vr, const char **value);
FMU_INTERNAL Status setString(ModelInstance *comp, unsigned int vr, const char *value);
#endif
#if HAS_ARRAYS
/* Number of elements of a Float64 variable (1 for a scalar) and element k of it
   (row-major), used instead of getFloat64 / setFloat64 by the FMI 3 wrapper. */
FMU_INTERNAL size_t float64Size(unsigned int vr);
FMU_INTERNAL Status getFloat64Element(ModelInstance *comp, unsigned int vr, size_t k, double *value);
FMU_INTERNAL Status setFloat64Element(ModelInstance *comp, unsigned int vr, size_t k, double value);
#endif

/* Model exchange: continuous states, nominals and derivatives (arrays of NX). */
FMU_INTERNAL void getContinuousStates(ModelInstance *comp, double x[], size_t nx);
FMU_INTERNAL Status setContinuousStates(ModelInstance *comp, const double x[], size_t nx);
FMU_INTERNAL void getNominalsOfContinuousStates(ModelInstance *comp, double nominals[], size_t nx);
FMU_INTERNAL void getDerivatives(ModelInstance *comp, double dx[], size_t nx);

/* Co-simulation: advance the states over [time, time + h] with the inputs
   held constant. Does not change comp->time (the wrapper does). */
FMU_INTERNAL Status doStep(ModelInstance *comp, double h);

#endif /* FMU_MODEL_H */
