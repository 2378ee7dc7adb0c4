"""`radical` console script: one entry point, one module per subcommand.

Each subcommand lives in its own module exposing ``add_arguments(parser)`` and ``run(args) -> int``;
this file only wires them together (lazily, so `radical --help` stays fast and a missing optional
dependency only affects its own subcommand).
"""

from __future__ import annotations

import argparse
import importlib
import re
import sys
import warnings

from radical_rt import __version__

#: subcommand -> (module, one-line help)
COMMANDS: dict[str, tuple[str, str]] = {
    "synth": ("replayer.synth.cli", "synthesize a MESSENGER-like telemetry archive (MCAP)"),
    "process": ("radical_rt.apps.batch", "run the calibration engine over archives (batch shell)"),
    "node": ("radical_rt.apps.node_cli", "run the streaming filter node over Zenoh"),
    "replay": ("replayer.replay", "publish an archive's input channels over Zenoh"),
    "record": ("replayer.record", "record radical/<vehicle>/** keys to MCAP"),
    "monitor": ("monitors.cli", "live dashboards (web, tui)"),
    "report": ("monitors.report", "paper-style tables and figures from an output archive"),
    "bench": ("perf.cli", "run the benchmark suite"),
    "export": ("monitors.fox_export", "re-encode an archive for Foxglove / Lichtblick (json)"),
    "allan": ("monitors.allan", "Allan deviation and gyro noise parameters from a static segment"),
    "design": ("radical_rt.apps.design.cli", "covariance analysis and optimization of a calibration maneuver"),
}


def build_parser() -> argparse.ArgumentParser:
    """Parser with one sub-parser per available subcommand."""
    parser = argparse.ArgumentParser(
        prog="radical", description="RADICAL-RT: RIMU calibration and attitude determination")
    parser.add_argument("--version", action="version", version=f"radical {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name, (module, help_text) in COMMANDS.items():
        try:
            mod = importlib.import_module(module)
        except ModuleNotFoundError as exc:
            if exc.name and module.startswith(exc.name):
                continue  # subcommand not built in this version
            _broken(sub, name, help_text, exc)
            continue
        except ImportError as exc:  # one broken subcommand must not take the others down
            _broken(sub, name, help_text, exc)
            continue
        p = sub.add_parser(name, help=help_text, description=plain_text(mod.__doc__ or help_text),
                           formatter_class=argparse.RawDescriptionHelpFormatter)
        mod.add_arguments(p)
        p.set_defaults(handler=mod.run)
    return parser


_ROLE = re.compile(r":[a-z]+:`~?([^`]+)`")  # :class:`~a.b.C`, :func:`f`


def plain_text(doc: str) -> str:
    """A module docstring as terminal help: reStructuredText markup removed (````x```` → x,
    :role:`~a.b.C` → C, :role:`a.b` → a.b, a literal block's ``::`` → ``:``)."""
    def role(m: re.Match) -> str:
        target = m.group(1)
        return target.rsplit(".", 1)[-1] if m.group(0).split("`")[1].startswith("~") else target

    text = _ROLE.sub(role, doc.strip())
    text = text.replace("``", "")
    return re.sub(r"(\S)::$", r"\1:", text, flags=re.M)


def _show_warning(message, category, filename, lineno, file=None, line=None) -> None:
    """Warnings on the command line: one clean line, no Python source line."""
    print(f"radical: warning: {' '.join(str(message).split())}", file=sys.stderr)


def _broken(sub, name: str, help_text: str, exc: Exception) -> None:
    """Register a subcommand whose module failed to import: it reports the error when run."""
    p = sub.add_parser(name, help=f"{help_text} (unavailable: {exc})")

    def run(_args: argparse.Namespace) -> int:
        print(f"radical {name}: unavailable: {exc}", file=sys.stderr)
        return 2

    p.set_defaults(handler=run)


def main(argv: list[str] | None = None) -> int:
    """Entry point of the `radical` console script."""
    parser = build_parser()
    args = parser.parse_args(argv)
    if not getattr(args, "handler", None):
        parser.print_help()
        return 2
    try:
        with warnings.catch_warnings():  # (restores the display when main returns)
            warnings.showwarning = _show_warning
            return int(args.handler(args) or 0)
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
