/* FMI 2.0 Co-Simulation functions shared by every lpvflow plant (see plant_fmu.h).
 *
 * Integration: classical fourth-order Runge-Kutta with n = ceil(h / solver_max_step)
 * equal sub-steps per communication step h; inputs are held constant over the step.
 * Effects (each off at its default value 0), applied at communication points:
 *   dead time   u_used(k) = u(k - d), d = round(effect_input_delay / h); before the first
 *               d steps the inputs present at initialisation are used; h must then stay constant
 *   dead zone   dz(u) = u - w sign(u) for |u| > w, else 0, with w = effect_deadzone
 *   saturation  sat(u) = min(max(u, -s), s) when s = effect_saturation > 0
 *   sensor      y_meas = y + effect_sensor_offset + effect_noise_std * e, e ~ N(0, 1) white,
 *               drawn from xoshiro256** seeded by splitmix64(effect_noise_seed)
 * Dead time, dead zone and saturation act on the actuator inputs only (in that order).
 */
#include <math.h>
#include <stdarg.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "plant_fmu.h"

#define MAX_DELAY_STEPS 1000000
#define MAX_INPUTS 16

typedef struct {
    fmi2CallbackFunctions cb;
    char *name;
    double *r;
    int *iv;
    double *x, *xs, *k1, *k2, *k3, *k4;
    double *u_init, *u_used; /* raw inputs at initialisation; inputs after the effects */
    double *delay_buf;
    long delay_steps, step_index;
    double h0;
    int initialized, started;
    uint64_t rng[4];
    int vr_delay, vr_deadzone, vr_saturation, vr_offset, vr_noise, vr_max_step, ivr_seed;
} Instance;

/* ---------------------------------------------------------------- logging */

static fmi2Status fail(Instance *in, const char *fmt, ...) {
    char buf[512];
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(buf, sizeof buf, fmt, ap);
    va_end(ap);
    for (char *p = buf; *p; ++p) {
        if (*p == '%') *p = ' '; /* the message is used as a printf format by importers */
    }
    if (in->cb.logger) in->cb.logger(in->cb.componentEnvironment, in->name, fmi2Error, "logStatusError", buf);
    return fmi2Error;
}

/* ------------------------------------------------------------ random noise */

static uint64_t splitmix64(uint64_t *s) {
    uint64_t z = (*s += 0x9E3779B97F4A7C15ULL);
    z = (z ^ (z >> 30)) * 0xBF58476D1CE4E5B9ULL;
    z = (z ^ (z >> 27)) * 0x94D049BB133111EBULL;
    return z ^ (z >> 31);
}

static uint64_t rotl(uint64_t v, int k) { return (v << k) | (v >> (64 - k)); }

static uint64_t xoshiro256ss(uint64_t *s) {
    const uint64_t result = rotl(s[1] * 5, 7) * 9;
    const uint64_t t = s[1] << 17;
    s[2] ^= s[0];
    s[3] ^= s[1];
    s[1] ^= s[2];
    s[0] ^= s[3];
    s[2] ^= t;
    s[3] = rotl(s[3], 45);
    return result;
}

static double uniform_open(uint64_t *s) { /* in (0, 1) */
    return ((double)(xoshiro256ss(s) >> 11) + 0.5) * (1.0 / 9007199254740992.0);
}

static double gaussian(uint64_t *s) { /* Box-Muller, one value per call */
    const double u1 = uniform_open(s), u2 = uniform_open(s);
    return sqrt(-2.0 * log(u1)) * cos(6.283185307179586 * u2);
}

static void seed_rng(Instance *in) {
    uint64_t s = (uint64_t)(int64_t)in->iv[in->ivr_seed];
    for (int i = 0; i < 4; ++i) in->rng[i] = splitmix64(&s);
}

/* ------------------------------------------------------------------ model */

static double dead_zone(double u, double w) {
    if (w <= 0.0) return u;
    if (u > w) return u - w;
    if (u < -w) return u + w;
    return 0.0;
}

static double saturate(double u, double s) {
    if (s <= 0.0) return u;
    return u > s ? s : (u < -s ? -s : u);
}

static void shape_inputs(Instance *in, const double *raw, const double *current, double *used) {
    for (int i = 0; i < PLANT.n_inputs; ++i) {
        if (PLANT.input_is_actuator[i]) {
            used[i] = saturate(dead_zone(raw[i], in->r[in->vr_deadzone]), in->r[in->vr_saturation]);
        } else {
            used[i] = current[i];
        }
    }
}

