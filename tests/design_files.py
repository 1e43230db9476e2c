"""Design-file text shared by the tests that run the pipeline on the ADIP FMU (tests/test_iterate.py,
tests/test_ident_experiment.py, tests/test_experiment_lpv_controller.py) and on the tanks FMU
(tests/test_design.py, tests/test_pipeline_structure.py, tests/test_robustness.py)."""


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


def tanks_head(plant: object, out: object) -> str:
    """[design], [experiment] and the signals of [identify] shared by the fast tanks designs of the tests
    (the stable two-tank FMU, random pump levels for 1500 s at Ts = 1 s, the lower level as scheduling);
    each test appends the rest of its [identify] table and its other tables."""
    return f"""
[design]
name = "tanks"
plant = "{plant}"
output_dir = "{out}"

[experiment]
Ts = 1.0
duration = 1500.0
inputs = {{ pump_voltage = "levels:lo=4,hi=11,min_hold=5,max_hold=40" }}
scheduling = {{ level = "lower_level" }}
seed = 3

[identify]
u = ["pump_voltage"]
y = ["lower_level"]
p = ["level"]
"""

