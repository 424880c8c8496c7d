"""The ``rhs-slam`` console command.

The top of the layers (``rhs_env`` <- ``slam`` <- ``agents`` <- here). Each
subcommand lives in its own module of the layer it belongs to, exposing
``configure(parser)`` and ``run(args) -> int``; this file only dispatches. A
subcommand whose module fails to import is an installation error and raises
(it is never silently dropped from the help).

``rhs-slam --version`` prints the installed package's version. Ctrl-C (SIGINT) that no
subcommand handles itself ends the command with one line on stderr and exit status 130
(128 + SIGINT), never a ``KeyboardInterrupt`` traceback.
"""

from __future__ import annotations

import argparse
import importlib
import signal
import sys

# name -> (module, one-line help)
SUBCOMMANDS: dict[str, tuple[str, str]] = {
    "demo": ("agents.demo", "one SLAM-in-the-loop episode with the shipped policy"),
    "patterns": ("rhs_env.patterns.cli", "build or load a holographic pattern library and report it"),
    "scan": ("rhs_env.scan_cli", "one radar cycle on targets from a scene JSON file"),
    "scenario": ("slam.gym.scenario_cli", "SLAM on a scripted run from a scenario JSON file"),
    "train": ("agents.algos.train", "train a driving agent with stable-baselines3"),
    "evaluate": ("agents.evaluate", "evaluate a driving policy with SLAM metrics"),
    "record": ("agents.record", "drive a policy and write the episodes as a Minari dataset"),
}


def build_parser() -> tuple[argparse.ArgumentParser, dict[str, str]]:
    parser = argparse.ArgumentParser(
        prog="rhs-slam",
        description="RHS radar SLAM on highway-env: patterns, radar scans, SLAM runs, agents.",
    )
    parser.add_argument("--version", action="version", version=f"%(prog)s {package_version()}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    modules = {}
    for name, (module, text) in SUBCOMMANDS.items():
        p = sub.add_parser(name, help=text, description=text)
        importlib.import_module(module).configure(p)
        modules[name] = module
    return parser, modules


def package_version() -> str:
    """The installed ``rhs-slam`` distribution's version (``importlib.metadata``), or ``unknown``."""
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("rhs-slam")
    except PackageNotFoundError:
        return "unknown (not installed: pip install -e .)"


def main(argv: list[str] | None = None) -> int:
    command = None
    try:
        parser, modules = build_parser()
        args = parser.parse_args(argv)
        command = args.command
        if command is None:
            parser.print_help()
            return 2
        return int(importlib.import_module(modules[command]).run(args) or 0)
    except KeyboardInterrupt:
        print(f"rhs-slam{f' {command}' if command else ''}: interrupted (Ctrl-C); stopped", file=sys.stderr)
        return 128 + int(signal.SIGINT)


if __name__ == "__main__":
    sys.exit(main())