static void read_inputs(const Instance *in, double *u) {
    for (int i = 0; i < PLANT.n_inputs; ++i) u[i] = in->r[PLANT.input_vr[i]];
}

static void compute_outputs(Instance *in) {
    const int n = PLANT.n_states;
    PLANT.outputs(in->r, in->u_used, in->x);
    PLANT.derivatives(in->r, in->u_used, in->x, in->k1);
    for (int i = 0; i < n; ++i) {
        in->r[PLANT.state_vr[i]] = in->x[i];
        in->r[PLANT.der_vr[i]] = in->k1[i];
    }
    for (int i = 0; i < PLANT.n_inputs; ++i) in->r[PLANT.applied_vr[i]] = in->u_used[i];
    const double offset = in->r[in->vr_offset], std = in->r[in->vr_noise];
    for (int j = 0; j < PLANT.n_measured; ++j) {
        double y = in->r[PLANT.measured_vr[j]] + offset;
        if (std > 0.0) y += std * gaussian(in->rng);
        in->r[PLANT.measured_vr[j]] = y;
    }
}

static void rk4_step(Instance *in, double h) {
    const int n = PLANT.n_states;
    const double *u = in->u_used;
    double *x = in->x, *xs = in->xs;
    PLANT.derivatives(in->r, u, x, in->k1);
    for (int i = 0; i < n; ++i) xs[i] = x[i] + 0.5 * h * in->k1[i];
    PLANT.derivatives(in->r, u, xs, in->k2);
    for (int i = 0; i < n; ++i) xs[i] = x[i] + 0.5 * h * in->k2[i];
    PLANT.derivatives(in->r, u, xs, in->k3);
    for (int i = 0; i < n; ++i) xs[i] = x[i] + h * in->k3[i];
    PLANT.derivatives(in->r, u, xs, in->k4);
    for (int i = 0; i < n; ++i) x[i] += h / 6.0 * (in->k1[i] + 2.0 * in->k2[i] + 2.0 * in->k3[i] + in->k4[i]);
    if (PLANT.constrain) PLANT.constrain(in->r, x);
}

/* --------------------------------------------------------------- instance */

static int find_real(const char *name) {
    for (int i = 0; i < PLANT.n_real; ++i)
        if (strcmp(PLANT.real_name[i], name) == 0) return i;
    return -1;
}

static int find_int(const char *name) {
    for (int i = 0; i < PLANT.n_int; ++i)
        if (strcmp(PLANT.int_name[i], name) == 0) return i;
    return -1;
}

static void load_start_values(Instance *in) {
    memcpy(in->r, PLANT.real_start, sizeof(double) * (size_t)PLANT.n_real);
    memcpy(in->iv, PLANT.int_start, sizeof(int) * (size_t)PLANT.n_int);
    free(in->delay_buf);
    in->delay_buf = NULL;
    in->initialized = in->started = 0;
    in->step_index = 0;
}

static void free_instance(Instance *in) {
    if (!in) return;
    free(in->name);
    free(in->r);
    free(in->iv);
    free(in->x);
    free(in->u_init);
    free(in->delay_buf);
    free(in);
}

const char *fmi2GetTypesPlatform(void) { return fmi2TypesPlatform; }
const char *fmi2GetVersion(void) { return fmi2Version; }

fmi2Status fmi2SetDebugLogging(fmi2Component c, fmi2Boolean on, size_t n, const fmi2String cat[]) {
    (void)c; (void)on; (void)n; (void)cat;
    return fmi2OK;
}

