/* FMI 3.0 co-simulation interface of the plant FMU (the work is in fmus/plant_fmu.py).
 * Every FMI 3 function is exported (importers bind them all); what a co-simulation plant
 * has no use for (model exchange, scheduled execution, clocks, derivatives)
 * returns fmi3Error with a message. */
#include <stdlib.h>
#include <string.h>

#include "fmi3Functions.h"
#include "plant_python.h"

#define PI ((PlantInstance *)instance)

static void log_fmi3(PlantInstance *pi, int status, const char *category, const char *message) {
    fmi3LogMessageCallback log = (fmi3LogMessageCallback)(void (*)(void))pi->callbacks;
    if (log) log((fmi3InstanceEnvironment)pi->env, (fmi3Status)status, category, message);
}

const char *fmi3GetVersion(void) { return fmi3Version; }

fmi3Status fmi3SetDebugLogging(fmi3Instance instance, fmi3Boolean loggingOn, size_t nCategories,
                               const fmi3String categories[]) {
    if (!instance) return fmi3Error;
    PI->logging = loggingOn ? 1 : 0;
    return fmi3OK;
}

fmi3Instance fmi3InstantiateCoSimulation(fmi3String instanceName, fmi3String instantiationToken,
        fmi3String resourcePath, fmi3Boolean visible, fmi3Boolean loggingOn,
        fmi3Boolean eventModeUsed, fmi3Boolean earlyReturnAllowed,
        const fmi3ValueReference requiredIntermediateVariables[],
        size_t nRequiredIntermediateVariables, fmi3InstanceEnvironment instanceEnvironment,
        fmi3LogMessageCallback logMessage, fmi3IntermediateUpdateCallback intermediateUpdate) {
    PlantInstance proto;
    char *resources = plant_resource_dir(resourcePath);
    PlantInstance *pi;
    memset(&proto, 0, sizeof proto);
    proto.name = (char *)instanceName;
    proto.fmi = 3;
    proto.logging = loggingOn ? 1 : 0;
    proto.logger = log_fmi3;
    proto.env = instanceEnvironment;
    proto.callbacks = (const void *)(void (*)(void))logMessage;
    if (eventModeUsed) {
        plant_log(&proto, PLANT_ERROR, "the plant FMU has no event mode (eventModeUsed)");
        free(resources);
        return NULL;
    }
    pi = plant_instantiate(&proto, resources, instantiationToken);
    free(resources);
    return (fmi3Instance)pi;
}

fmi3Instance fmi3InstantiateModelExchange(fmi3String instanceName, fmi3String instantiationToken,
        fmi3String resourcePath, fmi3Boolean visible, fmi3Boolean loggingOn,
        fmi3InstanceEnvironment instanceEnvironment, fmi3LogMessageCallback logMessage) {
    if (logMessage) logMessage(instanceEnvironment, fmi3Error, "logStatusError",
                               "the plant FMU is co-simulation only");
    return NULL;
}

fmi3Instance fmi3InstantiateScheduledExecution(fmi3String instanceName,
        fmi3String instantiationToken, fmi3String resourcePath, fmi3Boolean visible,
        fmi3Boolean loggingOn, fmi3InstanceEnvironment instanceEnvironment,
        fmi3LogMessageCallback logMessage, fmi3ClockUpdateCallback clockUpdate,
        fmi3LockPreemptionCallback lockPreemption, fmi3UnlockPreemptionCallback unlockPreemption) {
    if (logMessage) logMessage(instanceEnvironment, fmi3Error, "logStatusError",
                               "the plant FMU is co-simulation only");
    return NULL;
}

void fmi3FreeInstance(fmi3Instance instance) { plant_free(PI); }

fmi3Status fmi3EnterInitializationMode(fmi3Instance instance, fmi3Boolean toleranceDefined,
        fmi3Float64 tolerance, fmi3Float64 startTime, fmi3Boolean stopTimeDefined,
        fmi3Float64 stopTime) {
    return (fmi3Status)plant_call(PI, "enter_init", "d", startTime);
}

fmi3Status fmi3ExitInitializationMode(fmi3Instance instance) {
    return (fmi3Status)plant_call(PI, "exit_init", "");
}

fmi3Status fmi3Terminate(fmi3Instance instance) {
    return (fmi3Status)plant_call(PI, "terminate", "");
}

fmi3Status fmi3Reset(fmi3Instance instance) { return (fmi3Status)plant_call(PI, "reset", ""); }

