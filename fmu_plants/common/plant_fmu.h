/* Shared FMI 2.0 Co-Simulation engine for the lpvflow plant models.
 *
 * A plant supplies one `PlantModel` (its variable tables, generated from its
 * modelDescription.xml into model_variables.h by fmu_plants/build.py, plus its
 * equations); plant_fmu.c implements every FMI 2.0 function on top of it:
 * fixed-step RK4 with internal sub-steps, the effect parameters (input dead
 * time, dead zone, saturation, sensor offset, seeded Gaussian noise) and the
 * range checks of the parameters.
 */
#ifndef PLANT_FMU_H
#define PLANT_FMU_H

#include "fmi2Functions.h"

enum { CAUSALITY_PARAMETER = 0, CAUSALITY_INPUT = 1, CAUSALITY_OUTPUT = 2 };

typedef struct {
    /* variable tables (generated; real and integer value references are 0..n-1) */
    const char *guid;
    int n_real;
    const char *const *real_name;
    const double *real_start;
    const double *real_min;
    const double *real_max;
    const int *real_causality;
    int n_int;
    const char *const *int_name;
    const int *int_start;
    const int *int_min;
    const int *int_max;
    const int *int_causality;

    /* structure */
    int n_states;
    const fmi2ValueReference *x0_vr;    /* start-value parameter of each state */
    const fmi2ValueReference *state_vr; /* diagnostic output of each state */
    const fmi2ValueReference *der_vr;   /* diagnostic output of each state derivative */
    int n_inputs;
    const fmi2ValueReference *input_vr;
    const int *input_is_actuator;          /* 1: effects apply, 0: exogenous signal */
    const fmi2ValueReference *applied_vr;  /* diagnostic output of each input after the effects */
    int n_measured;
    const fmi2ValueReference *measured_vr; /* outputs that get the sensor offset and the noise */

    /* equations; r is the real-variable array indexed by value reference, u the
     * inputs after the effects (order of input_vr), x the state */
    void (*derivatives)(const double *r, const double *u, const double *x, double *dx);
    void (*outputs)(double *r, const double *u, const double *x); /* noise-free outputs */
    void (*constrain)(const double *r, double *x);                 /* stops/limits, may be NULL */
} PlantModel;

extern const PlantModel PLANT;

#endif
