"""``lpvflow experiment PLANT.fmu ...``: run an identification experiment on an FMU, write CSV + sidecar."""

from __future__ import annotations

import argparse

from lpvflow.errors import DataError
from lpvflow.experiment import run_fmu_experiment
from lpvflow.experiment.record import check_output_path, sidecar_path, write_record
from lpvflow.experiment.scheduling import parse_assignment
from lpvflow.experiment.specs import __doc__ as SPEC_HELP
from lpvflow.pipeline.cli_paths import declare
from lpvflow.pipeline.cli_values import assignments, intervals, numbers


def run(args: argparse.Namespace) -> int:
    inputs_of_run = [args.fmu, *([args.controller] if args.controller else [])]
    check_output_path(args.output, inputs_of_run)  # before the run: a wrong name costs nothing
    inputs = assignments(args.input, "--input", "throttle=multisine:f_lo=0.1,f_hi=5,rms=0.1")
    excitation = assignments(args.excitation, "--excitation", "voltage=multisine:f_lo=0.1,f_hi=5,rms=0.2")
    setpoint = assignments(args.setpoint, "--setpoint",
                            "arm_angle=levels:lo=-0.3,hi=0.3,min_hold=2,max_hold=4,ramp=0.5")
    parameters = numbers(assignments(args.set, "--set", "effect_noise_std=0.01"), "--set")
    quantization = numbers(assignments(args.quantization, "--quantization", "arm_angle=0.001534"),
                            "--quantization")
    noise = numbers(assignments(args.noise, "--noise", "arm_angle=1e-4"), "--noise")
    bounds = intervals(assignments(args.bound, "--bound", "pendulum_angle=-0.5,0.5"), "--bound")
    scheduling = None
    if args.scheduling:
        scheduling = dict(parse_assignment(item) for item in args.scheduling)
    record = run_fmu_experiment(
        args.fmu, args.Ts, args.duration, inputs=inputs, controller=args.controller, excitation=excitation,
        parameters=parameters, scheduling_columns=scheduling, seed=args.seed,
        record_diagnostics=args.diagnostics, setpoint=setpoint, quantization=quantization, noise=noise,
        output_bounds=bounds,
    )
    if not inputs and not args.controller:  # refused after the run: every other defect is named first
        raise DataError("no --input and no --controller: every plant input stayed at its start value "
                        "(a constant, uninformative record, not written); add --input NAME=SPEC per plant "
                        "input, e.g. --input pump_voltage=levels:lo=4,hi=11,min_hold=5,max_hold=40")
    write_record(record, args.output, inputs_of_run)
    columns = ", ".join(record.columns)
    print(f"wrote {args.output} ({record.metadata['n_samples']} samples; columns {columns}) "
          f"and {sidecar_path(args.output)}")
    return 0


def configure(parser: argparse.ArgumentParser) -> None:
    parser.description = (
        "Drive an FMU with excitation signals (open loop) or with a stabilising controller (LTI, "
        "gain-scheduled on a grid, or an LPV controller of `lpvflow synth`/`lpvflow design`) plus an "
        "excitation on its output and set-points on what it reads (closed loop); write CSV + <CSV>.json."
    )
    parser.epilog = SPEC_HELP
    parser.formatter_class = argparse.RawDescriptionHelpFormatter
    parser.add_argument("fmu", help="FMI 2.0 Co-Simulation FMU of the plant")
    parser.add_argument("--Ts", type=float, default=None,
                        help="communication step in seconds (default: the controller's Ts, else the step "
                        "the FMU declares)")
    parser.add_argument("--duration", type=float, required=True, help="experiment length in seconds")
    parser.add_argument("--input", action="append", metavar="NAME=SPEC",
                        help="signal driving a plant input directly (repeat per input)")
    parser.add_argument("--controller", metavar="CTRL.json",
                        help="stabilising controller, format lpvflow/lti-controller, "
                        "lpvflow/gridded-controller or lpvflow/lpv-controller (closed loop)")
    parser.add_argument("--excitation", action="append", metavar="NAME=SPEC",
                        help="signal added to the controller output driving plant input NAME")
    parser.add_argument("--setpoint", action="append", metavar="NAME=SPEC",
                        help="set-point for plant output NAME read by the controller, replacing its "
                        "y_operating_point (moves the operating point; multisine/prbs are centred on it); "
                        "an LPV controller's reference")
    parser.add_argument("--set", action="append", metavar="PARAM=VALUE",
                        help="FMU parameter set before initialisation, e.g. effect_noise_std=0.01")
    parser.add_argument("--scheduling", action="append", metavar="NAME=EXPR",
                        help="extra column computed from inputs/outputs, e.g. sin_arm=sin(arm_angle); "
                        "default: the plant's scheduling column, if it has one")
    parser.add_argument("--quantization", action="append", metavar="OUTPUT=STEP",
                        help="sensor quantization step of a plant output, e.g. "
                        "arm_angle=0.0015339807878856412 (4096 counts/rev); the controller and the record "
                        "see the quantized value")
    parser.add_argument("--noise", action="append", metavar="OUTPUT=STD",
                        help="standard deviation of white sensor noise on a plant output (added before "
                        "the quantization)")
    parser.add_argument("--bound", action="append", metavar="OUTPUT=MIN,MAX",
                        help="interval a plant output must stay in, e.g. pendulum_angle=-0.5,0.5: leaving "
                        "it ends the run as failed (exit 2, nothing written)")
    parser.add_argument("--diagnostics", action="store_true",
                        help="also record the FMU's diag_* outputs (noise-free states, applied inputs)")
    parser.add_argument("--seed", type=int, default=0, help="seed of the excitation signals (default 0)")
    parser.add_argument("-o", "--output", required=True, metavar="DATA.csv", help="CSV to write")
    parser.set_defaults(func=run)
    declare(parser, inputs=("fmu", "controller"), outputs=("output",))
