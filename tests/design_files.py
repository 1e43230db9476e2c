"""Design-file text shared by the tests that run the pipeline on the ADIP FMU (tests/test_iterate.py,
tests/test_ident_experiment.py, tests/test_experiment_lpv_controller.py)."""


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
