/* FMI 2.0 co-simulation interface of the plant FMU (the work is in fmus/plant_fmu.py).
 * Every FMI 2 function is exported; model exchange and derivatives return
 * fmi2Error with a message. */
#include <stdlib.h>
#include <string.h>

#include "fmi2Functions.h"
#include "plant_python.h"

#define PI ((PlantInstance *)c)

static void log_fmi2(PlantInstance *pi, int status, const char *category, const char *message) {
    const fmi2CallbackFunctions *f = (const fmi2CallbackFunctions *)pi->callbacks;
    /* the message goes as an argument: FMI 2 loggers read it as a format */
    if (f && f->logger)
        f->logger(f->componentEnvironment, pi->name, (fmi2Status)status, category, "%s", message);
}

const char *fmi2GetTypesPlatform(void) { return fmi2TypesPlatform; }
const char *fmi2GetVersion(void) { return fmi2Version; }

fmi2Status fmi2SetDebugLogging(fmi2Component c, fmi2Boolean loggingOn, size_t nCategories,
                               const fmi2String categories[]) {
    if (!c) return fmi2Error;
    PI->logging = loggingOn ? 1 : 0;
    return fmi2OK;
}

fmi2Component fmi2Instantiate(fmi2String instanceName, fmi2Type fmuType, fmi2String fmuGUID,
                              fmi2String fmuResourceLocation,
                              const fmi2CallbackFunctions *functions, fmi2Boolean visible,
                              fmi2Boolean loggingOn) {
    PlantInstance proto;
    PlantInstance *pi;
    char *resources;
    memset(&proto, 0, sizeof proto);
    proto.name = (char *)instanceName;
    proto.fmi = 2;
    proto.logging = loggingOn ? 1 : 0;
    proto.logger = log_fmi2;
    proto.callbacks = functions;
    if (fmuType != fmi2CoSimulation) {
        plant_log(&proto, PLANT_ERROR, "the plant FMU is co-simulation only");
        return NULL;
    }
    resources = plant_resource_dir(fmuResourceLocation);
    if (!resources) {
        plant_log(&proto, PLANT_ERROR, "unsupported resource location %s (a file URI is needed)",
                  fmuResourceLocation ? fmuResourceLocation : "(null)");
        return NULL;
    }
    pi = plant_instantiate(&proto, resources, fmuGUID);
    free(resources);
    return (fmi2Component)pi;
}

void fmi2FreeInstance(fmi2Component c) { plant_free(PI); }

fmi2Status fmi2SetupExperiment(fmi2Component c, fmi2Boolean toleranceDefined, fmi2Real tolerance,
                               fmi2Real startTime, fmi2Boolean stopTimeDefined, fmi2Real stopTime) {
    if (!c) return fmi2Error;
    PI->start_time = startTime;
    return fmi2OK;
}

fmi2Status fmi2EnterInitializationMode(fmi2Component c) {
    return c ? (fmi2Status)plant_call(PI, "enter_init", "d", PI->start_time) : fmi2Error;
}
fmi2Status fmi2ExitInitializationMode(fmi2Component c) {
    return (fmi2Status)plant_call(PI, "exit_init", "");
}
fmi2Status fmi2Terminate(fmi2Component c) { return (fmi2Status)plant_call(PI, "terminate", ""); }
fmi2Status fmi2Reset(fmi2Component c) { return (fmi2Status)plant_call(PI, "reset", ""); }

fmi2Status fmi2DoStep(fmi2Component c, fmi2Real currentCommunicationPoint,
                      fmi2Real communicationStepSize, fmi2Boolean noSetFMUStatePriorToCurrentPoint) {
    return (fmi2Status)plant_call(PI, "do_step", "dd", currentCommunicationPoint,
                                  communicationStepSize);
}

/* ------------------------------------------------------------- values */
fmi2Status fmi2GetReal(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, fmi2Real v[]) {
    return (fmi2Status)plant_get(PI, "Float64", vr, nvr, v, nvr);
}
fmi2Status fmi2GetInteger(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                          fmi2Integer v[]) {
    return (fmi2Status)plant_get(PI, "Int32", vr, nvr, v, nvr);
}
fmi2Status fmi2GetBoolean(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                          fmi2Boolean v[]) {
    return (fmi2Status)plant_get(PI, "Boolean", vr, nvr, v, nvr);
}
fmi2Status fmi2GetString(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                         fmi2String v[]) {
    return (fmi2Status)plant_get_strings(PI, vr, nvr, v);
}
fmi2Status fmi2SetReal(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                       const fmi2Real v[]) {
    return (fmi2Status)plant_set(PI, "Float64", vr, nvr, v, nvr);
}
fmi2Status fmi2SetInteger(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                          const fmi2Integer v[]) {
    return (fmi2Status)plant_set(PI, "Int32", vr, nvr, v, nvr);
}
fmi2Status fmi2SetBoolean(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                          const fmi2Boolean v[]) {
    return (fmi2Status)plant_set(PI, "Boolean", vr, nvr, v, nvr);
}
fmi2Status fmi2SetString(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                         const fmi2String v[]) {
    return (fmi2Status)plant_set_strings(PI, vr, nvr, v);
}

