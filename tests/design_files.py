"""Design-file text shared by the tests that run the pipeline on the ADIP FMU (tests/test_iterate.py,
tests/test_ident_experiment.py, tests/test_experiment_lpv_controller.py) and on the tanks FMU
(tests/test_design.py, tests/test_pipeline_structure.py, tests/test_robustness.py,
tests/test_trajectory_validation.py, tests/test_cli_errors.py and through it tests/test_bad_input.py and
tests/test_interrupt.py)."""


def adip_identification(grid: int, gate: str = "gate = false", remove_trim: bool = False) -> str:
    """The [identify], [reduce] and [validate] tables of an ADIP design: voltage to both angles scheduled
    on ``sin_arm``, reduced to order 4, validated on ``grid`` points against the FMU's linearizations with
    the ``gate`` line given (text, may be a format field)."""
    trim = "remove_trim = true\n" if remove_trim else ""
    return f"""
[identify]
u = ["voltage"]
y = ["arm_angle", "pendulum_angle"]
p = ["sin_arm"]
{trim}
[reduce]
order = 4

[validate]
grid = {grid}
reference = "linearization"
{gate}
"""


def tanks_head(plant: object, out: object, duration: float = 1500.0, seed: int = 3) -> str:
    """[design], [experiment] and the signals of [identify] shared by the fast tanks designs of the tests
    (the stable two-tank FMU, random pump levels for ``duration`` seconds at Ts = 1 s drawn with ``seed``,
    the lower level as scheduling); each test appends the rest of its [identify] table and its other
    tables."""
    return f"""
[design]
name = "tanks"
plant = "{plant}"
output_dir = "{out}"

[experiment]
Ts = 1.0
duration = {duration}
inputs = {{ pump_voltage = "levels:lo=4,hi=11,min_hold=5,max_hold=40" }}
scheduling = {{ level = "lower_level" }}
seed = {seed}

[identify]
u = ["pump_voltage"]
y = ["lower_level"]
p = ["level"]
"""



def tanks_synth(*keys: str) -> str:
    """The [synth] table of the tanks designs: the box of lower levels 5–18 cm and the mixed-sensitivity
    weights (W_S a first-order low-pass of bandwidth 0.2 rad/s, constant W_K, W_B a first-order input
    filter), with ``keys`` (lines such as ``method = "common"``) first."""
    return "\n[synth]\n" + "".join(f"{key}\n" for key in keys) + """box = [[0.05, 0.18]]
weights.S = { bandwidth = 0.2, hf_gain = 0.5 }
weights.K = { num = [0.01], den = [1] }
weights.B = { num = [0, 0.5], den = [1, -0.5] }
weights.integrator_shift = 1e-4
"""