fmi2Component fmi2Instantiate(fmi2String instanceName, fmi2Type fmuType, fmi2String guid,
                              fmi2String location, const fmi2CallbackFunctions *functions,
                              fmi2Boolean visible, fmi2Boolean loggingOn) {
    (void)location; (void)visible; (void)loggingOn;
    Instance *in = calloc(1, sizeof(Instance));
    if (!in) return NULL;
    if (functions) in->cb = *functions;
    const char *name = instanceName ? instanceName : "plant";
    in->name = malloc(strlen(name) + 1);
    const int n = PLANT.n_states, m = PLANT.n_inputs;
    in->r = calloc((size_t)PLANT.n_real, sizeof(double));
    in->iv = calloc((size_t)PLANT.n_int, sizeof(int));
    in->x = calloc((size_t)(6 * n), sizeof(double));
    in->u_init = calloc((size_t)(2 * m), sizeof(double));
    if (m > MAX_INPUTS || !in->name || !in->r || !in->iv || !in->x || !in->u_init) {
        free_instance(in);
        return NULL;
    }
    strcpy(in->name, name);
    in->xs = in->x + n; in->k1 = in->x + 2 * n; in->k2 = in->x + 3 * n;
    in->k3 = in->x + 4 * n; in->k4 = in->x + 5 * n;
    in->u_used = in->u_init + m;
    if (fmuType != fmi2CoSimulation) {
        fail(in, "this FMU supports Co-Simulation only");
        free_instance(in);
        return NULL;
    }
    if (!guid || strcmp(guid, PLANT.guid) != 0) {
        fail(in, "GUID mismatch: expected %s", PLANT.guid);
        free_instance(in);
        return NULL;
    }
    in->vr_delay = find_real("effect_input_delay");
    in->vr_deadzone = find_real("effect_deadzone");
    in->vr_saturation = find_real("effect_saturation");
    in->vr_offset = find_real("effect_sensor_offset");
    in->vr_noise = find_real("effect_noise_std");
    in->vr_max_step = find_real("solver_max_step");
    in->ivr_seed = find_int("effect_noise_seed");
    if (in->vr_delay < 0 || in->vr_deadzone < 0 || in->vr_saturation < 0 || in->vr_offset < 0 ||
        in->vr_noise < 0 || in->vr_max_step < 0 || in->ivr_seed < 0) {
        fail(in, "modelDescription lacks an effect parameter or solver_max_step");
        free_instance(in);
        return NULL;
    }
    load_start_values(in);
    return in;
}

void fmi2FreeInstance(fmi2Component c) { free_instance((Instance *)c); }

fmi2Status fmi2SetupExperiment(fmi2Component c, fmi2Boolean tolDef, fmi2Real tol, fmi2Real start,
                               fmi2Boolean stopDef, fmi2Real stop) {
    (void)c; (void)tolDef; (void)tol; (void)start; (void)stopDef; (void)stop;
    return fmi2OK;
}

fmi2Status fmi2EnterInitializationMode(fmi2Component c) { (void)c; return fmi2OK; }

fmi2Status fmi2ExitInitializationMode(fmi2Component c) {
    Instance *in = (Instance *)c;
    for (int i = 0; i < PLANT.n_states; ++i) in->x[i] = in->r[PLANT.x0_vr[i]];
    if (PLANT.constrain) PLANT.constrain(in->r, in->x);
    read_inputs(in, in->u_init);
    shape_inputs(in, in->u_init, in->u_init, in->u_used);
    seed_rng(in);
    in->initialized = 1;
    compute_outputs(in);
    return fmi2OK;
}

fmi2Status fmi2Terminate(fmi2Component c) { (void)c; return fmi2OK; }

fmi2Status fmi2Reset(fmi2Component c) {
    load_start_values((Instance *)c);
    return fmi2OK;
}

/* ------------------------------------------------------------ get and set */

fmi2Status fmi2GetReal(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, fmi2Real value[]) {
    Instance *in = (Instance *)c;
    for (size_t i = 0; i < nvr; ++i) {
        if (vr[i] >= (fmi2ValueReference)PLANT.n_real) return fail(in, "unknown Real value reference %u", vr[i]);
        value[i] = in->r[vr[i]];
    }
    return fmi2OK;
}

fmi2Status fmi2GetInteger(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, fmi2Integer value[]) {
    Instance *in = (Instance *)c;
    for (size_t i = 0; i < nvr; ++i) {
        if (vr[i] >= (fmi2ValueReference)PLANT.n_int) return fail(in, "unknown Integer value reference %u", vr[i]);
        value[i] = in->iv[vr[i]];
    }
    return fmi2OK;
}

