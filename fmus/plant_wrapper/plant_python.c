/* The plant FMU's bridge to Python (see plant_python.h). */
#define _GNU_SOURCE
#include <Python.h>

#include <dlfcn.h>
#include <pthread.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "plant_python.h"

/* ------------------------------------------------- the C-API, looked up at run time */
#define PY_FUNCTIONS(X)                                                                 \
    X(Py_IsInitialized) X(Py_GetVersion) X(PyConfig_InitPythonConfig)                   \
    X(PyConfig_SetBytesString) X(PyConfig_Clear) X(Py_InitializeFromConfig)             \
    X(PyStatus_Exception) X(PyEval_SaveThread) X(PyGILState_Ensure) X(PyGILState_Release) \
    X(PyRun_SimpleString) X(PyImport_ImportModule) X(PyObject_GetAttrString)            \
    X(PyObject_CallObject) X(Py_VaBuildValue) X(Py_DecRef) X(PyLong_AsLong)             \
    X(PyErr_Fetch) X(PyErr_Clear) X(PyObject_Str) X(PyUnicode_AsUTF8)

#define DECLARE(f) static __typeof__(&f) p_##f;
PY_FUNCTIONS(DECLARE)

static pthread_mutex_t py_lock = PTHREAD_MUTEX_INITIALIZER;
static int py_ready = 0;
static PyObject *py_module = NULL;      /* fmus.plant_fmu, kept for the process's life */

typedef struct {
    char python_version[32], libpython[4096], executable[4096], root[4096], bootstrap[16384];
} Config;

void plant_log(PlantInstance *pi, int status, const char *fmt, ...) {
    char message[8192];
    va_list ap;
    if (!pi || !pi->logger) return;
    if (status == PLANT_OK && !pi->logging) return;
    va_start(ap, fmt);
    vsnprintf(message, sizeof message, fmt, ap);
    va_end(ap);
    pi->logger(pi, status, status >= PLANT_ERROR ? "logStatusError" :
               status == PLANT_WARNING ? "logStatusWarning" : "logEvents", message);
}

char *plant_resource_dir(const char *location) {
    const char *p = location;
    char *out, *q;
    size_t n;
    if (!location) return NULL;
    if (strncmp(p, "file:", 5) == 0) {
        p += 5;
        if (strncmp(p, "///", 3) == 0) p += 2;
        else if (strncmp(p, "//localhost/", 12) == 0) p += 11;
    } else if (strstr(p, "://")) {
        return NULL;
    }
    out = q = malloc(strlen(p) + 1);
    if (!out) return NULL;
    for (; *p; p++) {                     /* percent-decoding of a file URI */
        unsigned int c;
        if (*p == '%' && sscanf(p + 1, "%2x", &c) == 1) { *q++ = (char)c; p += 2; }
        else *q++ = *p;
    }
    *q = '\0';
    n = strlen(out);
    while (n > 1 && out[n - 1] == '/') out[--n] = '\0';
    return out;
}

static int read_config(PlantInstance *pi, const char *resources, Config *cfg) {
    char path[4096], line[16384];
    FILE *f;
    memset(cfg, 0, sizeof *cfg);
    snprintf(path, sizeof path, "%s/plant.cfg", resources);
    f = fopen(path, "r");
    if (!f) {
        plant_log(pi, PLANT_ERROR, "cannot read %s: the FMU's resources are incomplete", path);
        return -1;
    }
    while (fgets(line, sizeof line, f)) {
        char *eq = strchr(line, '='), *end;
        if (!eq) continue;
        *eq = '\0';
        end = eq + 1 + strcspn(eq + 1, "\r\n");
        *end = '\0';
#define KEY(k) if (strcmp(line, #k) == 0) snprintf(cfg->k, sizeof cfg->k, "%s", eq + 1);
        KEY(python_version) KEY(libpython) KEY(executable) KEY(root) KEY(bootstrap)
#undef KEY
    }
    fclose(f);
    return 0;
}

static const char *missing_environment(const Config *cfg) {
    if (access(cfg->executable, X_OK) != 0) return cfg->executable;
    if (access(cfg->root, R_OK) != 0) return cfg->root;
    return NULL;
}