/* without event mode the instance is in step mode after initialization already */
fmi3Status fmi3EnterStepMode(fmi3Instance instance) { return instance ? fmi3OK : fmi3Error; }

fmi3Status fmi3DoStep(fmi3Instance instance, fmi3Float64 currentCommunicationPoint,
        fmi3Float64 communicationStepSize, fmi3Boolean noSetFMUStatePriorToCurrentPoint,
        fmi3Boolean *eventHandlingNeeded, fmi3Boolean *terminateSimulation,
        fmi3Boolean *earlyReturn, fmi3Float64 *lastSuccessfulTime) {
    fmi3Status status = (fmi3Status)plant_call(PI, "do_step", "dd", currentCommunicationPoint,
                                               communicationStepSize);
    if (eventHandlingNeeded) *eventHandlingNeeded = fmi3False;
    if (terminateSimulation) *terminateSimulation = fmi3False;
    if (earlyReturn) *earlyReturn = fmi3False;
    if (lastSuccessfulTime)
        *lastSuccessfulTime = currentCommunicationPoint +
                              (status == fmi3OK ? communicationStepSize : 0.0);
    return status;
}

/* ------------------------------------------------------------- values */
fmi3Status fmi3GetFloat64(fmi3Instance instance, const fmi3ValueReference vr[], size_t nvr,
                          fmi3Float64 values[], size_t nValues) {
    return (fmi3Status)plant_get(PI, "Float64", vr, nvr, values, nValues);
}
fmi3Status fmi3SetFloat64(fmi3Instance instance, const fmi3ValueReference vr[], size_t nvr,
                          const fmi3Float64 values[], size_t nValues) {
    return (fmi3Status)plant_set(PI, "Float64", vr, nvr, values, nValues);
}
fmi3Status fmi3GetInt32(fmi3Instance instance, const fmi3ValueReference vr[], size_t nvr,
                        fmi3Int32 values[], size_t nValues) {
    return (fmi3Status)plant_get(PI, "Int32", vr, nvr, values, nValues);
}
fmi3Status fmi3SetInt32(fmi3Instance instance, const fmi3ValueReference vr[], size_t nvr,
                        const fmi3Int32 values[], size_t nValues) {
    return (fmi3Status)plant_set(PI, "Int32", vr, nvr, values, nValues);
}
fmi3Status fmi3GetBoolean(fmi3Instance instance, const fmi3ValueReference vr[], size_t nvr,
                          fmi3Boolean values[], size_t nValues) {
    return (fmi3Status)plant_get(PI, "Boolean", vr, nvr, values, nValues);
}
fmi3Status fmi3SetBoolean(fmi3Instance instance, const fmi3ValueReference vr[], size_t nvr,
                          const fmi3Boolean values[], size_t nValues) {
    return (fmi3Status)plant_set(PI, "Boolean", vr, nvr, values, nValues);
}
fmi3Status fmi3GetString(fmi3Instance instance, const fmi3ValueReference vr[], size_t nvr,
                         fmi3String values[], size_t nValues) {
    if (nValues != nvr) return fmi3Error;
    return (fmi3Status)plant_get_strings(PI, vr, nvr, values);
}
fmi3Status fmi3SetString(fmi3Instance instance, const fmi3ValueReference vr[], size_t nvr,
                         const fmi3String values[], size_t nValues) {
    if (nValues != nvr) return fmi3Error;
    return (fmi3Status)plant_set_strings(PI, vr, nvr, values);
}

/* ------------------------------------------- everything the plant FMU does not offer */
static fmi3Status unsupported(fmi3Instance instance, const char *f) {
    if (instance) plant_log(PI, PLANT_ERROR, "%s is not supported by the plant FMU", f);
    return fmi3Error;
}
#define NO(f) { return unsupported(instance, #f); }

#define NO_GET_SET(T)                                                                      \
fmi3Status fmi3Get##T(fmi3Instance instance, const fmi3ValueReference vr[], size_t nvr,    \
                      fmi3##T values[], size_t nValues) NO(fmi3Get##T)                     \
fmi3Status fmi3Set##T(fmi3Instance instance, const fmi3ValueReference vr[], size_t nvr,    \
                      const fmi3##T values[], size_t nValues) NO(fmi3Set##T)
NO_GET_SET(Float32) NO_GET_SET(Int8) NO_GET_SET(UInt8) NO_GET_SET(Int16) NO_GET_SET(UInt16)
NO_GET_SET(UInt32) NO_GET_SET(Int64) NO_GET_SET(UInt64)

