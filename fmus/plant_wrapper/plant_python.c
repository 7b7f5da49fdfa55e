/* The plant FMU's bridge to Python (see plant_python.h). */
#define _GNU_SOURCE
#define Py_LIMITED_API 0x030A0000
#include <Python.h>

#include <errno.h>

#include <dlfcn.h>
#include <pthread.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "plant_python.h"

/* ------------------------------------------------- the C-API, looked up at run time
 * Only the limited C API of Python 3.10 (its stable ABI): one binary for Python >= 3.10. */
#define PY_FUNCTIONS(X)                                                                 \
    X(Py_IsInitialized) X(Py_GetVersion) X(Py_InitializeEx) X(PyEval_SaveThread)        \
    X(PyGILState_Ensure) X(PyGILState_Release) X(Py_CompileString) X(PyEval_EvalCode)   \
    X(PyEval_GetBuiltins) X(PyDict_New) X(PyDict_SetItemString) X(PyDict_GetItemString) \
    X(PyUnicode_FromString) X(PyObject_GetAttrString)                                   \
    X(PyObject_CallObject) X(Py_VaBuildValue) X(Py_DecRef) X(PyLong_AsLong)             \
    X(PyErr_Fetch) X(PyErr_Clear) X(PyObject_Str) X(PyUnicode_AsUTF8AndSize)              \
    X(PyImport_AddModule) X(PyModule_GetDict) X(Py_IncRef)

#define DECLARE(f) static __typeof__(&f) p_##f;
PY_FUNCTIONS(DECLARE)

/* deprecated since 3.11/3.12 and outside the limited API, used when the library has them:
 * where the embedded interpreter's standard library is, its sys.executable, and no site
 * import (a .pth file of the environment may do anything at startup: one re-executes the
 * interpreter, which would replace the host's process). Declared here, not taken from
 * Python.h, which hides them from the limited API. */
typedef void (*SetWideFn)(const wchar_t *);
typedef wchar_t *(*DecodeLocaleFn)(const char *, size_t *);

static pthread_mutex_t py_lock = PTHREAD_MUTEX_INITIALIZER;
static int py_ready = 0;
static char *py_query = NULL;           /* what the chosen Python said about itself */
static char py_where[4400];             /* which Python runs the FMU, and why that one */

static const char *utf8(PyObject *s) {
    return s ? p_PyUnicode_AsUTF8AndSize(s, NULL) : NULL;
}

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

static int read_config(PlantInstance *pi, const char *resources, PlantConfig *cfg) {
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
        if (strcmp(line, "python") == 0) snprintf(cfg->python, sizeof cfg->python, "%s", eq + 1);
    }
    fclose(f);
    return 0;
}