fmi2Status fmi2SetReal(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, const fmi2Real value[]) {
    Instance *in = (Instance *)c;
    for (size_t i = 0; i < nvr; ++i) {
        const fmi2ValueReference k = vr[i];
        if (k >= (fmi2ValueReference)PLANT.n_real) return fail(in, "unknown Real value reference %u", k);
        const char *name = PLANT.real_name[k];
        const double v = value[i];
        switch (PLANT.real_causality[k]) {
        case CAUSALITY_OUTPUT:
            return fail(in, "%s is an output and cannot be set", name);
        case CAUSALITY_INPUT:
            if (!isfinite(v)) return fail(in, "input %s = %g is not finite; give a finite value", name, v);
            break;
        default:
            if (in->initialized)
                return fail(in, "parameter %s can only be set before initialization; reset the FMU first", name);
            if (!isfinite(v) || v < PLANT.real_min[k] || v > PLANT.real_max[k])
                return fail(in, "parameter %s = %g is out of range [%g, %g]; give a value inside it", name, v,
                            PLANT.real_min[k], PLANT.real_max[k]);
        }
        in->r[k] = v;
    }
    return fmi2OK;
}

fmi2Status fmi2SetInteger(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, const fmi2Integer value[]) {
    Instance *in = (Instance *)c;
    for (size_t i = 0; i < nvr; ++i) {
        const fmi2ValueReference k = vr[i];
        if (k >= (fmi2ValueReference)PLANT.n_int) return fail(in, "unknown Integer value reference %u", k);
        const char *name = PLANT.int_name[k];
        if (in->initialized)
            return fail(in, "parameter %s can only be set before initialization; reset the FMU first", name);
        if (value[i] < PLANT.int_min[k] || value[i] > PLANT.int_max[k])
            return fail(in, "parameter %s = %d is out of range [%d, %d]; give a value inside it", name, value[i],
                        PLANT.int_min[k], PLANT.int_max[k]);
        in->iv[k] = value[i];
    }
    return fmi2OK;
}

fmi2Status fmi2GetBoolean(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, fmi2Boolean value[]) {
    (void)vr; (void)value;
    return nvr ? fail((Instance *)c, "this FMU has no Boolean variables") : fmi2OK;
}

fmi2Status fmi2GetString(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, fmi2String value[]) {
    (void)vr; (void)value;
    return nvr ? fail((Instance *)c, "this FMU has no String variables") : fmi2OK;
}

fmi2Status fmi2SetBoolean(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, const fmi2Boolean value[]) {
    (void)vr; (void)value;
    return nvr ? fail((Instance *)c, "this FMU has no Boolean variables") : fmi2OK;
}

fmi2Status fmi2SetString(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, const fmi2String value[]) {
    (void)vr; (void)value;
    return nvr ? fail((Instance *)c, "this FMU has no String variables") : fmi2OK;
}

/* ------------------------------------------------------------- stepping */

static fmi2Status start_stepping(Instance *in, double h) {
    const double delay = in->r[in->vr_delay];
    const double steps = floor(delay / h + 0.5);
    if (steps > MAX_DELAY_STEPS)
        return fail(in, "effect_input_delay = %g s is %g communication steps of %g s; at most %d allowed",
                    delay, steps, h, MAX_DELAY_STEPS);
    in->delay_steps = (long)steps;
    const size_t m = (size_t)PLANT.n_inputs, len = (size_t)in->delay_steps + 1;
    in->delay_buf = malloc(sizeof(double) * m * len);
    if (!in->delay_buf) return fail(in, "out of memory for the input delay buffer");
    for (size_t k = 0; k < len; ++k) memcpy(in->delay_buf + k * m, in->u_init, sizeof(double) * m);
    in->h0 = h;
    in->started = 1;
    return fmi2OK;
}

fmi2Status fmi2DoStep(fmi2Component c, fmi2Real t, fmi2Real h, fmi2Boolean noSetPrior) {
    (void)t; (void)noSetPrior;
    Instance *in = (Instance *)c;
    if (!in->initialized) return fail(in, "fmi2DoStep called before fmi2ExitInitializationMode");
    if (!(h > 0.0) || !isfinite(h)) return fail(in, "communication step size %g must be > 0", h);
    if (!in->started) {
        if (start_stepping(in, h) != fmi2OK) return fmi2Error;
    } else if (in->delay_steps > 0 && fabs(h - in->h0) > 1e-9 * in->h0) {
        return fail(in, "effect_input_delay needs a constant communication step (first %g s, now %g s)", in->h0, h);
    }
    const int m = PLANT.n_inputs;
    const long len = in->delay_steps + 1;
    double current[MAX_INPUTS], delayed[MAX_INPUTS];
    read_inputs(in, current);
    memcpy(in->delay_buf + (in->step_index % len) * m, current, sizeof(double) * (size_t)m);
    memcpy(delayed, in->delay_buf + ((in->step_index + 1) % len) * m, sizeof(double) * (size_t)m);
    in->step_index++;
    shape_inputs(in, delayed, current, in->u_used);
    const double max_step = in->r[in->vr_max_step];
    const long n_sub = (long)ceil(h / max_step - 1e-9);
    const double hs = h / (double)(n_sub < 1 ? 1 : n_sub);
    for (long k = 0; k < (n_sub < 1 ? 1 : n_sub); ++k) rk4_step(in, hs);
    for (int i = 0; i < PLANT.n_states; ++i) {
        if (!isfinite(in->x[i])) {
            return fail(in, "%s became non-finite: the simulated plant diverged (an unstable closed loop or inputs "
                        "far outside the operating range; if neither, reduce solver_max_step)",
                        PLANT.real_name[PLANT.state_vr[i]]);
        }
    }
    compute_outputs(in);
    return fmi2OK;
}

