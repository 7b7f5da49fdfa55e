/*
 * fmi2Functions.c -- generic FMI 2.0 wrapper (Model Exchange and
 * Co-Simulation) around the model interface declared in model.h.
 *
 * Nothing in this file is specific to a model: it manages the instance and
 * the FMI 2 state machine, logs through the importer's logger and forwards
 * to setStartValues / calculateValues / getFloat64 / setFloat64 / ... of the
 * model. All FMI 2 functions are exported; the ones the model does not
 * support (directional derivatives, input/output derivatives, asynchronous
 * steps) return fmi2Error and log why.
 *
 * Errors caused by an argument (unknown value reference, non-finite value,
 * a call in the wrong state) return fmi2Error, log a message and leave the
 * instance as it was.
 *
 * Build with the FMI 2 headers on the include path (fmpy ships them in
 * fmpy/c-code). C99.
 */
#include <math.h>
#include <stdarg.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "fmi2Functions.h"
#include "model.h"

/* ---------------------------------------------------------------- states */

#define ANY_STATE (Instantiated | InitializationMode | EventMode | ContinuousTimeMode | StepMode | Terminated)

#define MASK_fmi2SetDebugLogging                ANY_STATE
#define MASK_fmi2SetupExperiment                Instantiated
#define MASK_fmi2EnterInitializationMode        Instantiated
#define MASK_fmi2ExitInitializationMode         InitializationMode
#define MASK_fmi2Terminate                      (EventMode | ContinuousTimeMode | StepMode)
#define MASK_fmi2Reset                          ANY_STATE
#define MASK_fmi2GetReal                        (InitializationMode | EventMode | ContinuousTimeMode | StepMode | Terminated)
#define MASK_fmi2SetReal                        (Instantiated | InitializationMode | EventMode | ContinuousTimeMode | StepMode)
#define MASK_fmi2GetInteger                     MASK_fmi2GetReal
#define MASK_fmi2GetBoolean                     MASK_fmi2GetReal
#define MASK_fmi2GetString                      MASK_fmi2GetReal
#define MASK_fmi2SetInteger                     MASK_fmi2SetReal
#define MASK_fmi2SetBoolean                     MASK_fmi2SetReal
#define MASK_fmi2SetString                      MASK_fmi2SetReal
#define MASK_fmi2GetFMUstate                    ANY_STATE
#define MASK_fmi2SetFMUstate                    ANY_STATE
#define MASK_fmi2FreeFMUstate                   ANY_STATE
#define MASK_fmi2SerializedFMUstateSize         ANY_STATE
#define MASK_fmi2SerializeFMUstate              ANY_STATE
#define MASK_fmi2DeSerializeFMUstate            ANY_STATE
#define MASK_fmi2GetDirectionalDerivative       (InitializationMode | EventMode | ContinuousTimeMode | StepMode | Terminated)
/* Model Exchange */
#define MASK_fmi2EnterEventMode                 (EventMode | ContinuousTimeMode)
#define MASK_fmi2NewDiscreteStates              EventMode
#define MASK_fmi2EnterContinuousTimeMode        EventMode
#define MASK_fmi2CompletedIntegratorStep        ContinuousTimeMode
#define MASK_fmi2SetTime                        (EventMode | ContinuousTimeMode)
#define MASK_fmi2SetContinuousStates            ContinuousTimeMode
#define MASK_fmi2GetDerivatives                 (InitializationMode | EventMode | ContinuousTimeMode | Terminated)
#define MASK_fmi2GetEventIndicators             (InitializationMode | EventMode | ContinuousTimeMode | Terminated)
#define MASK_fmi2GetContinuousStates            (InitializationMode | EventMode | ContinuousTimeMode | Terminated)
#define MASK_fmi2GetNominalsOfContinuousStates  (Instantiated | EventMode | ContinuousTimeMode | Terminated)
/* Co-Simulation */
#define MASK_fmi2SetRealInputDerivatives        (Instantiated | InitializationMode | StepMode)
#define MASK_fmi2GetRealOutputDerivatives       (StepMode | Terminated)
#define MASK_fmi2DoStep                         StepMode
#define MASK_fmi2CancelStep                     StepMode
#define MASK_fmi2GetStatus                      (StepMode | Terminated)
#define MASK_fmi2GetRealStatus                  MASK_fmi2GetStatus
#define MASK_fmi2GetIntegerStatus               MASK_fmi2GetStatus
#define MASK_fmi2GetBooleanStatus               MASK_fmi2GetStatus
#define MASK_fmi2GetStringStatus                MASK_fmi2GetStatus

