/* FMU states of the plant FMU (see plant_python.h): the Python instance keeps each state
 * (fmus/plant_state.py) under an id >= 1, which is the opaque FMUState pointer. */
#include <stdint.h>
#include <stdlib.h>
#include <sys/types.h>

#include "plant_python.h"

#define ADDR(p) ((unsigned long long)(uintptr_t)(p))
#define ID(s) ((unsigned long long)(uintptr_t)(s))

int plant_get_state(PlantInstance *pi, void **state) {
    unsigned long long id = 0;
    int status;
    if (!state) return PLANT_ERROR;
    status = plant_call(pi, "get_state", "KK", ID(*state), ADDR(&id));
    if (status <= PLANT_WARNING) *state = (void *)(uintptr_t)id;
    return status;
}

int plant_set_state(PlantInstance *pi, void *state) {
    if (!state) {
        plant_log(pi, PLANT_ERROR, "setFMUState: no state (NULL)");
        return PLANT_ERROR;
    }
    return plant_call(pi, "set_state", "K", ID(state));
}

int plant_free_state(PlantInstance *pi, void **state) {
    int status;
    if (!state || !*state) return PLANT_OK;
    status = plant_call(pi, "free_state", "K", ID(*state));
    *state = NULL;
    return status;
}

int plant_state_size(PlantInstance *pi, void *state, size_t *size) {
    unsigned long long n = 0;
    int status;
    if (!size) return PLANT_ERROR;
    status = plant_call(pi, "state_size", "KK", ID(state), ADDR(&n));
    if (status <= PLANT_WARNING) *size = (size_t)n;
    return status;
}

int plant_serialize_state(PlantInstance *pi, void *state, unsigned char *bytes, size_t size) {
    if (!bytes) return PLANT_ERROR;
    return plant_call(pi, "serialize_state", "KKn", ID(state), ADDR(bytes), (ssize_t)size);
}

int plant_deserialize_state(PlantInstance *pi, const unsigned char *bytes, size_t size,
                            void **state) {
    unsigned long long id = 0;
    int status;
    if (!bytes || !state) return PLANT_ERROR;
    status = plant_call(pi, "deserialize_state", "KnK", ADDR(bytes), (ssize_t)size, ADDR(&id));
    if (status <= PLANT_WARNING) {
        if (*state) plant_free_state(pi, state);
        *state = (void *)(uintptr_t)id;
    }
    return status;
}
