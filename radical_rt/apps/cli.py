"""`radical` console script: one entry point, one module per subcommand.

Each subcommand lives in its own module exposing ``HELP`` (its line in ``radical --help``),
``add_arguments(parser)`` and ``run(args) -> int``; this file only wires them together. The
engine's own commands (``process``, ``node``) are named here; every other one is provided by an
installed package through an entry point of group ``radical.commands`` (``name = "module"``, in
pyproject.toml's ``[project.entry-points."radical.commands"]``), so that this package names none
of the tools built on it. The contract's commands (CONTRACT §5) are always listed: one whose
provider is not installed says so when run. A provider that fails to import is listed as
unavailable and reports its error when run, without taking the other subcommands down.
"""

from __future__ import annotations

import argparse
import importlib
import logging
import os
import re
import sys
import threading
import warnings
from importlib.metadata import entry_points
from types import ModuleType

from radical_rt import __version__

#: entry-point group of the subcommands provided by other packages
GROUP = "radical.commands"
#: subcommand -> module, for the commands of the engine package itself
BUILTIN = {"process": "radical_rt.apps.batch", "node": "radical_rt.apps.node_cli",
           "cmd": "radical_rt.apps.cmd_cli", "keys": "radical_rt.apps.keys_cli",
           "router": "radical_rt.apps.router_cli", "fleet": "radical_rt.apps.fleet_cli"}
#: the commands CONTRACT §5 requires of `radical`, in the order `radical --help` lists them
#: (the other subcommands follow in entry-point order)
CONTRACT_COMMANDS = ("synth", "process", "node", "replay", "record", "monitor", "report", "bench")


def providers() -> dict[str, str]:
    """subcommand -> module path: the engine's own commands, then the entry points of
    :data:`GROUP` (the first distribution providing a name wins; the engine's own are kept)."""
    found = dict(BUILTIN)
    for ep in entry_points(group=GROUP):
        found.setdefault(ep.name, ep.module)
    return found


def build_parser(command: str | None = None) -> argparse.ArgumentParser:
    """Parser with one sub-parser per subcommand (available, unavailable or not installed).

    ``command``: the subcommand a command line names (its first word); when it is a provided
    one, only its sub-parser is built, so that the other subcommands' modules are not imported
    (``radical process`` starts without the replayer, the monitors or the fleet). The parse of
    that command line is the same: the other sub-parsers only serve ``radical --help`` and the
    message for an unknown command, which a command line naming a provided one never prints."""
    parser = argparse.ArgumentParser(
        prog="radical", description="RADICAL-RT: RIMU calibration and attitude determination")
    parser.add_argument("--version", action="version", version=f"radical {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    found = {command: BUILTIN[command]} if command in BUILTIN else providers()
    names = [*CONTRACT_COMMANDS, *(n for n in found if n not in CONTRACT_COMMANDS)]
    if command in found:
        names = [command]
    for name in names:
        module = found.get(name)
        if module is None:
            _stub(sub, name, "not installed", f"not installed: no installed package provides "
                  f"this command (entry point group {GROUP!r}); reinstall radical-rt "
                  "(pip install -e .)")
            continue
        try:
            mod = importlib.import_module(module)
        except ModuleNotFoundError as exc:
            if exc.name and module.startswith(exc.name):  # the provider itself is missing
                _stub(sub, name, "not installed", f"not installed: its module {module} is "
                      "missing (a stale entry point); reinstall radical-rt (pip install -e .)")
            else:
                _stub(sub, name, f"unavailable: {exc}", f"unavailable: {exc}")
            continue
        except ImportError as exc:  # one broken subcommand must not take the others down
            _stub(sub, name, f"unavailable: {exc}", f"unavailable: {exc}")
            continue
        help_text = _help(mod)
        p = sub.add_parser(name, help=help_text, description=plain_text(mod.__doc__ or help_text),
                           formatter_class=argparse.RawDescriptionHelpFormatter)
        mod.add_arguments(p)
        p.set_defaults(handler=mod.run)
    return parser


def _help(mod: ModuleType) -> str:
    """A command module's ``HELP``, else the first line of its docstring."""
    text = getattr(mod, "HELP", None) or plain_text(mod.__doc__ or "").split("\n", 1)[0]
    return str(text)


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


def _stub(sub, name: str, note: str, error: str) -> None:
    """Register a subcommand that cannot run (``note`` in the help list): it prints
    ``radical NAME: ERROR`` and exits with 2 whatever its arguments."""
    p = sub.add_parser(name, help=f"({note})", add_help=False)

    def run(_args: argparse.Namespace) -> int:
        print(f"radical {name}: {error}", file=sys.stderr)
        return 2

    p.set_defaults(handler=run, stub_command=True)


def main(argv: list[str] | None = None) -> int:
    """Entry point of the `radical` console script (``argv`` None: the process's command line).

    A subcommand whose files are all written and closed when its handler returns may set the
    parser default ``exit_fast=True`` (``radical process`` does): on the process's own command
    line (``argv`` None) its exit code then ends the process at once (:func:`exit_fast`)."""
    words = sys.argv[1:] if argv is None else list(argv)
    parser = build_parser(words[0] if words and not words[0].startswith("-") else None)
    args, extra = parser.parse_known_args(words)
    if extra and not getattr(args, "stub_command", False):  # (a stub takes any arguments)
        parser.error(f"unrecognized arguments: {' '.join(extra)}")
    if not getattr(args, "handler", None):
        parser.print_help()
        return 2
    try:
        with warnings.catch_warnings():  # (restores the display when main returns)
            warnings.showwarning = _show_warning
            code = int(args.handler(args) or 0)
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        return 130
    if argv is None and getattr(args, "exit_fast", False):
        exit_fast(code)
    return code


def exit_fast(code: int) -> None:
    """End the process now with exit ``code``, skipping the interpreter's teardown (about 0.35 s
    after a `radical process` run: freeing Numba's dispatchers, LLVM's and every module's objects
    one by one; nothing of it reaches a file). Standard output and error are flushed and logging
    is shut down (its handlers flushed and closed) first; the exit handlers (atexit) do not run:
    after `radical process` they are Numba's and llvmlite's shutdown flags, the finalizers of
    Numba's dispatchers (which skip themselves at exit) and of its runtime (memory only), tqdm's
    monitor thread (a daemon) and multiprocessing's (no children); no file is left open. Returns, leaving the normal exit to do its part, when a
    thread that is not a daemon still runs (the normal exit waits for it) or a flush fails (e.g.
    a closed pipe: the normal exit reports it)."""
    if any(t.is_alive() and not t.daemon for t in threading.enumerate()
           if t is not threading.main_thread()):
        return
    try:
        sys.stdout.flush()
        sys.stderr.flush()
    except Exception:  # noqa: BLE001 - the normal exit reports it as Python does
        return
    logging.shutdown()
    os._exit(code)


if __name__ == "__main__":
    sys.exit(main())
