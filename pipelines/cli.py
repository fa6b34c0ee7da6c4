"""The ``vpr`` command line, above the pipelines.

Each pipeline module listed in :data:`MODULES` contributes its sub-commands:

- ``COMMANDS = {"name": "one-line help", ...}``, a literal dict;
- ``add_arguments(parser, command)``, adding the command's arguments;
- ``run_command(args) -> int``, a thin adapter from the parsed arguments to the
  module's functions (which take explicit parameters).

``vpr --help`` reads the ``COMMANDS`` literals from the modules' source
without importing them, and only the chosen command's module is imported, so
the help and typos stay fast.

Bad input (missing or corrupt files, wrong arguments) and file-system errors
(read-only or full disk, permissions) end the run with one line on stderr and exit
status 2; Ctrl-C, also during start-up, with ``vpr: interrupted`` and status 130;
an unexpected failure with a traceback and status 1. Warnings are one line each
(``vpr: warning: ...``), and progress bars are drawn only when stderr is a terminal.
"""
from __future__ import annotations

import argparse
import ast
import contextlib
import gc
import importlib
import importlib.util
import os
import re
import sys
import warnings
from pathlib import Path

from vpr.interrupts import Terminated, import_held, on_sigterm, restore, stopped_import

__all__ = ["MODULES", "commands", "build_parser", "main"]

#: The pipeline modules providing sub-commands, in the order ``vpr --help`` lists them.
MODULES = ("pipelines.demo", "pipelines.match", "pipelines.loops", "pipelines.render", "pipelines.encoders_cmd",
           "pipelines.encode", "pipelines.paper_fig3", "pipelines.nordland", "pipelines.localize")


def _declared_commands(module: str) -> dict:
    """The ``COMMANDS`` literal of ``module``, read from its source (importing would be slow)."""
    spec = importlib.util.find_spec(module)
    if spec is None or not spec.origin or not spec.origin.endswith(".py"):
        return dict(importlib.import_module(module).COMMANDS)
    tree = ast.parse(Path(spec.origin).read_text(encoding="utf-8"), spec.origin)
    for node in tree.body:
        target = node.target if isinstance(node, ast.AnnAssign) else (
            node.targets[0] if isinstance(node, ast.Assign) and len(node.targets) == 1 else None)
        if isinstance(target, ast.Name) and target.id == "COMMANDS" and node.value is not None:
            return dict(ast.literal_eval(node.value))
    raise RuntimeError(f"{spec.origin}: no literal COMMANDS dict (needed by pipelines.cli)")


def commands() -> dict[str, tuple[str, str]]:
    """Every sub-command: name -> (module, one-line help)."""
    out: dict[str, tuple[str, str]] = {}
    for module in MODULES:
        for name, help_ in _declared_commands(module).items():
            if name in out:
                raise RuntimeError(f"command {name!r} is declared by {out[name][0]} and {module}")
            out[name] = (module, help_)
    return out


def build_parser(only: str | None = None, table: dict | None = None) -> argparse.ArgumentParser:
    """The ``vpr`` parser; with ``only``, just that command gets its arguments (imports one module)."""
    from vpr import __version__  # imports here keep `vpr --help` and typos fast

    table = commands() if table is None else table
    ap = argparse.ArgumentParser(prog="vpr", description="Sequence-based visual place recognition: "
                                 "a sequence memory and its baselines, evaluation and plots.")
    ap.add_argument("--version", action="version", version=f"vpr {__version__}")
    sub = ap.add_subparsers(dest="command", metavar="COMMAND")
    for cmd, (module, help_) in table.items():
        p = sub.add_parser(cmd, help=help_, description=help_)
        if only is None or cmd == only:
            # NumPy, OpenCV, numba load here: a stop while they load is held, not lost in their loaders
            import_held(module).add_arguments(p, cmd)
    return ap


def _format_warning(message, category, filename, lineno, line=None) -> str:
    # one line in the project's words: no source path, no line of code
    return f"vpr: warning: {' '.join(str(message).split())}\n"


def _os_error_line(e: OSError) -> str:
    """One line naming the path and the reason of an OSError."""
    reason = e.strerror or " ".join(str(e).split())
    if e.filename is not None:
        extra = f" -> {e.filename2}" if getattr(e, "filename2", None) else ""
        return f"{e.filename}{extra}: {reason}"
    return reason


#: Options that name a file or folder to write or read: an empty value would mean the current folder.
_PATH_OPTIONS = ("out", "state_out", "resume", "cache")


