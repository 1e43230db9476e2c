"""`lpvflow design [DESIGN.toml]`: the whole chain; without an argument, the bundled ADIP example."""

from __future__ import annotations

import argparse

from lpvflow.pipeline.config import bundled_config


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("design", help="run experiment → identify → … → export → report on a design file")
    p.add_argument("config", nargs="?", help="design TOML (default: the bundled ADIP example)")
    p.add_argument("--example", choices=["adip", "maglev", "airpath"],
                   help="run a bundled example instead of a file")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from lpvflow.pipeline.design import main_design

    return main_design(args.config or bundled_config(args.example or "adip"))
