"""Output paths of every command, handled one way: missing parent directories are created before
any work starts; a path that cannot be written is refused at once with one line, never after a run.

Commands declare their output options with ``type=output_file`` (a file: its parent directories
are created) or ``type=output_dir`` (a directory: created with its parents), so argparse applies
the policy while parsing, before the command runs; an impossible path is a usage error (exit 2)
naming the option. Library entry points call :func:`prepare_output` themselves.
"""

from __future__ import annotations

import argparse
import os
from pathlib import Path


class OutputPathError(ValueError):
    """An output path that cannot be used; the message names the path and the reason."""


def prepare_output(path: str | os.PathLike, directory: bool = False) -> Path:
    """Create what ``path`` needs (its parent directories, or itself and its parents when
    ``directory``) and check it can be written. Returns the path; OutputPathError otherwise."""
    p = Path(path)
    target = p if directory else p.parent
    if not directory and p.is_dir():
        raise OutputPathError(f"{p} is a directory, not a file")
    if directory and p.exists() and not p.is_dir():
        raise OutputPathError(f"{p} exists and is not a directory")
    try:
        target.mkdir(parents=True, exist_ok=True)
    except FileExistsError:
        raise OutputPathError(f"cannot create directory {target}: a file is in the way") from None
    except OSError as exc:
        raise OutputPathError(f"cannot create directory {target}: {exc.strerror or exc}") from None
    if not os.access(target, os.W_OK | os.X_OK):
        raise OutputPathError(f"directory {target} is not writable")
    return p


def output_file(value: str) -> str:
    """argparse ``type`` of an output file option (parents created while parsing)."""
    try:
        prepare_output(value)
    except OutputPathError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None
    return value


def output_dir(value: str) -> str:
    """argparse ``type`` of an output directory option (created with its parents while parsing)."""
    try:
        prepare_output(value, directory=True)
    except OutputPathError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None
    return value