def _check_paths(args) -> None:
    """Refuse an empty path (``--out ""``), which would write into the current folder without saying so."""
    for name in _PATH_OPTIONS:
        value = getattr(args, name, None)
        if value is not None and not str(value).strip():
            raise ValueError(f"--{name.replace('_', '-')}: an empty path; name a folder or a file")


def _memory_budget(size):
    """``--memory-budget SIZE`` in force for the run (:func:`vpr.similarity.dense_budget`); none given: the default."""
    if size is None:
        return contextlib.nullcontext()
    from pipelines.args import parse_size
    from vpr.similarity import dense_budget  # numba's import only where the option is used

    return dense_budget(parse_size(size))


_NEGATIVE = re.compile(r"-\.?\d")


def _join_negative_values(argv: list[str]) -> list[str]:
    """``--every -1m`` as ``--every=-1m``: argparse takes a value that starts with ``-`` for an option, and would
    answer with its usage instead of the option's own one-line refusal of a negative value."""
    out = []
    for a in argv:
        if out and out[-1].startswith("--") and "=" not in out[-1] and _NEGATIVE.match(a):
            out[-1] = f"{out[-1]}={a}"
        else:
            out.append(a)
    return out


def main(argv=None) -> int:
    """Run ``vpr`` with ``argv`` (default: ``sys.argv[1:]``); returns the exit status.

    Bad input and file-system errors: one line on stderr, status 2; Ctrl-C (also
    while the modules load): ``vpr: interrupted``, status 130; stdout closed by
    its reader: no message, status 141 (as a process killed by SIGPIPE). Warnings are
    printed as ``vpr: warning: ...``; progress bars only on a terminal.
    """
    argv = _join_negative_values(sys.argv[1:] if argv is None else list(argv))
    # FFmpeg's decoder log (hundreds of lines for a damaged video) would bury the project's own
    # one-line report of skipped frames; read when OpenCV first opens a video, so set before any
    os.environ.setdefault("OPENCV_FFMPEG_LOGLEVEL", "-8")
    os.environ.setdefault("OPENCV_LOG_LEVEL", "ERROR")
    saved_format = warnings.formatwarning
    warnings.formatwarning = _format_warning
    saved_term = on_sigterm()
    stopped = False
    command = "vpr"
    try:
        table = commands()
        # build only the chosen command's arguments (cheap imports for --help and typos)
        cmd = next((a for a in argv if not a.startswith("-")), None)
        only = cmd if cmd in table else "__none__"
        try:
            ap = build_parser(only, table)
        except ModuleNotFoundError as e:
            print(f"vpr: error: command {cmd!r} is unavailable ({e})", file=sys.stderr)
            return 2
        args = ap.parse_args(argv)
        if not args.command:
            ap.print_help()
            return 2
        command = f"vpr {args.command}"
        if hasattr(args, "no_progress") and not sys.stderr.isatty():
            args.no_progress = True  # bars redrawn into a log file are noise
        try:
            if getattr(args, "verify", 0) or getattr(args, "geometry", "off") != "off":
                importlib.import_module("vpr.verify")  # its library's signal handlers replaced now, not mid-run
            _check_paths(args)
            with _memory_budget(getattr(args, "memory_budget", None)):
                return int(importlib.import_module(table[args.command][0]).run_command(args) or 0)
        except ValueError as e:  # bad input, including a state or map file that cannot be used
            print(f"{command}: error: {' '.join(str(e).split())}", file=sys.stderr)
            return 2
        except BrokenPipeError:
            # the reader of stdout went away (`vpr loops ... | head`): quiet, as Unix tools are; the
            # results were written before the table; stdout to devnull so the flush at exit cannot fail
            try:
                os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
            except (OSError, ValueError):  # a stdout without a file descriptor (captured, e.g. in tests)
                pass
            return 141
        except OSError as e:
            # read-only or full file system, permissions, missing files: the path and the reason
            print(f"{command}: error: {_os_error_line(e)}", file=sys.stderr)
            return 2
        except ImportError as e:  # a library loaded lazily (e.g. onnxruntime) stopped while it loaded
            if stopped_import(e):
                raise KeyboardInterrupt from e
            raise
    except Terminated:
        print("vpr: terminated", file=sys.stderr)
        stopped = True
        return 143
    except KeyboardInterrupt:
        print("vpr: interrupted", file=sys.stderr)
        stopped = True
        return 130
    finally:
        warnings.formatwarning = saved_format
        if stopped:  # what the stop cut short is finalised now, while its errors are known to be the stop's
            gc.collect()
        restore(saved_term)


if __name__ == "__main__":
    raise SystemExit(main())
