/* The plant FMU's C shim: an FMI 2/3 co-simulation interface over fmus/plant_fmu.py.
 *
 * A tool-coupling FMU: it needs a Python >= 3.10 with diffbot-cosim installed on the machine
 * it runs on. In a host that runs Python (fmpy, libcosimpy, ecospy) the host's interpreter
 * is used; elsewhere the shim chooses one (plant_choose_python), asks it where its libpython
 * and diffbot-cosim are (resources/plant_guest.py run as a script), then loads and
 * initialises that libpython once per process. Python is never linked at build time: every
 * C-API function (the limited API of 3.10) is looked up at run time, so a missing Python
 * or package is an FMI error with a message, not a failure to load the binary. The Python
 * side is reached through resources/plant_guest.py's Guest, in a namespace of its own. */
#ifndef PLANT_PYTHON_H
#define PLANT_PYTHON_H

#include <stddef.h>

enum { PLANT_OK = 0, PLANT_WARNING = 1, PLANT_DISCARD = 2, PLANT_ERROR = 3, PLANT_FATAL = 4 };

typedef struct PlantInstance PlantInstance;

/* how a message reaches the importer's logger (one per FMI version) */
typedef void (*PlantLogger)(PlantInstance *pi, int status, const char *category,
                            const char *message);

struct PlantInstance {
    void *py;                 /* the fmus.plant_fmu.PlantInstance object */
    char *name;
    int fmi;                  /* 2 or 3 */
    int logging;              /* debug logging on (logEvents) */
    double start_time;        /* FMI 2: from fmi2SetupExperiment */
    PlantLogger logger;
    void *env;                /* the importer's environment for the logger */
    const void *callbacks;    /* FMI 2: the callback functions */
    char **strings;           /* the values last returned by getString */
    size_t nstrings;
};

/* "file:///a/b" or "/a/b/" -> "/a/b" (malloc'ed), NULL on a URI of another scheme */
char *plant_resource_dir(const char *location);

/* A new instance, NULL on failure (the reason went to the logger). The caller fills in
 * logger, env, callbacks and fmi before, through *proto. */
PlantInstance *plant_instantiate(const PlantInstance *proto, const char *resources,
                                 const char *token);
void plant_free(PlantInstance *pi);

/* Call a method of the Python instance with Py_BuildValue arguments (fmt without the
 * parentheses); returns its FMI status (an exception: PLANT_ERROR). A status other than
 * OK is logged with the instance's message. */
int plant_call(PlantInstance *pi, const char *method, const char *fmt, ...);

/* get / set values of one FMI type ("Float64", "Int32", "Boolean") */
int plant_get(PlantInstance *pi, const char *kind, const unsigned int *vr, size_t nvr,
              void *values, size_t nvalues);
int plant_set(PlantInstance *pi, const char *kind, const unsigned int *vr, size_t nvr,
              const void *values, size_t nvalues);
int plant_get_strings(PlantInstance *pi, const unsigned int *vr, size_t nvr, const char **values);
int plant_set_strings(PlantInstance *pi, const unsigned int *vr, size_t nvr,
                      const char *const *values);

void plant_log(PlantInstance *pi, int status, const char *fmt, ...);

/* ---- plant_state.c: FMU states (an id the Python instance keeps, as the FMUState pointer) */
int plant_get_state(PlantInstance *pi, void **state);     /* *state NULL: a new one */
int plant_set_state(PlantInstance *pi, void *state);
int plant_free_state(PlantInstance *pi, void **state);
int plant_state_size(PlantInstance *pi, void *state, size_t *size);
int plant_serialize_state(PlantInstance *pi, void *state, unsigned char *bytes, size_t size);
int plant_deserialize_state(PlantInstance *pi, const unsigned char *bytes, size_t size,
                            void **state);

/* ---- plant_locate.c: the Python that runs the FMU in a host without one */
#define PLANT_PYTHON_ENV "DIFFBOT_FMU_PYTHON"

typedef struct {
    char python[4096];        /* resources/plant.cfg's python= (a bound export), else "" */
} PlantConfig;

/* $DIFFBOT_FMU_PYTHON, else cfg->python, else $VIRTUAL_ENV/bin/python, else python3 on
 * PATH: 0 with exe and why (how it was chosen) filled, -1 if there is none */
int plant_choose_python(const PlantConfig *cfg, char *exe, size_t n, char *why, size_t nwhy);
/* what `exe resources/plant_guest.py resources` printed (stdout and stderr, malloc'ed; NULL
 * if it could not be started); *exit_status its exit status */
char *plant_run_query(const char *exe, const char *resources, int *exit_status);
/* the value of the first "key=" line of text ("" if none) */
void plant_query_value(const char *text, const char *key, char *out, size_t n);
/* the "error=" lines of text joined with "; " ("" if none) */
void plant_query_errors(const char *text, char *out, size_t n);

#endif