static const char *stateName(ModelState state) {
    switch (state) {
        case StartAndEnd:        return "StartAndEnd";
        case Instantiated:       return "Instantiated";
        case InitializationMode: return "InitializationMode";
        case EventMode:          return "EventMode";
        case ContinuousTimeMode: return "ContinuousTimeMode";
        case StepMode:           return "StepComplete";
        case Terminated:         return "Terminated";
        default:                 return "unknown";
    }
}

/* --------------------------------------------------------------- logging */

/* The FMI 2 logger takes a printf-style format: escape '%' so that the
   (already formatted) message is printed verbatim. */
static void escapePercent(const char *in, char *out, size_t size) {
    size_t j = 0;
    for (; *in && j + 2 < size; in++) {
        if (*in == '%') {
            out[j++] = '%';
        }
        out[j++] = *in;
    }
    out[j] = '\0';
}

static void logVa(fmi2CallbackLogger logger, fmi2ComponentEnvironment env, const char *instanceName,
                  fmi2Status status, const char *category, const char *format, va_list args) {
    char message[1024];
    char escaped[2048];
    if (!logger) {
        return;
    }
    vsnprintf(message, sizeof(message), format, args);
    escapePercent(message, escaped, sizeof(escaped));
    logger(env, instanceName ? instanceName : "", status, category, escaped);
}

/* log before an instance exists (fmi2Instantiate) */
static void logFunctions(const fmi2CallbackFunctions *functions, const char *instanceName,
                         const char *format, ...) {
    va_list args;
    if (!functions) {
        return;
    }
    va_start(args, format);
    logVa(functions->logger, functions->componentEnvironment, instanceName, fmi2Error,
          "logStatusError", format, args);
    va_end(args);
}

void logError(ModelInstance *comp, const char *format, ...) {
    va_list args;
    if (!comp) {
        return;
    }
    va_start(args, format);
    logVa((fmi2CallbackLogger)comp->logger, comp->environment, comp->instanceName, fmi2Error,
          "logStatusError", format, args);
    va_end(args);
}

void logEvent(ModelInstance *comp, const char *format, ...) {
    va_list args;
    if (!comp || !comp->loggingOn) {
        return;
    }
    va_start(args, format);
    logVa((fmi2CallbackLogger)comp->logger, comp->environment, comp->instanceName, fmi2OK,
          "logEvents", format, args);
    va_end(args);
}

/* ---------------------------------------------------------------- checks */

static bool invalidState(ModelInstance *comp, const char *f, int mask) {
    if (!comp) {
        return true;
    }
    if (!(comp->state & mask)) {
        logError(comp, "%s() must not be called in state %s.", f, stateName(comp->state));
        return true;
    }
    return false;
}

static bool invalidType(ModelInstance *comp, const char *f, InterfaceType type) {
    if (comp->type != type) {
        logError(comp, "%s() is only available for %s.", f,
                 type == ModelExchange ? "Model Exchange" : "Co-Simulation");
        return true;
    }
    return false;
}

static bool nullPointer(ModelInstance *comp, const char *f, const char *arg, const void *p) {
    if (!p) {
        logError(comp, "%s(): argument %s must not be NULL.", f, arg);
        return true;
    }
    return false;
}

static bool invalidNumber(ModelInstance *comp, const char *f, const char *arg, size_t n, size_t expected) {
    if (n != expected) {
        logError(comp, "%s(): argument %s = %u, expected %u.", f, arg, (unsigned int)n, (unsigned int)expected);
        return true;
    }
    return false;
}

