/* Gasoline-engine mean-value air path, equations of fmu_plants/airpath/README.md.
 *
 *   p_m' = R T / V_m (m_th - m_cyl)                                   (isothermal manifold)
 *   m_th = c_d A(alpha) p_a / sqrt(R T) Psi(p_m / p_a)                (throttle orifice)
 *   A(alpha) = A_leak + pi D^2 / 4 (1 - cos alpha), alpha = throttle / 100 * pi / 2
 *   m_cyl = eta_v(n, lift) p_m V_d n / (120 R T)                      (four-stroke cylinder flow)
 *   eta_v = (e0 + e1 n_k + e2 n_k^2) (1 - exp(-lift / l_c)), n_k = n / 1000 rpm, lift in [0, 1]
 * Psi is the compressible flow function: constant when choked, linearised to 0 between
 * linear_flow_ratio and 1, and 0 for p_m >= p_a (no back-flow).
 */
#include "model_variables.h"

static double clamp(double v, double lo, double hi) { return v < lo ? lo : (v > hi ? hi : v); }

static double unchoked(double k, double ratio) {
    return sqrt(2.0 * k / (k - 1.0) * (pow(ratio, 2.0 / k) - pow(ratio, (k + 1.0) / k)));
}

static double flow_function(const double *r, double ratio) {
    const double k = r[VR_heat_capacity_ratio], linear = r[VR_linear_flow_ratio];
    const double critical = pow(2.0 / (k + 1.0), k / (k - 1.0));
    if (ratio <= critical) return unchoked(k, critical);
    if (ratio < linear) return unchoked(k, ratio);
    if (ratio < 1.0) return unchoked(k, linear) * (1.0 - ratio) / (1.0 - linear);
    return 0.0;
}

static void flows(const double *r, const double *u, double p, double *throttle_flow, double *cylinder_flow) {
    const double R = r[VR_gas_constant], T = r[VR_ambient_temperature], pa = r[VR_ambient_pressure];
    const double alpha = clamp(u[0], 0.0, 100.0) / 100.0 * 1.5707963267948966;
    const double lift = clamp(u[1], 0.0, 100.0) / 100.0;
    const double n = u[2] > 0.0 ? u[2] : 0.0, nk = n / 1000.0;
    const double D = r[VR_throttle_diameter];
    const double area = r[VR_throttle_leak_area] + 0.7853981633974483 * D * D * (1.0 - cos(alpha));
    *throttle_flow = r[VR_discharge_coefficient] * area * pa / sqrt(R * T) * flow_function(r, p / pa);
    const double eta = (r[VR_efficiency_e0] + r[VR_efficiency_e1] * nk + r[VR_efficiency_e2] * nk * nk) *
                       (1.0 - exp(-lift / r[VR_lift_constant]));
    *cylinder_flow = eta * p * r[VR_displacement] * n / (120.0 * R * T);
}

static void derivatives(const double *r, const double *u, const double *x, double *dx) {
    double throttle_flow, cylinder_flow;
    flows(r, u, x[0], &throttle_flow, &cylinder_flow);
    dx[0] = r[VR_gas_constant] * r[VR_ambient_temperature] / r[VR_manifold_volume] * (throttle_flow - cylinder_flow);
}

static void constrain(const double *r, double *x) {
    (void)r;
    if (x[0] < 0.0) x[0] = 0.0;
}

static void outputs(double *r, const double *u, const double *x) {
    double throttle_flow, cylinder_flow;
    flows(r, u, x[0], &throttle_flow, &cylinder_flow);
    r[VR_air_mass_flow] = 1000.0 * throttle_flow;
    r[VR_manifold_pressure] = x[0] / 1000.0;
    r[VR_diag_cylinder_air_flow] = 1000.0 * cylinder_flow;
    r[VR_diag_scheduling] = u[2];
}

static const fmi2ValueReference X0[] = {VR_x0_manifold_pressure};
static const fmi2ValueReference STATE[] = {VR_diag_state_manifold_pressure};
static const fmi2ValueReference DER[] = {VR_diag_der_manifold_pressure};
static const fmi2ValueReference INPUT[] = {VR_throttle_position, VR_valve_lift, VR_engine_speed};
static const int ACTUATOR[] = {1, 1, 0};
static const fmi2ValueReference APPLIED[] = {VR_diag_applied_throttle_position, VR_diag_applied_valve_lift,
                                             VR_diag_applied_engine_speed};
static const fmi2ValueReference MEASURED[] = {VR_air_mass_flow, VR_manifold_pressure};

const PlantModel PLANT = {
    MODEL_GUID, N_REAL, REAL_VAR_NAME, REAL_VAR_START, REAL_VAR_MIN, REAL_VAR_MAX, REAL_VAR_CAUSALITY,
    N_INT, INT_VAR_NAME, INT_VAR_START, INT_VAR_MIN, INT_VAR_MAX, INT_VAR_CAUSALITY,
    1, X0, STATE, DER,
    3, INPUT, ACTUATOR, APPLIED,
    2, MEASURED,
    derivatives, outputs, constrain,
};