fmi3Status fmi3EnterEventMode(fmi3Instance instance) NO(fmi3EnterEventMode)
fmi3Status fmi3GetBinary(fmi3Instance instance, const fmi3ValueReference vr[], size_t nvr,
                         size_t valueSizes[], fmi3Binary values[], size_t nValues) NO(fmi3GetBinary)
fmi3Status fmi3SetBinary(fmi3Instance instance, const fmi3ValueReference vr[], size_t nvr,
                         const size_t valueSizes[], const fmi3Binary values[],
                         size_t nValues) NO(fmi3SetBinary)
fmi3Status fmi3GetClock(fmi3Instance instance, const fmi3ValueReference vr[], size_t nvr,
                        fmi3Clock values[]) NO(fmi3GetClock)
fmi3Status fmi3SetClock(fmi3Instance instance, const fmi3ValueReference vr[], size_t nvr,
                        const fmi3Clock values[]) NO(fmi3SetClock)
fmi3Status fmi3GetNumberOfVariableDependencies(fmi3Instance instance,
        fmi3ValueReference valueReference, size_t *nDependencies)
    NO(fmi3GetNumberOfVariableDependencies)
fmi3Status fmi3GetVariableDependencies(fmi3Instance instance, fmi3ValueReference dependent,
        size_t elementIndicesOfDependent[], fmi3ValueReference independents[],
        size_t elementIndicesOfIndependents[], fmi3DependencyKind dependencyKinds[],
        size_t nDependencies) NO(fmi3GetVariableDependencies)
fmi3Status fmi3GetFMUState(fmi3Instance instance, fmi3FMUState *FMUState) {
    return instance ? (fmi3Status)plant_get_state(PI, FMUState) : fmi3Error;
}
fmi3Status fmi3SetFMUState(fmi3Instance instance, fmi3FMUState FMUState) {
    return instance ? (fmi3Status)plant_set_state(PI, FMUState) : fmi3Error;
}
fmi3Status fmi3FreeFMUState(fmi3Instance instance, fmi3FMUState *FMUState) {
    return instance ? (fmi3Status)plant_free_state(PI, FMUState) : fmi3Error;
}
fmi3Status fmi3SerializedFMUStateSize(fmi3Instance instance, fmi3FMUState FMUState,
                                      size_t *size) {
    return instance ? (fmi3Status)plant_state_size(PI, FMUState, size) : fmi3Error;
}
fmi3Status fmi3SerializeFMUState(fmi3Instance instance, fmi3FMUState FMUState,
        fmi3Byte serializedState[], size_t size) {
    return instance ? (fmi3Status)plant_serialize_state(PI, FMUState, serializedState, size)
                    : fmi3Error;
}
fmi3Status fmi3DeserializeFMUState(fmi3Instance instance, const fmi3Byte serializedState[],
        size_t size, fmi3FMUState *FMUState) {
    return instance ? (fmi3Status)plant_deserialize_state(PI, serializedState, size, FMUState)
                    : fmi3Error;
}
fmi3Status fmi3GetDirectionalDerivative(fmi3Instance instance, const fmi3ValueReference unknowns[],
        size_t nUnknowns, const fmi3ValueReference knowns[], size_t nKnowns,
        const fmi3Float64 seed[], size_t nSeed, fmi3Float64 sensitivity[],
        size_t nSensitivity) NO(fmi3GetDirectionalDerivative)
fmi3Status fmi3GetAdjointDerivative(fmi3Instance instance, const fmi3ValueReference unknowns[],
        size_t nUnknowns, const fmi3ValueReference knowns[], size_t nKnowns,
        const fmi3Float64 seed[], size_t nSeed, fmi3Float64 sensitivity[],
        size_t nSensitivity) NO(fmi3GetAdjointDerivative)
fmi3Status fmi3EnterConfigurationMode(fmi3Instance instance) NO(fmi3EnterConfigurationMode)
fmi3Status fmi3ExitConfigurationMode(fmi3Instance instance) NO(fmi3ExitConfigurationMode)
fmi3Status fmi3GetIntervalDecimal(fmi3Instance instance, const fmi3ValueReference vr[],
        size_t nvr, fmi3Float64 intervals[], fmi3IntervalQualifier qualifiers[])
    NO(fmi3GetIntervalDecimal)
fmi3Status fmi3GetIntervalFraction(fmi3Instance instance, const fmi3ValueReference vr[],
        size_t nvr, fmi3UInt64 counters[], fmi3UInt64 resolutions[],
        fmi3IntervalQualifier qualifiers[]) NO(fmi3GetIntervalFraction)