#define BEGIN(F)                                          \
    ModelInstance *comp = (ModelInstance *)c;             \
    if (invalidState(comp, #F, MASK_##F)) return fmi2Error;

/* functions of one interface type: check the type first, then the state */
#define BEGIN_TYPE(F, TYPE)                               \
    ModelInstance *comp = (ModelInstance *)c;             \
    if (!comp || invalidType(comp, #F, TYPE) || invalidState(comp, #F, MASK_##F)) return fmi2Error;

#define BEGIN_ME(F) BEGIN_TYPE(F, ModelExchange)
#define BEGIN_CS(F) BEGIN_TYPE(F, CoSimulation)

static fmi2Status unsupported(ModelInstance *comp, const char *f, const char *why) {
    logError(comp, "%s() is not supported by this FMU (%s).", f, why);
    return fmi2Error;
}

/* variables of a type this model has none of (Integer, Boolean, String) */
static fmi2Status noVariablesOfType(ModelInstance *comp, const char *f, const char *type,
                                    const fmi2ValueReference vr[], size_t nvr) {
    const char *name;
    if (nvr == 0) {
        return fmi2OK;
    }
    if (nullPointer(comp, f, "vr", vr)) {
        return fmi2Error;
    }
    name = variableName(vr[0]);
    if (name) {
        logError(comp, "%s(): variable \"%s\" (value reference %u) is not of type %s.", f, name, vr[0], type);
    } else {
        logError(comp, "%s(): unknown value reference %u.", f, vr[0]);
    }
    return fmi2Error;
}

/* -------------------------------------------- inquire platform and version */

const char *fmi2GetTypesPlatform(void) {
    return fmi2TypesPlatform;
}

const char *fmi2GetVersion(void) {
    return fmi2Version;
}

fmi2Status fmi2SetDebugLogging(fmi2Component c, fmi2Boolean loggingOn, size_t nCategories,
                               const fmi2String categories[]) {
    size_t i;
    BEGIN(fmi2SetDebugLogging)
    if (nCategories > 0 && nullPointer(comp, "fmi2SetDebugLogging", "categories", categories)) {
        return fmi2Error;
    }
    for (i = 0; i < nCategories; i++) {
        if (!categories[i] ||
            (strcmp(categories[i], "logEvents") != 0 && strcmp(categories[i], "logStatusError") != 0)) {
            logError(comp, "fmi2SetDebugLogging(): unknown log category \"%s\".",
                     categories[i] ? categories[i] : "(null)");
            return fmi2Error;
        }
    }
    comp->loggingOn = loggingOn ? true : false;
    return fmi2OK;
}

/* ------------------------------------------------- creation and destruction */

fmi2Component fmi2Instantiate(fmi2String instanceName, fmi2Type fmuType, fmi2String fmuGUID,
                              fmi2String fmuResourceLocation, const fmi2CallbackFunctions *functions,
                              fmi2Boolean visible, fmi2Boolean loggingOn) {
    ModelInstance *comp;
    size_t len;

    (void)fmuResourceLocation;
    (void)visible;

    if (!functions) {
        return NULL;
    }

    if (!instanceName || !*instanceName) {
        logFunctions(functions, "", "fmi2Instantiate(): missing instance name.");
        return NULL;
    }

    if (fmuType != fmi2ModelExchange && fmuType != fmi2CoSimulation) {
        logFunctions(functions, instanceName, "fmi2Instantiate(): unknown fmuType %d.", (int)fmuType);
        return NULL;
    }

    if (!fmuGUID || strcmp(fmuGUID, INSTANTIATION_TOKEN) != 0) {
        logFunctions(functions, instanceName, "fmi2Instantiate(): wrong GUID \"%s\", expected \"%s\".",
                     fmuGUID ? fmuGUID : "(null)", INSTANTIATION_TOKEN);
        return NULL;
    }

    comp = (ModelInstance *)calloc(1, sizeof(ModelInstance));
    len = strlen(instanceName);
    if (comp) {
        comp->instanceName = (char *)malloc(len + 1);
    }
    if (!comp || !comp->instanceName) {
        free(comp);
        logFunctions(functions, instanceName, "fmi2Instantiate(): out of memory.");
        return NULL;
    }
    memcpy(comp->instanceName, instanceName, len + 1);

    comp->type        = fmuType == fmi2ModelExchange ? ModelExchange : CoSimulation;
    comp->state       = Instantiated;
    comp->time        = 0.0;
    comp->loggingOn   = loggingOn ? true : false;
    comp->environment = functions->componentEnvironment;
    comp->logger      = (void (*)(void))functions->logger;

    setStartValues(comp);
    calculateValues(comp);

    logEvent(comp, "fmi2Instantiate(): %s instance of %s created.",
             comp->type == ModelExchange ? "Model Exchange" : "Co-Simulation", MODEL_NAME);

    return comp;
}

void fmi2FreeInstance(fmi2Component c) {
    ModelInstance *comp = (ModelInstance *)c;
    if (!comp) {
        return;
    }
    logEvent(comp, "fmi2FreeInstance()");
    free(comp->instanceName);
    free(comp);
}

/* ---------------------------------- enter and exit initialization mode etc. */

fmi2Status fmi2SetupExperiment(fmi2Component c, fmi2Boolean toleranceDefined, fmi2Real tolerance,
                               fmi2Real startTime, fmi2Boolean stopTimeDefined, fmi2Real stopTime) {
    BEGIN(fmi2SetupExperiment)
    (void)toleranceDefined;
    (void)tolerance;
    (void)stopTimeDefined;
    (void)stopTime;
    if (isnan(startTime) || isinf(startTime)) {
        logError(comp, "fmi2SetupExperiment(): startTime %g is not finite.", startTime);
        return fmi2Error;
    }
    comp->time = startTime;
    return fmi2OK;
}

fmi2Status fmi2EnterInitializationMode(fmi2Component c) {
    BEGIN(fmi2EnterInitializationMode)
    comp->state = InitializationMode;
    comp->isDirtyValues = true;
    logEvent(comp, "fmi2EnterInitializationMode()");
    return fmi2OK;
}

fmi2Status fmi2ExitInitializationMode(fmi2Component c) {
    BEGIN(fmi2ExitInitializationMode)
    /* still in InitializationMode: the states take their initial values */
    calculateValues(comp);
    comp->state = comp->type == ModelExchange ? EventMode : StepMode;
    logEvent(comp, "fmi2ExitInitializationMode()");
    return fmi2OK;
}

fmi2Status fmi2Terminate(fmi2Component c) {
    BEGIN(fmi2Terminate)
    comp->state = Terminated;
    logEvent(comp, "fmi2Terminate()");
    return fmi2OK;
}

fmi2Status fmi2Reset(fmi2Component c) {
    BEGIN(fmi2Reset)
    comp->state = Instantiated;
    comp->time = 0.0;
    setStartValues(comp);
    calculateValues(comp);
    logEvent(comp, "fmi2Reset()");
    return fmi2OK;
}

/* ------------------------------------------------------- getting and setting */

fmi2Status fmi2GetReal(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, fmi2Real value[]) {
    size_t i;
    BEGIN(fmi2GetReal)
    if (nvr == 0) {
        return fmi2OK;
    }
    if (nullPointer(comp, "fmi2GetReal", "vr", vr) || nullPointer(comp, "fmi2GetReal", "value", value)) {
        return fmi2Error;
    }
    for (i = 0; i < nvr; i++) {
        if (getFloat64(comp, vr[i], &value[i]) > Warning) {
            return fmi2Error;
        }
    }
    return fmi2OK;
}

fmi2Status fmi2GetInteger(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, fmi2Integer value[]) {
#if HAS_INT32
    size_t i;
    int v;
    BEGIN(fmi2GetInteger)
    if (nvr == 0) {
        return fmi2OK;
    }
    if (nullPointer(comp, "fmi2GetInteger", "vr", vr) || nullPointer(comp, "fmi2GetInteger", "value", value)) {
        return fmi2Error;
    }
    for (i = 0; i < nvr; i++) {
        if (getInt32(comp, vr[i], &v) > Warning) {
            return fmi2Error;
        }
        value[i] = v;
    }
    return fmi2OK;
#else
    BEGIN(fmi2GetInteger)
    (void)value;
    return noVariablesOfType(comp, "fmi2GetInteger", "Integer", vr, nvr);
#endif
}

fmi2Status fmi2GetBoolean(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, fmi2Boolean value[]) {
    BEGIN(fmi2GetBoolean)
    (void)value;
    return noVariablesOfType(comp, "fmi2GetBoolean", "Boolean", vr, nvr);
}

fmi2Status fmi2GetString(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, fmi2String value[]) {
    BEGIN(fmi2GetString)
    (void)value;
    return noVariablesOfType(comp, "fmi2GetString", "String", vr, nvr);
}

fmi2Status fmi2SetReal(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, const fmi2Real value[]) {
    size_t i;
    BEGIN(fmi2SetReal)
    if (nvr == 0) {
        return fmi2OK;
    }
    if (nullPointer(comp, "fmi2SetReal", "vr", vr) || nullPointer(comp, "fmi2SetReal", "value", value)) {
        return fmi2Error;
    }
    for (i = 0; i < nvr; i++) {
        if (setFloat64(comp, vr[i], value[i]) > Warning) {
            return fmi2Error;
        }
    }
    return fmi2OK;
}

fmi2Status fmi2SetInteger(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, const fmi2Integer value[]) {
#if HAS_INT32
    size_t i;
    BEGIN(fmi2SetInteger)
    if (nvr == 0) {
        return fmi2OK;
    }
    if (nullPointer(comp, "fmi2SetInteger", "vr", vr) || nullPointer(comp, "fmi2SetInteger", "value", value)) {
        return fmi2Error;
    }
    for (i = 0; i < nvr; i++) {
        if (setInt32(comp, vr[i], value[i]) > Warning) {
            return fmi2Error;
        }
    }
    return fmi2OK;
#else
    BEGIN(fmi2SetInteger)
    (void)value;
    return noVariablesOfType(comp, "fmi2SetInteger", "Integer", vr, nvr);
#endif
}

fmi2Status fmi2SetBoolean(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, const fmi2Boolean value[]) {
    BEGIN(fmi2SetBoolean)
    (void)value;
    return noVariablesOfType(comp, "fmi2SetBoolean", "Boolean", vr, nvr);
}

fmi2Status fmi2SetString(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, const fmi2String value[]) {
    BEGIN(fmi2SetString)
    (void)value;
    return noVariablesOfType(comp, "fmi2SetString", "String", vr, nvr);
}

/* ---------------------------------------------------------------- FMU state */

#define SNAPSHOT_MAGIC 0x464d5532u /* "FMU2" */

typedef struct {
    uint32_t   magic;
    uint32_t   size;
    int32_t    type;
    int32_t    state;
    double     time;
    ModelData  modelData;
} Snapshot;

static bool invalidSnapshot(ModelInstance *comp, const char *f, const Snapshot *s) {
    if (!s || s->magic != SNAPSHOT_MAGIC || s->size != (uint32_t)sizeof(Snapshot)) {
        logError(comp, "%s(): invalid FMU state.", f);
        return true;
    }
    if (s->type != (int32_t)comp->type) {
        logError(comp, "%s(): the FMU state belongs to a %s instance.", f,
                 s->type == (int32_t)ModelExchange ? "Model Exchange" : "Co-Simulation");
        return true;
    }
    return false;
}

fmi2Status fmi2GetFMUstate(fmi2Component c, fmi2FMUstate *FMUstate) {
    Snapshot *s;
    BEGIN(fmi2GetFMUstate)
    if (nullPointer(comp, "fmi2GetFMUstate", "FMUstate", FMUstate)) {
        return fmi2Error;
    }
    s = (Snapshot *)*FMUstate;
    if (!s) {
        s = (Snapshot *)calloc(1, sizeof(Snapshot));
        if (!s) {
            logError(comp, "fmi2GetFMUstate(): out of memory.");
            return fmi2Error;
        }
    }
    s->magic     = SNAPSHOT_MAGIC;
    s->size      = (uint32_t)sizeof(Snapshot);
    s->type      = (int32_t)comp->type;
    s->state     = (int32_t)comp->state;
    s->time      = comp->time;
    s->modelData = comp->modelData;
    *FMUstate = s;
    return fmi2OK;
}

fmi2Status fmi2SetFMUstate(fmi2Component c, fmi2FMUstate FMUstate) {
    const Snapshot *s = (const Snapshot *)FMUstate;
    BEGIN(fmi2SetFMUstate)
    if (invalidSnapshot(comp, "fmi2SetFMUstate", s)) {
        return fmi2Error;
    }
    comp->state         = (ModelState)s->state;
    comp->time          = s->time;
    comp->modelData     = s->modelData;
    comp->isDirtyValues = true;
    return fmi2OK;
}

fmi2Status fmi2FreeFMUstate(fmi2Component c, fmi2FMUstate *FMUstate) {
    BEGIN(fmi2FreeFMUstate)
    if (!FMUstate) {
        return fmi2OK;
    }
    free(*FMUstate);
    *FMUstate = NULL;
    return fmi2OK;
}

fmi2Status fmi2SerializedFMUstateSize(fmi2Component c, fmi2FMUstate FMUstate, size_t *size) {
    BEGIN(fmi2SerializedFMUstateSize)
    if (invalidSnapshot(comp, "fmi2SerializedFMUstateSize", (const Snapshot *)FMUstate) ||
        nullPointer(comp, "fmi2SerializedFMUstateSize", "size", size)) {
        return fmi2Error;
    }
    *size = sizeof(Snapshot);
    return fmi2OK;
}

fmi2Status fmi2SerializeFMUstate(fmi2Component c, fmi2FMUstate FMUstate, fmi2Byte serializedState[], size_t size) {
    BEGIN(fmi2SerializeFMUstate)
    if (invalidSnapshot(comp, "fmi2SerializeFMUstate", (const Snapshot *)FMUstate) ||
        nullPointer(comp, "fmi2SerializeFMUstate", "serializedState", serializedState) ||
        invalidNumber(comp, "fmi2SerializeFMUstate", "size", size, sizeof(Snapshot))) {
        return fmi2Error;
    }
    memcpy(serializedState, FMUstate, sizeof(Snapshot));
    return fmi2OK;
}

fmi2Status fmi2DeSerializeFMUstate(fmi2Component c, const fmi2Byte serializedState[], size_t size,
                                   fmi2FMUstate *FMUstate) {
    Snapshot tmp;
    BEGIN(fmi2DeSerializeFMUstate)
    if (nullPointer(comp, "fmi2DeSerializeFMUstate", "serializedState", serializedState) ||
        nullPointer(comp, "fmi2DeSerializeFMUstate", "FMUstate", FMUstate) ||
        invalidNumber(comp, "fmi2DeSerializeFMUstate", "size", size, sizeof(Snapshot))) {
        return fmi2Error;
    }
    memcpy(&tmp, serializedState, sizeof(Snapshot));
    if (invalidSnapshot(comp, "fmi2DeSerializeFMUstate", &tmp)) {
        return fmi2Error;
    }
    if (!*FMUstate) {
        *FMUstate = calloc(1, sizeof(Snapshot));
        if (!*FMUstate) {
            logError(comp, "fmi2DeSerializeFMUstate(): out of memory.");
            return fmi2Error;
        }
    }
    memcpy(*FMUstate, &tmp, sizeof(Snapshot));
    return fmi2OK;
}

fmi2Status fmi2GetDirectionalDerivative(fmi2Component c, const fmi2ValueReference vUnknown_ref[],
                                        size_t nUnknown, const fmi2ValueReference vKnown_ref[], size_t nKnown,
                                        const fmi2Real dvKnown[], fmi2Real dvUnknown[]) {
    BEGIN(fmi2GetDirectionalDerivative)
    (void)vUnknown_ref; (void)nUnknown; (void)vKnown_ref; (void)nKnown; (void)dvKnown; (void)dvUnknown;
    return unsupported(comp, "fmi2GetDirectionalDerivative", "providesDirectionalDerivative=false");
}

/* ------------------------------------------------------------ Model Exchange */

fmi2Status fmi2EnterEventMode(fmi2Component c) {
    BEGIN_ME(fmi2EnterEventMode)
    comp->state = EventMode;
    return fmi2OK;
}

fmi2Status fmi2NewDiscreteStates(fmi2Component c, fmi2EventInfo *eventInfo) {
    BEGIN_ME(fmi2NewDiscreteStates)
    if (nullPointer(comp, "fmi2NewDiscreteStates", "eventInfo", eventInfo)) {
        return fmi2Error;
    }
    eventInfo->newDiscreteStatesNeeded           = fmi2False;
    eventInfo->terminateSimulation               = fmi2False;
    eventInfo->nominalsOfContinuousStatesChanged = fmi2False;
    eventInfo->valuesOfContinuousStatesChanged   = fmi2False;
    eventInfo->nextEventTimeDefined              = fmi2False;
    eventInfo->nextEventTime                     = 0.0;
    return fmi2OK;
}

fmi2Status fmi2EnterContinuousTimeMode(fmi2Component c) {
    BEGIN_ME(fmi2EnterContinuousTimeMode)
    comp->state = ContinuousTimeMode;
    return fmi2OK;
}

fmi2Status fmi2CompletedIntegratorStep(fmi2Component c, fmi2Boolean noSetFMUStatePriorToCurrentPoint,
                                       fmi2Boolean *enterEventMode, fmi2Boolean *terminateSimulation) {
    BEGIN_ME(fmi2CompletedIntegratorStep)
    (void)noSetFMUStatePriorToCurrentPoint;
    if (nullPointer(comp, "fmi2CompletedIntegratorStep", "enterEventMode", enterEventMode) ||
        nullPointer(comp, "fmi2CompletedIntegratorStep", "terminateSimulation", terminateSimulation)) {
        return fmi2Error;
    }
    *enterEventMode = fmi2False;
    *terminateSimulation = fmi2False;
    return fmi2OK;
}

fmi2Status fmi2SetTime(fmi2Component c, fmi2Real time) {
    BEGIN_ME(fmi2SetTime)
    if (isnan(time) || isinf(time)) {
        logError(comp, "fmi2SetTime(): time %g is not finite.", time);
        return fmi2Error;
    }
    comp->time = time;
    return fmi2OK;
}

fmi2Status fmi2SetContinuousStates(fmi2Component c, const fmi2Real x[], size_t nx) {
    BEGIN_ME(fmi2SetContinuousStates)
    if (invalidNumber(comp, "fmi2SetContinuousStates", "nx", nx, NX) ||
        nullPointer(comp, "fmi2SetContinuousStates", "x", x)) {
        return fmi2Error;
    }
    return setContinuousStates(comp, x, nx) > Warning ? fmi2Error : fmi2OK;
}

fmi2Status fmi2GetDerivatives(fmi2Component c, fmi2Real derivatives[], size_t nx) {
    BEGIN_ME(fmi2GetDerivatives)
    if (invalidNumber(comp, "fmi2GetDerivatives", "nx", nx, NX) ||
        nullPointer(comp, "fmi2GetDerivatives", "derivatives", derivatives)) {
        return fmi2Error;
    }
    getDerivatives(comp, derivatives, nx);
    return fmi2OK;
}

fmi2Status fmi2GetEventIndicators(fmi2Component c, fmi2Real eventIndicators[], size_t ni) {
    BEGIN_ME(fmi2GetEventIndicators)
    (void)eventIndicators;
    if (invalidNumber(comp, "fmi2GetEventIndicators", "ni", ni, NZ)) {
        return fmi2Error;
    }
    return fmi2OK;
}

fmi2Status fmi2GetContinuousStates(fmi2Component c, fmi2Real x[], size_t nx) {
    BEGIN_ME(fmi2GetContinuousStates)
    if (invalidNumber(comp, "fmi2GetContinuousStates", "nx", nx, NX) ||
        nullPointer(comp, "fmi2GetContinuousStates", "x", x)) {
        return fmi2Error;
    }
    getContinuousStates(comp, x, nx);
    return fmi2OK;
}

fmi2Status fmi2GetNominalsOfContinuousStates(fmi2Component c, fmi2Real x_nominal[], size_t nx) {
    BEGIN_ME(fmi2GetNominalsOfContinuousStates)
    if (invalidNumber(comp, "fmi2GetNominalsOfContinuousStates", "nx", nx, NX) ||
        nullPointer(comp, "fmi2GetNominalsOfContinuousStates", "x_nominal", x_nominal)) {
        return fmi2Error;
    }
    getNominalsOfContinuousStates(comp, x_nominal, nx);
    return fmi2OK;
}

/* ------------------------------------------------------------- Co-Simulation */

fmi2Status fmi2SetRealInputDerivatives(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                                       const fmi2Integer order[], const fmi2Real value[]) {
    BEGIN_CS(fmi2SetRealInputDerivatives)
    (void)vr; (void)nvr; (void)order; (void)value;
    return unsupported(comp, "fmi2SetRealInputDerivatives", "canInterpolateInputs=false");
}

fmi2Status fmi2GetRealOutputDerivatives(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                                        const fmi2Integer order[], fmi2Real value[]) {
    BEGIN_CS(fmi2GetRealOutputDerivatives)
    (void)vr; (void)nvr; (void)order; (void)value;
    return unsupported(comp, "fmi2GetRealOutputDerivatives", "maxOutputDerivativeOrder=0");
}

fmi2Status fmi2DoStep(fmi2Component c, fmi2Real currentCommunicationPoint, fmi2Real communicationStepSize,
                      fmi2Boolean noSetFMUStatePriorToCurrentCommunicationPoint) {
    double tolerance;
    BEGIN_CS(fmi2DoStep)
    (void)noSetFMUStatePriorToCurrentCommunicationPoint;

    if (isnan(communicationStepSize) || isinf(communicationStepSize) || communicationStepSize < 0.0) {
        logError(comp, "fmi2DoStep(): communicationStepSize %g must be finite and >= 0.", communicationStepSize);
        return fmi2Error;
    }

    tolerance = 1e-9 * (fabs(comp->time) > 1.0 ? fabs(comp->time) : 1.0);
    if (isnan(currentCommunicationPoint) || fabs(currentCommunicationPoint - comp->time) > tolerance) {
        logError(comp, "fmi2DoStep(): currentCommunicationPoint %.17g does not match the FMU's time %.17g.",
                 currentCommunicationPoint, comp->time);
        return fmi2Error;
    }

    if (doStep(comp, communicationStepSize) > Warning) {
        return fmi2Error;
    }

    comp->time = currentCommunicationPoint + communicationStepSize;
    return fmi2OK;
}

fmi2Status fmi2CancelStep(fmi2Component c) {
    BEGIN_CS(fmi2CancelStep)
    return unsupported(comp, "fmi2CancelStep", "canRunAsynchronuously=false");
}

fmi2Status fmi2GetStatus(fmi2Component c, const fmi2StatusKind s, fmi2Status *value) {
    BEGIN_CS(fmi2GetStatus)
    (void)s; (void)value;
    return unsupported(comp, "fmi2GetStatus", "fmi2DoStep never returns fmi2Pending");
}

fmi2Status fmi2GetRealStatus(fmi2Component c, const fmi2StatusKind s, fmi2Real *value) {
    BEGIN_CS(fmi2GetRealStatus)
    if (s == fmi2LastSuccessfulTime && value) {
        *value = comp->time;
        return fmi2OK;
    }
    return unsupported(comp, "fmi2GetRealStatus", "only fmi2LastSuccessfulTime is available");
}

fmi2Status fmi2GetIntegerStatus(fmi2Component c, const fmi2StatusKind s, fmi2Integer *value) {
    BEGIN_CS(fmi2GetIntegerStatus)
    (void)s; (void)value;
    return unsupported(comp, "fmi2GetIntegerStatus", "no integer status");
}

fmi2Status fmi2GetBooleanStatus(fmi2Component c, const fmi2StatusKind s, fmi2Boolean *value) {
    BEGIN_CS(fmi2GetBooleanStatus)
    if (s == fmi2Terminated && value) {
        *value = fmi2False;
        return fmi2OK;
    }
    return unsupported(comp, "fmi2GetBooleanStatus", "only fmi2Terminated is available");
}

fmi2Status fmi2GetStringStatus(fmi2Component c, const fmi2StatusKind s, fmi2String *value) {
    BEGIN_CS(fmi2GetStringStatus)
    (void)s; (void)value;
    return unsupported(comp, "fmi2GetStringStatus", "no string status");
}
