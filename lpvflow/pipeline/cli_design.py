"""`lpvflow design [DESIGN.toml]`: the whole chain; without an argument, the bundled ADIP example."""

from __future__ import annotations

import argparse

from lpvflow.errors import DataError
from lpvflow.pipeline.config import BUNDLED, bundled_config, repository_root


def configure(p: argparse.ArgumentParser) -> None:
    p.add_argument("config", nargs="?", help="design TOML (default: the bundled ADIP example)")
    p.add_argument("--example", choices=BUNDLED,
                   help="run a bundled example instead of a file (its plant paths are relative to the "
                        "repository, so it runs from any folder; output in ./build/design/NAME)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from lpvflow.pipeline.design import main_design

    if args.config and args.example:
        raise DataError("give a design file or --example, not both")
    if args.config:
        return main_design(args.config)
    return main_design(bundled_config(args.example or BUNDLED[0]), root=repository_root())