/* Find the C-API (the host's Python, or libpython loaded here) and initialise Python once. */
static int load_python(PlantInstance *pi, const Config *cfg) {
    void *lib = RTLD_DEFAULT;
    if (!dlsym(RTLD_DEFAULT, "Py_IsInitialized")) {
        lib = dlopen(cfg->libpython, RTLD_NOW | RTLD_GLOBAL);
        if (!lib) {
            plant_log(pi, PLANT_ERROR, "cannot load the Python library of the FMU's "
                      "environment (%s): %s", cfg->libpython, dlerror());
            return -1;
        }
    }
#define RESOLVE(f)                                                                        \
    if (!(p_##f = (__typeof__(&f))dlsym(lib, #f))) {                                      \
        plant_log(pi, PLANT_ERROR, "the Python library has no %s: not Python %s?", #f,    \
                  cfg->python_version);                                                   \
        return -1;                                                                        \
    }
    PY_FUNCTIONS(RESOLVE)
#undef RESOLVE
    if (!p_Py_IsInitialized()) {
        PyConfig config;
        PyStatus status;
        p_PyConfig_InitPythonConfig(&config);
        config.install_signal_handlers = 0;   /* the host's signals stay the host's */
        config.parse_argv = 0;
        /* no site import: a .pth file of the environment may do anything at startup (one
         * here re-executes the interpreter, which would replace the host's process); the
         * bootstrap line of plant.cfg puts site-packages and the package root on sys.path */
        config.site_import = 0;
        status = p_PyConfig_SetBytesString(&config, &config.program_name, cfg->executable);
        if (!p_PyStatus_Exception(status)) status = p_Py_InitializeFromConfig(&config);
        p_PyConfig_Clear(&config);
        if (p_PyStatus_Exception(status)) {
            plant_log(pi, PLANT_ERROR, "cannot start Python from %s: %s", cfg->executable,
                      status.err_msg ? status.err_msg : "unknown error");
            return -1;
        }
        p_PyEval_SaveThread();                /* the GIL is taken per call from now on */
    } else {
        const char *v = p_Py_GetVersion();
        size_t n = strlen(cfg->python_version);
        if (strncmp(v, cfg->python_version, n) != 0 || (v[n] >= '0' && v[n] <= '9')) {
            plant_log(pi, PLANT_ERROR, "the host runs Python %.20s; this tool-coupling FMU "
                      "needs the Python %s environment of %s", v, cfg->python_version,
                      cfg->executable);
            return -1;
        }
    }
    return 0;
}

/* the pending exception's text (the caller holds the GIL) */
static void exception_text(char *out, size_t n) {
    PyObject *type = NULL, *value = NULL, *tb = NULL, *s;
    p_PyErr_Fetch(&type, &value, &tb);
    snprintf(out, n, "unknown Python error");
    s = value ? p_PyObject_Str(value) : NULL;
    if (s) {
        const char *text = p_PyUnicode_AsUTF8(s);
        if (text) snprintf(out, n, "%s", text);
        p_Py_DecRef(s);
    }
    p_PyErr_Clear();
    if (type) p_Py_DecRef(type);
    if (value) p_Py_DecRef(value);
    if (tb) p_Py_DecRef(tb);
}

static PyObject *call(PyObject *obj, const char *method, const char *fmt, va_list ap) {
    char format[64];
    PyObject *f, *args, *result;
    f = p_PyObject_GetAttrString(obj, method);
    if (!f) return NULL;
    snprintf(format, sizeof format, "(%s)", fmt);
    args = p_Py_VaBuildValue(format, ap);
    result = args ? p_PyObject_CallObject(f, args) : NULL;
    if (args) p_Py_DecRef(args);
    p_Py_DecRef(f);
    return result;
}

static PyObject *call_v(PyObject *obj, const char *method, const char *fmt, ...) {
    va_list ap;
    PyObject *r;
    va_start(ap, fmt);
    r = call(obj, method, fmt, ap);
    va_end(ap);
    return r;
}

/* the instance's message for a status other than OK (the caller holds the GIL) */
static void log_reason(PlantInstance *pi, int status, const char *method) {
    PyObject *m = call_v((PyObject *)pi->py, "pop_message", "");
    const char *text = m ? p_PyUnicode_AsUTF8(m) : NULL;
    plant_log(pi, status, "%s: %s", method, text && *text ? text : "failed");
    if (m) p_Py_DecRef(m);
    else p_PyErr_Clear();
}

int plant_call(PlantInstance *pi, const char *method, const char *fmt, ...) {
    va_list ap;
    PyObject *r;
    PyGILState_STATE gil;
    int status = PLANT_ERROR;
    char text[4096];
    if (!pi || !pi->py) return PLANT_ERROR;
    gil = p_PyGILState_Ensure();
    va_start(ap, fmt);
    r = call((PyObject *)pi->py, method, fmt, ap);
    va_end(ap);
    if (r) {
        status = (int)p_PyLong_AsLong(r);
        p_Py_DecRef(r);
        if (status != PLANT_OK) log_reason(pi, status, method);
    } else {
        exception_text(text, sizeof text);
        plant_log(pi, PLANT_ERROR, "%s: %s", method, text);
    }
    p_PyGILState_Release(gil);
    return status;
}

PlantInstance *plant_instantiate(const PlantInstance *proto, const char *resources,
                                 const char *token) {
    Config cfg;
    PlantInstance *pi = calloc(1, sizeof *pi);
    PyGILState_STATE gil;
    char text[4096];
    if (!pi) return NULL;
    *pi = *proto;
    pi->name = strdup(proto->name ? proto->name : "plant");
    pi->py = NULL;
    pi->strings = NULL;
    pi->nstrings = 0;
    if (!resources) {
        plant_log(pi, PLANT_ERROR, "no resource location: the FMU needs resources/plant.cfg");
        goto fail;
    }
    if (read_config(pi, resources, &cfg) != 0) goto fail;
    if (missing_environment(&cfg)) {
        plant_log(pi, PLANT_ERROR, "this tool-coupling FMU needs the Python environment it "
                  "was exported from, and %s is missing: export it again with `diffbot fmu "
                  "export-plant` in the environment that should run it",
                  missing_environment(&cfg));
        goto fail;
    }
    pthread_mutex_lock(&py_lock);
    if (!py_ready && load_python(pi, &cfg) != 0) {
        pthread_mutex_unlock(&py_lock);
        goto fail;
    }
    py_ready = 1;
    gil = p_PyGILState_Ensure();
    if (!py_module) {
        if (p_PyRun_SimpleString(cfg.bootstrap) != 0)
            plant_log(pi, PLANT_WARNING, "the FMU's sys.path bootstrap failed");
        py_module = p_PyImport_ImportModule("fmus.plant_fmu");
    }
    if (py_module) {
        pi->py = call_v(py_module, "instantiate", "isss", pi->fmi, resources, pi->name,
                        token ? token : "");
    }
    if (!pi->py) {
        exception_text(text, sizeof text);
        plant_log(pi, PLANT_ERROR, "%s (Python environment %s, package root %s)", text,
                  cfg.executable, cfg.root);
    }
    p_PyGILState_Release(gil);
    pthread_mutex_unlock(&py_lock);
    if (!pi->py) goto fail;
    plant_log(pi, PLANT_OK, "instantiated with the Python of %s", cfg.executable);
    return pi;
fail:
    free(pi->name);
    free(pi);
    return NULL;
}

static void free_strings(PlantInstance *pi) {
    size_t i;
    for (i = 0; i < pi->nstrings; i++) free(pi->strings[i]);
    free(pi->strings);
    pi->strings = NULL;
    pi->nstrings = 0;
}

void plant_free(PlantInstance *pi) {
    if (!pi) return;
    if (pi->py) {
        PyGILState_STATE gil;
        plant_call(pi, "free", "");
        gil = p_PyGILState_Ensure();
        p_Py_DecRef((PyObject *)pi->py);
        p_PyGILState_Release(gil);
    }
    free_strings(pi);
    free(pi->name);
    free(pi);
}

int plant_get(PlantInstance *pi, const char *kind, const unsigned int *vr, size_t nvr,
              void *values, size_t nvalues) {
    if (nvr == 0) return PLANT_OK;
    if (!vr || !values) {
        plant_log(pi, PLANT_ERROR, "get%s: NULL value references or values", kind);
        return PLANT_ERROR;
    }
    return plant_call(pi, "get", "sKnKn", kind, (unsigned long long)(size_t)vr,
                      (Py_ssize_t)nvr, (unsigned long long)(size_t)values, (Py_ssize_t)nvalues);
}

int plant_set(PlantInstance *pi, const char *kind, const unsigned int *vr, size_t nvr,
              const void *values, size_t nvalues) {
    if (nvr == 0) return PLANT_OK;
    if (!vr || !values) {
        plant_log(pi, PLANT_ERROR, "set%s: NULL value references or values", kind);
        return PLANT_ERROR;
    }
    return plant_call(pi, "set", "sKnKn", kind, (unsigned long long)(size_t)vr,
                      (Py_ssize_t)nvr, (unsigned long long)(size_t)values, (Py_ssize_t)nvalues);
}

int plant_get_strings(PlantInstance *pi, const unsigned int *vr, size_t nvr, const char **values) {
    size_t i;
    int status = PLANT_OK;
    PyGILState_STATE gil;
    if (nvr == 0) return PLANT_OK;
    if (!vr || !values || !pi || !pi->py) return PLANT_ERROR;
    free_strings(pi);
    pi->strings = calloc(nvr, sizeof *pi->strings);
    if (!pi->strings) return PLANT_ERROR;
    pi->nstrings = nvr;
    gil = p_PyGILState_Ensure();
    for (i = 0; i < nvr; i++) {
        PyObject *s = call_v((PyObject *)pi->py, "get_string", "I", vr[i]);
        const char *text = s ? p_PyUnicode_AsUTF8(s) : NULL;
        pi->strings[i] = strdup(text ? text : "");
        values[i] = pi->strings[i];
        if (s) p_Py_DecRef(s);
        else { p_PyErr_Clear(); status = PLANT_ERROR; }
    }
    p_PyGILState_Release(gil);
    return status;
}

int plant_set_strings(PlantInstance *pi, const unsigned int *vr, size_t nvr,
                      const char *const *values) {
    size_t i;
    int status = PLANT_OK, s;
    if (nvr == 0) return PLANT_OK;
    if (!vr || !values) return PLANT_ERROR;
    for (i = 0; i < nvr; i++) {
        const char *v = values[i] ? values[i] : "";
        s = plant_call(pi, "set_string", "Iy", vr[i], v);
        if (s > status) status = s;
    }
    return status;
}