fmi3Status fmi3GetShiftDecimal(fmi3Instance instance, const fmi3ValueReference vr[],
        size_t nvr, fmi3Float64 shifts[]) NO(fmi3GetShiftDecimal)
fmi3Status fmi3GetShiftFraction(fmi3Instance instance, const fmi3ValueReference vr[],
        size_t nvr, fmi3UInt64 counters[], fmi3UInt64 resolutions[]) NO(fmi3GetShiftFraction)
fmi3Status fmi3SetIntervalDecimal(fmi3Instance instance, const fmi3ValueReference vr[],
        size_t nvr, const fmi3Float64 intervals[]) NO(fmi3SetIntervalDecimal)
fmi3Status fmi3SetIntervalFraction(fmi3Instance instance, const fmi3ValueReference vr[],
        size_t nvr, const fmi3UInt64 counters[], const fmi3UInt64 resolutions[])
    NO(fmi3SetIntervalFraction)
fmi3Status fmi3SetShiftDecimal(fmi3Instance instance, const fmi3ValueReference vr[],
        size_t nvr, const fmi3Float64 shifts[]) NO(fmi3SetShiftDecimal)
fmi3Status fmi3SetShiftFraction(fmi3Instance instance, const fmi3ValueReference vr[],
        size_t nvr, const fmi3UInt64 counters[], const fmi3UInt64 resolutions[])
    NO(fmi3SetShiftFraction)
fmi3Status fmi3EvaluateDiscreteStates(fmi3Instance instance) NO(fmi3EvaluateDiscreteStates)
fmi3Status fmi3UpdateDiscreteStates(fmi3Instance instance, fmi3Boolean *discreteStatesNeedUpdate,
        fmi3Boolean *terminateSimulation, fmi3Boolean *nominalsOfContinuousStatesChanged,
        fmi3Boolean *valuesOfContinuousStatesChanged, fmi3Boolean *nextEventTimeDefined,
        fmi3Float64 *nextEventTime) NO(fmi3UpdateDiscreteStates)
fmi3Status fmi3EnterContinuousTimeMode(fmi3Instance instance) NO(fmi3EnterContinuousTimeMode)
fmi3Status fmi3CompletedIntegratorStep(fmi3Instance instance,
        fmi3Boolean noSetFMUStatePriorToCurrentPoint, fmi3Boolean *enterEventMode,
        fmi3Boolean *terminateSimulation) NO(fmi3CompletedIntegratorStep)
fmi3Status fmi3SetTime(fmi3Instance instance, fmi3Float64 time) NO(fmi3SetTime)
fmi3Status fmi3SetContinuousStates(fmi3Instance instance, const fmi3Float64 continuousStates[],
        size_t nContinuousStates) NO(fmi3SetContinuousStates)
fmi3Status fmi3GetContinuousStateDerivatives(fmi3Instance instance, fmi3Float64 derivatives[],
        size_t nContinuousStates) NO(fmi3GetContinuousStateDerivatives)
fmi3Status fmi3GetEventIndicators(fmi3Instance instance, fmi3Float64 eventIndicators[],
        size_t nEventIndicators) NO(fmi3GetEventIndicators)
fmi3Status fmi3GetContinuousStates(fmi3Instance instance, fmi3Float64 continuousStates[],
        size_t nContinuousStates) NO(fmi3GetContinuousStates)
fmi3Status fmi3GetNominalsOfContinuousStates(fmi3Instance instance, fmi3Float64 nominals[],
        size_t nContinuousStates) NO(fmi3GetNominalsOfContinuousStates)
fmi3Status fmi3GetNumberOfEventIndicators(fmi3Instance instance, size_t *nEventIndicators)
    NO(fmi3GetNumberOfEventIndicators)
fmi3Status fmi3GetNumberOfContinuousStates(fmi3Instance instance, size_t *nContinuousStates)
    NO(fmi3GetNumberOfContinuousStates)
fmi3Status fmi3GetOutputDerivatives(fmi3Instance instance, const fmi3ValueReference vr[],
        size_t nvr, const fmi3Int32 orders[], fmi3Float64 values[], size_t nValues)
    NO(fmi3GetOutputDerivatives)
fmi3Status fmi3ActivateModelPartition(fmi3Instance instance, fmi3ValueReference clockReference,
        fmi3Float64 activationTime) NO(fmi3ActivateModelPartition)