static int resolve(PlantInstance *pi, void *lib, const char *from) {
#define RESOLVE(f)                                                                        \
    if (!(p_##f = (__typeof__(&f))dlsym(lib, #f))) {                                      \
        plant_log(pi, PLANT_ERROR, "%s has no %s: not Python >= 3.10?", from, #f);        \
        return -1;                                                                        \
    }
    PY_FUNCTIONS(RESOLVE)
#undef RESOLVE
    return 0;
}

/* Python >= 3.10 from its version string */
static int recent_enough(const char *version) {
    int major = 0, minor = 0;
    return sscanf(version, "%d.%d", &major, &minor) == 2 && (major > 3 || (major == 3 && minor >= 10));
}

/* Find the C-API (the host's Python, or the chosen Python's libpython loaded here) and
 * initialise Python once. */
static int load_python(PlantInstance *pi, const PlantConfig *cfg, const char *resources) {
    char exe[4096], why[128], libpython[4096], home[4096], version[64], errors[8192];
    int (*initialized)(void) = (int (*)(void))dlsym(RTLD_DEFAULT, "Py_IsInitialized");
    int exit_status = 0;
    void *lib;
    if (initialized && initialized()) {         /* a Python host (fmpy, libcosimpy, ecospy) */
        if (resolve(pi, RTLD_DEFAULT, "the host's Python") != 0) return -1;
        snprintf(version, sizeof version, "%s", p_Py_GetVersion());
        version[strcspn(version, " ")] = '\0';
        if (!recent_enough(version)) {
            plant_log(pi, PLANT_ERROR, "the host runs Python %s; the plant FMU needs "
                      "Python >= 3.10 with diffbot-cosim installed", version);
            return -1;
        }
        snprintf(py_where, sizeof py_where, "the host's own Python %s", version);
        return 0;
    }
    if (plant_choose_python(cfg, exe, sizeof exe, why, sizeof why) != 0) {
        plant_log(pi, PLANT_ERROR, "no Python to run the plant FMU: set " PLANT_PYTHON_ENV " to a "
                  "python with diffbot-cosim installed, activate its virtual environment, or "
                  "put python3 on PATH");
        return -1;
    }
    if (access(exe, X_OK) != 0) {
        plant_log(pi, PLANT_ERROR, "the Python chosen to run the plant FMU (%s: %s) is "
                  "missing or not executable", why, exe);
        return -1;
    }
    free(py_query);
    py_query = plant_run_query(exe, resources, &exit_status);
    if (!py_query) {
        plant_log(pi, PLANT_ERROR, "cannot run %s (%s): %s", exe, why, strerror(errno));
        return -1;
    }
    plant_query_value(py_query, "version", version, sizeof version);
    plant_query_value(py_query, "libpython", libpython, sizeof libpython);
    plant_query_value(py_query, "home", home, sizeof home);
    plant_query_errors(py_query, errors, sizeof errors);
    if (!version[0] && !errors[0])
        snprintf(errors, sizeof errors, "it did not say what it is (exit status %d): %.2000s",
                 exit_status, py_query);
    snprintf(py_where, sizeof py_where, "the Python %s of %s (%s)", version, exe, why);
    if (errors[0]) {
        plant_log(pi, PLANT_ERROR, "%s cannot run the plant FMU: %s (mend that Python, or "
                  "name one that has what is missing in $" PLANT_PYTHON_ENV ")", py_where, errors);
        return -1;
    }
    lib = dlopen(libpython, RTLD_NOW | RTLD_GLOBAL);
    if (!lib) {
        plant_log(pi, PLANT_ERROR, "cannot load the Python library of %s (%s): %s", py_where,
                  libpython, dlerror());
        return -1;
    }
    if (resolve(pi, lib, libpython) != 0) return -1;
    if (!p_Py_IsInitialized()) {
        int *no_site = (int *)dlsym(lib, "Py_NoSiteFlag");
        SetWideFn set_name = (SetWideFn)dlsym(lib, "Py_SetProgramName");
        SetWideFn set_home = (SetWideFn)dlsym(lib, "Py_SetPythonHome");
        DecodeLocaleFn decode = (DecodeLocaleFn)dlsym(lib, "Py_DecodeLocale");
        if (no_site) *no_site = 1;
        /* the strings stay allocated: Python keeps pointers to them */
        if (set_name && decode) set_name(decode(exe, NULL));
        if (set_home && decode && home[0]) set_home(decode(home, NULL));
        p_Py_InitializeEx(0);               /* 0: the host's signals stay the host's */
        if (!p_Py_IsInitialized()) {
            plant_log(pi, PLANT_ERROR, "cannot start %s", py_where);
            return -1;
        }
        p_PyEval_SaveThread();              /* the GIL is taken per call from now on */
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
        const char *text = utf8(s);
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
    const char *text = utf8(m);
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

/* The guest through which every instance is made (NULL with the reason logged): the
 * process's one, kept in the private module GUEST_MODULE (this library may be unloaded and
 * loaded again between instances: its static variables do not last), else made by
 * resources/plant_guest.py's load(), that file run as that module's code, in a namespace of
 * its own. The caller holds the GIL. */
#define GUEST_MODULE "_diffbot_plant_guest"
static PyObject *load_guest(PlantInstance *pi, const char *resources) {
    char path[4200], text[4096];
    FILE *f;
    long size;
    char *source;
    PyObject *module, *globals, *code = NULL, *done = NULL, *load, *guest = NULL;
    module = p_PyImport_AddModule(GUEST_MODULE);                     /* borrowed */
    globals = module ? p_PyModule_GetDict(module) : NULL;           /* borrowed */
    guest = globals ? p_PyDict_GetItemString(globals, "guest") : NULL;
    if (guest) {
        p_Py_IncRef(guest);
        return guest;
    }
    if (!globals) {
        exception_text(text, sizeof text);
        plant_log(pi, PLANT_ERROR, "%s: %s", py_where, text);
        return NULL;
    }
    snprintf(path, sizeof path, "%s/plant_guest.py", resources);
    f = fopen(path, "rb");
    if (!f) {
        plant_log(pi, PLANT_ERROR, "cannot read %s: the FMU's resources are incomplete", path);
        return NULL;
    }
    fseek(f, 0, SEEK_END);
    size = ftell(f);
    rewind(f);
    source = size >= 0 ? malloc((size_t)size + 1) : NULL;
    if (source && fread(source, 1, (size_t)size, f) == (size_t)size) source[size] = '\0';
    else { free(source); source = NULL; }
    fclose(f);
    if (!source) {
        plant_log(pi, PLANT_ERROR, "cannot read %s", path);
        return NULL;
    }
    code = p_Py_CompileString(source, path, Py_file_input);
    free(source);
    if (code && !p_PyDict_GetItemString(globals, "__builtins__"))
        p_PyDict_SetItemString(globals, "__builtins__", p_PyEval_GetBuiltins());
    done = code ? p_PyEval_EvalCode(code, globals, globals) : NULL;
    load = done ? p_PyDict_GetItemString(globals, "load") : NULL;     /* borrowed */
    if (load) guest = call_v(load, "__call__", "ss", resources, py_query ? py_query : "");
    if (guest) p_PyDict_SetItemString(globals, "guest", guest);
    else {
        exception_text(text, sizeof text);
        plant_log(pi, PLANT_ERROR, "%s: %s", py_where, text);
    }
    if (done) p_Py_DecRef(done);
    if (code) p_Py_DecRef(code);
    return guest;
}

PlantInstance *plant_instantiate(const PlantInstance *proto, const char *resources,
                                 const char *token) {
    PlantConfig cfg;
    PlantInstance *pi = calloc(1, sizeof *pi);
    PyObject *guest;
    PyGILState_STATE gil;
    char text[4096];
    if (!pi) return NULL;
    *pi = *proto;
    pi->name = strdup(proto->name ? proto->name : "plant");
    pi->py = NULL;
    pi->strings = NULL;
    pi->nstrings = 0;
    if (!resources) {
        plant_log(pi, PLANT_ERROR, "no resource location: the FMU needs its resources/ folder");
        goto fail;
    }
    if (read_config(pi, resources, &cfg) != 0) goto fail;
    pthread_mutex_lock(&py_lock);
    if (!py_ready && load_python(pi, &cfg, resources) != 0) {
        pthread_mutex_unlock(&py_lock);
        goto fail;
    }
    py_ready = 1;
    gil = p_PyGILState_Ensure();
    guest = load_guest(pi, resources);
    if (guest) {
        pi->py = call_v(guest, "instantiate", "isss", pi->fmi, resources, pi->name,
                        token ? token : "");
        p_Py_DecRef(guest);
        if (!pi->py) {
            exception_text(text, sizeof text);
            plant_log(pi, PLANT_ERROR, "%s (in %s)", text, py_where);
        }
    }
    p_PyGILState_Release(gil);
    pthread_mutex_unlock(&py_lock);
    if (!pi->py) goto fail;
    plant_log(pi, PLANT_OK, "instantiated in %s", py_where);
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
        const char *text = utf8(s);
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
