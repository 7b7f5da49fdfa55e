/* Which Python runs the plant FMU in a host without one, and what that Python says about
 * itself (see plant_python.h). */
#define _GNU_SOURCE
#include <errno.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/wait.h>
#include <unistd.h>

#include "plant_python.h"

/* The Python to run the FMU in a host without one (docs/fmu.md): $DIFFBOT_FMU_PYTHON, else
 * the interpreter a bound export names, else the active virtual environment's python, else
 * python3 on PATH. 0 and exe, why filled; -1 if there is none. */
int plant_choose_python(const PlantConfig *cfg, char *exe, size_t n, char *why, size_t nwhy) {
    const char *v = getenv(PLANT_PYTHON_ENV), *path;
    if (v && *v) {
        snprintf(exe, n, "%s", v);
        snprintf(why, nwhy, "named by $" PLANT_PYTHON_ENV);
        return 0;
    }
    if (cfg->python[0]) {
        snprintf(exe, n, "%s", cfg->python);
        snprintf(why, nwhy, "the environment this FMU was exported bound to");
        return 0;
    }
    v = getenv("VIRTUAL_ENV");
    if (v && *v) {
        snprintf(exe, n, "%s/bin/python", v);
        snprintf(why, nwhy, "the active virtual environment ($VIRTUAL_ENV)");
        return 0;
    }
    for (path = getenv("PATH"); path && *path;) {
        size_t len = strcspn(path, ":");
        snprintf(exe, n, "%.*s/python3", (int)len, len ? path : ".");
        if (access(exe, X_OK) == 0) {
            snprintf(why, nwhy, "python3 on PATH");
            return 0;
        }
        path += len + (path[len] == ':');
    }
    return -1;
}

/* Run `exe resources/plant_guest.py resources` and return what it printed (stdout and
 * stderr, malloc'ed; NULL if it could not be started). */
char *plant_run_query(const char *exe, const char *resources, int *exit_status) {
    char script[4200];
    int fd[2], status = -1;
    pid_t pid;
    size_t size = 0, cap = 8192;
    ssize_t got;
    char *out = malloc(cap);
    if (!out || pipe(fd) != 0) { free(out); return NULL; }
    snprintf(script, sizeof script, "%s/plant_guest.py", resources);
    pid = fork();
    if (pid < 0) { close(fd[0]); close(fd[1]); free(out); return NULL; }
    if (pid == 0) {
        char *argv[] = {(char *)exe, script, (char *)resources, NULL};
        dup2(fd[1], 1);
        dup2(fd[1], 2);
        close(fd[0]);
        close(fd[1]);
        execv(exe, argv);
        _exit(127);                   /* (only async-signal-safe calls after fork) */
    }
    close(fd[1]);
    while ((got = read(fd[0], out + size, cap - size - 1)) != 0) {
        if (got < 0) { if (errno == EINTR) continue; break; }
        size += (size_t)got;
        if (cap - size < 1024) {
            char *more = realloc(out, cap * 2);
            if (!more) break;
            out = more;
            cap *= 2;
        }
    }
    out[size] = '\0';
    close(fd[0]);
    while (waitpid(pid, &status, 0) < 0 && errno == EINTR) {}
    *exit_status = WIFEXITED(status) ? WEXITSTATUS(status) : -1;
    return out;
}

/* the value of the first "key=" line of text, "" if none */
void plant_query_value(const char *text, const char *key, char *out, size_t n) {
    size_t k = strlen(key);
    const char *p = text;
    out[0] = '\0';
    while (p && *p) {
        if (strncmp(p, key, k) == 0 && p[k] == '=') {
            size_t len = strcspn(p + k + 1, "\n");
            snprintf(out, n, "%.*s", (int)len, p + k + 1);
            return;
        }
        p = strchr(p, '\n');
        if (p) p++;
    }
}

/* the "error=" lines of text joined with "; " (empty if none) */
void plant_query_errors(const char *text, char *out, size_t n) {
    const char *p = text;
    size_t used = 0;
    out[0] = '\0';
    while (p && *p && used + 1 < n) {
        if (strncmp(p, "error=", 6) == 0) {
            size_t len = strcspn(p + 6, "\n");
            used += (size_t)snprintf(out + used, n - used, "%s%.*s", used ? "; " : "",
                                     (int)len, p + 6);
        }
        p = strchr(p, '\n');
        if (p) p++;
    }
}

