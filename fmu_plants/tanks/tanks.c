/* Two cascaded tanks with Torricelli outflow, equations of fmu_plants/tanks/README.md.
 *
 *   A h1' = kp max(u, 0) - a1 sqrt(2 g h1)
 *   A h2' = a1 sqrt(2 g h1) - a2 sqrt(2 g h2)
 * A level at the tank height H does not rise further (the excess overflows and is lost);
 * levels stay in [0, H].
 */
#include "model_variables.h"

static double torricelli(double area, double g, double level) {
    return area * sqrt(2.0 * g * (level > 0.0 ? level : 0.0));
}

static void derivatives(const double *r, const double *u, const double *x, double *dx) {
    const double A = r[VR_tank_area], H = r[VR_tank_height], g = r[VR_gravity];
    const double inflow = r[VR_pump_gain] * (u[0] > 0.0 ? u[0] : 0.0);
    const double q1 = torricelli(r[VR_upper_outlet_area], g, x[0]);
    const double q2 = torricelli(r[VR_lower_outlet_area], g, x[1]);
    dx[0] = (inflow - q1) / A;
    dx[1] = (q1 - q2) / A;
    for (int i = 0; i < 2; ++i) {
        if (x[i] >= H && dx[i] > 0.0) dx[i] = 0.0;
    }
}

static void constrain(const double *r, double *x) {
    const double H = r[VR_tank_height];
    for (int i = 0; i < 2; ++i) x[i] = x[i] < 0.0 ? 0.0 : (x[i] > H ? H : x[i]);
}

static void outputs(double *r, const double *u, const double *x) {
    (void)u;
    r[VR_lower_level] = x[1];
    r[VR_diag_scheduling] = x[1];
}

static const fmi2ValueReference X0[] = {VR_x0_upper_level, VR_x0_lower_level};
static const fmi2ValueReference STATE[] = {VR_diag_state_upper_level, VR_diag_state_lower_level};
static const fmi2ValueReference DER[] = {VR_diag_der_upper_level, VR_diag_der_lower_level};
static const fmi2ValueReference INPUT[] = {VR_pump_voltage};
static const int ACTUATOR[] = {1};
static const fmi2ValueReference APPLIED[] = {VR_diag_applied_pump_voltage};
static const fmi2ValueReference MEASURED[] = {VR_lower_level};

const PlantModel PLANT = {
    MODEL_GUID, N_REAL, REAL_VAR_NAME, REAL_VAR_START, REAL_VAR_MIN, REAL_VAR_MAX, REAL_VAR_CAUSALITY,
    N_INT, INT_VAR_NAME, INT_VAR_START, INT_VAR_MIN, INT_VAR_MAX, INT_VAR_CAUSALITY,
    2, X0, STATE, DER,
    1, INPUT, ACTUATOR, APPLIED,
    1, MEASURED,
    derivatives, outputs, constrain,
};
