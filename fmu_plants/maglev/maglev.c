/* Two-disk magnetic levitation (ECP Model 730 type), equations of fmu_plants/maglev/README.md.
 *
 * Heights y1 (lower disk), y2 (upper disk) above the lower coil face, upward positive:
 *   m y1'' = F(i1, y1) - F(i2, yc - w - y1) - Fm - c1 y1' - Fc tanh(y1'/vc) - m g
 *   m y2'' = F(i2, yc - w - y2) - F(i1, y2) + Fm - c2 y2' - Fc tanh(y2'/vc) - m g
 * with the coil force F(i, s) = i / (a (s + b)^N) and the magnet repulsion
 * Fm = c / (y2 - y1 - w + d)^N. Stops: y1 >= 0 (lower coil), y2 <= yc - w (upper coil),
 * y2 - y1 >= w (disks touching, inelastic).
 */
#include "model_variables.h"

static double coil_force(const double *r, double current, double gap) {
    return current / (r[VR_coil_a] * pow(gap + r[VR_coil_b], r[VR_force_exponent]));
}

static void derivatives(const double *r, const double *u, const double *x, double *dx) {
    const double m = r[VR_disk_mass], g = r[VR_gravity], w = r[VR_disk_thickness];
    const double top = r[VR_coil_separation] - w;
    const double y1 = x[0], y2 = x[1], v1 = x[2], v2 = x[3];
    const double fm = r[VR_magnet_c] / pow(y2 - y1 - w + r[VR_magnet_d], r[VR_force_exponent]);
    const double fc = r[VR_effect_coulomb], vc = r[VR_coulomb_velocity];
    double a1 = (coil_force(r, u[0], y1) - coil_force(r, u[1], top - y1) - fm - r[VR_lower_friction] * v1 -
                 fc * tanh(v1 / vc)) / m - g;
    double a2 = (coil_force(r, u[1], top - y2) - coil_force(r, u[0], y2) + fm - r[VR_upper_friction] * v2 -
                 fc * tanh(v2 / vc)) / m - g;
    if (y1 <= 0.0 && v1 <= 0.0 && a1 < 0.0) a1 = 0.0; /* resting on the lower coil */
    if (y2 >= top && v2 >= 0.0 && a2 > 0.0) a2 = 0.0;  /* held against the upper coil */
    dx[0] = v1;
    dx[1] = v2;
    dx[2] = a1;
    dx[3] = a2;
}

static void constrain(const double *r, double *x) {
    const double w = r[VR_disk_thickness], top = r[VR_coil_separation] - w;
    const double overlap = x[0] + w - x[1];
    if (overlap > 0.0) { /* disks touching: inelastic contact of equal masses */
        x[0] -= 0.5 * overlap;
        x[1] += 0.5 * overlap;
        if (x[2] > x[3]) x[2] = x[3] = 0.5 * (x[2] + x[3]);
    }
    if (x[0] < 0.0) {
        x[0] = 0.0;
        if (x[2] < 0.0) x[2] = 0.0;
    }
    if (x[1] > top) {
        x[1] = top;
        if (x[3] > 0.0) x[3] = 0.0;
    }
    if (x[1] < x[0] + w) x[1] = x[0] + w;
    if (x[0] > x[1] - w) x[0] = x[1] - w;
}

static void outputs(double *r, const double *u, const double *x) {
    (void)u;
    r[VR_lower_disk_position] = x[0];
    r[VR_upper_disk_position] = x[1];
    r[VR_diag_scheduling] = x[1];
}

static const fmi2ValueReference X0[] = {VR_x0_lower_disk_position, VR_x0_upper_disk_position,
                                        VR_x0_lower_disk_velocity, VR_x0_upper_disk_velocity};
static const fmi2ValueReference STATE[] = {VR_diag_state_lower_disk_position, VR_diag_state_upper_disk_position,
                                           VR_diag_state_lower_disk_velocity, VR_diag_state_upper_disk_velocity};
static const fmi2ValueReference DER[] = {VR_diag_der_lower_disk_position, VR_diag_der_upper_disk_position,
                                         VR_diag_der_lower_disk_velocity, VR_diag_der_upper_disk_velocity};
static const fmi2ValueReference INPUT[] = {VR_lower_coil_current, VR_upper_coil_current};
static const int ACTUATOR[] = {1, 1};
static const fmi2ValueReference APPLIED[] = {VR_diag_applied_lower_coil_current, VR_diag_applied_upper_coil_current};
static const fmi2ValueReference MEASURED[] = {VR_lower_disk_position, VR_upper_disk_position};

const PlantModel PLANT = {
    MODEL_GUID, N_REAL, REAL_VAR_NAME, REAL_VAR_START, REAL_VAR_MIN, REAL_VAR_MAX, REAL_VAR_CAUSALITY,
    N_INT, INT_VAR_NAME, INT_VAR_START, INT_VAR_MIN, INT_VAR_MAX, INT_VAR_CAUSALITY,
    4, X0, STATE, DER,
    2, INPUT, ACTUATOR, APPLIED,
    2, MEASURED,
    derivatives, outputs, constrain,
};
