/*
 * fmi3Functions.c -- generic FMI 3.0 wrapper (Model Exchange and
 * Co-Simulation) around the model interface declared in model.h.
 *
 * Nothing in this file is specific to a model: it manages the instance and
 * the FMI 3 state machine, logs through the importer's logMessage callback
 * and forwards to setStartValues / calculateValues / getFloat64 /
 * setFloat64 / ... of the model. The model has Float64 scalars only, no
 * clocks, no event indicators, no structural parameters. All FMI 3 functions
 * are exported; the unsupported ones (Scheduled Execution, clocks,
 * configuration mode, directional / adjoint / output derivatives, variable
 * dependencies) return fmi3Error and log why.
 *
 * Errors caused by an argument (unknown value reference, non-finite value,
 * a call in the wrong state) return fmi3Error, log a message and leave the
 * instance as it was.
 *
 * Build with the FMI 3 headers on the include path (fmpy ships them in
 * fmpy/c-code). C99.
 */
#include <math.h>
#include <stdarg.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "fmi3Functions.h"
#include "model.h"

/* ---------------------------------------------------------------- states */

#define ANY_STATE (Instantiated | InitializationMode | EventMode | ContinuousTimeMode | StepMode | Terminated)

#define MASK_fmi3SetDebugLogging                ANY_STATE
#define MASK_fmi3EnterInitializationMode        Instantiated
#define MASK_fmi3ExitInitializationMode         InitializationMode
#define MASK_fmi3EnterEventMode                 (EventMode | ContinuousTimeMode)
#define MASK_fmi3Terminate                      (EventMode | ContinuousTimeMode | StepMode)
#define MASK_fmi3Reset                          ANY_STATE
#define MASK_GET                                (InitializationMode | EventMode | ContinuousTimeMode | StepMode | Terminated)
#define MASK_SET                                (Instantiated | InitializationMode | EventMode | ContinuousTimeMode | StepMode)
#define MASK_fmi3GetFloat64                     MASK_GET
#define MASK_fmi3SetFloat64                     MASK_SET
#define MASK_FMUState                           ANY_STATE
#define MASK_UNSUPPORTED                        ANY_STATE
#define MASK_fmi3EvaluateDiscreteStates         (InitializationMode | EventMode | ContinuousTimeMode | StepMode)
#define MASK_fmi3UpdateDiscreteStates           EventMode
/* Model Exchange */
#define MASK_fmi3EnterContinuousTimeMode        EventMode
#define MASK_fmi3CompletedIntegratorStep        ContinuousTimeMode
#define MASK_fmi3SetTime                        (EventMode | ContinuousTimeMode)
#define MASK_fmi3SetContinuousStates            ContinuousTimeMode
#define MASK_fmi3GetContinuousStateDerivatives  (InitializationMode | EventMode | ContinuousTimeMode | Terminated)
#define MASK_fmi3GetEventIndicators             (InitializationMode | EventMode | ContinuousTimeMode | Terminated)
#define MASK_fmi3GetContinuousStates            (InitializationMode | EventMode | ContinuousTimeMode | Terminated)
#define MASK_fmi3GetNominalsOfContinuousStates  (Instantiated | EventMode | ContinuousTimeMode | Terminated)
#define MASK_fmi3GetNumberOfEventIndicators     ANY_STATE
#define MASK_fmi3GetNumberOfContinuousStates    ANY_STATE
/* Co-Simulation */
#define MASK_fmi3EnterStepMode                  EventMode
#define MASK_fmi3DoStep                         StepMode

static const char *stateName(ModelState state) {
    switch (state) {
        case StartAndEnd:        return "StartAndEnd";
        case Instantiated:       return "Instantiated";
        case InitializationMode: return "InitializationMode";
        case EventMode:          return "EventMode";
        case ContinuousTimeMode: return "ContinuousTimeMode";
        case StepMode:           return "StepMode";
        case Terminated:         return "Terminated";
        default:                 return "unknown";
    }
}

/* --------------------------------------------------------------- logging */

static void logVa(fmi3LogMessageCallback logMessage, fmi3InstanceEnvironment env, fmi3Status status,
                  const char *category, const char *format, va_list args) {
    char message[1024];
    if (!logMessage) {
        return;
    }
    vsnprintf(message, sizeof(message), format, args);
    logMessage(env, status, category, message);
}

/* log before an instance exists (fmi3Instantiate...) */
static void logCallback(fmi3LogMessageCallback logMessage, fmi3InstanceEnvironment env, const char *format, ...) {
    va_list args;
    va_start(args, format);
    logVa(logMessage, env, fmi3Error, "logStatusError", format, args);
    va_end(args);
}

void logError(ModelInstance *comp, const char *format, ...) {
    va_list args;
    if (!comp) {
        return;
    }
    va_start(args, format);
    logVa((fmi3LogMessageCallback)comp->logger, comp->environment, fmi3Error, "logStatusError", format, args);
    va_end(args);
}

