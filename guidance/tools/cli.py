"""The ``guidance`` command: one entry point, subcommands registered by the packages.

Each package that adds subcommands exposes ``register(subparsers)`` in the module
named in ``_COMMAND_MODULES``; the subparser sets ``func`` to a callable taking
the parsed namespace and returning an exit code. Errors a user can cause (bad
file, bad value) are raised as ``UserError`` and printed as one clear line, never
as a traceback; ``--debug`` shows the traceback of unexpected failures.
"""

from __future__ import annotations

import argparse
import contextlib
import importlib
import logging
import sys
from collections.abc import Sequence

from guidance.errors import UserError
from guidance.version import version_text

_COMMAND_MODULES = (
    "hal_sim.cli",  # study, check-guidance
    "hal_sim.sim_cli",  # sim
    "drivers.cli",  # odometry, compass
    "guidance.app.run",  # run
    "guidance.tools.monitor",  # monitor
    "guidance.tools.replay",  # replay
    "guidance.tools.evaluate",  # evaluate
    "guidance.tools.calibrate",  # calibrate
    "guidance.tools.recording_cli",  # recording repair
    "guidance.tools.voice_cli",  # voice say, voice listen
)
DEVICE_RUNNERS = {"sim": "hal_sim.sim_cli:run_on_simulated_devices"}
"""``guidance run`` on devices the product does not build itself: a name to the
``module:function`` that runs it, imported on first use (``guidance.app.backends``' way for
drivers). ``sim``: a config whose ``[sim]`` table says ``devices = true``. The table is the
command's, beside ``_COMMAND_MODULES``, so the product (``guidance.app``) never names the
simulator; ``guidance run`` finds it in its parsed arguments (``device_runners``)."""


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="guidance",
        description="Urban driver guidance without GPS or a road map.",
    )
    version = version_text("guidance")
    parser.add_argument("--version", action="version", version=version)
    parser.add_argument("--debug", action="store_true", help="show tracebacks and debug logs")
    parser.set_defaults(device_runners=DEVICE_RUNNERS)
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name in _COMMAND_MODULES:
        try:
            module = importlib.import_module(name)
        except ModuleNotFoundError as exc:
            if exc.name == name:  # that package has not grown this command yet
                continue
            raise
        module.register(sub)
    for command in sub.choices.values():  # `guidance monitor --version` works too
        with contextlib.suppress(argparse.ArgumentError):  # unless it has its own
            command.add_argument("--version", action="version", version=version)
        with contextlib.suppress(argparse.ArgumentError):  # `guidance CMD --debug` as well
            command.add_argument(
                "--debug",
                action="store_true",
                default=argparse.SUPPRESS,  # absent: keeps `guidance --debug CMD`'s value
                help="show tracebacks and debug logs",
            )
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    logging.basicConfig(
        level=logging.DEBUG if args.debug else logging.WARNING,
        format="%(asctime)s %(levelname)s %(name)s: %(message)s",
    )
    if not getattr(args, "func", None):
        parser.print_help()
        return 2
    try:
        return int(args.func(args) or 0)
    except UserError as exc:
        print(f"guidance {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"guidance {args.command}: interrupted", file=sys.stderr)
        return 130
    except Exception as exc:
        if args.debug:
            raise
        print(
            f"guidance {args.command}: internal error: {type(exc).__name__}: {exc} "
            f"(run `guidance --debug {args.command} ...` for the traceback)",
            file=sys.stderr,
        )
        return 1


def entry() -> None:
    """The ``guidance`` program (the console script, ``python -m guidance.tools.cli``):
    ``main``, then the exit. After ``guidance run`` the process ends without the interpreter's
    finalization, everything flushed first (``guidance.app.run.end_process``)."""
    code = main()
    from guidance.app.run import end_process

    end_process(code)  # returns unless a run asked for it
    sys.exit(code)


if __name__ == "__main__":
    entry()
