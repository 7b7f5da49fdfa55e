/* A minimal FMI 3 co-simulation master in C, with no Python in it: the plant FMU's tests
 * use it to run the FMU as a non-Python tool does (the shim loads libpython itself).
 *
 *   fmi3_host BINARY RESOURCES_DIR TOKEN V_VR X_VR Y_VR V STEPS
 *
 * drives input V_VR at V for STEPS steps of 20 ms, then prints "x y" of X_VR, Y_VR.
 * Exit 0; 3 if instantiation failed (the logger's messages are on stdout). */
#include <dlfcn.h>
#include <stdio.h>
#include <stdlib.h>

#include "fmi3Functions.h"

static void logger(fmi3InstanceEnvironment env, fmi3Status status, fmi3String category,
                   fmi3String message) {
    printf("[%d %s] %s\n", (int)status, category, message);
    fflush(stdout);
}

#define LOAD(f) f##TYPE *f = (f##TYPE *)dlsym(lib, #f); if (!f) { printf("no %s\n", #f); return 2; }

int main(int argc, char **argv) {
    void *lib;
    fmi3Instance c;
    fmi3ValueReference v_vr, out[2];
    fmi3Float64 v, xy[2];
    int steps, i;
    fmi3Boolean a, b, e;
    fmi3Float64 last;
    if (argc != 9) { printf("usage: see the source\n"); return 2; }
    lib = dlopen(argv[1], RTLD_NOW | RTLD_LOCAL);
    if (!lib) { printf("dlopen: %s\n", dlerror()); return 2; }
    LOAD(fmi3InstantiateCoSimulation) LOAD(fmi3EnterInitializationMode)
    LOAD(fmi3ExitInitializationMode) LOAD(fmi3SetFloat64) LOAD(fmi3GetFloat64)
    LOAD(fmi3DoStep) LOAD(fmi3Terminate) LOAD(fmi3FreeInstance)
    v_vr = (fmi3ValueReference)atoi(argv[4]);
    out[0] = (fmi3ValueReference)atoi(argv[5]);
    out[1] = (fmi3ValueReference)atoi(argv[6]);
    v = atof(argv[7]);
    steps = atoi(argv[8]);
    c = fmi3InstantiateCoSimulation("host", argv[3], argv[2], fmi3False, fmi3False, fmi3False,
                                    fmi3False, NULL, 0, NULL, logger, NULL);
    if (!c) return 3;
    if (fmi3EnterInitializationMode(c, fmi3False, 0.0, 0.0, fmi3False, 0.0) != fmi3OK ||
        fmi3ExitInitializationMode(c) != fmi3OK) return 4;
    for (i = 0; i < steps; i++) {
        if (fmi3SetFloat64(c, &v_vr, 1, &v, 1) != fmi3OK) return 5;
        if (fmi3DoStep(c, i * 0.02, 0.02, fmi3True, &a, &b, &e, &last) != fmi3OK) return 6;
    }
    if (fmi3GetFloat64(c, out, 2, xy, 2) != fmi3OK) return 7;
    printf("%.17g %.17g\n", xy[0], xy[1]);
    fmi3Terminate(c);
    fmi3FreeInstance(c);
    return 0;
}
