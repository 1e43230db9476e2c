/* Arm-driven inverted pendulum (ADIP), equations of fmu_plants/adip/README.md.
 *
 * Two links in a vertical plane, angles phi1 (arm) and phi2 (pendulum) from the upward vertical:
 *   [a            c cos(d)] [phi1'']   [tau - B1 w1 + B2 (w2 - w1) - c sin(d) w2^2 + d1 sin(phi1) - Fc tanh(w1/wc)]
 *   [c cos(d)     b       ] [phi2''] = [    - B2 (w2 - w1) + c sin(d) w1^2 + d2 sin(phi2)                     ]
 * with d = phi1 - phi2, a = J1 + m1 l1^2 + m2 L1^2 + Jeq, b = J2 + m2 l2^2, c = m2 L1 l2,
 * d1 = (m1 l1 + m2 L1) g, d2 = m2 l2 g, and the DC motor torque
 *   tau = eta_g Kg eta_m kt (V - Kg km w1) / Rm.
 */
#include "model_variables.h"

static void coefficients(const double *r, double *a, double *b, double *c, double *d1, double *d2) {
    const double m1 = r[VR_arm_mass], L1 = r[VR_arm_length], l1 = r[VR_arm_com];
    const double m2 = r[VR_pendulum_mass], l2 = r[VR_pendulum_com], g = r[VR_gravity];
    *a = r[VR_arm_inertia] + m1 * l1 * l1 + m2 * L1 * L1 + r[VR_motor_inertia];
    *b = r[VR_pendulum_inertia] + m2 * l2 * l2;
    *c = m2 * L1 * l2;
    *d1 = (m1 * l1 + m2 * L1) * g;
    *d2 = m2 * l2 * g;
}

static void derivatives(const double *r, const double *u, const double *x, double *dx) {
    double a, b, c, d1, d2;
    coefficients(r, &a, &b, &c, &d1, &d2);
    const double w1 = x[2], w2 = x[3], delta = x[0] - x[1];
    const double kg = r[VR_gear_ratio];
    const double tau = r[VR_gear_efficiency] * kg * r[VR_motor_efficiency] * r[VR_motor_torque_constant] *
                       (u[0] - kg * r[VR_motor_emf_constant] * w1) / r[VR_motor_resistance];
    const double joint = r[VR_pendulum_damping] * (w2 - w1);
    const double friction = r[VR_effect_coulomb] * tanh(w1 / r[VR_coulomb_velocity]);
    const double f1 = tau - r[VR_arm_damping] * w1 + joint - c * sin(delta) * w2 * w2 + d1 * sin(x[0]) - friction;
    const double f2 = -joint + c * sin(delta) * w1 * w1 + d2 * sin(x[1]);
    const double m12 = c * cos(delta), det = a * b - m12 * m12;
    dx[0] = w1;
    dx[1] = w2;
    dx[2] = (b * f1 - m12 * f2) / det;
    dx[3] = (a * f2 - m12 * f1) / det;
}

static void outputs(double *r, const double *u, const double *x) {
    (void)u;
    double a, b, c, d1, d2;
    coefficients(r, &a, &b, &c, &d1, &d2);
    const double w1 = x[2], w2 = x[3];
    r[VR_arm_angle] = x[0];
    r[VR_pendulum_angle] = x[1];
    r[VR_diag_scheduling] = sin(x[0]);
    r[VR_diag_energy] = 0.5 * a * w1 * w1 + 0.5 * b * w2 * w2 + c * cos(x[0] - x[1]) * w1 * w2 +
                        d1 * (1.0 + cos(x[0])) + d2 * (1.0 + cos(x[1]));
}

static const fmi2ValueReference X0[] = {VR_x0_arm_angle, VR_x0_pendulum_angle, VR_x0_arm_rate,
                                        VR_x0_pendulum_rate};
static const fmi2ValueReference STATE[] = {VR_diag_state_arm_angle, VR_diag_state_pendulum_angle,
                                           VR_diag_state_arm_rate, VR_diag_state_pendulum_rate};
static const fmi2ValueReference DER[] = {VR_diag_der_arm_angle, VR_diag_der_pendulum_angle,
                                         VR_diag_der_arm_rate, VR_diag_der_pendulum_rate};
static const fmi2ValueReference INPUT[] = {VR_voltage};
static const int ACTUATOR[] = {1};
static const fmi2ValueReference APPLIED[] = {VR_diag_applied_voltage};
static const fmi2ValueReference MEASURED[] = {VR_arm_angle, VR_pendulum_angle};

const PlantModel PLANT = {
    MODEL_GUID, N_REAL, REAL_VAR_NAME, REAL_VAR_START, REAL_VAR_MIN, REAL_VAR_MAX, REAL_VAR_CAUSALITY,
    N_INT, INT_VAR_NAME, INT_VAR_START, INT_VAR_MIN, INT_VAR_MAX, INT_VAR_CAUSALITY,
    4, X0, STATE, DER,
    1, INPUT, ACTUATOR, APPLIED,
    2, MEASURED,
    derivatives, outputs, NULL,
};