fmi2Status fmi2GetStatus(fmi2Component c, const fmi2StatusKind s, fmi2Status *value) {
    if (!c || !value || s != fmi2DoStepStatus) return fmi2Discard;
    *value = fmi2OK;                      /* doStep always returns at once */
    return fmi2OK;
}

/* ------------------------------------------- everything the plant FMU does not offer */
static fmi2Status unsupported(fmi2Component c, const char *f) {
    if (c) plant_log(PI, PLANT_ERROR, "%s is not supported by the plant FMU", f);
    return fmi2Error;
}
#define NO(f) { return unsupported(c, #f); }

fmi2Status fmi2GetFMUstate(fmi2Component c, fmi2FMUstate *s) {
    return c ? (fmi2Status)plant_get_state(PI, s) : fmi2Error;
}
fmi2Status fmi2SetFMUstate(fmi2Component c, fmi2FMUstate s) {
    return c ? (fmi2Status)plant_set_state(PI, s) : fmi2Error;
}
fmi2Status fmi2FreeFMUstate(fmi2Component c, fmi2FMUstate *s) {
    return c ? (fmi2Status)plant_free_state(PI, s) : fmi2Error;
}
fmi2Status fmi2SerializedFMUstateSize(fmi2Component c, fmi2FMUstate s, size_t *size) {
    return c ? (fmi2Status)plant_state_size(PI, s, size) : fmi2Error;
}
fmi2Status fmi2SerializeFMUstate(fmi2Component c, fmi2FMUstate s, fmi2Byte b[], size_t size) {
    return c ? (fmi2Status)plant_serialize_state(PI, s, (unsigned char *)b, size) : fmi2Error;
}
fmi2Status fmi2DeSerializeFMUstate(fmi2Component c, const fmi2Byte b[], size_t size,
                                   fmi2FMUstate *s) {
    return c ? (fmi2Status)plant_deserialize_state(PI, (const unsigned char *)b, size, s)
             : fmi2Error;
}
fmi2Status fmi2GetDirectionalDerivative(fmi2Component c, const fmi2ValueReference u[],
        size_t nu, const fmi2ValueReference k[], size_t nk, const fmi2Real dk[], fmi2Real du[])
    NO(fmi2GetDirectionalDerivative)
fmi2Status fmi2EnterEventMode(fmi2Component c) NO(fmi2EnterEventMode)
fmi2Status fmi2NewDiscreteStates(fmi2Component c, fmi2EventInfo *info) NO(fmi2NewDiscreteStates)
fmi2Status fmi2EnterContinuousTimeMode(fmi2Component c) NO(fmi2EnterContinuousTimeMode)
fmi2Status fmi2CompletedIntegratorStep(fmi2Component c, fmi2Boolean noSet,
        fmi2Boolean *enterEventMode, fmi2Boolean *terminateSimulation)
    NO(fmi2CompletedIntegratorStep)
fmi2Status fmi2SetTime(fmi2Component c, fmi2Real time) NO(fmi2SetTime)
fmi2Status fmi2SetContinuousStates(fmi2Component c, const fmi2Real x[], size_t nx)
    NO(fmi2SetContinuousStates)
fmi2Status fmi2GetDerivatives(fmi2Component c, fmi2Real d[], size_t nx) NO(fmi2GetDerivatives)
fmi2Status fmi2GetEventIndicators(fmi2Component c, fmi2Real e[], size_t ni)
    NO(fmi2GetEventIndicators)
fmi2Status fmi2GetContinuousStates(fmi2Component c, fmi2Real x[], size_t nx)
    NO(fmi2GetContinuousStates)
fmi2Status fmi2GetNominalsOfContinuousStates(fmi2Component c, fmi2Real x[], size_t nx)
    NO(fmi2GetNominalsOfContinuousStates)
fmi2Status fmi2SetRealInputDerivatives(fmi2Component c, const fmi2ValueReference vr[],
        size_t nvr, const fmi2Integer order[], const fmi2Real value[])
    NO(fmi2SetRealInputDerivatives)
fmi2Status fmi2GetRealOutputDerivatives(fmi2Component c, const fmi2ValueReference vr[],
        size_t nvr, const fmi2Integer order[], fmi2Real value[]) NO(fmi2GetRealOutputDerivatives)
fmi2Status fmi2CancelStep(fmi2Component c) NO(fmi2CancelStep)
fmi2Status fmi2GetRealStatus(fmi2Component c, const fmi2StatusKind s, fmi2Real *v)
    NO(fmi2GetRealStatus)
fmi2Status fmi2GetIntegerStatus(fmi2Component c, const fmi2StatusKind s, fmi2Integer *v)
    NO(fmi2GetIntegerStatus)
fmi2Status fmi2GetBooleanStatus(fmi2Component c, const fmi2StatusKind s, fmi2Boolean *v)
    NO(fmi2GetBooleanStatus)
fmi2Status fmi2GetStringStatus(fmi2Component c, const fmi2StatusKind s, fmi2String *v)
    NO(fmi2GetStringStatus)