fmi2Status fmi2CancelStep(fmi2Component c) { (void)c; return fmi2Error; }

/* -------------------------------------------------- unsupported features */

fmi2Status fmi2GetFMUstate(fmi2Component c, fmi2FMUstate *s) {
    (void)s;
    return fail((Instance *)c, "canGetAndSetFMUstate is false");
}
fmi2Status fmi2SetFMUstate(fmi2Component c, fmi2FMUstate s) {
    (void)s;
    return fail((Instance *)c, "canGetAndSetFMUstate is false");
}
fmi2Status fmi2FreeFMUstate(fmi2Component c, fmi2FMUstate *s) {
    (void)s;
    return fail((Instance *)c, "canGetAndSetFMUstate is false");
}
fmi2Status fmi2SerializedFMUstateSize(fmi2Component c, fmi2FMUstate s, size_t *n) {
    (void)s; (void)n;
    return fail((Instance *)c, "canSerializeFMUstate is false");
}
fmi2Status fmi2SerializeFMUstate(fmi2Component c, fmi2FMUstate s, fmi2Byte b[], size_t n) {
    (void)s; (void)b; (void)n;
    return fail((Instance *)c, "canSerializeFMUstate is false");
}
fmi2Status fmi2DeSerializeFMUstate(fmi2Component c, const fmi2Byte b[], size_t n, fmi2FMUstate *s) {
    (void)b; (void)n; (void)s;
    return fail((Instance *)c, "canSerializeFMUstate is false");
}
fmi2Status fmi2GetDirectionalDerivative(fmi2Component c, const fmi2ValueReference u[], size_t nu,
                                        const fmi2ValueReference z[], size_t nz, const fmi2Real dv[],
                                        fmi2Real dz[]) {
    (void)u; (void)nu; (void)z; (void)nz; (void)dv; (void)dz;
    return fail((Instance *)c, "providesDirectionalDerivative is false");
}
fmi2Status fmi2SetRealInputDerivatives(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                                       const fmi2Integer order[], const fmi2Real value[]) {
    (void)vr; (void)nvr; (void)order; (void)value;
    return fail((Instance *)c, "canInterpolateInputs is false");
}
fmi2Status fmi2GetRealOutputDerivatives(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                                        const fmi2Integer order[], fmi2Real value[]) {
    (void)vr; (void)nvr; (void)order; (void)value;
    return fail((Instance *)c, "maxOutputDerivativeOrder is 0");
}
fmi2Status fmi2GetStatus(fmi2Component c, const fmi2StatusKind s, fmi2Status *value) {
    (void)c; (void)s;
    *value = fmi2OK;
    return fmi2OK;
}
fmi2Status fmi2GetRealStatus(fmi2Component c, const fmi2StatusKind s, fmi2Real *value) {
    (void)s; (void)value;
    return fail((Instance *)c, "fmi2GetRealStatus is not supported");
}
fmi2Status fmi2GetIntegerStatus(fmi2Component c, const fmi2StatusKind s, fmi2Integer *value) {
    (void)s; (void)value;
    return fail((Instance *)c, "fmi2GetIntegerStatus is not supported");
}
fmi2Status fmi2GetBooleanStatus(fmi2Component c, const fmi2StatusKind s, fmi2Boolean *value) {
    (void)s; (void)value;
    return fail((Instance *)c, "fmi2GetBooleanStatus is not supported");
}
fmi2Status fmi2GetStringStatus(fmi2Component c, const fmi2StatusKind s, fmi2String *value) {
    (void)s; (void)value;
    return fail((Instance *)c, "fmi2GetStringStatus is not supported");
}
