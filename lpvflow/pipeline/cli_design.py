"""`lpvflow design [DESIGN.toml]`: the whole chain; without an argument, the bundled ADIP example."""

from __future__ import annotations

import argparse

from lpvflow.pipeline.config import bundled_config


def configure(p: argparse.ArgumentParser) -> None:
    p.add_argument("config", nargs="?", help="design TOML (default: the bundled ADIP example)")
    p.add_argument("--example", choices=["adip", "maglev", "airpath"],
                   help="run a bundled example instead of a file")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from lpvflow.pipeline.design import main_design

    return main_design(args.config or bundled_config(args.example or "adip"))