void logEvent(ModelInstance *comp, const char *format, ...) {
    va_list args;
    if (!comp || !comp->loggingOn) {
        return;
    }
    va_start(args, format);
    logVa((fmi3LogMessageCallback)comp->logger, comp->environment, fmi3OK, "logEvents", format, args);
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

#define BEGIN_MASK(F, MASK)                               \
    ModelInstance *comp = (ModelInstance *)instance;      \
    if (invalidState(comp, #F, MASK)) return fmi3Error;

#define BEGIN(F)    BEGIN_MASK(F, MASK_##F)

/* functions of one interface type: check the type first, then the state */
#define BEGIN_TYPE(F, TYPE)                               \
    ModelInstance *comp = (ModelInstance *)instance;      \
    if (!comp || invalidType(comp, #F, TYPE) || invalidState(comp, #F, MASK_##F)) return fmi3Error;

#define BEGIN_ME(F) BEGIN_TYPE(F, ModelExchange)
#define BEGIN_CS(F) BEGIN_TYPE(F, CoSimulation)

#define UNSUPPORTED(F, WHY)                               \
    BEGIN_MASK(F, MASK_UNSUPPORTED)                       \
    logError(comp, "%s() is not supported by this FMU (%s).", #F, WHY); \
    return fmi3Error;

/* variables of a type this model has none of (everything but Float64) */
static fmi3Status noVariablesOfType(ModelInstance *comp, const char *f, const char *type,
                                    const fmi3ValueReference valueReferences[], size_t nValueReferences) {
    const char *name;
    if (nValueReferences == 0) {
        return fmi3OK;
    }
    if (nullPointer(comp, f, "valueReferences", valueReferences)) {
        return fmi3Error;
    }
    name = variableName(valueReferences[0]);
    if (name) {
        logError(comp, "%s(): variable \"%s\" (value reference %u) is not of type %s.",
                 f, name, valueReferences[0], type);
    } else {
        logError(comp, "%s(): unknown value reference %u.", f, valueReferences[0]);
    }
    return fmi3Error;
}

#define GET_OTHER(T)                                                                          \
fmi3Status fmi3Get##T(fmi3Instance instance, const fmi3ValueReference valueReferences[],      \
                      size_t nValueReferences, fmi3##T values[], size_t nValues) {            \
    BEGIN_MASK(fmi3Get##T, MASK_GET)                                                          \
    (void)values; (void)nValues;                                                              \
    return noVariablesOfType(comp, "fmi3Get" #T, #T, valueReferences, nValueReferences);     \
}

#define SET_OTHER(T)                                                                          \
fmi3Status fmi3Set##T(fmi3Instance instance, const fmi3ValueReference valueReferences[],      \
                      size_t nValueReferences, const fmi3##T values[], size_t nValues) {      \
    BEGIN_MASK(fmi3Set##T, MASK_SET)                                                          \
    (void)values; (void)nValues;                                                              \
    return noVariablesOfType(comp, "fmi3Set" #T, #T, valueReferences, nValueReferences);     \
}

/* -------------------------------------------- inquire version, set logging */

const char *fmi3GetVersion(void) {
    return fmi3Version;
}

fmi3Status fmi3SetDebugLogging(fmi3Instance instance, fmi3Boolean loggingOn, size_t nCategories,
                               const fmi3String categories[]) {
    size_t i;
    BEGIN(fmi3SetDebugLogging)
    if (nCategories > 0 && nullPointer(comp, "fmi3SetDebugLogging", "categories", categories)) {
        return fmi3Error;
    }
    for (i = 0; i < nCategories; i++) {
        if (!categories[i] ||
            (strcmp(categories[i], "logEvents") != 0 && strcmp(categories[i], "logStatusError") != 0)) {
            logError(comp, "fmi3SetDebugLogging(): unknown log category \"%s\".",
                     categories[i] ? categories[i] : "(null)");
            return fmi3Error;
        }
    }
    comp->loggingOn = loggingOn ? true : false;
    return fmi3OK;
}

/* ------------------------------------------------- creation and destruction */

static ModelInstance *createInstance(InterfaceType type, fmi3String instanceName, fmi3String instantiationToken,
                                     fmi3Boolean loggingOn, fmi3InstanceEnvironment instanceEnvironment,
                                     fmi3LogMessageCallback logMessage, const char *f) {
    ModelInstance *comp;
    size_t len;

    if (!instanceName || !*instanceName) {
        logCallback(logMessage, instanceEnvironment, "%s(): missing instance name.", f);
        return NULL;
    }

    if (!instantiationToken || strcmp(instantiationToken, INSTANTIATION_TOKEN) != 0) {
        logCallback(logMessage, instanceEnvironment,
                    "%s(): wrong instantiationToken \"%s\", expected \"%s\".", f,
                    instantiationToken ? instantiationToken : "(null)", INSTANTIATION_TOKEN);
        return NULL;
    }

    comp = (ModelInstance *)calloc(1, sizeof(ModelInstance));
    len = strlen(instanceName);
    if (comp) {
        comp->instanceName = (char *)malloc(len + 1);
    }
    if (!comp || !comp->instanceName) {
        free(comp);
        logCallback(logMessage, instanceEnvironment, "%s(): out of memory.", f);
        return NULL;
    }
    memcpy(comp->instanceName, instanceName, len + 1);

    comp->type        = type;
    comp->state       = Instantiated;
    comp->time        = 0.0;
    comp->loggingOn   = loggingOn ? true : false;
    comp->environment = instanceEnvironment;
    comp->logger      = (void (*)(void))logMessage;

    setStartValues(comp);
    calculateValues(comp);

    logEvent(comp, "%s(): instance \"%s\" of %s created.", f, comp->instanceName, MODEL_NAME);

    return comp;
}

fmi3Instance fmi3InstantiateModelExchange(fmi3String instanceName, fmi3String instantiationToken,
                                          fmi3String resourcePath, fmi3Boolean visible, fmi3Boolean loggingOn,
                                          fmi3InstanceEnvironment instanceEnvironment,
                                          fmi3LogMessageCallback logMessage) {
    (void)resourcePath;
    (void)visible;
    return createInstance(ModelExchange, instanceName, instantiationToken, loggingOn, instanceEnvironment,
                          logMessage, "fmi3InstantiateModelExchange");
}

fmi3Instance fmi3InstantiateCoSimulation(fmi3String instanceName, fmi3String instantiationToken,
                                         fmi3String resourcePath, fmi3Boolean visible, fmi3Boolean loggingOn,
                                         fmi3Boolean eventModeUsed, fmi3Boolean earlyReturnAllowed,
                                         const fmi3ValueReference requiredIntermediateVariables[],
                                         size_t nRequiredIntermediateVariables,
                                         fmi3InstanceEnvironment instanceEnvironment,
                                         fmi3LogMessageCallback logMessage,
                                         fmi3IntermediateUpdateCallback intermediateUpdate) {
    (void)resourcePath;
    (void)visible;
    (void)eventModeUsed;      /* the model has no events: event mode is never entered */
    (void)earlyReturnAllowed; /* fmi3DoStep never returns early */
    (void)requiredIntermediateVariables;
    (void)nRequiredIntermediateVariables;
    (void)intermediateUpdate;
    return createInstance(CoSimulation, instanceName, instantiationToken, loggingOn, instanceEnvironment,
                          logMessage, "fmi3InstantiateCoSimulation");
}

fmi3Instance fmi3InstantiateScheduledExecution(fmi3String instanceName, fmi3String instantiationToken,
                                               fmi3String resourcePath, fmi3Boolean visible,
                                               fmi3Boolean loggingOn, fmi3InstanceEnvironment instanceEnvironment,
                                               fmi3LogMessageCallback logMessage,
                                               fmi3ClockUpdateCallback clockUpdate,
                                               fmi3LockPreemptionCallback lockPreemption,
                                               fmi3UnlockPreemptionCallback unlockPreemption) {
    (void)instanceName; (void)instantiationToken; (void)resourcePath; (void)visible; (void)loggingOn;
    (void)clockUpdate; (void)lockPreemption; (void)unlockPreemption;
    logCallback(logMessage, instanceEnvironment,
                "fmi3InstantiateScheduledExecution(): Scheduled Execution is not supported by this FMU.");
    return NULL;
}

void fmi3FreeInstance(fmi3Instance instance) {
    ModelInstance *comp = (ModelInstance *)instance;
    if (!comp) {
        return;
    }
    logEvent(comp, "fmi3FreeInstance()");
    free(comp->instanceName);
    free(comp);
}

/* ------------------------------------------- enter and exit the initialization */

fmi3Status fmi3EnterInitializationMode(fmi3Instance instance, fmi3Boolean toleranceDefined, fmi3Float64 tolerance,
                                       fmi3Float64 startTime, fmi3Boolean stopTimeDefined, fmi3Float64 stopTime) {
    BEGIN(fmi3EnterInitializationMode)
    (void)toleranceDefined;
    (void)tolerance;
    (void)stopTimeDefined;
    (void)stopTime;
    if (isnan(startTime) || isinf(startTime)) {
        logError(comp, "fmi3EnterInitializationMode(): startTime %g is not finite.", startTime);
        return fmi3Error;
    }
    comp->time = startTime;
    comp->state = InitializationMode;
    comp->isDirtyValues = true;
    logEvent(comp, "fmi3EnterInitializationMode()");
    return fmi3OK;
}

fmi3Status fmi3ExitInitializationMode(fmi3Instance instance) {
    BEGIN(fmi3ExitInitializationMode)
    /* still in InitializationMode: the states take their initial values */
    calculateValues(comp);
    comp->state = comp->type == ModelExchange ? EventMode : StepMode;
    logEvent(comp, "fmi3ExitInitializationMode()");
    return fmi3OK;
}

fmi3Status fmi3EnterEventMode(fmi3Instance instance) {
    BEGIN_ME(fmi3EnterEventMode)
    comp->state = EventMode;
    return fmi3OK;
}

fmi3Status fmi3Terminate(fmi3Instance instance) {
    BEGIN(fmi3Terminate)
    comp->state = Terminated;
    logEvent(comp, "fmi3Terminate()");
    return fmi3OK;
}

fmi3Status fmi3Reset(fmi3Instance instance) {
    BEGIN(fmi3Reset)
    comp->state = Instantiated;
    comp->time = 0.0;
    setStartValues(comp);
    calculateValues(comp);
    logEvent(comp, "fmi3Reset()");
    return fmi3OK;
}

/* ------------------------------------------------------- getting and setting */

/* values expected for these Float64 variables: one each, or their array sizes */
static size_t elementsOf(const fmi3ValueReference vr[], size_t nvr) {
#if HAS_ARRAYS
    size_t i, n = 0;
    for (i = 0; i < nvr; i++) {
        n += float64Size(vr[i]);
    }
    return n;
#else
    (void)vr;
    return nvr;
#endif
}

#define GET_SCALARS(T, CT, GETTER, CONVERT)                                                   \
fmi3Status fmi3Get##T(fmi3Instance instance, const fmi3ValueReference valueReferences[],      \
                      size_t nValueReferences, fmi3##T values[], size_t nValues) {            \
    size_t i;                                                                                 \
    CT v;                                                                                     \
    BEGIN_MASK(fmi3Get##T, MASK_GET)                                                          \
    if (nValueReferences == 0) return fmi3OK;                                                 \
    if (nullPointer(comp, "fmi3Get" #T, "valueReferences", valueReferences) ||                \
        nullPointer(comp, "fmi3Get" #T, "values", values) ||                                  \
        invalidNumber(comp, "fmi3Get" #T, "nValues", nValues, nValueReferences)) {            \
        return fmi3Error;                                                                     \
    }                                                                                         \
    for (i = 0; i < nValueReferences; i++) {                                                  \
        if (GETTER(comp, valueReferences[i], &v) > Warning) return fmi3Error;                 \
        values[i] = CONVERT(v);                                                               \
    }                                                                                         \
    return fmi3OK;                                                                            \
}

#define SET_SCALARS(T, SETTER, CONVERT)                                                       \
fmi3Status fmi3Set##T(fmi3Instance instance, const fmi3ValueReference valueReferences[],      \
                      size_t nValueReferences, const fmi3##T values[], size_t nValues) {      \
    size_t i;                                                                                 \
    BEGIN_MASK(fmi3Set##T, MASK_SET)                                                          \
    if (nValueReferences == 0) return fmi3OK;                                                 \
    if (nullPointer(comp, "fmi3Set" #T, "valueReferences", valueReferences) ||                \
        nullPointer(comp, "fmi3Set" #T, "values", values) ||                                  \
        invalidNumber(comp, "fmi3Set" #T, "nValues", nValues, nValueReferences)) {            \
        return fmi3Error;                                                                     \
    }                                                                                         \
    for (i = 0; i < nValueReferences; i++) {                                                  \
        if (SETTER(comp, valueReferences[i], CONVERT(values[i])) > Warning) return fmi3Error; \
    }                                                                                         \
    return fmi3OK;                                                                            \
}

#define AS_IS(x) (x)

fmi3Status fmi3GetFloat64(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                          size_t nValueReferences, fmi3Float64 values[], size_t nValues) {
    size_t i;
    BEGIN(fmi3GetFloat64)
    if (nValueReferences == 0) {
        return fmi3OK;
    }
    if (nullPointer(comp, "fmi3GetFloat64", "valueReferences", valueReferences) ||
        nullPointer(comp, "fmi3GetFloat64", "values", values) ||
        invalidNumber(comp, "fmi3GetFloat64", "nValues", nValues, elementsOf(valueReferences, nValueReferences))) {
        return fmi3Error;
    }
#if HAS_ARRAYS
    {
        size_t k, n = 0;
        for (i = 0; i < nValueReferences; i++) {
            for (k = 0; k < float64Size(valueReferences[i]); k++) {
                if (getFloat64Element(comp, valueReferences[i], k, &values[n++]) > Warning) {
                    return fmi3Error;
                }
            }
        }
    }
#else
    for (i = 0; i < nValueReferences; i++) {
        if (getFloat64(comp, valueReferences[i], &values[i]) > Warning) {
            return fmi3Error;
        }
    }
#endif
    return fmi3OK;
}

fmi3Status fmi3SetFloat64(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                          size_t nValueReferences, const fmi3Float64 values[], size_t nValues) {
    size_t i;
    BEGIN(fmi3SetFloat64)
    if (nValueReferences == 0) {
        return fmi3OK;
    }
    if (nullPointer(comp, "fmi3SetFloat64", "valueReferences", valueReferences) ||
        nullPointer(comp, "fmi3SetFloat64", "values", values) ||
        invalidNumber(comp, "fmi3SetFloat64", "nValues", nValues, elementsOf(valueReferences, nValueReferences))) {
        return fmi3Error;
    }
#if HAS_ARRAYS
    {
        size_t k, n = 0;
        for (i = 0; i < nValueReferences; i++) {
            for (k = 0; k < float64Size(valueReferences[i]); k++) {
                if (setFloat64Element(comp, valueReferences[i], k, values[n++]) > Warning) {
                    return fmi3Error;
                }
            }
        }
    }
#else
    for (i = 0; i < nValueReferences; i++) {
        if (setFloat64(comp, valueReferences[i], values[i]) > Warning) {
            return fmi3Error;
        }
    }
#endif
    return fmi3OK;
}

GET_OTHER(Float32)
GET_OTHER(Int8)
GET_OTHER(UInt8)
GET_OTHER(Int16)
GET_OTHER(UInt16)
#if HAS_INT32
GET_SCALARS(Int32, int, getInt32, AS_IS)
#else
GET_OTHER(Int32)
#endif
GET_OTHER(UInt32)
GET_OTHER(Int64)
GET_OTHER(UInt64)
#if HAS_BOOLEAN
GET_SCALARS(Boolean, bool, getBoolean, AS_IS)
#else
GET_OTHER(Boolean)
#endif
#if HAS_STRING
GET_SCALARS(String, const char *, getString, AS_IS)
#else
GET_OTHER(String)
#endif

SET_OTHER(Float32)
SET_OTHER(Int8)
SET_OTHER(UInt8)
SET_OTHER(Int16)
SET_OTHER(UInt16)
#if HAS_INT32
SET_SCALARS(Int32, setInt32, AS_IS)
#else
SET_OTHER(Int32)
#endif
SET_OTHER(UInt32)
SET_OTHER(Int64)
SET_OTHER(UInt64)
#if HAS_BOOLEAN
SET_SCALARS(Boolean, setBoolean, AS_IS)
#else
SET_OTHER(Boolean)
#endif
#if HAS_STRING
SET_SCALARS(String, setString, AS_IS)
#else
SET_OTHER(String)
#endif

fmi3Status fmi3GetBinary(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                         size_t nValueReferences, size_t valueSizes[], fmi3Binary values[], size_t nValues) {
    BEGIN_MASK(fmi3GetBinary, MASK_GET)
    (void)valueSizes; (void)values; (void)nValues;
    return noVariablesOfType(comp, "fmi3GetBinary", "Binary", valueReferences, nValueReferences);
}

fmi3Status fmi3SetBinary(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                         size_t nValueReferences, const size_t valueSizes[], const fmi3Binary values[],
                         size_t nValues) {
    BEGIN_MASK(fmi3SetBinary, MASK_SET)
    (void)valueSizes; (void)values; (void)nValues;
    return noVariablesOfType(comp, "fmi3SetBinary", "Binary", valueReferences, nValueReferences);
}

fmi3Status fmi3GetClock(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                        size_t nValueReferences, fmi3Clock values[]) {
    BEGIN_MASK(fmi3GetClock, MASK_GET)
    (void)values;
    return noVariablesOfType(comp, "fmi3GetClock", "Clock", valueReferences, nValueReferences);
}

fmi3Status fmi3SetClock(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                        size_t nValueReferences, const fmi3Clock values[]) {
    BEGIN_MASK(fmi3SetClock, MASK_SET)
    (void)values;
    return noVariablesOfType(comp, "fmi3SetClock", "Clock", valueReferences, nValueReferences);
}

/* ------------------------------------------------------- variable dependencies */

fmi3Status fmi3GetNumberOfVariableDependencies(fmi3Instance instance, fmi3ValueReference valueReference,
                                               size_t *nDependencies) {
    (void)valueReference; (void)nDependencies;
    UNSUPPORTED(fmi3GetNumberOfVariableDependencies, "see <ModelStructure> in modelDescription.xml")
}

fmi3Status fmi3GetVariableDependencies(fmi3Instance instance, fmi3ValueReference dependent,
                                       size_t elementIndicesOfDependent[], fmi3ValueReference independents[],
                                       size_t elementIndicesOfIndependents[], fmi3DependencyKind dependencyKinds[],
                                       size_t nDependencies) {
    (void)dependent; (void)elementIndicesOfDependent; (void)independents; (void)elementIndicesOfIndependents;
    (void)dependencyKinds; (void)nDependencies;
    UNSUPPORTED(fmi3GetVariableDependencies, "see <ModelStructure> in modelDescription.xml")
}

/* ---------------------------------------------------------------- FMU state */

#define SNAPSHOT_MAGIC 0x464d5533u /* "FMU3" */

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

fmi3Status fmi3GetFMUState(fmi3Instance instance, fmi3FMUState *FMUState) {
    Snapshot *s;
    BEGIN_MASK(fmi3GetFMUState, MASK_FMUState)
    if (nullPointer(comp, "fmi3GetFMUState", "FMUState", FMUState)) {
        return fmi3Error;
    }
    s = (Snapshot *)*FMUState;
    if (!s) {
        s = (Snapshot *)calloc(1, sizeof(Snapshot));
        if (!s) {
            logError(comp, "fmi3GetFMUState(): out of memory.");
            return fmi3Error;
        }
    }
    s->magic     = SNAPSHOT_MAGIC;
    s->size      = (uint32_t)sizeof(Snapshot);
    s->type      = (int32_t)comp->type;
    s->state     = (int32_t)comp->state;
    s->time      = comp->time;
    s->modelData = comp->modelData;
    *FMUState = s;
    return fmi3OK;
}

fmi3Status fmi3SetFMUState(fmi3Instance instance, fmi3FMUState FMUState) {
    const Snapshot *s = (const Snapshot *)FMUState;
    BEGIN_MASK(fmi3SetFMUState, MASK_FMUState)
    if (invalidSnapshot(comp, "fmi3SetFMUState", s)) {
        return fmi3Error;
    }
    comp->state         = (ModelState)s->state;
    comp->time          = s->time;
    comp->modelData     = s->modelData;
    comp->isDirtyValues = true;
    return fmi3OK;
}

fmi3Status fmi3FreeFMUState(fmi3Instance instance, fmi3FMUState *FMUState) {
    BEGIN_MASK(fmi3FreeFMUState, MASK_FMUState)
    if (!FMUState) {
        return fmi3OK;
    }
    free(*FMUState);
    *FMUState = NULL;
    return fmi3OK;
}

fmi3Status fmi3SerializedFMUStateSize(fmi3Instance instance, fmi3FMUState FMUState, size_t *size) {
    BEGIN_MASK(fmi3SerializedFMUStateSize, MASK_FMUState)
    if (invalidSnapshot(comp, "fmi3SerializedFMUStateSize", (const Snapshot *)FMUState) ||
        nullPointer(comp, "fmi3SerializedFMUStateSize", "size", size)) {
        return fmi3Error;
    }
    *size = sizeof(Snapshot);
    return fmi3OK;
}

fmi3Status fmi3SerializeFMUState(fmi3Instance instance, fmi3FMUState FMUState, fmi3Byte serializedState[],
                                 size_t size) {
    BEGIN_MASK(fmi3SerializeFMUState, MASK_FMUState)
    if (invalidSnapshot(comp, "fmi3SerializeFMUState", (const Snapshot *)FMUState) ||
        nullPointer(comp, "fmi3SerializeFMUState", "serializedState", serializedState) ||
        invalidNumber(comp, "fmi3SerializeFMUState", "size", size, sizeof(Snapshot))) {
        return fmi3Error;
    }
    memcpy(serializedState, FMUState, sizeof(Snapshot));
    return fmi3OK;
}

fmi3Status fmi3DeserializeFMUState(fmi3Instance instance, const fmi3Byte serializedState[], size_t size,
                                   fmi3FMUState *FMUState) {
    Snapshot tmp;
    BEGIN_MASK(fmi3DeserializeFMUState, MASK_FMUState)
    if (nullPointer(comp, "fmi3DeserializeFMUState", "serializedState", serializedState) ||
        nullPointer(comp, "fmi3DeserializeFMUState", "FMUState", FMUState) ||
        invalidNumber(comp, "fmi3DeserializeFMUState", "size", size, sizeof(Snapshot))) {
        return fmi3Error;
    }
    memcpy(&tmp, serializedState, sizeof(Snapshot));
    if (invalidSnapshot(comp, "fmi3DeserializeFMUState", &tmp)) {
        return fmi3Error;
    }
    if (!*FMUState) {
        *FMUState = calloc(1, sizeof(Snapshot));
        if (!*FMUState) {
            logError(comp, "fmi3DeserializeFMUState(): out of memory.");
            return fmi3Error;
        }
    }
    memcpy(*FMUState, &tmp, sizeof(Snapshot));
    return fmi3OK;
}

/* ------------------------------------------------------------- derivatives */

fmi3Status fmi3GetDirectionalDerivative(fmi3Instance instance, const fmi3ValueReference unknowns[],
                                        size_t nUnknowns, const fmi3ValueReference knowns[], size_t nKnowns,
                                        const fmi3Float64 seed[], size_t nSeed, fmi3Float64 sensitivity[],
                                        size_t nSensitivity) {
    (void)unknowns; (void)nUnknowns; (void)knowns; (void)nKnowns; (void)seed; (void)nSeed;
    (void)sensitivity; (void)nSensitivity;
    UNSUPPORTED(fmi3GetDirectionalDerivative, "providesDirectionalDerivatives=false")
}

fmi3Status fmi3GetAdjointDerivative(fmi3Instance instance, const fmi3ValueReference unknowns[],
                                    size_t nUnknowns, const fmi3ValueReference knowns[], size_t nKnowns,
                                    const fmi3Float64 seed[], size_t nSeed, fmi3Float64 sensitivity[],
                                    size_t nSensitivity) {
    (void)unknowns; (void)nUnknowns; (void)knowns; (void)nKnowns; (void)seed; (void)nSeed;
    (void)sensitivity; (void)nSensitivity;
    UNSUPPORTED(fmi3GetAdjointDerivative, "providesAdjointDerivatives=false")
}

/* ------------------------------------------------------ configuration mode */

fmi3Status fmi3EnterConfigurationMode(fmi3Instance instance) {
    UNSUPPORTED(fmi3EnterConfigurationMode, "no structural or tunable parameters")
}

fmi3Status fmi3ExitConfigurationMode(fmi3Instance instance) {
    UNSUPPORTED(fmi3ExitConfigurationMode, "no structural or tunable parameters")
}

/* ------------------------------------------------------------------ clocks */

fmi3Status fmi3GetIntervalDecimal(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                                  size_t nValueReferences, fmi3Float64 intervals[],
                                  fmi3IntervalQualifier qualifiers[]) {
    (void)valueReferences; (void)nValueReferences; (void)intervals; (void)qualifiers;
    UNSUPPORTED(fmi3GetIntervalDecimal, "no clocks")
}

fmi3Status fmi3GetIntervalFraction(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                                   size_t nValueReferences, fmi3UInt64 counters[], fmi3UInt64 resolutions[],
                                   fmi3IntervalQualifier qualifiers[]) {
    (void)valueReferences; (void)nValueReferences; (void)counters; (void)resolutions; (void)qualifiers;
    UNSUPPORTED(fmi3GetIntervalFraction, "no clocks")
}

fmi3Status fmi3GetShiftDecimal(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                               size_t nValueReferences, fmi3Float64 shifts[]) {
    (void)valueReferences; (void)nValueReferences; (void)shifts;
    UNSUPPORTED(fmi3GetShiftDecimal, "no clocks")
}

fmi3Status fmi3GetShiftFraction(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                                size_t nValueReferences, fmi3UInt64 counters[], fmi3UInt64 resolutions[]) {
    (void)valueReferences; (void)nValueReferences; (void)counters; (void)resolutions;
    UNSUPPORTED(fmi3GetShiftFraction, "no clocks")
}

fmi3Status fmi3SetIntervalDecimal(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                                  size_t nValueReferences, const fmi3Float64 intervals[]) {
    (void)valueReferences; (void)nValueReferences; (void)intervals;
    UNSUPPORTED(fmi3SetIntervalDecimal, "no clocks")
}

fmi3Status fmi3SetIntervalFraction(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                                   size_t nValueReferences, const fmi3UInt64 counters[],
                                   const fmi3UInt64 resolutions[]) {
    (void)valueReferences; (void)nValueReferences; (void)counters; (void)resolutions;
    UNSUPPORTED(fmi3SetIntervalFraction, "no clocks")
}

fmi3Status fmi3SetShiftDecimal(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                               size_t nValueReferences, const fmi3Float64 shifts[]) {
    (void)valueReferences; (void)nValueReferences; (void)shifts;
    UNSUPPORTED(fmi3SetShiftDecimal, "no clocks")
}

fmi3Status fmi3SetShiftFraction(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                                size_t nValueReferences, const fmi3UInt64 counters[],
                                const fmi3UInt64 resolutions[]) {
    (void)valueReferences; (void)nValueReferences; (void)counters; (void)resolutions;
    UNSUPPORTED(fmi3SetShiftFraction, "no clocks")
}

fmi3Status fmi3ActivateModelPartition(fmi3Instance instance, fmi3ValueReference clockReference,
                                      fmi3Float64 activationTime) {
    (void)clockReference; (void)activationTime;
    UNSUPPORTED(fmi3ActivateModelPartition, "Scheduled Execution is not supported")
}

/* ---------------------------------------------------------- discrete states */

fmi3Status fmi3EvaluateDiscreteStates(fmi3Instance instance) {
    BEGIN(fmi3EvaluateDiscreteStates)
    return fmi3OK; /* the model has no discrete states */
}

fmi3Status fmi3UpdateDiscreteStates(fmi3Instance instance, fmi3Boolean *discreteStatesNeedUpdate,
                                    fmi3Boolean *terminateSimulation,
                                    fmi3Boolean *nominalsOfContinuousStatesChanged,
                                    fmi3Boolean *valuesOfContinuousStatesChanged,
                                    fmi3Boolean *nextEventTimeDefined, fmi3Float64 *nextEventTime) {
    BEGIN(fmi3UpdateDiscreteStates)
    if (discreteStatesNeedUpdate)          *discreteStatesNeedUpdate = fmi3False;
    if (terminateSimulation)               *terminateSimulation = fmi3False;
    if (nominalsOfContinuousStatesChanged) *nominalsOfContinuousStatesChanged = fmi3False;
    if (valuesOfContinuousStatesChanged)   *valuesOfContinuousStatesChanged = fmi3False;
    if (nextEventTimeDefined)              *nextEventTimeDefined = fmi3False;
    if (nextEventTime)                     *nextEventTime = 0.0;
    return fmi3OK;
}

/* ------------------------------------------------------------ Model Exchange */

fmi3Status fmi3EnterContinuousTimeMode(fmi3Instance instance) {
    BEGIN_ME(fmi3EnterContinuousTimeMode)
    comp->state = ContinuousTimeMode;
    return fmi3OK;
}

fmi3Status fmi3CompletedIntegratorStep(fmi3Instance instance, fmi3Boolean noSetFMUStatePriorToCurrentPoint,
                                       fmi3Boolean *enterEventMode, fmi3Boolean *terminateSimulation) {
    BEGIN_ME(fmi3CompletedIntegratorStep)
    (void)noSetFMUStatePriorToCurrentPoint;
    if (nullPointer(comp, "fmi3CompletedIntegratorStep", "enterEventMode", enterEventMode) ||
        nullPointer(comp, "fmi3CompletedIntegratorStep", "terminateSimulation", terminateSimulation)) {
        return fmi3Error;
    }
    *enterEventMode = fmi3False;
    *terminateSimulation = fmi3False;
    return fmi3OK;
}

fmi3Status fmi3SetTime(fmi3Instance instance, fmi3Float64 time) {
    BEGIN_ME(fmi3SetTime)
    if (isnan(time) || isinf(time)) {
        logError(comp, "fmi3SetTime(): time %g is not finite.", time);
        return fmi3Error;
    }
    comp->time = time;
    return fmi3OK;
}

fmi3Status fmi3SetContinuousStates(fmi3Instance instance, const fmi3Float64 continuousStates[],
                                   size_t nContinuousStates) {
    BEGIN_ME(fmi3SetContinuousStates)
    if (invalidNumber(comp, "fmi3SetContinuousStates", "nContinuousStates", nContinuousStates, NX) ||
        nullPointer(comp, "fmi3SetContinuousStates", "continuousStates", continuousStates)) {
        return fmi3Error;
    }
    return setContinuousStates(comp, continuousStates, nContinuousStates) > Warning ? fmi3Error : fmi3OK;
}

fmi3Status fmi3GetContinuousStateDerivatives(fmi3Instance instance, fmi3Float64 derivatives[],
                                             size_t nContinuousStates) {
    BEGIN_ME(fmi3GetContinuousStateDerivatives)
    if (invalidNumber(comp, "fmi3GetContinuousStateDerivatives", "nContinuousStates", nContinuousStates, NX) ||
        nullPointer(comp, "fmi3GetContinuousStateDerivatives", "derivatives", derivatives)) {
        return fmi3Error;
    }
    getDerivatives(comp, derivatives, nContinuousStates);
    return fmi3OK;
}

fmi3Status fmi3GetEventIndicators(fmi3Instance instance, fmi3Float64 eventIndicators[], size_t nEventIndicators) {
    BEGIN_ME(fmi3GetEventIndicators)
    (void)eventIndicators;
    if (invalidNumber(comp, "fmi3GetEventIndicators", "nEventIndicators", nEventIndicators, NZ)) {
        return fmi3Error;
    }
    return fmi3OK;
}

fmi3Status fmi3GetContinuousStates(fmi3Instance instance, fmi3Float64 continuousStates[],
                                   size_t nContinuousStates) {
    BEGIN_ME(fmi3GetContinuousStates)
    if (invalidNumber(comp, "fmi3GetContinuousStates", "nContinuousStates", nContinuousStates, NX) ||
        nullPointer(comp, "fmi3GetContinuousStates", "continuousStates", continuousStates)) {
        return fmi3Error;
    }
    getContinuousStates(comp, continuousStates, nContinuousStates);
    return fmi3OK;
}

fmi3Status fmi3GetNominalsOfContinuousStates(fmi3Instance instance, fmi3Float64 nominals[],
                                             size_t nContinuousStates) {
    BEGIN_ME(fmi3GetNominalsOfContinuousStates)
    if (invalidNumber(comp, "fmi3GetNominalsOfContinuousStates", "nContinuousStates", nContinuousStates, NX) ||
        nullPointer(comp, "fmi3GetNominalsOfContinuousStates", "nominals", nominals)) {
        return fmi3Error;
    }
    getNominalsOfContinuousStates(comp, nominals, nContinuousStates);
    return fmi3OK;
}

fmi3Status fmi3GetNumberOfEventIndicators(fmi3Instance instance, size_t *nEventIndicators) {
    BEGIN(fmi3GetNumberOfEventIndicators)
    if (nullPointer(comp, "fmi3GetNumberOfEventIndicators", "nEventIndicators", nEventIndicators)) {
        return fmi3Error;
    }
    *nEventIndicators = NZ;
    return fmi3OK;
}

fmi3Status fmi3GetNumberOfContinuousStates(fmi3Instance instance, size_t *nContinuousStates) {
    BEGIN(fmi3GetNumberOfContinuousStates)
    if (nullPointer(comp, "fmi3GetNumberOfContinuousStates", "nContinuousStates", nContinuousStates)) {
        return fmi3Error;
    }
    *nContinuousStates = NX;
    return fmi3OK;
}

/* ------------------------------------------------------------- Co-Simulation */

fmi3Status fmi3EnterStepMode(fmi3Instance instance) {
    BEGIN_CS(fmi3EnterStepMode)
    comp->state = StepMode;
    return fmi3OK;
}

fmi3Status fmi3GetOutputDerivatives(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                                    size_t nValueReferences, const fmi3Int32 orders[], fmi3Float64 values[],
                                    size_t nValues) {
    (void)valueReferences; (void)nValueReferences; (void)orders; (void)values; (void)nValues;
    UNSUPPORTED(fmi3GetOutputDerivatives, "maxOutputDerivativeOrder=0")
}

fmi3Status fmi3DoStep(fmi3Instance instance, fmi3Float64 currentCommunicationPoint,
                      fmi3Float64 communicationStepSize, fmi3Boolean noSetFMUStatePriorToCurrentPoint,
                      fmi3Boolean *eventHandlingNeeded, fmi3Boolean *terminateSimulation,
                      fmi3Boolean *earlyReturn, fmi3Float64 *lastSuccessfulTime) {
    double tolerance;
    BEGIN_CS(fmi3DoStep)
    (void)noSetFMUStatePriorToCurrentPoint;

    if (isnan(communicationStepSize) || isinf(communicationStepSize) || communicationStepSize < 0.0) {
        logError(comp, "fmi3DoStep(): communicationStepSize %g must be finite and >= 0.", communicationStepSize);
        return fmi3Error;
    }

    tolerance = 1e-9 * (fabs(comp->time) > 1.0 ? fabs(comp->time) : 1.0);
    if (isnan(currentCommunicationPoint) || fabs(currentCommunicationPoint - comp->time) > tolerance) {
        logError(comp, "fmi3DoStep(): currentCommunicationPoint %.17g does not match the FMU's time %.17g.",
                 currentCommunicationPoint, comp->time);
        return fmi3Error;
    }

    if (doStep(comp, communicationStepSize) > Warning) {
        return fmi3Error;
    }

    comp->time = currentCommunicationPoint + communicationStepSize;

    if (eventHandlingNeeded) *eventHandlingNeeded = fmi3False;
    if (terminateSimulation) *terminateSimulation = fmi3False;
    if (earlyReturn)         *earlyReturn = fmi3False;
    if (lastSuccessfulTime)  *lastSuccessfulTime = comp->time;

    return fmi3OK;
}
