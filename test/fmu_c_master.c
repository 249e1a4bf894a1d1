/*
 * Copyright 2026 valve_sim developers
 *
 * Licensed under the Apache License, Version 2.0 (the "License");
 * you may not use this file except in compliance with the License.
 * You may obtain a copy of the License at
 *
 *     http://www.apache.org/licenses/LICENSE-2.0
 *
 * Unless required by applicable law or agreed to in writing, software
 * distributed under the License is distributed on an "AS IS" BASIS,
 * WITHOUT WARRANTIES OR CONDITIONS OF ANY KIND, either express or implied.
 * See the License for the specific language governing permissions and
 * limitations under the License.
 *
 * A minimal FMI 2.0 co-simulation master in C, as OpenModelica, Hopsan and fmi_adapter
 * load an FMU: dlopen the binary, instantiate, step, terminate, free, dlclose; then exit
 * normally (the exit status tells whether the FMU lets its master end cleanly).
 * test_fmu.py compiles and runs it.
 *
 *   fmu_c_master BINARY RESOURCE_URI GUID VR_INLET VR_OUT Q0 Q1 STEP_TIME END_TIME DT
 *                [refuse|failstart]
 *
 * Runs the inlet-flow step Q0 -> Q1 [m^3/s] at STEP_TIME [s] to END_TIME at the
 * communication step DT [s]; prints "time value" of the output VR_OUT after each step
 * (%.17g) and exits 1 at the first status that is not fmi2OK. With "refuse", it first
 * asks for three steps the FMU must refuse with fmi2Discard (an infinite step, a NaN
 * time, a step of 1e6 s; exit 3 otherwise), then runs as above. With "failstart" (Q0 nan),
 * fmi2ExitInitializationMode must return fmi2Error (exit 4 otherwise), then it terminates,
 * frees, unloads and exits 0. The logger prints the category and aborts on a NULL one.
 * On Linux the binary needs libpython loaded first (LD_PRELOAD) and the environment
 * docs/fmu.md gives (valve_sim.fmu.environment).
 */
#include <dlfcn.h>
#include <stdarg.h>
#include <stdio.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "fmi2Functions.h"

static void logger(fmi2ComponentEnvironment env, fmi2String instance, fmi2Status status,
                   fmi2String category, fmi2String message, ...)
{
    va_list args;
    (void)env;
    if (!category) {
        fprintf(stderr, "NULL category from %s\n", instance);
        abort();
    }
    fprintf(stderr, "[%s status %d %s] ", instance, (int)status, category);
    va_start(args, message);
    vfprintf(stderr, message, args);
    va_end(args);
    fputc('\n', stderr);
}

#define LOAD(name) \
    name##TYPE *name = (name##TYPE *)dlsym(library, #name); \
    if (!name) { fprintf(stderr, "no %s\n", #name); return 2; }

int main(int argc, char **argv)
{
    if (argc != 11 && argc != 12) {
        fprintf(stderr, "usage: see the comment of fmu_c_master.c\n");
        return 2;
    }
    void *library = dlopen(argv[1], RTLD_NOW | RTLD_LOCAL);
    if (!library) {
        fprintf(stderr, "dlopen: %s\n", dlerror());
        return 2;
    }
    LOAD(fmi2Instantiate) LOAD(fmi2SetupExperiment) LOAD(fmi2EnterInitializationMode)
    LOAD(fmi2ExitInitializationMode) LOAD(fmi2SetReal) LOAD(fmi2GetReal) LOAD(fmi2DoStep)
    LOAD(fmi2Terminate) LOAD(fmi2FreeInstance)
    int refuse = argc == 12 && strcmp(argv[11], "refuse") == 0;
    int failstart = argc == 12 && strcmp(argv[11], "failstart") == 0;
    fmi2ValueReference inlet = (fmi2ValueReference)atoi(argv[4]);
    fmi2ValueReference out = (fmi2ValueReference)atoi(argv[5]);
    double q0 = atof(argv[6]), q1 = atof(argv[7]), step_time = atof(argv[8]);
    double end_time = atof(argv[9]), dt = atof(argv[10]);
    fmi2CallbackFunctions callbacks = {logger, calloc, free, NULL, NULL};
    fmi2Component c = fmi2Instantiate("c_master", fmi2CoSimulation, argv[3], argv[2],
                                      &callbacks, fmi2False, fmi2True);
    if (!c) {
        fprintf(stderr, "fmi2Instantiate failed\n");
        return 1;
    }
    if (fmi2SetupExperiment(c, fmi2False, 0.0, 0.0, fmi2False, 0.0) != fmi2OK
        || fmi2EnterInitializationMode(c) != fmi2OK
        || fmi2SetReal(c, &inlet, 1, &q0) != fmi2OK) {
        fprintf(stderr, "initialisation failed\n");
        return 1;
    }
    fmi2Status started = fmi2ExitInitializationMode(c);
    fprintf(stderr, "fmi2ExitInitializationMode: status %d\n", (int)started);
    if (failstart) {
        fmi2Status terminated = fmi2Terminate(c);
        fmi2FreeInstance(c);
        int closed = dlclose(library);
        fprintf(stderr, "fmi2Terminate: status %d; fmi2FreeInstance returned; dlclose %d\n",
                (int)terminated, closed);
        return started == fmi2Error && terminated == fmi2OK && closed == 0 ? 0 : 4;
    }
    if (started != fmi2OK) return 1;
    double bad[3][2] = {{0.0, INFINITY}, {NAN, dt}, {0.0, 1e6}};  /* (time, step) */
    for (int i = 0; refuse && i < 3; ++i) {
        fmi2Status status = fmi2DoStep(c, bad[i][0], bad[i][1], fmi2True);
        fprintf(stderr, "refused step %d: status %d\n", i, (int)status);
        if (status != fmi2Discard) return 3;
    }
    long steps = lround(end_time / dt);
    for (long k = 0; k < steps; ++k) {
        double t = k * dt, value;
        double flow = t + 0.5 * dt >= step_time ? q1 : q0;
        if (fmi2SetReal(c, &inlet, 1, &flow) != fmi2OK
            || fmi2DoStep(c, t, dt, fmi2True) != fmi2OK
            || fmi2GetReal(c, &out, 1, &value) != fmi2OK) {
            fprintf(stderr, "step %ld failed\n", k);
            return 1;
        }
        printf("%.17g %.17g\n", (k + 1) * dt, value);
    }
    fmi2Status terminated = fmi2Terminate(c);
    fmi2FreeInstance(c);
    int closed = dlclose(library);
    fflush(stdout);
    fprintf(stderr, "fmi2Terminate: status %d; fmi2FreeInstance returned; dlclose %d\n",
            (int)terminated, closed);
    return terminated == fmi2OK && closed == 0 ? 0 : 1;
}
